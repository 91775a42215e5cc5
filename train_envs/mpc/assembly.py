r"""Assembly of the QP of :class:`~train_envs.mpc.LinearMPC`: ``P``, ``A`` and the data map.

Condensed prediction (Maciejowski 2002, sec. 3.1): :math:`\Phi = [A; A^2; \dots;
A^{N_p}]`, :math:`\Gamma_{it} = A^{i-t} B`, :math:`\Gamma_{d,it} = A^{i-t}` (:math:`t \le
i`); inputs :math:`U = T_z z + T_u u_{-1}`, :math:`\Delta U = D_z z + D_u u_{-1}`.  All
weighted residuals :math:`e = E_z z + E_\theta \theta` with block weight :math:`W` give
the condensed Hessian :math:`H = E_z^\top W E_z` (OSQP's :math:`P_{zz} = 2H`) and
:math:`q_z = 2 E_z^\top W E_\theta \theta`; the constant :math:`\lVert L_w E_\theta
\theta\rVert^2` (:math:`L_w^\top L_w = W`) makes ``MPCSolution.cost`` the full cost.
The sparse form keeps the states as variables and the dynamics
:math:`-x_{t+1} + A x_t + B u_t + d_t = 0` as equality rows.

Every block a weight or model change can touch is stored dense (zeros included) in a
sparsity pattern fixed at construction, so :meth:`_AssemblyMixin.set_weights` and
:meth:`_AssemblyMixin.set_model` update OSQP's matrix values (``Px``, ``Ax``) without
a new setup; the weight-independent part (prediction matrices, constraint rows on
``z``) is made once per model (:meth:`_AssemblyMixin._structure`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from train_envs.mpc.blas import single_thread_blas
from train_envs.mpc.description import _check_penalty_arg, _is_diagonal, _weight, _weight_eigh

_MEMO_MAX = 64  # entries per memo below (a tuner's weight search would grow them)
_SQRT: dict[bytes, np.ndarray] = {}
_CHECKED: dict[tuple[str, bytes], np.ndarray] = {}


def _memo_put(memo: dict, key: object, value: np.ndarray) -> np.ndarray:
    value.setflags(write=False)  # shared between problems
    if len(memo) >= _MEMO_MAX:
        memo.clear()
    memo[key] = value
    return value


#: largest diagonal weight whose factor :func:`_diagonal_sqrt` forms without LAPACK
_DIAG_SQRT_MAX = 25


def _diagonal_factor(d: list[float]) -> tuple[list[int], list[float]]:
    """The rows of the factor ``numpy.linalg.eigh`` gives :func:`_psd_sqrt` for
    ``diag(d)``, without it: row ``i`` has the one entry ``vals[i]`` in column
    ``cols[i]``.

    For a diagonal matrix of order n <= 25 LAPACK's ``dsyevd`` (through ``dstedc`` and
    ``dsteqr``) leaves the eigenvalues in place with unit eigenvectors and only orders
    them, by a selection sort that swaps the first strictly smaller value found in each
    pass; this replays that sort, so the rows (and their order among equal weights) are
    the same numbers as the ``eigh`` path's, at a fraction of its cost.
    """
    n = len(d)
    lam = list(d)
    perm = list(range(n))
    for i in range(n - 1):
        k, p = i, lam[i]
        for j in range(i + 1, n):
            if lam[j] < p:
                k, p = j, lam[j]
        if k != i:
            lam[k], lam[i] = lam[i], p
            perm[i], perm[k] = perm[k], perm[i]
    top = max(1.0, max((abs(x) for x in lam), default=0.0))
    rows = [r for r in range(n) if lam[r] > 1e-14 * top]
    return [perm[r] for r in rows], [math.sqrt(lam[r]) for r in rows]


def _diagonal_sqrt(d: np.ndarray) -> np.ndarray:
    """The factor of :func:`_psd_sqrt` for ``diag(d)`` (:func:`_diagonal_factor`'s rows)."""
    cols, vals = _diagonal_factor(d.tolist())
    L = np.zeros((len(cols), d.size))
    L[np.arange(len(cols)), cols] = vals
    return L


def _psd_sqrt(W: np.ndarray) -> np.ndarray:
    """Return L with L.T @ L == W for a symmetric PSD W (rows of zero weight dropped;
    remembered per value: a family of problems shares its weights)."""
    key = W.tobytes()
    hit = _SQRT.get(key)
    if hit is not None:
        return hit
    if 0 < W.shape[0] <= _DIAG_SQRT_MAX and _is_diagonal(W):
        return _memo_put(_SQRT, key, _diagonal_sqrt(W.diagonal()))
    return _memo_put(_SQRT, key, _eigh_sqrt(*np.linalg.eigh(W)))


def _eigh_sqrt(lam: np.ndarray, V: np.ndarray) -> np.ndarray:
    """The factor of :func:`_psd_sqrt` from ``eigh``'s ``(lam, V)`` (C-ordered)."""
    lv = lam.tolist()
    thr = 1e-14 * max(1.0, max(map(abs, lv), default=0.0))
    if all(x > thr for x in lv):  # every row kept (a positive definite weight)
        return np.multiply(np.sqrt(lam)[:, None], V.T, order="C")
    keep = lam > thr
    return np.sqrt(lam[keep])[:, None] * V[:, keep].T


def _checked_weight(name: str, value: ArrayLike, dim: int) -> np.ndarray:
    """``_weight(name, value, dim)``; a float ``(dim, dim)`` array equal byte for byte to
    one checked before returns that check's (read-only) result."""
    if not (isinstance(value, np.ndarray) and value.dtype == np.float64):
        return _weight(name, value, dim)
    if value.shape != (dim, dim):
        return _weight(name, value, dim)
    key = (name, value.tobytes())
    hit = _CHECKED.get(key)
    if hit is not None:
        return hit
    w, eig = _weight_eigh(name, value, dim)
    if eig is not None:  # a full weight: _psd_sqrt finds its factor from the check's eigh
        _memo_put(_SQRT, w.tobytes(), _eigh_sqrt(*eig))
    return _memo_put(_CHECKED, key, w)


class _ResidualWeight:
    """The block-diagonal residual weight ``W`` and its factor ``Lw`` (``LwᵀLw = W``),
    as the products with them need them.

    The leading diagonal blocks (the stage weights) are kept as ``W``'s diagonal ``d``
    and the factor's rows, one entry each (``vals`` in ``cols``): there ``X @ W`` scales
    columns and ``Lw @ Y`` scales and picks rows; the blocks from the first full one on
    (a terminal cost) are kept dense (``tail``, ``tail_f``: ``W`` and ``Lw`` from there
    on) and multiply only their own rows and columns. Each entry of such a product has
    the dense product's non-zero terms in the same order, so the shortcut gives the dense
    product's numbers.
    """

    __slots__ = ("n", "_d", "_cols", "_vals", "_tail", "_tail_f")

    def __init__(
        self,
        n: int,
        d: np.ndarray,
        cols: np.ndarray,
        vals: np.ndarray,
        tail: np.ndarray,
        tail_f: np.ndarray,
    ) -> None:
        """``n``: the order of ``W``; ``d``, ``cols``, ``vals``: the leading diagonal
        blocks (``d.size`` columns); ``tail``, ``tail_f``: ``W`` and ``Lw`` from there on."""
        self.n, self._d, self._cols, self._vals = n, d, cols, vals
        self._tail, self._tail_f = tail, tail_f

    def right(self, X: np.ndarray) -> np.ndarray:
        """``X @ W``."""
        c0 = self._d.size
        if c0 == 0:
            return X @ self._tail
        if c0 == self.n:
            return np.multiply(X, self._d, order="C")
        out = np.empty((X.shape[0], self.n))
        np.multiply(X[:, :c0], self._d, out=out[:, :c0])
        out[:, c0:] = X[:, c0:] @ self._tail
        return out

    def factor(self, Y: np.ndarray) -> np.ndarray:
        """``Lw @ Y``."""
        c0 = self._d.size
        if c0 == 0:
            return self._tail_f @ Y
        head = self._vals[:, None] * Y[self._cols]
        if c0 == self.n:
            return head
        return np.vstack([head, self._tail_f @ Y[c0:]])


def _stage_weights(blocks: list[tuple[np.ndarray | None, int, np.ndarray]]) -> _ResidualWeight:
    """The residual weight of ``blocks``: ``(scales, k, X)`` per weighted residual, ``X``
    repeated on ``k`` stages, stage ``t`` scaled by ``scales[t]`` (``None``: 1) and its
    factor rows by ``sqrt(scales[t])`` -- ``block_diag(kron(diag(scales), X), ...)``.

    The leading blocks with a diagonal ``X`` (of order <= 25) give their diagonal and
    factor rows as arrays (stage by stage the same products ``s_t X_jj`` and
    ``sqrt(s_t) L_ij``); the rest is filled densely.
    """
    # (on Python floats: the same IEEE products and square roots as numpy's)
    d: list[float] = []
    cols: list[int] = []
    vals: list[float] = []
    c = 0
    i0 = len(blocks)
    for i, (scales, k, X) in enumerate(blocks):
        dim = X.shape[0]
        if not (0 < dim <= _DIAG_SQRT_MAX and _is_diagonal(X)):
            i0 = i
            break
        diag = X.diagonal().tolist()
        fc, fv = _diagonal_factor(diag)
        if scales is None:
            d += diag * k
            vals += fv * k
        else:
            sl = scales.tolist()
            d += [s_t * x for s_t in sl for x in diag]
            vals += [math.sqrt(s_t) * v for s_t in sl for v in fv]
        cols += [c + dim * t + j for t in range(k) for j in fc]
        c += k * dim
    # a row whose value is 0 (a zero stage scale) points at column 0, as the row scan of
    # the dense factor would
    if 0.0 in vals:
        cols = [j if v != 0.0 else 0 for j, v in zip(cols, vals, strict=True)]
    cols_all = np.array(cols, dtype=np.intp)
    d_all, vals_all = np.array(d, dtype=float), np.array(vals, dtype=float)
    rest = blocks[i0:]
    if len(rest) == 1 and rest[0][0] is None and rest[0][1] == 1:  # one terminal block
        X = rest[0][2]
        return _ResidualWeight(c + X.shape[0], d_all, cols_all, vals_all, X, _psd_sqrt(X))
    facs = [_psd_sqrt(X) for _, _, X in rest]
    nt = sum(k * X.shape[0] for _, k, X in rest)
    W = np.zeros((nt, nt))
    Lw = np.zeros((sum(k * L.shape[0] for (_, k, _), L in zip(rest, facs, strict=True)), nt))
    r = ct = 0
    for (scales, k, X), L in zip(rest, facs, strict=True):
        dim, rl = X.shape[0], L.shape[0]
        # the k diagonal blocks at once: W[ct:, ct:] and Lw[r:, ct:] as (k, d, k, d) and
        # (k, rl, k, d) views, the blocks on their diagonal (stage by stage the same
        # products s_t X and sqrt(s_t) L)
        t = np.arange(k)
        Wb = W[ct : ct + k * dim, ct : ct + k * dim].reshape(k, dim, k, dim)
        Lb = Lw[r : r + k * rl, ct : ct + k * dim].reshape(k, rl, k, dim)
        if scales is None:
            Wb[t, :, t, :] = X
            Lb[t, :, t, :] = L
        else:
            Wb[t, :, t, :] = scales[:, None, None] * X
            Lb[t, :, t, :] = np.sqrt(scales)[:, None, None] * L
        r += k * rl
        ct += k * dim
    return _ResidualWeight(c + nt, d_all, cols_all, vals_all, W, Lw)


class _SparseCost:
    """The sparse form's cost products ``Ewᵀ W Ew`` (its upper triangle) and ``Ewᵀ W
    Eθ`` from the non-zeros of the residual maps ``Ew`` (on the variables) and ``Eθ``.

    Every residual row of the sparse form touches one or two variables (an output of
    one stage, an increment, an input) and at most a few entries of θ, so each entry of
    the products is a sum of a few terms: with ``W``'s diagonal head ``d`` (its rows
    ``r < c0``), entry ``(i, j)`` is ``Σ_r (Ew_ri d_r) Ew_rj`` over the rows ``r`` where
    both factors are non-zero, summed in increasing ``r`` (:func:`numpy.bincount`), and
    the dense tail of ``W`` (a full terminal weight) multiplies only its own rows'
    non-zero columns.  The pairs of non-zeros are found once per pair of maps; a weight
    change is then two gathers, two products and two bincounts instead of two dense
    products of the full maps.  BLAS sums those in its own order, with fused
    multiply-adds: the two agree to rounding, and bit for bit where the maps' entries
    are ±1 (selection and differencing, as in the train MPCs) and an entry has at most
    two terms.
    """

    __slots__ = ("oe", "nt", "_rows", "_vals", "_hw", "_hq", "_ew", "_eth")

    def __init__(self, Ew: np.ndarray, Eth: np.ndarray) -> None:
        self.oe, self.nt = Ew.shape[1], Eth.shape[1]
        self._ew, self._eth = Ew, Eth
        r, c = np.nonzero(Ew)  # row-major: by row, then column
        rt, ct = np.nonzero(Eth)
        n = Ew.shape[0]
        self._rows, self._vals = r, Ew[r, c]
        ptr = np.searchsorted(r, np.arange(n + 1))
        ptr_t = np.searchsorted(rt, np.arange(n + 1))
        k = np.arange(r.size)
        # pairs (a, b), a <= b, of non-zeros of one row: Ew's upper triangle (i <= j)
        cnt = ptr[r + 1] - k
        a = np.repeat(k, cnt)
        b = a + np.arange(a.size) - np.repeat(np.cumsum(cnt) - cnt, cnt)
        self._hw = (a, b, c[a] * self.oe + c[b], r[a])
        # pairs (a, t) of a non-zero of Ew and one of Eth in the same row
        cnt_t = ptr_t[r + 1] - ptr_t[r]
        a_t = np.repeat(k, cnt_t)
        t = (
            np.repeat(ptr_t[r], cnt_t)
            + np.arange(a_t.size)
            - np.repeat(np.cumsum(cnt_t) - cnt_t, cnt_t)
        )
        self._hq = (a_t, Eth[rt[t], ct[t]], c[a_t] * self.nt + ct[t], r[a_t])

    def products(self, wt: _ResidualWeight) -> tuple[np.ndarray, np.ndarray]:
        """``(triu(Ewᵀ W Ew), Ewᵀ W Eθ)`` for the residual weight ``wt``, as ``(oe, oe)``
        and ``(oe, nt)`` arrays."""
        oe, nt = self.oe, self.nt
        c0 = wt._d.size
        kh = np.searchsorted(self._rows, c0)  # the non-zeros in the diagonal head's rows
        ad = self._vals[:kh] * wt._d[self._rows[:kh]]  # Ew_ri d_r
        a, b, tgt, ra = self._hw
        ka = np.searchsorted(ra, c0)  # the pairs of the diagonal head's rows
        Hu = np.bincount(tgt[:ka], ad[a[:ka]] * self._vals[b[:ka]], minlength=oe * oe)
        a_t, v_t, tgt_t, rt = self._hq
        kq = np.searchsorted(rt, c0)
        Hq = np.bincount(tgt_t[:kq], ad[a_t[:kq]] * v_t[:kq], minlength=oe * nt)
        # (float even without pairs: numpy gives an empty bincount integers)
        Hu = Hu.astype(float, copy=False).reshape(oe, oe)
        Hq = Hq.astype(float, copy=False).reshape(oe, nt)
        if c0 < wt.n:  # the dense tail: its rows' non-zero columns only
            Et, Tt = self._ew[c0:], self._eth[c0:]
            cz = np.flatnonzero(np.any(Et != 0.0, axis=0))
            EtW = Et[:, cz].T @ wt._tail
            Ht = EtW @ Et[:, cz]
            Hu[np.ix_(cz, cz)] += np.triu(0.5 * (Ht + Ht.T))
            Hq[cz] += EtW @ Tt
        return Hu, Hq


@dataclass(frozen=True)
class _Structure:
    """Weight-independent condensed matrices of one model (``θ``: the data vector).

    ``U = Tz z + Tu u_prev``; ``Cb = I ⊗ C``; ``vec(X) = Sx z + Xth θ``,
    ``vec(Y) = Sy z + Yth θ``, ``vec(U) = Tz z + Uth θ``, ``vec(ΔU) = Dz z + dUth θ``;
    ``Dth θ`` the affine term of every stage; the output/state constraint rows
    ``g = Gz z + Gth θ`` and their coefficients ``Gx`` on the state of their stage;
    ``Cpinv = pinv(C)`` (default terminal reference).
    """

    Tu: np.ndarray
    Tz: np.ndarray
    Cb: np.ndarray
    Sx: np.ndarray
    Sy: np.ndarray
    Dth: np.ndarray
    Xth: np.ndarray
    Yth: np.ndarray
    Uth: np.ndarray
    dUth: np.ndarray
    Gz: np.ndarray
    Gth: np.ndarray
    Gx: np.ndarray
    Cpinv: np.ndarray


@dataclass(frozen=True)
class ResidualMaps:
    """The weight-independent maps of a condensed :class:`LinearMPC` (decision ``z``,
    data ``θ``): the cost's residuals ``e = Ez z + Eth θ`` in the order of ``W``, its
    row ``blocks`` (``"Q"``: stage-major ``(Np, p)``, ``"R"``: ``(Nc, m)``, ``"S"``:
    ``(Np, m)``, ``"P"``; absent blocks omitted), the predictions ``vec(X) = Sx z + Xth
    θ``, ``vec(Y) = Sy z + Yth θ``, the plan ``vec(U) = Tz z + Uth θ`` and ``θ``'s
    ``slots``.  A caller that knows how its weights vary weights these itself."""

    Ez: np.ndarray
    Eth: np.ndarray
    blocks: dict[str, slice]
    Sx: np.ndarray
    Xth: np.ndarray
    Sy: np.ndarray
    Yth: np.ndarray
    Tz: np.ndarray
    Uth: np.ndarray
    slots: dict[str, slice]
    ntheta: int


class _AssemblyMixin:
    """``P``, ``q``, ``A`` and the per-step data map from the model and the weights."""

    def _sel(self, name: str, ntheta: int) -> np.ndarray:
        s = self._slots[name]
        M = np.zeros((s.stop - s.start, ntheta))
        M[:, s] = np.eye(s.stop - s.start)
        return M

    def _structure(self) -> _Structure:
        """The weight-independent part of :meth:`_build`: condensed prediction matrices and
        the constraint rows on ``z`` (made once per model; weight changes reuse it)."""
        st = self.__dict__.get("_struct")
        if st is not None:
            return st
        n, m, p, Np, Nc, nz = self.n, self.m, self.p, self.Np, self.Nc, self._nz
        A, B, C = self._A, self._B, self._C
        nt = self._ntheta
        sel = self._sel
        # condensed prediction -------------------------------------------------------
        powers = [np.eye(n)]
        for _ in range(Np):
            powers.append(A @ powers[-1])
        Phi = np.vstack(powers[1:])
        Gam = np.zeros((Np * n, Np * m))
        GamD = np.zeros((Np * n, Np * n))
        for i in range(Np):  # x_{i+1}
            for t in range(i + 1):
                Gam[i * n : (i + 1) * n, t * m : (t + 1) * m] = powers[i - t] @ B
                GamD[i * n : (i + 1) * n, t * n : (t + 1) * n] = powers[i - t]
        hold = np.minimum(np.arange(Np), Nc - 1)  # stage t uses block hold[t]
        if self._z_is_du:
            blocks = (np.arange(Nc)[None, :] <= hold[:, None]).astype(float)
            Tu = np.kron(np.ones((Np, 1)), np.eye(m))
            Du = np.zeros((nz, m))
        else:
            blocks = (np.arange(Nc)[None, :] == hold[:, None]).astype(float)
            Tu = np.zeros((Np * m, m))
            Du = np.zeros((nz, m))
            Du[:m] = -np.eye(m)
        Tz = np.kron(blocks, np.eye(m))
        Cb = np.kron(np.eye(Np), C)
        Sx = Gam @ Tz
        Sy = Cb @ Sx
        ones_n = np.kron(np.ones((Np, 1)), np.eye(n))
        Dth = ones_n @ sel("d", nt) + sel("D", nt)  # affine term of every stage
        Xth = Phi @ sel("x0", nt) + Gam @ Tu @ sel("up", nt) + GamD @ Dth
        Yth = Cb @ Xth
        Uth = Tu @ sel("up", nt)
        dUth = Du @ sel("up", nt)

        # output/state constraint rows on z (condensed)
        con = self._con
        ncon = con["g"].size
        Gz = np.zeros((ncon, nz))
        Gth = np.zeros((ncon, nt))
        Gx = np.zeros((ncon, n))  # coefficient on the state of the row's stage
        for gi, g in enumerate(self._groups):
            idx = np.flatnonzero(con["g"] == gi)
            K = g.stages.size
            dim = p if g.on == "y" else n
            rows = (g.stages[:, None] - 1) * dim + np.arange(dim)[None, :]
            Sz = (Sy if g.on == "y" else Sx)[rows.ravel()]
            St = (Yth if g.on == "y" else Xth)[rows.ravel()]
            GK = np.kron(np.eye(K), g.G)
            Gz[idx] = GK @ Sz
            Gth[idx] = GK @ St
            Gx[idx] = np.tile(g.G @ C if g.on == "y" else g.G, (K, 1))
        st = self._struct = _Structure(
            Tu=Tu,
            Tz=Tz,
            Cb=Cb,
            Sx=Sx,
            Sy=Sy,
            Dth=Dth,
            Xth=Xth,
            Yth=Yth,
            Uth=Uth,
            dUth=dUth,
            Gz=Gz,
            Gth=Gth,
            Gx=Gx,
            Cpinv=np.linalg.pinv(C),
        )
        return st

    def _build(self) -> None:
        """Compute every model/weight-dependent matrix (dense) and the OSQP values.

        The condensed quantities (prediction matrices, Hessian ``H``, the maps of the
        constraint rows onto ``z``) are built for both forms: they give
        :meth:`gain_unconstrained`, the exact refinement and the fallback prediction.
        The weight-independent part (:meth:`_build_model`) is kept per model; a weight
        change runs :meth:`_build_weights` only.
        """
        self._build_model()
        self._build_weights()
        if np.any(self._P_dense[~self._Pmask] != 0):
            raise RuntimeError("internal error: QP entries outside the fixed sparsity pattern")

    def _build_model(self) -> None:
        """The weight-independent matrices of :meth:`_build`: the weighted residuals'
        maps ``Ez``, ``Eth`` (sparse: ``Ew``, ``Eth_s``), the constraint matrix ``A`` and
        the offset, plan and trajectory maps (made once per model)."""
        n, m, p, Np, nz = self.n, self.m, self.p, self.Np, self._nz
        A, B, C = self._A, self._B, self._C
        nt = self._ntheta
        sel = self._sel
        sparse = self._sparse

        S_ = self._structure()
        Tu, Tz, Cb, Sx, Sy = S_.Tu, S_.Tz, S_.Cb, S_.Sx, S_.Sy
        Dth, Xth, Yth, Uth, dUth = S_.Dth, S_.Xth, S_.Yth, S_.Uth, S_.dUth
        Gz, Gth, Gx = S_.Gz, S_.Gth, S_.Gx

        # weighted residuals e = Ez z + Eth theta (condensed), in the order of W ---------
        Ez_parts = [Sy, self._Dz]
        Eth_parts = [Yth - sel("r", nt), dUth]
        if self._S is not None:
            Ez_parts.append(Tz)
            Eth_parts.append(Uth - sel("ur", nt))
        if self._P is not None:
            if self.terminal == "state":
                Ez_parts.append(Sx[-n:])
                Eth_parts.append(Xth[-n:] - sel("xN", nt))
            else:
                Ez_parts.append(Sy[-p:])
                Eth_parts.append(Yth[-p:] - sel("r", nt)[-p:])
        self._Ez = np.vstack(Ez_parts)
        self._Eth = np.vstack(Eth_parts)

        con = self._con
        ns, nh, nlu, r0 = self._ns, self._row_soft, self._n_bound_row, self._row_input
        n_u = nz
        n_du = nz if self._has_du else 0
        o = r0 + n_u + n_du
        hard_c, soft_c, soft2_c = self._hard_c, self._soft_c, self._soft2_c
        # semantic rows (everything except the dynamics) in condensed coordinates
        self._Gsem = np.vstack(
            [self._Tz_c] + ([self._Dz] if n_du else []) + [Gz[hard_c], Gz[soft_c], Gz[soft2_c]]
        )
        self._Csem = np.vstack(
            [Uth[:nz]] + ([dUth] if n_du else []) + [Gth[hard_c], Gth[soft_c], Gth[soft2_c]]
        )

        # OSQP constraint matrix -----------------------------------------------------------
        oz, oe, nv = self._col_input, self._col_slack, self._n_var
        sl = np.arange(ns)
        Ad = np.zeros((self._n_row, nv))
        if not sparse:
            Ad[:nlu, :nz] = self._Gsem
            Cth = self._Csem
        else:
            nxv = self._nxv
            # dynamics: -x_{t+1} + A x_t + B u_t + (A x0 [t = 0] + d_t) = 0
            Cth_dyn = np.zeros((nxv, nt))
            for t in range(Np):
                rows = slice(t * n, (t + 1) * n)
                Ad[rows, t * n : (t + 1) * n] = -np.eye(n)
                if t:
                    Ad[rows, (t - 1) * n : t * n] = A
                Ad[rows, oz : oz + nz] = B @ Tz[t * m : (t + 1) * m]
                Cth_dyn[rows] = B @ Tu[t * m : (t + 1) * m] @ sel("up", nt) + Dth[rows]
            Cth_dyn[:n] += A @ sel("x0", nt)
            Ad[r0 : r0 + n_u, oz : oz + nz] = self._Tz_c
            if n_du:
                Ad[r0 + n_u : o, oz : oz + nz] = self._Dz
            for rows_c, at in (
                (hard_c, np.arange(o, nh)),
                (soft_c, np.arange(nh, nh + ns)),
                (soft2_c, np.arange(nh + ns, nlu)),
            ):
                for k, rr in zip(rows_c, at, strict=True):
                    st = con["s"][k] - 1
                    Ad[rr, st * n : (st + 1) * n] = Gx[k]
            # cost: residuals Ew w + Eth_s theta in the variables w = (X, z)
            Ew_parts = [np.hstack([Cb, np.zeros((Np * p, nz))])]
            Ew_parts.append(np.hstack([np.zeros((nz, nxv)), self._Dz]))
            Eth_s = [-sel("r", nt), dUth]
            if self._S is not None:
                Ew_parts.append(np.hstack([np.zeros((Np * m, nxv)), Tz]))
                Eth_s.append(Uth - sel("ur", nt))
            if self._P is not None:
                last = np.zeros((n, nxv + nz))
                last[:, nxv - n : nxv] = np.eye(n)
                if self.terminal == "state":
                    Ew_parts.append(last)
                    Eth_s.append(-sel("xN", nt))
                else:
                    Ew_parts.append(C @ last)
                    Eth_s.append(-sel("r", nt)[-p:])
            self._Ew = np.vstack(Ew_parts)
            self._Eth_s = np.vstack(Eth_s)
            self._sparse_cost = _SparseCost(self._Ew, self._Eth_s)
            # theta-dependent offsets: dynamics, input and rate rows (the state and
            # output rows act on the variables directly and have constant bounds)
            Cth = np.vstack([Cth_dyn, Uth[:nz]] + ([dUth] if n_du else []))
        self._Cth = Cth
        Ad[nh + sl, oe + sl] = -1.0
        if soft2_c.size:
            Ad[nh + ns + np.arange(soft2_c.size), oe + self._soft2_slack] = 1.0
        Ad[nlu + sl, oe + sl] = 1.0
        if np.any(Ad[~self._Amask] != 0):
            raise RuntimeError("internal error: QP entries outside the fixed sparsity pattern")
        self._A_dense = Ad

        self._y_is_x = p == n and np.array_equal(C, np.eye(n))
        # (condensed: the planned inputs' offsets are part of v; the predicted states and
        # outputs, rarely read, have their own map evaluated on demand -- MPCSolution.X/Y)
        if sparse:  # the states are variables
            self._traj_th: list[np.ndarray] = []
            self._M_xy = self._Wz_xy = None
        else:
            self._traj_th = [Uth[:nz]]
            self._M_xy = np.ascontiguousarray(np.vstack([Xth] + ([] if self._y_is_x else [Yth])))
            self._Wz_xy = np.ascontiguousarray(np.vstack([Sx] + ([] if self._y_is_x else [Sy])))
        self._Wz_u = None if sparse else np.ascontiguousarray(self._Tz_c)
        self._Cpinv = S_.Cpinv
        self._Xth, self._Sx = Xth, Sx
        self._iu_z = np.triu_indices(nz)  # the condensed Hessian's entries in OSQP's P

    def _build_weights(self) -> None:
        """The weight-dependent part of :meth:`_build`: ``P``, the linear cost map, the
        cost constant and the condensed Hessian (on the matrices of :meth:`_build_model`)."""
        self._unc_cache = None  # the unconstrained shortcut's data follow the matrices
        self._pin_key: bytes | None | bool = False  # pinned inputs: not looked at yet
        Np, Nc = self.Np, self.Nc
        nt = self._ntheta
        sparse = self._sparse
        Ez, Eth = self._Ez, self._Eth

        # weights W of the residuals (per-stage scales: ``stage_scales``) -----------------
        sQ, sR, sS = self._stage_scales
        blocks = [(sQ, Np, self._Q), (sR, Nc, self._R)]
        if self._S is not None:
            blocks.append((sS, Np, self._S))
        if self._P is not None:
            blocks.append((None, 1, self._P))
        wt = _stage_weights(blocks)
        self._lw_ez = None
        self._condensed_src = (Ez, Eth, wt)
        # the sparse form needs the condensed quantities only for the refinement and the
        # fallback: made on first use (:meth:`_condensed_data`)
        self._condensed = None
        if not sparse:
            self._condensed_data()

        # the soft rows' penalties and the slacks' block of P (kept until they change)
        rho_all = self._con["rho"]
        soft = self.__dict__.get("_soft_cache")
        if soft is None or soft[0] is not rho_all or soft[1] != self._gamma:
            rho_s = rho_all[self._soft_c]  # exact-penalty weights of the soft rows
            gamma_s = 0.01 * rho_s if self._gamma is None else np.full(rho_s.size, self._gamma)
            sl = self._col_slack + np.arange(self._ns)
            P0 = np.zeros((self._n_var, self._n_var))
            P0[sl, sl] = 2.0 * gamma_s
            soft = self._soft_cache = (rho_all, self._gamma, rho_s, gamma_s, P0)
        rho_s = self._rho_s = soft[2]
        self._gamma_s = soft[3]

        # OSQP cost matrix ---------------------------------------------------------------
        oe, nv = self._col_slack, self._n_var
        Pd = soft[4].copy()
        if not sparse:
            H, Fq, Lth_c = self._condensed
            iu = self._iu_z
            Pd[iu] = 2.0 * H[iu]  # 2 triu(H)
            Hw_q = Fq  # q of the non-slack variables
            Lth = Lth_c
        else:
            Hu, Hq = self._sparse_cost.products(wt)
            Pd[:oe, :oe] = 2.0 * Hu
            Hw_q = 2.0 * Hq
            Lth = wt.factor(self._Eth_s)
        self._P_dense = Pd

        # the per-step affine map v = M theta ---------------------------------------------
        # v = [q (nv) | offsets of the rows self._offset_rows | trajectory offsets | cost factor]
        qth = np.zeros((nv, nt))
        qth[:oe] = Hw_q
        qth[oe:, 0] = rho_s  # column 0 of theta is the constant 1
        Lth = Lth[np.any(Lth != 0, axis=1)]
        M = np.vstack([qth, self._Cth] + self._traj_th + [Lth])
        self._M_full = np.ascontiguousarray(M)
        self._M_no_D = np.ascontiguousarray(M[:, : self._n_theta_no_D])
        self._v = np.empty(M.shape[0])
        self._v_q = slice(0, nv)
        n_off = self._offset_rows.stop - self._offset_rows.start
        self._v_offsets = slice(nv, nv + n_off)
        t0 = nv + n_off
        n_tu = 0 if sparse else self._n_plan
        self._v_plan = slice(t0, t0 + n_tu)
        self._v_cost = slice(t0 + n_tu, M.shape[0])

    def _condensed_data(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(H, Fq, Lth_c)`` of the current weights: the condensed Hessian, the linear cost
        map ``q_z = Fq θ`` and the cost constant's factor (made once per weight change)."""
        c = self._condensed
        if c is None:
            Ez, Eth, wt = self._condensed_src
            EzW = wt.right(Ez.T)
            H = EzW @ Ez
            H = 0.5 * (H + H.T)
            Fq = 2.0 * EzW @ Eth  # condensed q_z = Fq theta
            Lth_c = wt.factor(Eth)  # condensed cost constant = ||Lth_c theta||^2
            c = self._condensed = (H, Fq, Lth_c)
        return c

    # condensed data for gain_unconstrained(), the refinement and the fallback
    @property
    def _H(self) -> np.ndarray:
        return self._condensed_data()[0]

    @property
    def _Fq(self) -> np.ndarray:
        return self._condensed_data()[1]

    @property
    def _Lth_c(self) -> np.ndarray:
        return self._condensed_data()[2]

    @property
    def _LwEz(self) -> np.ndarray | None:
        """Weighted residuals ``e = LwEz z + Lth_c θ`` (condensed form; unconstrained_affine's
        cost), made on first use after a weight change."""
        if self._sparse:
            return None
        if self._lw_ez is None:
            Ez, _, wt = self._condensed_src
            self._lw_ez = wt.factor(Ez)
        return self._lw_ez

    def residual_maps(self) -> ResidualMaps:
        """The weight-independent maps of the cost and the predictions (condensed form;
        :class:`ResidualMaps`), made once per model."""
        if self._sparse:
            raise ValueError("residual_maps() needs the condensed form")
        S_ = self._structure()
        sizes = [("Q", self.Np * self.p), ("R", self._nz)]
        if self._S is not None:
            sizes.append(("S", self.Np * self.m))
        if self._P is not None:
            sizes.append(("P", self.n if self.terminal == "state" else self.p))
        blocks, r = {}, 0
        for name, k in sizes:
            blocks[name] = slice(r, r + k)
            r += k
        return ResidualMaps(
            Ez=self._Ez,
            Eth=self._Eth,
            blocks=blocks,
            Sx=S_.Sx,
            Xth=S_.Xth,
            Sy=S_.Sy,
            Yth=S_.Yth,
            Tz=self._Tz_c,
            Uth=S_.Uth[: self._nz],
            slots=dict(self._slots),
            ntheta=self._ntheta,
        )

    def _q_init(self) -> np.ndarray:
        q = np.zeros(self._n_var)
        q[self._col_slack :] = self._rho_s
        return q

    def _push_matrices(self) -> None:
        """Mark OSQP's matrix values stale: they are sent (and OSQP's KKT system
        refactorised) by :meth:`_flush_matrices` before the next OSQP call, so weight
        changes between steps that never reach OSQP cost no refactorisation."""
        self._mat_dirty = True

    def _flush_matrices(self) -> None:
        """Send the current ``P`` and ``A`` values to OSQP if they changed since the last
        call (OSQP keeps no state that depends on when they arrive before a solve)."""
        if self._mat_dirty:
            self._mat_dirty = False
            Px = self._P_dense[self._P_rows, self._P_cols]
            Ax = self._A_dense[self._A_rows, self._A_cols]
            self._backend.update_mat(Px, Ax)

    def set_weights(
        self,
        *,
        Q: ArrayLike | None = None,
        R: ArrayLike | None = None,
        S: ArrayLike | None = None,
        P: ArrayLike | None = None,
        soft_penalty: float | Mapping[str, float | ArrayLike] | None = None,
        soft_quadratic: float | None = None,
        stage_scales: Mapping[str, ArrayLike] | None = None,
    ) -> None:
        """Change cost weights (``None`` keeps a weight); matrix values are updated in OSQP.

        ``stage_scales`` replaces the per-stage multipliers (see the constructor).

        ``S`` / ``P`` can only be changed if they were given at construction (pass zeros
        to reserve them).  ``soft_penalty`` may change finite values but cannot turn a
        soft row hard or vice versa (that would change the QP structure).
        """
        Q_ = self._Q if Q is None else _checked_weight("Q", Q, self.p)
        R_ = self._R if R is None else _checked_weight("R", R, self.m)
        if S is not None and self._S is None:
            raise ValueError("S was not given at construction; pass S=0 there to reserve it")
        if P is not None and self._P is None:
            raise ValueError("P was not given at construction; pass P=0 there to reserve it")
        S_ = self._S if S is None else _checked_weight("S", S, self.m)
        dimP = self.n if self.terminal == "state" else self.p
        P_ = self._P if P is None else _checked_weight("P", P, dimP)
        g_ = self._gamma if soft_quadratic is None else self._check_gamma(soft_quadratic)
        scales = None if stage_scales is None else self._check_stage_scales(stage_scales)
        new_rho = None
        if soft_penalty is not None:
            _check_penalty_arg(soft_penalty)
            parts = []
            for g in self._groups:
                full = self._penalty(g.name, soft_penalty, g.dim_full)
                rho_g = full[g.cols]
                if np.any(np.isfinite(rho_g) != np.isfinite(g.rho)):
                    raise ValueError(
                        f"soft_penalty[{g.name!r}] cannot switch rows between soft and hard "
                        "after construction"
                    )
                parts.append(rho_g)
            new_rho = parts
        self._Q, self._R, self._S, self._P, self._gamma = Q_, R_, S_, P_, g_
        if scales is not None:
            self._stage_scales = scales
        if new_rho is not None:
            for g, rho_g in zip(self._groups, new_rho, strict=True):
                g.rho = rho_g
            self._con["rho"] = (
                np.concatenate([np.tile(g.rho, g.stages.size) for g in self._groups])
                if self._groups
                else np.zeros(0)
            )
        with single_thread_blas():
            self._build_weights()
            self._push_matrices()

    def replace_weights(
        self,
        *,
        Q: np.ndarray | None = None,
        R: np.ndarray | None = None,
        S: np.ndarray | None = None,
        P: np.ndarray | None = None,
    ) -> None:
        """:meth:`set_weights` of ``Q``, ``R``, ``S``, ``P`` without its checks of the
        values (the shapes are checked): for a controller that builds them itself from
        checked parameters -- float arrays, symmetric positive semidefinite and finite
        (diagonal stage weights, a Riccati solution as ``P``). The matrices are then the
        same as through :meth:`set_weights` (whose check of an exactly symmetric matrix
        returns its values); ``None`` keeps a weight."""
        dimP = self.n if self.terminal == "state" else self.p
        for name, W, dim, have in (
            ("Q", Q, self.p, True),
            ("R", R, self.m, True),
            ("S", S, self.m, self._S is not None),
            ("P", P, dimP, self._P is not None),
        ):
            if W is None:
                continue
            if not have:
                raise ValueError(
                    f"{name} was not given at construction; pass {name}=0 there to reserve it"
                )
            if W.shape != (dim, dim):
                raise ValueError(f"{name} must have shape ({dim}, {dim}), got {W.shape}")
        if Q is not None:
            self._Q = Q
        if R is not None:
            self._R = R
        if S is not None:
            self._S = S
        if P is not None:
            self._P = P
        with single_thread_blas():
            self._build_weights()
            self._push_matrices()

    def set_model(self, A: ArrayLike, B: ArrayLike, C: ArrayLike | None = None) -> None:
        """Replace the model (same dimensions; ``C=None`` keeps the current ``C``)."""
        A_, B_, C_ = self._check_model(A, B, self._C if C is None else C, (self.n, self.m, self.p))
        self._A, self._B, self._C = A_, B_, C_
        self._struct = None
        with single_thread_blas():
            self._build()
            self._push_matrices()
