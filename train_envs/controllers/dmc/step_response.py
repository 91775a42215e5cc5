r"""Step-response model, dynamic matrix and unconstrained gain of the DMC (004 §4.1).

Nominal linear model the controller may know (single point, command in acceleration
units ``u_a = u / M(1+ρ)``, first-order traction lag τ, dead time T_d)::

    v̇ = F_a − κ v,     τ Ḟ_a = u_a(t − T_d) − F_a,     κ = R'(v_nom) / M(1+ρ)

κ is the Davis slope ``b + 2 c v_nom`` linearised at v_nom. The step coefficients are
the sampled unit-step response ``a_i = s(i Δt − T_d)`` (0 before the dead time), by
exact (matrix-exponential) discretisation — exact for a piecewise-constant command,
fractional dead times included. ``a = (a_1 … a_N)``, N the model length (Cutler &
Ramaker, "Dynamic matrix control — a computer control algorithm", *Joint Automatic
Control Conf.*, 1980; Xi Yugeng, *Predictive Control*, 2nd ed., 2013, ch. 2).

*Integrating tail.* The speed response to a force step is integrating in practice
(1/κ far above N Δt), so the truncation "a_i = a_N for i > N" of the finite
step-response model, which assumes a settling process (Cutler & Ramaker 1980; Camacho
& Bordons, *Model Predictive Control*, 2nd ed., 2007, ch. 3), would be wrong. As usual
for integrating processes in step-response MPC, the response beyond N is continued
from the final slope (Gupta, "Control of integrating processes using dynamic matrix
control", *Chem. Eng. Res. Des.* 76(4), 1998; Lundström, Lee, Morari & Skogestad,
"Limitations of dynamic matrix control", *Comput. Chem. Eng.* 19(4), 1995)::

    a_{N+j} = a_N + Σ_{l≤j} ρ^l (a_N − a_{N−1})

with ρ = 1 (linear extrapolation, ``tail="linear"``) or ρ = e^{−κΔt} (``tail="model"``:
the slope decays as the model's slow mode does — exact for the nominal model once the
lag has settled within N, and the linear rule for κ = 0).

Dynamic matrix and the classic law: ``A = [a_{i−j+1}]_{i≤P, j≤L}`` (P × L); without
active constraints the first move is ``Δu(k) = dᵀ (w − ŷ_P0)``, dᵀ the first row of
``(AᵀQA + R)⁻¹ AᵀQ`` with Q = q I, R = r I (Cutler & Ramaker 1980).
"""

from __future__ import annotations

import math

import numpy as np

from train_envs.controllers.models import point_lag_continuous
from train_envs.mpc.design import zoh
from train_envs.validation import check_nonnegative, check_positive


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
    # the speed (and lag) states of the single-point model; the position is not needed
    Ac, Bc, _ = point_lag_continuous(kappa_1ps, tau_s)
    A, B = Ac[1:, 1:], Bc[1:, :1]
    nx = A.shape[0]

    def flow(t: float) -> tuple[np.ndarray, np.ndarray]:
        Ad, Bd = zoh(A, B, t)
        return Ad, Bd[:, 0]

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


def tail_ratio(kappa_1ps: float, dt_s: float, tail: str = "model") -> float:
    """Slope ratio ρ of the integrating tail: ``e^{−κΔt}`` (``"model"``) or 1 (``"linear"``)."""
    return math.exp(-kappa_1ps * dt_s) if tail == "model" else 1.0


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


def dmc_gain(A: np.ndarray, q: float, r: float, *, plan: bool = False) -> np.ndarray:
    """dᵀ: first row of ``(AᵀQA + R)⁻¹AᵀQ`` with Q = q I, R = r I (unconstrained DMC law);
    with ``plan=True`` the whole ``(L, P)`` matrix K (all L moves ``ΔU = K (w − ŷ_P0)``)."""
    P, L = A.shape
    K = np.linalg.solve(q * A.T @ A + r * np.eye(L), q * A.T)
    return np.ascontiguousarray(K) if plan else K[0]
