r"""Recovery of :class:`~train_envs.mpc.LinearMPC` when OSQP does not converge.

ADMM usually identifies the active set long before it meets tight tolerances; this is
typical when soft constraints are violated (their multipliers sit at the penalty
:math:`\rho` and the QP behaves like a degenerate LP) and at the end of a stop, where
most slacks sit at zero and ADMM's linear rate is slow (``docs/benchmarks.md``).  OSQP
therefore runs to an iteration cap (``max_iter``, 100 by default); on the statuses
solved inaccurate and maximum iterations the cascade (:meth:`_RecoveryMixin._rescue`)
runs (after a primal-infeasibility verdict steps 1 and 3 only, step 3 briefly):

1. the exact finish (:meth:`_RecoveryMixin._exact`): DAQP, the dual active-set solver
   for small dense QPs of Arnström, Bemporad and Axehill (IEEE TAC 2022), on the full
   QP, warm-started from OSQP's iterate (in the sparse form first the KKT system of
   the active set the iterate names, one sparse LU; a larger condensed QP first in the
   decision alone, its slacks as DAQP's soft constraints), accepted only when the full
   QP's KKT conditions hold to :data:`KKT_TOL`;
2. OSQP continued from the last iterate with tolerance :math:`\max(10^{-4}, 10\epsilon)`
   and OSQP's polishing;
3. failing that, an exact primal-dual active-set iteration (semismooth Newton) on the
   condensed QP with the slacks eliminated, accepted only when every KKT condition of
   the full QP holds (:meth:`_RecoveryMixin._refine`);
4. failing that, the fallback (:meth:`_RecoveryMixin._fallback`): the previous plan
   shifted by one stage (or the held input), clipped stage by stage to the box and
   rate window; its prediction, soft violation and cost come from the condensed model
   (:meth:`_RecoveryMixin._evaluate_plan`).

A verified KKT point is reported as ``"solved (polished)"`` (status 1), a relaxed
unpolished solution as ``"solved inaccurate"`` (status 2).
"""

from __future__ import annotations

import math
import time
from typing import Any

import daqp
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from train_envs.mpc.osqp_backend import _BIG, _RESCUE, _SOLVED, _SOLVED_INACCURATE, _Stats
from train_envs.mpc.solution import MPCSolution

#: OSQP's statuses primal infeasible and primal infeasible inaccurate
_PRIMAL_INFEASIBLE = (3, 4)
#: active-set iterations tried after a primal-infeasibility verdict
_INFEASIBLE_REFINE = 5
#: OSQP's statuses maximum iterations and solved inaccurate: finished exactly by DAQP
_FINISH_EXACT = (7, 2)
#: relative tolerance of the KKT conditions an exact finish must meet (stationarity
#: scaled by ``1 + max|q|``, feasibility and complementarity by ``1 + max|bound|``)
KKT_TOL = 1e-9
_DAQP_OPTIMAL = 1
_DAQP_INFEASIBLE = -1
#: the size (variables, slacks included) from which a condensed QP goes to DAQP with its
#: slacks as soft constraints (:meth:`_RecoveryMixin._exact_soft`): below it DAQP on the
#: full QP costs less than the reduced form's setup (on the Yizhuang MPC's QPs, 30
#: variables, ~100 µs a finish either way; on the RSMPC's and SEMPC's, 44-76, the reduced
#: form ~1.9x faster; docs/benchmarks.md)
_SOFT_MIN_VARS = 40
#: DAQP's exit flag of an optimum that violates soft constraints
_DAQP_SOFT_OPTIMAL = 2
_PRIMAL_INFEASIBLE_NAME = "primal infeasible"
#: the status of a verified KKT point (the exact finish, the refinement, polishing)
_POLISHED = "solved (polished)"


def _symmetric_P(host: Any) -> np.ndarray:
    """The full symmetric ``P`` of ``host._P_dense`` (its upper triangle), made once per
    ``P``: the assembly replaces ``_P_dense`` on every weight or model change and never
    writes into it, so the cache is keyed on the array object."""
    Pd = host._P_dense
    cached = getattr(host, "_P_sym", None)
    if cached is not None and cached[0] is Pd:
        return cached[1]
    P = Pd + Pd.T
    P[np.diag_indices_from(P)] *= 0.5
    host._P_sym = (Pd, P)
    return P


