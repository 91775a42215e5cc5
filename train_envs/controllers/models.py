"""Linear prediction models shared by the controllers.

Two models, each built by one function per coordinate choice so that every controller
assembles the same matrices with the same floating-point operations:

**Single point with actuator lag and dead time** (001 eq. 8–10; 000 eq. 5 for one car),
acceleration units, ``k_v = R'(v_lin)/M'``::

    ṡ = v,   v̇ = a − k_v v + w,   ȧ = (a_cmd − a)/τ     (τ > 0; state [s, v, a])
    ṡ = v,   v̇ = a_cmd − k_v v + w                        (no lag; state [s, v])

Dead time ``T_d = l T``: ``x(k+l) = A^l x(k) + Γ_u u_pend + Γ_w w_pend`` with the ``l``
commands already sent, oldest first (001 eq. 10).

**n cars joined by spring-damper couplers** (000 eq. 1–7, 002 eq. 3), cars numbered from
the front, coupler j between cars j and j+1, force ``f_j = k δ_j + d (v_j − v_{j+1})``::

    m_i' v̇_i = u_i + f_{i−1} − f_i − R_i'(v_lin) v_i + m_i' w_i

in positions ``[q_1..q_n, v_1..v_n]`` (q shifted by the rest spacing, u in kN) or in
coupler displacements ``[ξ_1..ξ_{n−1} (mm), v_1..v_n]`` (u in kN). The per-stage affine
term ``w_i`` holds the Davis offset about the linearisation and the gradient force.

Every continuous model is discretised exactly by one zero-order hold of ``[B E]``
(:func:`discretise`).
"""

from __future__ import annotations

import numpy as np

from train_envs.mpc.design import zoh
from train_envs.plants.physics import coupler_matrix, davis_N
from train_envs.trains import G

__all__ = [
    "coupled_cars_continuous",
    "coupled_cars_relative_continuous",
    "coupler_pattern",
    "dead_time_maps",
    "difference_matrix",
    "discretise",
    "gradient_accel",
    "point_lag_continuous",
    "resistance_offset_accel",
]


