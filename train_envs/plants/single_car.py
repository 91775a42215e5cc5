"""The ETD2 step of the single-point train as one scalar loop, and its compiled twin.

:func:`run_single` is the step of :class:`~train_envs.plants.multi_car.TrainPlant` for
one car (actuator order 0 or 1) unrolled on scalars, with the nonlinear term
(:func:`train_envs.plants.physics.davis_signed_N`, :func:`~train_envs.plants.physics.gradient_at`),
the dead-time buffer, the standstill logic and the energy integrals inlined: the same
IEEE operations in the same order as the general path.  It is registered in
:data:`train_envs._jit.TWINS` as :data:`SINGLE_CAR_STEP`: the reference
:func:`single_car_step` runs it on Python floats and lists, the compiled twin is
:func:`run_single` itself compiled by numba on the arrays; both take the same arrays.
Disturbances stay Python objects: the caller sums their accelerations at the sub-step
times ``t_0 + j h`` (``j = 0..k``, the times at which the loop evaluates the nonlinear
term) and passes the sums.
"""

from __future__ import annotations

import math

import numpy as np

from train_envs import _jit
from train_envs._jit import bisect_right
from train_envs.plants.physics import davis_signed_N

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
    i: int,
    has_tab: bool,
    wd: float,
    has_dist: bool,
) -> float:
    """N(z, t) = −(Davis + gradient + disturbances)/M' per unit mass (the operations of
    :meth:`train_envs.plants.nonlinear.NonlinearTerm.single`), the gradient read on the
    table's segment ``i`` (the one holding ``pos``)."""
    f = davis_signed_N(c[C_CA], c[C_CB], c[C_CC], vel)
    if has_tab:
        f += c[C_MG] * (y0l[i] + sl[i] * (pos - xl[i]))
    if has_dist:
        f += c[C_M0] * wd
    return -f * c[C_MINV]


def _crossing_time(d: float, v: float, acc: float, h: float, ds: float) -> float:
    """Time to cover ``d`` from speed ``v`` at constant acceleration ``acc`` (the root of
    ``v t + acc t²/2 = d`` in the direction of the motion, written without
    cancellation); ``h d / ds`` (along the step's predicted displacement ``ds``) when
    there is none in ``[0, h]``; clipped to ``[0, h]``."""
    disc = v * v + 2.0 * acc * d
    tau = -1.0
    if disc >= 0.0:
        root = math.sqrt(disc)
        den = v + root if d >= 0.0 else v - root
        if den != 0.0:
            tau = 2.0 * d / den
    if not (0.0 <= tau <= h):
        tau = h * d / ds if ds != 0.0 else h
    return 0.0 if tau < 0.0 else (h if tau > h else tau)


