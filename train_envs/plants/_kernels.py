"""The single-car plant step as one scalar loop, compiled by numba (:mod:`train_envs._jit`).

:func:`run_single` is the ETD2 step of a single point train unrolled on scalars, with
the nonlinear term, the gradient table and the dead-time buffer inlined.
:meth:`TrainPlant._run_single` runs it compiled where numba is available and as plain
Python otherwise (the same IEEE operations in the same order, so the same numbers:
``tests/test_plants.py`` compares them bit for bit, and both with the general numpy
path).  Disturbances stay Python objects: the caller sums their accelerations at the
sub-step times ``t_0 + j h`` (``j = 0..k``, the times at which the loop evaluates the
nonlinear term) and passes the sums.
"""

from __future__ import annotations

import numpy as np

from train_envs._jit import bisect_right

#: layout of the float state vector ``st`` (in and out)
ST_Z0, ST_Z1, ST_Z2, ST_T, ST_PLAST, ST_STOPPED, ST_W, ST_WT, ST_WB = range(9)
#: layout of the constants ``c``: h, Davis a/b/c per unit mass, m g / 1000, m, 1/m',
#: hold speed, then Φ (row major), Γ, h φ1, h φ2 (of the 3 or 2 states)
C_H, C_CA, C_CB, C_CC, C_MG, C_M0, C_MINV, C_HOLD, C_MATS = range(9)


def _nonlinear(
    pos: float,
    vel: float,
    c: np.ndarray,
    xl: np.ndarray,
    y0l: np.ndarray,
    sl: np.ndarray,
    has_tab: bool,
    wd: float,
    has_dist: bool,
) -> float:
    """N(z, t) = −(Davis + gradient + disturbances)/M' per unit mass (the plant's
    ``_nl_single``, the same operations)."""
    av = vel if vel >= 0.0 else -vel
    f = c[C_CA] + c[C_CB] * av + c[C_CC] * av * av
    f = f if vel > 0 else (-f if vel < 0 else 0.0)
    if has_tab:
        i = bisect_right(xl, pos) - 1
        f += c[C_MG] * (y0l[i] + sl[i] * (pos - xl[i]))
    if has_dist:
        f += c[C_M0] * wd
    return -f * c[C_MINV]


def run_single(
    st: np.ndarray,
    bl: np.ndarray,
    head: int,
    k: int,
    order: int,
    c: np.ndarray,
    xl: np.ndarray,
    y0l: np.ndarray,
    sl: np.ndarray,
    has_tab: bool,
    wd: np.ndarray,
    has_dist: bool,
) -> int:
    """``k`` ETD2 sub-steps of the single car with command ``st[ST_W]`` issued now
    (through the dead-time buffer ``bl`` when it has more than one slot); updates ``st``
    and ``bl`` in place and returns the new buffer head.  ``xl, y0l, sl``: the gradient
    table (``has_tab``); ``wd[j]``: the disturbance sum at ``t_0 + j h`` (``has_dist``).
    """
    h = c[C_H]
    h2 = 0.25 * h
    ca, mg, hold = c[C_CA], c[C_MG], c[C_HOLD]
    nb = len(bl)
    z0, z1 = st[ST_Z0], st[ST_Z1]
    if order:
        z2 = st[ST_Z2]
        p00, p01, p02, p10, p11, p12, p20, p21, p22 = c[C_MATS : C_MATS + 9]
        g0, g1, g2 = c[C_MATS + 9 : C_MATS + 12]
        q0, q1, q2 = c[C_MATS + 12 : C_MATS + 15]
        r0, r1, r2 = c[C_MATS + 15 : C_MATS + 18]
    else:
        z2 = 0.0
        p00, p01, p10, p11 = c[C_MATS : C_MATS + 4]
        p02 = p12 = p20 = p21 = p22 = 0.0
        g0, g1 = c[C_MATS + 4 : C_MATS + 6]
        g2 = 0.0
        q0, q1 = c[C_MATS + 6 : C_MATS + 8]
        q2 = 0.0
        r0, r1 = c[C_MATS + 8 : C_MATS + 10]
        r2 = 0.0
    t = st[ST_T]
    p_last = st[ST_PLAST]
    stopped = st[ST_STOPPED] != 0.0
    w_cmd = st[ST_W]
    w = w_cmd
    wt = 0.0
    wb = 0.0
    for j in range(k):
        if nb > 1:
            bl[head] = w_cmd
            head = (head + 1) % nb
            w = bl[head]
        if stopped:
            F = w if order == 0 else z2
            g_f = 0.0
            if has_tab:
                i = bisect_right(xl, z0) - 1
                g_f = mg * (y0l[i] + sl[i] * (z0 - xl[i]))
            if F > g_f + ca:
                stopped = False
            else:
                if order:
                    z2 = p22 * z2 + g2 * w
                z1 = 0.0
                t += h
                p_last = 0.0
                continue
        w0 = wd[j] if has_dist else 0.0
        n0 = _nonlinear(z0, z1, c, xl, y0l, sl, has_tab, w0, has_dist)  # N(z, t)
        if order:
            a0 = p00 * z0 + p01 * z1 + p02 * z2 + g0 * w + q0 * n0
            a1 = p10 * z0 + p11 * z1 + p12 * z2 + g1 * w + q1 * n0
            a2 = p20 * z0 + p21 * z1 + p22 * z2 + g2 * w + q2 * n0
        else:
            a0 = p00 * z0 + p01 * z1 + g0 * w + q0 * n0
            a1 = p10 * z0 + p11 * z1 + g1 * w + q1 * n0
            a2 = 0.0
        # N(a, t + h) − N(z, t)
        w1 = wd[j + 1] if has_dist else 0.0
        dn = _nonlinear(a0, a1, c, xl, y0l, sl, has_tab, w1, has_dist) - n0
        s_new = a0 + r0 * dn
        v_new = a1 + r1 * dn
        F_old = w if order == 0 else z2
        if order:
            z2 = a2 + r2 * dn
        p1 = (w if order == 0 else z2) * v_new
        tot = p_last + p1
        mag = abs(p_last) + abs(p1)
        wt += h2 * (mag + tot)
        wb += h2 * (mag - tot)
        p_last = p1
        if z1 > 0.0 and 0.0 < v_new < hold and v_new < z1 and F_old <= ca:
            v_new = 0.0
            stopped = True
        elif z1 > 0.0 and v_new <= 0.0:
            frac = z1 / (z1 - v_new)
            s_new = z0 + 0.5 * z1 * frac * h
            v_new = 0.0
            stopped = True
        z0, z1 = s_new, v_new
        t += h
    st[ST_Z0] = z0
    st[ST_Z1] = z1
    st[ST_Z2] = z2
    st[ST_T] = t
    st[ST_PLAST] = p_last
    st[ST_STOPPED] = 1.0 if stopped else 0.0
    st[ST_W] = w
    st[ST_WT] = wt
    st[ST_WB] = wb
    return head


#: what :func:`run_single` calls, for :func:`train_envs._jit.compiled`
RUN_SINGLE_HELPERS = {"bisect_right": bisect_right, "_nonlinear": _nonlinear}
