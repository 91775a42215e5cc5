r"""Bounds of :class:`~train_envs.mpc.LinearMPC`: base bounds, per-call bounds, safe move.

Three levels: the construction-time bounds; base bounds
(:meth:`_BoundsMixin.set_base_bounds`, kept until changed: per-stage input box, output
box, terminal polyhedron offsets); per-call bounds of
:meth:`~train_envs.mpc.LinearMPC.solve` (one call only).  Values beyond
:math:`\pm 10^{30}` are OSQP's infinity.  When the previous input lies outside the box
while rates are limited, stage :math:`k`'s input bounds become the reachable box
:math:`[\min(u_{\min}, u_{-1} + k\,\Delta u_{\max}),\ \max(u_{\max}, u_{-1} +
k\,\Delta u_{\min})]`, so the QP stays feasible.  The applied first move is clipped
to the box intersected with one step's rate window (:meth:`_BoundsMixin._input_window`;
the rate limit wins when the box is out of reach), which removes the solver's
:math:`O(\epsilon)` violations.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from train_envs.mpc.osqp_backend import _BIG


def _as_slice(idx: np.ndarray) -> slice | np.ndarray | None:
    """``idx`` (sorted, unique) as a slice when contiguous (basic indexing gives views)."""
    if idx.size == 0:
        return None
    if idx[-1] - idx[0] + 1 == idx.size:
        return slice(int(idx[0]), int(idx[-1]) + 1)
    return idx


def _bound_label(name: str, side: int) -> str:
    """User-facing name of a per-call bound (``y_min``, ``y_max``, ``h_y``, ``h_x``)."""
    if name == "y":
        return "y_max" if side else "y_min"
    return "h" + name[1:]


class _BoundsMixin:
    """Base bounds, per-call bounds, the reachable input box and the safe first move."""

    def set_base_bounds(
        self,
        *,
        u_min: ArrayLike | None = None,
        u_max: ArrayLike | None = None,
        y_min: ArrayLike | None = None,
        y_max: ArrayLike | None = None,
        h_N: ArrayLike | None = None,
    ) -> None:
        """Replace construction-time bounds until the next call (cheap: no matrix update).

        ``u_min`` / ``u_max``: per-stage input box ``(Nc, m)`` (or ``(m,)``, held), e.g.
        equal bounds to fix inputs (move blocking); ``y_min`` / ``y_max``: per-stage
        output box ``(Np, p)`` (values of rows dropped at construction are ignored); ``h_N``:
        offsets ``(r,)`` of the terminal polyhedron ``H_N x_Np <= h_N`` given at
        construction (rows that were infinite there stay dropped).  ``None`` leaves a
        bound as it is; per-call bounds of :meth:`solve` still override these for one
        call.  Setting all per-step bounds here and calling :meth:`solve` without
        overrides is the cheapest way to move them every step.  The first
        input is still clipped to the construction-time box and rate window after the
        solve, so stage-0 input bounds should stay inside them; when the previous input
        lies outside the box with rate limits, the reachable-box relaxation of
        :meth:`solve` replaces the stage input bounds for that call.
        """
        Nc, m = self.Nc, self.m
        lo0, hi0 = self._lower_base, self._upper_base
        r0, nu = self._row_input, self._nz
        groups = self.__dict__.get("_base_groups")
        if groups is None:
            groups = self._base_groups = {g.name: g for g in self._groups}
        if u_min is not None or u_max is not None:
            new = [lo0[r0 : r0 + nu].copy(), hi0[r0 : r0 + nu].copy()]
            for name, val, side in (("u_min", u_min, 0), ("u_max", u_max, 1)):
                if val is None:
                    continue
                try:
                    arr = np.broadcast_to(np.asarray(val, dtype=float), (Nc, m))
                except ValueError:
                    raise ValueError(
                        f"set_base_bounds(): {name} must have shape ({Nc}, {m}) or ({m},), "
                        f"got {np.shape(val)}"
                    ) from None
                if np.isnan(arr).any():
                    raise ValueError(f"set_base_bounds(): {name} must not contain NaN")
                new[side] = np.clip(arr, -_BIG, _BIG).ravel()
            if np.any(new[0] > new[1]):
                raise ValueError("set_base_bounds(): u_min must not exceed u_max at any stage")
            lo0[r0 : r0 + nu], hi0[r0 : r0 + nu] = new
            self._pin_key = False
        if y_min is not None or y_max is not None:  # called every step: keep it lean
            g, _, cols, lb, ub_pos, _ = self._bounds_entry("y")
            if g is None:
                raise ValueError("set_base_bounds(): y bounds given but no y box at construction")
            for name, val in (("y_min", y_min), ("y_max", y_max)):
                if val is None:
                    continue
                arr = val if type(val) is np.ndarray else np.asarray(val, dtype=float)
                if arr.shape != (self.Np, self.p):
                    try:
                        arr = np.broadcast_to(arr, (self.Np, self.p))
                    except ValueError:
                        raise ValueError(
                            f"set_base_bounds(): {name} must have shape ({self.Np}, {self.p}) "
                            f"or ({self.p},), got {np.shape(val)}"
                        ) from None
                vals = arr if cols is None else arr[:, cols]
                tot = float(vals.sum())
                if tot != tot and np.isnan(vals).any():  # (+inf + -inf is NaN too)
                    raise ValueError(f"set_base_bounds(): {name} must not contain NaN")
                vals = np.minimum(np.maximum(vals, -_BIG), _BIG)
                if name == "y_min":
                    pos, ok = lb
                    lo0[pos] = vals if ok is None else vals[ok]
                else:
                    hi0[ub_pos] = vals
        if h_N is not None:  # called every step by terminal sets that move: keep it lean
            g = groups.get("H_N")
            if g is None:
                raise ValueError("set_base_bounds(): h_N given but H_N was not set at construction")
            h = h_N if type(h_N) is np.ndarray else np.asarray(h_N, dtype=float)
            if h.shape != (g.dim_full,):
                raise ValueError(f"set_base_bounds(): h_N must have shape ({g.dim_full},)")
            cols = self._bounds_entry("H_N")[2]
            if cols is not None:
                h = h[cols]
            lo_h = float(h.min()) if h.size else 0.0
            if lo_h != lo_h or lo_h == -np.inf:
                raise ValueError("set_base_bounds(): h_N must not contain NaN or -inf")
            hi0[g.ub_pos[0]] = np.minimum(h, _BIG)
        self._bounds_dirty = True

    def _bounds_entry(self, name: str) -> tuple:
        """Per-group constants of :meth:`_set_bounds` (cached: it runs every step)."""
        cache = self.__dict__.setdefault("_bounds_cache", {})
        hit = cache.get(name)
        if hit is None:
            g = next((g for g in self._groups if g.name == name), None)
            if g is None:
                hit = (None, None, None, None, None, False)
            else:
                dropped = _as_slice(np.setdiff1d(np.arange(g.dim_full), g.cols))
                cols = None if np.array_equal(g.cols, np.arange(g.dim_full)) else g.cols
                cols = None if cols is None else _as_slice(cols)
                lb_ok = g.lb_pos >= 0
                lb_all = bool(lb_ok.all())
                lb = (g.lb_pos if lb_all else g.lb_pos[lb_ok], None if lb_all else lb_ok)
                # rows of a hard group bound OSQP rows that need l <= u
                hard = bool(np.any(g.ub_pos < self._row_soft)) or bool(
                    np.any(g.lb_pos[lb_ok] < self._row_soft)
                )
                hit = (g, dropped, cols, lb, g.ub_pos, hard)
            cache[name] = hit
        return hit

    def _set_bounds(
        self,
        up: np.ndarray,
        relax: bool,
        y_min: ArrayLike | None,
        y_max: ArrayLike | None,
        h_y: ArrayLike | None,
        h_x: ArrayLike | None,
    ) -> bool:
        """Write per-call bounds into the working bound vectors; False if they contain NaN."""
        Lb, Ub = self._lower_call, self._upper_call
        self._bounds_call[...] = self._bounds_base
        self._bounds_dirty = True
        check = relax
        if relax:
            # reachable input bounds when u_prev lies outside [u_min, u_max]
            nu = self._nz
            with np.errstate(invalid="ignore"):
                lo = np.minimum(self._umin_t, up[None, :] + self._k_dumax)
                hi = np.maximum(self._umax_t, up[None, :] + self._k_dumin)
            r0 = self._row_input
            Lb[r0 : r0 + nu] = np.clip(np.nan_to_num(lo, nan=-_BIG), -_BIG, _BIG).ravel()
            Ub[r0 : r0 + nu] = np.clip(np.nan_to_num(hi, nan=_BIG), -_BIG, _BIG).ravel()
        for name, val, side in (
            ("y", y_min, 0),
            ("y", y_max, 1),
            ("H_y", h_y, 1),
            ("H_x", h_x, 1),
        ):
            if val is None:
                continue
            g, dropped, cols, lb, ub_pos, hard = self._bounds_entry(name)
            arr = val if type(val) is np.ndarray else np.asarray(val, dtype=float)
            if g is not None and arr.shape == g.lb_pos.shape and dropped is not None:
                # only the rows constrained at construction, (Np, kept): nothing to drop;
                # min/max propagate NaN
                vals = arr
                lo_v, hi_v = vals.min(), vals.max()
                if lo_v != lo_v or hi_v != hi_v:
                    return False
            else:
                if g is not None:
                    dim = g.dim_full
                elif name == "y":
                    dim = self.p
                else:
                    dim = arr.shape[-1] if arr.ndim else 1
                if arr.shape != (self.Np, dim):
                    try:
                        arr = np.broadcast_to(arr, (self.Np, dim))
                    except ValueError:
                        raise ValueError(
                            f"solve(): {_bound_label(name, side)} must have shape "
                            f"({self.Np}, {dim}) or ({dim},), got {arr.shape}"
                        ) from None
                total = arr.sum()
                if total != total and np.isnan(arr).any():  # +inf plus -inf is NaN too
                    return False
                if g is None:
                    if np.isfinite(arr).any():
                        raise ValueError(
                            f"solve(): {_bound_label(name, side)} given but no {name} "
                            "constraint was set at construction"
                        )
                    continue
                if dropped is not None and np.isfinite(arr[:, dropped]).any():
                    rows = np.arange(dim)[dropped].tolist()
                    raise ValueError(
                        f"solve(): {_bound_label(name, side)} has finite values in rows "
                        f"{rows} that were unconstrained at construction"
                    )
                vals = arr if cols is None else arr[:, cols]
                lo_v, hi_v = vals.min(), vals.max()
            if lo_v < -_BIG or hi_v > _BIG:
                vals = np.minimum(np.maximum(vals, -_BIG), _BIG)
            if side == 0:
                pos, ok = lb
                Lb[pos] = vals if ok is None else vals[ok]
            else:
                Ub[ub_pos] = vals
            check = check or hard
        if not check:
            return True
        # hard rows must have l <= u for OSQP
        nh = self._row_soft
        return bool((Lb[:nh] <= Ub[:nh]).all())

    def _outside_box(self, upl: list[float]) -> bool:
        """Whether the previous input lies outside the input box (with rate limits the
        solve then relaxes the stage input bounds to the reachable box)."""
        umin_l, umax_l = self._umin_l, self._umax_l
        for i in range(self.m):
            if upl[i] < umin_l[i] or upl[i] > umax_l[i]:
                return True
        return False

    def _input_window(self, up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Inputs reachable from ``up`` in one step: box intersected with the rate window.

        If the box cannot be reached in one step (``up`` far outside it) the rate
        limit wins and the window is the rate-limited point closest to the box.
        """
        r_lo = up + self._dumin
        r_hi = up + self._dumax
        lo = np.minimum(np.maximum(self._umin, r_lo), r_hi)
        hi = np.maximum(np.minimum(self._umax, r_hi), r_lo)
        return lo, hi

    def _clip_to_window(self, u0: np.ndarray, upl: list[float]) -> bool:
        """In-place clip of ``u0`` to :meth:`_input_window`; False if ``u0`` is not finite.

        Python floats: ``m`` is small and numpy calls cost more than the arithmetic.
        """
        umin, umax, dmin, dmax = self._umin_l, self._umax_l, self._dumin_l, self._dumax_l
        u0l = u0.tolist()
        for i in range(self.m):
            a = upl[i]
            rlo = a + dmin[i]
            rhi = a + dmax[i]
            lo = umin[i] if umin[i] > rlo else rlo
            if lo > rhi:
                lo = rhi
            hi = umax[i] if umax[i] < rhi else rhi
            if hi < rlo:
                hi = rlo
            val = u0l[i]
            if val < lo:
                u0[i] = lo
            elif val > hi:
                u0[i] = hi
            elif val != val:  # NaN
                return False
        return True
