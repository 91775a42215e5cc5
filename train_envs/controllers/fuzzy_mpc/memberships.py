"""Triangular membership functions of the T-S fuzzy model (003 §2.2, eq. 9–10).

Premise: the lead car's speed-tracking error e_1 [m/s], on centres ε_1 < … < ε_r
(Tanaka & Wang 2001, ch. 2, sector nonlinearity). Memberships are ≥ 0, sum to 1 and are
saturated outside [ε_1, ε_r] (003 §4, Fig. 3 was lost; this is the standard choice).
Because the lead car's resistance slope ``b_1 + c_1 (2 v_r + e_1)`` is affine in e_1 and
triangular memberships interpolate linearly, the blend ``Σ h_i S_i`` of the rule slopes
``S_i = b_1 + c_1 (2 v_r + ε_i)`` equals the exact slope on [ε_1, ε_r].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from train_envs.validation import check_finite

__all__ = ["TriangularMemberships"]


@dataclass(frozen=True)
class TriangularMemberships:
    """Triangular membership functions on the premise variable (speed error, m/s).

    ``centres`` ε_1 < … < ε_r (r ≥ 2). Rule i's membership is the triangle peaking at ε_i
    with feet at the neighbouring centres; the first and last are shoulders (1 beyond the
    outer centres). For any e the memberships are ≥ 0 and sum to 1, and at most two are
    non-zero: ``h_i = (ε_{i+1} − e)/(ε_{i+1} − ε_i)``, ``h_{i+1} = 1 − h_i``.
    """

    centres: tuple[float, ...] = (-15.0, 15.0)

    def __post_init__(self) -> None:
        c = tuple(float(x) for x in self.centres)
        if len(c) < 2:
            raise ValueError(f"centres needs at least 2 values, got {len(c)}")
        for i, x in enumerate(c):
            check_finite(f"centres[{i}]", x)
        if any(b <= a for a, b in zip(c[:-1], c[1:], strict=True)):
            raise ValueError(f"centres must be strictly increasing, got {c}")
        object.__setattr__(self, "centres", c)

    @property
    def n_rules(self) -> int:
        return len(self.centres)

    def __call__(self, e: float) -> np.ndarray:
        c = self.centres
        h = np.zeros(len(c))
        x = min(max(float(e), c[0]), c[-1])
        i = 0
        while i < len(c) - 2 and x > c[i + 1]:
            i += 1
        w = (c[i + 1] - x) / (c[i + 1] - c[i])
        h[i] = w
        h[i + 1] = 1.0 - w
        return h
