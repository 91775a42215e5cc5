r"""Design helpers shared by the controllers: terminal costs and discretisation.

* :func:`terminal_cost_dare` -- LQR terminal weight from the discrete algebraic Riccati
  equation :math:`P = A^\top P A - A^\top P B (R + B^\top P B)^{-1} B^\top P A + Q_x`;
* :func:`terminal_cost_lyapunov` -- cost-to-go of a fixed stable loop,
  :math:`A_{cl}^\top P A_{cl} - P + Q_x = 0`; :class:`LyapunovSolver` -- the same for
  many :math:`Q_x` and one loop (its linear system factorised once);
* :func:`augmented_terminal_cost` -- the Riccati terminal cost of the
  :math:`\Delta u`-augmented model :math:`\xi = [x; u_{k-1}]` (papers 000 sec. III-B,
  001 eq. 11, 20), solved by :func:`dare_doubling` (scipy's Schur method where the
  doubling does not converge);
* :func:`zoh` -- exact zero-order-hold discretisation (one matrix exponential).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike
from scipy.linalg import expm, lu_factor, lu_solve, solve_discrete_are, solve_discrete_lyapunov

from train_envs._jit import implementation, register
from train_envs.mpc.description import _matrix, _weight


def terminal_cost_dare(
    A: ArrayLike, B: ArrayLike, Qx: ArrayLike, R: ArrayLike
) -> tuple[np.ndarray, np.ndarray]:
    r"""Infinite-horizon LQR terminal weight.

    Solves :math:`P = A^\top P A - A^\top P B (R + B^\top P B)^{-1} B^\top P A + Q_x`
    and returns ``(P, K)`` with :math:`K = (R + B^\top P B)^{-1} B^\top P A`
    (control law :math:`u = -K x`).
    """
    A_ = _matrix("A", A)
    n = A_.shape[0]
    if A_.shape != (n, n):
        raise ValueError(f"A must be square, got shape {A_.shape}")
    B_ = _matrix("B", B, column=True)
    if B_.shape[0] != n:
        raise ValueError(f"B must have {n} rows to match A, got shape {B_.shape}")
    m = B_.shape[1]
    Q_ = _weight("Qx", Qx, n)
    R_ = _weight("R", R, m)
    try:
        P = solve_discrete_are(A_, B_, Q_, R_)
    except (np.linalg.LinAlgError, ValueError) as exc:
        raise ValueError(f"terminal_cost_dare: no stabilising solution ({exc})") from exc
    P = 0.5 * (P + P.T)
    K = np.linalg.solve(R_ + B_.T @ P @ B_, B_.T @ P @ A_)
    return P, K


def terminal_cost_lyapunov(A_cl: ArrayLike, Qx: ArrayLike) -> np.ndarray:
    r"""Terminal weight of a fixed stabilising closed loop :math:`x^+ = A_{cl} x`.

    Returns ``P`` with :math:`A_{cl}^\top P A_{cl} - P + Q_x = 0` (the cost-to-go
    :math:`\sum_k x_k^\top Q_x x_k`).  For a local law ``u = -K x`` pass
    ``A_cl = A - B K`` and ``Qx + K.T @ R @ K``.  Raises ``ValueError`` if
    ``A_cl`` is not Schur stable.
    """
    Acl = _matrix("A_cl", A_cl)
    n = Acl.shape[0]
    if Acl.shape != (n, n):
        raise ValueError(f"A_cl must be square, got shape {Acl.shape}")
    Q_ = _weight("Qx", Qx, n)
    rad = float(np.max(np.abs(np.linalg.eigvals(Acl)))) if n else 0.0
    if rad >= 1.0:
        raise ValueError(f"A_cl must be Schur stable (spectral radius {rad:.6g} >= 1)")
    P = solve_discrete_lyapunov(Acl.T, Q_)
    return 0.5 * (P + P.T)


class LyapunovSolver:
    r""":func:`terminal_cost_lyapunov` for one stable loop ``A_cl`` and many ``Q_x``.

    ``A_cl`` is checked (square, finite, Schur stable) once. For ``n < 10`` scipy's
    direct method solves :math:`(I - A_{cl}^\top \otimes A_{cl}^\top) \operatorname{vec}
    P = \operatorname{vec} Q_x` with LAPACK ``getrf`` + ``getrs``; here ``getrf`` runs
    once (:func:`scipy.linalg.lu_factor`) and each :meth:`solve` is the ``getrs`` of the
    same factors, so its result equals :func:`terminal_cost_lyapunov`'s bit for bit
    (tested). Larger loops call :func:`terminal_cost_lyapunov` itself.
    """

    def __init__(self, A_cl: ArrayLike) -> None:
        Acl = _matrix("A_cl", A_cl)
        n = Acl.shape[0]
        if Acl.shape != (n, n):
            raise ValueError(f"A_cl must be square, got shape {Acl.shape}")
        rad = float(np.max(np.abs(np.linalg.eigvals(Acl)))) if n else 0.0
        if rad >= 1.0:
            raise ValueError(f"A_cl must be Schur stable (spectral radius {rad:.6g} >= 1)")
        self.n = n
        self._Acl = Acl
        a = Acl.T
        self._lu = lu_factor(np.eye(n * n) - np.kron(a, a.conj())) if 0 < n < 10 else None

    def solve(self, Qx: ArrayLike) -> np.ndarray:
        """``P`` with ``A_clᵀ P A_cl − P + Q_x = 0`` (symmetrised, as
        :func:`terminal_cost_lyapunov` returns it)."""
        if self._lu is None:
            return terminal_cost_lyapunov(self._Acl, Qx)
        Q_ = _weight("Qx", Qx, self.n)
        P = lu_solve(self._lu, Q_.flatten()).reshape(Q_.shape)
        return 0.5 * (P + P.T)


def zoh(Ac: np.ndarray, Bc: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order-hold discretisation of ``ẋ = Ac x + Bc u`` (one ``expm``)."""
    n, m = Ac.shape[0], Bc.shape[1]
    M = np.zeros((n + m, n + m))
    M[:n, :n] = Ac * dt
    M[:n, n:] = Bc * dt
    E = expm(M)
    return E[:n, :n], E[:n, n:]


