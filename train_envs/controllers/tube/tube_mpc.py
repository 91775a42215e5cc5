r"""Paper 001's tube robust MPC (RMPC) for accurate stopping, on the shared OSQP core.

Model, feedback, terminal weight and tightening: :mod:`.model` (001 eq. 8–10, 13,
14–16, 18–20).  Each step the dead-time predicted state ``ξ_0 = x(k+l)`` (eq. 10) is
the initial state of the QP (001 eq. 11–12)::

    min Σ_{i<N} ‖y_i − y_s,i‖²_Q + ‖Δu_i‖²_R + ‖ξ_N − ξ_s,N‖²_P

with ``y = [s, v]``, ``Q = diag(q_s, q_v)`` (the paper's ``diag(0, 0, q1, q2)``),
``R = r_du`` and ``P`` the terminal weight of eq. (19); the core weights stages
``1..N``, so it gets ``P − CᵀQC`` on ξ_N (its cost is the paper's up to the constant
``‖y_0 − y_s,0‖²_Q``).  ξ_s is the reference state [s_r, v_r, a_r − w_ff, a_r − w_ff]
of the profile.  Constraints: the tightened set ``X_i = X ⊖ R_i`` (Chisci et al.'s
"restricted constraints": the shifted plan plus ``K`` times the one-step error is
feasible at the next step) with ``X`` (001 leaves it unspecified; our choice)

* ``s ≤ s_stop + allowance`` (``allowance``: the scenario's ``stop_window_m``),
* ``v ≤ v_limit(s)`` (and ``v ≥ 0`` with ``v_min_row=True``),
* ``u_min ≤ u ≤ u_max`` (``command_box``) and ``|Δu| ≤ jerk_max T`` (hard),

stage rows soft with an exact L1 penalty (``soft_penalty``: a solution without slack
is feasible for the paper's problem), and the terminal set ``X̃_f = Σ ⊖ R_N`` of
eq. (14, 16): the tightened ``s`` (and ``v``) rows along the LQR law's prediction
``ξ_{N+t} = ξ_s,N+t + A_cl^t (ξ_N − ξ_s,N)`` for ``t ∈ terminal_steps``, hard; when it
is unreachable the step is re-solved without it.

Each step first evaluates the unconstrained optimum in closed form
(:mod:`.closed_form`, on the stage vector of :mod:`.stage`); when no row binds it is
the QP's optimum and the core is not called.  The stage vector and the closed forms
run through the table of compiled twins (:func:`train_envs._jit.implementation`,
chosen once per reset; ``compiled_twins`` asks for one side explicitly).  Design
notes and measurements: ``docs/design/tube_mpc.md``.

Sources: paper 001 (Liu, Xun, Gao, Yin, Acta Automatica Sinica 2022), §2; L. Chisci,
J. A. Rossiter, G. Zappa, "Systems with persistent disturbances: predictive control
with restricted constraints", Automatica 37 (2001).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from train_envs._jit import implementation
from train_envs.controllers._common import distribute, input_shares
from train_envs.controllers.base import ControlContext, Controller, Observation, TunableParam
from train_envs.controllers.tube.closed_form import adopt, make_closed_form, weight_coefficients
from train_envs.controllers.tube.model import (
    StoppingModel,
    TubeFeedback,
    core_terminal_basis,
    stopping_model,
    terminal_weight,
    tube_feedback,
    tube_tightening,
)
from train_envs.controllers.tube.problem import BIG, ClosedForm, Limits, TubeProblem
from train_envs.controllers.tube.settings import DEFAULT_W_BOUND_MPS2, TubeSettings
from train_envs.controllers.tube.stage import StageData, StageLayout
from train_envs.mpc import LinearMPC, MPCSolution
from train_envs.mpc.blas import single_thread_blas
from train_envs.plants.lookup import gradient_table
from train_envs.trains import G

__all__ = ["TubeMPC"]

#: the name this module gave the limiter (re-exported by ``controllers.tube_mpc``)
_single_thread_blas = single_thread_blas


class TubeMPC(Controller):
    """Paper 001's tube robust MPC ("rmpc"); see the module docstring for the equations.

    Tunable: ``q_s`` and ``q_v`` (position and speed weights, the paper's q2 and q1),
    ``r_du`` (increment weight R) and ``w_scale`` (the disturbance set W = w_scale ·
    [−w̄, w̄]; 0 gives the nominal MPC).  ``w̄`` (``w_bound_mps2``) defaults to the
    scenario's ``disturbance.random_bound_mps2`` when the factory gets a scenario that
    has one, else :data:`DEFAULT_W_BOUND_MPS2`.

    Structural options: :class:`TubeSettings` (and ``qp_form``, ``osqp_settings`` of the
    core).  ``compiled_twins``: None takes the compiled twins of the stage vector and the
    closed forms where numba is available (the default), True / False asks for the
    twins / their reference implementations (:func:`train_envs._jit.implementation`).
    """

    name = "rmpc"
    PARAMS: tuple[TunableParam, ...] = (
        TunableParam("q_s", 1e-3, 1e3, 1.0, log=True, description="position weight [1/m^2]"),
        TunableParam("q_v", 1e-2, 1e4, 20.0, log=True, description="speed weight [s^2/m^2]"),
        TunableParam("r_du", 1e-3, 1e4, 10.0, log=True, description="increment weight [s^4/m^2]"),
        TunableParam("w_scale", 0.0, 3.0, 1.0, description="disturbance set scale (0 = nominal)"),
    )

    def __init__(
        self,
        scenario: Any = None,
        *,
        N: int = 10,
        w_bound_mps2: float | None = None,
        feedback_weights: Sequence[float] | str = (10.0, 30.0, 10.0),
        jerk_max: float = 1.0,
        soft_penalty: float = 1e3,
        terminal_steps: Sequence[int] = (2, 5, 10, 20, 40),
        tighten: bool = True,
        feas_tol: float = 1e-3,
        overrun_allowance_m: float | None = None,
        qp_form: str = "condensed",
        osqp_settings: Mapping[str, Any] | None = None,
        v_min_row: bool = False,
        terminal_speed_rows: bool = True,
        command_box: str = "soft",
        compiled_twins: bool | None = None,
        **params: float,
    ) -> None:
        if w_bound_mps2 is None:
            dist = getattr(scenario, "disturbance", None)
            rb = float(getattr(dist, "random_bound_mps2", 0.0) or 0.0)
            w_bound_mps2 = rb if rb > 0 else DEFAULT_W_BOUND_MPS2
        fw = feedback_weights if isinstance(feedback_weights, str) else tuple(feedback_weights)
        self.settings = TubeSettings(
            N=N,
            w_bound_mps2=float(w_bound_mps2),
            feedback_weights=fw,
            jerk_max=float(jerk_max),
            soft_penalty=float(soft_penalty),
            terminal_steps=tuple(terminal_steps),
            tighten=bool(tighten),
            feas_tol=float(feas_tol),
            overrun_allowance_m=overrun_allowance_m,
            v_min_row=bool(v_min_row),
            terminal_speed_rows=bool(terminal_speed_rows),
            command_box=command_box,
        )
        if qp_form not in ("auto", "condensed", "sparse"):
            raise ValueError(f"qp_form must be 'auto', 'condensed' or 'sparse', got {qp_form!r}")
        self.N = int(N)
        self.qp_form = qp_form
        self.osqp_settings = dict(osqp_settings or {})
        self.compiled_twins = compiled_twins
        self._problems: dict[int, TubeProblem] = {}
        self._structure_key: tuple | None = None
        self._model: StoppingModel | None = None
        self._keys: tuple | None = None  # (weights key, w̄), refreshed on a parameter change
        super().__init__(**params)

    def _on_params_changed(self) -> None:
        self._keys = None

    # ------------------------------------------------------------------ design
    def _holds(self) -> list[int]:
        """Hold lengths M whose problems this controller needs (RMPC: only 1)."""
        return [1]

    def _horizon(self, M: int) -> int:
        """Prediction horizon of the problem with hold ``M`` (RMPC: N)."""
        return self.N

    def _feedback(self) -> TubeFeedback:
        fw = self.settings.feedback_weights
        if isinstance(fw, str):
            p = self._params
            return tube_feedback(self._model, p["q_s"], p["q_v"], p["r_du"])
        return tube_feedback(self._model, *fw)

    def terminal_weight(self) -> np.ndarray:
        """The paper's terminal weight ``P`` (eq. 19/20) for the current parameters."""
        p = self._params
        fb = self._feedback()
        return terminal_weight(fb.A_cl, fb.K, np.diag([p["q_s"], p["q_v"], 0.0, 0.0]), p["r_du"])

    def _cost_matrices(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Core weights: Q on [s, v, u], S = r_du on Δu, terminal ``P − CᵀQC`` on ξ (made
        once per parameter change and model: every problem of the family shares them);
        ``P − CᵀQC = A_clᵀ P A_cl + r_du KᵀK`` from its pieces
        (:func:`.model.core_terminal_basis`)."""
        return self._costs()[0]

    def _costs(self) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray], np.ndarray, np.ndarray]:
        """``(core weights, terminal basis, closed-form coefficients)`` of the current
        parameters (cached per parameter change and model)."""
        key = (self._current_keys()[0], self._model)
        hit = self.__dict__.get("_cost_cache")
        if hit is not None and hit[0][0] is key[0] and hit[0][1] is key[1]:
            return hit[1]
        p = self._params
        fb = self._feedback()
        basis = core_terminal_basis(fb.A_cl, fb.K)
        P_core = np.tensordot(np.array([p["q_s"], p["q_v"], p["r_du"]]), basis, 1)
        core = (np.diag([p["q_s"], p["q_v"], 0.0]), np.array([[p["r_du"]]]), P_core)
        coef = weight_coefficients(p["q_s"], p["q_v"], p["r_du"], self._beta())
        out = (core, basis, coef)
        self._cost_cache = (key, out)
        return out

    def _beta(self) -> float:
        """The discount of the held stages' cost (RSMPC's β; 1 here)."""
        return 1.0

    def _held(self, M: int) -> tuple[np.ndarray, np.ndarray]:
        """Output stages ``1..Np`` and increments ``0..Np−1`` weighted ``1/β`` (none here)."""
        Np = self._horizon(M)
        return np.zeros(Np, dtype=bool), np.zeros(Np, dtype=bool)

    def _set_cost(self, prob: TubeProblem) -> None:
        """The closed form's weights of ``prob`` (:func:`.closed_form.weight_coefficients`)."""
        core, prob.basis, prob.coef = self._costs()
        prob.P_core = core[2]

    def _sync_qp(self, prob: TubeProblem) -> None:
        """Give the QP core the current weights before it solves (deferred: most steps
        are decided in closed form)."""
        if prob.qp_stale:
            Q, S, P_core = self._cost_matrices()
            with single_thread_blas():
                prob.mpc.set_weights(Q=Q, S=S, P=P_core, stage_scales=self._stage_scales(prob.M))
            prob.qp_stale = False

    def _stage_scales(self, M: int) -> dict[str, np.ndarray] | None:
        """Per-stage multipliers of Q and of the increment weight S (RSMPC's 1/β)."""
        return None

    def _terminal_rows(self, fb: TubeFeedback) -> np.ndarray:
        """Rows ``h A_cl^t`` of the terminal set: s rows, then v rows (if enabled)."""
        rows = []
        for h in (0, 1) if self.settings.terminal_speed_rows else (0,):
            for t in self.settings.terminal_steps:
                rows.append(np.linalg.matrix_power(fb.A_cl, t)[h])
        return np.array(rows).reshape(-1, 4)

    def _make_problem(self, M: int) -> TubeProblem:
        """Build the QP with hold ``M`` (001 eq. 11–14; eq. 25–26 for ``M > 1``)."""
        st = self.settings
        model = self._model
        fb = self._feedback()
        Np = self._horizon(M)
        tight = tube_tightening(model, fb, Np + max(st.terminal_steps, default=0), M)
        Q, S, P_core = self._cost_matrices()
        C = np.zeros((3, 4))
        C[0, 0] = C[1, 1] = C[2, 3] = 1.0
        H_N = self._terminal_rows(fb)
        rate = self._rate
        rho = st.soft_penalty
        rho_u = {"soft": rho, "hard": np.inf, "off": rho}[st.command_box]
        u_lo, u_hi = (-BIG, BIG) if st.command_box == "off" else (self._u_lo, self._u_hi)
        terminal = {"H_N": H_N, "h_N": np.full(H_N.shape[0], BIG)} if H_N.shape[0] else {}
        mpc = LinearMPC(
            model.A,
            model.B,
            C,
            Np=Np,
            Q=Q,
            R=np.zeros((1, 1)),
            S=S,
            P=P_core,
            u_min=[-rate],
            u_max=[rate],
            y_min=[-BIG, 0.0, u_lo],
            y_max=[BIG, BIG, u_hi],
            soft_penalty={"y": [rho, rho, rho_u], "H_N": np.inf},  # hard, see _solve
            delta_u=False,
            form=self.qp_form,
            osqp_settings=self.osqp_settings,
            stage_scales=self._stage_scales(M),
            unconstrained_first=True,
            **terminal,
        )
        prob = TubeProblem(M=M, Np=Np, mpc=mpc, tight=tight, H_N=H_N, held=self._held(M))
        prob.weights_key = self._weights_key()
        self._set_cost(prob)
        return prob

    def _weights_key(self) -> tuple:
        return tuple(sorted((k, v) for k, v in self._params.items() if k != "w_scale"))

    def _w_bar(self) -> float:
        if not self.settings.tighten:
            return 0.0
        return self._params["w_scale"] * self.settings.w_bound_mps2

    def _current_keys(self) -> tuple:
        keys = self._keys
        if keys is None:
            keys = self._keys = (self._weights_key(), self._w_bar())
        return keys

    def _refresh(self, prob: TubeProblem) -> None:
        """Apply parameter changes to one problem lazily (weights, stage scales, W)."""
        key = self._current_keys()[0]
        old = prob.weights_key
        if old is None or any(
            not math.isclose(a[1], b[1], rel_tol=1e-12, abs_tol=0.0)
            for a, b in zip(key, old, strict=True)
        ):
            if isinstance(self.settings.feedback_weights, str):
                # K follows the weights: new tube, terminal rows and QP
                fresh = self._make_problem(prob.M)
                prob.mpc, prob.tight, prob.H_N = fresh.mpc, fresh.tight, fresh.H_N
                prob.frames = None
                prob.qp_stale = False
                prob.w_bar = -1.0  # a new tube: its bounds follow
            else:
                # the tube (fixed K) and the limits are the same: so are the tightened
                # bounds of an unchanged w̄ (TubeProblem.set_disturbance_bound)
                prob.qp_stale = True
            self._set_cost(prob)
            prob.explicit = None
        # (a change below 1e-12 relative -- an env's action round trip -- only updates
        # the key: no rebuild)
        prob.weights_key = key
        wb = self._current_keys()[1]
        if wb != prob.w_bar:
            prob.set_disturbance_bound(wb, self._limits, self.settings)

    def _problem(self, M: int) -> TubeProblem:
        prob = self._problems.get(M)
        if prob is None:
            with single_thread_blas():
                prob = self._problems[M] = self._make_problem(M)
        key, wb = self._current_keys()
        if prob.weights_key is not key or prob.w_bar != wb:
            with single_thread_blas():
                self._refresh(prob)
                self._explicit(prob)  # in the same BLAS block: each entry costs ~µs
        return prob

    # ------------------------------------------------------------------- reset
    def reset(self, ctx: ControlContext) -> None:
        super().reset(ctx)
        self._reset_model_and_limits(ctx)
        self._reset_stage_vector(ctx)
        self._pend = [0.0] * self._l  # commands [m/s²] still in the dead time, oldest first
        self._initialised = False
        self._multi = ctx.n_inputs > 1
        self._shares = input_shares(ctx) if self._multi else None
        self._steps = 0
        self._relaxed = 0  # solves whose terminal set had to be dropped

    def _reset_model_and_limits(self, ctx: ControlContext) -> None:
        """The stopping model and the untightened limits of the episode; the QPs are
        kept across resets of the same problem structure."""
        tr = ctx.train
        self._mi = tr.inertial_mass_kg
        tau = ctx.actuator_tau_s if ctx.actuator_order >= 1 else 0.0
        l = int(round(ctx.dead_time_s / ctx.dt_s))  # noqa: E741
        self._model = stopping_model(ctx.dt_s, tau, l)
        self._l = l
        rate = self.settings.jerk_max * ctx.dt_s
        if math.isfinite(ctx.du_max_Nps):
            rate = min(rate, ctx.du_max_Nps * ctx.n_inputs * ctx.dt_s / self._mi)
        self._rate = rate
        self._u_lo = -tr.max_brake_N(0.0) / self._mi
        self._u_hi = tr.max_traction_N(0.0) / self._mi
        self._v_min = 0.0 if self.settings.v_min_row else -BIG
        allow = self.settings.overrun_allowance_m
        if allow is None:
            allow = float(ctx.extra.get("stop_window_m", 0.5))
        self._s_max = float(ctx.s_stop_m) + allow if ctx.s_stop_m is not None else BIG
        key = (ctx.dt_s, tau, l, rate, self._u_lo, self._u_hi, self._s_max)
        if key != self._structure_key:  # QPs are kept across resets of the same problem
            self._problems = {}
            self._structure_key = key
        for prob in self._problems.values():  # reproducible per seed without a rebuild
            prob.mpc.reset_solver()
        self._limits = Limits(self._rate, self._u_lo, self._u_hi, self._v_min, self._s_max)

    def _reset_stage_vector(self, ctx: ControlContext) -> None:
        """The per-step constants of the stage vector (:mod:`.stage`) and the
        implementations (compiled twin or reference) that fill and read it."""
        tr = ctx.train
        l = self._l  # noqa: E741
        self._prof = ctx.reference.profile
        self._distance_mode = ctx.reference.mode == "distance"
        self._grad = gradient_table(ctx.track) if ctx.track is not None else None
        self._track = ctx.track
        self._ca = tr.davis_a_N / self._mi
        self._cb = tr.davis_b_Ns_per_m / self._mi
        self._cc = tr.davis_c_Ns2_per_m2 / self._mi
        self._cg = tr.mass_kg * G / 1000.0 / self._mi
        n_max = max(self._horizon(M) for M in self._holds())
        self._n_grid = l + n_max + max(self.settings.terminal_steps, default=0) + 2
        self._tgrid = ctx.dt_s * np.arange(self._n_grid)
        g = self._grad
        self._ref_tables = (
            self._prof.t_s,
            self._prof._seg_tbl,
            g.x if g is not None else np.zeros(1),
            np.column_stack([g.y0, g.slope]) if g is not None else np.zeros((1, 2)),
            g is not None,
            self._ca,
            self._cb,
            self._cc,
            self._cg,
        )
        # the compiled twins or their references, chosen once (train_envs._jit)
        twin = self.compiled_twins
        self._fill_reference = implementation("tube.fill_reference", compiled_twin=twin)
        self._closed_form_cost = implementation("tube.closed_form", compiled_twin=twin)
        self._inv_dt = 1.0 / ctx.dt_s
        self._term_idx = np.asarray(self.settings.terminal_steps, dtype=int)
        self._E4 = self._model.E[:, 0].copy()
        self._minus_E4 = -self._E4
        old = getattr(self, "_layout", None)
        if not (
            old is not None
            and old.model is self._model
            and (old.n_grid, old.l, old.inv_dt) == (self._n_grid, l, self._inv_dt)
            and np.array_equal(old.term_idx, self._term_idx)
        ):
            # (the same layout again is kept: the problems' closed-form frames are made
            # per layout object, and a reset of the same structure keeps its problems)
            self._layout = StageLayout(
                self._n_grid, l, self._model, self._inv_dt, self._minus_E4, self._term_idx
            )
        # a line with one speed limit (paper 001): the limit row is the same every step
        lims = None if ctx.track is None else np.unique(ctx.track.speed_limits_mps)
        self._v_lim_const = (
            np.full(self._n_grid, float(lims[0])) if lims is not None and lims.size == 1 else None
        )
        self._v_lim_none = np.full(self._n_grid, BIG)

    # -------------------------------------------------------------- per step
    def _stage_data(self, obs: Observation) -> StageData:
        """The step's stage vector ``h = [1, s, v, a, u_prev, u_pend (l), s_r, v_r, res,
        v_lim]`` (:mod:`.stage`; what the closed forms read); the QP core's per-stage
        arrays are derived from it on first access (:meth:`StageLayout.derive`)."""
        prof = self._prof
        t0 = float(prof.t_at_s(obs.s_m)) if self._distance_mode else obs.t_s
        ng, l = self._n_grid, self._l  # noqa: E741
        o = 5 + l
        h = np.empty(o + 4 * ng)
        self._fill_reference(h, o, self._tgrid, t0, *self._ref_tables)
        s_r = h[o : o + ng]
        mi = self._mi
        up, fo = obs.u_prev_N, obs.forces_N
        # (a single input: its value, as the sum would give it)
        u_prev = (up.item() if up.size == 1 else float(up.sum())) / mi
        if not self._initialised:
            self._pend = [u_prev] * l
            self._initialised = True
        a = (fo.item() if fo.size == 1 else float(fo.sum())) / mi
        if not math.isfinite(obs.s_m + obs.v_mps + a + u_prev):
            raise ValueError(
                f"{self.name}: non-finite measurement (s_m={obs.s_m}, v_mps={obs.v_mps}, "
                f"forces_N={fo.tolist()}, u_prev_N={up.tolist()}); all must be finite"
            )
        h[0] = 1.0
        h[1] = obs.s_m
        h[2] = obs.v_mps
        h[3] = a
        h[4] = u_prev
        h[5:o] = self._pend
        lim = self._v_lim_const
        if lim is None:
            track = self._track
            lim = track.speed_limit_at(s_r) if track is not None else self._v_lim_none
        h[o + 3 * ng :] = lim
        data = StageData(h=h, u_prev=u_prev)
        data.derive = self._layout.derive
        return data

    def _lower_bound(self, prob: TubeProblem, data: Mapping[str, Any]) -> float | None:
        """A lower bound on :meth:`_solve`'s cost (:meth:`TubeProblem.lower_bound`)."""
        self._sync_qp(prob)
        return prob.lower_bound(self._layout, data)

    def _explicit(self, prob: TubeProblem) -> ClosedForm | bool:
        """The problem's closed form (made on first use after a weight or W change)."""
        e = prob.explicit
        if e is None:
            with single_thread_blas():
                e = prob.explicit = make_closed_form(prob, self._layout)
        return e

    def _closed_form(self, prob: TubeProblem, h: np.ndarray) -> tuple[float, bool] | None:
        """``(J, feasible)`` for the stage vector ``h`` of :meth:`_stage_data`: the cost of
        the problem's unconstrained optimum (a lower bound on the QP's cost, equal to it
        when ``feasible``: no row binds, so the optimum is the QP's); None without a
        closed form.  Non-finite data: not feasible."""
        e = prob.explicit
        if e is None:
            e = self._explicit(prob)
        if e is False:
            return None
        return self._closed_form_cost(e.T, e.cols, h, e.b, e.nchk)

    def _adopt(self, prob: TubeProblem, h: np.ndarray) -> float:
        """Take the feasible closed-form optimum for ``h`` as the problem's solution
        (:func:`.closed_form.adopt`); returns the first increment."""
        return adopt(prob, h, self._rate)

    def _solve(self, prob: TubeProblem, data: Mapping[str, Any]) -> MPCSolution:
        """Solve one problem of the family from the stage data (001 eq. 11, 14 / 25–26)."""
        self._sync_qp(prob)
        sol, relaxed = prob.solve(self._layout, data, self._s_max)
        if relaxed:
            self._relaxed += 1
        return sol

    def _command(self, obs: Observation, u_acc: float) -> np.ndarray:
        """Clip to the speed-dependent envelope, remember it for the dead time, to newtons."""
        ctx, mi = self.ctx, self._mi
        v = obs.v_mps
        tr = ctx.train
        u_acc = min(max(u_acc, -tr.max_brake_N(v) / mi), tr.max_traction_N(v) / mi)
        if self._l:
            p = self._pend
            del p[0]
            p.append(u_acc)
        if self._multi:
            return distribute(ctx, u_acc * mi, v, obs.u_prev_N, self._shares)
        return np.array([u_acc * mi])

    def _info(self, sol: MPCSolution) -> dict[str, Any]:
        return {"terminal_relaxed": self._relaxed, **sol.solver_info(), "J": sol.cost}

    def compute(self, obs: Observation) -> tuple[np.ndarray, Mapping[str, Any]]:
        data = self._stage_data(obs)
        prob = self._problem(1)
        self._steps += 1
        h = data["h"]
        ev = self._closed_form(prob, h)
        if ev is not None and ev[1]:  # no row binds: the QP's optimum in closed form
            du0 = self._adopt(prob, h)
            return self._command(obs, data["u_prev"] + du0), {
                "terminal_relaxed": self._relaxed,
                "solve_time_s": 0.0,
                "iterations": 0,
                "fallback": False,
                "slack_max": 0.0,
                "status_val": 1,
                "overhead_s": 0.0,
                "J": ev[0],
            }
        sol = self._solve(prob, data)
        return self._command(obs, data["u_prev"] + float(sol.u0[0])), self._info(sol)
