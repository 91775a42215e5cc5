"""Per-step min-γ LMI of paper 003 (Theorem 3), built once with cvxpy and solved by Clarabel.

Kothare, Balakrishnan & Morari (1996), Automatica 32(10), Thm. 1 and §3.2, with the
T-S rules of 003. Stage cost ``q_v Σ e_i² + q_dx Σ δ_j² [cm²] + r_e Σ ũ_i² [kN²]``
(003 eq. 11: safety/comfort, energy and tracking terms; the energy weight r_e is the
input weight), i.e. ``xᵀ W x + gᵀ R g`` with ``W = Cᵀ C`` and ``R`` in the scaled
reduced coordinates (:meth:`ReducedTrainModel.weights`). At the current state x::

    minimise γ over Q = Qᵀ, Y_1..Y_r, X_1..X_r, γ
    [[1, xᵀ], [x, Q]] ⪰ 0,   Q ⪰ ρ² I
    for every pair i ≤ j (Tanaka, Ikeda & Wang 1998 relaxation of the PDC conditions):
      [[Q, G_ijᵀ, (W½ Q)ᵀ, (R½ Ȳ_ij)ᵀ], [G_ij, Q, 0, 0], [W½ Q, 0, γI, 0],
       [R½ Ȳ_ij, 0, 0, γI]] ⪰ 0,
      G_ij = (A_i Q + B_i Y_j + A_j Q + B_j Y_i)/2,  Ȳ_ij = (Y_i + Y_j)/2
    for every rule j (input constraint, Kothare eq. 33 with the per-car output map C_u):
      [[X_j, C_u Y_j], [(C_u Y_j)ᵀ, Q]] ⪰ 0,   (X_j)_ll ≤ ū_l²

PDC gains ``F_j = Y_j Q⁻¹`` (Tanaka & Wang 2001, ch. 2), law ``g = Σ h_j(e_1) F_j x``.
Because Σ_ij h_i h_j of the pair LMIs is the Kothare LMI of the blended closed loop
``A(h) + B(h) F(h)``, ``V(x) = xᵀ P x`` with ``P = γ Q⁻¹`` decreases by at least the
stage cost for every membership vector h, and the ellipsoid ``xᵀ Q⁻¹ x ≤ 1`` is
invariant with every car's force deviation within ū on it. ρ (the controller's
``floor``, default 0.05 scaled units) keeps the problem well posed at x ≈ 0 (there
γ → 0 and Q → 0 otherwise).

The problem is built once per shape with ``cp.Parameter`` s (rule matrices, state,
weight factors, bounds; DPP-compliant, so a re-solve only updates parameter values) and
shared by all controllers; solves are serialised by a lock.
"""

from __future__ import annotations

import math
import threading
import time
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import cvxpy as cp
import numpy as np

__all__ = ["KothareLMI", "LMISolution"]


@dataclass
class LMISolution:
    """Result of one LMI solve: γ, Q, Y_i, PDC gains F_i = Y_i Q⁻¹, P = γ Q⁻¹."""

    gamma: float
    Q: np.ndarray
    Y: list[np.ndarray]
    F: list[np.ndarray]
    P: np.ndarray
    Q_inv: np.ndarray
    status: str
    solve_time_s: float
    wall_s: float
    iterations: int
    x: np.ndarray


def _sqrt_factor(M: np.ndarray) -> np.ndarray:
    """Symmetric square root ``M½`` of a positive semidefinite matrix (``M = M½ M½``)."""
    w, V = np.linalg.eigh(0.5 * (M + M.T))
    return (V * np.sqrt(np.maximum(w, 0.0))) @ V.T


