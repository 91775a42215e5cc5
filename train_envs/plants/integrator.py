"""Exponential integrator for semi-linear plant models ż = A z + B w + N(z, t).

The linear part (couplers, actuator lags, kinematics) is integrated exactly, the
nonlinear part (Davis v², gradient along the track, disturbances) with second-order
accuracy, by the exponential time-differencing Runge–Kutta scheme ETD2RK of
Cox & Matthews (J. Comput. Phys. 176, 2002, eq. 22):

    a       = e^{Ah} z_n + h φ1(Ah) (B w + N(z_n, t_n))
    z_{n+1} = a + h φ2(Ah) (N(a, t_n + h) − N(z_n, t_n))

with φ1(X) = X⁻¹(e^X − I) and φ2(X) = X⁻²(e^X − I − X). Both are read off one matrix
exponential of the block matrix [[Ah, I, 0], [0, 0, I], [0, 0, 0]] (scipy.linalg.expm),
whose first block row is [e^{Ah}, φ1(Ah), φ2(Ah)] (Higham, *Functions of Matrices*,
2008, Thm. 10.11 / Al-Mohy & Higham 2011). The input w is held constant over a step
(zero-order hold), so for N ≡ 0 the scheme *is* the exact ZOH discretisation: the stiff
coupler modes of a k_s = 1e7 N/m train stay exact whatever the step.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.linalg import expm


class ETD2Integrator:
    """Precomputed ETD2RK stepper for a fixed (A, B, h)."""

    def __init__(
        self, A: np.ndarray, B: np.ndarray, h: float, nonlinear_rows: slice | None = None
    ) -> None:
        A = np.atleast_2d(np.asarray(A, dtype=float))
        B = np.asarray(B, dtype=float).reshape(A.shape[0], -1)
        n = A.shape[0]
        big = np.zeros((3 * n, 3 * n))
        big[:n, :n] = A * h
        big[:n, n : 2 * n] = np.eye(n)
        big[n : 2 * n, 2 * n :] = np.eye(n)
        E = expm(big)
        self.h = float(h)
        self.Phi = E[:n, :n].copy()
        self.hphi1 = h * E[:n, n : 2 * n]
        self.hphi2 = h * E[:n, 2 * n :]
        self.Gamma = self.hphi1 @ B  # exact ZOH input matrix
        self.n = n
        # the nonlinear term only enters these rows of ż (the accelerations)
        rows = nonlinear_rows if nonlinear_rows is not None else slice(0, n)
        self.P1 = np.ascontiguousarray(self.hphi1[:, rows])
        self.P2 = np.ascontiguousarray(self.hphi2[:, rows])

    def step(
        self,
        z: np.ndarray,
        w: np.ndarray,
        t: float,
        nonlinear: Callable[[np.ndarray, float], np.ndarray],
        gw: np.ndarray | None = None,
    ) -> np.ndarray:
        """Advance ``z`` by one step ``h`` with input ``w`` held constant.

        ``nonlinear(z, t)`` returns the nonlinear part of ż restricted to the rows
        ``nonlinear_rows`` given at construction. ``gw`` optionally passes ``Γ w``
        precomputed (an input held over several steps); it must equal
        ``self.Gamma @ w``.
        """
        # (``M.dot(x)`` is the same BLAS matrix-vector product as ``M @ x``, with less
        # call overhead on these small matrices)
        n0 = nonlinear(z, t)
        a = self.Phi.dot(z) + (self.Gamma.dot(w) if gw is None else gw) + self.P1.dot(n0)
        n1 = nonlinear(a, t + self.h)
        return a + self.P2.dot(n1 - n0)
