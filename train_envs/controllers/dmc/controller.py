r"""The DMC controller of paper 004: one control step built from the package's laws.

Each step (§ numbers of the package docstring):

1. setpoint y_r(k) and preview y_r(k+1 … k+P) (:class:`~.setpoint.SetpointPreview`);
   error e = y_r(k) − v and its filtered rate ė (:func:`~.laws.filtered_rate`);
2. correction coefficient h_c (:func:`~.laws.correction_coefficient`), feedforward
   u_ff (:func:`~.laws.feedforward_force`, gradient read τ + T_d ahead), prediction
   vector moved, corrected and shifted (:mod:`.prediction`);
3. satisfaction index J of the speeds predicted with the previous plan's remaining
   moves, ``ŷ_P0 + A [ΔU*(k−1)_{2…L}, 0]`` (:func:`~.laws.satisfaction`), softening
   factor α (:func:`~.laws.softening_factor`), softened reference w;
4. the move plan: the classic law when no bound binds, else the QP (:mod:`.qp`);
5. command ``u = M(1+ρ) u_a + u_ff``, then the comfort jerk limit
   ``|Δu| ≤ j_max M(1+ρ) Δt`` (also the QP's hard Δu bound, with ``ctx.du_max_Nps``),
   the envelope ``[−B(v), F(v)]`` and the per-input rate limit ``ctx.du_max_Nps``
   (:func:`train_envs.controllers._common.distribute`, which also splits the force by
   car mass share for per-car scenarios).

The prediction vector's input memory is rebuilt every step from the command actually
applied (``obs.u_prev_N``), so clipping or an external override enters it as the move
it really was. Without feedforward the DMC has to absorb the gradient and resistance
through the correction alone — on an integrating process a constant load is exactly
what the step-type correction cannot remove (Lundström et al. 1995).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from train_envs.controllers._common import (
    distribute,
    distribute_single,
    envelope_N,
    input_shares,
)
from train_envs.controllers.base import ControlContext, Controller, Observation, TunableParam
from train_envs.controllers.dmc.laws import (
    SatisfactionShape,
    correction_coefficient,
    correction_rules,
    feedforward_force,
    filtered_rate,
    satisfaction,
    softened_reference,
    softened_reference_error,
    softening_factor,
    softening_weights,
)
from train_envs.controllers.dmc.prediction import add_move, correct_and_shift, predict
from train_envs.controllers.dmc.qp import UNCONSTRAINED_INFO, DMCProblem
from train_envs.controllers.dmc.setpoint import SetpointPreview
from train_envs.controllers.dmc.step_response import (
    dmc_gain,
    dynamic_matrix,
    step_response,
    tail_ratio,
)
from train_envs.mpc import LinearMPC, MPCSolution
from train_envs.plants.physics import davis_slope
from train_envs.trains import KMH, G
from train_envs.validation import (
    check_choice,
    check_finite,
    check_nonnegative,
    check_positive,
    check_range,
)


class DMCController(Controller):
    """DMC with fuzzy online softening factor α and correction coefficient h_c (paper 004).

    The seven tunable parameters are those 004's MOWOA tunes. ``alpha_order="raise"``
    (default) checks α_min ≤ α_max whenever parameters are set (``ValueError`` naming
    both); tuners and the env sample all seven independently from a box, and
    ``alpha_order="clip"`` accepts such samples, using ``min(α_min, α_max)`` as the lower
    bound (the stored values are kept, so ``get_params`` returns what was set).
    The other arguments are structural: horizons (N = ``model_length``, P, L), weights
    q, r, the jerk limit, the satisfaction shapes (response-time bounds and widths in
    samples, scaled by Δt), the catch-up and stop hold of the setpoint, the tail rule
    (``"model"``/``"linear"``), the reference form (``"level"``/``"error"``), the QP's
    ``soft_penalty`` and ``osqp_eps``, and ``classic_law`` (try the unconstrained plan
    first). ``v_nominal_mps`` is the speed the Davis slope is linearised at (default:
    the reference's mean speed, length / duration); a second-order actuator is modelled
    by the lag ``ctx.actuator_tau_s`` (the context carries no ω_n, ζ). ``compute``'s
    info holds α, h_c, J, μ_t, μ_y, t_r, the prediction error
    e_c, the DMC and feedforward forces and the solver fields.
    """

    name = "dmc"
    #: the model, dynamic matrix and QP kept across resets do not depend on the seven
    #: tunable parameters (see reset): a reused env keeps this controller
    keeps_parameter_state = False
    PARAMS = (
        TunableParam("alpha_max", 0.0, 0.99, 0.4,
                     description="largest softening factor α_max [-]"),
        TunableParam("alpha_min", 0.0, 0.99, 0.1,
                     description="smallest softening factor α_min [-]"),
        TunableParam("alpha_trend", -10.0, 10.0, 2.0,
                     description="shaping (trend) factor γ of α(J) [-]"),
        TunableParam("k_e", 0.1, 1000.0, 30.0, log=True,
                     description="speed error quantisation factor [s/m] (|e| >= 3/k_e is 'big')"),
        TunableParam("h0", 0.05, 1.0, 0.8,
                     description="initial (nominal) correction coefficient h_0 [-]"),
        TunableParam("k_ec", 0.1, 1000.0, 30.0, log=True,
                     description="error-rate quantisation factor [s^2/m]"),
        TunableParam("k_h", 0.0, 0.3, 0.05,
                     description="correction proportional factor k_h [-] (h_c swing 3 k_h)"),
    )

    def __init__(
        self,
        *,
        model_length: int = 60,
        prediction_horizon: int = 15,
        control_horizon: int = 15,
        q: float = 1.0,
        r: float = 0.5,
        jerk_max_mps3: float = 1.5,
        feedforward: bool = True,
        v_nominal_mps: float | None = None,
        response_bounds_samples: tuple[float, float] = (10.0, 160.0),
        response_widths_samples: tuple[float, float] = (6.0, 6.0),
        pred_error_bound_mps: float = 0.2 * KMH,
        pred_error_width_mps: float = 0.05 * KMH,
        e_tol_mps: float = 0.05 * KMH,
        edot_tol_mps2: float = 0.02,
        combine: str = "min",
        h_min: float = 0.05,
        edot_filter_s: float = 0.4,
        soft_penalty: float = 1e3,
        tail: str = "model",
        reference_form: str = "level",
        position_gain_1ps: float = 0.1,
        catchup_max_mps: float = 0.2,
        catchup_fade_mps: float = 1.0,
        stop_hold_mps: float = 0.1,
        feedforward_lead: bool = True,
        alpha_order: str = "raise",
        osqp_eps: float = 1e-4,
        classic_law: bool = True,
        **params: float,
    ) -> None:
        for name, val in (
            ("model_length", model_length),
            ("prediction_horizon", prediction_horizon),
            ("control_horizon", control_horizon),
        ):
            if isinstance(val, bool) or not isinstance(val, int | np.integer) or val < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {val!r}")
        if model_length < 2:
            raise ValueError(f"model_length must be >= 2, got {model_length}")
        if prediction_horizon > model_length:
            raise ValueError(
                f"prediction_horizon ({prediction_horizon}) must not exceed "
                f"model_length ({model_length})"
            )
        if control_horizon > prediction_horizon:
            raise ValueError(
                f"control_horizon ({control_horizon}) must not exceed "
                f"prediction_horizon ({prediction_horizon})"
            )
        self.N = int(model_length)
        self.P = int(prediction_horizon)
        self.L = int(control_horizon)
        self.q = check_positive("q", q)
        self.r = check_positive("r", r)
        self.jerk_max = check_positive("jerk_max_mps3", jerk_max_mps3, allow_inf=True)
        self.feedforward = bool(feedforward)
        self.v_nominal = (
            None if v_nominal_mps is None else check_nonnegative("v_nominal_mps", v_nominal_mps)
        )
        lo, hi = (check_nonnegative("response_bounds_samples", x) for x in response_bounds_samples)
        if lo > hi:
            raise ValueError(f"response_bounds_samples must be (low, high), got {lo} > {hi}")
        self.t_bounds_samples = (lo, hi)
        self.t_widths_samples = tuple(
            check_nonnegative("response_widths_samples", x) for x in response_widths_samples
        )
        self.eps_y = check_nonnegative("pred_error_bound_mps", pred_error_bound_mps)
        self.delta_y = check_nonnegative("pred_error_width_mps", pred_error_width_mps)
        self.e_tol = check_nonnegative("e_tol_mps", e_tol_mps)
        self.edot_tol = check_nonnegative("edot_tol_mps2", edot_tol_mps2)
        self.combine = check_choice("combine", combine, ("min", "product"))
        self.h_min = check_positive("h_min", h_min)
        if self.h_min > 1.0:
            raise ValueError(f"h_min must lie in (0, 1], got {h_min}")
        self.edot_filter_s = check_nonnegative("edot_filter_s", edot_filter_s)
        self.soft_penalty = check_positive("soft_penalty", soft_penalty)
        self.osqp_eps = check_range("osqp_eps", osqp_eps, 1e-10, 1e-2)
        if not isinstance(classic_law, bool):
            raise ValueError(f"classic_law must be True or False, got {classic_law!r}")
        self.classic_law = classic_law
        self.tail = check_choice("tail", tail, ("model", "linear"))
        self.reference_form = check_choice("reference_form", reference_form, ("level", "error"))
        self.lambda_x = check_nonnegative("position_gain_1ps", position_gain_1ps)
        self.catchup_max = check_nonnegative("catchup_max_mps", catchup_max_mps)
        self.catchup_fade = check_positive("catchup_fade_mps", catchup_fade_mps)
        self.stop_hold = check_nonnegative("stop_hold_mps", stop_hold_mps)
        self.ff_lead = bool(feedforward_lead)
        self.alpha_order = check_choice("alpha_order", alpha_order, ("raise", "clip"))
        self.rules = correction_rules()
        super().__init__(**params)
        self._on_params_changed()

    # -------------------------------------------------------------- params
    def set_params(self, **params: float) -> None:
        old = dict(self._params)
        super().set_params(**params)
        if self.alpha_order == "raise" and self._params["alpha_min"] > self._params["alpha_max"]:
            self._params = old
            self._on_params_changed()  # the derived values follow the rollback
            raise ValueError(
                f"param alpha_min ({params.get('alpha_min', old['alpha_min'])}) must not "
                f"exceed param alpha_max ({params.get('alpha_max', old['alpha_max'])})"
            )

    def _on_params_changed(self) -> None:
        if not hasattr(self, "rules"):
            return
        p = self._params
        self.rules.scale_e = p["k_e"]
        self.rules.scale_ec = p["k_ec"]
        #: (α_min, α_max, γ) of softening_factor(): the effective lower bound
        #: min(α_min, α_max) (α_min > α_max only where alpha_order="clip" let it)
        self._alpha_law = (min(p["alpha_min"], p["alpha_max"]), p["alpha_max"], p["alpha_trend"])
        self._h_law = (p["h0"], p["k_h"])  # h_0, k_h of correction_coefficient()

    # -------------------------------------------------------------- model
    def reset(self, ctx: ControlContext) -> None:
        super().reset(ctx)
        tr = ctx.train
        dt = ctx.dt_s
        self.M = tr.inertial_mass_kg
        ref = ctx.reference
        if self.v_nominal is not None:
            v_nom = self.v_nominal
        else:
            v_nom = ref.end_m / max(ref.duration_s, 1e-9) if ref.duration_s > 0 else 0.0
        self.v_nom = float(v_nom)
        #: linearised Davis slope R'(v_nom) [N s/m]
        self.k_davis = davis_slope(tr.davis_b_Ns_per_m, tr.davis_c_Ns2_per_m2, self.v_nom)
        tau = ctx.actuator_tau_s if ctx.actuator_order else 0.0
        self._shares = input_shares(ctx)
        # rate bound (whole train, acceleration units): comfort jerk and ctx rate limit
        du = self.jerk_max * dt
        if math.isfinite(ctx.du_max_Nps):
            du = min(du, ctx.du_max_Nps * dt / float(np.max(self._shares)) / self.M)
        self.du_max_a = du
        # the model, the dynamic matrix and the QP depend on the train and the timing only
        # (not on the tunable parameters): kept across resets of the same structure, the QP
        # with OSQP's state reset so that every episode is reproducible on its own
        key = (dt, self.k_davis, self.M, tau, ctx.dead_time_s, du, envelope_N(tr, 0.0))
        cached = getattr(self, "_model_cache", None)
        if cached is not None and cached[0] == key:
            _, self.a, self.tail_ratio, self.A_dyn, self.qp = cached
            self.qp.core.reset_solver()
        else:
            self._build_model(ctx, tau)
            self._model_cache = (key, self.a, self.tail_ratio, self.A_dyn, self.qp)
        self.d_gain = self.qp.K[0]
        self._init_step(ctx, tau)

    def _build_model(self, ctx: ControlContext, tau: float) -> None:
        """Step coefficients, tail ratio, dynamic matrix, plan gain and QP of one structure."""
        dt = ctx.dt_s
        kappa = self.k_davis / self.M
        #: step coefficients a_1 … a_N (m/s per m/s² of command)
        self.a = step_response(dt, self.N, kappa_1ps=kappa, tau_s=tau,
                               dead_time_s=ctx.dead_time_s)
        if not np.any(self.a[: self.P] > 0):
            raise ValueError(
                f"dead time {ctx.dead_time_s} s hides the whole prediction horizon "
                f"({self.P} x {dt} s): increase prediction_horizon"
            )
        #: slope ratio of the tail extrapolation (1: linear; e^{−κΔt}: exact for the model)
        self.tail_ratio = tail_ratio(kappa, dt, self.tail)
        #: P × L dynamic matrix
        self.A_dyn = dynamic_matrix(self.a, self.P, self.L, self.tail_ratio)
        lo0, hi0 = envelope_N(ctx.train, 0.0)
        #: the QP on the shared core, with the plan gain K = (AᵀQA + R)⁻¹AᵀQ (L, P)
        self.qp = DMCProblem(
            self.a,
            dmc_gain(self.A_dyn, self.q, self.r, plan=True),
            q=self.q,
            r=self.r,
            du_max=self.du_max_a,
            level_bound=10.0 * max(abs(lo0), abs(hi0)) / self.M,
            soft_penalty=self.soft_penalty,
            osqp_eps=self.osqp_eps,
        )

    @property
    def mpc(self) -> LinearMPC:
        """The QP core (:class:`LinearMPC`) of the current structure."""
        return self.qp.core

    def _init_step(self, ctx: ControlContext, tau: float) -> None:
        """Per-episode state and the per-step constants of :meth:`compute`."""
        dt = ctx.dt_s
        tr = ctx.train
        self._yN0: np.ndarray | None = None  # None until the first step
        self._yN0_buf, self._yN1_buf = np.empty(self.N), np.empty(self.N)
        self._dU_shift = np.zeros(self.L)  # [ΔU*(k−1)_{2…L}, 0]
        self._u_prev2 = 0.0  # u_a(k−2)
        self._ff_prev = 0.0
        self._e_prev: float | None = None
        self._edot = 0.0
        self._kf = dt / (self.edot_filter_s + dt)  # ė filter gain Δt / (T_f + Δt)
        self._w_cache: dict[float, tuple[list[float], list[float]]] = {}
        sp = SetpointPreview(
            ctx.reference,
            dt,
            self.P,
            gain_1ps=self.lambda_x,
            c_max_mps=self.catchup_max,
            fade_mps=self.catchup_fade,
            hold_mps=self.stop_hold if ctx.s_stop_m is not None else 0.0,
        )
        # the same preview as before (same reference and settings): keep the old one,
        # with the time rows it remembers (SetpointPreview.time_row)
        old = getattr(self, "_setpoint", None)
        self._setpoint = old if old is not None and old.same_as(sp) else sp
        self.satisfaction_shape = SatisfactionShape.build(
            dt, self.t_bounds_samples, self.t_widths_samples, self.eps_y, self.delta_y,
            self.e_tol, self.edot_tol, self.combine,
        )
        #: the gradient feedforward is read this far ahead (actuator lag + dead time)
        self._ff_lead = (tau + ctx.dead_time_s) if self.ff_lead else 0.0
        self._mG = tr.mass_kg * G
        self._has_track = bool(ctx.track)
        # comfort jerk bound on the command [N per step]
        self._jerk_du = self.jerk_max * self.M * dt if math.isfinite(self.jerk_max) else None
        # one whole-train input: distribute() on floats
        sh = self._shares
        self._single = ctx.n_inputs == 1 and sh.shape == (1,) and sh[0] == 1.0
        self._du_step = ctx.du_max_Nps * dt if math.isfinite(ctx.du_max_Nps) else None

    # -------------------------------------------------------------- parts of the step
    def reference_preview(self, obs: Observation) -> tuple[float, float, list[float]]:
        """(v_ref(k), y_r(k), y_r(k+1 … k+P)): profile speed now, DMC setpoint and preview."""
        return self._setpoint(obs.t_s, obs.s_m)

    def _feedforward(self, s_m: float, v_mps: float) -> float:
        """:func:`~.laws.feedforward_force` with the gradient read at the look-ahead
        position ``s + max(v, 0) (τ + T_d)`` (0 without feedforward)."""
        if not self.feedforward:
            return 0.0
        ctx = self.ctx
        s_ff = s_m + max(v_mps, 0.0) * self._ff_lead
        theta = float(ctx.track.equivalent_gradient_permil_at(s_ff)) if self._has_track else 0.0
        return feedforward_force(v_mps, ctx.train.resistance_N(v_mps), self.k_davis, self._mG,
                                 theta)

    def _update_prediction(
        self, y: float, u_total_prev: float, ff: float, h_c: float
    ) -> tuple[float, float | None]:
        """(u_a(k−1), e_c): the input level really applied and the prediction error; the
        prediction vector moved by the last move, corrected and shifted in place."""
        M = self.M
        if self._yN0 is None:
            yN0 = self._yN0 = self._yN0_buf
            yN0.fill(y)
            # input memory of the flat ŷ_N0 = y(0): the model's equilibrium level κ y(0)
            self._u_prev2 = self.k_davis * y / M
            return (u_total_prev - ff) / M, None
        u_prev = (u_total_prev - self._ff_prev) / M  # u_a(k−1) as really applied
        yN1 = add_move(self._yN0, self.a, u_prev - self._u_prev2, self._yN1_buf)
        e_c = y - yN1.item(0)
        correct_and_shift(yN1, e_c, h_c, self.tail_ratio, self._yN0)
        self._u_prev2 = u_prev
        return u_prev, e_c

    def _softened(self, y: float, y0_ref: float, y_r: list[float], alpha: float) -> list[float]:
        """The softened reference w (level or error form; α^i cached per α)."""
        weights = self._w_cache.get(alpha)
        if weights is None:  # α mostly sits at its bounds
            weights = softening_weights(alpha, self.P)
            if len(self._w_cache) >= 64:
                self._w_cache.clear()
            self._w_cache[alpha] = weights
        if self.reference_form == "level":
            return softened_reference(y, y_r, alpha, weights)
        return softened_reference_error(y, y0_ref, y_r, alpha, weights)

    def optimise(
        self,
        w: np.ndarray | list[float],
        y_free: np.ndarray | list[float],
        u_prev: float,
        u_lo: np.ndarray | list[float] | float = -np.inf,
        u_hi: np.ndarray | list[float] | float = np.inf,
    ) -> MPCSolution:
        """Solve the DMC QP ``min ‖w − ŷ_P0 − AΔU‖²_Q + ‖ΔU‖²_R`` on the shared core.

        Args (acceleration units, m/s²): ``w`` the softened reference (P,), ``y_free``
        the free response ŷ_P0 (P,), ``u_prev`` the input level u(k−1), ``u_lo``/``u_hi``
        the soft level bounds of stages k … k+P−1 (scalars or (P,)).
        """
        return self.qp.optimise(w, y_free, u_prev, u_lo, u_hi)

    def _plan(
        self,
        w: list[float],
        y_free: list[float],
        u_prev: float,
        y: float,
        y_pred: list[float],
        ff: float,
    ) -> tuple[float, tuple[float, int, float, float, int]]:
        """(u_a(k), solver fields): the first level of the move plan; the plan's moves
        2 … L are kept for the next step's satisfaction."""
        v_plan = [v if v > 0.0 else 0.0 for v in [y, *y_pred[:-1]]]
        tr = self.ctx.train
        M = self.M
        env = None
        if self.classic_law:
            e_w = [w_i - p_i for w_i, p_i in zip(w, y_free, strict=True)]
            dU, lev, env = self.qp.classic_plan(e_w, u_prev, v_plan, tr, ff, M)
            if dU is not None:
                self._dU_shift[:-1] = dU[1:]
                # the core's warm start: what its own unconstrained shortcut leaves
                self.qp.core.adopt_unconstrained(dU, lev.reshape(-1, 1))
                return lev.item(0), UNCONSTRAINED_INFO
        lo, hi = tr.envelope_lists(v_plan) if env is None else env
        sol = self.optimise(w, y_free, u_prev, [(x - ff) / M for x in lo],
                            [(x - ff) / M for x in hi])
        U = sol.U[:, 0]
        np.subtract(U[1:], U[:-1], out=self._dU_shift[:-1])
        return float(sol.u0[0]), (
            sol.solve_time_s, sol.iterations, float(sol.fallback), sol.slack_max,
            sol.status_val,
        )

    def _command(self, u: float, y: float, up_N: np.ndarray, u_total_prev: float) -> np.ndarray:
        """The comfort jerk limit, then the envelope, rate limit and split of distribute()."""
        du = self._jerk_du
        if du is not None:
            u = min(max(u, u_total_prev - du), u_total_prev + du)
        if not self._single:
            return distribute(self.ctx, u, y, up_N, self._shares)
        lo_y, hi_y = envelope_N(self.ctx.train, y)
        return np.array([distribute_single(lo_y, hi_y, u, u_total_prev, self._du_step)])

    # -------------------------------------------------------------- control
    def compute(self, obs: Observation) -> tuple[np.ndarray, Mapping[str, Any]]:
        y = obs.v_mps
        if type(y) is not float or y - y != 0.0:  # x − x is 0 iff x is a finite float
            y = check_finite("measured speed v_mps", y)
        s_m = obs.s_m
        if type(s_m) is not float or s_m - s_m != 0.0:
            check_finite("measured position s_m", s_m)
        v_ref, y0_ref, y_r = self.reference_preview(obs)
        e = y0_ref - y
        if self._e_prev is None:
            self._e_prev = e
        edot = self._edot = filtered_rate(self._edot, e, self._e_prev, self.ctx.dt_s, self._kf)
        self._e_prev = e

        # correction coefficient, feedforward, prediction vector (§3, §5, §6)
        h_c = correction_coefficient(e, edot, self.rules, *self._h_law, self.h_min)
        ff = self._feedforward(s_m, y)
        up_N = obs.u_prev_N
        if type(up_N) is np.ndarray and up_N.shape == (1,):
            u_total_prev = up_N.item(0)
        else:
            u_total_prev = float(np.sum(up_N))
        u_prev, e_c = self._update_prediction(y, u_total_prev, ff, h_c)
        yP0_arr = self._yN0[: self.P]
        yP0 = yP0_arr.tolist()

        # satisfaction, softening factor, softened reference (§2, §4)
        y_pred = predict(yP0_arr, self.A_dyn, self._dU_shift).tolist()
        t_r, mu_t, mu_y, J = satisfaction(e, edot, y_pred, y_r, self.satisfaction_shape)
        alpha = softening_factor(J, *self._alpha_law)
        w = self._softened(y, y0_ref, y_r, alpha)

        # rolling optimisation and command (§2, §6)
        u_a, sol_info = self._plan(w, yP0, u_prev, y, y_pred, ff)
        out = self._command(u_a * self.M + ff, y, up_N, u_total_prev)
        self._ff_prev = ff
        return out, {
            "v_ref": v_ref,
            "setpoint": y0_ref,
            "error": e,
            "error_rate": edot,
            "alpha": alpha,
            "h_c": h_c,
            "J": J,
            "mu_t": mu_t,
            "mu_y": mu_y,
            "t_r": t_r,
            "prediction_error": 0.0 if e_c is None else e_c,
            "u_dmc_N": u_a * self.M,
            "u_ff_N": ff,
            "solve_time_s": sol_info[0],
            "iterations": sol_info[1],
            "fallback": sol_info[2],
            "slack_max": sol_info[3],
            "status_val": sol_info[4],
        }
