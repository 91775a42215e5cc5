"""Linear MPC for trains on the shared OSQP core: single-point MPC and paper 000's SEMPC.

Both controllers build a linear prediction model of the train from what the
:class:`~train_envs.controllers.base.ControlContext` says (nominal train, line,
reference, actuator), discretise it **exactly** (zero-order hold, scipy ``expm``) and
hand it to :class:`~train_envs.mpc.LinearMPC` in the Δu-augmented
form ξ = [x; u(k−1)] of papers 000 (eq. 7) and 001 (eq. 9).

Davis resistance is linearised about the reference speed (000 eq. 4,
v² ≈ 2 v_r v − v_r²): ``R(v) ≈ R(v_r) + R'(v_lin) (v − v_r)``. The affine part
``R(v_r,i) − R'(v_lin) v_r,i`` and the gradient force at the reference position are
recomputed **every step for every stage** of the horizon (the affine sequence ``D`` of
the engine); the slope R'(v_lin) sits in the model matrix and is re-linearised (a matrix
value update in OSQP) only when the reference speed has moved more than
``relinearise_mps`` (5 m/s) from v_lin (why that suffices: ``docs/design/mpc_engine.md``).

Terminal cost (SEMPC, 000 §III-B; 001 eq. 11, 20): P is the solution of the discrete
Riccati equation of the augmented model with the stage weights (the doubling iteration
``dare_doubling``, scipy's Schur method as fallback), i.e. the cost-to-go of the LQR
law ``Δu = K ξ``, which satisfies the Lyapunov equation
``A_clᵀ P A_cl − P + Q + Kᵀ R K = 0`` (000 eq. 17–19).
The core weights the model state x at the end of the horizon, so the x-block of P
is used (the u(k−1) block is the cost of a command not yet at its steady value and is
left out). ``terminal=False`` gives the plain MPC of paper 000's comparison.

Offset-free tracking: a disturbance observer (the input-disturbance model of
Muske & Badgwell 2002 / Pannocchia & Rawlings 2003, reduced to one scalar) integrates
the one-step prediction error of the speed into an estimate ŵ of the unknown
per-unit-mass force (wind, load, resistance error), ``ŵ ← ŵ + κ (v_meas − v_pred)/T``
with κ = ``observer_gain`` (0.3), and adds it to the affine term of every stage.
``observer_gain=0`` switches it off.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping
from typing import Any

import numpy as np

from train_envs.controllers._common import distribute, input_shares, per_car_davis
from train_envs.controllers.base import ControlContext, Controller, Observation, TunableParam
from train_envs.controllers.models import (
    coupled_cars_continuous,
    dead_time_maps,
    discretise,
    gradient_accel,
    point_lag_continuous,
    resistance_offset_accel,
)
from train_envs.mpc import LinearMPC, augmented_model, augmented_terminal_cost, dare_doubling, zoh
from train_envs.mpc.blas import single_thread_blas
from train_envs.plants.lookup import gradient_table
from train_envs.plants.physics import davis_horner_N, davis_slope
from train_envs.trains import G
from train_envs.validation import check_range

__all__ = [
    "MultiCarMPC",
    "PointMassMPC",
    "augmented_terminal_cost",
    "dare_doubling",
    "zoh",
]


class _TrainMPCBase(Controller):
    """Shared plumbing: options, terminal weight, weight updates only when values change.

    Options (keywords of both controllers): ``Np`` horizon, ``terminal`` (augmented
    Riccati terminal cost), ``feedforward`` (``"full"``, ``"gradient"``, ``"none"``),
    ``relinearise_mps`` (5 m/s), ``soft_penalty`` (1e3), ``observer_gain`` (0.3),
    ``unconstrained_first`` (try the exact unconstrained optimum before OSQP); any
    other keyword is a tunable parameter.
    """

    def __init__(
        self,
        *,
        Np: int,
        terminal: bool = True,
        feedforward: str = "full",
        relinearise_mps: float = 5.0,
        soft_penalty: float = 1e3,
        observer_gain: float = 0.3,
        unconstrained_first: bool = True,
        **params: float,
    ) -> None:
        if feedforward not in ("full", "gradient", "none"):
            raise ValueError(
                f"feedforward must be 'full', 'gradient' or 'none', got {feedforward!r}"
            )
        if int(Np) < 1:
            raise ValueError(f"Np must be >= 1, got {Np}")
        self.Np = int(Np)
        self.terminal = bool(terminal)
        self.feedforward = feedforward
        self.observer_gain = float(observer_gain)
        self.relinearise_mps = float(relinearise_mps)
        self.soft_penalty = float(soft_penalty)
        #: try the exact unconstrained optimum before OSQP (see LinearMPC)
        self.unconstrained_first = bool(unconstrained_first)
        self._mpc: LinearMPC | None = None
        self._weights_key: tuple | None = None
        super().__init__(**params)

    def _apply_weights(self) -> None:
        with single_thread_blas():
            Q, R, P = self._weights()
            # Q, R diagonal from the checked parameters, P a Riccati solution: the
            # engine's checks of public weights are not repeated
            self._mpc.replace_weights(Q=Q, R=R, P=P)
        self._weights_key = tuple(sorted(self._params.items()))

    def _terminal_weight(self, Q: np.ndarray, R: np.ndarray) -> np.ndarray | None:
        """Augmented-Riccati terminal cost of the stage weights (None without ``terminal``;
        the augmented model is kept per discretisation)."""
        if not self.terminal:
            return None
        C = self._C
        aug = self.__dict__.get("_aug_model")
        if aug is None or aug[0] is not self._Ad or aug[1] is not self._Bd:
            aug = self._aug_model = (self._Ad, self._Bd, augmented_model(self._Ad, self._Bd))
        _, _, P = augmented_terminal_cost(
            self._Ad, self._Bd, C.T @ Q @ C, R, gain=False, model=aug[2]
        )
        return P

    def _on_params_changed(self) -> None:
        # rebuild the QP only for a real change: an env maps its action back onto the
        # parameters with rounding (1e-16 relative), which must not cost a rebuild
        if getattr(self, "_mpc", None) is not None:
            key = tuple(sorted(self._params.items()))
            old = self._weights_key
            if old is None or any(
                not math.isclose(a[1], b[1], rel_tol=1e-12, abs_tol=0.0)
                for a, b in zip(key, old, strict=True)
            ):
                self._apply_weights()


class PointMassMPC(_TrainMPCBase):
    """Linear MPC of a single-point train with actuator lag and dead time.

    Model (acceleration units, M' = M(1+ρ); 001 eq. 8–10 with the resistance as a
    known affine term, or 000 eq. 5 for one car)::

        ṡ = v,   v̇ = a − k_v v + w(t),   ȧ = (a_cmd − a)/τ        (τ > 0)
        k_v = R'(v_lin)/M',   w = −(R(v_r) − R'(v_lin) v_r + M g θ(s_r)/1000)/M'

    Outputs y = [s, v] tracked against the reference (time-indexed: s_ref(t), v_ref(t);
    distance-indexed: along the profile from the current position). Dead time
    T_d = l·dt (001 eq. 9–10): the state is first predicted l steps ahead with the
    commands already sent, and the MPC is solved from x(k+l). Constraints: hard
    command box (traction/brake envelope) and rate (``du_max_Nps`` of the scenario or
    the comfort jerk limit ``jerk_max``, whichever is tighter); soft
    ``0 ≤ v ≤ v_limit(s_r,i)`` and ``s ≤ s_stop`` (000 eq. 11, 13). Tunable: the
    weights q_s, q_v (outputs) and r_du (increments).

    ``feedforward``: ``"full"`` uses the nominal Davis resistance and the line's
    gradient in w (paper 001's *ideal* MPC when the plant is nominal), ``"gradient"``
    the gradient only, ``"none"`` neither (resistance is then a disturbance, as in
    001's robust MPCs).
    """

    name = "mpc"
    PARAMS = (
        TunableParam("q_s", 1e-4, 1e2, 0.1, log=True, description="position weight [1/m^2]"),
        TunableParam("q_v", 1e-2, 1e4, 20.0, log=True, description="speed weight [s^2/m^2]"),
        TunableParam("r_du", 1e-3, 1e4, 10.0, log=True, description="increment weight [s^4/m^2]"),
    )

    def __init__(
        self,
        scenario: Any = None,
        *,
        Np: int = 10,
        jerk_max: float = 1.0,
        **options: Any,
    ) -> None:
        # a zero rate pins the command at its start value (the train never moves)
        self.jerk_max = check_range("jerk_max", jerk_max, 0.0, 100.0, low_inclusive=False)
        super().__init__(Np=Np, **options)

    # ----------------------------------------------------------------- model
    def _continuous(self, v_lin: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        tr = self.ctx.train
        mi = tr.inertial_mass_kg
        kv = davis_slope(tr.davis_b_Ns_per_m, tr.davis_c_Ns2_per_m2, max(v_lin, 0.0)) / mi
        if self.feedforward == "none":
            kv = 0.0
        return point_lag_continuous(kv, self.ctx.actuator_tau_s if self._lag else 0.0)

    def _discretise(self, v_lin: float) -> None:
        Ad, Bd, Ed = discretise(*self._continuous(v_lin), self.ctx.dt_s)
        self._Ad, self._Bd, self._Ed = Ad, Bd, Ed[:, 0]
        self._v_lin = v_lin
        # dead-time prediction in one shot (001 eq. 10): x(k+l) = A^l x + B_l u_pend + E_l w
        nd = getattr(self, "_l", 0)
        if nd:
            self._Al, self._Bl, self._El = dead_time_maps(Ad, Bd[:, 0], Ed[:, 0], nd)

    def _weights(self) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        p = self._params
        Q = np.zeros((2, 2))
        Q[0, 0], Q[1, 1] = p["q_s"], p["q_v"]
        R = np.array([[p["r_du"]]])
        return Q, R, self._terminal_weight(Q, R)

    def reset(self, ctx: ControlContext) -> None:
        super().reset(ctx)
        tr = ctx.train
        self._mi = tr.inertial_mass_kg
        self._lag = ctx.actuator_order >= 1 and ctx.actuator_tau_s > 0
        n = 3 if self._lag else 2
        self._C = np.zeros((2, n))
        self._C[0, 0] = 1.0
        self._C[1, 1] = 1.0
        self._l = int(round(ctx.dead_time_s / ctx.dt_s))
        v0 = float(ctx.reference.profile.v_mps[0])
        self._discretise(max(v0, 1.0))
        Q, R, P = self._weights()
        dt = ctx.dt_s
        rate = self.jerk_max * dt
        if math.isfinite(ctx.du_max_Nps):
            rate = min(rate, ctx.du_max_Nps * ctx.n_inputs * dt / self._mi)
        a_max = tr.max_traction_N(0.0) / self._mi
        a_min = -tr.max_brake_N(0.0) / self._mi
        big = 1e6
        # position ≤ stop point and speed ≤ limit: static bounds when the line has one
        # speed limit (paper 001), otherwise written per step from the horizon's limits
        track = ctx.track
        limits = None if track is None else np.unique(track.speed_limits_mps)
        self._static_ymax = track is None or limits.size == 1
        y_max = [big if ctx.s_stop_m is None else float(ctx.s_stop_m), big]
        if track is not None and limits.size == 1:
            y_max[1] = float(limits[0])
        self._mpc = LinearMPC(
            self._Ad,
            self._Bd,
            self._C,
            Np=self.Np,
            Q=Q,
            R=R,
            P=P if P is not None else None,
            u_min=[a_min],
            u_max=[a_max],
            du_min=[-rate],
            du_max=[rate],
            y_min=[-big, 0.0],
            y_max=y_max,
            soft_penalty=self.soft_penalty,
            unconstrained_first=self.unconstrained_first,
        )
        self._weights_key = tuple(sorted(self._params.items()))
        self._pending: deque[float] = deque([0.0] * self._l, maxlen=max(self._l, 1))
        self._initialised = False
        self._w_hat = 0.0
        self._v_pred: float | None = None  # one-step speed prediction (observer)
        self._yref_buf = np.zeros((self.Np, 2))
        self._ymax_buf = np.full((self.Np, 2), 1e6)
        if ctx.s_stop_m is not None:
            self._ymax_buf[:, 0] = ctx.s_stop_m
        # constants of the per-stage affine term (see _preview)
        self._ff_full = self.feedforward == "full"
        use_grad = self.feedforward in ("full", "gradient") and ctx.track is not None
        self._grad_tab = gradient_table(ctx.track) if use_grad else None
        self._k_grad = tr.mass_kg * G / 1000.0 / self._mi
        self._prof = ctx.reference.profile
        self._distance_mode = ctx.reference.mode == "distance"
        self._dt = ctx.dt_s
        self._D_buf = np.zeros((self.Np, self._Ad.shape[0]))
        self._up_buf = np.zeros(1)

    # --------------------------------------------------------------- helpers
    def _observe(self, x: np.ndarray) -> None:
        """Disturbance observer: integrate the one-step speed prediction error."""
        if self._v_pred is not None and self.observer_gain > 0:
            innov = float(x[1]) - self._v_pred
            self._w_hat += self.observer_gain * innov / float(self._Ed[1])
            self._w_hat = min(max(self._w_hat, -1.0), 1.0)

    def _preview(self, t: float, s: float, n: int) -> tuple[list, list, list]:
        """Reference ``(s_r, v_r)`` and affine acceleration ``w`` of stages 1..n (floats).

        Stages start at time ``t`` (time-indexed reference) or at the profile time of
        position ``s`` (distance-indexed).  ``w = ŵ − (R(v_r) − R'(v_lin) v_r)/M' −
        M g θ(s_r)/(1000 M')`` with the Davis constant term only where v_r > 0 (at
        standstill resistance cannot drive); plain floats, no numpy calls on the
        few-element arrays of a short horizon.
        """
        t0 = self._prof.t_at_s(s) if self._distance_mode else t
        s_r, v_r = self._prof.sample_sv(t0, self._dt, n)
        w_hat = self._w_hat
        grad = self._grad_tab
        kg = self._k_grad
        if self._ff_full:
            tr = self.ctx.train
            a, c, mi = tr.davis_a_N, tr.davis_c_Ns2_per_m2, self._mi
            bs = tr.davis_b_Ns_per_m - davis_slope(tr.davis_b_Ns_per_m, c, self._v_lin)
            if grad is not None:
                w = [
                    w_hat - davis_horner_N(a * (v > 0.0), bs, c, v) / mi - kg * grad(s)
                    for s, v in zip(s_r, v_r, strict=True)
                ]
            else:
                w = [w_hat - davis_horner_N(a * (v > 0.0), bs, c, v) / mi for v in v_r]
        elif grad is not None:
            w = [w_hat - kg * grad(s) for s in s_r]
        else:
            w = [w_hat] * n
        return s_r, v_r, w

    # --------------------------------------------------------------- control
    def compute(self, obs: Observation) -> tuple[np.ndarray, Mapping[str, Any]]:
        ctx = self.ctx
        mi = self._mi
        u_prev = float(obs.u_prev_N.sum()) / mi
        if not self._initialised:
            self._pending = deque([u_prev] * self._l, maxlen=max(self._l, 1))
            self._initialised = True
        s_m, v_m = float(obs.s_m), float(obs.v_mps)
        if self._lag:
            x = np.array([s_m, v_m, float(obs.forces_N.sum()) / mi])
        else:
            x = np.array([s_m, v_m])
        self._observe(x)
        x_meas = x
        t = obs.t_s
        l = self._l  # noqa: E741
        # predict across the dead time with the commands already sent (001 eq. 10)
        if l:
            _, _, w = self._preview(t - ctx.dt_s, s_m, l)
            u_pend = np.fromiter(self._pending, float, l)
            x = self._Al @ x + self._Bl @ u_pend + self._El @ w
            t = t + l * ctx.dt_s
        s_r, v_r, w_r = self._preview(t, float(x[0]), self.Np)
        v_now = v_r[0]
        if abs(v_now - self._v_lin) > self.relinearise_mps:
            # new slope in the model; the terminal weight (a function of the weights
            # and, weakly, of the slope) is refreshed with the next weight change
            self._discretise(max(v_now, 0.0))
            self._mpc.set_model(self._Ad, self._Bd)
            s_r, v_r, w_r = self._preview(t, float(x[0]), self.Np)
        D = self._D_buf
        np.multiply(np.array(w_r)[:, None], self._Ed, out=D)
        y_ref, y_max = self._yref_buf, self._ymax_buf
        y_ref[:, 0] = s_r
        y_ref[:, 1] = v_r
        if self._static_ymax:
            y_max = None
        else:
            limit = ctx.track.speed_limit_at
            y_max[:, 1] = [limit(si) for si in s_r]
        self._up_buf[0] = u_prev
        sol = self._mpc.solve(x, self._up_buf, y_ref, d=D, y_max=y_max)
        a_cmd = float(sol.u0[0])
        # the speed-dependent envelope (power limit) is tighter than the QP's static box
        tr = ctx.train
        a_cmd = min(max(a_cmd, -tr.max_brake_N(v_m) / mi), tr.max_traction_N(v_m) / mi)
        # one-step prediction of the next measurement, for the disturbance observer
        # (the affine term of the coming interval, ŵ included: the dead-time prediction's
        # first stage when there is a dead time)
        if l:
            u_act = self._pending[0]
            w_1 = w[0]
        else:
            u_act = a_cmd
            w_1 = self._preview(obs.t_s - ctx.dt_s, s_m, 1)[2][0]
        self._v_pred = (
            float(np.dot(self._Ad[1], x_meas))
            + float(self._Bd[1, 0]) * u_act
            + float(self._Ed[1]) * w_1
        )
        if l:
            self._pending.append(a_cmd)
        if ctx.n_inputs > 1:
            u = distribute(ctx, a_cmd * mi, v_m, obs.u_prev_N, input_shares(ctx))
        else:
            u = np.array([a_cmd * mi])
        return u, sol.solver_info()


class MultiCarMPC(_TrainMPCBase):
    """Linear MPC of the n-car train with per-car forces: paper 000's SEMPC and MPC.

    Model (000 eq. 1–7, with our sign conventions and exact ZOH instead of the paper's
    forward Euler, which is unstable for its own coupler mode ω = sqrt(2k/m) = 17.6
    rad/s at any T > 2/ω = 0.11 s)::

        q̇_i = v_i
        m_i' v̇_i = 1000 u_i + f_{i−1} − f_i − R_i'(v_lin) v_i + m_i' w_i(t)
        f_j = k (q_j − q_{j+1}) + d (v_j − v_{j+1})

    with q_i the car positions shifted by the rest spacing (q_j − q_{j+1} is coupler j's
    deformation), u_i the force of car i in kN (scaled for the QP's conditioning) and
    w_i the per-stage affine term (Davis about v_r, gradient at s_r; see the module
    docstring). Outputs, as 000's relative-state formulation (eq. 5):
    y = [x_1, δ_1..δ_{n−1}, v_1, v_1−v_2, …, v_{n−1}−v_n], tracked against
    [s_ref, 0, …, v_ref, 0, …] (000 eq. 10). Constraints: hard per-car force box and
    rate (000 eq. 14–15), soft 0 ≤ x_1 ≤ x_stop (11), |δ_j| ≤ l_safe (12),
    0 ≤ v_1 ≤ v_max(s) (13). With ``terminal=True`` (SEMPC) the augmented Riccati
    terminal cost is added (000 §III-B); ``terminal=False`` is 000's plain MPC. Each QP
    first tries the exact unconstrained optimum (``unconstrained_first`` of
    :class:`LinearMPC`): on 000's single section no row binds at 98 % of the steps, and
    OSQP runs for the rest.

    Tunable: q_s (lead position), q_v (lead speed), q_dx (coupler deformations),
    q_dv (relative speeds), r_du (force increments, per kN²). Paper 000's own weights
    (Q = diag(0.5, 1e12…, 1e9, 1e12…), R = 1e−5 I on N) are available as
    :data:`PAPER000_WEIGHTS` (converted to kN); their 1e12 spread is beyond what a
    first-order QP solver resolves at 1e−6 tolerances, see the reproduction notes.
    """

    name = "sempc"
    PARAMS = (
        TunableParam("q_s", 1e-4, 1e2, 2.0, log=True, description="lead position weight [1/m^2]"),
        TunableParam("q_v", 1e-2, 1e4, 100.0, log=True, description="lead speed weight [s^2/m^2]"),
        TunableParam("q_dx", 1e0, 1e8, 1e4, log=True, description="coupler deformation weight"),
        TunableParam("q_dv", 1e-2, 1e6, 1e2, log=True, description="relative speed weight"),
        TunableParam(
            "r_du", 1e-6, 1e2, 1e-2, log=True, description="force increment weight [1/kN^2]"
        ),
    )

    def __init__(
        self,
        scenario: Any = None,
        *,
        Np: int = 3,
        terminal: bool = True,
        **options: Any,
    ) -> None:
        super().__init__(Np=Np, terminal=terminal, **options)
        if not terminal:
            self.name = "mpc000"

    def _discretise(self, v_lin: float) -> None:
        ctx, n = self.ctx, self._n
        tr = ctx.train
        k, d = tr.coupler.stiffness_N_per_m, tr.coupler.damping_Ns_per_m
        slope = davis_slope(self._cb, self._cc, max(v_lin, 0.0))
        if self.feedforward == "none":
            slope = np.zeros(n)
        Ac, Bc, Ec = coupled_cars_continuous(k, d, self._mi, slope)
        self._Ad, self._Bd, self._Ed = discretise(Ac, Bc, Ec, ctx.dt_s)
        self._v_lin = v_lin
        self._slope = slope

    def _weights(self):
        p, n = self._params, self._n
        Q = np.diag([p["q_s"]] + [p["q_dx"]] * (n - 1) + [p["q_v"]] + [p["q_dv"]] * (n - 1))
        R = p["r_du"] * np.eye(n)
        return Q, R, self._terminal_weight(Q, R)

    def reset(self, ctx: ControlContext) -> None:
        super().reset(ctx)
        tr = ctx.train
        n = ctx.n_cars
        if ctx.n_inputs != n:
            raise ValueError(
                f"{self.name} needs per-car inputs (n_inputs == n_cars = {n}), got {ctx.n_inputs}"
            )
        self._n = n
        self._m, self._mi, self._ca, self._cb, self._cc = per_car_davis(tr)
        C = np.zeros((2 * n, 2 * n))
        C[0, 0] = 1.0
        for j in range(n - 1):
            C[1 + j, j], C[1 + j, j + 1] = 1.0, -1.0
            C[n + 1 + j, n + j], C[n + 1 + j, n + j + 1] = 1.0, -1.0
        C[n, n] = 1.0
        self._C = C
        v0 = float(ctx.reference.profile.v_mps[0])
        self._discretise(max(v0, 1.0))
        Q, R, P = self._weights()
        ex = ctx.extra
        u_max = float(ex.get("u_max_car_N", tr.max_traction_N(0.0) / n)) / 1000.0
        u_min = float(ex.get("u_min_car_N", -tr.max_brake_N(0.0) / n)) / 1000.0
        du = float(ex.get("du_max_car_Nps", ctx.du_max_Nps))
        du = du * ctx.dt_s / 1000.0 if math.isfinite(du) else np.inf
        l_safe = float(ex.get("l_safe_m", 0.2))
        big = 1e6
        y_min = np.r_[0.0, np.full(n - 1, -l_safe), 0.0, np.full(n - 1, -big)]
        y_max = np.r_[big, np.full(n - 1, l_safe), big, np.full(n - 1, big)]
        self._y_min, self._y_max = y_min, y_max
        self._mpc = LinearMPC(
            self._Ad,
            self._Bd,
            C,
            Np=self.Np,
            Q=Q,
            R=R,
            P=P,
            u_min=np.full(n, u_min),
            u_max=np.full(n, u_max),
            du_min=np.full(n, -du),
            du_max=np.full(n, du),
            y_min=y_min,
            y_max=y_max,
            soft_penalty=self.soft_penalty,
            unconstrained_first=self.unconstrained_first,
        )
        self._weights_key = tuple(sorted(self._params.items()))
        self._yref = np.zeros((self.Np, 2 * n))
        self._w_hat = 0.0
        self._x_pred: np.ndarray | None = None

    def _affine(self, s_r: np.ndarray, v_r: np.ndarray) -> np.ndarray:
        """Per-stage, per-car affine accelerations w (Np, n)."""
        w = np.full((v_r.shape[0], self._n), self._w_hat)
        if self.feedforward == "full":
            w -= resistance_offset_accel(self._ca, self._cb, self._cc, self._slope, self._mi, v_r)
        if self.feedforward in ("full", "gradient") and self.ctx.track is not None:
            theta = gradient_table(self.ctx.track)(s_r)[:, None]
            w -= gradient_accel(self._m, self._mi, theta)
        return w

    def compute(self, obs: Observation) -> tuple[np.ndarray, Mapping[str, Any]]:
        ctx, n = self.ctx, self._n
        spacing = ctx.train.coupler.rest_length_m
        q = obs.positions_m + np.arange(n) * spacing
        x = np.concatenate([q, obs.speeds_mps])
        if self._x_pred is not None and self.observer_gain > 0:
            # disturbance observer: a common per-unit-mass disturbance on all cars
            innov = float(np.mean(x[n:] - self._x_pred[n:]))
            gain = float(np.mean(np.diag(self._Ed[n:, :])))
            self._w_hat = min(max(self._w_hat + self.observer_gain * innov / gain, -1.0), 1.0)
        ts = obs.t_s + ctx.dt_s * np.arange(1, self.Np + 1)
        prof = ctx.reference.profile
        s_r = np.asarray(prof.s_at_t(ts), float)
        v_r = np.asarray(prof.v_at_t(ts), float)
        if abs(float(v_r[0]) - self._v_lin) > self.relinearise_mps:
            self._discretise(max(float(v_r[0]), 0.0))
            self._mpc.set_model(self._Ad, self._Bd)
        D = self._affine(s_r, v_r) @ self._Ed.T
        yref = self._yref
        yref[:, 0] = s_r
        yref[:, n] = v_r
        y_max = np.tile(self._y_max, (self.Np, 1))
        if ctx.s_stop_m is not None:
            y_max[:, 0] = ctx.s_stop_m
        if ctx.track is not None:
            y_max[:, n] = np.asarray(ctx.track.speed_limit_at(s_r), float)
        u_prev = np.asarray(obs.u_prev_N, float) / 1000.0
        sol = self._mpc.solve(x, u_prev, yref, d=D, y_max=y_max)
        self._x_pred = self._Ad @ x + self._Bd @ sol.u0 + D[0]
        info = sol.solver_info()
        info["w_hat"] = self._w_hat
        return sol.u0 * 1000.0, info
