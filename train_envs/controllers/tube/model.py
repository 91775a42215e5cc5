r"""Paper 001's stopping model, tube feedback, terminal weight and tube tightening.

Model (001 eq. 8–10): single point with a first-order brake lag and a dead time, in
acceleration units (``u`` the commanded acceleration, ``a`` the brake acceleration)::

    ṡ = v,   v̇ = a + w_ff(s, v) + w,   ȧ = (u(t − T_d) − a)/τ                  (8)

discretised exactly (zero-order hold) and augmented with the last command,
ξ = [s, v, a, u(k−1)], input Δu::

    ξ(k+1) = A ξ(k) + B Δu(k) + E (w_ff + w),   A = [[A_d, B_d], [0, 1]],
    B = [B_d; 1],   E = [E_d; 0].                                                   (9)

The dead time ``T_d = l T`` is bridged by predicting the measured state ``l`` steps
ahead with the commands already sent (eq. 10).

Feedback (001 eq. 13): ``Δu = −K (ξ − ξ_s)``, ``K`` the LQR gain of the augmented model
(DARE).  Terminal weight (001 eq. 19 with equality, the smallest solution of LMI 20)::

    A_clᵀ P A_cl − P + Q_ξ + Kᵀ R K = 0.

Tightening (001 eq. 14–16; Chisci, Rossiter & Zappa 2001): for a box ``W = [−w̄, w̄]``
and a row ``hᵀξ ≤ b`` the Pontryagin difference ``X ⊖ R_i`` is exact::

    τ_i(h) = w̄ Σ_{j<i} |hᵀ A_cl^j Ẽ| + w̄ Σ_{j<l} |hᵀ A^j E|,   Ẽ = A^l E,

the second sum (the dead-time tube ``D_l``) on the state rows only.  Every design is
cached per its inputs (bounded caches: a tuner searching weights would grow them).

Reference: L. Chisci, J. A. Rossiter, G. Zappa, "Systems with persistent disturbances:
predictive control with restricted constraints", Automatica 37 (2001).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from train_envs.controllers.models import dead_time_maps, discretise, point_lag_continuous
from train_envs.mpc.design import LyapunovSolver, terminal_cost_dare
from train_envs.validation import check_positive, check_range

__all__ = [
    "ROW_DU",
    "ROW_S",
    "ROW_U",
    "ROW_V",
    "StoppingModel",
    "core_terminal_basis",
    "TubeFeedback",
    "stopping_model",
    "terminal_weight",
    "tube_feedback",
    "tube_tightening",
]

#: constraint rows of the tightening table: s, v, u (on ξ) and Δu (= K e)
ROW_S, ROW_V, ROW_U, ROW_DU = 0, 1, 2, 3
_CACHE_MAX = 512  # entries per design cache (weights searched by a tuner would grow it)


def _cache_put(cache: dict, key: Any, value: Any) -> None:
    if len(cache) >= _CACHE_MAX:
        cache.clear()
    cache[key] = value


# ----------------------------------------------------------------------------- model
@dataclass(frozen=True)
class StoppingModel:
    """Discrete single-point braking model of 001 eq. (9) (exact ZOH) and the dead-time map.

    Attributes:
        dt_s, tau_s, delay_steps: sampling period T, lag τ and dead time ``l = T_d/T``.
        Ad, Bd, Ed: 3-state [s, v, a] model ``x⁺ = Ad x + Bd u + Ed w``.
        A, B, E: augmented 4-state ξ = [s, v, a, u(k−1)] model with input Δu.
        Phi_l, Gam_u, Gam_w: ``x(k+l) = Phi_l x(k) + Gam_u u_pend + Gam_w w_pend`` with
            the ``l`` commands already sent (oldest first) and the affine terms.
    """

    dt_s: float
    tau_s: float
    delay_steps: int
    Ad: np.ndarray
    Bd: np.ndarray
    Ed: np.ndarray
    A: np.ndarray
    B: np.ndarray
    E: np.ndarray
    Phi_l: np.ndarray
    Gam_u: np.ndarray
    Gam_w: np.ndarray


_MODELS: dict[tuple[float, float, int], StoppingModel] = {}


def stopping_model(dt_s: float, tau_s: float, delay_steps: int) -> StoppingModel:
    """Build (cached) the model of 001 eq. (8)–(10) for period ``dt_s``, lag ``tau_s``
    (0 = no lag: ``a`` is then the command of the last period) and ``delay_steps``."""
    dt = check_positive("dt_s", dt_s)
    tau = check_range("tau_s", tau_s, 0.0, 100.0)
    if isinstance(delay_steps, bool) or int(delay_steps) != delay_steps or delay_steps < 0:
        raise ValueError(f"delay_steps must be an integer >= 0, got {delay_steps!r}")
    l = int(delay_steps)  # noqa: E741 - the paper's symbol
    key = (dt, tau, l)
    hit = _MODELS.get(key)
    if hit is not None:
        return hit
    if tau > 0:
        Ad, Bd, Ed = discretise(*point_lag_continuous(0.0, tau), dt)
        Bd, Ed = Bd[:, 0], Ed[:, 0]
    else:  # no lag: the acceleration follows the command within the period
        Ad = np.array([[1.0, dt, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.0]])
        Bd = np.array([0.5 * dt * dt, dt, 1.0])
        Ed = np.array([0.5 * dt * dt, dt, 0.0])
    A = np.zeros((4, 4))
    A[:3, :3] = Ad
    A[:3, 3] = Bd
    A[3, 3] = 1.0
    B = np.append(Bd, 1.0).reshape(4, 1)
    E = np.append(Ed, 0.0).reshape(4, 1)
    Phi_l, Gam_u, Gam_w = dead_time_maps(Ad, Bd, Ed, l)
    arrays = [np.array(a, dtype=float) for a in (Ad, Bd, Ed, A, B, E, Phi_l, Gam_u, Gam_w)]
    for a in arrays:
        a.setflags(write=False)  # shared through the cache
    model = StoppingModel(dt, tau, l, *arrays)
    _cache_put(_MODELS, key, model)
    return model


# ------------------------------------------------------------------ feedback, terminal
@dataclass(frozen=True)
class TubeFeedback:
    """Stabilising tube feedback ``Δu = −K (ξ − ξ_s)`` (001 eq. 13).

    Attributes:
        K: gain ``(4,)``; A_cl: ``A − B K`` (Schur stable);
        P_lqr: the Riccati solution of the weights K was designed with.
    """

    K: np.ndarray
    A_cl: np.ndarray
    P_lqr: np.ndarray


_FEEDBACK: dict[tuple, TubeFeedback] = {}


def tube_feedback(model: StoppingModel, q_s: float, q_v: float, r: float) -> TubeFeedback:
    """LQR gain of the augmented model for ``Q_ξ = diag(q_s, q_v, 0, 0)``, ``R = r`` (cached)."""
    for name, val in (("q_s", q_s), ("q_v", q_v), ("r", r)):
        check_positive(f"feedback weight {name}", val)
    key = (model.dt_s, model.tau_s, model.delay_steps, float(q_s), float(q_v), float(r))
    hit = _FEEDBACK.get(key)
    if hit is not None:
        return hit
    Qx = np.diag([q_s, q_v, 0.0, 0.0])
    Rm = np.array([[r]])
    P, K = terminal_cost_dare(model.A, model.B, Qx, Rm)
    K = K.ravel()
    A_cl = model.A - np.outer(model.B[:, 0], K)
    for a in (K, A_cl, P):
        a.setflags(write=False)
    fb = TubeFeedback(K, A_cl, P)
    _cache_put(_FEEDBACK, key, fb)
    return fb


def terminal_weight(A_cl: np.ndarray, K: np.ndarray, Qx: np.ndarray, r: float) -> np.ndarray:
    """``P`` with ``A_clᵀ P A_cl − P + Q_x + Kᵀ r K = 0`` (001 eq. 19 with equality).

    This is the smallest solution of LMI (20); raises ``ValueError`` if ``A_cl`` is not
    Schur stable.
    """
    K = np.asarray(K, float).reshape(1, -1)
    A = np.asarray(A_cl, float)
    key = (A.shape, A.tobytes())
    solver = _LYAPUNOV.get(key)
    if solver is None:
        solver = LyapunovSolver(A)
        _cache_put(_LYAPUNOV, key, solver)
    return solver.solve(Qx + r * (K.T @ K))


_LYAPUNOV: dict[tuple, LyapunovSolver] = {}  # per loop A_cl: its factorised linear system
_CORE_BASIS: dict[tuple, np.ndarray] = {}


def core_terminal_basis(A_cl: np.ndarray, K: np.ndarray) -> np.ndarray:
    """The QP core's terminal weight ``P_c = A_clᵀ P A_cl + r KᵀK`` (``= P − Q_ξ``, ``P``
    of :func:`terminal_weight` for ``Q_ξ = diag(q_s, q_v, 0, 0)``) is linear in ``(q_s,
    q_v, r)`` for a fixed loop: returns the three ``(4, 4)`` pieces ``B`` (symmetric,
    read-only; cached per loop) with ``P_c = q_s B_0 + q_v B_1 + r B_2``."""
    K = np.asarray(K, float).reshape(1, -1)
    A = np.asarray(A_cl, float)
    key = (A.shape, A.tobytes(), K.tobytes())
    hit = _CORE_BASIS.get(key)
    if hit is not None:
        return hit
    n = A.shape[0]
    KtK = K.T @ K
    units = [np.zeros((n, n)), np.zeros((n, n)), KtK]
    units[0][0, 0] = 1.0
    units[1][1, 1] = 1.0
    out = np.empty((3, n, n))
    for j, Qj in enumerate(units):
        P = terminal_weight(A, K, Qj, 0.0)
        Pc = A.T @ P @ A + (KtK if j == 2 else 0.0)
        out[j] = 0.5 * (Pc + Pc.T)
    out.setflags(write=False)
    _cache_put(_CORE_BASIS, key, out)
    return out


# ------------------------------------------------------------------------ tightening
_TIGHTENING: dict[tuple, np.ndarray] = {}


def tube_tightening(
    model: StoppingModel, fb: TubeFeedback, n_stages: int, hold: int = 1
) -> np.ndarray:
    r"""Constraint tightening per unit disturbance bound (w̄ = 1), stages ``0..n_stages``.

    Returns ``T`` of shape ``(n_stages + 1, 4)`` with columns s, v, u (rows of ξ) and Δu
    (``K e``): the support function of the stage-``i`` tube in the row's direction.
    ``hold = M`` is the self-triggered tube of 001 (after eq. 25; Brunner et al. 2016):
    the input is held open loop on stages ``< M`` and the LQR law acts afterwards::

        R_i^M = ⊕_{j<i} A^j Ẽ W                                         (i ≤ M)
        R_i^M = A_cl^{i−M} (⊕_{j<M} A^j Ẽ W) ⊕ ⊕_{j<i−M} A_cl^j Ẽ W      (i > M)

    with ``Ẽ = A^l E``; ``hold = 1`` is the tube-MPC tube ``⊕_{j<i} A_cl^j Ẽ W``.  The
    s and v columns add the dead-time tube ``D_l = ⊕_{j<l} A^j E W``.  For a box the
    support function is exact: ``h_R(η) = Σ_j |ηᵀ G_j|`` over the generators ``G_j``.
    """
    n_stages = int(n_stages)
    hold = int(hold)
    if n_stages < 0 or hold < 1:
        raise ValueError(f"need n_stages >= 0 and hold >= 1, got {n_stages}, {hold}")
    key = (model.dt_s, model.tau_s, model.delay_steps, fb.K.tobytes(), n_stages, hold)
    hit = _TIGHTENING.get(key)
    if hit is not None:
        return hit
    A, A_cl, E = model.A, fb.A_cl, model.E[:, 0]
    H = np.zeros((4, 4))
    H[ROW_S, 0] = 1.0
    H[ROW_V, 1] = 1.0
    H[ROW_U, 3] = 1.0
    H[ROW_DU] = fb.K
    l = model.delay_steps  # noqa: E741
    e = E.copy()
    d_l = np.zeros(4)
    for _ in range(l):
        d_l += np.abs(H @ e)
        e = A @ e
    e_t = e  # Ẽ = A^l E
    d_l[ROW_U] = d_l[ROW_DU] = 0.0  # inputs are applied exactly as planned
    # open-loop generators during the hold: Y[:, j] = A^j Ẽ, j < M
    Y = np.zeros((4, hold))
    g = e_t.copy()
    for j in range(hold):
        Y[:, j] = g
        g = A @ g
    T = np.zeros((n_stages + 1, 4))
    acc = np.zeros(4)
    for i in range(1, min(hold, n_stages) + 1):  # i <= M: open loop
        acc = acc + np.abs(H @ Y[:, i - 1])
        T[i] = acc
    Acl_pow = np.eye(4)  # A_cl^{i-M}
    acc2 = np.zeros(4)  # Σ_{j<i-M} |H A_cl^j Ẽ|
    g2 = e_t.copy()  # A_cl^{i-M-1} Ẽ
    for i in range(hold + 1, n_stages + 1):
        acc2 = acc2 + np.abs(H @ g2)
        g2 = A_cl @ g2
        Acl_pow = A_cl @ Acl_pow
        T[i] = np.abs(H @ Acl_pow @ Y).sum(axis=1) + acc2
    T[1:] += d_l
    T.setflags(write=False)
    _cache_put(_TIGHTENING, key, T)
    return T
