"""Compiled twins (numba) of the tube MPC family's per-step hot path.

At a trigger of the self-triggered MPC the work is a few dozen numpy calls on arrays of
a few dozen entries, so the calls' overhead, not the arithmetic, sets the time.  The two
kernels here do the same arithmetic in one call each:

* :func:`fill_reference` -- the reference position and speed along the prediction grid
  (:meth:`SpeedProfile.sv_at_t`, the same operations in the same order) and the nominal
  resistance per unit inertial mass at the reference (Davis law and the gradient table,
  as :meth:`TubeMPC._stage_data` writes them); the results equal the numpy path's bit
  for bit (``tests/test_robust_mpc.py`` checks it).
* :func:`closed_form` -- one candidate's closed-form unconstrained optimum: its
  constraint margins and cost ``‖r‖²`` from the composed map (the numpy path's
  ``T @ h[cols]``; the sums may differ from BLAS's in the last bits).

The numpy code in :mod:`train_envs.controllers.tube_mpc` stays the reference and the
fallback: ``TRAIN_ENVS_NO_JIT=1`` or a missing numba selects it.  Compiled code is
cached on disk (``cache=True``), so only the first process after an install or a change
of this file compiles (about a second).
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from train_envs._jit import bisect_right, compiled

_STATE: dict[str, SimpleNamespace | None] = {}


def kernels() -> SimpleNamespace | None:
    """``fill_reference`` and ``closed_form`` compiled, or None (numba missing or
    ``TRAIN_ENVS_NO_JIT=1``)."""
    if "k" not in _STATE:
        fr = compiled(_fill_reference, {"bisect_right": bisect_right})
        cf = compiled(_closed_form)
        _STATE["k"] = None if fr is None else SimpleNamespace(fill_reference=fr, closed_form=cf)
    return _STATE["k"]


def _fill_reference(
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
        r = v * cc
        r += cb
        r *= v
        r += ca if v > 0.0 else 0.0
        if has_grad:
            k = bisect_right(g_x, s) - 1  # (a NaN position gives NaN at any index)
            if k < 0:
                k = 0
            r += cg * (g_tbl[k, 0] + g_tbl[k, 1] * (s - g_x[k]))
        h[o + 2 * ng + j] = r


def _closed_form(
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
