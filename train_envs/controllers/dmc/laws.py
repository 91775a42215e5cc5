r"""The DMC's online laws: softened reference, satisfaction, α, h_c, feedforward (004 §4).

Every function here is the implementation :class:`~.controller.DMCController` runs;
they work on Python floats and short lists (the DMC's vectors have P = 15 entries,
where NumPy's per-call overhead costs more than the arithmetic). Signs: e = y_r − v.

* Softened reference (Xi Yugeng, *Predictive Control*, 2nd ed., 2013, ch. 2; 004 §4.2):
  ``w(k+i) = α^i y(k) + (1 − α^i) y_r(k+i)``, or the error form
  ``w(k+i) = y_r(k+i) − α^i (y_r(k) − y(k))``.
* Response time, satisfactions and index J (004 §4.4)::

      t_r = 0 if |e| ≤ e_tol and |ė| ≤ ė_tol;  |e|/|ė| if e ė < 0;  M otherwise
      μ_t = trap(t_r; t_lo − δ_t, t_lo, t_hi, t_hi + δ_t)     (1 in the stable state)
      μ_y = mean_i trap(ŷ(k+i) − y_r(k+i); −ε − δ_y, −ε, ε, ε + δ_y)
      J   = min(μ_t, μ_y)  (or μ_t μ_y)

  the fuzzy decision as intersection (Bellman & Zadeh, "Decision-making in a fuzzy
  environment", *Management Sci.* 17(4), 1970); trapezoids of
  :func:`train_envs.controllers.fuzzy.trapmf`.
* Softening factor, decreasing in J:
  ``α = α_min + (α_max − α_min)(e^{γ(1−J)} − 1)/(e^γ − 1)`` (linear for γ → 0).
* Correction coefficient (004 §4.5): ``h_c = clip(h_0 + k_h Δh(k_e e, k_ec ė), h_min, 1)``
  with Δh ∈ [−3, 3] the 7 × 7 rule base :data:`H_TABLE` (product inference,
  centre of sets, :class:`~train_envs.controllers.fuzzy.RuleBase2`). 004's Table 2 was
  lost; the table is written from its stated logic: large |e| and rapidly decreasing →
  smaller h (avoid overshoot); small e rapidly increasing → larger h (react faster);
  near-zero error and rate → h_0. It is even (``T[6−i][6−j] = T[i][j]``).
* Error rate ė: the difference quotient of e through a first-order filter.
* Feedforward ``u_ff = R̂(v) − R'(v_nom) v + M g θ / 1000``: the gradient force and the
  non-linear part of the Davis resistance (the linear part is in the model).
* Position catch-up of the setpoint: ``c = sat(λ_x (s_ref − s), ±c_max)``, added as
  ``v + c · min(1, v / v_fade)``.

The shapes chosen where 004 is silent, and their measured effect, are in
``docs/design/dmc.md``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from train_envs.controllers.fuzzy import NB, NM, NS, PB, PM, PS, ZO, RuleBase2, trapmf_scalar

# Δh rule table: rows e = NB … PB, columns ė = NB … PB (e = v_ref − v)
H_TABLE = np.array([
    [PM, PM, PS, PS, NS, NM, NB],  # e NB
    [PM, PM, PS, PS, ZO, NS, NM],  # e NM
    [PB, PM, PS, ZO, ZO, ZO, NS],  # e NS
    [PB, PM, PS, ZO, PS, PM, PB],  # e ZO
    [NS, ZO, ZO, ZO, PS, PM, PB],  # e PS
    [NM, NS, ZO, PS, PS, PM, PM],  # e PM
    [NB, NM, NS, PS, PS, PM, PM],  # e PB
])


# ------------------------------------------------------------------ softened reference
def softening_weights(alpha: float, n: int) -> tuple[list[float], list[float]]:
    """``(α^i, 1 − α^i)`` for i = 1 … n, as lists of floats."""
    ai = alpha ** np.arange(1, n + 1)
    return ai.tolist(), (1.0 - ai).tolist()


def softened_reference(
    y: float,
    y_r: Sequence[float],
    alpha: float,
    weights: tuple[list[float], list[float]] | None = None,
) -> list[float]:
    """``w(k+i) = α^i y(k) + (1 − α^i) y_r(k+i)``, i = 1 … len(y_r).

    ``weights`` are :func:`softening_weights` of α when the caller keeps them.
    """
    ai, om = softening_weights(alpha, len(y_r)) if weights is None else weights
    return [a_i * y + o_i * r_i for a_i, o_i, r_i in zip(ai, om, y_r, strict=True)]


def softened_reference_error(
    y: float,
    y_r0: float,
    y_r: Sequence[float],
    alpha: float,
    weights: tuple[list[float], list[float]] | None = None,
) -> list[float]:
    """Error form ``w(k+i) = y_r(k+i) − α^i (y_r(k) − y(k))``, i = 1 … len(y_r).

    The same as :func:`softened_reference` for a constant setpoint, without the level
    form's lag on ramps.
    """
    ai = softening_weights(alpha, len(y_r))[0] if weights is None else weights[0]
    d0 = y_r0 - y
    return [r_i - a_i * d0 for a_i, r_i in zip(ai, y_r, strict=True)]


# ------------------------------------------------------------------ satisfaction
@dataclass(frozen=True)
class SatisfactionShape:
    """Shapes of the satisfaction index J (units: m/s, m/s², s).

    ``t_trap`` and ``y_trap`` are the corners (a, b, c, d) of the trapezoids of μ_t and
    μ_y; ``t_big`` is the response time M of a growing error.
    """

    e_tol: float
    edot_tol: float
    t_big: float
    t_trap: tuple[float, float, float, float]
    y_trap: tuple[float, float, float, float]
    combine: str = "min"

    @classmethod
    def build(
        cls,
        dt_s: float,
        bounds_samples: tuple[float, float],
        widths_samples: tuple[float, float],
        eps_y: float,
        delta_y: float,
        e_tol: float,
        edot_tol: float,
        combine: str = "min",
    ) -> SatisfactionShape:
        """From the response-time bounds and widths in samples (scaled by Δt), M = 10 t_hi,
        and the output bound ε with width δ_y."""
        t_lo = bounds_samples[0] * dt_s
        t_hi = bounds_samples[1] * dt_s
        w_lo = widths_samples[0] * dt_s
        w_hi = widths_samples[1] * dt_s
        return cls(
            e_tol=e_tol,
            edot_tol=edot_tol,
            t_big=10.0 * t_hi,
            t_trap=(t_lo - w_lo, t_lo, t_hi, t_hi + w_hi),
            y_trap=(-eps_y - delta_y, -eps_y, eps_y, eps_y + delta_y),
            combine=combine,
        )


def response_time(e: float, edot: float, e_tol: float, edot_tol: float, big: float) -> float:
    """Estimated response time: 0 (stable), |e|/|ė| (error decreasing) or ``big``."""
    if abs(e) <= e_tol and abs(edot) <= edot_tol:
        return 0.0
    if e * edot < 0.0:
        return min(big, abs(e) / abs(edot))
    return big


def time_satisfaction(t_r: float, a: float, b: float, c: float, d: float) -> float:
    """``μ_t = trap(t_r; a, b, c, d)``, and 1 in the stable state (t_r = 0)."""
    return 1.0 if t_r == 0.0 else trapmf_scalar(t_r, a, b, c, d)


def output_satisfaction(
    y_pred: Sequence[float], y_r: Sequence[float], a: float, b: float, c: float, d: float
) -> float:
    """``μ_y = mean_i trap(ŷ_i − y_r,i; a, b, c, d)`` (NumPy's pairwise sum for the mean)."""
    if a == -d and b == -c and b - a == d - c and b > a:
        # symmetric trapezoid: the rising edge is the mirror image of the falling one,
        # μ(x) = clip((d − |x|)/(d − c), 0, 1), the same values as trapmf_scalar
        dc = d - c
        mus = []
        for yp, yr in zip(y_pred, y_r, strict=True):
            ax = abs(yp - yr)
            mus.append(1.0 if ax <= c else (0.0 if ax >= d else (d - ax) / dc))
    else:
        mus = [trapmf_scalar(yp - yr, a, b, c, d) for yp, yr in zip(y_pred, y_r, strict=True)]
    n = len(mus)
    n1 = mus.count(1.0)
    if n1 + mus.count(0.0) == n:  # a sum of 0s and 1s is exact in any order
        return n1 / n
    return float(np.add.reduce(np.array(mus))) / n


def satisfaction(
    e: float,
    edot: float,
    y_pred: Sequence[float],
    y_r: Sequence[float],
    shape: SatisfactionShape,
) -> tuple[float, float, float, float]:
    """(t_r, μ_t, μ_y, J) from the error, its rate, the predicted speeds ŷ(k+i) and the
    setpoint preview y_r(k+i)."""
    t_r = response_time(e, edot, shape.e_tol, shape.edot_tol, shape.t_big)
    mu_t = time_satisfaction(t_r, *shape.t_trap)
    mu_y = output_satisfaction(y_pred, y_r, *shape.y_trap)
    J = min(mu_t, mu_y) if shape.combine == "min" else mu_t * mu_y
    return t_r, mu_t, mu_y, J


def softening_factor(J: float, alpha_min: float, alpha_max: float, trend: float) -> float:
    """``α = α_min + (α_max − α_min)(e^{γ(1−J)} − 1)/(e^γ − 1)`` (linear for γ → 0)."""
    J = min(1.0, max(0.0, J))
    if abs(trend) < 1e-9:
        f = 1.0 - J
    else:
        f = math.expm1(trend * (1.0 - J)) / math.expm1(trend)
    return alpha_min + (alpha_max - alpha_min) * f


# ------------------------------------------------------------------ correction, ė
def correction_rules(k_e: float = 1.0, k_ec: float = 1.0) -> RuleBase2:
    """The rule base Δh(k_e e, k_ec ė) of :data:`H_TABLE`."""
    return RuleBase2(H_TABLE, scale_e=k_e, scale_ec=k_ec, names=("e", "edot"))


def correction_coefficient(
    e: float, edot: float, rules: RuleBase2, h0: float, k_h: float, h_min: float
) -> float:
    """``h_c = clip(h_0 + k_h Δh(k_e e, k_ec ė), h_min, 1)`` (``rules``: Δh with k_e, k_ec)."""
    return min(1.0, max(h_min, h0 + k_h * rules.outputs(e, edot)[0]))


def filtered_rate(rate: float, x: float, x_prev: float, dt_s: float, gain: float) -> float:
    """``ė ← ė + g ((x − x_prev)/Δt − ė)``, g = Δt / (T_f + Δt): the difference quotient
    through a first-order filter of time constant T_f (backward Euler)."""
    return rate + gain * ((x - x_prev) / dt_s - rate)


# ------------------------------------------------------------------ setpoint, command
def position_catchup(s_ref_m: float, s_m: float, gain_1ps: float, c_max_mps: float) -> float:
    """``c = sat(λ_x (s_ref − s), ±c_max)`` [m/s]."""
    c = gain_1ps * (s_ref_m - s_m)
    return min(c_max_mps, max(-c_max_mps, c))


def with_catchup(v_mps: Sequence[float], c_mps: float, fade_mps: float) -> list[float]:
    """``v + c · min(1, v / v_fade)`` for each speed v: the catch-up c fades out as the
    profile comes to rest."""
    out = []
    for v in v_mps:
        q = v / fade_mps
        out.append(v + c_mps * (q if q < 1.0 else 1.0))
    return out


def feedforward_force(
    v_mps: float,
    resistance_N: float,
    k_davis_Ns_per_m: float,
    weight_N: float,
    gradient_permil: float,
) -> float:
    """``u_ff = R̂(v) − R'(v_nom) v + M g θ / 1000`` [N] (``resistance_N`` = R̂(v),
    ``weight_N`` = M g)."""
    return resistance_N - k_davis_Ns_per_m * v_mps + weight_N * gradient_permil / 1000.0