def augmented_model(A: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The Δu-augmented model of ``x⁺ = A x + B u``: ``ξ = [x; u(k−1)]``, input ``Δu``,
    ``Aa = [[A, B], [0, I]]``, ``Ba = [B; I]`` (what :func:`augmented_terminal_cost`
    solves on; a controller that solves it for many weights on one model keeps it)."""
    n, m = B.shape
    Aa = np.zeros((n + m, n + m))
    Aa[:n, :n] = A
    Aa[:n, n:] = B
    Aa[n:, n:] = np.eye(m)
    Ba = np.zeros((n + m, m))
    Ba[:n] = B
    Ba[n:] = np.eye(m)
    return Aa, Ba


def augmented_terminal_cost(
    A: np.ndarray,
    B: np.ndarray,
    Qx: np.ndarray,
    R: np.ndarray,
    *,
    gain: bool = True,
    model: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """Riccati terminal cost of the Δu-augmented model ξ = [x; u(k−1)].

    Returns ``(P_aug, K, P_x)``: the full (n+m)² solution, the LQR gain of
    ``Δu = −K ξ`` (``None`` with ``gain=False``: a weight change that needs only the
    cost skips its solve) and the x-block used as the core's state terminal weight.
    ``model``: :func:`augmented_model` of ``(A, B)`` if the caller has it.
    """
    n, m = B.shape
    Aa, Ba = augmented_model(A, B) if model is None else model
    Qa = np.zeros((n + m, n + m))
    Qa[:n, :n] = Qx
    try:
        # the doubling iteration: 2-5x cheaper than scipy's QZ method on these small
        # models and free of its reordering failures on badly scaled weights (e.g. an
        # RL agent's q_dx = 1e8 with r_du = 1e-6); measurements: docs/design/mpc_engine.md
        P = dare_doubling(Aa, Ba, Qa, R)
    except np.linalg.LinAlgError:
        P = solve_discrete_are(Aa, Ba, Qa, R)
    P = 0.5 * (P + P.T)
    K = np.linalg.solve(R + Ba.T @ P @ Ba, Ba.T @ P @ Aa) if gain else None
    return P, K, P[:n, :n].copy()


def _doubling_kernel(
    A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: np.ndarray, tol: float
) -> tuple[np.ndarray, bool]:
    """The iteration of :func:`dare_doubling` on C-contiguous float arrays: ``(H, converged)``
    (plain numpy the compiler accepts; registered as the twin ``"dare_doubling"``)."""
    n = A.shape[0]
    Ak = A.copy()
    G = B @ np.linalg.solve(R, B.T.copy())
    H = Q.copy()
    eye = np.eye(n)
    AG = np.empty((n, 2 * n))  # [A | G]: both solves with W in one call
    for _ in range(80):
        AG[:, :n] = Ak
        AG[:, n:] = G
        X = np.linalg.solve(eye + G @ H, AG)
        WA = X[:, :n].copy()
        H_new = H + Ak.T.copy() @ H @ WA
        G = G + Ak @ X[:, n:].copy() @ Ak.T.copy()
        Ak = Ak @ WA
        H_new = 0.5 * (H_new + H_new.T)
        step = np.abs(H_new - H).sum(axis=0).max()  # 1-norm of the change
        H = H_new
        if not step == step or not np.all(np.isfinite(H)):
            return H, False
        if step <= tol * max(1.0, np.abs(H).sum(axis=0).max()):
            return H, True
    return H, False


register("dare_doubling", _doubling_kernel)


def dare_doubling(
    A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: np.ndarray, *, tol: float = 1e-12
) -> np.ndarray:
    """Stabilising solution of the DARE by the structure-preserving doubling algorithm.

    ``P = AᵀPA − AᵀPB (R + BᵀPB)⁻¹ BᵀPA + Q`` (Chu, Fan & Lin, "A structure-preserving
    doubling algorithm for continuous-time algebraic Riccati equations", Linear
    Algebra Appl. 396, 2005, and its discrete-time form): with ``A₀ = A``,
    ``G₀ = B R⁻¹ Bᵀ``, ``H₀ = Q``, each step ``W = I + G H``::

        A ← A W⁻¹ A,   G ← G + A W⁻¹ G Aᵀ,   H ← H + Aᵀ H W⁻¹ A

    and ``H → P`` quadratically (``H_k`` is the Riccati iterate of ``2^k`` steps).
    Runs the compiled twin where available (same operations). Raises
    ``np.linalg.LinAlgError`` if it does not converge in 80 doublings.
    """
    args = [np.ascontiguousarray(X, dtype=float) for X in (A, B, Q, R)]
    H, converged = implementation("dare_doubling")(*args, float(tol))
    if not converged:
        raise np.linalg.LinAlgError("DARE doubling iteration did not converge")
    return H
