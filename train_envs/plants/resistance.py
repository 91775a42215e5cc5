"""Running resistance and external disturbances.

Basic (Davis) resistance, per car or whole train::

    R(v) = a + b v + c v²      [N]            (Davis 1926; 000 eq. 2, 001 eq. 7, 002 eq. 3)

acts against the direction of motion. Line resistance from the gradient θ [‰, uphill
positive] and curves (as an equivalent gradient, see :mod:`train_envs.lines.track`)::

    F_g(s) = m g θ(s) / 1000   [N]            (small-angle form used by 000 eq. 3, 001 eq. 6)

Disturbances are accelerations per unit mass [m/s²], positive = resisting, as in paper
000's wind model (ŵ = 0.2 constant, ŵ = 0.1 + 0.1 cos t harmonic, §IV-C) and paper
001's bounded resistance uncertainty w ∈ W (tube assumption, eq. 13).

Time-varying Davis coefficients (paper 002 §2, bounded deviations around nominal) are
modelled as ``c_j(t) = c_j* + δ_j sin(2π t / T_j + φ_j)`` with |δ_j| ≤ the paper's bound
and random phases drawn at reset; a bounded random walk variant models slow drift.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from train_envs.validation import check_nonnegative, check_positive


class Disturbance:
    """Base class: a resisting acceleration per unit mass [m/s²] as a function of time."""

    def reset(self, rng: np.random.Generator) -> None:  # noqa: B027 - optional hook
        """Draw any random quantities for a new episode."""

    def accel(self, t: float) -> float:
        raise NotImplementedError


@dataclass
class ConstantWind(Disturbance):
    """Constant resisting acceleration ``w`` [m/s²] (paper 000: ŵ = 0.2)."""

    w_mps2: float = 0.2

    def accel(self, t: float) -> float:
        return self.w_mps2


@dataclass
class HarmonicWind(Disturbance):
    """Harmonic disturbance ``w0 + w1 cos(ω t + φ)`` [m/s²] (paper 000: 0.1 + 0.1 cos t)."""

    w0_mps2: float = 0.1
    w1_mps2: float = 0.1
    omega_radps: float = 1.0
    phase_rad: float = 0.0

    def accel(self, t: float) -> float:
        return self.w0_mps2 + self.w1_mps2 * math.cos(self.omega_radps * t + self.phase_rad)


@dataclass
class BoundedRandomDisturbance(Disturbance):
    """Piecewise-constant uniform disturbance in [−bound, bound] [m/s²].

    A new value is drawn every ``hold_s`` seconds: paper 001's bounded resistance
    uncertainty w ∈ W used by the tube MPC.
    """

    bound_mps2: float = 0.02
    hold_s: float = 1.0

    def __post_init__(self) -> None:
        check_nonnegative("bound_mps2", self.bound_mps2)
        check_positive("hold_s", self.hold_s)
        self._values = np.zeros(1)

    def reset(self, rng: np.random.Generator) -> None:
        self._values = rng.uniform(-self.bound_mps2, self.bound_mps2, size=4096)

    def accel(self, t: float) -> float:
        i = int(t / self.hold_s) % self._values.size
        return float(self._values[i])


@dataclass
class DavisVariation:
    """Bounded time variation of the per-unit-mass Davis coefficients (paper 002).

    ``delta_*`` are the maximal deviations of c0 [N/kg], c1 [N s/(m kg)], c2
    [N s²/(m² kg)]; 002 Table 1 gives 0.01, 0.00035, 0.000008. ``mode="sinusoid"``:
    δ_j(t) = delta_j sin(2π t / period_s + φ_j); ``mode="random_walk"``: a bounded
    random walk (reflected at ±delta_j) with step std ``delta_j * sqrt(dt/period_s)``,
    sampled on a 1 s grid — a slow parameter drift.
    """

    delta_c0: float = 0.01
    delta_c1: float = 0.00035
    delta_c2: float = 0.000008
    period_s: float = 300.0
    mode: str = "sinusoid"

    def __post_init__(self) -> None:
        for name in ("delta_c0", "delta_c1", "delta_c2"):
            check_nonnegative(name, getattr(self, name))
        check_positive("period_s", self.period_s)
        if self.mode not in ("sinusoid", "random_walk"):
            raise ValueError(f"mode must be 'sinusoid' or 'random_walk', got {self.mode!r}")
        self._phase = np.zeros(3)
        self._walk = np.zeros((1, 3))

    @property
    def bounds(self) -> np.ndarray:
        return np.array([self.delta_c0, self.delta_c1, self.delta_c2])

    def reset(self, rng: np.random.Generator) -> None:
        self._phase = rng.uniform(0.0, 2 * math.pi, size=3)
        if self.mode == "random_walk":
            n = 20000
            steps = rng.normal(size=(n, 3)) * self.bounds * math.sqrt(1.0 / self.period_s)
            walk = np.zeros((n, 3))
            for i in range(1, n):
                x = walk[i - 1] + steps[i]
                # reflect at the bounds
                x = np.where(x > self.bounds, 2 * self.bounds - x, x)
                x = np.where(x < -self.bounds, -2 * self.bounds - x, x)
                walk[i] = x
            self._walk = walk

    def deltas(self, t: float) -> tuple[float, float, float]:
        """Deviation (δc0, δc1, δc2) per unit mass at time ``t``."""
        if self.mode == "sinusoid":
            # sin(2π t / T + φ_j) δ_j: numpy's sine, the products on floats
            s0, s1, s2 = np.sin(2 * math.pi * t / self.period_s + self._phase).tolist()
            return s0 * self.delta_c0, s1 * self.delta_c1, s2 * self.delta_c2
        i = min(int(t), self._walk.shape[0] - 1)
        w0, w1, w2 = self._walk[i].tolist()
        return w0, w1, w2
