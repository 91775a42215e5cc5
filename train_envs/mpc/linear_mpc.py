r"""Linear MPC on OSQP: one QP per sampling instant (condensed or sparse form).

Model :math:`x_{k+1} = A x_k + B u_k + d_k`, :math:`y_k = C x_k` (affine term
:math:`d_k` may vary over the horizon).  With ``delta_u=True`` the condensed decision
is :math:`z = (\Delta u_0, \dots, \Delta u_{N_c-1})` of the augmented state
:math:`\xi_k = [x_k; u_{k-1}]` (Maciejowski 2002, sec. 2.4), otherwise
:math:`z = (u_0, \dots, u_{N_c-1})`; inputs are held after :math:`N_c`.  The prediction
is affine in :math:`z`: :math:`U = T_z z + T_u u_{-1}`, :math:`X = \Phi x_0 + \Gamma U
+ \Gamma_d D`, :math:`Y = (I \otimes C) X`.  QP:

.. math::

    \min\ \sum_{i=1}^{N_p} \lVert y_i - r_i\rVert_Q^2
      + \sum_{i=0}^{N_c-1} \lVert \Delta u_i\rVert_R^2
      + \sum_{i=0}^{N_p-1} \lVert u_i - u^{\mathrm{ref}}_i\rVert_S^2
      + \lVert x_{N_p} - x^{\mathrm{ref}}_{N}\rVert_P^2
      + \sum_k \bigl(\rho_k \varepsilon_k + \gamma_k \varepsilon_k^2\bigr)

subject to the hard input box :math:`u_{\min} \le u_i \le u_{\max}` and rate box
:math:`\Delta u_{\min} \le \Delta u_i \le \Delta u_{\max}`, the soft output box
:math:`y_{\min,i} - \varepsilon \le y_i \le y_{\max,i} + \varepsilon` and soft polyhedra
:math:`H_y y_i \le h_{y,i} + \varepsilon`, :math:`H_x x_i \le h_{x,i} + \varepsilon`, an
optional soft terminal box / polyhedron on :math:`x_{N_p}`, :math:`\varepsilon \ge 0`
(one slack per row and stage).  The linear slack cost is an exact (L1) penalty
(Kerrigan & Maciejowski 2000): the soft QP returns the hard solution when that is
feasible and :math:`\rho_k` exceeds its multiplier; :math:`\gamma_k = 0.01\rho_k` (default)
makes the QP strictly convex without changing that threshold.  ``np.inf`` makes a row
hard.  A previous input outside the box with rate limits relaxes the first stages'
input bounds to the reachable box.

Every per-step vector (``q``, the row offsets, the free response, the cost constant)
is linear in :math:`\theta = (1, x_0, u_{-1}, r, x^{\mathrm{ref}}_N, d, u^{\mathrm{ref}}, D)`:
one matrix-vector product per step (layout: :mod:`train_envs.mpc.layout`).

Forms: *condensed* -- :math:`w = (z, \varepsilon)`, dense Hessian; *sparse* --
:math:`w = (X, U, \varepsilon)` with the dynamics as equality rows (absolute inputs).
``form="auto"`` picks condensed for ``Nc*m <= 20``.  OSQP (Stellato et al. 2020) is
set up once; :meth:`LinearMPC.solve` updates ``q, l, u`` and warm-starts from the
previous solution shifted by one stage; weight and model changes update the matrix
values of a fixed sparsity pattern.  A non-converged solve is rescued
(:mod:`train_envs.mpc.recovery`), else the shifted previous plan is applied
(``fallback=True``).  Measurements behind the defaults: ``docs/design/mpc_engine.md``.

References: J. M. Maciejowski, *Predictive Control with Constraints*, Prentice Hall,
2002 (sec. 2.4, 3.1); E. C. Kerrigan and J. M. Maciejowski, "Soft constraints and exact
penalty functions in model predictive control", UKACC Control, 2000; B. Stellato,
G. Banjac, P. Goulart, A. Bemporad and S. Boyd, "OSQP: an operator splitting solver for
quadratic programs", Math. Prog. Comp. 12, 637-672, 2020.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from typing import Any

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike

from train_envs.mpc.assembly import _AssemblyMixin
from train_envs.mpc.bounds import _BoundsMixin
from train_envs.mpc.description import _check_order, _DescriptionMixin, _vector, _weight
from train_envs.mpc.layout import _LayoutMixin
from train_envs.mpc.osqp_backend import (
    _SOLVED,
    _SOLVED_INACCURATE,
    _STATUS_EXCEPTION,
    _STATUS_INVALID_INPUT,
    _UNCONSTRAINED,
    _Backend,
    osqp_settings_with,
)
from train_envs.mpc.recovery import _FINISH_EXACT, _POLISHED, _RecoveryMixin
from train_envs.mpc.solution import MPCSolution, _Predictions
from train_envs.mpc.unconstrained import _UnconstrainedMixin


class LinearMPC(
    _DescriptionMixin,
    _LayoutMixin,
    _AssemblyMixin,
    _BoundsMixin,
    _UnconstrainedMixin,
    _RecoveryMixin,
):
    r"""Linear MPC solved with OSQP (see the module docstring for the QP).

    Typical loop::

        mpc = LinearMPC(A, B, C, Np=20, Q=Q, R=R, u_min=-1, u_max=1, du_min=-0.1,
                        du_max=0.1, y_max=[v_max], soft_penalty=1e5)
        sol = mpc.solve(x, u_prev, y_ref, d=d)   # never raises on solver failure
        u_prev = sol.u0                          # finite, inside box and rate window

    Args:
        A, B, C: model matrices, shapes ``(n, n)``, ``(n, m)``, ``(p, n)``;
            ``C=None`` means ``C = I`` (state tracking).
        Np: prediction horizon (>= 1).  Nc: control horizon, ``1 <= Nc <= Np``
            (default ``Np``); inputs are held after ``Nc``.
        Q: output weight ``(p, p)`` (scalar or diagonal vector accepted).
        R: weight on input increments ``Delta u`` ``(m, m)``.
        S: optional weight on input levels ``u_i - u_ref_i`` ``(m, m)``.
        P: optional terminal weight: ``(n, n)`` on ``x_Np - x_ref_N``
            (``terminal="state"``, default) or ``(p, p)`` on ``y_Np - r_Np``
            (``terminal="output"``).
        u_min, u_max: hard input bounds ``(m,)`` (scalars broadcast; +-inf allowed).
        du_min, du_max: hard increment bounds ``(m,)``; ``None`` = unbounded.
        y_min, y_max: output box ``(p,)`` at stages ``1..Np``; rows with both
            bounds infinite are dropped (they cannot be given per-stage values
            later).
        H_y, h_y: output polyhedron ``H_y y_i <= h_y`` (``(r, p)``, ``(r,)``).
        H_x, h_x: state polyhedron ``H_x x_i <= h_x`` (``(r, n)``, ``(r,)``).
        xN_min, xN_max, H_N, h_N: terminal state box / polyhedron at ``x_Np``.
        soft_penalty: exact-penalty weight rho: a scalar for all output/state
            constraints, or a mapping with keys ``"y"``, ``"H_y"``, ``"H_x"``,
            ``"xN"``, ``"H_N"`` whose values are scalars or per-row vectors
            (missing keys use 1e5).  ``np.inf`` makes a row hard.
        soft_quadratic: gamma of the strictly convex term ``gamma_k * eps_k^2``; ``None``
            (default) uses ``gamma_k = 0.01 * rho_k`` per row.  For physically small
            violations this term is negligible next to ``rho_k * eps_k`` (it never
            changes the exact-penalty threshold), but its curvature makes violated
            problems far easier for ADMM (``docs/design/mpc_engine.md``).
        delta_u: condensed decision variables are the increments (default) or the
            absolute inputs; both give the same optimum.  The sparse form always
            uses absolute inputs as variables.
        terminal: ``"state"`` or ``"output"`` (what ``P`` weights).
        osqp_settings: overrides of the default OSQP settings (``eps_abs``,
            ``eps_rel``, ``max_iter``, ``polishing``, ``time_limit``, ...).
        fast_osqp: call OSQP's compiled solver object directly (default True).
        unconstrained_first: (condensed form) before calling OSQP, take the
            unconstrained minimiser ``z = −H⁻¹ q`` and keep it when it satisfies every
            constraint row -- then it *is* the QP's optimum (strictly convex cost, zero
            slacks), reported with status ``"solved (unconstrained)"``, zero iterations
            and zero solve time.  Otherwise OSQP runs as usual, warm-started as always.
            Off by default; worth it where constraints are rarely active.
        warm_start: ``"shift"`` (default): start OSQP from the previous primal/dual
            solution shifted by one stage; ``"previous"``: from the previous
            solution as is; ``"none"``: let OSQP start from its last iterate.
        rescue: on a non-converged solve, try the relaxed/polished second attempt
            and the exact active-set refinement before falling back (default True;
            see :meth:`_rescue`).  With it, in the condensed form (small dense QPs,
            which DAQP solves in a fraction of OSQP's time), once an OSQP solve has
            ended at its iteration cap or solved inaccurate (the approach to a stop,
            where ADMM crawls), the following solves run the exact finish
            (:meth:`_exact`) from the warm start first, reported as ``"solved
            (polished)"`` with zero ADMM iterations, and OSQP only when that finish
            fails its KKT check (its outcome then decides again; :meth:`reset` clears
            the state).
        form: ``"condensed"``, ``"sparse"`` or ``"auto"`` (default; condensed for
            ``Nc*m <= 20``, measured in ``docs/design/mpc_engine.md``).
        stage_scales: optional per-stage weight multipliers ``{"Q": (Np,), "R": (Nc,),
            "S": (Np,)}`` (entries >= 0; missing keys = 1): the cost terms of stage
            ``i`` are multiplied by ``c_i`` -- time-varying weights, e.g. the ``1/beta``
            weighting of the held stages of self-triggered MPC.
    """

    def __init__(
        self,
        A: ArrayLike,
        B: ArrayLike,
        C: ArrayLike | None = None,
        *,
        Np: int,
        Nc: int | None = None,
        Q: ArrayLike,
        R: ArrayLike,
        S: ArrayLike | None = None,
        P: ArrayLike | None = None,
        u_min: ArrayLike,
        u_max: ArrayLike,
        du_min: ArrayLike | None = None,
        du_max: ArrayLike | None = None,
        y_min: ArrayLike | None = None,
        y_max: ArrayLike | None = None,
        H_y: ArrayLike | None = None,
        h_y: ArrayLike | None = None,
        H_x: ArrayLike | None = None,
        h_x: ArrayLike | None = None,
        xN_min: ArrayLike | None = None,
        xN_max: ArrayLike | None = None,
        H_N: ArrayLike | None = None,
        h_N: ArrayLike | None = None,
        soft_penalty: float | Mapping[str, float | ArrayLike] = 1e5,
        soft_quadratic: float | None = None,
        delta_u: bool = True,
        terminal: str = "state",
        osqp_settings: Mapping[str, Any] | None = None,
        fast_osqp: bool = True,
        unconstrained_first: bool = False,
        warm_start: str = "shift",
        rescue: bool = True,
        form: str = "auto",
        stage_scales: Mapping[str, ArrayLike] | None = None,
    ) -> None:
        # ---- model ---------------------------------------------------------
        A_, B_, C_ = self._check_model(A, B, C, None)
        n, m, p = A_.shape[0], B_.shape[1], C_.shape[0]
        self.n, self.m, self.p = n, m, p
        self._A, self._B, self._C = A_, B_, C_

        if isinstance(Np, bool) or not isinstance(Np, int | np.integer) or Np < 1:
            raise ValueError(f"Np must be an integer >= 1, got {Np!r}")
        Nc = Np if Nc is None else Nc
        if isinstance(Nc, bool) or not isinstance(Nc, int | np.integer) or not 1 <= Nc <= Np:
            raise ValueError(f"Nc must be an integer with 1 <= Nc <= Np ({Np}), got {Nc!r}")
        self.Np, self.Nc = int(Np), int(Nc)
        self.delta_u = bool(delta_u)
        if terminal not in ("state", "output"):
            raise ValueError(f"terminal must be 'state' or 'output', got {terminal!r}")
        self.terminal = terminal

        # ---- weights -------------------------------------------------------
        self._Q = _weight("Q", Q, p)
        self._R = _weight("R", R, m)
        self._S = None if S is None else _weight("S", S, m)
        self._P = None if P is None else _weight("P", P, n if terminal == "state" else p)
        self._gamma = None if soft_quadratic is None else self._check_gamma(soft_quadratic)

        # ---- input constraints ---------------------------------------------
        self._umin = _vector("u_min", u_min, m, allow_inf=True)
        self._umax = _vector("u_max", u_max, m, allow_inf=True)
        _check_order("u_min", self._umin, "u_max", self._umax)
        self._dumin = (
            np.full(m, -np.inf) if du_min is None else _vector("du_min", du_min, m, allow_inf=True)
        )
        self._dumax = (
            np.full(m, np.inf) if du_max is None else _vector("du_max", du_max, m, allow_inf=True)
        )
        _check_order("du_min", self._dumin, "du_max", self._dumax)
        self._has_du = bool(np.any(np.isfinite(self._dumin)) or np.any(np.isfinite(self._dumax)))
        self._umin_l, self._umax_l = self._umin.tolist(), self._umax.tolist()
        self._dumin_l, self._dumax_l = self._dumin.tolist(), self._dumax.tolist()
        self._n_plan, self._n_pred_x = self.Nc * m, self.Np * n
        if warm_start not in ("shift", "previous", "none"):
            raise ValueError(
                f"warm_start must be 'shift', 'previous' or 'none', got {warm_start!r}"
            )
        self._ws_mode = warm_start
        self._rescue_on = bool(rescue)
        if form not in ("auto", "condensed", "sparse"):
            raise ValueError(f"form must be 'auto', 'condensed' or 'sparse', got {form!r}")
        if form == "auto":
            form = self._auto_form(self.Np, self.Nc, n, m)
        self.form = form
        self._sparse = form == "sparse"
        self._z_is_du = self.delta_u and not self._sparse

        # ---- output / state constraints --------------------------------------
        self._groups = self._make_groups(
            y_min, y_max, H_y, h_y, H_x, h_x, xN_min, xN_max, H_N, h_N, soft_penalty
        )

        # ---- OSQP settings ---------------------------------------------------
        settings = osqp_settings_with(osqp_settings)
        self.osqp_settings = settings

        self._stage_scales = self._check_stage_scales(stage_scales)
        self._layout()
        self._build()
        P0 = sp.csc_matrix(
            (self._P_dense[self._P_rows, self._P_cols], self._P_ind, self._P_ptr),
            shape=(self._n_var, self._n_var),
        )
        A0 = sp.csc_matrix(
            (self._A_dense[self._A_rows, self._A_cols], self._A_ind, self._A_ptr),
            shape=(self._n_row, self._n_var),
        )
        self._backend = _Backend(P0, self._q_init(), A0, self._l, self._u, settings, fast_osqp)
        self._mat_dirty = False  # P, A values changed since OSQP last got them
        self._unc_first = bool(unconstrained_first) and not self._sparse
        #: the exact finish may run before OSQP (condensed form: a small dense QP)
        self._finish_first = self._rescue_on and not self._sparse
        self.reset()

    def reset(self) -> None:
        """Forget the warm start, the last plan and the last applied input."""
        self._theta = np.zeros(self._ntheta)
        self._theta[0] = 1.0
        self._has_xN = "xN" in self._slots
        self._has_ur = "ur" in self._slots
        self._theta_no_D = self._theta[: self._n_theta_no_D]
        self._theta_up = self._theta[self._slots["up"]]
        self._theta_x0 = self._theta[self._slots["x0"]]
        self._theta_r = self._theta[self._slots["r"]].reshape(self.Np, self.p)
        self._theta_D = self._theta[self._slots["D"]].reshape(self.Np, self.n)
        self._shape_D = (self.Np, self.n)
        if self._has_xN:
            self._theta_xN = self._theta[self._slots["xN"]]
        self._d_dirty = 0  # 0: no d, 1: constant d written, 2: sequence D written
        self._ur_dirty = False
        self._ws_x: np.ndarray | None = None
        self._ws_y: np.ndarray | None = None
        #: the last solution (primal, dual; dual None: condensed z with zero slacks and
        #: duals), turned into the next warm start only when OSQP runs (_warm_start)
        self._ws_src: tuple[np.ndarray, np.ndarray | None] | None = None
        self._xbuf = np.zeros(self._n_var + 1)
        self._plan: np.ndarray | None = None
        self._plan_age = 0
        self._u_last: np.ndarray | None = None
        #: the last OSQP solve ended at its cap (or solved inaccurate): the exact
        #: finish runs first (from the warm start) until it fails once
        self._exact_first = False
        #: singular active-set KKT systems in a row (sparse form; see _active_set_kkt)
        self._kkt_singular = 0

    def reset_solver(self) -> None:
        """:meth:`reset` plus OSQP's own state: initial ``rho`` and a zero iterate.

        OSQP keeps its adapted ``rho`` (and, without a warm start, its last iterate)
        between solves; after this call identical data give identical solutions, so a
        controller can keep one QP across episodes and stay reproducible per seed
        (costs one KKT refactorisation).
        """
        self.reset()
        self._flush_matrices()
        self._backend.reset(self._n_var, self._n_row)

    def solve(
        self,
        x0: ArrayLike,
        u_prev: ArrayLike,
        y_ref: ArrayLike,
        *,
        d: ArrayLike | None = None,
        u_ref: ArrayLike | None = None,
        x_ref_N: ArrayLike | None = None,
        y_min: ArrayLike | None = None,
        y_max: ArrayLike | None = None,
        h_y: ArrayLike | None = None,
        h_x: ArrayLike | None = None,
    ) -> MPCSolution:
        """Solve the MPC problem at the current sampling instant.

        Args:
            x0: current state ``(n,)``.
            u_prev: input applied at the previous instant ``(m,)``.
            y_ref: output references ``r_1 .. r_Np`` as ``(Np, p)`` (or ``(p,)``, held).
            d: affine model term: ``(n,)`` constant or ``(Np, n)`` for ``d_0 .. d_{Np-1}``.
            u_ref: input-level references ``(Np, m)`` or ``(m,)`` (used with ``S``; default 0).
            x_ref_N: terminal state reference (state terminal weight only); default
                ``pinv(C) @ y_ref[-1]`` (exactly ``y_ref[-1]`` when ``C = I``).
            y_min, y_max, h_y, h_x: per-stage bounds ``(Np, .)`` (or one row, held)
                replacing the construction-time values for this call only; where some
                rows were unconstrained at construction, ``(Np, k)`` with only the ``k``
                constrained ones is accepted too (the cheapest form).

        Never raises for non-finite data or solver failures: the result then has
        ``fallback=True`` and a safe ``u0``.  Wrong shapes raise ``ValueError``.
        """
        t_start = time.perf_counter()
        th = self._theta
        M = self._load(x0, u_prev, y_ref, d, u_ref, x_ref_N)
        v = self._v
        tv = self._theta_no_D if M is self._M_no_D else th
        up = self._theta_up
        if not math.isfinite(np.dot(tv, tv)):  # NaN/inf anywhere in the data
            v.fill(np.nan)
            return self._fallback(t_start, "invalid input", _STATUS_INVALID_INPUT, up)
        np.dot(M, tv, out=v)
        upl = up.tolist()

        # bounds -------------------------------------------------------------------
        override = y_min is not None or y_max is not None or h_y is not None or h_x is not None
        relax = self._has_du and self._outside_box(upl)
        changed = False
        if override or relax:
            ok = self._set_bounds(up, relax, y_min, y_max, h_y, h_x)
            if not ok:
                return self._fallback(t_start, "invalid input", _STATUS_INVALID_INPUT, up)
            changed = True
        elif self._bounds_dirty:
            self._bounds_call[...] = self._bounds_base
            self._bounds_dirty = False
            changed = True
        # rows with constant offsets (sparse form): their bounds are the bounds themselves
        if changed and self._offset_rows.stop < self._n_bound_row:
            k = self._offset_rows.stop
            self._lu[:, k : self._n_bound_row] = self._bounds_call[:, k:]
        c = v[self._v_offsets]
        np.subtract(self._lower_call_off, c, out=self._l_off)  # l = lower bounds - offsets
        np.subtract(self._upper_call_off, c, out=self._u_off)

        # unconstrained optimum when it is feasible (exact; see unconstrained_first) ---
        if self._unc_first:
            hit = self._unconstrained(v[self._v_q], relax)
            if hit is not None:
                x, y, obj_val = hit
                status_val, status, iters, solve_time = _SOLVED, _UNCONSTRAINED, 0, 0.0
                return self._finish(
                    t_start,
                    x,
                    y,
                    v,
                    th,
                    upl,
                    up,
                    status,
                    status_val,
                    iters,
                    solve_time,
                    obj_val,
                    0.0,
                )

        # OSQP -----------------------------------------------------------------------
        try:
            ws_x, ws_y = self._warm_start()
            if self._exact_first and ws_x is not None:  # the exact finish first
                t0 = time.perf_counter()
                ex = self._exact(ws_x, ws_y)
                if isinstance(ex, tuple):
                    x, y, obj_val = ex
                    return self._finish(
                        t_start,
                        x,
                        y,
                        v,
                        th,
                        upl,
                        up,
                        _POLISHED,
                        _SOLVED,
                        0,
                        time.perf_counter() - t0,
                        obj_val,
                    )
            self._flush_matrices()
            res = self._backend.step(v[self._v_q], self._l, self._u, ws_x, ws_y)
            if res is None:  # OSQP rejected the vector update
                return self._fallback(t_start, "solver error", _STATUS_EXCEPTION, up)
            x, y, stats = res
            status_val, status, iters, solve_time, obj_val, _ = stats
            self._exact_first = self._finish_first and status_val in _FINISH_EXACT
            if status_val != _SOLVED and self._rescue_on:
                x, y, stats = self._rescue(x, y, stats)
                status_val, status, iters, solve_time, obj_val, _ = stats
        except Exception:  # noqa: BLE001 - the control loop must never raise here
            return self._fallback(t_start, "solver error", _STATUS_EXCEPTION, up)
        if status_val != _SOLVED and status_val != _SOLVED_INACCURATE:
            return self._fallback(t_start, status, status_val, up, iters, solve_time)
        return self._finish(
            t_start, x, y, v, th, upl, up, status, status_val, iters, solve_time, obj_val
        )

    def _finish(
        self,
        t_start: float,
        x: np.ndarray,
        y: np.ndarray,
        v: np.ndarray,
        th: np.ndarray,
        upl: list[float],
        up: np.ndarray,
        status: str,
        status_val: int,
        iters: int,
        solve_time: float,
        obj_val: float,
        slack_max: float | None = None,
    ) -> MPCSolution:
        """Plan, safe first move, cost and warm start from a solution ``(x, y)``
        (``slack_max`` when the caller knows it)."""
        # result ---------------------------------------------------------------------
        if self._sparse:  # states and (absolute) inputs are variables
            U = x[self._col_input : self._col_slack].reshape(self.Nc, self.m)
        else:  # inputs now, predicted states and outputs when read (MPCSolution.X/Y)
            U = np.dot(self._Wz_u, x[: self._nz])
            U += v[self._v_plan]
            U = U.reshape(self.Nc, self.m)
        u0 = U[0]
        # remove the solver's O(eps) constraint violation: u0 exactly inside both boxes
        if self.m == 1:  # the common single-input case without the helper call
            a = upl[0]
            v0 = float(u0[0])
            rlo = a + self._dumin_l[0]
            rhi = a + self._dumax_l[0]
            lo = min(max(self._umin_l[0], rlo), rhi)
            hi = max(min(self._umax_l[0], rhi), rlo)
            if v0 < lo:
                u0[0] = lo
            elif v0 > hi:
                u0[0] = hi
            elif v0 != v0:  # NaN
                return self._fallback(t_start, status, status_val, up, iters, solve_time)
        elif not self._clip_to_window(u0, upl):
            return self._fallback(t_start, status, status_val, up, iters, solve_time)
        Lv = v[self._v_cost]
        cost = obj_val + float(np.dot(Lv, Lv))
        if slack_max is None:
            ns = self._ns
            if ns == 0:
                slack_max = 0.0
            elif ns <= 64:  # python max beats a ufunc call for short vectors
                slack_max = max(0.0, max(x[self._col_slack :].tolist()))
            else:
                slack_max = max(0.0, float(x[self._col_slack :].max()))
        self._ws_src = (x, y)  # the next warm start, formed when OSQP runs next
        self._plan = U
        self._plan_age = 0
        self._u_last = u0
        return MPCSolution(
            u0,
            u0 - up,
            U,
            None,
            None,
            status,
            status_val,
            iters,
            solve_time,
            time.perf_counter() - t_start - solve_time,
            slack_max,
            False,
            cost,
            _Predictions(self, x, th),
        )

    def _warm_start(self) -> tuple[np.ndarray | None, np.ndarray | None]:
        """The warm start of the next OSQP call, formed from the last solution on demand
        (shifted by one stage or as it is, per ``warm_start``): most solves of the MPCs
        that try the unconstrained optimum first never reach OSQP."""
        src = self._ws_src
        if src is not None:
            self._ws_src = None
            x, y = src
            mode = self._ws_mode
            if y is None:  # condensed decision z, zero slacks and duals
                xb = self._xbuf
                xb[: self._nz] = x
                xb[self._nz : self._n_var] = 0.0
                if mode == "shift":
                    self._ws_x, self._ws_y = xb[self._xshift], self._zero_duals()
                elif mode == "previous":
                    self._ws_x, self._ws_y = xb[: self._n_var].copy(), self._zero_duals()
            elif mode == "shift":
                xb = self._xbuf
                xb[: self._n_var] = x
                self._ws_x = xb[self._xshift]
                self._ws_y = y[self._yshift]
            elif mode == "previous":
                self._ws_x, self._ws_y = x, y
        return self._ws_x, self._ws_y

    def _zero_duals(self) -> np.ndarray:
        y = self.__dict__.get("_y_zero")
        if y is None or y.size != self._n_row:
            y = self._y_zero = np.zeros(self._n_row)  # shared: nothing writes into duals
        return y

    def _predictions(self, x: np.ndarray, th: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Predicted states and outputs ``(X, Y)`` of the QP solution ``x`` (data ``th``)."""
        npn = self._n_pred_x
        if self._sparse:
            X = x[:npn].reshape(self.Np, self.n)
            return X, X if self._y_is_x else X @ self._C.T
        traj = np.dot(self._Wz_xy, x[: self._nz])
        traj += np.dot(self._M_xy, th)
        X = traj[:npn].reshape(self.Np, self.n)
        return X, X if self._y_is_x else traj[npn:].reshape(self.Np, self.p)

    @property
    def n_variables(self) -> int:
        """Number of QP decision variables (states in the sparse form, inputs, slacks)."""
        return self._n_var

    @property
    def n_constraints(self) -> int:
        """Number of QP constraint rows."""
        return self._n_row
