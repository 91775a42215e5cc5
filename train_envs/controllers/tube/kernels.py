"""Sources of the compiled twins (numba) of the tube MPC family's per-step hot path.

Each function here is the scalar-loop twin of a numpy reference, with the same
signature, registered next to that reference (:mod:`train_envs._jit`):

* :func:`fill_reference_source` -- twin of :func:`.stage.fill_reference`: the reference
  position and speed along the prediction grid and the nominal resistance per unit
  inertial mass at the reference, the same operations in the same order (equal bit
  for bit);
* :func:`closed_form_source` -- twin of :func:`.closed_form.closed_form_cost`: one
  candidate's constraint margins and cost ``‖r‖²`` (the sum of squares may differ from
  BLAS's in the last bits).

At a trigger the work is a few dozen numpy calls on arrays of a few dozen entries, so
the calls' overhead, not the arithmetic, sets the time: each twin does it in one call.
"""

from __future__ import annotations

import numpy as np

from train_envs._jit import bisect_right
from train_envs.plants.physics import davis_horner_N

__all__ = ["closed_form_source", "fill_reference_source"]


def fill_reference_source(
    h: np.ndarray,
    o: int,
    tgrid: np.ndarray,
    t0: float,
    p_t: np.ndarray,
    p_tbl: np.ndarray,
    g_x: np.ndarray,
    g_tbl: np.ndarray,
    has_grad: bool,
    ca: float,
    cb: float,
    cc: float,
    cg: float,
) -> None:
    """Write ``s_r``, ``v_r`` and ``res`` at the grid times ``tgrid + t0`` into
    ``h[o:o+ng]``, ``h[o+ng:o+2ng]``, ``h[o+2ng:o+3ng]``.

    ``p_t``: the profile's node times; ``p_tbl``: per segment ``t_i, t_i+1 − t_i, v_i,
    a_i/2, a_i, s_i, s_i+1`` (``SpeedProfile._seg_tbl``); ``g_x``, ``g_tbl``: the
    gradient table's breakpoints and per-segment ``(y0, slope)``.
    """
    ng = tgrid.size
    last = p_t.size - 2
    for j in range(ng):
        x = tgrid[j] + t0
        i = bisect_right(p_t, x) - 1  # clip(searchsorted(p_t, x, "right") − 1, 0, last)
        if i < 0:
            i = 0
        elif i > last:
            i = last
        tau = x - p_tbl[i, 0]
        if tau < 0.0:  # (comparisons keep NaN, as np.maximum / np.minimum do)
            tau = 0.0
        span = p_tbl[i, 1]
        if tau > span:
            tau = span
        v0 = p_tbl[i, 2]
        s = p_tbl[i, 3] * tau
        s += v0
        s *= tau
        s += p_tbl[i, 5]
        s1 = p_tbl[i, 6]
        if s > s1:
            s = s1
        v = p_tbl[i, 4] * tau
        v += v0
        if v < 0.0:
            v = 0.0
        h[o + j] = s
        h[o + ng + j] = v
        r = davis_horner_N(ca if v > 0.0 else 0.0, cb, cc, v)
        if has_grad:
            k = bisect_right(g_x, s) - 1  # (a NaN position gives NaN at any index)
            if k < 0:
                k = 0
            r += cg * (g_tbl[k, 0] + g_tbl[k, 1] * (s - g_x[k]))
        h[o + 2 * ng + j] = r


def closed_form_source(
    T: np.ndarray, cols: np.ndarray, h: np.ndarray, b: np.ndarray, nchk: int
) -> tuple[float, bool]:
    """``(J, feasible)`` of one candidate: ``out = T @ h[cols]``, feasible when every
    margin ``b − out[:nchk]`` is ``>= 0`` (NaN is not), ``J = ‖out[nchk:]‖²``."""
    nc = cols.size
    hv = np.empty(nc)
    for c in range(nc):
        hv[c] = h[cols[c]]
    out = np.dot(T, hv)
    feasible = True
    for r in range(nchk):
        if not (b[r] - out[r] >= 0.0):
            feasible = False
            break
    J = 0.0
    for r in range(nchk, out.size):
        J += out[r] * out[r]
    return J, feasible
