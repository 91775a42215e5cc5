"""Helpers shared by the speed controllers: reference look-up, feedforward, command limits.

* :func:`reference_at` — v_ref and the profile's acceleration a_ref at the train's
  position (reference mode ``"distance"``) or at the current time (mode ``"time"``).
* :func:`feedforward_N` — nominal resistance plus gradient force ``R̂(v) + M g θ(s)/1000``.
* :func:`envelope_N` — the speed-dependent force envelope ``[−B(v), F(v)]`` of the train.
* :func:`input_shares` and :func:`distribute` — split a whole-train force over the
  controller's inputs in proportion to car mass, then clip every input to its share of
  the envelope and to the per-input rate limit ``du_max_Nps``;
  :func:`distribute_single` is its float twin for one whole-train input.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from train_envs.controllers.base import ControlContext, Observation
from train_envs.plants.physics import car_davis
from train_envs.trains import G, TrainParams

if TYPE_CHECKING:
    pass


def reference_at(ctx: ControlContext, obs: Observation) -> tuple[float, float]:
    """Reference speed and acceleration (v_ref [m/s], a_ref [m/s²]) for this observation."""
    ref = ctx.reference
    prof = ref.profile
    if ref.mode == "distance":
        v_ref = float(prof.v_at_s(obs.s_m))
        a_ref = float(np.interp(obs.s_m, prof.s_m, prof.a_mps2))
    else:
        v_ref = float(prof.v_at_t(obs.t_s))
        a_ref = float(np.interp(obs.t_s, prof.t_s, prof.a_mps2))
    return v_ref, a_ref


def feedforward_N(ctx: ControlContext, s_m: float, v_mps: float) -> float:
    """Nominal resistance plus gradient force at (s, v): ``R̂(v) + M g θ(s) / 1000`` [N]."""
    tr = ctx.train
    theta = float(ctx.track.equivalent_gradient_permil_at(s_m)) if ctx.track else 0.0
    return tr.resistance_N(v_mps) + tr.mass_kg * G * theta / 1000.0


def envelope_N(train: TrainParams, v_mps: float) -> tuple[float, float]:
    """Whole-train force bounds at speed v: ``(−max_brake_N(v), max_traction_N(v))``."""
    return -train.max_brake_N(v_mps), train.max_traction_N(v_mps)


def input_shares(ctx: ControlContext) -> np.ndarray:
    """Fraction of the whole-train force given to each input (sums to one).

    One input: ``[1]``. Per-car inputs (``n_inputs == len(train.car_masses)``): the car's
    mass share ``m_i / M`` — equal accelerations for all cars, so couplers carry no
    steady force; the plant saturates each car at the same share of the envelope.
    Any other input count: equal shares.
    """
    n = int(ctx.n_inputs)
    masses = np.asarray(ctx.train.car_masses, dtype=float)
    if n > 1 and masses.size == n:
        return masses / masses.sum()
    return np.full(n, 1.0 / n)


def distribute(
    ctx: ControlContext,
    u_total_N: float,
    v_mps: float,
    u_prev_N: np.ndarray,
    shares: np.ndarray,
) -> np.ndarray:
    """Per-input commands: ``clip(share_i u, share_i [−B(v), F(v)], u_prev_i ± du_max dt)``.

    The rate limit wins over the envelope when both cannot hold (the envelope can
    shrink faster with speed than the rate limit allows; the plant clips the rest).
    """
    lo, hi = envelope_N(ctx.train, v_mps)
    u = np.clip(shares * u_total_N, shares * lo, shares * hi)
    if math.isfinite(ctx.du_max_Nps):
        prev = np.asarray(u_prev_N, dtype=float).reshape(-1)
        if prev.size != u.size:
            prev = shares * float(np.sum(prev))
        du = ctx.du_max_Nps * ctx.dt_s
        u = np.clip(u, prev - du, prev + du)
    return u


def distribute_single(
    lo: float, hi: float, u: float, u_prev: float, du_step: float | None
) -> float:
    """:func:`distribute` for one whole-train input, on floats: ``u`` clipped to the
    envelope ``[lo, hi]``, then to the rate window ``u_prev ± du_step`` (none when
    ``du_step`` is None)."""
    u = min(max(u, lo), hi)
    if du_step is not None:
        u = min(max(u, u_prev - du_step), u_prev + du_step)
    return u


def per_car_davis(
    train: TrainParams,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per-car masses and Davis coefficients of an n-car model.

    Returns ``(m, m', a, b, c)``: car masses, inertial masses ``m (1 + ρ)``, and the
    Davis coefficients split by mass share — except the aerodynamic ``c``, which sits
    on the lead car alone when ``train.lead_car_aero`` (papers 002/003), else is split
    by mass share too (paper 000's per-car resistance).
    """
    m = np.asarray(train.car_masses, float)
    mi = m * (1.0 + train.rotating_mass_factor)
    share = m / m.sum()
    a, b, c = train.davis_a_N, train.davis_b_Ns_per_m, train.davis_c_Ns2_per_m2
    ca, cb, c = car_davis(a, b, c, share, train.lead_car_aero)
    return m, mi, ca, cb, c