def _kkt_point(
    P: np.ndarray,
    A: np.ndarray,
    q: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    w: np.ndarray,
    lam: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, float] | None:
    """``(w, lam, obj)`` when ``(w, lam)`` meets the full QP's KKT conditions to
    :data:`KKT_TOL` (stationarity, feasibility, complementarity: see
    :meth:`_RecoveryMixin._exact`), else None."""
    if not (np.all(np.isfinite(w)) and np.all(np.isfinite(lam))):
        return None
    Pw = P @ w
    if np.max(np.abs(Pw + q + A.T @ lam)) > KKT_TOL * (1.0 + np.max(np.abs(q))):
        return None
    Aw = A @ w
    gap_hi = hi - Aw  # >= -tol_hi where feasible, <= tol_hi where y > 0
    gap_lo = Aw - lo
    tol_hi = KKT_TOL * (1.0 + np.abs(hi))
    tol_lo = KKT_TOL * (1.0 + np.abs(lo))
    if np.any(gap_hi < -tol_hi) or np.any(gap_lo < -tol_lo):
        return None
    tol_d = KKT_TOL * (1.0 + float(np.max(np.abs(lam), initial=0.0)))
    if np.any((lam > tol_d) & (gap_hi > tol_hi)) or np.any((lam < -tol_d) & (gap_lo > tol_lo)):
        return None
    return w, lam, float(0.5 * (w @ Pw) + q @ w)


def _soft_structure(host: Any, A: np.ndarray) -> tuple | None:
    """The fixed parts of :meth:`_RecoveryMixin._exact_soft`'s QP for the condensed
    ``A`` and the current soft penalties: ``(hard, jl, rows, sense, rho, w_lin)`` --
    the hard rows in DAQP's order (first those that are the identity on ``z``, DAQP's
    simple bounds: the input rows, else the rate rows, else none), the slacks with a
    lower-side row, DAQP's constraint matrix (the general hard rows, then the soft upper
    rows, in ``z``), the constraint kinds (soft rows 8) and the soft rows' reciprocal
    quadratic and linear weights ``1 / (2 gamma)``, ``rho``; None when a soft row has
    no quadratic penalty. Made once per ``A`` and penalties (the assembly replaces
    ``_A_dense`` on a model change and the penalty arrays when they change, and writes
    into neither)."""
    rho_s, gam = host._rho_s, host._gamma_s
    cached = getattr(host, "_soft_split", None)
    if cached is not None and cached[0] is A and cached[1] is rho_s and cached[2] is gam:
        return cached[3]
    nz, nh, ns = host._nz, host._row_soft, host._ns
    split = None
    if np.all(gam > 0.0):
        eye = np.eye(nz)
        simple = np.zeros(0, dtype=np.intp)
        for start in (0, nz):
            blk = A[start : start + nz]
            if start + nz <= nh and np.array_equal(blk[:, :nz], eye) and not blk[:, nz:].any():
                simple = np.arange(start, start + nz)
                break
        general = np.setdiff1d(np.arange(nh), simple)
        rows = np.ascontiguousarray(np.vstack([A[general, :nz], A[nh : nh + ns, :nz]]))
        hard = np.concatenate([simple, general])
        nk = hard.size + ns
        sense = np.zeros(nk, dtype=np.int32)
        sense[hard.size :] = 8
        rho = np.ones(nk)
        rho[hard.size :] = 0.5 / gam
        w_lin = np.zeros(nk)
        w_lin[hard.size :] = rho_s
        jl = np.asarray(host._soft2_slack, dtype=np.intp)
        split = (hard, jl, rows, sense, rho, w_lin)
    host._soft_split = (A, rho_s, gam, split)
    return split


#: singular active-set KKT systems in a row after which a sparse-form problem stops
#: trying the active set OSQP names (:meth:`_RecoveryMixin._active_set_kkt`) until reset
_KKT_TRIES = 3


