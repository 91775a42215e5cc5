r"""The DMC's prediction vector: move, feedback correction and shift (004 §4.1, §4.3).

Predictions (Xi Yugeng, *Predictive Control*, 2nd ed., 2013, ch. 2)::

    ŷ_N1(k) = ŷ_N0(k) + a Δu(k)                            (effect of the move at k)
    ŷ_PM(k) = ŷ_P0(k) + A ΔU_L(k)                          (A the P × L dynamic matrix)

ŷ_N0 is the N-vector of predicted speeds at k+1 … k+N with the input held, ŷ_P0 its
first P entries. At the first step ŷ_N0 = y(0)·1, the model's equilibrium at y(0),
whose input level κ y(0) is the memory u(−1) of the vector (anchoring it on the actual
previous command instead leaves a permanent slope error in ŷ_N0).

Feedback correction and shift (Xi 2013, ch. 2; Camacho & Bordons, *Model Predictive
Control*, 2nd ed., 2007, ch. 3): at k+1 the prediction error
``e_c(k+1) = y(k+1) − ŷ_1(k)`` corrects the vector, which is then shifted::

    ŷ_cor = ŷ_N1(k) + h e_c(k+1),   h = [1, h_c, …, h_c]ᵀ
    ŷ_N0(k+1) = S ŷ_cor,            (S y)_i = y_{i+1} (i < N),  (S y)_N = y_N + ρ (y_N − y_{N−1})

The first-order-filter form of 004 §4.3 is taken as h_1 = 1, h_i = h_c (i ≥ 2): the
measured sample is matched exactly and the rest of the prediction moves by h_c e_c, so
a persistent error is absorbed geometrically at the rate h_c. The last entry continues
the integrating tail with the slope ratio ρ of :mod:`.step_response` (ρ = 1: the linear
extrapolation ``2 y_N − y_{N−1}``).
"""

from __future__ import annotations

import numpy as np


def extrapolate_tail(y_n: float, y_n1: float, ratio: float = 1.0) -> float:
    """``y_N + ρ (y_N − y_{N−1})``: the entry after y_N on the integrating tail."""
    return y_n + ratio * (y_n - y_n1)


def shift_prediction(y: np.ndarray, ratio: float = 1.0) -> np.ndarray:
    """Shift matrix S: ``(S y)_i = y_{i+1}``, ``(S y)_N = y_N + ρ (y_N − y_{N−1})``.

    ρ = 1 is the linear extrapolation of an integrating tail (``2 y_N − y_{N−1}``).
    """
    out = np.empty_like(y)
    out[:-1] = y[1:]
    out[-1] = extrapolate_tail(y[-1], y[-2], ratio) if y.size > 1 else y[-1]
    return out


def add_move(y_free: np.ndarray, a: np.ndarray, du: float, out: np.ndarray) -> np.ndarray:
    """``ŷ_N1 = ŷ_N0 + a Δu``, written into ``out`` (which may not be ``y_free``)."""
    np.multiply(a, du, out=out)
    np.add(y_free, out, out=out)
    return out


def correct_and_shift(
    y_n1: np.ndarray, e_c: float, h_c: float, ratio: float, out: np.ndarray
) -> np.ndarray:
    """``ŷ_N0(k+1) = S (ŷ_N1 + h e_c)``, ``h = [1, h_c, …, h_c]``, written into ``out``.

    ``out`` (length N ≥ 2) must not be ``y_n1``. The first corrected entry
    ``ŷ_N1,1 + e_c`` only enters the tail when N = 2.
    """
    n = out.shape[0]
    np.add(y_n1[1:], h_c * e_c, out=out[:-1])
    c1 = out.item(n - 2)
    c2 = out.item(n - 3) if n > 2 else y_n1.item(0) + e_c
    out[n - 1] = extrapolate_tail(c1, c2, ratio)
    return out


def predict(y_free: np.ndarray, A: np.ndarray, dU: np.ndarray) -> np.ndarray:
    """``ŷ_PM = ŷ_P0 + A ΔU`` (P,): the speeds a move plan ΔU (L,) predicts."""
    return y_free + A @ dU
