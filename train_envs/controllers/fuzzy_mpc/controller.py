"""Paper 003's fuzzy constrained predictive cruise controller (+ actuator compensator).

Per step: measure the coupler displacements δ and speed errors e about the reference
v_r, map them to the scaled reduced state x (:class:`ReducedTrainModel`), weigh the
rules by the memberships h(e_1) (:class:`TriangularMemberships`), and command

    u_d = clip(u^eq + M' Φ_r Σ_j h_j F_j x, envelope),   u = compensator(u_d)

with the PDC gains F_j of the last LMI solve (:class:`KothareLMI`) and the equilibrium
force ``u^eq = R_i(v_r) + m_i g θ_i/1000 [+ m_i' a_r]`` (``feedforward="full"`` adds the
reference acceleration for ramp references; ``"resistance"`` is 003 eq. 5).

**When the LMI is re-solved (ours).** (a) the state leaves the cached invariant
ellipsoid (a reference step) further than its gains allow: the cached solution scaled
by the level L = xᵀQ⁻¹x > 1, (L·Q, L·Y_j, L·γ), satisfies every LMI but the input one
with the same gains F_j, so if the cached gains keep every car's force deviation within
the current ū on the enlarged ellipsoid (``L · (C_u F_j Q F_jᵀ C_uᵀ)_ll ≤ ū_l²``) the
scaled solution is kept instead of a re-solve (invariance and input bound hold, the
cost bound is L·γ; ``enlarge_outside=False`` re-solves at every departure, as
``train-envs reproduce paper003`` does); (b) it has shrunk to ``xᵀQ⁻¹x < resolve_shrink``
(Kothare's receding horizon: a smaller ellipsoid allows stronger gains; not once the
state is inside the ρ-ball); (c) v_r moved by more than ``resolve_dv_mps`` since the
last solve (the rule matrices depend on v_r); (d) new weights, see below; (e) every
``lmi_period`` steps if ``lmi_period > 0`` (``lmi_period=1`` is Kothare's
solve-every-step scheme). Between solves the cached PDC gains are used with the
current memberships; by invariance of the cached ellipsoid they still satisfy the
constraints (nominal model). If every solver setting fails the cached gains are kept
(an LQR gain of the middle rule before the first success) and the solve is retried
10 steps later.

**When new weights take effect (ours).** At the next re-solve (a)-(c), (e), and at the
latest ``weights_delay_steps`` (100) control steps after the first change not yet taken
(``0``: at once, one LMI solve per change). Until then the cached PDC gains of the last
feasible solve stay in use: the invariance of their ellipsoid and the constraints they
satisfy do not depend on the weights (which enter only the cost bound γ), so the
guarantees hold; only optimality refers to the earlier weights. An RL agent changing
the weights at every env step pays a few LMI solves per episode, not one per step.

**Defaults (ours; 003's weight units were lost).** q_v = 0.5 (003's value) per (m/s)²,
r_e = 0.02 per kN², q_dx = 1e-3 per cm², c_1 = c_2 = 3 1/s, ε = ±15 m/s (covers 003's
50 km/h step), one coupler mode. The compensator's ω_n and ζ come from the scenario
given to the constructor (``scenario.actuator``), else from
``ctx.extra["actuator_omega_n_radps"/"actuator_zeta"]``, else from the constructor
arguments; ``compensator=False`` or an actuator of order ≠ 2 passes u_d through.
Design notes and measurements: ``docs/design/fuzzy_mpc.md``.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from train_envs.controllers._common import per_car_davis
from train_envs.controllers.base import ControlContext, Controller, Observation, TunableParam
from train_envs.controllers.fuzzy_mpc.compensator import BacksteppingCompensator
from train_envs.controllers.fuzzy_mpc.lmi import KothareLMI, LMISolution
from train_envs.controllers.fuzzy_mpc.memberships import TriangularMemberships
from train_envs.controllers.fuzzy_mpc.model import ReducedTrainModel
from train_envs.mpc import terminal_cost_dare
from train_envs.plants.lookup import gradient_table
from train_envs.plants.physics import davis_N
from train_envs.trains import G
from train_envs.validation import check_range

__all__ = ["FuzzyMPCController"]


class FuzzyMPCController(Controller):
    """Paper 003's fuzzy constrained predictive controller (+ actuator compensator).

    See the module docstrings of the package for the equations. Per-car inputs are required
    (``ctx.n_inputs == ctx.n_cars``).

    Args:
        scenario: the scenario (its ``actuator`` gives ω_n, ζ for the compensator).
        compensator: pass the designed force through the backstepping compensator when
            the actuator is second order.
        n_modes: coupler modes kept in the design model (``None`` = all, slow).
        centres_mps: membership centres of the lead-car speed error [m/s].
        lmi_period: also re-solve every this many steps (0 = only on events, 1 = every
            step as in Kothare et al.).
        resolve_shrink: re-solve once ``xᵀQ⁻¹x`` falls below this (0 = never).
        resolve_dv_mps: re-solve once v_r moved by this much since the last solve.
        weights_delay_steps: new weights are taken by a re-solve at the latest this
            many control steps after they were set (0 = at once; see the module docstring).
        floor: ρ, radius of the ball the ellipsoid must contain (scaled units).
        feedforward: ``"full"`` (resistance + gradient + reference acceleration, for ramp
            references) or ``"resistance"`` (003 eq. 5: resistance + gradient only).
        u_bound_N: bound on each car's force deviation from equilibrium [N] (003's
            "usual and simplified" input constraint); ``None`` = the car's envelope.
        omega_n_radps, zeta: actuator values used when neither the scenario nor
            ``ctx.extra`` gives them.
    """

    name = "fuzzy_mpc"
    PARAMS = (
        TunableParam("q_v", 1e-3, 1e3, 0.5, log=True, description="speed-error weight [s^2/m^2]"),
        TunableParam(
            "q_dx", 1e-4, 1e2, 1e-3, log=True, description="coupler displacement weight [1/cm^2]"
        ),
        TunableParam(
            "r_e", 1e-5, 1e1, 0.02, log=True, description="energy (force) weight [1/kN^2]"
        ),
        TunableParam("c1", 0.1, 3.0, 3.0, description="compensator gain of F - u_d [1/s]"),
        TunableParam("c2", 0.1, 3.0, 3.0, description="compensator gain of the rate error [1/s]"),
    )
    _WEIGHTS = ("q_v", "q_dx", "r_e")
    #: when a parameter change acts (shown on the env contract pages)
    PARAMS_TAKE_EFFECT = (
        "`c1`, `c2` act at the next control step. The weights `q_v`, `q_dx`, `r_e` act "
        "at the next LMI re-solve: one that an event triggers anyway (the state leaves "
        "or has shrunk inside the cached invariant ellipsoid, the reference speed moved), "
        "at the latest `weights_delay_steps` (default 100) control steps after the first change "
        "not yet taken. Until then the PDC gains of the last feasible solve stay in use; "
        "their invariant ellipsoid and the input bounds it certifies do not depend on the "
        "weights, so only optimality refers to the earlier weights."
    )

    def __init__(
        self,
        scenario: Any = None,
        *,
        compensator: bool = True,
        n_modes: int | None = 1,
        centres_mps: Sequence[float] = (-15.0, 15.0),
        lmi_period: int = 0,
        resolve_shrink: float = 0.25,
        resolve_dv_mps: float = 1.0,
        enlarge_outside: bool = True,
        weights_delay_steps: int = 100,
        floor: float = 0.05,
        feedforward: str = "full",
        u_bound_N: float | None = None,
        omega_n_radps: float = 2.0,
        zeta: float = 0.8,
        **params: float,
    ) -> None:
        if feedforward not in ("full", "resistance"):
            raise ValueError(f"feedforward must be 'full' or 'resistance', got {feedforward!r}")
        if int(lmi_period) != lmi_period or lmi_period < 0:
            raise ValueError(f"lmi_period must be an integer >= 0, got {lmi_period}")
        if n_modes is not None and (int(n_modes) != n_modes or n_modes < 0):
            raise ValueError(f"n_modes must be None or an integer >= 0, got {n_modes}")
        self.compensator = bool(compensator)
        self.n_modes = None if n_modes is None else int(n_modes)
        self.memberships = TriangularMemberships(tuple(centres_mps))
        self.lmi_period = int(lmi_period)
        #: keep the cached gains on a certified enlargement of the ellipsoid (rule (a))
        self.enlarge_outside = bool(enlarge_outside)
        if int(weights_delay_steps) != weights_delay_steps or weights_delay_steps < 0:
            raise ValueError(
                f"weights_delay_steps must be an integer >= 0, got {weights_delay_steps}"
            )
        self.weights_delay_steps = int(weights_delay_steps)
        self._weights_since: int | None = None  # step of the first change not yet solved
        self.resolve_shrink = check_range("resolve_shrink", resolve_shrink, 0.0, 1.0)
        self.resolve_dv_mps = check_range(
            "resolve_dv_mps", resolve_dv_mps, 0.0, math.inf, low_inclusive=False
        )
        self.floor = check_range("floor", floor, 0.0, 10.0, low_inclusive=False)
        self.feedforward = feedforward
        self.u_bound_N = (
            None
            if u_bound_N is None
            else check_range("u_bound_N", u_bound_N, 0.0, math.inf, low_inclusive=False)
        )
        act = getattr(scenario, "actuator", None)
        self._omega_default = check_range(
            "omega_n_radps",
            getattr(act, "omega_n_radps", omega_n_radps),
            0.0,
            math.inf,
            low_inclusive=False,
        )
        self._zeta_default = check_range(
            "zeta", getattr(act, "zeta", zeta), 0.0, math.inf, low_inclusive=False
        )
        self._comp: BacksteppingCompensator | None = None
        self._sol: LMISolution | None = None
        super().__init__(**params)

    # ------------------------------------------------------------------ params
    def _on_params_changed(self) -> None:
        if getattr(self, "_model", None) is None:
            return
        key = tuple(self._params[k] for k in self._WEIGHTS)
        if key != self._weights_key:
            self._set_weights()
            if self._sol is None or self.weights_delay_steps == 0:
                self._force_solve = True
            elif self._weights_since is None:
                self._weights_since = self._k
        if self._comp is not None and (self._comp.c1, self._comp.c2) != (
            self._params["c1"],
            self._params["c2"],
        ):
            self._comp.set_gains(self._params["c1"], self._params["c2"])

    def _set_weights(self) -> None:
        p = self._params
        self._W, self._R = self._model.weights(p["q_v"], p["q_dx"], p["r_e"])
        self._weights_key = tuple(p[k] for k in self._WEIGHTS)

    # ------------------------------------------------------------------- reset
    def reset(self, ctx: ControlContext) -> None:
        super().reset(ctx)
        n = int(ctx.n_cars)
        if n < 2 or ctx.n_inputs != n:
            raise ValueError(
                f"{self.name} needs a multi-car train with per-car inputs "
                f"(n_inputs == n_cars >= 2), got n_cars={n}, n_inputs={ctx.n_inputs}"
            )
        tr = ctx.train
        if len(tr.car_masses) != n:
            raise ValueError(f"train has {len(tr.car_masses)} car masses, scenario {n} cars")
        self._n = n
        m, mi, ca, cb, cc = per_car_davis(tr)
        self._m, self._mi = m, mi
        self._share = m / m.sum()
        self._ca, self._cb, self._cc = ca, cb, cc
        if self.n_modes is not None and self.n_modes > n - 1:
            raise ValueError(f"n_modes must lie in [0, {n - 1}] for {n} cars, got {self.n_modes}")
        self._model = ReducedTrainModel(
            self._mi,
            tr.coupler.stiffness_N_per_m,
            tr.coupler.damping_Ns_per_m,
            self._cb,
            self._cc,
            ctx.dt_s,
            self.n_modes,
        )
        self._spacing = np.arange(n) * tr.coupler.rest_length_m
        self._grad = gradient_table(ctx.track) if ctx.track is not None else None
        self._lmi = KothareLMI.shared(self._model.nx, self._model.nu, n, self.memberships.n_rules)
        self._set_weights()
        self._force_solve = True
        self._weights_since = None
        self._sol = None
        self._k = 0
        self._k_solve = 0
        self._v_solve = math.nan
        self._fallback = False
        self._retry_at = 0
        # compensator
        self._comp = None
        if self.compensator and ctx.actuator_order == 2:
            ex = ctx.extra
            self._comp = BacksteppingCompensator(
                float(ex.get("actuator_omega_n_radps", self._omega_default)),
                float(ex.get("actuator_zeta", self._zeta_default)),
                ctx.dt_s,
                self._params["c1"],
                self._params["c2"],
            )

    # ----------------------------------------------------------------- helpers
    def _reference(self, obs: Observation) -> tuple[float, float]:
        ref = self.ctx.reference
        dt = self.ctx.dt_s
        v_r = float(ref.v_ref(obs.t_s, obs.s_m))
        if ref.mode == "time":
            a_r = (float(ref.profile.v_at_t(obs.t_s + dt)) - v_r) / dt
        else:
            s1 = obs.s_m + max(v_r, 0.0) * dt
            a_r = (float(ref.profile.v_at_s(s1)) - v_r) / dt
        return v_r, a_r

    def _bounds(self, v: float) -> tuple[np.ndarray, np.ndarray]:
        tr = self.ctx.train
        av = abs(v)
        return -tr.max_brake_N(av) * self._share, tr.max_traction_N(av) * self._share

    def _equilibrium(self, obs: Observation, v_r: float, a_r: float) -> np.ndarray:
        vr = max(v_r, 0.0)
        u = davis_N(self._ca if vr > 0 else 0.0, self._cb, self._cc, vr)
        if self._grad is not None:
            u = u + self._m * G * np.asarray(self._grad(obs.positions_m), float) / 1000.0
        if self.feedforward == "full":
            u = u + self._mi * a_r
        return np.asarray(u, float)

    def solve_lmi(self, x: np.ndarray, v_r: float, u_bar_kN: np.ndarray) -> LMISolution:
        """Solve the LMI problem at scaled state ``x`` for reference speed ``v_r``."""
        A, B = self._model.rules(v_r, self.memberships.centres)
        return self._lmi.solve(
            A,
            B,
            x,
            self._W,
            self._R,
            self._model.C_u,
            u_bar_kN,
            self.floor,
        )

    def _lqr_fallback(self, v_r: float, x: np.ndarray) -> LMISolution:
        """LQR gain of the middle rule (used only if the LMI solve fails)."""
        A, B = self._model.rules(v_r, self.memberships.centres)
        i = len(A) // 2
        P, K = terminal_cost_dare(A[i], B[i], self._W, self._R)
        K = -K
        Qi = P / max(float(x @ P @ x), 1.0)
        return LMISolution(
            gamma=float(x @ P @ x),
            Q=np.linalg.inv(Qi),
            Y=[],
            F=[K] * len(A),
            P=P,
            Q_inv=Qi,
            status="lqr_fallback",
            solve_time_s=0.0,
            wall_s=0.0,
            iterations=0,
            x=np.array(x),
        )

    def _input_room_kN(self, u_eq: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """ū [kN]: each car's room for a force deviation about ``u_eq`` inside its
        envelope ``[lo, hi]`` (and ``u_bound_N``), at least 1 kN."""
        room = np.minimum(hi - u_eq, u_eq - lo)
        if self.u_bound_N is not None:
            room = np.minimum(room, self.u_bound_N)
        return np.maximum(room, 1e3) / 1000.0

    def _rescale(self, level: float, u_bar: np.ndarray) -> bool:
        """Enlarge the cached ellipsoid to ``xᵀ Q⁻¹ x = level`` if its gains allow it.

        The LMIs of the pair conditions are homogeneous in (Q, Y_j, γ) and the PDC gains
        F_j = Y_j Q⁻¹ do not change under (Q, Y_j, γ) → level·(Q, Y_j, γ); Q ⪰ ρ² I holds
        for level ≥ 1. The input constraint holds on the enlarged ellipsoid iff
        ``level · (C_u F_j Q F_jᵀ C_uᵀ)_ll ≤ ū_l²`` for every rule j and car l (the squared
        largest force deviation of car l on it). If so the scaled solution is a feasible
        point of the LMI at the current state with the same gains, it replaces the cached
        one (cost bound level·γ) and True is returned: no re-solve is needed.
        """
        sol = self._sol
        if sol is None or sol.status == "lqr_fallback" or not sol.Y:
            return False
        Cu = self._model.C_u
        lim = np.asarray(u_bar, float) ** 2
        for Y in sol.Y:
            CY = Cu @ Y
            peak = np.einsum("ij,jk,ik->i", CY, sol.Q_inv, CY)  # diag(C_u Y Q⁻¹ Yᵀ C_uᵀ)
            if np.any(level * peak > lim):
                return False
        self._sol = dataclasses.replace(
            sol,
            gamma=level * sol.gamma,
            Q=level * sol.Q,
            Y=[level * Y for Y in sol.Y],
            Q_inv=sol.Q_inv / level,
        )
        return True

    def _needs_solve(self, x: np.ndarray, v_r: float, u_bar: Callable[[], np.ndarray]) -> bool:
        """Whether the LMI is re-solved this step (rules (a)-(e) of the module docstring);
        ``u_bar()``: the current input room [kN], asked for only by rule (a)."""
        sol = self._sol
        if sol is None or self._force_solve:
            return True
        if self._fallback:
            return self._k >= self._retry_at
        if self.lmi_period and self._k - self._k_solve >= self.lmi_period:
            return True
        since = self._weights_since
        if since is not None and self._k - since >= self.weights_delay_steps:
            return True
        if abs(v_r - self._v_solve) > self.resolve_dv_mps:
            return True
        level = float(x @ sol.Q_inv @ x)
        if level > 1.0 + 1e-9:
            return not (self.enlarge_outside and self._rescale(level, u_bar()))
        return (
            self.resolve_shrink > 0
            and level < self.resolve_shrink
            and float(np.linalg.norm(sol.x)) > self.floor
        )

    # ----------------------------------------------------------------- control
    def compute(self, obs: Observation) -> tuple[np.ndarray, Mapping[str, Any]]:
        model = self._model
        v_r, a_r = self._reference(obs)
        q = np.asarray(obs.positions_m, float) + self._spacing
        delta = q[:-1] - q[1:]
        e = np.asarray(obs.speeds_mps, float) - v_r
        x = model.state(delta, e)
        h = self.memberships(float(e[0]))
        u_eq = self._equilibrium(obs, v_r, a_r)
        lo, hi = self._bounds(float(obs.speeds_mps[0]))
        info: dict[str, Any] = {"triggered": 0.0, "solve_time_s": 0.0, "iterations": 0.0}
        u_bar = functools.partial(self._input_room_kN, u_eq, lo, hi)  # only where needed
        if self._needs_solve(x, v_r, u_bar):
            sol = self.solve_lmi(x, v_r, u_bar())
            self._force_solve = False
            self._weights_since = None
            self._k_solve = self._k
            self._v_solve = v_r
            info.update(triggered=1.0, solve_time_s=sol.solve_time_s, iterations=sol.iterations)
            if np.isfinite(sol.gamma) and all(np.all(np.isfinite(F)) for F in sol.F):
                self._sol = sol
                self._fallback = False
            else:
                if self._sol is None:
                    self._sol = self._lqr_fallback(v_r, x)
                self._fallback = True
                self._retry_at = self._k + (1 if self.lmi_period == 1 else 10)
        sol = self._sol
        g = np.zeros(model.nu)
        for hi_, F in zip(h, sol.F, strict=True):
            if hi_ > 0.0:
                g += hi_ * (F @ x)
        u_d = u_eq + 1000.0 * (model.C_u @ g)
        u_d = np.minimum(np.maximum(u_d, lo), hi)
        if self._comp is not None:
            u, _ = self._comp.command(u_d, obs.forces_N, lo, hi)
        else:
            u = u_d
        self._k += 1
        info.update(J=sol.gamma, fallback=float(self._fallback))
        return u, info