class _RecoveryMixin:
    """Rescue, exact refinement, fallback plan and its evaluation."""

    def _rescue(self, x: np.ndarray, y: np.ndarray, stats: _Stats) -> tuple[Any, Any, _Stats]:
        """Recover from a solve that did not meet the tolerances.

        ADMM usually identifies the active set long before it meets tight
        tolerances; this is typical when soft constraints are violated, because
        their multipliers then sit at the large penalty ``rho`` and the QP behaves
        like a degenerate LP.  Cascade:

        1. at the iteration cap or solved inaccurate: DAQP from OSQP's iterate
           (:meth:`_exact`);
        2. failing that, OSQP continued from the last iterate with a relaxed tolerance
           (``max(1e-4, 10 eps)``) and OSQP's own solution polishing;
        3. if polishing failed: an exact active-set iteration (:meth:`_refine`).

        After a primal-infeasibility verdict only steps 1 and 3 run (step 3 for a few
        iterations, and only when DAQP neither found an optimum nor confirmed the
        verdict): OSQP stops there with a certificate, and continuing ADMM from the
        diverging iterate only re-derives the verdict after thousands of iterations
        (RSMPC candidates with tightened hard rows, ``docs/benchmarks.md``).

        A verified KKT point is reported as ``"solved (polished)"`` (status 1); an
        unpolished relaxed-tolerance solution as ``"solved inaccurate"`` (status 2).
        """
        status_val, status, iters, solve_time = stats[0], stats[1], stats[2], stats[3]
        if status_val not in _RESCUE or x is None or not math.isfinite(np.dot(x, x)):
            return x, y, stats
        t0 = time.perf_counter()
        if status_val in _PRIMAL_INFEASIBLE:
            # OSQP holds a certificate of infeasibility: continuing ADMM cannot find a
            # solution; only an exact KKT point (a false verdict) would overturn it.
            # DAQP settles it first (cheaper than the refinement on these QPs)
            ex = self._exact(x, y)
            if isinstance(ex, tuple):
                t = solve_time + time.perf_counter() - t0
                return ex[0], ex[1], (_SOLVED, _POLISHED, iters, t, ex[2], 1)
            if ex == _DAQP_INFEASIBLE:
                t = solve_time + time.perf_counter() - t0
                return x, y, (status_val, status, iters, t, stats[4], stats[5])
            ref = self._refine(x, y, _INFEASIBLE_REFINE)
            t = solve_time + time.perf_counter() - t0
            if ref is not None:
                return ref[0], ref[1], (_SOLVED, _POLISHED, iters, t, ref[2], 1)
            return x, y, (status_val, status, iters, t, stats[4], stats[5])
        if status_val in _FINISH_EXACT:
            ex = self._exact(x, y)
            t = solve_time + time.perf_counter() - t0
            if isinstance(ex, tuple):
                return ex[0], ex[1], (_SOLVED, _POLISHED, iters, t, ex[2], 1)
            if ex == _DAQP_INFEASIBLE:  # a verdict of the exact method: final
                return x, y, (_PRIMAL_INFEASIBLE[0], _PRIMAL_INFEASIBLE_NAME, iters, t, *stats[4:])
        st = self.osqp_settings
        eps = max(1e-4, 10.0 * float(st["eps_abs"]), 10.0 * float(st["eps_rel"]))
        restore = {k: st[k] for k in ("eps_abs", "eps_rel", "polishing")}
        x2, y2, s2 = self._backend.rescue(x, y, eps, True, restore)
        it = iters + s2[2]
        if s2[0] == _SOLVED and s2[5] == 1:
            t = solve_time + time.perf_counter() - t0
            return x2, y2, (_SOLVED, _POLISHED, it, t, s2[4], 1)
        ok2 = x2 is not None and math.isfinite(np.dot(x2, x2))
        ref = self._refine(x2, y2) if ok2 else self._refine(x, y)
        t = solve_time + time.perf_counter() - t0
        if ref is not None:
            return ref[0], ref[1], (_SOLVED, _POLISHED, it, t, ref[2], 1)
        if ok2 and s2[0] == _SOLVED:
            return x2, y2, (_SOLVED_INACCURATE, "solved inaccurate", it, t, s2[4], s2[5])
        return x, y, (status_val, status, it, t, stats[4], stats[5])

    def _exact(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, float] | int:
        """The full QP solved exactly by DAQP, warm-started from OSQP's iterate ``(x, y)``.

        DAQP (dual active-set method, Arnström et al., IEEE TAC 2022) takes the QP
        ``min 1/2 w'Pw + q'w  s.t.  l <= Aw <= u`` of this call densely (``P``
        symmetric positive definite on the train MPCs: the slacks carry the quadratic
        penalty), rows with ``l = u`` as equalities, its initial active set from the
        signs of OSQP's duals and the rows nearly active at ``x``.  In the sparse form
        the active set OSQP's iterate names is tried first
        (:meth:`_active_set_kkt`: DAQP's dense setup dominates on those larger QPs);
        DAQP runs when that point fails the checks below.  A condensed QP of at least
        :data:`_SOFT_MIN_VARS` variables goes to DAQP without its slacks, as soft
        constraints (:meth:`_exact_soft`: the same optimum, about half the time); the
        full QP when that fails.  Accepted only when
        DAQP reports an optimum and the KKT conditions of the full QP hold to
        :data:`KKT_TOL`: stationarity ``|Pw + q + A'y| <= tol (1 + max|q|)``,
        feasibility of every row within ``tol (1 + |bound|)`` of its bound and
        complementarity (a row with ``|y_i| > tol (1 + max|y|)`` lies on its bound
        ``u_i`` (``y_i > 0``) or ``l_i`` (``y_i < 0``) within ``tol (1 + |bound|)``).  Returns
        ``(w, y, obj)`` in OSQP's variables and sign convention, or DAQP's exit flag when
        it found no optimum (-1: primal infeasible) and 0 when the KKT check failed.
        """
        P = _symmetric_P(self)
        A = self._A_dense
        q = self._v[self._v_q]
        lo = np.maximum(self._l, -_BIG)
        hi = np.minimum(self._u, _BIG)
        eq = hi - lo <= 1e-12 * (1.0 + np.abs(hi))
        sparse = getattr(self, "_sparse", False)
        if sparse and self.__dict__.get("_kkt_singular", 0) < _KKT_TRIES:
            out = self._active_set_kkt(x, y, P, A, q, lo, hi, eq)
            if out is not None:
                return out
        if not sparse and P.shape[0] >= _SOFT_MIN_VARS and getattr(self, "_row_input", 1) == 0:
            red = self._exact_soft(x, y, P, A, q, lo, hi, eq)
            if red is not None:
                return red
        sense = np.where(eq, 5, 0).astype(np.int32)
        w, _, flag, info = daqp.solve(
            P, q, A, hi, lo, sense, primal_tol=KKT_TOL, primal_start=x, dual_start=y
        )
        if flag != _DAQP_OPTIMAL:
            return int(flag)
        w = np.asarray(w)
        lam = np.asarray(info["lam"])
        out = _kkt_point(P, A, q, lo, hi, w, lam)
        return 0 if out is None else out

    def _exact_soft(
        self,
        x: np.ndarray,
        y: np.ndarray,
        P: np.ndarray,
        A: np.ndarray,
        q: np.ndarray,
        lo: np.ndarray,
        hi: np.ndarray,
        eq: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray, float] | int | None:
        r"""Condensed form: the QP solved by DAQP in the decision ``z`` alone, the slacks
        left to DAQP's soft constraints (the same optimum, a QP of ``nz`` variables and
        no ``eps >= 0`` rows instead of ``nz + ns`` variables).

        Soft row ``k`` (``L_k <= g_k z <= U_k``, slack ``eps_k``) costs ``rho_k eps_k +
        gamma_k eps_k²`` in the full QP; DAQP's soft constraint with linear weight
        ``w = rho_k`` and reciprocal quadratic weight ``1 / (2 gamma_k)`` charges the
        same for the same violation (``eps_k = max(0, g_k z - U_k, L_k - g_k z)`` at
        the optimum), so the minimisers in ``z`` coincide. Input (or rate) rows that
        are the identity on ``z`` become DAQP's simple bounds. The full QP's point is
        rebuilt: ``w = [z; eps]``, the soft rows' duals from DAQP's multiplier ``mu_k``
        (upper row ``max(mu_k, 0)``, lower row ``min(mu_k, 0)``) and the ``eps >= 0``
        rows' from stationarity in ``eps_k``, ``max(mu,0) - min(mu,0) - rho_k - 2
        gamma_k eps_k``, and accepted under the full QP's KKT conditions
        (:func:`_kkt_point`) as :meth:`_exact`'s own. DAQP's infeasibility verdict is
        final (the soft rows can always be met with slacks, so the full QP is
        infeasible exactly when the reduced one is). None (the full QP goes to DAQP)
        when a soft row has no quadratic penalty, a soft row is an equality, DAQP's
        setup fails or it stops otherwise, or the point fails the checks.
        """
        st = _soft_structure(self, A)
        if st is None:
            return None
        hard, jl, rows, sense, rho, w_lin = st
        nz, ns, nh, nlu = self._nz, self._ns, self._row_soft, self._n_bound_row
        nk = hard.size
        soft_up = slice(nh, nh + ns)
        L = np.full(ns, -_BIG)
        L[jl] = lo[nh + ns : nlu]
        U = hi[soft_up]
        if jl.size and np.any(U[jl] - L[jl] <= 1e-12 * (1.0 + np.abs(U[jl]))):
            return None  # a two-sided soft row with equal bounds
        eq_h = eq[hard]
        if eq_h.any():
            sense = sense.copy()
            sense[:nk][eq_h] = 5
        dual = np.concatenate([y[hard], y[soft_up]])
        dual[nk + jl] += y[nh + ns : nlu]  # one multiplier per soft row: upper + lower
        m = daqp.Model()
        m.settings = {"primal_tol": KKT_TOL}
        setup_flag, _ = m.setup(
            np.ascontiguousarray(P[:nz, :nz]), q[:nz], rows,
            np.concatenate([hi[hard], U]), np.concatenate([lo[hard], L]), sense,
            primal_start=x[:nz], dual_start=dual,
        )  # fmt: skip
        if setup_flag < 0:  # e.g. H not positive definite
            return None
        m.soft_weights(rho_l=rho, rho_u=rho, w_l=w_lin, w_u=w_lin)
        z, _, flag, info = m.solve()
        if flag == _DAQP_INFEASIBLE:
            return _DAQP_INFEASIBLE
        if flag != _DAQP_OPTIMAL and flag != _DAQP_SOFT_OPTIMAL:
            return None
        z = np.asarray(z)
        g = np.dot(rows[rows.shape[0] - ns :], z)  # the soft rows
        eps = np.maximum(np.maximum(g - U, L - g), 0.0)
        mu_all = np.asarray(info["lam"])
        mu = mu_all[nk:]
        lam = np.zeros(A.shape[0])
        lam[hard] = mu_all[:nk]
        mu_up, mu_lo = np.maximum(mu, 0.0), np.minimum(mu, 0.0)
        lam[soft_up] = mu_up
        lam[nh + ns : nlu] = mu_lo[jl]
        lam[nlu:] = mu_up - mu_lo - self._rho_s - 2.0 * self._gamma_s * eps
        return _kkt_point(P, A, q, lo, hi, np.concatenate([z, eps]), lam)

    def _active_set_kkt(
        self,
        x: np.ndarray,
        y: np.ndarray,
        P: np.ndarray,
        A: np.ndarray,
        q: np.ndarray,
        lo: np.ndarray,
        hi: np.ndarray,
        eq: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray, float] | None:
        """Sparse form: the equality-constrained QP of the active set OSQP's iterate
        names, solved by one sparse LU of its KKT system (DAQP works densely).

        Rows with ``l = u`` and rows OSQP's polishing rule marks active (``u_i - a_i <
        y_i`` on the upper, ``a_i - l_i < -y_i`` on the lower bound, ``a = Ax``) hold
        with equality: ``[P A_a'; A_a 0] [w; y_a] = [-q; b_a]``.  Accepted under the
        same KKT conditions as DAQP's point (:func:`_kkt_point`); None otherwise.
        """
        Ax = A @ x
        up = (hi - Ax < y) | eq
        act = np.flatnonzero(up | (Ax - lo < -y))
        n, k = P.shape[0], act.size
        pos = np.full(A.shape[0], -1)
        pos[act] = np.arange(n, n + k)
        pr, pc = self._P_rows, self._P_cols
        ar, ac = self._A_rows, self._A_cols
        on = pos[ar] >= 0
        off = pr != pc
        ka, kc = pos[ar[on]], ac[on]
        rows = np.concatenate([pr, pc[off], ka, kc])
        cols = np.concatenate([pc, pr[off], kc, ka])
        pv, av = P[pr, pc], A[ar[on], kc]
        vals = np.concatenate([pv, pv[off], av, av])
        nz = vals != 0.0  # explicit zeros of the fixed pattern upset SuperLU
        K = sp.csc_matrix((vals[nz], (rows[nz], cols[nz])), shape=(n + k, n + k))
        rhs = np.concatenate([-q, np.where(up[act], hi[act], lo[act])])
        try:
            sol = spla.splu(K).solve(rhs)
        except RuntimeError:  # singular: dependent active rows
            # (scipy's SuperLU keeps ~0.2 MB of every such factorisation of these KKT
            # systems: after _KKT_TRIES in a row this problem goes to DAQP directly)
            self._kkt_singular = self.__dict__.get("_kkt_singular", 0) + 1
            return None
        self._kkt_singular = 0
        lam = np.zeros(A.shape[0])
        lam[act] = sol[n:]
        return _kkt_point(P, A, q, lo, hi, sol[:n], lam)

    def _refine(
        self, x: np.ndarray, y: np.ndarray, max_iter: int = 20
    ) -> tuple[np.ndarray, np.ndarray, float] | None:
        """Exact solution by a primal-dual active-set iteration started from ``(x, y)``.

        Slacks are eliminated: each soft constraint ``k`` (row ``g_k``, bounds
        ``L_k <= g_k z <= U_k``) is *free* (``eps_k = 0``, bounds inactive), *bound*
        (``eps_k = 0``, ``g_k z`` on a bound, multiplier in ``[0, rho_k]``) or
        *violated* (``eps_k = g_k z - U_k > 0`` or ``L_k - g_k z > 0``, whose penalty
        ``rho_k eps_k + gamma eps_k^2`` enters the cost).  Each iteration solves the
        equality-constrained QP in ``z`` of the current active set (dense KKT
        system) and updates the set with the complementarity rules of the
        primal-dual active-set method (semismooth Newton); the result is accepted
        only if every KKT condition of the full QP holds.  Returns ``(w, y, obj)``
        in OSQP's variables or ``None``.
        """
        nz, ns, r0 = self._nz, self._ns, self._row_input
        nh, nlu = (
            self._row_soft - r0,
            self._n_bound_row - r0,
        )  # semantic row counts (no dynamics rows)
        th = self._theta
        c_sem = self._Csem @ th  # condensed offsets of the semantic rows
        lb = np.clip(self._lower_call[r0:] - c_sem, -_BIG, _BIG)
        ub = np.clip(self._upper_call[r0:] - c_sem, -_BIG, _BIG)
        ys = y[r0:]  # duals of the semantic rows (and of the eps >= 0 rows)
        Gsem = self._Gsem
        Gh = Gsem[:nh]
        lo_h, hi_h = lb[:nh], ub[:nh]
        Gs = Gsem[nh : nh + ns]
        jl = self._soft2_slack
        U_s = ub[nh : nh + ns]
        L_s = np.full(ns, -_BIG)
        L_s[jl] = lb[nh + ns : nlu]
        rho = self._rho_s
        g2 = 2.0 * self._gamma_s
        H2 = 2.0 * self._H
        q = self._Fq @ th
        eq_h = (hi_h - lo_h) <= 1e-12 * (1.0 + np.abs(hi_h))

        # initial active set from the ADMM iterate (OSQP's polishing rule)
        z = x[self._col_input : self._col_slack]
        ah = Gh @ z
        yh = ys[:nh]
        st_h = np.where((hi_h - ah) < yh, 1, np.where((ah - lo_h) < -yh, -1, 0))
        st_h[eq_h] = 1
        st_s = np.zeros(ns, dtype=np.int64)
        if ns:
            eps = x[self._col_slack :]
            ysu = ys[nh : nh + ns]
            ysl = np.zeros(ns)
            ysl[jl] = ys[nh + ns : nlu]
            gs = Gs @ z
            zero = eps < -ys[nlu:]
            st_s = np.where(ysu >= -ysl, 1, -1)
            st_s = np.where(
                zero, np.where(ysu >= -ysl, (U_s - gs) < ysu, (gs - L_s) < -ysl) * st_s, 2 * st_s
            )
        for _ in range(max_iter):
            # ---- KKT system of the current active set -----------------------------
            Hr = H2
            f = q
            vu, vl = st_s == 2, st_s == -2
            if vu.any() or vl.any():
                Gv = Gs[vu | vl]
                Hr = H2 + (Gv.T * g2[vu | vl]) @ Gv
                coef = np.where(st_s == 2, rho - g2 * U_s, -rho - g2 * L_s)[vu | vl]
                f = q + Gv.T @ coef
            ah_idx = np.flatnonzero(st_h != 0)
            bs_idx = np.flatnonzero(np.abs(st_s) == 1)
            E = np.vstack([Gh[ah_idx], Gs[bs_idx]])
            e = np.concatenate(
                [
                    np.where(st_h[ah_idx] > 0, hi_h[ah_idx], lo_h[ah_idx]),
                    np.where(st_s[bs_idx] > 0, U_s[bs_idx], L_s[bs_idx]),
                ]
            )
            ne = e.size
            K = np.zeros((nz + ne, nz + ne))
            K[:nz, :nz] = Hr
            K[:nz, nz:] = E.T
            K[nz:, :nz] = E
            rhs = np.concatenate([-f, e])
            try:
                sol = np.linalg.solve(K, rhs)
            except np.linalg.LinAlgError:
                sol = np.linalg.lstsq(K, rhs, rcond=None)[0]
            if not np.all(np.isfinite(sol)):
                return None
            z = sol[:nz]
            lam_h = np.zeros(nh)
            lam_h[ah_idx] = sol[nz : nz + ah_idx.size]
            ah = Gh @ z
            gs = Gs @ z
            v_u = gs - U_s
            v_l = L_s - gs
            mu = np.zeros(ns)  # signed multiplier of soft constraint k (upper > 0)
            mu[bs_idx] = sol[nz + ah_idx.size :]
            mu = np.where(st_s == 2, rho + g2 * v_u, np.where(st_s == -2, -(rho + g2 * v_l), mu))
            # ---- complementarity update (c = 1) -----------------------------------
            new_h = np.where(lam_h + (ah - hi_h) > 0, 1, np.where(lam_h + (ah - lo_h) < 0, -1, 0))
            new_h[eq_h] = 1
            t_u = np.maximum(mu, 0.0) + v_u
            t_l = np.maximum(-mu, 0.0) + v_l
            new_s = np.where(
                t_u >= t_l,
                np.where(t_u > rho, 2, np.where(t_u > 0, 1, 0)),
                np.where(t_l > rho, -2, np.where(t_l > 0, -1, 0)),
            )
            if np.array_equal(new_h, st_h) and np.array_equal(new_s, st_s):
                break
            st_h, st_s = new_h, new_s
        else:
            return None

        # ---- verify the KKT conditions of the full QP ---------------------------------
        scale = 1.0 + float(np.max(np.abs(rhs), initial=0.0))
        if np.max(np.abs(K @ sol - rhs), initial=0.0) > 1e-8 * scale:
            return None  # inconsistent (singular) active set
        tol_p = 1e-9 * (
            1.0 + float(np.max(np.abs(e), initial=0.0)) + float(np.abs(ah).max(initial=0))
        )
        tol_d = 1e-9 * (
            1.0 + float(np.max(np.abs(sol[nz:]), initial=0.0)) + float(rho.max(initial=0))
        )
        if np.any(ah > hi_h + tol_p) or np.any(ah < lo_h - tol_p):
            return None
        act = (st_h != 0) & ~eq_h
        if np.any(lam_h[act] * st_h[act] < -tol_d):
            return None
        if ns:
            free = st_s == 0
            if np.any(v_u[free] > tol_p) or np.any(v_l[free] > tol_p):
                return None
            bound = np.abs(st_s) == 1
            if np.any(mu[bound] * st_s[bound] < -tol_d) or np.any(
                np.abs(mu[bound]) > rho[bound] + tol_d
            ):
                return None
            if np.any(v_u[st_s == 2] < -tol_p) or np.any(v_l[st_s == -2] < -tol_p):
                return None
        eps_r = np.where(st_s == 2, v_u, np.where(st_s == -2, v_l, 0.0)).clip(min=0.0)
        parts = [z, eps_r]
        if self._sparse:
            parts.insert(0, self._Xth @ th + self._Sx @ z)
        w = np.concatenate(parts)
        # OSQP-convention duals, useful as the next warm start
        yw = np.array(y, dtype=float)
        yw[r0 : r0 + nh] = lam_h
        if ns:
            yw[r0 + nh : r0 + nh + ns] = np.maximum(mu, 0.0)
            yw[r0 + nh + ns : r0 + nlu] = np.minimum(mu, 0.0)[jl]
            yw[r0 + nlu :] = -rho - g2 * eps_r + np.maximum(mu, 0.0) - np.minimum(mu, 0.0)
        # OSQP objective 1/2 w'Pw + q'w (P stored as its upper triangle)
        Pd = self._P_dense
        qv = self._v[self._v_q]
        obj = float(w @ (Pd @ w) - 0.5 * (np.diagonal(Pd) * w) @ w + qv @ w)
        return w, yw, obj

    def _fallback(
        self,
        t_start: float,
        status: str,
        status_val: int,
        up: np.ndarray,
        iters: int = 0,
        solve_time: float = 0.0,
    ) -> MPCSolution:
        """Safe command: shifted previous plan (or held input), clipped to all input bounds."""
        m, Nc = self.m, self.Nc
        up = np.array(up, dtype=float)
        if not np.all(np.isfinite(up)):
            up = (
                self._u_last.copy()
                if self._u_last is not None and np.all(np.isfinite(self._u_last))
                else np.where(np.isfinite(up), up, 0.0)
            )
            rate_ok = False
        else:
            rate_ok = True
        self._plan_age += 1
        if self._plan is not None:
            idx = np.minimum(np.arange(Nc) + self._plan_age, Nc - 1)
            cand = self._plan[idx]
        else:
            cand = np.tile(up, (Nc, 1))
        U = np.empty((Nc, m))
        prev = up
        for i in range(Nc):
            lo, hi = self._umin, self._umax
            if rate_ok or i > 0:
                lo, hi = self._input_window(prev)
            ui = np.clip(cand[i], lo, hi)
            ui = np.where(np.isfinite(ui), ui, np.clip(0.0, lo, hi))
            U[i] = ui
            prev = ui
        u0 = U[0].copy()
        # prediction with the fallback plan (NaN if the data were not finite)
        if self._z_is_du:
            z = np.diff(np.vstack([up[None, :], U]), axis=0).ravel()
        else:
            z = U.ravel()
        self._theta[self._slots["up"]] = up
        X, Y, slack_max, cost = self._evaluate_plan(z)
        # next warm start: shift the previous one again (never reuse a failed iterate)
        ws_x, ws_y = self._warm_start()
        if ws_x is not None:
            xb = self._xbuf
            xb[: self._n_var] = ws_x
            self._ws_x = xb[self._xshift]
            self._ws_y = ws_y[self._yshift]
        self._u_last = u0
        return MPCSolution(
            u0=u0,
            du0=u0 - up,
            U=U,
            X=X,
            Y=Y,
            status=status,
            status_val=status_val,
            iterations=iters,
            solve_time_s=solve_time,
            overhead_s=time.perf_counter() - t_start - solve_time,
            slack_max=slack_max,
            fallback=True,
            cost=cost,
        )

    def _evaluate_plan(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, float]:
        """Prediction, soft violation and cost of a plan ``z`` from the condensed model.

        Used for fallback plans; NaN where the data of this call were not finite.
        """
        th = self._theta
        ns, r0 = self._ns, self._row_input
        nh, nlu = self._row_soft - r0, self._n_bound_row - r0
        with np.errstate(invalid="ignore", over="ignore"):
            X = (self._Xth @ th + self._Sx @ z).reshape(self.Np, self.n)
            Y = X if self._y_is_x else X @ self._C.T
            g = self._Gsem @ z + self._Csem @ th
            eps = np.zeros(ns)
            if ns:
                eps = np.maximum(eps, g[nh : nh + ns] - self._upper_call[r0 + nh : r0 + nh + ns])
                np.maximum.at(
                    eps, self._soft2_slack, self._lower_call[r0 + nh + ns :] - g[nh + ns : nlu]
                )
            Lc = self._Lth_c @ th
            cost = float(
                z @ self._H @ z
                + (self._Fq @ th) @ z
                + Lc @ Lc
                + self._rho_s @ eps
                + self._gamma_s @ eps**2
            )
            slack_max = float(eps.max()) if ns else 0.0
        if not math.isfinite(cost):
            cost = float("nan")
        return X, Y, slack_max, cost