class KothareLMI:
    """The min-γ LMI problem of the module docstring, built once with cvxpy Parameters.

    Shape: ``nx`` states, ``nu`` inputs, ``n_out`` constrained car forces, ``n_rules``.
    :meth:`solve` sets the parameter values and calls Clarabel; the problem is DPP, so
    cvxpy reuses its canonicalisation. Clarabel is the only solver offered
    (``docs/design/fuzzy_mpc.md`` says why).
    """

    #: Clarabel settings tried in turn: the defaults, then (on a numerical breakdown,
    #: which the nearly undamped coupler modes occasionally cause) a larger static
    #: regularisation, then no equilibration
    RETRY_SETTINGS: tuple[dict[str, Any], ...] = (
        {},
        {"static_regularization_constant": 1e-7},
        {"equilibrate_enable": False},
    )
    _cache: dict[tuple[int, int, int, int], KothareLMI] = {}
    _lock = threading.Lock()

    @classmethod
    def shared(cls, nx: int, nu: int, n_out: int, n_rules: int) -> KothareLMI:
        """One problem per shape, shared by all controllers (solves are serialised)."""
        key = (nx, nu, n_out, n_rules)
        with cls._lock:
            if key not in cls._cache:
                cls._cache[key] = cls(nx, nu, n_out, n_rules)
            return cls._cache[key]

    def __init__(self, nx: int, nu: int, n_out: int, n_rules: int) -> None:
        self.nx, self.nu, self.n_out, self.r = nx, nu, n_out, n_rules
        r = n_rules
        self.A = [cp.Parameter((nx, nx), name=f"A{i}") for i in range(r)]
        self.B = [cp.Parameter((nx, nu), name=f"B{i}") for i in range(r)]
        self.x = cp.Parameter(nx, name="x")
        self.Wh = cp.Parameter((nx, nx), name="W_half")
        self.Rh = cp.Parameter((nu, nu), name="R_half")
        self.Cu = cp.Parameter((n_out, nu), name="C_u")
        self.ubar2 = cp.Parameter(n_out, nonneg=True, name="u_bar_sq")
        self.rho2 = cp.Parameter(nonneg=True, name="rho_sq")
        self.Q = cp.Variable((nx, nx), symmetric=True, name="Q")
        self.Y = [cp.Variable((nu, nx), name=f"Y{i}") for i in range(r)]
        self.X = [cp.Variable((n_out, n_out), symmetric=True, name=f"X{i}") for i in range(r)]
        self.gamma = cp.Variable(name="gamma")
        Q, Y, g = self.Q, self.Y, self.gamma
        xc = cp.reshape(self.x, (nx, 1), order="F")
        cons = [
            cp.bmat([[np.ones((1, 1)), xc.T], [xc, Q]]) >> 0,
            Q - self.rho2 * np.eye(nx) >> 0,
        ]
        Z = np.zeros
        for i in range(r):
            for j in range(i, r):
                Gm = 0.5 * (self.A[i] @ Q + self.B[i] @ Y[j] + self.A[j] @ Q + self.B[j] @ Y[i])
                Nm = self.Rh @ (0.5 * (Y[i] + Y[j]))
                WQ = self.Wh @ Q
                L = cp.bmat(
                    [
                        [Q, Gm.T, WQ.T, Nm.T],
                        [Gm, Q, Z((nx, nx)), Z((nx, nu))],
                        [WQ, Z((nx, nx)), g * np.eye(nx), Z((nx, nu))],
                        [Nm, Z((nu, nx)), Z((nu, nx)), g * np.eye(nu)],
                    ]
                )
                cons.append(0.5 * (L + L.T) >> 0)
        for j in range(r):
            CY = self.Cu @ Y[j]
            Lu = cp.bmat([[self.X[j], CY], [CY.T, Q]])
            cons.append(0.5 * (Lu + Lu.T) >> 0)
            cons.append(cp.diag(self.X[j]) <= self.ubar2)
        self.problem = cp.Problem(cp.Minimize(g), cons)
        if not self.problem.is_dpp():  # pragma: no cover - construction guarantees DPP
            raise RuntimeError("fuzzy MPC LMI problem is not DPP")

    def solve(
        self,
        A: Sequence[np.ndarray],
        B: Sequence[np.ndarray],
        x: np.ndarray,
        W: np.ndarray,
        R: np.ndarray,
        C_u: np.ndarray,
        u_bar: np.ndarray,
        rho: float,
    ) -> LMISolution:
        """Solve at state ``x`` for rule models (A_i, B_i), weights W, R and bounds ū."""
        with self._lock:
            for i in range(self.r):
                self.A[i].value = np.asarray(A[i], float)
                self.B[i].value = np.asarray(B[i], float)
            self.x.value = np.asarray(x, float)
            self.Wh.value = _sqrt_factor(W)
            self.Rh.value = _sqrt_factor(R)
            self.Cu.value = np.asarray(C_u, float)
            self.ubar2.value = np.asarray(u_bar, float) ** 2
            self.rho2.value = float(rho) ** 2
            t0 = time.perf_counter()
            status = "not solved"
            solver_time = 0.0
            iters = 0
            for opts in self.RETRY_SETTINGS:
                try:
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore", UserWarning)  # "may be inaccurate"
                        self.problem.solve(solver=cp.CLARABEL, **opts)
                    status = str(self.problem.status)
                    stats = self.problem.solver_stats
                    solver_time += float(stats.solve_time or 0.0)
                    iters += int(stats.num_iters or 0)
                except cp.error.SolverError as exc:
                    status = f"solver_error: {exc}"
                if status in ("optimal", "optimal_inaccurate"):
                    break
            wall = time.perf_counter() - t0
            ok = status in ("optimal", "optimal_inaccurate") and self.Q.value is not None
            if not ok:
                nan = np.full((self.nx, self.nx), np.nan)
                return LMISolution(
                    math.nan, nan, [], [], nan, nan, status, solver_time, wall, iters, np.array(x)
                )
            Q = 0.5 * (self.Q.value + self.Q.value.T)
            Qi = np.linalg.inv(Q)
            Qi = 0.5 * (Qi + Qi.T)
            Ys = [np.array(y.value) for y in self.Y]
            gam = float(self.gamma.value)
            return LMISolution(
                gamma=gam,
                Q=Q,
                Y=Ys,
                F=[y @ Qi for y in Ys],
                P=gam * Qi,
                Q_inv=Qi,
                status=status,
                solve_time_s=solver_time,
                wall_s=wall,
                iterations=iters,
                x=np.array(x, float),
            )
