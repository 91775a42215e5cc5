"""Traction and braking work of the plant: trapezoidal integrals of the car powers.

Per sub-step of length h, with ``p_i = F_i v_i`` at its start (``p0``) and end (``p1``)::

    W_traction += h/4 Σ_i (|p0_i| + |p1_i| + p0_i + p1_i)     (the positive part of F v)
    W_brake    += h/4 Σ_i (|p0_i| + |p1_i| − p0_i − p1_i)     (the negative part)

The sums over the cars follow numpy's order of summation (:func:`np_sum`), so the
float code gives the same bits as ``np.sum`` over the per-car arrays.
"""

from __future__ import annotations

import numpy as np


def np_sum(x) -> float:
    """``float(np.sum(x))`` of a short sequence (a list, or an array in compiled code), in
    numpy's order of summation.

    numpy adds up to 7 numbers left to right and longer runs (up to its 128-element
    block) in 8 interleaved partial sums, combined pairwise; restating that keeps the
    float paths' sums identical to the array code's (the plants' energy integrals, the
    lockstep DMC's satisfaction mean). Written with indices only, so that numba compiles
    it as a helper of a compiled twin.
    """
    n = len(x)
    if n < 8:
        r = x[0]
        for i in range(1, n):
            r += x[i]
        return r
    if n > 128:
        return float(np.sum(x))
    r0, r1, r2, r3 = x[0], x[1], x[2], x[3]
    r4, r5, r6, r7 = x[4], x[5], x[6], x[7]
    m = n - n % 8
    for i in range(8, m, 8):
        r0 += x[i]
        r1 += x[i + 1]
        r2 += x[i + 2]
        r3 += x[i + 3]
        r4 += x[i + 4]
        r5 += x[i + 5]
        r6 += x[i + 6]
        r7 += x[i + 7]
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    for i in range(m, n):
        res += x[i]
    return res


def power_sums(
    p0: list[float], forces: list[float], speeds: list[float]
) -> tuple[list[float], float, float]:
    """``(p1, Σ (|p0|+|p1|+p0+p1), Σ (|p0|+|p1|−p0−p1))`` with ``p1 = F v`` per car."""
    p1 = []
    if len(p0) < 8:
        s_up = s_down = 0.0  # (the terms are >= +0, so 0.0 + x0 is x0)
        for a_, f, v in zip(p0, forces, speeds, strict=True):
            b_ = f * v
            p1.append(b_)
            tot = a_ + b_
            mag = abs(a_) + abs(b_)
            s_up += mag + tot
            s_down += mag - tot
        return p1, s_up, s_down
    up = []
    down = []
    for a_, f, v in zip(p0, forces, speeds, strict=True):
        b_ = f * v
        p1.append(b_)
        tot = a_ + b_
        mag = abs(a_) + abs(b_)
        up.append(mag + tot)
        down.append(mag - tot)
    return p1, np_sum(up), np_sum(down)
