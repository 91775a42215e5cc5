"""Backstepping compensator of a second-order actuator (003 §3.2, Theorem 5).

Backstepping after Krstić, Kanellakopoulos & Kokotović (1995), ch. 2. Actuator of every
car (003 eq. 43): ``F̈ + 2ζω_n Ḟ + ω_n² F = ω_n² w``. With the designed force u_d (held
over the period), ``z_1 = F − u_d``, virtual rate ``α = −c_1 z_1``, ``z_2 = Ḟ − α``,
``V = (z_1² + z_2²)/2``, the actuator command::

    w = F + (2ζω_n Ḟ − c_1 Ḟ − z_1 − c_2 z_2) / ω_n²

gives ``V̇ = −c_1 z_1² − c_2 z_2²``. The continuous law is held over the period
(emulation; 003 derives its law with forward differences, a poor actuator model at
ω_n T = 1), and the sampled loop ``Φ + Γ K`` is checked to be stable (spectral radius
< 1) whenever the gains are set. F is the measured actuator output; Ḟ is estimated
from the last two measurements and the last command with the exact sampled actuator
model (a dead-beat observer; Ḟ = 0 at the first step, the actuators start at rest).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from train_envs.mpc import zoh
from train_envs.validation import check_range

__all__ = ["BacksteppingCompensator"]


@dataclass
class BacksteppingCompensator:
    """Backstepping compensator of a second-order actuator (003 Theorem 5; module docstring).

    Attributes:
        omega_n_radps, zeta: the actuator ``F̈ + 2ζω_n Ḟ + ω_n² F = ω_n² w``.
        dt_s: control period (the command is held over it).
        c1, c2: backstepping gains [1/s] of ``z_1`` and ``z_2``.
    """

    omega_n_radps: float
    zeta: float
    dt_s: float
    c1: float = 2.0
    c2: float = 2.0

    def __post_init__(self) -> None:
        check_range("omega_n_radps", self.omega_n_radps, 0.0, math.inf, low_inclusive=False)
        check_range("zeta", self.zeta, 0.0, math.inf, low_inclusive=False)
        check_range("dt_s", self.dt_s, 0.0, math.inf, low_inclusive=False)
        w, z = self.omega_n_radps, self.zeta
        Ac = np.array([[0.0, 1.0], [-(w**2), -2.0 * z * w]])
        Bc = np.array([[0.0], [w**2]])
        Phi, Gam = zoh(Ac, Bc, self.dt_s)
        self.Phi, self.Gam = Phi, Gam[:, 0]
        self.set_gains(self.c1, self.c2)
        self.reset()

    def set_gains(self, c1: float, c2: float) -> None:
        """Set c1, c2; raises ValueError if the sampled loop would be unstable."""
        c1 = check_range("c1", c1, 0.0, math.inf, low_inclusive=False)
        c2 = check_range("c2", c2, 0.0, math.inf, low_inclusive=False)
        w, z = self.omega_n_radps, self.zeta
        # w = k_F F + k_Fd Ḟ + k_u u_d
        kF = 1.0 - (1.0 + c1 * c2) / w**2
        kFd = (2.0 * z * w - c1 - c2) / w**2
        ku = (1.0 + c1 * c2) / w**2
        Acl = self.Phi + np.outer(self.Gam, [kF, kFd])
        rad = float(max(abs(np.linalg.eigvals(Acl))))
        if rad >= 1.0:
            raise ValueError(
                f"compensator gains c1={c1}, c2={c2} make the sampled actuator loop unstable "
                f"(spectral radius {rad:.3f} >= 1 for omega_n={w}, zeta={z}, T={self.dt_s}); "
                "lower c1/c2"
            )
        self.c1, self.c2 = c1, c2
        self._k = (kF, kFd, ku)
        self.spectral_radius = rad

    def reset(self) -> None:
        self._F_prev: np.ndarray | None = None
        self._w_prev: np.ndarray | None = None

    def rate_estimate(self, F: np.ndarray) -> np.ndarray:
        """Ḟ now, from F now, F and w one period ago and the exact sampled actuator model."""
        if self._F_prev is None:
            return np.zeros_like(F)
        P, g = self.Phi, self.Gam
        Fd_prev = (F - P[0, 0] * self._F_prev - g[0] * self._w_prev) / P[0, 1]
        return P[1, 0] * self._F_prev + P[1, 1] * Fd_prev + g[1] * self._w_prev

    def command(
        self, u_d: np.ndarray, F: np.ndarray, lo: np.ndarray, hi: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Actuator command w (clipped to [lo, hi]) and the rate estimate Ḟ."""
        F = np.asarray(F, float)
        Fd = self.rate_estimate(F)
        kF, kFd, ku = self._k
        w = kF * F + kFd * Fd + ku * np.asarray(u_d, float)
        w = np.minimum(np.maximum(w, lo), hi)
        self._F_prev = F.copy()
        self._w_prev = w.copy()
        return w, Fd
