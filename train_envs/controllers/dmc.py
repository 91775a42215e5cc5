r"""Dynamic matrix control with online softening and correction adjustment (paper 004).

Paper 004 (MPC-MOWOA) tracks the speed profile with a dynamic matrix controller (DMC)
whose reference-softening factor α and feedback-correction coefficient h_c are adjusted
online by fuzzy logic; the seven parameters of that adjustment are what its MOWOA tunes
(004 §3.4). The formulas of 004 §4 were lost in extraction; the standard DMC forms are
used and cited below (Cutler & Ramaker, "Dynamic matrix control — a computer control
algorithm", *Joint Automatic Control Conf.*, 1980; Xi Yugeng, *Predictive Control*, 2nd
ed., 2013, ch. 2; Camacho & Bordons, *Model Predictive Control*, 2nd ed., 2007, ch. 3).
Signs: e = y_r − v (tracking error, y_r the DMC's setpoint, see 2.), ė its rate.

1. Step-response model (004 §4.1)
---------------------------------
Nominal linear model the controller may know (single point, command in acceleration
units u_a = u / M(1+ρ), first-order traction lag τ = ``ctx.actuator_tau_s``, dead time
T_d = ``ctx.dead_time_s``)::

    v̇ = F_a − κ v,     τ Ḟ_a = u_a(t − T_d) − F_a,     κ = R'(v_nom) / M(1+ρ)

κ is the Davis slope ``b + 2 c v_nom`` linearised at v_nom (default: the reference's
mean speed, length / duration). The step coefficients are the sampled unit-step
response, ``a_i = s(i Δt − T_d)`` (0 before the dead time), by exact (matrix-exponential)
discretisation at ``ctx.dt_s`` — exact for a piecewise-constant command, fractional
dead times included (:func:`step_response`). ``a = (a_1 … a_N)``, N = ``model_length``
(60). A second-order actuator (``ctx.actuator_order == 2``) is modelled by the lag
``ctx.actuator_tau_s`` the context gives (the context carries no ω_n, ζ).

*Integrating tail.* The speed response to a force step is integrating in practice:
1/κ ≈ 320 s on paper 004's train against N Δt = 12 s, so a_N is nowhere near a steady
state and the truncation "a_i = a_N for i > N" of the finite step-response model
(which assumes a settling process: Cutler & Ramaker 1980; Camacho & Bordons 2007,
ch. 3) would be wrong. As usual for integrating processes in step-response MPC, the
response beyond N and the shift of the prediction vector are continued from the
final slope (e.g. Gupta, "Control of integrating processes using dynamic matrix
control", *Chem. Eng. Res. Des.* 76(4), 1998; the limits of DMC on such processes:
Lundström, Lee, Morari & Skogestad, "Limitations of dynamic matrix control", *Comput.
Chem. Eng.* 19(4), 1995)::

    a_{N+j} = a_N + Σ_{l≤j} ρ^l (a_N − a_{N−1}),    (S y)_N = y_N + ρ (y_N − y_{N−1})

``tail="linear"`` is the plain linear extrapolation ρ = 1 (``2 y_N − y_{N−1}``).
The default ``tail="model"`` uses ρ = e^{−κΔt} (0.99938 here): the *same* slope
extrapolation, with the slope decaying as the model's slow mode does — exact for the
nominal model once the lag has settled within N (it has: e^{−NΔt/τ} ≈ e^{−24}), and
identical to the linear rule for κ = 0. Why: with ρ = 1 the prediction vector keeps
integrating every past move for ever, i.e. it forgets the −κ v of the model; at
cruise that is κ v M(1+ρ) ≈ 12 kN of phantom traction, a persistent one-step
prediction error (−0.011 m/s on average over the run) that the step-type correction
below cannot remove (it never changes the predicted slope). Measured on
``paper004_urban`` without the position catch-up of 2.: E_v 0.050 m/s and a −9.8 m
stopping error with ρ = 1, against 0.011 m/s and −1.5 m with the model's ρ (with the
catch-up the position loop hides most of it: stop −0.36 m against +0.001 m).

Predictions (Xi 2013, ch. 2)::

    ŷ_N1(k) = ŷ_N0(k) + a Δu(k)                            (effect of the move at k)
    ŷ_PM(k) = ŷ_P0(k) + A ΔU_L(k),   A = [a_{i−j+1}]_{i≤P, j≤L} (P × L dynamic matrix)

ŷ_N0 is the N-vector of predicted speeds at k+1 … k+N with the input held, ŷ_P0 its
first P entries; P = ``prediction_horizon`` (15), L = ``control_horizon`` (15),
L ≤ P ≤ N. At the first step ŷ_N0 = y(0)·1, the model's equilibrium at y(0), whose input
level κ y(0) is taken as the memory u(−1) of the vector (anchoring it on the actual
previous command instead — e.g. 0 N at a standstill on a 2 ‰ grade, whose gradient
force the feedforward then adds — leaves a permanent slope error in ŷ_N0).

2. Reference trajectory and rolling optimisation (004 §4.2)
-----------------------------------------------------------
Softened reference (Xi 2013, ch. 2; 004 §4.2)::

    w(k+i) = α^i y(k) + (1 − α^i) y_r(k+i),    i = 1 … P

with y(k) the measured speed and y_r the setpoint preview: the profile speed
``v_ref(t + iΔt)`` for a time-indexed reference; for a distance-indexed one the
profile followed at its own timing from the current position, ``v(t_p(s) + iΔt)``.
``reference_form="error"`` offers ``w(k+i) = y_r(k+i) − α^i (y_r(k) − y(k))``
(the same for a constant setpoint, but without the lag of the level form on ramps:
the level form pulls w towards y(k) by α^i (y_r(k+i) − y(k)), which on the 0.8 m/s²
braking ramp with α = 0.7 leaves a steady −0.17 m/s error).

Choices where 004 is silent (it tracks speed, but is judged on the stopping position
and time of a time-indexed run):

* *position catch-up* (time-indexed references only): y_r = v_ref +
  ``sat(λ_x (s_ref(t) − s), ±c_max) · min(1, v_ref / v_fade)``, λ_x = 0.1 1/s,
  c_max = 0.2 m/s, v_fade = 1 m/s. A pure speed tracker keeps the position deficit of
  the start (reference acceleration step at t = 0 against the 0.5 s lag and the jerk
  limit: 1.5 m) to the stop; the fade switches the catch-up off as the reference comes
  to rest, so that the train stops instead of creeping up to the stop point;
* *stop hold*: once the preview reaches the end of a profile that ends at the stop,
  the setpoint there is −0.1 m/s (``stop_hold_mps``), so the train really comes to
  rest and is held; an exact regulator to 0 m/s hovers at +1 mm/s for ever.

QP at every step::

    min_ΔU  ‖w − ŷ_P0 − A ΔU‖²_Q + ‖ΔU‖²_R ,   Q = q I_P,  R = r I_L
    s.t.    |Δu(k+j)| ≤ Δu_max                                      (hard)
            u_lo(k+j) ≤ u(k−1) + Σ_{l≤j} Δu(k+l) ≤ u_hi(k+j)        (soft, exact L1 penalty)

Without active constraints the first move is the classic DMC law
``Δu(k) = dᵀ (w − ŷ_P0)``, dᵀ = first row of ``(AᵀQA + R)⁻¹ AᵀQ`` (Cutler & Ramaker
1980; :func:`dmc_gain`; tested against the QP).

*Realisation on the shared core* (:class:`~train_envs.controllers.mpc_core.LinearMPC`,
Δu form, :meth:`DMCController.optimise`): the model is an FIR shift register of the
input level, ``z_1(k+1) = u(k)``, ``z_{j+1}(k+1) = z_j(k)`` (j < P), with two outputs:
``y₁ = Σ_j g_j z_j`` (pulse-response taps ``g_j = a_j − a_{j−1}``) and ``y₂ = z_1`` (the
input level, i.e. the integrator of the moves). From ``x0 = 0`` and the previous level
u(k−1) the core predicts ``y₁(k+i) = u(k−1) a_i + Σ_j a_{i−j+1} Δu(k+j)`` — since
``Σ g_j u_{i−j} = Σ a_j Δu_{i−j}`` its condensed sensitivity *is* the dynamic matrix A
(tested). Passing the reference ``r_i = w_i − ŷ_P0,i + u(k−1) a_i`` on y₁ (weight q; y₂
has weight 0) makes the core's cost the DMC cost above. y₂ carries per-stage soft
bounds [u_lo, u_hi] — the envelope ``[−B(v), F(v)]`` at the speeds the current plan
predicts, minus the feedforward — and the core's hard Δu box is the rate bound. Inside
the QP u is in acceleration units (well scaled for OSQP); q = 1, r = 0.5 by default.
The exact-penalty weight is 1e3 (``soft_penalty``): large against the cost gradients
in these units (the slacks stay at solver precision, ≤ 2e-6 m/s², on the urban run, so
the penalty acts as exact) and moderate enough to keep the QP well conditioned.
OSQP's tolerance is ``eps_abs = eps_rel = 1e-4`` (``osqp_eps``; the core's default is
1e-6): in acceleration units that is 1e-4 m/s², 40 N on a 400 t train. ADMM's slow tail
is the whole cost here: on the constrained steps of the disturbed 004 run (bounds
active, ~5 % of steps) OSQP needed 526 iterations (1.9 ms) on average at 1e-6, 335 at
1e-5 and 32 (0.12 ms) at 1e-4, while the episode metrics (ITAE, stopping, time error,
jerk, energy; two parameter sets x three seeds) moved by at most 4e-4 relative.

*Classic law first* (``classic_law=True``, default).  Each step first forms the whole
unconstrained move plan ``ΔU = K (w − ŷ_P0)``, ``K = (AᵀQA + R)⁻¹AᵀQ``
(:func:`dmc_gain` with ``plan=True``), and keeps it when every ``|Δu| ≤ Δu_max`` and
every level lies inside the envelope at its stage: then no row is active and the plan
*is* the QP's optimum (zero slacks).  The envelope is first checked against the box
:meth:`~train_envs.trains.TrainParams.envelope_box` over the plan's speed range (two
evaluations), per stage only when that box is too tight.  Only the other steps (the
bounds bind on ~3 % of the 004 run's steps) go through the core and OSQP; the core is
told the plan (:meth:`LinearMPC.adopt_unconstrained`), so its warm start is what its
own unconstrained shortcut would have left.  Against sending every step through the
core: the same decisions up to rounding (episode metrics within 1e-4 relative over
six parameter sets x two seeds, the residue of OSQP's 1e-4 tolerance on the
constrained steps); with the QP kept in a reused env (``keeps_parameter_state``), a
tuning evaluation of the 004 env took 1.5x less time than before (median of six
alternating pairs).

3. Feedback correction (004 §4.3)
---------------------------------
At k+1 the prediction error ``e_c(k+1) = y(k+1) − ŷ_1(k)`` corrects the vector, which
is then shifted (Xi 2013, ch. 2; Camacho & Bordons 2007, ch. 3)::

    ŷ_cor = ŷ_N1(k) + h e_c(k+1),   h = [1, h_c, …, h_c]ᵀ
    ŷ_N0(k+1) = S ŷ_cor,            (S y)_i = y_{i+1} (i < N), (S y)_N as in 1.

The first-order-filter form of 004 §4.3 is taken as h_1 = 1, h_i = h_c (i ≥ 2): the
measured sample is matched exactly, the rest of the prediction is moved by h_c e_c,
so a persistent error is absorbed geometrically at the rate h_c — a first-order
filter of the prediction error. Larger h_c rejects an unmodelled disturbance faster,
smaller h_c reacts more calmly (less sensitive to noise, less overshoot). The
prediction vector's input memory is rebuilt every step from the command actually
applied (``obs.u_prev_N``), so clipping or an external override enters it as the move
it really was.

4. Online softening factor (004 §4.4)
-------------------------------------
Estimated response time from e and ė (ė: first-order-filtered difference of e,
T_f = ``edot_filter_s`` = 0.4 s)::

    t_r = 0            if |e| ≤ e_tol and |ė| ≤ ė_tol       (stable state)
    t_r = |e| / |ė|    if e ė < 0                            (error decreasing)
    t_r = M            otherwise                              (error increasing)

Satisfactions (trapezoids, :func:`train_envs.controllers.fuzzy.trapmf`)::

    μ_t = trap(t_r; t_lo − δ_t, t_lo, t_hi, t_hi + δ_t),      μ_t = 1 in the stable state
    μ_y = mean_i trap(ŷ(k+i) − y_r(k+i); −ε − δ_y, −ε, ε, ε + δ_y)
    J   = min(μ_t, μ_y)      (fuzzy decision as intersection: Bellman & Zadeh,
                              "Decision-making in a fuzzy environment", *Management
                              Sci.* 17(4), 1970; ``combine="product"`` available)

ŷ(k+i) are the speeds predicted with the previous plan's remaining moves,
``ŷ_P0 + A [ΔU*(k−1)_{2…L}, 0]``. Softening factor, decreasing in J::

    α = α_min + (α_max − α_min) (e^{γ(1−J)} − 1) / (e^γ − 1),   γ = alpha_trend

(linear for γ → 0; γ > 0 keeps α near α_min unless J is low, γ < 0 the opposite).
004's logic: high satisfaction (small error, response not too fast) → small α, the
reference goes straight to y_r; low satisfaction (error growing, or predicted far
off) → large α, a smoother approach. Choices where 004 is silent:

* 004 gives t_lo = 0.005 s, t_hi = 0.08 s and widths 0.003 s for its 0.5 ms sampling
  period (a scaled motor rig); they are rescaled in *samples*: 10, 160 and 6 samples
  → t_lo = 2 s, t_hi = 32 s, δ_t = 1.2 s at our 0.2 s (they scale with ``ctx.dt_s``).
  M = 10 t_hi. The stable state counts as fully satisfactory (004 only calls it
  "stable"; a strict trapezoid would give μ_t = 0, maximal softening, whenever the
  train tracks well).
* 004's width of the output satisfaction, 0.05 km/h, is kept (δ_y = 0.0139 m/s); its
  bound values were lost: ε = 0.2 km/h. The horizon is aggregated by the mean (the min
  would let one far sample decide). e_tol = 0.05 km/h (004's width), ė_tol = 0.02 m/s².
* μ_t is in practice nearly binary (stable / error decreasing in 2–32 s → 1; error
  growing or vanishing in < 0.8 s → 0), so α mostly switches between its bounds at the
  transients (start, traction/cruise/braking changes, gradient changes); γ only
  matters while J is graded.

5. Online correction coefficient (004 §4.5)
-------------------------------------------
::

    h_c = clip(h_0 + k_h Δh(k_e e, k_ec ė), h_min, 1),    h_min = 0.05

Δh ∈ [−3, 3] is the 7 × 7 rule base :data:`H_TABLE` (product inference, centre-of-sets;
:class:`train_envs.controllers.fuzzy.RuleBase2`) with inputs quantised by k_e [s/m] and
k_ec [s²/m]. 004's Table 2 is lost; the table is written from its stated logic: large
|e| and rapidly decreasing → smaller h (the loop already converges fast, avoid
overshoot); small e rapidly increasing → larger h (react faster to a growing error);
near-zero error and rate → h_0. The table is even (``T[6−i][6−j] = T[i][j]``): only
the size of the error and whether it grows count.

6. Command
----------
``u = M(1+ρ) u_a + u_ff``. Feedforward (``feedforward=True``, default): the nominal
gradient force and the *non-linear part* of the Davis resistance,
``u_ff = R̂(v) − R'(v_nom) v + M g θ(s + v (τ + T_d))/1000`` — the linear part of R is
in the model, so the nominal plant seen by the DMC is exactly the linear model of 1.
The gradient is read τ + T_d ahead (``feedforward_lead``), so that its force arrives
through the actuator lag when the train reaches the gradient change (E_v 0.0203 →
0.0178 m/s, ITAE 146 → 88 m s on ``paper004_urban``). Without feedforward the DMC has to
absorb the gradient and resistance through the correction alone — on an integrating
process a constant load is exactly what the step-type correction cannot remove
(Lundström et al. 1995). The command then passes the comfort jerk limit
``|Δu| ≤ j_max M(1+ρ) Δt`` (j_max = 1.5 m/s³ on the command — the 0.5 s traction lag
smooths the felt jerk further; it is also the QP's hard Δu bound, together with
``ctx.du_max_Nps``), the envelope ``[−B(v), F(v)]`` and the per-input rate limit
``ctx.du_max_Nps`` (:func:`train_envs.controllers._common.distribute`, which also splits
the force by car mass share for per-car scenarios). With 0.75 m/s³ the start (a 0.83
m/s² reference acceleration step at t = 0) builds a 3.2 m position deficit and E_v
rises to 0.035 m/s; without feedforward E_v is 0.052 m/s and ITAE 807 m s.

α_min ≤ α_max is checked whenever parameters are set (``ValueError`` naming both).
Tuners and the Gymnasium env set all seven parameters independently from a box, so
half of their samples would fail: ``alpha_order="clip"`` accepts them and uses
``min(α_min, α_max)`` as the lower bound instead (the stored values are kept, so
``get_params`` returns what was set).

Defaults (tunables: α_max 0.4, α_min 0.1, γ 2, k_e 30 s/m — |e| ≥ 0.1 m/s is "big" —,
h_0 0.8, k_ec 30 s²/m, k_h 0.05, so h_c ∈ [0.65, 0.95]) were picked on
``paper004_urban``: stop error +0.001 m, time error 0.2 s, E_v 0.0178 m/s, ITAE 88 m s
(Fuzzy-PID: −0.75 m, 0.0253 m/s, 357 m s; AFSMC: +0.064 m, 0.0325 m/s, 453 m s). On that
nominal run the DMC's model is exact up to the feedforward's lag, so the prediction
error is tiny and the online adjustments, though active, change the metrics little
(fixed α = 0.1 and h_c = 0.8: E_v 0.0175 m/s, ITAE 78 m s; fixed α = 0.7: stop
+1.67 m, E_v 0.0274 m/s); they matter more under model error (mass, Davis, wind),
where e_c is not small. ``reference_form="error"`` gives E_v 0.0175 m/s, ITAE 77 m s.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import scipy.linalg as sla

from train_envs.controllers._common import distribute, envelope_N, input_shares
from train_envs.controllers.base import ControlContext, Controller, Observation, TunableParam
from train_envs.controllers.fuzzy import (
    NB,
    NM,
    NS,
    PB,
    PM,
    PS,
    ZO,
    RuleBase2,
    trapmf,
    trapmf_scalar,
)
from train_envs.controllers.mpc_core import LinearMPC, MPCSolution
from train_envs.lines.profiles import SpeedProfile
from train_envs.trains import G
from train_envs.validation import (
    check_choice,
    check_finite,
    check_nonnegative,
    check_positive,
    check_range,
)

KMH = 1.0 / 3.6

# Δh rule table: rows e = NB … PB, columns ė = NB … PB (e = v_ref − v)
H_TABLE = np.array([
    [PM, PM, PS, PS, NS, NM, NB],  # e NB
    [PM, PM, PS, PS, ZO, NS, NM],  # e NM
    [PB, PM, PS, ZO, ZO, ZO, NS],  # e NS
    [PB, PM, PS, ZO, PS, PM, PB],  # e ZO
    [NS, ZO, ZO, ZO, PS, PM, PB],  # e PS
    [NM, NS, ZO, PS, PS, PM, PM],  # e PM
    [NB, NM, NS, PS, PS, PM, PM],  # e PB
])


# ------------------------------------------------------------------ model helpers
def step_response(
    dt_s: float,
    n: int,
    *,
    kappa_1ps: float = 0.0,
    tau_s: float = 0.0,
    dead_time_s: float = 0.0,
) -> np.ndarray:
    """Unit-step response a_1 … a_n of ``v̇ = F − κ v``, ``τ Ḟ = u(t − T_d) − F``.

    Exact: the continuous step response sampled at ``i dt − T_d`` (ZOH-exact, matrix
    exponential). Units: speed per unit input (m/s per m/s² with u in acceleration units).
    """
    check_positive("dt_s", dt_s)
    check_nonnegative("kappa_1ps", kappa_1ps)
    check_nonnegative("tau_s", tau_s)
    check_nonnegative("dead_time_s", dead_time_s)
    if n < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    if tau_s > 0:
        A = np.array([[-kappa_1ps, 1.0], [0.0, -1.0 / tau_s]])
        B = np.array([0.0, 1.0 / tau_s])
    else:
        A = np.array([[-kappa_1ps]])
        B = np.array([1.0])
    nx = A.shape[0]

    def flow(t: float) -> tuple[np.ndarray, np.ndarray]:
        M = np.zeros((nx + 1, nx + 1))
        M[:nx, :nx] = A * t
        M[:nx, nx] = B * t
        E = sla.expm(M)
        return E[:nx, :nx], E[:nx, nx]

    Ad, Bd = flow(dt_s)
    out = np.zeros(n)
    x = np.zeros(nx)
    started = False
    for i in range(1, n + 1):
        t = i * dt_s - dead_time_s
        if t <= 1e-12:
            continue
        if not started:  # first sample after the dead time: partial interval
            _, Bt = flow(t)
            x = Bt.copy()
            started = True
        else:
            x = Ad @ x + Bd
        out[i - 1] = x[0]
    return out


def extend_step_response(a: np.ndarray, n: int, ratio: float = 1.0) -> np.ndarray:
    """a_1 … a_n, continuing a beyond its length from its final slope (integrating tail).

    ``a_{N+j} = a_N + Σ_{l=1..j} ρ^l (a_N − a_{N−1})``: linear extrapolation for ρ = 1,
    the exact tail of a slow first-order mode for ρ = e^{−κΔt} < 1.
    """
    a = np.asarray(a, dtype=float)
    if n <= a.size:
        return a[:n].copy()
    slope = a[-1] - a[-2] if a.size > 1 else a[-1]
    j = np.arange(1, n - a.size + 1)
    incr = slope * ratio**j
    return np.concatenate([a, a[-1] + np.cumsum(incr)])


def dynamic_matrix(a: np.ndarray, P: int, L: int, ratio: float = 1.0) -> np.ndarray:
    """P × L dynamic matrix ``A[i, j] = a_{i−j+1}`` (0 above the diagonal)."""
    a = extend_step_response(a, P, ratio)
    A = np.zeros((P, L))
    for j in range(L):
        A[j:, j] = a[: P - j]
    return A


#: solver fields of a step decided by the unconstrained law (solved, no OSQP)
_UNCONSTRAINED_INFO = (0.0, 0, 0.0, 0.0, 1)


def _max_abs(x: np.ndarray) -> float:
    """max |x_i| of a short vector (two reductions instead of abs + max)."""
    return max(float(x.max()), -float(x.min()))


def dmc_gain(A: np.ndarray, q: float, r: float, *, plan: bool = False) -> np.ndarray:
    """dᵀ: first row of ``(AᵀQA + R)⁻¹AᵀQ`` with Q = q I, R = r I (unconstrained DMC law);
    with ``plan=True`` the whole ``(L, P)`` matrix (all L moves of the plan)."""
    P, L = A.shape
    K = np.linalg.solve(q * A.T @ A + r * np.eye(L), q * A.T)
    return np.ascontiguousarray(K) if plan else K[0]


def shift_prediction(y: np.ndarray, ratio: float = 1.0) -> np.ndarray:
    """Shift matrix S: ``(S y)_i = y_{i+1}``, ``(S y)_N = y_N + ρ (y_N − y_{N−1})``.

    ρ = 1 is the linear extrapolation of an integrating tail (``2 y_N − y_{N−1}``).
    """
    out = np.empty_like(y)
    out[:-1] = y[1:]
    out[-1] = y[-1] + ratio * (y[-1] - y[-2]) if y.size > 1 else y[-1]
    return out


def softened_reference(y: float, y_r: np.ndarray, alpha: float) -> np.ndarray:
    """``w(k+i) = α^i y(k) + (1 − α^i) y_r(k+i)``, i = 1 … len(y_r)."""
    ai = alpha ** np.arange(1, len(y_r) + 1)
    return ai * y + (1.0 - ai) * np.asarray(y_r, dtype=float)


def softening_factor(J: float, alpha_min: float, alpha_max: float, trend: float) -> float:
    """``α = α_min + (α_max − α_min)(e^{γ(1−J)} − 1)/(e^γ − 1)`` (linear for γ → 0)."""
    J = min(1.0, max(0.0, J))
    if abs(trend) < 1e-9:
        f = 1.0 - J
    else:
        f = math.expm1(trend * (1.0 - J)) / math.expm1(trend)
    return alpha_min + (alpha_max - alpha_min) * f


def response_time(e: float, edot: float, e_tol: float, edot_tol: float, big: float) -> float:
    """Estimated response time: 0 (stable), |e|/|ė| (error decreasing) or ``big``."""
    if abs(e) <= e_tol and abs(edot) <= edot_tol:
        return 0.0
    if e * edot < 0.0:
        return min(big, abs(e) / abs(edot))
    return big


# ------------------------------------------------------------------ controller
class DMCController(Controller):
    """DMC with fuzzy online softening factor α and correction coefficient h_c (paper 004)."""

    name = "dmc"
    #: the model, dynamic matrix and QP kept across resets do not depend on the seven
    #: tunable parameters (see reset): a reused env keeps this controller
    keeps_parameter_state = False
    PARAMS = (
        TunableParam("alpha_max", 0.0, 0.99, 0.4,
                     description="largest softening factor α_max [-]"),
        TunableParam("alpha_min", 0.0, 0.99, 0.1,
                     description="smallest softening factor α_min [-]"),
        TunableParam("alpha_trend", -10.0, 10.0, 2.0,
                     description="shaping (trend) factor γ of α(J) [-]"),
        TunableParam("k_e", 0.1, 1000.0, 30.0, log=True,
                     description="speed error quantisation factor [s/m] (|e| >= 3/k_e is 'big')"),
        TunableParam("h0", 0.05, 1.0, 0.8,
                     description="initial (nominal) correction coefficient h_0 [-]"),
        TunableParam("k_ec", 0.1, 1000.0, 30.0, log=True,
                     description="error-rate quantisation factor [s^2/m]"),
        TunableParam("k_h", 0.0, 0.3, 0.05,
                     description="correction proportional factor k_h [-] (h_c swing 3 k_h)"),
    )

    def __init__(
        self,
        *,
        model_length: int = 60,
        prediction_horizon: int = 15,
        control_horizon: int = 15,
        q: float = 1.0,
        r: float = 0.5,
        jerk_max_mps3: float = 1.5,
        feedforward: bool = True,
        v_nominal_mps: float | None = None,
        response_bounds_samples: tuple[float, float] = (10.0, 160.0),
        response_widths_samples: tuple[float, float] = (6.0, 6.0),
        pred_error_bound_mps: float = 0.2 * KMH,
        pred_error_width_mps: float = 0.05 * KMH,
        e_tol_mps: float = 0.05 * KMH,
        edot_tol_mps2: float = 0.02,
        combine: str = "min",
        h_min: float = 0.05,
        edot_filter_s: float = 0.4,
        soft_penalty: float = 1e3,
        tail: str = "model",
        reference_form: str = "level",
        position_gain_1ps: float = 0.1,
        catchup_max_mps: float = 0.2,
        catchup_fade_mps: float = 1.0,
        stop_hold_mps: float = 0.1,
        feedforward_lead: bool = True,
        alpha_order: str = "raise",
        osqp_eps: float = 1e-4,
        classic_law: bool = True,
        **params: float,
    ) -> None:
        for name, val in (
            ("model_length", model_length),
            ("prediction_horizon", prediction_horizon),
            ("control_horizon", control_horizon),
        ):
            if isinstance(val, bool) or not isinstance(val, int | np.integer) or val < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {val!r}")
        if model_length < 2:
            raise ValueError(f"model_length must be >= 2, got {model_length}")
        if prediction_horizon > model_length:
            raise ValueError(
                f"prediction_horizon ({prediction_horizon}) must not exceed "
                f"model_length ({model_length})"
            )
        if control_horizon > prediction_horizon:
            raise ValueError(
                f"control_horizon ({control_horizon}) must not exceed "
                f"prediction_horizon ({prediction_horizon})"
            )
        self.N = int(model_length)
        self.P = int(prediction_horizon)
        self.L = int(control_horizon)
        self.q = check_positive("q", q)
        self.r = check_positive("r", r)
        self.jerk_max = check_positive("jerk_max_mps3", jerk_max_mps3, allow_inf=True)
        self.feedforward = bool(feedforward)
        self.v_nominal = (
            None if v_nominal_mps is None else check_nonnegative("v_nominal_mps", v_nominal_mps)
        )
        lo, hi = (check_nonnegative("response_bounds_samples", x) for x in response_bounds_samples)
        if lo > hi:
            raise ValueError(f"response_bounds_samples must be (low, high), got {lo} > {hi}")
        self.t_bounds_samples = (lo, hi)
        self.t_widths_samples = tuple(
            check_nonnegative("response_widths_samples", x) for x in response_widths_samples
        )
        self.eps_y = check_nonnegative("pred_error_bound_mps", pred_error_bound_mps)
        self.delta_y = check_nonnegative("pred_error_width_mps", pred_error_width_mps)
        self.e_tol = check_nonnegative("e_tol_mps", e_tol_mps)
        self.edot_tol = check_nonnegative("edot_tol_mps2", edot_tol_mps2)
        self.combine = check_choice("combine", combine, ("min", "product"))
        self.h_min = check_positive("h_min", h_min)
        if self.h_min > 1.0:
            raise ValueError(f"h_min must lie in (0, 1], got {h_min}")
        self.edot_filter_s = check_nonnegative("edot_filter_s", edot_filter_s)
        self.soft_penalty = check_positive("soft_penalty", soft_penalty)
        self.osqp_eps = check_range("osqp_eps", osqp_eps, 1e-10, 1e-2)
        if not isinstance(classic_law, bool):
            raise ValueError(f"classic_law must be True or False, got {classic_law!r}")
        self.classic_law = classic_law
        self.tail = check_choice("tail", tail, ("model", "linear"))
        self.reference_form = check_choice("reference_form", reference_form, ("level", "error"))
        self.lambda_x = check_nonnegative("position_gain_1ps", position_gain_1ps)
        self.catchup_max = check_nonnegative("catchup_max_mps", catchup_max_mps)
        self.catchup_fade = check_positive("catchup_fade_mps", catchup_fade_mps)
        self.stop_hold = check_nonnegative("stop_hold_mps", stop_hold_mps)
        self.ff_lead = bool(feedforward_lead)
        self.alpha_order = check_choice("alpha_order", alpha_order, ("raise", "clip"))
        self.rules = RuleBase2(H_TABLE, names=("e", "edot"))
        super().__init__(**params)
        self._on_params_changed()

    # -------------------------------------------------------------- params
    def set_params(self, **params: float) -> None:
        old = dict(self._params)
        super().set_params(**params)
        if self.alpha_order == "raise" and self._params["alpha_min"] > self._params["alpha_max"]:
            self._params = old
            self._on_params_changed()  # the derived values follow the rollback
            raise ValueError(
                f"param alpha_min ({params.get('alpha_min', old['alpha_min'])}) must not "
                f"exceed param alpha_max ({params.get('alpha_max', old['alpha_max'])})"
            )

    def _on_params_changed(self) -> None:
        if not hasattr(self, "rules"):
            return
        p = self._params
        self.rules.scale_e = p["k_e"]
        self.rules.scale_ec = p["k_ec"]
        self._update_laws()

    def _update_laws(self) -> None:
        """Per-step constants of compute() from the parameters: the effective α bounds
        (α_min ≤ α_max unless alpha_order="clip" let it exceed), γ and e^γ − 1 of
        softening_factor(), h_0 and k_h."""
        p = self._params
        a_max = p["alpha_max"]
        trend = p["alpha_trend"]
        self._alpha_law = (
            min(p["alpha_min"], a_max),
            a_max,
            trend,
            None if abs(trend) < 1e-9 else math.expm1(trend),
        )
        self._h_law = (p["h0"], p["k_h"])

    # -------------------------------------------------------------- model
    def reset(self, ctx: ControlContext) -> None:
        super().reset(ctx)
        tr = ctx.train
        dt = ctx.dt_s
        self.M = tr.inertial_mass_kg
        ref = ctx.reference
        if self.v_nominal is not None:
            v_nom = self.v_nominal
        else:
            v_nom = ref.end_m / max(ref.duration_s, 1e-9) if ref.duration_s > 0 else 0.0
        self.v_nom = float(v_nom)
        #: linearised Davis slope R'(v_nom) [N s/m]
        self.k_davis = tr.davis_b_Ns_per_m + 2.0 * tr.davis_c_Ns2_per_m2 * self.v_nom
        tau = ctx.actuator_tau_s if ctx.actuator_order else 0.0
        self._shares = input_shares(ctx)
        # rate bound (whole train, acceleration units): comfort jerk and ctx rate limit
        du = self.jerk_max * dt
        if math.isfinite(ctx.du_max_Nps):
            du = min(du, ctx.du_max_Nps * dt / float(np.max(self._shares)) / self.M)
        self.du_max_a = du
        # the model, the dynamic matrix and the QP depend on the train and the timing only
        # (not on the tunable parameters): kept across resets of the same structure, the QP
        # with OSQP's state reset so that every episode is reproducible on its own
        key = (
            dt,
            self.k_davis,
            self.M,
            tau,
            ctx.dead_time_s,
            du,
            envelope_N(tr, 0.0),
        )
        cached = getattr(self, "_model_cache", None)
        if cached is not None and cached[0] == key:
            _, self.a, self.tail_ratio, self.A_dyn, self._K_plan, self.mpc, self._du_rows = cached
            self.d_gain = self._K_plan[0]
            self.mpc.reset_solver()
        else:
            #: step coefficients a_1 … a_N (m/s per m/s² of command)
            self.a = step_response(
                dt,
                self.N,
                kappa_1ps=self.k_davis / self.M,
                tau_s=tau,
                dead_time_s=ctx.dead_time_s,
            )
            if not np.any(self.a[: self.P] > 0):
                raise ValueError(
                    f"dead time {ctx.dead_time_s} s hides the whole prediction horizon "
                    f"({self.P} x {dt} s): increase prediction_horizon"
                )
            #: slope ratio of the tail extrapolation (1: linear; e^{−κΔt}: exact for the model)
            self.tail_ratio = (
                math.exp(-self.k_davis / self.M * dt) if self.tail == "model" else 1.0
            )
            #: P × L dynamic matrix
            self.A_dyn = dynamic_matrix(self.a, self.P, self.L, self.tail_ratio)
            #: the whole unconstrained move plan ΔU = K (w − ŷ_P0), (L, P); its first row
            #: is the classic gain dᵀ
            self._K_plan = dmc_gain(self.A_dyn, self.q, self.r, plan=True)
            self.d_gain = self._K_plan[0]
            self.mpc = self._build_core()
            self._model_cache = (
                key, self.a, self.tail_ratio, self.A_dyn, self._K_plan, self.mpc, self._du_rows
            )
        self._i = np.arange(1, self.P + 1)
        self._yN0: np.ndarray | None = None
        self._u_prev2 = 0.0  # u_a(k−2)
        self._ff_prev = 0.0
        self._e_prev: float | None = None
        self._edot = 0.0
        #: the gradient feedforward is read this far ahead (actuator lag + dead time)
        self._ff_lead = (tau + ctx.dead_time_s) if self.ff_lead else 0.0
        self._t_lo = self.t_bounds_samples[0] * dt
        self._t_hi = self.t_bounds_samples[1] * dt
        self._dt1 = self.t_widths_samples[0] * dt
        self._dt2 = self.t_widths_samples[1] * dt
        self._t_big = 10.0 * self._t_hi
        tp = getattr(ref.profile, "t_s", None)
        self._t_profile_end = float(tp[-1]) if tp is not None else math.inf
        self._prepare_fast_path(ctx)

    # -------------------------------------------------------------- per-step fast path
    def _prepare_fast_path(self, ctx: ControlContext) -> None:
        """Precompute what :meth:`compute` needs every step (its arithmetic is unchanged).

        The per-step work runs on Python floats and lists where NumPy's per-call overhead
        on 15-element vectors dominated, with the *same* floating-point operations in the
        same order, so that the result is identical bit for bit (checked by replaying
        recorded runs against the previous implementation). Vector operations whose
        rounding depends on NumPy's kernels (the dynamic-matrix product, the pairwise
        sum of the mean) stay in NumPy. Look-ups go through the owners' own methods: the
        time-indexed :class:`SpeedProfile`'s scalar ``v_at_t``/``s_at_t`` and
        :meth:`SpeedProfile.sample_sv` (equal to its array methods bit for bit), and
        ``TrainParams.envelope_lists`` (equal to ``envelope_N`` bit for bit) for the
        force bounds over the plan.
        """
        dt = ctx.dt_s
        P, N = self.P, self.N
        tr = ctx.train
        self._update_laws()
        self._kf = dt / (self.edot_filter_s + dt)  # ė filter gain Δt / (T_f + Δt)
        self._aP = self.a[:P].tolist()
        self._dtk = (dt * self._i).tolist()  # the preview's time offsets i Δt
        # prediction vector buffers and fixed views: ŷ_N0, ŷ_N1, ŷ_P0 = ŷ_N0[:P], the
        # shifted write ŷ_N0[:−1] ← ŷ_N1[1:] + h_c e_c, and ΔU of the previous plan
        self._yN0_buf, self._yN1_buf = np.empty(N), np.empty(N)
        self._dU_shift = np.zeros(self.L)  # [ΔU*(k−1)_{2…L}, 0]
        self._w_cache: dict[float, tuple[list[float], list[float]]] = {}
        # QP data buffers (shared with optimise())
        r = np.zeros((P, 2))
        # bounds of the input-level output only (the tracked output has none): the
        # core's narrow per-call form
        y_min = np.zeros((P, 1))
        y_max = np.zeros((P, 1))
        self._opt_bufs = (r, y_min, y_max, np.zeros(P))
        self._link_views()
        # comfort jerk bound on the command [N per step]
        self._jerk_du = self.jerk_max * self.M * dt if math.isfinite(self.jerk_max) else None
        # feedforward: M g and whether there is a track
        self._mG = tr.mass_kg * G
        self._has_track = bool(ctx.track)
        # one whole-train input: distribute() on floats
        sh = self._shares
        self._single = ctx.n_inputs == 1 and sh.shape == (1,) and sh[0] == 1.0
        self._du_step = ctx.du_max_Nps * dt if math.isfinite(ctx.du_max_Nps) else None
        # satisfaction trapezoids: (a, b, c, d) of μ_t, and of μ_y with its symmetry
        self._t_trap = (self._t_lo - self._dt1, self._t_lo, self._t_hi, self._t_hi + self._dt2)
        eps, dy = self.eps_y, self.delta_y
        ya, yb, yc, yd = -eps - dy, -eps, eps, eps + dy
        self._y_trap = (ya, yb, yc, yd)
        # μ_y(x) = clip((d − |x|)/(d − c), 0, 1) exactly when a = −d, b = −c, b − a = d − c
        # (the rising edge is the mirror image of the falling one) and b > a
        self._y_sym = ya == -yd and yb == -yc and yb - ya == yd - yc and yb > ya
        self._fast_ref = self._check_fast_preview(ctx)

    def _link_views(self) -> None:
        """Fixed views into the per-run buffers that compute() writes through."""
        yN0, yN1 = self._yN0_buf, self._yN1_buf
        self._yN_views = (yN0[: self.P], yN0[:-1], yN1[1:])
        self._dU_head = self._dU_shift[:-1]
        r, y_min, y_max, _ = self._opt_bufs
        self._qp_cols = (r[:, 0], y_min[:, 0], y_max[:, 0])

    def __setstate__(self, state: dict[str, Any]) -> None:
        # copies (pickle, deepcopy) turn views into arrays of their own: link them again
        self.__dict__.update(state)
        if "_yN_views" in state:
            self._link_views()

    def _check_fast_preview(self, ctx: ControlContext) -> SpeedProfile | None:
        """The reference's SpeedProfile when it is time-indexed (the float fast path).

        The fast path reads it through its own scalar methods (``v_at_t``/``s_at_t`` on a
        float, :meth:`SpeedProfile.sample_sv` for the preview), which equal its array
        methods bit for bit.
        """
        ref = ctx.reference
        prof = getattr(ref, "profile", None)
        if getattr(ref, "mode", None) != "time" or not isinstance(prof, SpeedProfile):
            return None
        return prof

    def _reference_now(self, t0: float, s_m: float) -> tuple[float, float, float]:
        """(v_ref, y_r(k), catch-up c) of :meth:`reference_preview` (fast path)."""
        prof = self._fast_ref
        v0 = prof.v_at_t(t0)
        y0 = v0
        c = 0.0
        if self.lambda_x > 0.0:  # position catch-up
            c = self.lambda_x * (prof.s_at_t(t0) - s_m)
            c = min(self.catchup_max, max(-self.catchup_max, c))
            y0 = v0 + c * min(1.0, v0 / self.catchup_fade)
        if self.stop_hold > 0.0 and self.ctx.s_stop_m is not None and t0 >= self._t_profile_end:
            y0 = -self.stop_hold
        return v0, y0, c

    def _preview_memberships(
        self, t0: float, c: float, y_pred: list[float]
    ) -> tuple[list[float], list[float]]:
        """(y_r(k+1 … k+P), μ_y terms) for a time-indexed SpeedProfile (fast path).

        The preview of :meth:`reference_preview` (profile speed at t0 + iΔt, plus the
        faded catch-up c, then the stop hold) and the trapezoid memberships of the
        predicted errors ``ŷ − y_r`` of :meth:`satisfaction`.
        """
        _, v_prof = self._fast_ref.sample_sv(t0, self.ctx.dt_s, self.P)
        lam = self.lambda_x > 0.0
        fade = self.catchup_fade
        hold = self.stop_hold > 0.0 and self.ctx.s_stop_m is not None
        t_end = self._t_profile_end
        y_r: list[float] = []
        for d, v in zip(self._dtk, v_prof, strict=True):
            if lam:
                q = v / fade
                v = v + c * (q if q < 1.0 else 1.0)
            if hold and t0 + d >= t_end:
                # the profile has ended at the stop: aim a little below zero (see
                # reference_preview)
                v = -self.stop_hold
            y_r.append(v)
        return y_r, self._memberships(y_pred, y_r)

    def _memberships(self, y_pred: list[float], y_r: list[float]) -> list[float]:
        """Trapezoid memberships of the predicted errors ``ŷ − y_r`` (as in satisfaction)."""
        ya, yb, yc, yd = self._y_trap
        if self._y_sym:
            dc = yd - yc
            out = []
            for yp, yr in zip(y_pred, y_r, strict=True):
                ax = abs(yp - yr)
                out.append(1.0 if ax <= yc else (0.0 if ax >= yd else (yd - ax) / dc))
            return out
        return [trapmf_scalar(yp - yr, ya, yb, yc, yd) for yp, yr in zip(y_pred, y_r, strict=True)]

    def _build_core(self) -> LinearMPC:
        """The DMC QP on :class:`LinearMPC`: FIR register of the input level (see module doc)."""
        P = self.P
        g = np.diff(np.concatenate([[0.0], self.a[:P]]))  # pulse-response taps
        A = np.eye(P, k=-1)
        B = np.zeros((P, 1))
        B[0, 0] = 1.0
        C = np.zeros((2, P))
        C[0] = g
        C[1, 0] = 1.0
        tr = self.ctx.train
        lo0, hi0 = envelope_N(tr, 0.0)
        big = 10.0 * max(abs(lo0), abs(hi0)) / self.M  # construction-time bounds; per call
        # no rate bound at all: a bound far outside reach keeps the core's Δu rows
        # (LinearMPC with du_min = du_max = None fails to build at the time of writing)
        du = self.du_max_a if math.isfinite(self.du_max_a) else 100.0 * big
        self._du_rows = du
        return LinearMPC(
            A, B, C,
            Np=P,
            Nc=self.L,
            Q=np.diag([self.q, 0.0]),
            R=self.r,
            u_min=-np.inf,
            u_max=np.inf,
            du_min=-du,
            du_max=du,
            y_min=[-np.inf, -big],
            y_max=[np.inf, big],
            soft_penalty=self.soft_penalty,
            # the DMC's bounds are active on ~3 % of the 004 run's steps: the exact
            # unconstrained optimum spares OSQP the rest (see LinearMPC)
            unconstrained_first=True,
            osqp_settings={"eps_abs": self.osqp_eps, "eps_rel": self.osqp_eps},
        )

    # -------------------------------------------------------------- helpers
    def feedforward_force(self, s_m: float, v_mps: float) -> float:
        """``R̂(v) − R'(v_nom) v + M g θ(s)/1000`` [N] (0 without feedforward)."""
        if not self.feedforward:
            return 0.0
        ctx = self.ctx
        tr = ctx.train
        theta = float(ctx.track.equivalent_gradient_permil_at(s_m)) if ctx.track else 0.0
        return tr.resistance_N(v_mps) - self.k_davis * v_mps + tr.mass_kg * G * theta / 1000.0

    def reference_preview(self, obs: Observation) -> tuple[float, float, np.ndarray]:
        """(v_ref(k), y_r(k), y_r(k+1 … k+P)): profile speed now, DMC setpoint and preview.

        The setpoint is the profile speed plus, for time-indexed references, the faded
        position catch-up ``c = sat(λ_x (s_ref(t) − s), ±c_max) · min(1, v_r / v_fade)``.
        """
        ctx = self.ctx
        ref = ctx.reference
        prof = ref.profile
        dt = ctx.dt_s
        if ref.mode == "distance":
            t0 = float(prof.t_at_s(obs.s_m))
            v0 = float(prof.v_at_s(obs.s_m))
        else:
            t0 = obs.t_s
            v0 = float(prof.v_at_t(t0))
        ts = t0 + dt * self._i
        y_r = np.asarray(prof.v_at_t(ts), dtype=float)
        y0 = v0
        if ref.mode == "time" and self.lambda_x > 0.0:
            c = self.lambda_x * (float(prof.s_at_t(t0)) - obs.s_m)
            c = min(self.catchup_max, max(-self.catchup_max, c))
            y0 = v0 + c * min(1.0, v0 / self.catchup_fade)
            y_r = y_r + c * np.minimum(1.0, y_r / self.catchup_fade)
        if self.stop_hold > 0.0 and ctx.s_stop_m is not None and ts[-1] >= self._t_profile_end:
            # the profile has ended at the stop: aim a little below zero so that the
            # train really comes to rest (and is held) instead of creeping towards 0
            y_r = np.where(ts >= self._t_profile_end, -self.stop_hold, y_r)
            if t0 >= self._t_profile_end:
                y0 = -self.stop_hold
        return v0, y0, y_r

    def satisfaction(self, e: float, edot: float, eps_pred: np.ndarray) -> tuple[float, ...]:
        """(t_r, μ_t, μ_y, J) from the error, its rate and the predicted tracking errors."""
        t_r = response_time(e, edot, self.e_tol, self.edot_tol, self._t_big)
        if t_r == 0.0:
            mu_t = 1.0
        else:
            mu_t = float(trapmf(
                t_r, self._t_lo - self._dt1, self._t_lo, self._t_hi, self._t_hi + self._dt2
            ))
        eps, dy = self.eps_y, self.delta_y
        mu_y = float(np.mean(trapmf(eps_pred, -eps - dy, -eps, eps, eps + dy)))
        J = min(mu_t, mu_y) if self.combine == "min" else mu_t * mu_y
        return t_r, mu_t, mu_y, J

    def correction_coefficient(self, e: float, edot: float) -> float:
        """``h_c = clip(h_0 + k_h Δh(k_e e, k_ec ė), h_min, 1)``."""
        p = self._params
        return min(1.0, max(self.h_min, p["h0"] + p["k_h"] * float(self.rules(e, edot))))

    def optimise(
        self,
        w: np.ndarray,
        y_free: np.ndarray,
        u_prev: float,
        u_lo: np.ndarray | float = -np.inf,
        u_hi: np.ndarray | float = np.inf,
    ) -> MPCSolution:
        """Solve the DMC QP ``min ‖w − ŷ_P0 − AΔU‖²_Q + ‖ΔU‖²_R`` on the shared core.

        Args (acceleration units, m/s²): ``w`` the softened reference (P,), ``y_free``
        the free response ŷ_P0 (P,), ``u_prev`` the input level u(k−1), ``u_lo``/``u_hi``
        the soft level bounds of stages k … k+P−1 (scalars or (P,)).
        """
        P = self.P
        bufs = self.__dict__.get("_opt_bufs")
        if bufs is None or bufs[0].shape[0] != P:
            r = np.zeros((P, 2))
            y_min = np.zeros((P, 1))
            y_max = np.zeros((P, 1))
            bufs = self._opt_bufs = (r, y_min, y_max, np.zeros(P))
        r, y_min, y_max, x0 = bufs
        np.subtract(w, y_free, out=r[:, 0])
        r[:, 0] += u_prev * self.a[:P]
        y_min[:, 0] = u_lo
        y_max[:, 0] = u_hi
        return self.mpc.solve(x0, np.array([u_prev]), r, y_min=y_min, y_max=y_max)

    # -------------------------------------------------------------- control
    def compute(self, obs: Observation) -> tuple[np.ndarray, Mapping[str, Any]]:
        ctx = self.ctx
        dt = ctx.dt_s
        M = self.M
        P = self.P
        y = obs.v_mps
        if type(y) is not float or y - y != 0.0:  # x − x is 0 iff x is a finite float
            y = check_finite("measured speed v_mps", y)
        s_m = obs.s_m
        if type(s_m) is not float or s_m - s_m != 0.0:
            check_finite("measured position s_m", s_m)
        t0 = obs.t_s
        y_r: list[float] | None = None
        if self._fast_ref is not None and type(t0) is float and t0 - t0 == 0.0:
            # reference_preview() in two parts: now, and the preview (below, with μ_y)
            v_ref, y0_ref, c_catch = self._reference_now(t0, s_m)
        else:
            v_ref, y0_ref, y_r_arr = self.reference_preview(obs)
            y_r = np.asarray(y_r_arr, dtype=float).tolist()
        e = y0_ref - y
        if self._e_prev is None:
            self._e_prev = e
        self._edot += self._kf * ((e - self._e_prev) / dt - self._edot)
        self._e_prev = e
        edot = self._edot

        # ---- correction coefficient and feedback correction + shift (§3, §5)
        h0, k_h = self._h_law  # correction_coefficient()
        h_c = min(1.0, max(self.h_min, h0 + k_h * self.rules.outputs(e, edot)[0]))
        if self.feedforward:  # feedforward_force() at the look-ahead position
            s_ff = s_m + max(y, 0.0) * self._ff_lead
            theta = float(ctx.track.equivalent_gradient_permil_at(s_ff)) if self._has_track else 0.0
            ff = ctx.train.resistance_N(y) - self.k_davis * y + self._mG * theta / 1000.0
        else:
            ff = 0.0
        up_N = obs.u_prev_N
        if type(up_N) is np.ndarray and up_N.shape == (1,):
            u_total_prev = up_N.item(0)
        else:
            u_total_prev = float(np.sum(up_N))
        yP0_arr, yN0_head, yN1_tail = self._yN_views
        if self._yN0 is None:
            u_prev = (u_total_prev - ff) / M
            yN0 = self._yN0 = self._yN0_buf
            yN0.fill(y)
            e_c = None
            # input memory of the prediction vector: at the first step the flat ŷ_N0 = y(0)
            # is the model's equilibrium at y(0), i.e. the input level κ y(0)
            self._u_prev2 = self.k_davis * y / M
        else:
            u_prev = (u_total_prev - self._ff_prev) / M  # u_a(k−1) as really applied
            yN0, yN1 = self._yN0, self._yN1_buf
            np.multiply(self.a, u_prev - self._u_prev2, out=yN1)
            np.add(yN0, yN1, out=yN1)  # ŷ_N1 = ŷ_N0 + a Δu
            y1 = yN1.item(0)
            e_c = y - y1
            # ŷ_N0 ← S ŷ_cor with ŷ_cor = ŷ_N1 + h e_c (h = [1, h_c, …]), written in place
            # (shift_prediction: the entries 2 … N move up, the last is extrapolated)
            np.add(yN1_tail, h_c * e_c, out=yN0_head)
            N = self.N
            c1 = yN0.item(N - 2)
            c2 = yN0.item(N - 3) if N > 2 else y1 + e_c
            yN0[N - 1] = c1 + self.tail_ratio * (c1 - c2)
            self._u_prev2 = u_prev
        yP0 = yP0_arr.tolist()

        # ---- satisfaction and softening factor (§4)
        y_pred = (yP0_arr + self.A_dyn @ self._dU_shift).tolist()
        # response time and μ_t (response_time(), satisfaction())
        if abs(e) <= self.e_tol and abs(edot) <= self.edot_tol:
            t_r = 0.0
        elif e * edot < 0.0:
            t_r = min(self._t_big, abs(e) / abs(edot))
        else:
            t_r = self._t_big
        mu_t = 1.0 if t_r == 0.0 else trapmf_scalar(t_r, *self._t_trap)
        # μ_y: mean trapezoid membership of the predicted errors ŷ − y_r
        if y_r is None:
            y_r, mus = self._preview_memberships(t0, c_catch, y_pred)
        else:
            mus = self._memberships(y_pred, y_r)
        n1 = mus.count(1.0)
        if n1 + mus.count(0.0) == P:  # a sum of 0s and 1s is exact in any order
            mu_y = n1 / P
        else:  # np.mean's pairwise summation
            mu_y = float(np.add.reduce(np.array(mus))) / P
        J = min(mu_t, mu_y) if self.combine == "min" else mu_t * mu_y
        # softening_factor()
        a_min, a_max, trend, em = self._alpha_law
        Jc = min(1.0, max(0.0, J))
        f = 1.0 - Jc if em is None else math.expm1(trend * (1.0 - Jc)) / em
        alpha = a_min + (a_max - a_min) * f
        # α^i and 1 − α^i (i = 1 … P), cached per α (α mostly sits at its bounds)
        powers = self._w_cache.get(alpha)
        if powers is None:
            ai = alpha ** self._i
            powers = (ai.tolist(), (1.0 - ai).tolist())
            if len(self._w_cache) >= 64:
                self._w_cache.clear()
            self._w_cache[alpha] = powers
        ai, om = powers

        # ---- rolling optimisation on the shared core (§2)
        # QP data of optimise(): r = w − ŷ_P0 + u(k−1) a with the softened reference w,
        # soft level bounds (lo − ff)/M, (hi − ff)/M of the envelope at the plan's speeds
        # the tracking error the moves act on, w − ŷ_P0
        if self.reference_form == "level":  # w = softened_reference(y, y_r, α)
            rows = zip(ai, om, y_r, yP0, strict=True)
            e_w = [a_i * y + o_i * r_i - p_i for a_i, o_i, r_i, p_i in rows]
        else:  # w = y_r − α^i (y_r(k) − y)
            d0 = y0_ref - y
            e_w = [r_i - a_i * d0 - p_i for a_i, r_i, p_i in zip(ai, y_r, yP0, strict=True)]
        v_plan = [y]
        v_plan += y_pred[:-1]
        v_plan = [v if v > 0.0 else 0.0 for v in v_plan]
        tr = ctx.train
        # unconstrained plan by the classic DMC law, ΔU = K (w − ŷ_P0), kept when it keeps
        # the rate box and the envelope at every stage: then it is the QP's optimum (zero
        # slacks, no active row); the box of envelope_box() first, the exact per-stage
        # envelope only when that box is too tight
        lo = hi = None
        fast = self.classic_law
        if fast:
            dU = np.dot(self._K_plan, e_w)
            lev = np.cumsum(dU)
            lev += u_prev
            lev_l = lev.tolist()
            fast = _max_abs(dU) <= self._du_rows
        if fast:
            l_min, l_max = min(lev_l), max(lev_l)
            lo_b, hi_b = tr.envelope_box(min(v_plan), max(v_plan))
            if not (l_min >= (lo_b - ff) / M and l_max <= (hi_b - ff) / M):
                lo, hi = tr.envelope_lists(v_plan)
                levels = lev_l + [lev_l[-1]] * (P - self.L)  # held after the last move
                fast = all(
                    (lo_i - ff) / M <= x <= (hi_i - ff) / M
                    for lo_i, hi_i, x in zip(lo, hi, levels, strict=True)
                )
        if fast:
            u_a = lev_l[0]
            self._dU_head[:] = dU[1:]  # the plan's moves 2 … L, then 0
            self.mpc.adopt_unconstrained(dU, lev.reshape(-1, 1))
            sol_info = _UNCONSTRAINED_INFO
        else:
            if lo is None:
                lo, hi = tr.envelope_lists(v_plan)
            col_r, col_lo, col_hi = self._qp_cols
            col_r[:] = [e_i + u_prev * s_i for e_i, s_i in zip(e_w, self._aP, strict=True)]
            col_lo[:] = [(x - ff) / M for x in lo]
            col_hi[:] = [(x - ff) / M for x in hi]
            r, y_min, y_max, x0 = self._opt_bufs
            sol = self.mpc.solve(x0, np.array([u_prev]), r, y_min=y_min, y_max=y_max)
            u_a = float(sol.u0[0])
            U = sol.U[:, 0]
            np.subtract(U[1:], U[:-1], out=self._dU_head)  # the plan's moves 2 … L, then 0
            sol_info = (
                sol.solve_time_s, sol.iterations, float(sol.fallback), sol.slack_max,
                sol.status_val,
            )

        # ---- command: feedforward, comfort jerk, envelope, rate, split (§6)
        u = u_a * M + ff
        du = self._jerk_du
        if du is not None:
            u = min(max(u, u_total_prev - du), u_total_prev + du)
        if self._single:
            # distribute() for one whole-train input, on floats: envelope, then rate window
            lo_y, hi_y = envelope_N(ctx.train, y)
            u = min(max(u, lo_y), hi_y)
            if self._du_step is not None:
                u = min(max(u, u_total_prev - self._du_step), u_total_prev + self._du_step)
            out = np.array([u])
        else:
            out = distribute(ctx, u, y, up_N, self._shares)
        self._ff_prev = ff
        return out, {
            "v_ref": v_ref,
            "setpoint": y0_ref,
            "error": e,
            "error_rate": edot,
            "alpha": alpha,
            "h_c": h_c,
            "J": J,
            "mu_t": mu_t,
            "mu_y": mu_y,
            "t_r": t_r,
            "prediction_error": 0.0 if e_c is None else e_c,
            "u_dmc_N": u_a * M,
            "u_ff_N": ff,
            "solve_time_s": sol_info[0],
            "iterations": sol_info[1],
            "fallback": sol_info[2],
            "slack_max": sol_info[3],
            "status_val": sol_info[4],
        }
