"""PID speed controller with feedforward, anti-windup and rate limit (paper 001's comparator).

Control law (acceleration units, so gains are train-independent)::

    e(t)   = v_ref − v
    a_cmd  = a_ff + k_p e + k_i ∫e dt + k_d ė_f ,   ė_f low-pass filtered (T_f = 5 dt)
    u      = M(1+ρ) a_cmd + R̂(v) + M g θ(s)/1000     (feedforward of the nominal
                                                       resistance if ``feedforward``)

``a_ff`` is the reference acceleration (the profile's slope). The integrator is frozen
while the command saturates (conditional integration anti-windup, Åström & Hägglund,
*Advanced PID Control*, 2006, §3.5), and the command change per step is limited by the
scenario's rate limit ``du_max_Nps``. ``k_p = 0`` etc. gives P/PI/PD variants; with
k_i = k_d = 0 it is the simple reference-tracking baseline (feedforward + P).

``integrate_saturated=True`` integrates e in every step. On a time-indexed reference
∫e dt = s_ref(t) − s is the position lag behind the timetable, which a stopping run
must make up; conditional integration forgets the lag built up while the command is
saturated (the start from standstill), and the train stops short by that much
(measured: ``docs/design/compatibility.md``). ``make_controller`` sets it on the
time-indexed stopping runs (:mod:`train_envs.controllers.requirements`), with
``k_i = k_p² / 4``: there ``a_cmd − a_ref = k_p ė_x + k_i e_x`` (e_x = s_ref − s) is a
position loop with characteristic polynomial ``λ² + k_p λ + k_i``; the default
k_i = 0.05 puts a slow pole at −0.07 1/s (15 s), so the lag left by the final braking
(actuator lag and dead time) is still open at the stop (+0.5…+0.7 m on four Yizhuang
station pairs); k_i = k_p²/4 = 0.16 is the critically damped double pole at −k_p/2 =
−0.4 1/s (2.5 s), measured within 0.02 m on every real-line station pair.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from train_envs.controllers._common import feedforward_N, reference_at
from train_envs.controllers.base import ControlContext, Controller, Observation, TunableParam


class PIDController(Controller):
    """Speed PID with feedforward; tunable k_p, k_i, k_d (acceleration units)."""

    name = "pid"
    PARAMS = (
        TunableParam("kp", 0.01, 10.0, 0.8, log=True, description="proportional gain [1/s]"),
        TunableParam("ki", 0.0, 2.0, 0.05, description="integral gain [1/s^2]"),
        TunableParam("kd", 0.0, 2.0, 0.0, description="derivative gain [-]"),
    )

    def __init__(
        self, feedforward: bool = True, integrate_saturated: bool = False, **params: float
    ) -> None:
        self.feedforward = feedforward
        self.integrate_saturated = bool(integrate_saturated)
        super().__init__(**params)

    def reset(self, ctx: ControlContext) -> None:
        super().reset(ctx)
        self._integral = 0.0
        self._e_prev: float | None = None
        self._de_f = 0.0
        self._u_prev: np.ndarray | None = None

    def _reference(self, obs: Observation) -> tuple[float, float]:
        return reference_at(self.ctx, obs)

    def compute(self, obs: Observation) -> tuple[np.ndarray, Mapping[str, Any]]:
        ctx = self.ctx
        p = self._params
        dt = ctx.dt_s
        tr = ctx.train
        v_ref, a_ref = self._reference(obs)
        e = v_ref - obs.v_mps
        if self._e_prev is None:
            self._e_prev = e
        tf = 5.0 * dt
        self._de_f += (dt / (tf + dt)) * ((e - self._e_prev) / dt - self._de_f)
        self._e_prev = e
        a_cmd = a_ref + p["kp"] * e + p["ki"] * self._integral + p["kd"] * self._de_f
        u = tr.inertial_mass_kg * a_cmd
        if self.feedforward:
            u += feedforward_N(ctx, obs.s_m, obs.v_mps)
        u_hi = tr.max_traction_N(obs.v_mps)
        u_lo = -tr.max_brake_N(obs.v_mps)
        u_sat = min(max(u, u_lo), u_hi)
        u_prev = float(np.sum(obs.u_prev_N))
        if math.isfinite(ctx.du_max_Nps):
            du = ctx.du_max_Nps * dt * ctx.n_inputs
            u_sat = min(max(u_sat, u_prev - du), u_prev + du)
        sat_ok = self.integrate_saturated
        if sat_ok or u_sat == u or (u > u_sat and e < 0) or (u < u_sat and e > 0):
            self._integral += e * dt  # conditional integration (anti-windup)
        out = np.full(ctx.n_inputs, u_sat / ctx.n_inputs)
        return out, {"v_ref": v_ref, "error": e}
