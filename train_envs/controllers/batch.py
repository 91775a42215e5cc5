"""B PID or Fuzzy-PID controllers in lockstep, and the array forms of their shared laws.

:class:`BatchPID` and :class:`BatchFuzzyPID` run the step of
:class:`~train_envs.controllers.pid.PIDController` and
:class:`~train_envs.controllers.fuzzy_pid.FuzzyPIDController` (control laws in their
module docstrings) for B members of one scenario with one whole-train input, each with
its own gains and state, elementwise over the members with the single controller's
operations (every member equals its single controller bit for bit, tested). The helpers
are their array forms: the reference read-out, the nominal resistance and feedforward,
Python's ``min(max(x, lo), hi)``, the rule base's active cell (:func:`rules_batchable`
also decides for the batched DMC, :mod:`.dmc.batch`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from train_envs.controllers.base import Controller
from train_envs.controllers.fuzzy import UNIVERSE, RuleBase2, TriangularPartition
from train_envs.trains import G, TrainParams

__all__ = [
    "BatchFuzzyPID",
    "BatchPID",
    "clip_like",
    "common_time",
    "davis_array",
    "per_time",
    "resistance_array",
    "rule_outputs",
]


def clip_like(x: np.ndarray, lo: np.ndarray | float, hi: np.ndarray | float) -> np.ndarray:
    """``min(max(x, lo), hi)`` elementwise, with Python's choice of operand on ties."""
    x = np.where(lo > x, lo, x)
    return np.where(hi < x, hi, x)


def resistance_array(train: TrainParams, v: np.ndarray) -> np.ndarray:
    """:meth:`TrainParams.resistance_N` elementwise: ``sign(v) R(|v|)``, 0 at rest."""
    return davis_array(train.davis_a_N, train.davis_b_Ns_per_m, train.davis_c_Ns2_per_m2, v)


def davis_array(a: float, b: float, c: float, v: np.ndarray) -> np.ndarray:
    """``sign(v) (a + b|v| + c|v|²)`` elementwise, 0 at rest (:func:`resistance_array` of
    the coefficients)."""
    av = np.abs(v)
    r = a + b * av + c * av * av
    return np.where(v != 0, np.copysign(r, v), 0.0)


def common_time(t: np.ndarray) -> float | None:
    """The members' one time where they are in lockstep (every ``t_i`` equal), else
    None (a list comparison: for the few members of a population cheaper than an
    array reduction)."""
    tl = t.tolist()
    t0 = tl[0]
    return t0 if tl.count(t0) == len(tl) else None


def per_time(t: np.ndarray, fn: Any) -> np.ndarray:
    """``fn(t_i)`` for every member's time ``t_i`` (members in lockstep share one time,
    evaluated once): an array of ``fn``'s values, one row per member."""
    t0 = common_time(t)
    if t0 is not None:  # in lockstep: one evaluation, repeated
        return np.asarray(fn(t0), dtype=float)[None].repeat(t.shape[0], axis=0)
    ut, inv = np.unique(t, return_inverse=True)
    vals = np.array([fn(float(x)) for x in ut.tolist()], dtype=float)
    return vals[inv.reshape(-1)]


