"""Fuzzy self-tuning PID speed controller (paper 004's Fuzzy-PID comparator).

Paper 004 compares its DMC with a "Fuzzy-PID" but gives neither its rules nor its
gains; this is the standard self-tuning form of that literature (a PID whose gains are
corrected online by fuzzy rules on the error e and its rate ec; see e.g. the fuzzy
gain-scheduling scheme of Zhao, Tomizuka & Isaka, "Fuzzy gain scheduling of PID
controllers", *IEEE Trans. SMC* 23(5), 1993; fuzzy logic in ATO goes back to
Yasunobu & Miyamoto, "Automatic train operation system by predictive fuzzy control",
in Sugeno (ed.), *Industrial Applications of Fuzzy Control*, 1985). The rule tables
below are our own, written from the usual design heuristics stated with them.

Control law (acceleration units, like :mod:`train_envs.controllers.pid`)::

    e      = v_ref − v,     ec = ė filtered (first-order, T_f = 5 dt)
    [ΔK_p, ΔK_i, ΔK_d] = [dkp, dki, dkd] ⊙ y(k_e e, k_ec ec) / 3
    K_p = max(0, kp0 + ΔK_p),  K_i = max(0, ki0 + ΔK_i),  K_d = max(0, kd0 + ΔK_d)
    I     ← I + K_i e dt                      (conditional integration)
    a_cmd = a_ref + K_p e + I + K_d ec
    u     = M(1+ρ) a_cmd + R̂(v) + M g θ(s)/1000

``y`` is the three-output fuzzy system of :mod:`train_envs.controllers.fuzzy`: inputs
quantised onto [−3, 3] by ``k_e`` [s/m] and ``k_ec`` [s²/m] (saturating), seven
triangular terms each, product inference, centre-of-sets defuzzification, so each
correction lies in [−dk, dk]. Choices where the sources are silent:

* the integral state accumulates K_i(t) e(t) rather than multiplying Σe by the current
  K_i, so gain changes do not kick the command (bumpless parameter changes, Åström &
  Hägglund, *Advanced PID Control*, 2006);
* gains are clipped at zero (the corrections never flip a gain's sign);
* anti-windup, rate limit and envelope as in ``pid``: the integrator is frozen while
  the command saturates in the direction of the error (``integrate_saturated=True``:
  never, as in ``pid``, for time-indexed stopping runs, paper 004's included: with
  conditional integration the train stops 0.75 m short there, the lag of the
  traction-limited start never made up; integrating in every step, 0.02 m; the env
  ``TrainEnvs/Urban004FuzzyPID-v0`` keeps the comparator as paper 004's reproduction
  ran it, conditional integration); the command is clipped to the
  speed-dependent envelope ``[−B(v), F(v)]`` and to ``du_max_Nps`` per input; per-car
  scenarios get the whole-train force split by car mass share
  (:func:`train_envs.controllers._common.distribute`).

Rule logic (e = v_ref − v, ec = de/dt; "growing" = e and ec of the same sign):

* ΔK_p: large |e| → large K_p (fast recovery), more so when the error is growing;
  when the error is already shrinking fast the correction drops to zero or below to
  avoid overshoot; near zero error K_p stays nominal unless |ec| is large.
* ΔK_i: large |e| → small K_i (no windup, no overshoot from a large integral); small
  |e| → larger K_i to remove the steady-state (resistance-model) error; a little less
  while the error shrinks fast.
* ΔK_d: large |e| or large |ec| → small K_d (no derivative kick during transients);
  small |e| with small |ec| → moderate K_d (damping near the reference).

All three tables are even (``T[6−i][6−j] = T[i][j]``): the gain changes do not depend
on the direction of the error, only on its size and on whether it grows.

Defaults: kp0 0.6 1/s, ki0 0.05 1/s², kd0 0.1, k_e 3 s/m (|e| ≥ 1 m/s is "big"),
k_ec 6 s²/m, corrections ±0.2 / ±0.04 / ±0.1 (how they were picked:
``docs/design/baselines.md``).
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
    feedforward_N,
    input_shares,
    reference_at,
)
from train_envs.controllers.base import ControlContext, Controller, Observation, TunableParam
from train_envs.controllers.fuzzy import NB, NM, NS, PB, PM, PS, UNIVERSE, ZO, RuleBase2

# rows: e = NB … PB; columns: ec = NB … PB
DKP_TABLE = np.array([
    [PB, PB, PB, PB, PM, PM, PS],  # e NB
    [PB, PB, PM, PM, PS, PS, ZO],  # e NM
    [PM, PM, PS, PS, ZO, ZO, NS],  # e NS
    [PS, ZO, ZO, ZO, ZO, ZO, PS],  # e ZO
    [NS, ZO, ZO, PS, PS, PM, PM],  # e PS
    [ZO, PS, PS, PM, PM, PB, PB],  # e PM
    [PS, PM, PM, PB, PB, PB, PB],  # e PB
])
DKI_TABLE = np.array([
    [NB, NB, NB, NB, NB, NB, NB],
    [NS, NS, NS, NS, NS, NM, NM],
    [PS, PS, PS, PS, PS, ZO, ZO],
    [PS, PS, PM, PM, PM, PS, PS],
    [ZO, ZO, PS, PS, PS, PS, PS],
    [NM, NM, NS, NS, NS, NS, NS],
    [NB, NB, NB, NB, NB, NB, NB],
])
DKD_TABLE = np.array([
    [NB, NB, NM, NM, NM, NB, NB],
    [NS, NS, ZO, ZO, ZO, NS, NS],
    [ZO, ZO, PS, PS, PS, ZO, ZO],
    [ZO, PS, PM, PM, PM, PS, ZO],
    [ZO, ZO, PS, PS, PS, ZO, ZO],
    [NS, NS, ZO, ZO, ZO, NS, NS],
    [NB, NB, NM, NM, NM, NB, NB],
])


class FuzzyPIDController(Controller):
    """PID on speed error with fuzzy online correction of K_p, K_i, K_d."""

    name = "fuzzy_pid"
    PARAMS = (
        TunableParam("kp0", 0.01, 10.0, 0.6, log=True,
                     description="nominal proportional gain [1/s]"),
        TunableParam("ki0", 0.0, 2.0, 0.05, description="nominal integral gain [1/s^2]"),
        TunableParam("kd0", 0.0, 2.0, 0.1, description="nominal derivative gain [-]"),
        TunableParam("ke", 0.1, 100.0, 3.0, log=True,
                     description="error quantisation factor [s/m] (|e| >= 3/ke is 'big')"),
        TunableParam("kec", 0.1, 100.0, 6.0, log=True,
                     description="error-rate quantisation factor [s^2/m]"),
        TunableParam("dkp", 0.0, 5.0, 0.2, description="largest K_p correction [1/s]"),
        TunableParam("dki", 0.0, 1.0, 0.04, description="largest K_i correction [1/s^2]"),
        TunableParam("dkd", 0.0, 2.0, 0.1, description="largest K_d correction [-]"),
    )

    def __init__(
        self,
        feedforward: bool = True,
        inference: str = "product",
        integrate_saturated: bool = False,
        **params: float,
    ) -> None:
        self.feedforward = feedforward
        self.integrate_saturated = bool(integrate_saturated)
        self.rules = RuleBase2(
            np.stack([DKP_TABLE, DKI_TABLE, DKD_TABLE]), inference=inference, names=("e", "ec")
        )
        super().__init__(**params)
        self._on_params_changed()

    def _on_params_changed(self) -> None:
        p = self._params
        self.rules.scale_e = p["ke"]
        self.rules.scale_ec = p["kec"]
        self._out_scale = np.array([p["dkp"], p["dki"], p["dkd"]]) / UNIVERSE
        self._update_gain_consts()

    def _update_gain_consts(self) -> None:
        """(kp0, ki0, kd0, ΔK scales) as Python floats for the per-step path."""
        p = self._params
        self._gain_consts = (p["kp0"], p["ki0"], p["kd0"], *self._out_scale.tolist())

    def reset(self, ctx: ControlContext) -> None:
        super().reset(ctx)
        self._integral = 0.0
        self._e_prev: float | None = None
        self._de_f = 0.0
        self._shares = input_shares(ctx)
        self._prepare_fast_path(ctx)

    def _prepare_fast_path(self, ctx: ControlContext) -> None:
        """Per-run constants of :meth:`compute` (its arithmetic is unchanged by them).

        * the de/dt filter gain ``Δt / (T_f + Δt)`` and the inertial mass;
        * one whole-train input (share 1): the command is clipped with Python floats,
          exactly as :func:`distribute` does it on arrays.
        """
        dt = ctx.dt_s
        tr = ctx.train
        self._update_gain_consts()
        self._kf = dt / (5.0 * dt + dt)
        self._Mi = tr.inertial_mass_kg
        self._single = ctx.n_inputs == 1 and self._shares.shape == (1,) and self._shares[0] == 1.0
        self._du_step = ctx.du_max_Nps * ctx.dt_s if math.isfinite(ctx.du_max_Nps) else None

    def gains(self, e: float, ec: float) -> tuple[float, float, float]:
        """Scheduled (K_p, K_i, K_d) for error ``e`` [m/s] and error rate ``ec`` [m/s²]."""
        kp0, ki0, kd0, sp, si, sd = self._gain_consts
        dp, di, dd = self.rules.outputs(e, ec)  # ΔK = (dkp, dki, dkd) ⊙ y / 3
        return max(0.0, kp0 + dp * sp), max(0.0, ki0 + di * si), max(0.0, kd0 + dd * sd)

    def compute(self, obs: Observation) -> tuple[np.ndarray, Mapping[str, Any]]:
        ctx = self.ctx
        dt = ctx.dt_s
        tr = ctx.train
        v = obs.v_mps
        v_ref, a_ref = reference_at(ctx, obs)
        e = v_ref - v
        if self._e_prev is None:
            self._e_prev = e
        self._de_f += self._kf * ((e - self._e_prev) / dt - self._de_f)
        self._e_prev = e
        kp, ki, kd = self.gains(e, self._de_f)
        a_cmd = a_ref + kp * e + self._integral + kd * self._de_f
        u = self._Mi * a_cmd
        if self.feedforward:
            u += feedforward_N(ctx, obs.s_m, v)
        lo, hi = envelope_N(tr, v)
        if self._single and type(v) is float:
            prev = float(np.sum(obs.u_prev_N))  # whole-train previous command
            u_sat = distribute_single(lo, hi, u, prev, self._du_step)
            out = np.array([u_sat])
        else:
            out = distribute(ctx, u, v, obs.u_prev_N, self._shares)
            u_sat = float(np.sum(out))
        clipped = abs(u_sat - u) > 1e-9 * max(1.0, hi - lo)
        free = self.integrate_saturated or not clipped
        if free or (u > u_sat and e < 0) or (u < u_sat and e > 0):
            self._integral += ki * e * dt  # conditional integration (anti-windup)
        return out, {"v_ref": v_ref, "error": e, "kp": kp, "ki": ki, "kd": kd}
