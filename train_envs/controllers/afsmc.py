"""Adaptive fuzzy sliding-mode speed/position controller (paper 000's AFSMC comparator).

Paper 000 gives no law for its "AFSMC" comparator (its ref. [18]); this is the standard
form: the switching term of a sliding-mode law replaced by an adaptive fuzzy system
with Lyapunov-tuned singleton consequents (Wang L.-X., *Adaptive Fuzzy Systems and
Control*, 1994; Yoo & Ham, *IEEE Trans. Fuzzy Syst.* 6(2), 1998; boundary layer: Slotine
& Li, *Applied Nonlinear Control*, 1991, ch. 7; projection: Ioannou & Sun, 1996).

Model used for the design (nominal train, point mass)::

    M(1+ρ) v̇ = u − R̂(v) − M g θ(s)/1000 + d          (d: unknown, lumped)

Errors ``e_v = v_ref − v``; sliding variable ``σ = ė_z + λ e_z`` on an error e_z:

* reference mode ``"time"``: ``e_z = e_x = s_ref(t) − s`` (ė_x = e_v), so
  ``σ = e_v + λ e_x`` — position tracking, which is what makes the train stop at
  s_ref(t_end);
* reference mode ``"distance"`` (v_ref(s), no meaningful s_ref(t)): ``e_z = ∫e_v dt``,
  so ``σ = e_v + λ ∫e_v dt`` — speed error only.

``surface="speed"`` drops the position/integral part: ``σ = e_v`` (relative degree
one), a speed-only tracker whose position drifts with every unmodelled force; it is
registered as ``"afsmc000"``, our reading of paper 000's comparator (ref. [18], Guo et
al., IET ITS 17(2), 2023; why: ``docs/design/baselines.md``).

Control law (whole-train force)::

    σ = e_v + sat_δ(λ e_z)                          (sat_δ: clip to ±δ, δ = catchup_max_mps)
    u = M(1+ρ) [a_ref + λ e_v·1{|λ e_z| < δ} + k_s sat(σ/φ) + f̂(σ | θ)] + R̂(v) + M g θ(s)/1000
    f̂(σ | θ) = θᵀ ξ(σ)
    θ̇ = γ σ ξ(σ),   θ_i projected onto [−θ_max, θ_max]

With this u the nominal closed loop is ``σ̇ = −k_s sat(σ/φ) − f̂(σ|θ) − d/M(1+ρ)``;
``V = σ²/2 + |θ − θ*|²/(2γ)`` gives the adaptive law above (Wang 1994).
ξ(σ) are the seven fuzzy basis functions NB … PB of a strong triangular partition over
σ (centres ``σ_span · {−1, −⅔, …, 1}``, σ_span = 1 m/s by default; outer terms
saturate), so f̂ is the piecewise-linear interpolation of θ: a learnt σ-dependent
compensation of the unknown disturbance and model error.

Choices where the sources are silent:

* the position (or integral) part of σ is saturated at ±δ (0.2 m/s by default): a
  train that fell behind a time reference (e.g. traction-limited at the start) catches
  up at most δ faster than v_ref, instead of overspeeding by λ e_x; outside the bound
  σ is a pure speed error;
* boundary layer: the robust term is ``k_s sat(σ/φ)`` (continuous inside |σ| < φ,
  no chattering); adaptation is *not* dead-zoned, so constant disturbances inside
  the layer are still learnt; boundedness comes from the projection;
* anti-windup: adaptation and the ∫e_v integrator are frozen while the command is
  clipped (envelope or rate limit) in the direction σ asks for; the integrator also
  stops growing once λ∫e_v reaches the catch-up bound δ;
* envelope, rate limit, per-car split (:func:`train_envs.controllers._common.distribute`)
  and a_ref (the profile's acceleration at the position or time) as in ``pid``.

Defaults: λ = 0.1 1/s, γ = 0.03 1/s², φ = 0.5 m/s, k_s = 0.2 m/s², θ_max = 0.5 m/s²
(how they were picked: ``docs/design/baselines.md``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from train_envs.controllers._common import (
    distribute,
    envelope_N,
    feedforward_N,
    input_shares,
    reference_at,
)
from train_envs.controllers.base import ControlContext, Controller, Observation, TunableParam
from train_envs.controllers.fuzzy import UNIVERSE, standard_partition
from train_envs.validation import check_choice, check_positive


class AFSMCController(Controller):
    """Adaptive fuzzy sliding-mode controller with boundary layer and projection."""

    name = "afsmc"
    PARAMS = (
        TunableParam("lambda_", 0.01, 2.0, 0.1, description="sliding-surface slope λ [1/s]"),
        TunableParam("gamma", 1e-3, 10.0, 0.03, log=True, description="adaptation gain γ [1/s^2]"),
        TunableParam("phi", 0.01, 5.0, 0.5, log=True, description="boundary-layer width φ [m/s]"),
        TunableParam("k_s", 0.0, 2.0, 0.2, description="robust (switching) gain k_s [m/s^2]"),
    )

    def __init__(
        self,
        feedforward: bool = True,
        theta_max_mps2: float = 0.5,
        sigma_span_mps: float = 1.0,
        catchup_max_mps: float = 0.2,
        surface: str = "position",
        **params: float,
    ) -> None:
        self.surface = check_choice("surface", surface, ("position", "speed"))
        self._speed_surface = self.surface == "speed"
        self.feedforward = feedforward
        self.theta_max = check_positive("theta_max_mps2", theta_max_mps2)
        self.sigma_span = check_positive("sigma_span_mps", sigma_span_mps)
        self.catchup_max = check_positive("catchup_max_mps", catchup_max_mps, allow_inf=True)
        self._partition = standard_partition()
        self._sigma_scale = UNIVERSE / self.sigma_span
        super().__init__(**params)
        self.theta = np.zeros(self._partition.n)

    def reset(self, ctx: ControlContext) -> None:
        super().reset(ctx)
        self.theta = np.zeros(self._partition.n)
        self._int_ev = 0.0
        self._shares = input_shares(ctx)
        self._time_mode = ctx.reference.mode == "time"

    def basis(self, sigma: float) -> tuple[int, float]:
        """Active fuzzy basis functions at σ: (i, w) with ξ_i = 1 − w, ξ_{i+1} = w."""
        return self._partition.locate(sigma * self._sigma_scale)

    def f_hat(self, sigma: float) -> float:
        """Adaptive fuzzy term f̂(σ | θ) = θᵀ ξ(σ) [m/s²]."""
        i, w = self.basis(sigma)
        return float((1.0 - w) * self.theta[i] + w * self.theta[i + 1])

    def compute(self, obs: Observation) -> tuple[np.ndarray, Mapping[str, Any]]:
        ctx = self.ctx
        p = self._params
        dt = ctx.dt_s
        tr = ctx.train
        lam, gamma, phi, k_s = p["lambda_"], p["gamma"], p["phi"], p["k_s"]
        v_ref, a_ref = reference_at(ctx, obs)
        e_v = v_ref - obs.v_mps
        if self._time_mode:
            e_x = float(ctx.reference.profile.s_at_t(obs.t_s)) - obs.s_m
            z_term = lam * e_x
        else:
            e_x = math.nan
            z_term = lam * self._int_ev
        # σ = e_v + sat(λ e_z, ±δ); d/dt of the bounded term is λ e_v inside the bound, 0 outside
        if self._speed_surface:
            sigma = e_v
            dz_term = 0.0
        elif abs(z_term) < self.catchup_max:
            sigma = e_v + z_term
            dz_term = lam * e_v
        else:
            sigma = e_v + math.copysign(self.catchup_max, z_term)
            dz_term = 0.0
        i, w = self.basis(sigma)
        f_hat = (1.0 - w) * self.theta[i] + w * self.theta[i + 1]
        sat = min(1.0, max(-1.0, sigma / phi))
        a_cmd = a_ref + dz_term + k_s * sat + f_hat
        u = tr.inertial_mass_kg * a_cmd
        if self.feedforward:
            u += feedforward_N(ctx, obs.s_m, obs.v_mps)
        out = distribute(ctx, u, obs.v_mps, obs.u_prev_N, self._shares)
        u_sat = float(np.sum(out))
        lo, hi = envelope_N(tr, obs.v_mps)
        clipped = abs(u_sat - u) > 1e-9 * max(1.0, hi - lo)
        if not clipped or (u > u_sat and sigma < 0) or (u < u_sat and sigma > 0):
            # adaptive law θ̇ = γ σ ξ(σ) (explicit Euler) with box projection
            th = self.theta
            th[i] += gamma * sigma * (1.0 - w) * dt
            th[i + 1] += gamma * sigma * w * dt
            np.clip(th, -self.theta_max, self.theta_max, out=th)
            if (
                not self._time_mode
                and not self._speed_surface
                and (abs(z_term) < self.catchup_max or z_term * e_v < 0)
            ):
                self._int_ev += e_v * dt  # no windup beyond the catch-up bound
        return out, {
            "v_ref": v_ref,
            "error": e_v,
            "position_error": e_x,
            "sigma": sigma,
            "f_hat": f_hat,
            "theta_abs_max": float(np.max(np.abs(self.theta))),
        }