def reference_arrays(ctx: Any, t: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`~train_envs.controllers._common.reference_at` over the members (times
    ``t``, positions ``s``): ``(v_ref, a_ref)``."""
    ref = ctx.reference
    prof = ref.profile
    if ref.mode == "distance":
        return (
            np.asarray(prof.v_at_s(s), dtype=float),
            np.interp(s, prof.s_m, prof.a_mps2),
        )
    va = per_time(t, lambda x: (float(prof.v_at_t(x)), float(np.interp(x, prof.t_s, prof.a_mps2))))
    return va[:, 0], va[:, 1]


def feedforward_array(ctx: Any, s: np.ndarray, v: np.ndarray) -> np.ndarray:
    """:func:`~train_envs.controllers._common.feedforward_N` elementwise."""
    tr = ctx.train
    theta = (
        np.asarray(ctx.track.equivalent_gradient_permil_at(s), dtype=float)
        if ctx.track
        else np.zeros(s.shape)
    )
    return resistance_array(tr, v) + tr.mass_kg * G * theta / 1000.0


def locate_uniform(
    x: np.ndarray, lo: float, h: float, n: int, hi: float
) -> tuple[np.ndarray, np.ndarray]:
    """:meth:`TriangularPartition.locate` of a uniform partition (first centre ``lo``,
    spacing ``h``, ``n`` terms, last centre ``hi``), elementwise."""
    f = (x - lo) / h
    i = np.minimum(np.where(f > 0.0, f, 0.0).astype(np.int64), n - 2)
    w = np.minimum(1.0, f - i)
    below, above = x <= lo, x >= hi
    return (
        np.where(below, 0, np.where(above, n - 2, i)),
        np.where(below, 0.0, np.where(above, 1.0, w)),
    )


def locate(part: TriangularPartition, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:meth:`TriangularPartition.locate` of a uniform partition, elementwise."""
    return locate_uniform(x, part._lo, part._h, part.n, part._hi)


def rule_cell(
    C: np.ndarray, i: np.ndarray, a: np.ndarray, j: np.ndarray, b: np.ndarray
) -> np.ndarray:
    """Product inference over the active cell ``(i, j)`` (weights ``a``, ``b`` of the
    right and upper terms) of the rule table ``C``, elementwise."""
    a1, b1 = 1.0 - a, 1.0 - b
    w00, w01, w10, w11 = a1 * b1, a1 * b, a * b1, a * b
    i1, j1 = i + 1, j + 1
    return w00 * C[i, j] + w01 * C[i, j1] + w10 * C[i1, j] + w11 * C[i1, j1]


def rule_outputs(
    rules: RuleBase2, e: np.ndarray, ec: np.ndarray, scale_e: np.ndarray, scale_ec: np.ndarray
) -> list[np.ndarray]:
    """:meth:`RuleBase2.outputs` (product inference, uniform partitions) over the
    members, each with its own quantisation factors: one array per output."""
    i, a = locate(rules.pe, e * scale_e)
    j, b = locate(rules.pc, ec * scale_ec)
    return [rule_cell(C, i, a, j, b) for C in rules.C]


def rules_batchable(rules: RuleBase2) -> bool:
    """Whether :func:`rule_outputs` covers ``rules``."""
    return rules.inference == "product" and rules.pe._uniform and rules.pc._uniform


def _params(params: Sequence[Mapping[str, float]]) -> dict[str, np.ndarray]:
    return {n: np.array([float(p[n]) for p in params]) for n in params[0]}


class _BatchPIDBase:
    """State and the command clipping shared by the two PIDs."""

    def __init__(self, ref: Controller, params: Sequence[Mapping[str, float]]) -> None:
        ctx = ref.ctx
        if ctx.n_inputs != 1:
            raise ValueError("the lockstep PIDs need one whole-train input")
        self.ref = ref
        self.ctx = ctx
        self.B = len(params)
        self.p = _params(params)
        self.reset()

    def reset(self, ix: np.ndarray | None = None) -> None:
        """Start an episode for members ``ix`` (all by default)."""
        if ix is None:
            self.integral = np.zeros(self.B)
            self.e_prev = np.zeros(self.B)
            self.de_f = np.zeros(self.B)
            self.started = np.zeros(self.B, dtype=bool)
            return
        self.integral[ix] = 0.0
        self.de_f[ix] = 0.0
        self.started[ix] = False

    def set_params(self, b: int, params: Mapping[str, float]) -> None:
        """Member ``b``'s parameters (the full set, as ``get_params`` gives it)."""
        for n, val in params.items():
            self.p[n][b] = float(val)
        self._derived(b)

    def _derived(self, b: int | None = None) -> None:
        """Per-member values derived from the parameters: of every member, or of member
        ``b`` alone."""

    def _error(self, ix: np.ndarray, t: np.ndarray, s: np.ndarray, v: np.ndarray, kf: float):
        """(e, a_ref, filtered ė) with the filter state of members ``ix`` advanced."""
        v_ref, a_ref = reference_arrays(self.ctx, t, s)
        e = v_ref - v
        e_prev = np.where(self.started[ix], self.e_prev[ix], e)
        de = self.de_f[ix]
        de = de + kf * ((e - e_prev) / self.ctx.dt_s - de)
        self.de_f[ix] = de
        self.e_prev[ix] = e
        self.started[ix] = True
        return e, a_ref, de


class BatchPID(_BatchPIDBase):
    """B members of :class:`~train_envs.controllers.pid.PIDController`."""

    def compute(
        self, ix: np.ndarray, t: np.ndarray, s: np.ndarray, v: np.ndarray, u_prev_N: np.ndarray
    ) -> tuple[np.ndarray, Mapping[str, np.ndarray]]:
        ctx = self.ctx
        dt = ctx.dt_s
        tr = ctx.train
        e, a_ref, de = self._error(ix, t, s, v, dt / (5.0 * dt + dt))
        p = self.p
        a_cmd = a_ref + p["kp"][ix] * e + p["ki"][ix] * self.integral[ix] + p["kd"][ix] * de
        u = tr.inertial_mass_kg * a_cmd
        if self.ref.feedforward:
            u = u + feedforward_array(ctx, s, v)
        lo, hi = tr.envelope_N(v)
        u_sat = clip_like(u, lo, hi)
        if math.isfinite(ctx.du_max_Nps):
            du = ctx.du_max_Nps * dt * ctx.n_inputs
            u_sat = clip_like(u_sat, u_prev_N - du, u_prev_N + du)
        grow = (u_sat == u) | ((u > u_sat) & (e < 0)) | ((u < u_sat) & (e > 0))
        if self.ref.integrate_saturated:
            grow[:] = True  # integrate in every step (see PIDController)
        self.integral[ix] = np.where(grow, self.integral[ix] + e * dt, self.integral[ix])
        return u_sat / ctx.n_inputs, {}


class BatchFuzzyPID(_BatchPIDBase):
    """B members of :class:`~train_envs.controllers.fuzzy_pid.FuzzyPIDController`."""

    def __init__(self, ref: Controller, params: Sequence[Mapping[str, float]]) -> None:
        if not (rules_batchable(ref.rules) and ref._single):
            raise ValueError("this Fuzzy-PID configuration has no lockstep twin")
        super().__init__(ref, params)
        self._derived()

    def _derived(self, b: int | None = None) -> None:
        p = self.p
        if b is not None:
            for scale, name in zip(self.scales, ("dkp", "dki", "dkd"), strict=True):
                scale[b] = p[name][b] / UNIVERSE
            return
        self.scales = [p["dkp"] / UNIVERSE, p["dki"] / UNIVERSE, p["dkd"] / UNIVERSE]

    def compute(
        self, ix: np.ndarray, t: np.ndarray, s: np.ndarray, v: np.ndarray, u_prev_N: np.ndarray
    ) -> tuple[np.ndarray, Mapping[str, np.ndarray]]:
        ref, ctx, p = self.ref, self.ctx, self.p
        dt = ctx.dt_s
        e, a_ref, de = self._error(ix, t, s, v, ref._kf)
        dp, di, dd = rule_outputs(ref.rules, e, de, p["ke"][ix], p["kec"][ix])
        sp, si, sd = (x[ix] for x in self.scales)
        kp, ki, kd = (
            np.where(x > 0.0, x, 0.0)  # max(0.0, x)
            for x in (p["kp0"][ix] + dp * sp, p["ki0"][ix] + di * si, p["kd0"][ix] + dd * sd)
        )
        a_cmd = a_ref + kp * e + self.integral[ix] + kd * de
        u = ref._Mi * a_cmd
        if ref.feedforward:
            u = u + feedforward_array(ctx, s, v)
        lo, hi = ctx.train.envelope_N(v)
        u_sat = clip_like(u, lo, hi)
        if ref._du_step is not None:
            u_sat = clip_like(u_sat, u_prev_N - ref._du_step, u_prev_N + ref._du_step)
        clipped = np.abs(u_sat - u) > 1e-9 * np.where(hi - lo > 1.0, hi - lo, 1.0)
        grow = ~clipped | ((u > u_sat) & (e < 0)) | ((u < u_sat) & (e > 0))
        if ref.integrate_saturated:
            grow[:] = True  # integrate in every step (see FuzzyPIDController)
        self.integral[ix] = np.where(grow, self.integral[ix] + ki * e * dt, self.integral[ix])
        return u_sat, {}