# ------------------------------------------------------------------ discretisation
def discretise(
    Ac: np.ndarray, Bc: np.ndarray, Ec: np.ndarray, dt_s: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact ZOH of ``ẋ = Ac x + Bc u + Ec w``: ``(Ad, Bd, Ed)`` from one ``expm``.

    ``Bd`` and ``Ed`` are column slices of the same discretised ``[B E]``.
    """
    nu = Bc.shape[1]
    Ad, BE = zoh(Ac, np.hstack([Bc, Ec]), dt_s)
    return Ad, BE[:, :nu], BE[:, nu:]


def dead_time_maps(
    Ad: np.ndarray, bd: np.ndarray, ed: np.ndarray, delay_steps: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(A^l, Γ_u, Γ_w)`` of ``x(k+l) = A^l x + Γ_u u_pend + Γ_w w_pend`` (001 eq. 10).

    ``bd``, ``ed``: the single input and affine columns (1-D). Column j of ``Γ_u`` is
    ``A^{l−1−j} b`` (command j of the ``l`` pending ones, oldest first).
    """
    l = int(delay_steps)  # noqa: E741 - the paper's symbol
    pows = [np.eye(Ad.shape[0])]
    for _ in range(l):
        pows.append(Ad @ pows[-1])
    Gam_u = np.zeros((Ad.shape[0], l))
    Gam_w = np.zeros((Ad.shape[0], l))
    for j in range(l):
        Gam_u[:, j] = pows[l - 1 - j] @ bd
        Gam_w[:, j] = pows[l - 1 - j] @ ed
    return pows[l], Gam_u, Gam_w


# ------------------------------------------------------------------ single point
def point_lag_continuous(kv_1ps: float, tau_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Continuous ``(Ac, Bc, Ec)`` of the single-point model (module docstring).

    ``tau_s > 0``: state ``[s, v, a]`` with the first-order lag; ``tau_s <= 0``: state
    ``[s, v]``, the command acting directly. Input and affine term in m/s².
    """
    kv = kv_1ps
    if tau_s > 0:
        Ac = np.array([[0.0, 1.0, 0.0], [0.0, -kv, 1.0], [0.0, 0.0, -1.0 / tau_s]])
        Bc = np.array([[0.0], [0.0], [1.0 / tau_s]])
        Ec = np.array([[0.0], [1.0], [0.0]])
    else:
        Ac = np.array([[0.0, 1.0], [0.0, -kv]])
        Bc = np.array([[0.0], [1.0]])
        Ec = np.array([[0.0], [1.0]])
    return Ac, Bc, Ec


# ------------------------------------------------------------------ n cars
def difference_matrix(n: int) -> np.ndarray:
    """``(n−1) × n`` matrix D with ``(D q)_j = q_j − q_{j+1}`` (coupler deformations)."""
    D = np.zeros((n - 1, n))
    for j in range(n - 1):
        D[j, j], D[j, j + 1] = 1.0, -1.0
    return D


def coupler_pattern(n: int) -> np.ndarray:
    """``n × n`` matrix ``K_c = −DᵀD``: car i's coupler force is ``k (K_c q)_i`` [N]
    (:func:`~train_envs.plants.physics.coupler_matrix`)."""
    return coupler_matrix(n)


def coupled_cars_continuous(
    k_N_per_m: float, d_Ns_per_m: float, m_inertial: np.ndarray, slope: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Continuous ``(Ac, Bc, Ec)`` of the n-car model in positions ``[q, v]``.

    ``slope``: per-car ``R_i'(v_lin)`` [N s/m]; input u in kN; affine term per car [m/s²].
    """
    mi = m_inertial
    n = mi.size
    Kc = coupler_pattern(n)
    Ac = np.zeros((2 * n, 2 * n))
    Ac[:n, n:] = np.eye(n)
    Ac[n:, :n] = k_N_per_m * Kc / mi[:, None]
    Ac[n:, n:] = d_Ns_per_m * Kc / mi[:, None] - np.diag(slope / mi)
    Bc = np.zeros((2 * n, n))
    Bc[n:, :] = np.diag(1000.0 / mi)
    Ec = np.zeros((2 * n, n))
    Ec[n:, :] = np.eye(n)
    return Ac, Bc, Ec


def coupled_cars_relative_continuous(
    k_N_per_m: float, d_Ns_per_m: float, m_inertial: np.ndarray, slope: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Continuous ``(Ac, Bc, Ec)`` of the n-car model in ``[ξ (mm), v]`` (002 eq. 3).

    ``ξ_j = 1000 (q_j − q_{j+1})``, tension > 0; input u in kN; affine term [m/s²].
    """
    mi, k, dmp = m_inertial, k_N_per_m, d_Ns_per_m
    n = mi.size
    nx = 2 * n - 1
    Ac = np.zeros((nx, nx))
    for j in range(n - 1):  # dξ_j/dt [mm/s] = 1000 (v_j − v_{j+1})
        Ac[j, n - 1 + j] = 1000.0
        Ac[j, n + j] = -1000.0
    # m_i dv_i/dt = 1000 u_i + f_{i−1} − f_i − slope_i v_i,  f_j = k ξ_j/1000 + d (v_j − v_{j+1})
    for i in range(n):
        r = n - 1 + i
        if i > 0:
            Ac[r, i - 1] += k / 1000.0 / mi[i]
            Ac[r, r - 1] += dmp / mi[i]
            Ac[r, r] -= dmp / mi[i]
        if i < n - 1:
            Ac[r, i] -= k / 1000.0 / mi[i]
            Ac[r, r] -= dmp / mi[i]
            Ac[r, r + 1] += dmp / mi[i]
        Ac[r, r] -= slope[i] / mi[i]
    Bc = np.zeros((nx, n))
    Bc[n - 1 :, :] = np.diag(1000.0 / mi)
    Ec = np.zeros((nx, n))
    Ec[n - 1 :, :] = np.eye(n)
    return Ac, Bc, Ec


def resistance_offset_accel(
    ca: np.ndarray,
    cb: np.ndarray,
    cc: np.ndarray,
    slope: np.ndarray,
    m_inertial: np.ndarray,
    v_r: np.ndarray,
) -> np.ndarray:
    """``(R_i(v_r) − R_i'(v_lin) v_r)/m_i'`` per stage and car, shape ``(len(v_r), n)``.

    The part of the Davis resistance the linear model's slope does not carry; the
    affine term is its negative. ``v_r`` is clipped at zero (no ``a`` at standstill).
    """
    vr = np.maximum(v_r, 0.0)[:, None]
    R = davis_N(ca * (vr > 0), cb, cc, vr)
    return (R - slope * vr) / m_inertial


def gradient_accel(m: np.ndarray, m_inertial: np.ndarray, theta_permil: np.ndarray) -> np.ndarray:
    """Per-car gradient deceleration ``m_i g θ/1000 / m_i'`` [m/s²] (θ broadcast)."""
    return m * G * theta_permil / 1000.0 / m_inertial