def _jumps(
    x: float,
    v: float,
    acc: float,
    ds: float,
    i0: int,
    i1: int,
    h: float,
    xl: np.ndarray,
    y0l: np.ndarray,
    sl: np.ndarray,
    kg: float,
) -> tuple[float, float]:
    """Corrections ``(c, l)`` of the nonlinear term of a car that crosses the breakpoints
    between table segments ``i0`` and ``i1`` within a sub-step ``h`` (from position ``x``,
    speed ``v``, acceleration ``acc``; predicted displacement ``ds``).

    A breakpoint crossed at ``θ h`` makes N jump by ``ΔN = −kg (g_right − g_left)``
    (``kg = m g / (1000 m')``).  The ETD2 step is exact for ``N = n_0 + c + (n_1 − n_0
    + l) t/h``; ``c = ΔN (1 − θ)(1 − 3θ)`` and ``l = ΔN (6θ(1 − θ) − 1)`` give that
    line the zeroth and first moments of the jump over the step, which are all that
    the speed and position of a car's centre of mass respond to (their response to N
    is ``(h − t, 1)``): the kinematics stay second order across the jump.
    """
    c = 0.0
    lin = 0.0
    step = 1 if i1 > i0 else -1
    i = i0
    while i != i1:
        j = i + step
        xb = xl[i + 1] if step > 0 else xl[i]
        dN = -kg * ((y0l[j] + sl[j] * (xb - xl[j])) - (y0l[i] + sl[i] * (xb - xl[i])))
        th = _crossing_time(xb - x, v, acc, h, ds) / h
        c += dN * ((1.0 - th) * (1.0 - 3.0 * th))
        lin += dN * (6.0 * th * (1.0 - th) - 1.0)
        i = j
    return c, lin


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
    A sub-step whose predicted position leaves the gradient segment it starts on takes
    the jump of the gradient force at the crossing into account (:func:`_jumps`); the
    others cost one comparison more.
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
        w0 = wd[j] if has_dist else 0.0
        i0 = bisect_right(xl, z0) - 1 if has_tab else 0
        if stopped:
            # held by the brakes until the force overcomes gradient, disturbances and
            # the Davis constant term (a held train never leaves rest backwards)
            F = w if order == 0 else z2
            g_f = 0.0
            if has_tab:
                g_f = mg * (y0l[i0] + sl[i0] * (z0 - xl[i0]))
            if has_dist:
                g_f += c[C_M0] * w0
            if F > g_f + ca:
                stopped = False
            else:
                if order:
                    z2 = p22 * z2 + g2 * w
                z1 = 0.0
                t += h
                p_last = 0.0
                continue
        n0 = _nonlinear(z0, z1, c, xl, y0l, sl, i0, has_tab, w0, has_dist)  # N(z, t)
        if order:
            a0 = p00 * z0 + p01 * z1 + p02 * z2 + g0 * w + q0 * n0
            a1 = p10 * z0 + p11 * z1 + p12 * z2 + g1 * w + q1 * n0
            a2 = p20 * z0 + p21 * z1 + p22 * z2 + g2 * w + q2 * n0
        else:
            a0 = p00 * z0 + p01 * z1 + g0 * w + q0 * n0
            a1 = p10 * z0 + p11 * z1 + g1 * w + q1 * n0
            a2 = 0.0
        w1 = wd[j + 1] if has_dist else 0.0
        F_old = w if order == 0 else z2
        i1 = bisect_right(xl, a0) - 1 if has_tab else 0
        if i1 == i0:
            # N(a, t + h) − N(z, t)
            dn = _nonlinear(a0, a1, c, xl, y0l, sl, i1, has_tab, w1, has_dist) - n0
            s_new = a0 + r0 * dn
            v_new = a1 + r1 * dn
            if order:
                z2 = a2 + r2 * dn
        else:
            # the predictor left the segment: the jump(s) of N inside the sub-step
            acc = c[C_MINV] * F_old + n0
            cj, dl = _jumps(z0, z1, acc, a0 - z0, i0, i1, h, xl, y0l, sl, mg * c[C_MINV])
            dn = _nonlinear(a0, a1, c, xl, y0l, sl, i1, has_tab, w1, has_dist) - n0 + dl
            s_new = a0 + q0 * cj + r0 * dn
            v_new = a1 + q1 * cj + r1 * dn
            if order:
                z2 = a2 + q2 * cj + r2 * dn
        p1 = (w if order == 0 else z2) * v_new
        tot = p_last + p1
        mag = abs(p_last) + abs(p1)
        wt += h2 * (mag + tot)
        wb += h2 * (mag - tot)
        p_last = p1
        if z1 > 0.0 and 0.0 < v_new < hold and v_new < z1 and F_old <= ca:
            v_new = 0.0
            stopped = True
        elif v_new <= 0.0:
            # interpolate the stop inside the sub-step; a train that has just left rest
            # and would roll back stays where it is
            if z1 > 0.0:
                frac = z1 / (z1 - v_new)
                s_new = z0 + 0.5 * z1 * frac * h
            else:
                s_new = z0
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


#: the name of the single-car step in :data:`train_envs._jit.TWINS`
SINGLE_CAR_STEP = "plants.single_car_step"

_LISTS: dict[int, tuple[tuple[np.ndarray, ...], tuple[list[float], ...]]] = {}


def _as_lists(c: np.ndarray, xl: np.ndarray, y0l: np.ndarray, sl: np.ndarray):
    """``(c, xl, y0l, sl)`` as lists, kept per plant: the constants and the gradient
    table do not change between the calls of one plant."""
    hit = _LISTS.get(id(c))
    if hit is None or hit[0][0] is not c or hit[0][1] is not xl:
        if len(_LISTS) > 256:
            _LISTS.clear()
        hit = _LISTS[id(c)] = ((c, xl), (c.tolist(), xl.tolist(), y0l.tolist(), sl.tolist()))
    return hit[1]


def single_car_step(
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
    """:func:`run_single` on Python floats and lists (the reference of the twin): the same
    arguments, ``st`` and ``bl`` updated in place.  ``c`` and the table ``xl, y0l, sl``
    must not change between calls with the same ``c`` (their lists are kept)."""
    stl = st.tolist()
    bll = bl.tolist()
    cl, xll, y0ll, sll = _as_lists(c, xl, y0l, sl)
    head = run_single(stl, bll, head, k, order, cl, xll, y0ll, sll, has_tab, wd.tolist(), has_dist)
    st[:] = stl
    bl[:] = bll
    return head


_jit.register(
    SINGLE_CAR_STEP,
    single_car_step,
    source=run_single,
    helpers={
        "bisect_right": bisect_right,
        "davis_signed_N": davis_signed_N,
        "_nonlinear": _nonlinear,
        "_crossing_time": _crossing_time,
        "_jumps": _jumps,
    },
)
