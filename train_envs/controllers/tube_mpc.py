r"""Paper 001's tube robust MPC (RMPC) for accurate stopping, on the shared OSQP core.

Model (001 eq. 8–10)
--------------------
Single point with a first-order brake lag and a dead time, in acceleration units
(``u`` is the commanded acceleration ``c·u`` of the paper, ``a`` the brake
acceleration ``a_c``)::

    ṡ = v,   v̇ = a + w_ff(s, v) + w,   ȧ = (u(t − T_d) − a)/τ                  (8)

``w_ff = −(R̂(v) + M g θ(s)/1000)/M'`` is the nominal running resistance (Davis law
and the line's gradient, both known: 001 §2.1 feeds them forward, eq. 10) and ``w`` the
unknown rest, a bounded disturbance ``w ∈ W = [−w̄, w̄]`` (001 §2.2).  The lag is
discretised **exactly** (zero-order hold, ``expm``), not with the paper's Euler rows for
``v`` and ``s``.  The augmented state of eq. (9) is ξ = [s, v, a, u(k−1)] (the
paper's [a_c, u(k−l), v, s] reordered) with the increment Δu as input::

    ξ(k+1) = A ξ(k) + B Δu(k) + E (w_ff + w),   A = [[A_d, B_d], [0, 1]],
    B = [B_d; 1],   E = [E_d; 0].                                                   (9)

The dead time ``T_d = l T`` is handled as in eq. (10): the measured state is
predicted ``l`` steps ahead with the commands already sent (a cheap precomputed
affine map), and the MPC is solved from ``x_{0|k} = x(k+l)``.

MPC problem (001 eq. 11–12)
---------------------------
``min Σ_{i<N} ‖y_i − y_s,i‖²_Q + ‖Δu_i‖²_R + ‖ξ_N − ξ_s,N‖²_P`` with
``y = [s, v]``, ``Q = diag(q_s, q_v)`` (the paper's ``diag(0, 0, q1, q2)``),
``R = r_du``.  The core weights stages ``1..N``; giving it the terminal weight
``P − CᵀQC`` makes its cost the paper's up to the constant ``‖y_0 − y_s,0‖²_Q``.
ξ_s is the reference state [s_r, v_r, a_r − w_ff, a_r − w_ff] of the profile.

Stabilising feedback and terminal cost (001 eq. 13, 18–20)
----------------------------------------------------------
``Δu = −K (ξ − ξ_s)`` with ``K`` the LQR gain (``scipy.linalg.solve_discrete_are``)
of the augmented model for the *tube* weights ``feedback_weights`` =
(q_s, q_v, r) = (10, 30, 10) by default.  001 only asks for ``A_cl = A − BK`` to be
stable; the choice trades the width of the state tube against the input tube.  Worst-case
tube widths ``τ_∞`` at w̄ = 0.05 m/s² (s [m], v [m/s], u [m/s²], Δu [m/s²/step]):
(10, 30, 10): 0.23, 0.16, 0.14, 0.071 (35 % of the 0.2 rate limit);
(100, 100, 1): 0.12, 0.13, 0.26, 0.29 (the rate box collapses at later stages; the
runs overshot the stop by up to 0.26 m at N = 15); the cost weights themselves
(``feedback_weights="cost"``, q_s = 1, q_v = 20, r = 10): 0.46, 0.16, 0.10, 0.043
(slow position mode |λ| = 0.956).  ``P`` is the solution of the Lyapunov equation
(19) with equality,

    A_clᵀ P A_cl − P + Q_ξ + Kᵀ R K = 0,

the smallest ``P`` satisfying the LMI (20) — by the Schur complement (20) is exactly
``P − A_clᵀ P A_cl − Q_ξ − KᵀRK ⪰ 0``, i.e. (19) as an inequality, and any solution
is ⪰ the Lyapunov solution.  With ``feedback_weights="cost"`` ``P`` is the Riccati
solution, which satisfies the same equation for its own LQR gain.

Tube and constraint tightening (001 eq. 14–16; Chisci, Rossiter & Zappa 2001)
----------------------------------------------------------------------------
The QP is solved every step from the *measured* (dead-time predicted) state with
tightened constraints ``X_i = X ⊖ R_i`` (the "restricted constraints" form of
Chisci et al., whose shifted plan plus ``K`` times the one-step error is feasible at
the next step).  A disturbance ``w_t`` enters ξ through ``E`` and is only seen by the
controller ``l`` steps later, so the deviation between two consecutive plans is
``A^l E w`` and the real state additionally carries the open-loop dead-time error:

    R_i = D_l ⊕ ⊕_{j<i} A_cl^j Ẽ W,   Ẽ = A^l E,   D_l = ⊕_{j<l} A^j E W.

(001 writes ``R_i = ⊕_{j=0}^{i} A_cl^j W`` without dead time; ``R_0 = {0}`` at the
measured stage is Chisci's index.)  For a box ``W`` and a half-space ``hᵀξ ≤ b`` the
Pontryagin difference is exact and needs no polytope library: the support function
of a Minkowski sum of linear images of a box is

    τ_i(h) = w̄ Σ_{j<i} |hᵀ A_cl^j Ẽ| + w̄ Σ_{j<l} |hᵀ A^j E|,   X_i = {hᵀξ ≤ b − τ_i(h)}.

``D_l`` applies to the state rows (``s``, ``v``) only: the command rows concern
inputs that are applied exactly as planned.  The tightening is computed offline per
unit ``w̄`` and cached per (model, K, horizon, hold); ``w̄ = w_scale · w_bound`` only
rescales it, so ``w_scale`` is free to change between steps.

Constraint set ``X`` (001 leaves it unspecified: "the feasible set of the tracking
error"), our choice:

* ``s ≤ s_stop + allowance`` (no overrun beyond the stopping window; ``allowance`` =
  the scenario's ``stop_window_m``, 0.5 m for 001).  With ``allowance = 0`` the
  reference's own end point lies on the boundary of ``X``, outside every tightened set:
  the runs then stop short (2–22 cm over 4 seeds, N = 3 … 15) and the terminal set is
  unreachable during the whole final approach (about 60 re-solves without it per run).
* ``v ≤ v_limit(s)``; ``v ≥ 0`` only with ``v_min_row=True`` (near standstill the
  linear prediction crosses zero speed, the soft row was violated at every step of the
  final approach and OSQP needed 4000+ iterations; the plant cannot reverse under
  braking anyway).
* ``u_min ≤ u ≤ u_max`` (brake/traction envelope at standstill, ``command_box``) and
  the rate box ``|Δu| ≤ jerk_max T`` (hard, tightened by ``|K A_cl^j Ẽ|`` per stage).

Stage rows are soft with an exact L1 penalty (``soft_penalty``): a solution without
slack is a feasible point of the paper's problem, and the QP stays solvable when a
disturbance outside ``W`` has pushed the state out.

Terminal set (001 eq. 14, 16): ``X̃_f = Σ ⊖ R_N`` with ``Σ`` the constraint-admissible
set of the LQR law: the terminal state must keep the tightened ``s`` and ``v`` rows
along the law's own prediction ``ξ_{N+t} = ξ_s,N+t + A_cl^t (ξ_N − ξ_s,N)``, i.e.
``hᵀ A_cl^t ξ_N ≤ b_{N+t} − τ_{N+t}(h) − hᵀ(ξ_s,N+t − A_cl^t ξ_s,N)`` for
``t ∈ terminal_steps`` (default 2, 5, 10, 20, 40 steps; ``A_cl^40`` has decayed to
1 %): a sampled Kolmanovsky–Gilbert set whose offsets move with the reference every
step.  Its rows are hard: as soft rows (exact penalty) they tripled OSQP's iterations
(20 → 63 per solve at N = 10).  If the terminal set is unreachable (the QP fails) the
step is re-solved without it rather than falling back to the previous plan.

QP: condensed form of the core (single input; at N = 15 the sparse form of the
self-triggered family was 2x slower).  Positions are passed relative to the
dead-time predicted position (eq. 9 is translation invariant in ``s``), which keeps
the QP data O(1).  The QPs are built once per problem structure and kept across
episodes; :meth:`LinearMPC.reset_solver` at every reset keeps runs reproducible per
seed.  Each step first evaluates the exact unconstrained optimum in closed form: it is
affine in the step's stage vector (the measured state, the commands in the dead time,
and along the longest horizon the reference, the resistance at it and the speed limit;
:meth:`TubeMPC._stage_data`), and so are the tightened rows and the weighted cost residuals
(:meth:`LinearMPC.unconstrained_affine` composed with that vector once per weight or W
change); when no row binds it is the QP's optimum and the core is not called
(:meth:`LinearMPC.adopt_unconstrained` keeps its warm start and fallback plan).  On
paper 001's runs no tightened row binds at 98 % of the steps (undisturbed); the rest
goes through the core (its own exact shortcut, then OSQP).  The stage vector and the
closed forms run as compiled twins (:mod:`train_envs.controllers._kernels`, numba) of
the numpy code here, which stays the reference and the fallback
(``TRAIN_ENVS_NO_JIT=1``).

Reference: L. Chisci, J. A. Rossiter, G. Zappa, "Systems with persistent
disturbances: predictive control with restricted constraints", Automatica 37 (2001).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.linalg import solve_discrete_are, solve_discrete_lyapunov

from train_envs.controllers._common import distribute, input_shares
from train_envs.controllers._kernels import kernels
from train_envs.controllers.base import ControlContext, Controller, Observation, TunableParam
from train_envs.controllers.mpc_core import LinearMPC, MPCSolution
from train_envs.controllers.train_mpc import zoh
from train_envs.plants.lookup import gradient_table
from train_envs.trains import G
from train_envs.validation import check_positive, check_range

__all__ = [
    "DEFAULT_W_BOUND_MPS2",
    "StoppingModel",
    "TubeFeedback",
    "TubeMPC",
    "TubeSettings",
    "stopping_model",
    "terminal_weight",
    "tube_feedback",
    "tube_tightening",
]

#: default bound of the unknown resistance [m/s²] (about paper 001's basic resistance at
#: 20 m/s, 6.25 N/kN = 0.061 m/s², and the library's usual random disturbance)
DEFAULT_W_BOUND_MPS2 = 0.05
_min_reduce = np.minimum.reduce
_BIG = 1e6  # "no bound" for rows whose offsets change per call
_THREADPOOLS: Any = None


def _single_thread_blas() -> Any:
    """Context limiting BLAS to one thread while QPs are (re)built.

    Building a QP is a few hundred small dense products; on a busy 2-core machine
    OpenBLAS's threads made one build of the N = 15 self-triggered family 6x slower
    (0.25 s against 0.04 s).  The controller is created once (~0.1 ms per use).
    """
    global _THREADPOOLS
    if _THREADPOOLS is None:
        from threadpoolctl import ThreadpoolController

        _THREADPOOLS = ThreadpoolController()
    return _THREADPOOLS.limit(limits=1, user_api="blas")


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
        Ac = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0 / tau]])
        Bc = np.array([[0.0], [0.0], [1.0 / tau]])
        Ec = np.array([[0.0], [1.0], [0.0]])
        Ad, BE = zoh(Ac, np.hstack([Bc, Ec]), dt)
        Bd, Ed = BE[:, 0], BE[:, 1]
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
    pows = [np.eye(3)]
    for _ in range(l):
        pows.append(Ad @ pows[-1])
    Gam_u = np.zeros((3, l))
    Gam_w = np.zeros((3, l))
    for j in range(l):
        Gam_u[:, j] = pows[l - 1 - j] @ Bd
        Gam_w[:, j] = pows[l - 1 - j] @ Ed
    arrays = [np.array(a, dtype=float) for a in (Ad, Bd, Ed, A, B, E, pows[l], Gam_u, Gam_w)]
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
    P = solve_discrete_are(model.A, model.B, Qx, Rm)
    P = 0.5 * (P + P.T)
    K = np.linalg.solve(Rm + model.B.T @ P @ model.B, model.B.T @ P @ model.A).ravel()
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
    rad = float(np.max(np.abs(np.linalg.eigvals(A_cl))))
    if rad >= 1.0:
        raise ValueError(f"A_cl must be Schur stable (spectral radius {rad:.6g} >= 1)")
    K = np.asarray(K, float).reshape(1, -1)
    P = solve_discrete_lyapunov(A_cl.T, Qx + r * (K.T @ K))
    return 0.5 * (P + P.T)


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


# ---------------------------------------------------------------------------- settings
@dataclass(frozen=True)
class TubeSettings:
    """Structural (non-tunable) options of the robust MPCs; validated on construction.

    Attributes:
        N: prediction horizon (001: 3 … 15).
        w_bound_mps2: bound w̄ of the unknown resistance per unit mass before ``w_scale``.
        feedback_weights: (q_s, q_v, r) of the LQR tube feedback, or ``"cost"`` for the
            cost weights (K and P then from one Riccati equation).
        jerk_max: command rate limit [m/s³] (``|Δu| ≤ jerk_max T``).
        soft_penalty: exact L1 penalty of the soft stage rows (s, v, command).
        terminal_steps: LQR-law steps ``t`` at which the (hard) terminal set checks the
            rows; ``()`` = no terminal set.
        tighten: False gives the nominal MPC (same QP, no tightening).
        feas_tol: largest slack [m, m/s, m/s²] still counted as feasible (RSMPC).
        overrun_allowance_m: the position row is ``s ≤ s_stop + allowance``; ``None`` =
            the scenario's stopping window (``extra["stop_window_m"]``, else 0.5 m).
        v_min_row: add the soft row ``v ≥ 0`` (off: see the module docstring).
        terminal_speed_rows: the terminal set also checks ``v ≤ v_limit``.
        command_box: ``"soft"``, ``"hard"`` or ``"off"``: the tightened command box.
    """

    N: int = 10
    w_bound_mps2: float = DEFAULT_W_BOUND_MPS2
    feedback_weights: tuple[float, float, float] | str = (10.0, 30.0, 10.0)
    jerk_max: float = 1.0
    soft_penalty: float = 1e3
    terminal_steps: tuple[int, ...] = (2, 5, 10, 20, 40)
    tighten: bool = True
    feas_tol: float = 1e-3
    overrun_allowance_m: float | None = None
    v_min_row: bool = False
    terminal_speed_rows: bool = True
    command_box: str = "soft"

    def __post_init__(self) -> None:
        if isinstance(self.N, bool) or int(self.N) != self.N or not 1 <= self.N <= 60:
            raise ValueError(f"N must be an integer in [1, 60], got {self.N!r}")
        check_range("w_bound_mps2", self.w_bound_mps2, 0.0, 1.0)
        fw = self.feedback_weights
        if isinstance(fw, str):
            if fw != "cost":
                raise ValueError(f"feedback_weights must be 'cost' or (q_s, q_v, r), got {fw!r}")
        else:
            if len(fw) != 3:
                raise ValueError(f"feedback_weights must be (q_s, q_v, r), got {fw!r}")
            for name, val in zip(("q_s", "q_v", "r"), fw, strict=True):
                check_range(f"feedback_weights {name}", val, 0.0, 1e8, low_inclusive=False)
        check_range("jerk_max", self.jerk_max, 0.0, 100.0, low_inclusive=False)
        check_range("soft_penalty", self.soft_penalty, 0.0, 1e8, low_inclusive=False)
        ts = tuple(self.terminal_steps)
        if any(isinstance(t, bool) or int(t) != t or not 1 <= t <= 500 for t in ts):
            raise ValueError(f"terminal_steps must be integers in [1, 500], got {ts!r}")
        if len(set(ts)) != len(ts):
            raise ValueError(f"terminal_steps must not repeat, got {ts!r}")
        check_range("feas_tol", self.feas_tol, 0.0, 1.0, low_inclusive=False)
        if self.command_box not in ("soft", "hard", "off"):
            raise ValueError(
                f"command_box must be 'soft', 'hard' or 'off', got {self.command_box!r}"
            )
        if self.overrun_allowance_m is not None:
            check_range("overrun_allowance_m", self.overrun_allowance_m, 0.0, 100.0)


# -------------------------------------------------------------------------- controller
@dataclass
class _Problem:
    """One QP of the family: hold ``M`` (1 = plain tube MPC) with horizon ``Np``."""

    M: int
    Np: int
    mpc: LinearMPC
    tight: np.ndarray  # (Np + t_max + 1, 4), per unit w̄
    H_N: np.ndarray  # terminal rows h A_cl^t
    weights_key: tuple | None = None
    w_bar: float = -1.0
    y_min: np.ndarray | None = None
    y_max: np.ndarray | None = None
    tau_v: np.ndarray | None = None
    tau_term: np.ndarray | None = None
    buffers: tuple | None = None  # per-step index constants and work arrays of _solve
    du: np.ndarray | None = None  # per-stage increment bound (0: pinned, a held stage)
    explicit: _Explicit | bool | None = None  # closed form (None: not made, False: n/a)


@dataclass
class _Explicit:
    """One problem's unconstrained optimum as affine maps of the trigger's stage vector.

    ``out = T @ h[cols]`` (``h`` of :meth:`TubeMPC._stage_data`) stacks the constraint
    rows written as ``row <= b`` (``nchk`` rows: first the decision ``z`` itself, ``nz``
    rows, as the upper side of the increment box, then its lower side, the tightened
    ``s``, ``v``, command rows of every stage and the terminal set) and the weighted cost
    residuals (``J = ‖r‖²``); ``Umap @ h[cols]`` is the input plan (None: it is ``z``).
    """

    cols: np.ndarray
    T: np.ndarray
    nz: int
    nchk: int
    b: np.ndarray
    Umap: np.ndarray | None


class _StageData(dict):
    """One step's data: the stage vector ``h`` and ``u_prev``; the QP core's arrays
    (``xs``, ``D``, ``v_lim``, ``xi0``, ``s_o``) are derived on first access."""

    __slots__ = ("derive",)

    def __missing__(self, key: str) -> Any:
        if "xs" in self:
            raise KeyError(key)
        self.update(self.derive(self))
        return dict.__getitem__(self, key)


class TubeMPC(Controller):
    """Paper 001's tube robust MPC ("rmpc"); see the module docstring for the equations.

    Tunable: ``q_s`` and ``q_v`` (position and speed weights, the paper's q2 and q1),
    ``r_du`` (increment weight R) and ``w_scale`` (the disturbance set W = w_scale ·
    [−w̄, w̄]; 0 gives the nominal MPC).  ``w̄`` (``w_bound_mps2``) defaults to the
    scenario's ``disturbance.random_bound_mps2`` when the factory gets a scenario that
    has one, else :data:`DEFAULT_W_BOUND_MPS2`.
    """

    name = "rmpc"
    PARAMS: tuple[TunableParam, ...] = (
        TunableParam("q_s", 1e-3, 1e3, 1.0, log=True, description="position weight [1/m^2]"),
        TunableParam("q_v", 1e-2, 1e4, 20.0, log=True, description="speed weight [s^2/m^2]"),
        TunableParam("r_du", 1e-3, 1e4, 10.0, log=True, description="increment weight [s^4/m^2]"),
        TunableParam("w_scale", 0.0, 3.0, 1.0, description="disturbance set scale (0 = nominal)"),
    )

    def __init__(
        self,
        scenario: Any = None,
        *,
        N: int = 10,
        w_bound_mps2: float | None = None,
        feedback_weights: Sequence[float] | str = (10.0, 30.0, 10.0),
        jerk_max: float = 1.0,
        soft_penalty: float = 1e3,
        terminal_steps: Sequence[int] = (2, 5, 10, 20, 40),
        tighten: bool = True,
        feas_tol: float = 1e-3,
        overrun_allowance_m: float | None = None,
        qp_form: str = "condensed",
        osqp_settings: Mapping[str, Any] | None = None,
        v_min_row: bool = False,
        terminal_speed_rows: bool = True,
        command_box: str = "soft",
        **params: float,
    ) -> None:
        if w_bound_mps2 is None:
            dist = getattr(scenario, "disturbance", None)
            rb = float(getattr(dist, "random_bound_mps2", 0.0) or 0.0)
            w_bound_mps2 = rb if rb > 0 else DEFAULT_W_BOUND_MPS2
        fw = feedback_weights if isinstance(feedback_weights, str) else tuple(feedback_weights)
        self.settings = TubeSettings(
            N=N,
            w_bound_mps2=float(w_bound_mps2),
            feedback_weights=fw,
            jerk_max=float(jerk_max),
            soft_penalty=float(soft_penalty),
            terminal_steps=tuple(terminal_steps),
            tighten=bool(tighten),
            feas_tol=float(feas_tol),
            overrun_allowance_m=overrun_allowance_m,
            v_min_row=bool(v_min_row),
            terminal_speed_rows=bool(terminal_speed_rows),
            command_box=command_box,
        )
        if qp_form not in ("auto", "condensed", "sparse"):
            raise ValueError(f"qp_form must be 'auto', 'condensed' or 'sparse', got {qp_form!r}")
        self.N = int(N)
        self.qp_form = qp_form
        self.osqp_settings = dict(osqp_settings or {})
        self._problems: dict[int, _Problem] = {}
        self._structure_key: tuple | None = None
        self._model: StoppingModel | None = None
        self._keys: tuple | None = None  # (weights key, w̄), refreshed on a parameter change
        super().__init__(**params)

    def _on_params_changed(self) -> None:
        self._keys = None

    # ------------------------------------------------------------------ design
    def _holds(self) -> list[int]:
        """Hold lengths M whose problems this controller needs (RMPC: only 1)."""
        return [1]

    def _horizon(self, M: int) -> int:
        """Prediction horizon of the problem with hold ``M`` (RMPC: N)."""
        return self.N

    def _feedback(self) -> TubeFeedback:
        fw = self.settings.feedback_weights
        if isinstance(fw, str):
            p = self._params
            return tube_feedback(self._model, p["q_s"], p["q_v"], p["r_du"])
        return tube_feedback(self._model, *fw)

    def terminal_weight(self) -> np.ndarray:
        """The paper's terminal weight ``P`` (eq. 19/20) for the current parameters."""
        p = self._params
        fb = self._feedback()
        return terminal_weight(fb.A_cl, fb.K, np.diag([p["q_s"], p["q_v"], 0.0, 0.0]), p["r_du"])

    def _cost_matrices(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Core weights: Q on [s, v, u], S = r_du on Δu, terminal ``P − CᵀQC`` on ξ (made
        once per parameter change and model: every problem of the family shares them)."""
        key = (self._current_keys()[0], self._model)
        hit = self.__dict__.get("_cost_cache")
        if hit is not None and hit[0][0] is key[0] and hit[0][1] is key[1]:
            return hit[1]
        p = self._params
        fb = self._feedback()
        Qx = np.diag([p["q_s"], p["q_v"], 0.0, 0.0])
        P = terminal_weight(fb.A_cl, fb.K, Qx, p["r_du"])
        Kr = fb.K.reshape(1, 4)
        P_core = fb.A_cl.T @ P @ fb.A_cl + p["r_du"] * (Kr.T @ Kr)  # = P − Qx exactly
        out = (np.diag([p["q_s"], p["q_v"], 0.0]), np.array([[p["r_du"]]]), P_core)
        self._cost_cache = (key, out)
        return out

    def _stage_scales(self, M: int) -> dict[str, np.ndarray] | None:
        """Per-stage multipliers of Q and of the increment weight S (RSMPC's 1/β)."""
        return None

    def _terminal_rows(self, fb: TubeFeedback) -> np.ndarray:
        """Rows ``h A_cl^t`` of the terminal set: s rows, then v rows (if enabled)."""
        rows = []
        for h in (0, 1) if self.settings.terminal_speed_rows else (0,):
            for t in self.settings.terminal_steps:
                rows.append(np.linalg.matrix_power(fb.A_cl, t)[h])
        return np.array(rows).reshape(-1, 4)

    def _make_problem(self, M: int) -> _Problem:
        """Build the QP with hold ``M`` (001 eq. 11–14; eq. 25–26 for ``M > 1``)."""
        st = self.settings
        model = self._model
        fb = self._feedback()
        Np = self._horizon(M)
        tight = tube_tightening(model, fb, Np + max(st.terminal_steps, default=0), M)
        Q, S, P_core = self._cost_matrices()
        C = np.zeros((3, 4))
        C[0, 0] = C[1, 1] = C[2, 3] = 1.0
        H_N = self._terminal_rows(fb)
        rate = self._rate
        rho = st.soft_penalty
        rho_u = {"soft": rho, "hard": np.inf, "off": rho}[st.command_box]
        u_lo, u_hi = (-_BIG, _BIG) if st.command_box == "off" else (self._u_lo, self._u_hi)
        terminal = {"H_N": H_N, "h_N": np.full(H_N.shape[0], _BIG)} if H_N.shape[0] else {}
        mpc = LinearMPC(
            model.A,
            model.B,
            C,
            Np=Np,
            Q=Q,
            R=np.zeros((1, 1)),
            S=S,
            P=P_core,
            u_min=[-rate],
            u_max=[rate],
            y_min=[-_BIG, 0.0, u_lo],
            y_max=[_BIG, _BIG, u_hi],
            soft_penalty={"y": [rho, rho, rho_u], "H_N": np.inf},  # hard, see _solve
            delta_u=False,
            form=self.qp_form,
            osqp_settings=self.osqp_settings,
            stage_scales=self._stage_scales(M),
            unconstrained_first=True,
            **terminal,
        )
        prob = _Problem(M=M, Np=Np, mpc=mpc, tight=tight, H_N=H_N)
        prob.weights_key = self._weights_key()
        return prob

    def _weights_key(self) -> tuple:
        return tuple(sorted((k, v) for k, v in self._params.items() if k != "w_scale"))

    def _w_bar(self) -> float:
        if not self.settings.tighten:
            return 0.0
        return self._params["w_scale"] * self.settings.w_bound_mps2

    def _current_keys(self) -> tuple:
        keys = self._keys
        if keys is None:
            keys = self._keys = (self._weights_key(), self._w_bar())
        return keys

    def _refresh(self, prob: _Problem) -> None:
        """Apply parameter changes to one problem lazily (weights, stage scales, W)."""
        key = self._current_keys()[0]
        old = prob.weights_key
        if old is None or any(
            not math.isclose(a[1], b[1], rel_tol=1e-12, abs_tol=0.0)
            for a, b in zip(key, old, strict=True)
        ):
            if isinstance(self.settings.feedback_weights, str):
                # K follows the weights: new tube, terminal rows and QP
                fresh = self._make_problem(prob.M)
                prob.mpc, prob.tight, prob.H_N = fresh.mpc, fresh.tight, fresh.H_N
            else:
                Q, S, P_core = self._cost_matrices()
                prob.mpc.set_weights(Q=Q, S=S, P=P_core, stage_scales=self._stage_scales(prob.M))
            prob.w_bar = -1.0
            prob.explicit = None
        # (a change below 1e-12 relative -- an env's action round trip -- only updates
        # the key: no rebuild)
        prob.weights_key = key
        wb = self._current_keys()[1]
        if wb != prob.w_bar:
            Np, M = prob.Np, prob.M
            tight = prob.tight
            rate = self._rate
            # input (Δu) box per stage: rate tightened by |K A_cl^j Ẽ|, held stages fixed
            du = np.maximum(rate - wb * tight[:Np, ROW_DU], 0.0)
            du[0] = rate
            du[1:M] = 0.0
            prob.mpc.set_base_bounds(u_min=-du.reshape(Np, 1), u_max=du.reshape(Np, 1))
            prob.du = du
            ts = tight[1 : Np + 1]
            y_min = np.empty((Np, 3))
            y_max = np.empty((Np, 3))
            y_min[:, 0] = -_BIG
            y_min[:, 1] = self._v_min
            y_min[:, 2] = self._u_lo + wb * ts[:, ROW_U]
            y_max[:, 0] = self._s_max - wb * ts[:, ROW_S]
            y_max[:, 2] = self._u_hi - wb * ts[:, ROW_U]
            if self.settings.command_box == "off":
                y_min[:, 2], y_max[:, 2] = -_BIG, _BIG
            # an empty command box (W too large) keeps its midpoint
            bad = y_min[:, 2] > y_max[:, 2]
            if bad.any():
                mid = 0.5 * (y_min[bad, 2] + y_max[bad, 2])
                y_min[bad, 2] = y_max[bad, 2] = mid
            prob.y_min, prob.y_max = y_min, y_max
            prob.mpc.set_base_bounds(y_min=y_min)
            prob.tau_v = wb * ts[:, ROW_V]
            steps = np.asarray(self.settings.terminal_steps, dtype=int)
            rows = (ROW_S, ROW_V) if self.settings.terminal_speed_rows else (ROW_S,)
            prob.tau_term = np.concatenate([wb * tight[Np + steps, r] for r in rows])
            prob.w_bar = wb
            prob.explicit = None

    def _problem(self, M: int) -> _Problem:
        prob = self._problems.get(M)
        if prob is None:
            with _single_thread_blas():
                prob = self._problems[M] = self._make_problem(M)
        key, wb = self._current_keys()
        if prob.weights_key is not key or prob.w_bar != wb:
            with _single_thread_blas():
                self._refresh(prob)
        return prob

    # ------------------------------------------------------------------- reset
    def reset(self, ctx: ControlContext) -> None:
        super().reset(ctx)
        tr = ctx.train
        self._mi = tr.inertial_mass_kg
        tau = ctx.actuator_tau_s if ctx.actuator_order >= 1 else 0.0
        l = int(round(ctx.dead_time_s / ctx.dt_s))  # noqa: E741
        self._model = stopping_model(ctx.dt_s, tau, l)
        self._l = l
        rate = self.settings.jerk_max * ctx.dt_s
        if math.isfinite(ctx.du_max_Nps):
            rate = min(rate, ctx.du_max_Nps * ctx.n_inputs * ctx.dt_s / self._mi)
        self._rate = rate
        self._u_lo = -tr.max_brake_N(0.0) / self._mi
        self._u_hi = tr.max_traction_N(0.0) / self._mi
        self._v_min = 0.0 if self.settings.v_min_row else -_BIG
        allow = self.settings.overrun_allowance_m
        if allow is None:
            allow = float(ctx.extra.get("stop_window_m", 0.5))
        self._s_max = float(ctx.s_stop_m) + allow if ctx.s_stop_m is not None else _BIG
        key = (ctx.dt_s, tau, l, rate, self._u_lo, self._u_hi, self._s_max)
        if key != self._structure_key:  # QPs are kept across resets of the same problem
            self._problems = {}
            self._structure_key = key
        for prob in self._problems.values():  # reproducible per seed without a rebuild
            prob.mpc.reset_solver()
        # per-step constants
        self._prof = ctx.reference.profile
        self._distance_mode = ctx.reference.mode == "distance"
        self._grad = gradient_table(ctx.track) if ctx.track is not None else None
        self._track = ctx.track
        self._ca = tr.davis_a_N / self._mi
        self._cb = tr.davis_b_Ns_per_m / self._mi
        self._cc = tr.davis_c_Ns2_per_m2 / self._mi
        self._cg = tr.mass_kg * G / 1000.0 / self._mi
        n_max = max(self._horizon(M) for M in self._holds())
        self._n_grid = l + n_max + max(self.settings.terminal_steps, default=0) + 2
        self._tgrid = ctx.dt_s * np.arange(self._n_grid)
        self._kern = kernels()
        if self._kern is not None:
            g = self._grad
            self._kern_tables = (
                self._prof.t_s,
                self._prof._seg_tbl,
                g.x if g is not None else np.zeros(1),
                np.column_stack([g.y0, g.slope]) if g is not None else np.zeros((1, 2)),
                g is not None,
                self._ca,
                self._cb,
                self._cc,
                self._cg,
            )
        self._inv_dt = 1.0 / ctx.dt_s
        self._term_idx = np.asarray(self.settings.terminal_steps, dtype=int)
        self._E4 = self._model.E[:, 0].copy()
        self._minus_E4 = -self._E4
        # a line with one speed limit (paper 001): the limit row is the same every step
        lims = None if ctx.track is None else np.unique(ctx.track.speed_limits_mps)
        self._v_lim_const = (
            np.full(self._n_grid, float(lims[0])) if lims is not None and lims.size == 1 else None
        )
        self._v_lim_none = np.full(self._n_grid, _BIG)
        self._pend = [0.0] * l  # commands [m/s²] still in the dead time, oldest first
        self._initialised = False
        self._multi = ctx.n_inputs > 1
        self._shares = input_shares(ctx) if self._multi else None
        self._steps = 0
        self._relaxed = 0  # solves whose terminal set had to be dropped

    # -------------------------------------------------------------- per step
    def _stage_data(self, obs: Observation) -> dict[str, Any]:
        """The step's stage vector ``h`` (what the closed forms read); the QP core's
        per-stage arrays are derived from it on first access (:meth:`_derive`).

        ``h = [1, s, v, a, u_prev, u_pend (l), s_r, v_r, res, v_lim]``: the measured
        state, the commands still in the dead time, and along the grid (index ``j`` is
        time ``t_0 + j T``; ``t_0``: now, or the profile time at the train's position
        for distance-indexed references) the reference position and speed, the nominal
        resistance per unit inertial mass at the reference (``w_ff = −res``) and the
        speed limit.
        """
        prof = self._prof
        t0 = float(prof.t_at_s(obs.s_m)) if self._distance_mode else obs.t_s
        ng, l = self._n_grid, self._l  # noqa: E741
        o = 5 + l
        h = np.empty(o + 4 * ng)
        kern = self._kern
        if kern is not None:  # the same numbers in one compiled call
            kern.fill_reference(h, o, self._tgrid, t0, *self._kern_tables)
            s_r = h[o : o + ng]
        else:
            s_r, v_r = prof.sv_at_t(self._tgrid + t0)  # one segment search for both
            h[o : o + ng] = s_r
            h[o + ng : o + 2 * ng] = v_r
            res = h[o + 2 * ng : o + 3 * ng]
            np.multiply(v_r, self._cc, out=res)
            res += self._cb
            res *= v_r
            res += self._ca * (v_r > 0)
            if self._grad is not None:
                res += self._cg * self._grad(s_r)
        mi = self._mi
        up, fo = obs.u_prev_N, obs.forces_N
        # (a single input: its value, as the sum would give it)
        u_prev = (up.item() if up.size == 1 else float(up.sum())) / mi
        if not self._initialised:
            self._pend = [u_prev] * l
            self._initialised = True
        a = (fo.item() if fo.size == 1 else float(fo.sum())) / mi
        if not math.isfinite(obs.s_m + obs.v_mps + a + u_prev):
            raise ValueError(
                f"{self.name}: non-finite measurement (s_m={obs.s_m}, v_mps={obs.v_mps}, "
                f"forces_N={fo.tolist()}, u_prev_N={up.tolist()}); all must be finite"
            )
        h[0] = 1.0
        h[1] = obs.s_m
        h[2] = obs.v_mps
        h[3] = a
        h[4] = u_prev
        h[5:o] = self._pend
        lim = self._v_lim_const
        if lim is None:
            track = self._track
            lim = track.speed_limit_at(s_r) if track is not None else self._v_lim_none
        h[o + 3 * ng :] = lim
        data = _StageData(h=h, u_prev=u_prev)
        data.derive = self._derive
        return data

    def _derive(self, data: Mapping[str, Any]) -> dict[str, Any]:
        """The QP core's data from the stage vector: the dead-time prediction ξ_0 (eq. 10),
        the reference states ξ_s and the affine terms along the grid (stage ``i`` of a QP
        is grid index ``l + i``).  Positions are relative to the dead-time predicted one,
        ``s_o`` (eq. 9 is translation invariant in ``s``): the QP data stay O(1) for
        OSQP's relative tolerances."""
        h = data["h"]
        ng, l = self._n_grid, self._l  # noqa: E741
        o = 5 + l
        s_r, v_r = h[o : o + ng], h[o + ng : o + 2 * ng]
        res, v_lim = h[o + 2 * ng : o + 3 * ng], h[o + 3 * ng :]
        x = h[1:4]
        if l:
            m = self._model
            x = m.Phi_l @ x + m.Gam_u @ h[5:o] - m.Gam_w @ res[:l]  # w_ff = −res
        s_o = float(x[0])
        # reference state ξ_s = [s_r, v_r, a_s, u_s]: a_s = mean reference acceleration of
        # the next interval minus w_ff, u_s = a_s of the previous interval
        xs = np.empty((ng, 4))
        np.subtract(s_r, s_o, out=xs[:, 0])
        xs[:, 1] = v_r
        a_s = xs[:-1, 2]
        np.subtract(v_r[1:], v_r[:-1], out=a_s)
        a_s *= self._inv_dt
        a_s += res[:-1]
        xs[-1, 2] = xs[-2, 2]
        xs[1:, 3] = a_s
        xs[0, 3] = xs[0, 2]
        return {
            "xs": xs,
            "D": np.multiply(res[:, None], self._minus_E4),  # d_j = E w_ff,j
            "v_lim": v_lim,
            "xi0": np.array([0.0, x[1], x[2], h[4]]),
            "s_o": s_o,
        }

    def _fold(self, G: np.ndarray) -> np.ndarray:
        """Maps on the derived layout ``g = [1, ξ_0, s_o, ξ_s (ng × 4), res, v_lim]`` as
        maps on the stage vector ``h`` of :meth:`_stage_data` (every relation of
        :meth:`_derive` is linear: substitute it column by column)."""
        ng, l = self._n_grid, self._l  # noqa: E741
        rows = G.shape[0]
        XS, RES, VL = 6, 6 + 4 * ng, 6 + 5 * ng
        o = 5 + l
        xsc = G[:, XS:RES].reshape(rows, ng, 4)
        A2 = xsc[:, :-1, 2].copy()  # on a_s,j = (v_r,j+1 − v_r,j)/T + res_j, j < ng − 1
        A2 += xsc[:, 1:, 3]  # u_s,j+1 = a_s,j
        A2[:, 0] += xsc[:, 0, 3]  # u_s,0 = a_s,0
        A2[:, -1] += xsc[:, -1, 2]  # a_s,ng−1 = a_s,ng−2
        Vr = xsc[:, :, 1].copy()
        Vr[:, 1:] += A2 * self._inv_dt
        Vr[:, :-1] -= A2 * self._inv_dt
        Res = G[:, RES:VL].copy()
        Res[:, :-1] += A2
        Sr = xsc[:, :, 0]
        # on the dead-time predicted (s_o, v, a): s_o also enters every ξ_s,j = s_r,j − s_o
        cx = np.column_stack([G[:, 5] - Sr.sum(axis=1), G[:, 2], G[:, 3]])
        H = np.zeros((rows, o + 4 * ng))
        H[:, 0] = G[:, 0]
        H[:, 4] = G[:, 4]
        if l:
            m = self._model
            H[:, 1:4] = cx @ m.Phi_l
            H[:, 5:o] = cx @ m.Gam_u
            Res[:, :l] -= cx @ m.Gam_w
        else:
            H[:, 1:4] = cx
        H[:, o : o + ng] = Sr
        H[:, o + ng : o + 2 * ng] = Vr
        H[:, o + 2 * ng : o + 3 * ng] = Res
        H[:, o + 3 * ng :] = G[:, VL:]
        return H

    def _buffers(self, prob: _Problem) -> tuple:
        """Per-step index constants and work arrays of one problem (made on first use)."""
        Np, l = prob.Np, self._l  # noqa: E741
        bufs = prob.buffers
        if bufs is None or bufs[0] != l:
            bufs = prob.buffers = (
                l,
                slice(l + 1, l + Np + 1),  # stages 1..Np on the grid
                np.zeros((Np, 3)),  # y_ref (command column stays 0)
                np.empty((Np, 3)),  # y_max
                self._term_idx + (l + Np),  # grid indices of the terminal checks
                np.empty(prob.H_N.shape[0]),
                slice(l, l + Np),  # d_0 .. d_{Np-1}
            )
        return bufs

    def _lower_bound(self, prob: _Problem, data: Mapping[str, Any]) -> float | None:
        """A lower bound on :meth:`_solve`'s cost for the same data, exact when the
        problem's unconstrained optimum (held increments pinned) is feasible; None when
        not available (:meth:`LinearMPC.unconstrained_cost`).  No bounds are set."""
        _, idx, y_ref, _, _, _, d_idx = self._buffers(prob)
        xs = data["xs"]
        y_ref[:, :2] = xs[idx, :2]
        return prob.mpc.unconstrained_cost(
            data["xi0"], self._zero1, y_ref, d=data["D"][d_idx], x_ref_N=xs[self._l + prob.Np]
        )

    def _explicit(self, prob: _Problem) -> _Explicit | bool:
        """The problem's closed form (made on first use after a weight or W change)."""
        e = prob.explicit
        if e is None:
            with _single_thread_blas():
                e = prob.explicit = self._make_explicit(prob)
        return e

    def _make_explicit(self, prob: _Problem) -> _Explicit | bool:
        """Compose the core's unconstrained optimum (:meth:`LinearMPC.unconstrained_affine`)
        with the stage vector of :meth:`_stage_data` and the rows :meth:`_solve` sets.

        Row for row the same constraints as the QP: the increment box ``|Δu_i| <= du_i``
        (held stages pinned at 0), per stage ``s + s_o <= s_max − τ_s``, ``v >= v_min``,
        ``v − v_lim <= −τ_v``, ``u_lo + τ_u <= u <= u_hi − τ_u``, and the terminal rows
        ``h A_cl^t ξ_N − h ξ_s,N + (s_o + s_r,N+t | v_r,N+t − v_lim,N+t) <= (s_max | 0) −
        τ_N+t``.  False when the core has no closed form for this problem.
        """
        aff = prob.mpc.unconstrained_affine()
        if aff is None or prob.du is None or aff.Z.shape[0] != prob.Np:
            return False
        Np, l, ng = prob.Np, self._l, self._n_grid  # noqa: E741
        nth = aff.ntheta
        XS, VL = 6, 6 + 5 * ng
        RES = 6 + 4 * ng
        # where each entry of the core's data vector θ comes from in the stage vector
        tgt = np.full(nth, -1)
        coef = np.ones(nth)
        ith = np.arange(nth)
        sl = aff.slots
        tgt[0] = 0
        tgt[ith[sl["x0"]]] = 1 + np.arange(4)
        stage = l + 1 + np.arange(Np)  # grid index of stage i = 1..Np
        r = ith[sl["r"]].reshape(Np, 3)  # the command column's reference stays 0
        tgt[r[:, 0]] = XS + 4 * stage
        tgt[r[:, 1]] = XS + 4 * stage + 1
        if "xN" in sl:
            tgt[ith[sl["xN"]]] = XS + 4 * (l + Np) + np.arange(4)
        Dk = ith[sl["D"]].reshape(Np, 4)  # d_i = −E res_{l+i}
        tgt[Dk] = RES + (l + np.arange(Np))[:, None]
        coef[Dk] = self._minus_E4[None, :]
        used = np.flatnonzero(tgt >= 0)
        order = used[np.argsort(tgt[used], kind="stable")]
        gcols, starts = np.unique(tgt[order], return_index=True)
        ngv = 6 + 6 * ng

        def on_g(A: np.ndarray) -> np.ndarray:
            out = np.zeros((A.shape[0], ngv))
            out[:, gcols] = np.add.reduceat(A[:, order] * coef[order], starts, axis=1)
            return out

        Y = aff.Y.reshape(Np, 3, nth)
        Z = aff.Z
        ymin, ymax = prob.y_min, prob.y_max
        nb = prob.H_N.shape[0]
        nt = self._term_idx.size
        # every distinct row once on g (the stage vector before folding), then the unit
        # terms of the data-dependent bounds, then the fold onto h
        base = [Z, Y[:, 0], Y[:, 1], Y[:, 2]]
        if nb:
            base.append(prob.H_N @ aff.X[-4:])
        base.append(aff.R)
        Gb = on_g(np.vstack(base))
        s_rows = slice(Np, 2 * Np)
        Gb[s_rows, 5] += 1.0  # s + s_o <= s_max − τ_s
        Gv = Gb[2 * Np : 3 * Np].copy()
        Gv[np.arange(Np), VL + stage] -= 1.0  # v − v_lim <= −τ_v
        if nb:
            steps = self._term_idx + (l + Np)
            tr = np.arange(4 * Np, 4 * Np + nb)
            Gb[tr, XS + 4 * (l + Np) : XS + 4 * (l + Np) + 4] -= prob.H_N
            Gb[tr[:nt], 5] += 1.0
            Gb[tr[:nt], XS + 4 * steps] += 1.0
            if nb > nt:
                Gb[tr[nt:], XS + 4 * steps + 1] += 1.0
                Gb[tr[nt:], VL + steps] -= 1.0
        H = self._fold(np.vstack([Gb, Gv]))
        Hz, Hs, Hv, Hu = H[:Np], H[Np : 2 * Np], H[2 * Np : 3 * Np], H[3 * Np : 4 * Np]
        Ht, Hr, Hvl = H[4 * Np : 4 * Np + nb], H[4 * Np + nb : -Np], H[-Np:]
        rows = [Hz, -Hz, Hs, -Hv, Hvl, -Hu, Hu, Ht, Hr]  # (z's rows are its upper bounds)
        b = [prob.du, prob.du, ymax[:, 0], -ymin[:, 1], -prob.tau_v, -ymin[:, 2], ymax[:, 2]]
        if nb:
            b.append(np.concatenate([np.full(nt, self._s_max), np.zeros(nb - nt)]) - prob.tau_term)
        G = np.vstack(rows)
        # the plan is the decision itself in the absolute-input form
        Um = None if np.array_equal(aff.U, Z) else self._fold(on_g(aff.U))
        used = np.any(G != 0.0, axis=0)
        if Um is not None:
            used |= np.any(Um != 0.0, axis=0)
        cols = np.flatnonzero(used)
        bb = np.concatenate(b)
        return _Explicit(
            cols=cols,
            T=np.ascontiguousarray(G[:, cols]),
            nz=Np,
            nchk=bb.size,
            b=bb,
            Umap=None if Um is None else np.ascontiguousarray(Um[:, cols]),
        )

    def _closed_form(self, prob: _Problem, h: np.ndarray) -> tuple[float, bool] | None:
        """``(J, feasible)`` for the stage vector ``h`` of :meth:`_stage_data`: the cost of
        the problem's unconstrained optimum (a lower bound on the QP's cost, equal to it
        when ``feasible``: no row binds, so the optimum is the QP's); None without a
        closed form.  Non-finite data: not feasible."""
        e = prob.explicit
        if e is None:
            e = self._explicit(prob)
        if e is False:
            return None
        kern = self._kern
        if kern is not None:
            return kern.closed_form(e.T, e.cols, h, e.b, e.nchk)
        out = np.dot(e.T, h[e.cols])
        r = out[e.nchk :]
        return float(np.dot(r, r)), bool(_min_reduce(e.b - out[: e.nchk]) >= 0.0)

    def _adopt(self, prob: _Problem, h: np.ndarray) -> float:
        """Take the feasible closed-form optimum for ``h`` as the problem's solution: leave
        the core the state its solve would, return the first increment."""
        e = prob.explicit
        nz = e.nz
        hv = h[e.cols]
        z = np.dot(e.T[:nz], hv)
        U = z if e.Umap is None else np.dot(e.Umap, hv)
        prob.mpc.adopt_unconstrained(z, U.reshape(nz, 1))
        rate = self._rate
        return min(max(float(z[0]), -rate), rate)

    def _solve(self, prob: _Problem, data: Mapping[str, Any]) -> MPCSolution:
        """Solve one problem of the family from the stage data (001 eq. 11, 14 / 25–26)."""
        Np, l = prob.Np, self._l  # noqa: E741
        _, idx, y_ref, y_max, steps, b, d_idx = self._buffers(prob)
        xs, v_lim, s_o = data["xs"], data["v_lim"], data["s_o"]
        y_ref[:, :2] = xs[idx, :2]
        y_max[...] = prob.y_max
        y_max[:, 0] -= s_o
        np.subtract(v_lim[idx], prob.tau_v, out=y_max[:, 1])
        xs_N = xs[l + Np]
        # terminal set: rows h A_cl^t ξ_N <= b_{N+t} − τ_{N+t} − h (ξ_s,N+t − A_cl^t ξ_s,N)
        nt = steps.size
        if nt:
            xt = xs[steps]
            np.subtract(self._s_max - s_o, xt[:, 0], out=b[:nt])
            if b.size > nt:
                np.subtract(v_lim[steps], xt[:, 1], out=b[nt:])
            b -= prob.tau_term
            b += prob.H_N @ xs_N
            prob.mpc.set_base_bounds(y_max=y_max, h_N=b)
        else:
            prob.mpc.set_base_bounds(y_max=y_max)
        args = (data["xi0"], self._zero1, y_ref)
        kw = {"d": data["D"][d_idx], "x_ref_N": xs_N}
        sol = prob.mpc.solve(*args, **kw)
        if nt and (sol.fallback or sol.status_val not in (1, 2)):
            # terminal set unreachable (the train is already headed beyond it): drop it
            # for this step rather than fall back to the previous plan
            prob.mpc.set_base_bounds(h_N=np.full(prob.H_N.shape[0], _BIG))
            sol = prob.mpc.solve(*args, **kw)
            self._relaxed += 1
        return sol

    def _command(self, obs: Observation, u_acc: float) -> np.ndarray:
        """Clip to the speed-dependent envelope, remember it for the dead time, to newtons."""
        ctx, mi = self.ctx, self._mi
        v = obs.v_mps
        tr = ctx.train
        u_acc = min(max(u_acc, -tr.max_brake_N(v) / mi), tr.max_traction_N(v) / mi)
        if self._l:
            p = self._pend
            del p[0]
            p.append(u_acc)
        if self._multi:
            return distribute(ctx, u_acc * mi, v, obs.u_prev_N, self._shares)
        return np.array([u_acc * mi])

    def _info(self, sol: MPCSolution) -> dict[str, Any]:
        return {
            "terminal_relaxed": self._relaxed,
            "solve_time_s": sol.solve_time_s,
            "iterations": sol.iterations,
            "fallback": sol.fallback,
            "slack_max": sol.slack_max,
            "status_val": sol.status_val,
            "overhead_s": sol.overhead_s,
            "J": sol.cost,
        }

    def compute(self, obs: Observation) -> tuple[np.ndarray, Mapping[str, Any]]:
        data = self._stage_data(obs)
        prob = self._problem(1)
        self._steps += 1
        h = data["h"]
        ev = self._closed_form(prob, h)
        if ev is not None and ev[1]:  # no row binds: the QP's optimum in closed form
            du0 = self._adopt(prob, h)
            return self._command(obs, data["u_prev"] + du0), {
                "terminal_relaxed": self._relaxed,
                "solve_time_s": 0.0,
                "iterations": 0,
                "fallback": False,
                "slack_max": 0.0,
                "status_val": 1,
                "overhead_s": 0.0,
                "J": ev[0],
            }
        sol = self._solve(prob, data)
        return self._command(obs, data["u_prev"] + float(sol.u0[0])), self._info(sol)

    _zero1 = np.zeros(1)
