"""Reduced design model of paper 003: the error model about the cruise equilibrium.

**Error model (003 §2.1, eq. 4–8).** n cars joined by linear couplers (stiffness k,
damping d), Davis resistance per car ``R_i(v) = a_i + b_i v + c_i v²`` (aero ``c v²`` on
the lead car only when the train says so, 003's assumption). Around the cruise
equilibrium at the reference speed v_r (zero coupler displacement, equilibrium forces
``u_i^eq = R_i(v_r) + m_i g θ_i/1000 [+ m_i' a_r]``) the state is the coupler
displacements δ_j = q_j − q_{j+1} and the speed errors e_i = v_i − v_r::

    δ̇ = D e
    M' ė = ũ − Dᵀ(k δ + d D e) − S(e_1) e,   S = diag(b_i + c_i (2 v_r + e_1))

(D the (n−1)×n difference matrix, ũ = u − u^eq). The only nonlinearity is the aero
term ``c_1 (2 v_r + e_1) e_1`` of the lead car; rule i of the T-S model takes the slope
at e_1 = ε_i and is discretised exactly (zero-order hold, period T).

**Modal reduction (ours; 003 is silent on computation).** The generalised eigenproblem
``k DᵀD φ = ω² M' φ`` gives the rigid mode and the n−1 coupler modes; the design keeps
the rigid mode (its speed) and the ``n_modes`` lowest coupler modes (displacement and
speed each), and the controller commands forces in the span of those mode shapes,
``ũ = M' Φ_r g``, so the truncated modes are not excited by the feedback.
``n_modes = n − 1`` is the exact 003 model in modal coordinates. States and inputs are
scaled so that one unit is 1 m/s of car speed, 1 cm of coupler displacement and 1 kN of
car force (conditioning of the LMI).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import eigh

from train_envs.controllers.models import difference_matrix
from train_envs.mpc import zoh
from train_envs.plants.physics import coupler_matrix

__all__ = ["ReducedTrainModel"]


@dataclass
class ReducedTrainModel:
    """Modal reduction of 003's error model (module docstring), in scaled units.

    Built from per-car inertial masses ``m_inertial`` [kg], coupler ``k``, ``d``, Davis
    ``b`` and ``c`` per car, period ``dt`` and ``n_modes`` retained coupler modes.
    Scaled state: ``x = [ė_0, η_1, ė_1, …, η_m, ė_m]`` (rigid-mode speed, then coupler
    mode displacement and speed), input ``g`` (modal forces); one unit is 1 m/s, 1 cm
    of coupler displacement, 1 kN of car force at the car that moves most in the mode.
    """

    m_inertial: np.ndarray
    k: float
    d: float
    b: np.ndarray
    c: np.ndarray
    dt: float
    n_modes: int | None = None
    nx: int = field(init=False)
    nu: int = field(init=False)

    def __post_init__(self) -> None:
        m = np.asarray(self.m_inertial, float)
        n = m.size
        if n < 2:
            raise ValueError(f"the fuzzy MPC needs at least 2 cars, got {n}")
        nm = n - 1 if self.n_modes is None else int(self.n_modes)
        if not 0 <= nm <= n - 1:
            raise ValueError(f"n_modes must lie in [0, {n - 1}] for {n} cars, got {self.n_modes}")
        self.n = n
        self.m_ = nm
        D = difference_matrix(n)
        self.D = D
        lap = 0.0 - coupler_matrix(n)  # DᵀD
        M = np.diag(m)
        w2, Phi = eigh(self.k * lap, M)  # Phiᵀ M Phi = I, ascending ω²
        w2[0] = 0.0
        self.w2 = w2
        self.Phi = Phi
        self._lap = lap
        self._M = M
        keep = list(range(nm + 1))
        Pr = Phi[:, keep]
        self.Pr = Pr
        nx, nu = 1 + 2 * nm, nm + 1
        self.nx, self.nu = nx, nu
        self._iv = [0] + [2 * kk for kk in range(1, nm + 1)]
        self._ip = [2 * kk - 1 for kk in range(1, nm + 1)]
        # scaling: 1 m/s at the fastest car, 1 cm at the most deformed coupler, 1 kN
        sz = np.ones(nx)
        for kk in range(nm + 1):
            sz[self._iv[kk]] = np.max(np.abs(Phi[:, kk]))
        for kk in range(1, nm + 1):
            sz[self._ip[kk - 1]] = 100.0 * np.max(np.abs(D @ Phi[:, kk]))
        su = np.array([np.max(np.abs(M @ Phi[:, kk])) / 1000.0 for kk in range(nm + 1)])
        self.sz, self.su = sz, su
        # measurement map: full (δ, e) -> scaled reduced state
        dphi = D @ Phi[:, 1:]  # (n-1)x(n-1), invertible
        eta_of_delta = np.linalg.solve(dphi, np.eye(n - 1))[:nm]
        Tm = np.zeros((nx, 2 * n - 1))
        etad = Pr.T @ M  # modal speeds of the retained modes from e
        for kk in range(nm + 1):
            Tm[self._iv[kk], n - 1 :] = etad[kk] * sz[self._iv[kk]]
        for kk in range(1, nm + 1):
            Tm[self._ip[kk - 1], : n - 1] = eta_of_delta[kk - 1] * sz[self._ip[kk - 1]]
        self.T_meas = Tm
        # outputs in physical units from the scaled state / input
        Ce = np.zeros((n, nx))
        for kk in range(nm + 1):
            Ce[:, self._iv[kk]] = Phi[:, kk] / sz[self._iv[kk]]
        Cd = np.zeros((n - 1, nx))
        for kk in range(1, nm + 1):
            Cd[:, self._ip[kk - 1]] = 100.0 * (D @ Phi[:, kk]) / sz[self._ip[kk - 1]]
        self.C_e, self.C_d = Ce, Cd
        self.C_u = (M @ Pr) / 1000.0 / su[None, :]  # per-car force [kN] from scaled g

    def state(self, delta_m: np.ndarray, e_mps: np.ndarray) -> np.ndarray:
        """Scaled reduced state from coupler displacements [m] and speed errors [m/s]."""
        return self.T_meas @ np.concatenate([delta_m, e_mps])

    def continuous(self, slopes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Scaled continuous (A, B) for per-car resistance slopes ``∂R_i/∂v`` [N s/m]."""
        nx, nu, nm = self.nx, self.nu, self.m_
        Pr = self.Pr
        Cm = Pr.T @ (self.d * self._lap + np.diag(slopes)) @ Pr
        A = np.zeros((nx, nx))
        B = np.zeros((nx, nu))
        iv, ip = self._iv, self._ip
        for kk in range(nm + 1):
            for ll in range(nm + 1):
                A[iv[kk], iv[ll]] = -Cm[kk, ll]
            B[iv[kk], kk] = 1.0
        for kk in range(1, nm + 1):
            A[ip[kk - 1], iv[kk]] = 1.0
            A[iv[kk], ip[kk - 1]] = -self.w2[kk]
        S = np.diag(self.sz)
        Si = np.diag(1.0 / self.sz)
        return S @ A @ Si, S @ B @ np.diag(1.0 / self.su)

    def rules(self, v_r: float, centres: Sequence[float]) -> tuple[list, list]:
        """Discrete (A_i, B_i) of every rule: lead-car slope at e_1 = ε_i (ZOH, period dt)."""
        As, Bs = [], []
        for eps in centres:
            # Davis slope b + c (2 v_r + ε): not davis_slope's b + (2 c) v₀ order
            slopes = self.b + self.c * max(2.0 * v_r + eps, 0.0)
            Ac, Bc = self.continuous(slopes)
            A, B = zoh(Ac, Bc, self.dt)
            As.append(A)
            Bs.append(B)
        return As, Bs

    def weights(self, q_v: float, q_dx: float, r_e: float) -> tuple[np.ndarray, np.ndarray]:
        """Stage weights (W, R) in scaled coordinates for the physical weights."""
        W = q_v * self.C_e.T @ self.C_e + q_dx * self.C_d.T @ self.C_d
        R = r_e * self.C_u.T @ self.C_u
        return 0.5 * (W + W.T), 0.5 * (R + R.T)
