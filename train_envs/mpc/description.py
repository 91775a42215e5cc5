r"""Problem description of :class:`~train_envs.mpc.LinearMPC`: argument checks.

Every argument of the constructor, :meth:`~train_envs.mpc.LinearMPC.set_weights` and
:meth:`~train_envs.mpc.LinearMPC.set_model` is checked here and turned into float
arrays of the documented shapes (errors name the argument).  Output/state
constraints are grouped per family (:class:`_Group`: output box ``y``, output
polyhedron ``H_y``, state polyhedron ``H_x``, terminal box ``xN``, terminal polyhedron
``H_N``); rows with infinite bounds are dropped, each row keeps its exact-penalty
weight :math:`
ho` (``inf``: hard row).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

_SOFT_GROUPS = ("y", "H_y", "H_x", "xN", "H_N")


def _matrix(name: str, value: ArrayLike, *, column: bool = False) -> np.ndarray:
    try:
        a = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a real matrix, got {value!r}") from exc
    if a.ndim == 0:
        a = a.reshape(1, 1)
    elif a.ndim == 1:
        a = a.reshape(-1, 1) if column else a.reshape(1, -1)
    if a.ndim != 2:
        raise ValueError(f"{name} must be a 2-D matrix, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must contain only finite values")
    return a


def _weight(name: str, value: ArrayLike, dim: int) -> np.ndarray:
    """Scalar, diagonal (vector) or full symmetric PSD weight -> (dim, dim) matrix."""
    return _weight_eigh(name, value, dim)[0]


def _weight_eigh(
    name: str, value: ArrayLike, dim: int
) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray] | None]:
    """:func:`_weight` and, for a weight that is not diagonal, the ``eigh`` of the result
    its PSD check computed (``None`` for a diagonal one)."""
    try:
        w = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a real matrix, got {value!r}") from exc
    if w.ndim == 0:
        w = w * np.eye(dim)
    elif w.ndim == 1:
        if w.shape[0] != dim:
            raise ValueError(f"{name} must have shape ({dim},) or ({dim}, {dim}), got {w.shape}")
        w = np.diag(w)
    if w.shape != (dim, dim):
        raise ValueError(f"{name} must have shape ({dim}, {dim}), got {w.shape}")
    if not dim:
        if not np.all(np.isfinite(w)):
            raise ValueError(f"{name} must contain only finite values")
        return w, None
    eig = None
    if _is_diagonal(w):
        # a diagonal weight (the usual case, at every weight change): symmetric as it is,
        # PSD by its diagonal; a NaN or an infinity off the diagonal would count as
        # non-zero, so only the diagonal can hold one (checked on Python floats)
        d = np.diagonal(w).tolist()
        if not all(map(math.isfinite, d)):
            raise ValueError(f"{name} must contain only finite values")
        lam_min, scale = min(d), max(1.0, max(map(abs, d)))
    else:
        if not np.all(np.isfinite(w)):
            raise ValueError(f"{name} must contain only finite values")
        scale = max(1.0, float(np.max(np.abs(w))))
        if np.max(np.abs(w - w.T)) > 1e-9 * scale:
            raise ValueError(f"{name} must be symmetric")
        w = 0.5 * (w + w.T)
        eig = np.linalg.eigh(w)
        lam_min = float(eig[0][0])
    if lam_min < -1e-10 * scale:
        raise ValueError(f"{name} must be positive semidefinite")
    return w, eig


def _is_diagonal(w: np.ndarray) -> bool:
    """Whether every non-zero entry of the square matrix ``w`` lies on its diagonal (a NaN
    counts as non-zero)."""
    n = w.shape[0]
    if n <= 6:  # on Python floats: cheaper than two counts for the usual small weights
        flat = w.ravel().tolist()
        return all(flat[k] == 0.0 for k in range(n * n) if k % (n + 1))
    return np.count_nonzero(w) == np.count_nonzero(np.diagonal(w))


def _vector(name: str, value: ArrayLike, dim: int, *, allow_inf: bool = False) -> np.ndarray:
    try:
        v = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be real numbers, got {value!r}") from exc
    if v.ndim == 0:
        v = np.full(dim, float(v))
    if v.shape != (dim,):
        raise ValueError(f"{name} must have shape ({dim},), got {v.shape}")
    if np.any(np.isnan(v)) or (not allow_inf and not np.all(np.isfinite(v))):
        raise ValueError(f"{name} must contain only {'non-NaN' if allow_inf else 'finite'} values")
    return v


def _check_order(lo_name: str, lo: np.ndarray, hi_name: str, hi: np.ndarray) -> None:
    bad = np.flatnonzero(lo > hi)
    if bad.size:
        i = int(bad[0])
        raise ValueError(f"{lo_name}[{i}] ({lo[i]}) > {hi_name}[{i}] ({hi[i]})")


def _check_penalty_arg(soft_penalty: Any) -> None:
    if isinstance(soft_penalty, Mapping):
        unknown = set(soft_penalty) - set(_SOFT_GROUPS)
        if unknown:
            raise ValueError(
                f"soft_penalty keys must be among {_SOFT_GROUPS}, got {sorted(unknown)}"
            )
        return
    if np.ndim(soft_penalty) != 0:
        raise ValueError(
            "soft_penalty must be a scalar or a mapping {group: scalar or per-row vector}"
        )
    _vector("soft_penalty", soft_penalty, 1, allow_inf=True)


class _Group:
    """One family of output/state constraints (before the soft/hard split)."""

    def __init__(
        self,
        name: str,
        on: str,
        stages: np.ndarray,
        G: np.ndarray,
        lo: np.ndarray,
        hi: np.ndarray,
        rho: np.ndarray,
        two_sided: bool,
        cols: np.ndarray,
        dim_full: int,
    ) -> None:
        self.name = name
        self.on = on  # "x" or "y"
        self.stages = stages  # 1-based prediction stages
        self.G = G  # (r, n or p)
        self.lo = lo
        self.hi = hi
        self.rho = rho  # per row; inf -> hard
        self.two_sided = two_sided
        self.cols = cols  # original rows kept (indices into the construction-time rows)
        self.dim_full = dim_full  # number of construction-time rows (before dropping)
        self.lb_pos = np.empty((0, 0), dtype=np.int64)  # (stages, r) index into bound prefix
        self.ub_pos = np.empty((0, 0), dtype=np.int64)


class _DescriptionMixin:
    """Checks of the model, weights, penalties and stage scales; the constraint groups."""

    @staticmethod
    def _auto_form(Np: int, Nc: int, n: int, m: int) -> str:
        """QP form chosen by ``form="auto"`` (measured crossover, ``docs/design/mpc_engine.md``).

        Condensed for few decision variables (``Nc*m <= 20``), sparse otherwise.  The
        state dimension does not enter: the condensed QP does not grow with ``n``
        (e.g. a DMC FIR register), while the sparse one does.
        """
        del Np, n
        return "condensed" if Nc * m <= 20 else "sparse"

    def _check_model(
        self, A: ArrayLike, B: ArrayLike, C: ArrayLike | None, dims: tuple[int, int, int] | None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        A_ = _matrix("A", A)
        n = A_.shape[0]
        if A_.shape != (n, n):
            raise ValueError(f"A must be square, got shape {A_.shape}")
        if dims is not None and n != dims[0]:
            raise ValueError(
                f"set_model must keep the dimensions (n, m, p) = {dims}, got A {A_.shape}"
            )
        B_ = _matrix("B", B, column=True)
        if B_.shape[0] != n:
            raise ValueError(f"B must have shape ({n}, m) to match A, got {B_.shape}")
        C_ = np.eye(n) if C is None else _matrix("C", C)
        if C_.shape[1] != n:
            raise ValueError(f"C must have shape (p, {n}) to match A, got {C_.shape}")
        if dims is not None and (n, B_.shape[1], C_.shape[0]) != dims:
            raise ValueError(
                f"set_model must keep the dimensions (n, m, p) = {dims}, "
                f"got {(n, B_.shape[1], C_.shape[0])}"
            )
        return A_, B_, C_

    @staticmethod
    def _check_gamma(value: float) -> float:
        g = float(value)
        if not math.isfinite(g) or g < 0:
            raise ValueError(f"soft_quadratic must be finite and >= 0, got {value!r}")
        return g

    @staticmethod
    def _penalty(name: str, soft_penalty: Any, rows: int) -> np.ndarray:
        if isinstance(soft_penalty, Mapping):
            unknown = set(soft_penalty) - set(_SOFT_GROUPS)
            if unknown:
                raise ValueError(
                    f"soft_penalty keys must be among {_SOFT_GROUPS}, got {sorted(unknown)}"
                )
            val = soft_penalty.get(name, 1e5)
        else:
            val = soft_penalty
        rho = _vector(f"soft_penalty[{name!r}]", val, rows, allow_inf=True)
        if np.any(rho <= 0):
            raise ValueError(f"soft_penalty[{name!r}] must be > 0 (np.inf for hard), got {rho}")
        return rho

    def _make_groups(
        self,
        y_min: ArrayLike | None,
        y_max: ArrayLike | None,
        H_y: ArrayLike | None,
        h_y: ArrayLike | None,
        H_x: ArrayLike | None,
        h_x: ArrayLike | None,
        xN_min: ArrayLike | None,
        xN_max: ArrayLike | None,
        H_N: ArrayLike | None,
        h_N: ArrayLike | None,
        soft_penalty: Any,
    ) -> list[_Group]:
        n, p, Np = self.n, self.p, self.Np
        _check_penalty_arg(soft_penalty)
        groups: list[_Group] = []
        all_stages = np.arange(1, Np + 1)

        def box(name: str, lo_v: Any, hi_v: Any, dim: int, on: str, stages: np.ndarray) -> None:
            if lo_v is None and hi_v is None:
                return
            lo_name, hi_name = {"y": ("y_min", "y_max"), "xN": ("xN_min", "xN_max")}[name]
            lo = (
                np.full(dim, -np.inf)
                if lo_v is None
                else _vector(lo_name, lo_v, dim, allow_inf=True)
            )
            hi = (
                np.full(dim, np.inf)
                if hi_v is None
                else _vector(hi_name, hi_v, dim, allow_inf=True)
            )
            _check_order(lo_name, lo, hi_name, hi)
            rho = self._penalty(name, soft_penalty, dim)
            keep = np.flatnonzero(np.isfinite(lo) | np.isfinite(hi))
            if keep.size:
                G = np.eye(dim)[keep]
                groups.append(
                    _Group(name, on, stages, G, lo[keep], hi[keep], rho[keep], True, keep, dim)
                )

        def poly(name: str, H: Any, h: Any, dim: int, on: str, stages: np.ndarray) -> None:
            if H is None and h is None:
                return
            hn = "h" + name[1:]
            if H is None or h is None:
                raise ValueError(f"{name} and {hn} must be given together")
            H_ = _matrix(name, H)
            if H_.shape[1] != dim:
                raise ValueError(f"{name} must have shape (r, {dim}), got {H_.shape}")
            r = H_.shape[0]
            h_ = _vector(hn, h, r, allow_inf=True)
            if np.any(h_ == -np.inf):
                raise ValueError(f"{hn} must not contain -inf (the constraint could never hold)")
            rho = self._penalty(name, soft_penalty, r)
            keep = np.flatnonzero(np.isfinite(h_))
            if keep.size:
                groups.append(
                    _Group(
                        name,
                        on,
                        stages,
                        H_[keep],
                        np.full(keep.size, -np.inf),
                        h_[keep],
                        rho[keep],
                        False,
                        keep,
                        r,
                    )
                )

        box("y", y_min, y_max, p, "y", all_stages)
        poly("H_y", H_y, h_y, p, "y", all_stages)
        poly("H_x", H_x, h_x, n, "x", all_stages)
        box("xN", xN_min, xN_max, n, "x", np.array([Np]))
        poly("H_N", H_N, h_N, n, "x", np.array([Np]))
        return groups

    def _check_stage_scales(
        self, stage_scales: Mapping[str, ArrayLike] | None
    ) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None]:
        """Validate ``stage_scales`` -> (Q (Np,), R (Nc,), S (Np,)) multipliers or None."""
        if stage_scales is None:
            return (None, None, None)
        if not isinstance(stage_scales, Mapping) or set(stage_scales) - {"Q", "R", "S"}:
            raise ValueError(
                "stage_scales must be a mapping with keys among 'Q', 'R', 'S', "
                f"got {stage_scales!r}"
            )
        out = []
        for name, dim in (("Q", self.Np), ("R", self.Nc), ("S", self.Np)):
            val = stage_scales.get(name)
            if val is None:
                out.append(None)
                continue
            v = _vector(f"stage_scales[{name!r}]", val, dim)
            if np.any(v < 0):
                raise ValueError(f"stage_scales[{name!r}] must be >= 0, got {v}")
            out.append(v)
        return out[0], out[1], out[2]
