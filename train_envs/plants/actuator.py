"""Actuator dynamics and the linear part of the n-car model.

Actuator of car i, input w_i (the commanded force, delayed by the dead time T_d)::

    order 0 (ideal):        F_i = w_i(t − T_d)
    order 1 (001 eq. 1–2):  τ Ḟ_i = −F_i + w_i(t − T_d)
    order 2 (003 §2.2):     F̈_i + 2ζω_n Ḟ_i + ω_n² F_i = ω_n² w_i(t − T_d)

:func:`linear_model` assembles ``ż = A z + B w`` of the kinematics, the couplers
(:func:`train_envs.plants.physics.coupler_matrix`) and the actuators, with the state
``z = (q_1..q_n, v_1..v_n, F_1..F_n, Ḟ_1..Ḟ_n)`` (force states for order ≥ 1, force
rates for order 2) on the shifted positions ``q_i = x_i + (i − 1) L``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from train_envs.plants.physics import coupler_matrix
from train_envs.validation import check_nonnegative, check_positive


@dataclass(frozen=True)
class ActuatorParams:
    """Traction/braking actuator: ideal (0), first-order lag (1) or second order (2) + dead time."""

    order: int = 0
    tau_s: float = 0.4
    dead_time_s: float = 0.0
    omega_n_radps: float = 2.0
    zeta: float = 0.8

    def __post_init__(self) -> None:
        if self.order not in (0, 1, 2):
            raise ValueError(f"actuator.order must be 0, 1 or 2, got {self.order}")
        if self.order == 1:
            check_positive("actuator.tau_s", self.tau_s)
        check_nonnegative("actuator.dead_time_s", self.dead_time_s)
        if self.order == 2:
            check_positive("actuator.omega_n_radps", self.omega_n_radps)
            check_positive("actuator.zeta", self.zeta)


def linear_model(
    n: int, actuator: ActuatorParams, m_inertial: np.ndarray, k: float, d: float
) -> tuple[np.ndarray, np.ndarray]:
    """``(A, B)`` of the linear part for ``n`` cars of inertial masses ``m_inertial``
    joined by couplers of stiffness ``k`` [N/m] and damping ``d`` [N s/m]."""
    order = actuator.order
    nz = 2 * n + n * order
    A = np.zeros((nz, nz))
    B = np.zeros((nz, n))
    iv = slice(n, 2 * n)
    A[:n, iv] = np.eye(n)
    Kc = coupler_matrix(n)
    minv = 1.0 / m_inertial
    A[iv, :n] = (k * Kc) * minv[:, None]
    A[iv, iv] = (d * Kc) * minv[:, None]
    if order == 0:
        B[iv, :] = np.diag(minv)
    elif order == 1:
        iF = slice(2 * n, 3 * n)
        A[iv, iF] = np.diag(minv)
        A[iF, iF] = -np.eye(n) / actuator.tau_s
        B[iF, :] = np.eye(n) / actuator.tau_s
    else:
        iF = slice(2 * n, 3 * n)
        iFd = slice(3 * n, 4 * n)
        w = actuator.omega_n_radps
        A[iv, iF] = np.diag(minv)
        A[iF, iFd] = np.eye(n)
        A[iFd, iF] = -(w**2) * np.eye(n)
        A[iFd, iFd] = -2 * actuator.zeta * w * np.eye(n)
        B[iFd, :] = (w**2) * np.eye(n)
    return A, B
