"""The three array stages of :class:`~.batch.BatchDMC`'s step, with their compiled twins.

Each stage is registered in :data:`train_envs._jit.TWINS`: the numpy reference (array
operations over the members) and the member loop numba compiles, with the same
signature and the single controller's IEEE operations in the same order:

* :data:`FRONT`: the setpoint y_r(k), its preview y_r(k+1 … k+P) (from the time rows
  of :meth:`~.setpoint.SetpointPreview.time_row`: catch-up and stop hold) and the
  feedforward ``u_ff = R̂(v) − R'(v_nom) v + M g θ(s + max(v, 0) τ_ff) / 1000``
  (:func:`~.laws.feedforward_force`, the track's equivalent gradient θ);
* :data:`PREDICT`: error and filtered rate, h_c (rule base), the prediction vector
  moved, corrected and shifted, ``ŷ = ŷ_P0 + A [ΔU*(k−1)_{2…L}, 0]``, the satisfaction
  J (mean by numpy's pairwise sum) and the softening factor α;
* :data:`PLAN`: the envelope's bounds at the plan's speeds
  (:func:`~train_envs.effort.bounds_loop`), the softened reference w (from the weights
  α^i, which numpy's ``power`` gives outside: its SIMD routine is not the C library's),
  the classic plan ``ΔU = K (w − ŷ_P0)``, its levels and whether it keeps the rate box
  and the envelope;
* :data:`COMMAND`: ``u = M u_a + u_ff``, the jerk limit, the envelope, the rate limit.

The matrix-vector products of the loops call numpy's own ``cblas_dgemv``
(:func:`train_envs._jit.numpy_dgemv`, at the address ``gemv`` through the helper
:data:`train_envs._jit.DGEMV`): the sums of ``ndarray.dot``, bit for bit. The
envelope's bounds are the one envelope's (:meth:`~train_envs.effort.ForceEnvelope.bounds`
and its twin; the caller passes the effort tables' forces); the reference's rule
base is :func:`~train_envs.controllers.batch.locate_uniform` and
:func:`~train_envs.controllers.batch.rule_cell`.
"""

from __future__ import annotations

import math

import numpy as np

from train_envs import _jit
from train_envs._jit import dgemv_at
from train_envs.controllers.batch import davis_array, locate_uniform, rule_cell
from train_envs.controllers.fuzzy import trapmf
from train_envs.effort import BOUNDS_HELPERS, bounds_arrays, bounds_loop
from train_envs.lines.track import equivalent_gradient_1, equivalent_gradient_arrays
from train_envs.plants.energy import np_sum

__all__ = ["COMMAND", "FRONT", "PLAN", "PREDICT"]

FRONT = "controllers.dmc_batch_front"
PREDICT = "controllers.dmc_batch_predict"
PLAN = "controllers.dmc_batch_plan"
COMMAND = "controllers.dmc_batch_command"


def front_ref(
    s, v, ri, V, S, F, H, spc, ffc, gp, gv, cp, ce, k0, k1, y0_o, y_r_o, ff_o,
) -> bool:  # fmt: skip
    """Stage 0 at positions ``s`` and speeds ``v``: member ``r`` reads the time row
    ``ri[r]`` of ``V`` (profile speeds now and over the preview, (m, P+1)), ``S``
    (s_ref), ``F`` (the catch-up fade) and ``H`` (the stop-hold mask); ``spc`` = catch-up
    (1/0), λ_x, c_max, stop hold; ``ffc`` = feedforward (1/0), track (1/0), τ_ff, the
    Davis a, b, c, R'(v_nom), M g; ``gp … k1``: the track's section arrays
    (:meth:`~train_envs.lines.track.Track.section_arrays`). Outputs y_r(k), the
    preview and u_ff; returns False, writing nothing, where a position or a speed is
    not finite."""
    if not (np.isfinite(v).all() and np.isfinite(s).all()):
        return False
    catchup, gain, c_max, hold = spc.tolist()
    y_all = V[ri]
    if catchup:
        c = gain * (S[ri] - s)
        c = np.where(-c_max > c, -c_max, c)
        c = np.where(c_max < c, c_max, c)
        y_all = y_all + c[:, None] * F[ri]
    held = H[ri]
    if held.any():
        y_all[held] = -hold
    y0_o[:] = y_all[:, 0]
    y_r_o[:] = y_all[:, 1:]
    feed, track, lead, da, db, dc, kd, mG = ffc.tolist()
    if not feed:
        ff_o[:] = 0.0
        return True
    s_ff = s + np.where(0.0 > v, 0.0, v) * lead
    theta = (
        equivalent_gradient_arrays(s_ff, gp, gv, cp, ce, k0, k1) if track else np.zeros(s.shape)
    )
    ff_o[:] = davis_array(da, db, dc, v) - kd * v + mG * theta / 1000.0
    return True


def predict_ref(
    ix, y, y0_ref, y_r, ff, u_prev_N, started, e_prev, edot_s, u_prev2_s, ff_prev, yN0_s,
    dU_shift, par, a, A_dyn, Ch, rc, sc, gemv, u_prev_o, h_c_o, yP0_o, y_pred_o, J_o, alpha_o,
    v_plan_o,
) -> None:  # fmt: skip
    """Stage 1 of the members ``ix`` (state arrays over all B members, updated in
    place; outputs ``*_o`` one row per member of ``ix``). ``par`` rows: k_e, k_ec, h0,
    k_h, trend, α_lo, α_hi; ``rc``: the two uniform partitions (lo, h, n, hi) each;
    ``sc``: k_f, Δt, h_min, M, k_davis, tail ratio, e_tol, ė_tol, t_big, μ_t corners,
    μ_y corners, combine "min" (1/0), μ_y symmetric (1/0). ``v_plan_o``: the plan's
    speeds ``max(·, 0)`` of the measured one and the first P − 1 predictions (where
    the caller reads the envelope)."""
    kf, dt, h_min, M, k_davis, tail = sc[:6].tolist()
    e_tol, edot_tol, t_big = sc[6:9].tolist()
    ta, tb, tc, td, ya, yb, yc, yd, cmin, sym = sc[9:19].tolist()
    N, P = yN0_s.shape[1], y_r.shape[1]
    e = y0_ref - y
    first = ~started[ix]
    ep = np.where(first, e, e_prev[ix])
    eo = edot_s[ix]
    edot = eo + kf * ((e - ep) / dt - eo)
    edot_s[ix] = edot
    e_prev[ix] = e
    i, wa = locate_uniform(e * par[0, ix], rc[0], rc[1], int(rc[2]), rc[3])
    j, wb = locate_uniform(edot * par[1, ix], rc[4], rc[5], int(rc[6]), rc[7])
    dh = rule_cell(Ch, i, wa, j, wb)
    h_c = par[2, ix] + par[3, ix] * dh
    h_c = np.where(h_min > h_c, h_min, h_c)
    h_c = np.where(1.0 < h_c, 1.0, h_c)
    yN0 = yN0_s[ix]
    u_prev2 = u_prev2_s[ix]
    u_prev = (u_prev_N - np.where(first, ff, ff_prev[ix])) / M
    yN1 = yN0 + a * (u_prev - u_prev2)[:, None]
    e_c = y - yN1[:, 0]
    out = np.empty_like(yN1)
    out[:, :-1] = yN1[:, 1:] + (h_c * e_c)[:, None]
    c1 = out[:, -2]
    c2 = out[:, -3] if N > 2 else yN1[:, 0] + e_c
    out[:, -1] = c1 + tail * (c1 - c2)
    out[first] = y[first, None]
    u_prev2_s[ix] = np.where(first, k_davis * y / M, u_prev)
    yN0_s[ix] = out
    started[ix] = True
    yP0 = out[:, :P]
    y_pred = yP0 + np.array([A_dyn.dot(x) for x in dU_shift[ix]]).reshape(yP0.shape)
    # satisfaction J, softening factor α
    ae, aed = np.abs(e), np.abs(edot)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = ae / aed
    t_r = np.where(
        (ae <= e_tol) & (aed <= edot_tol),
        0.0,
        np.where(e * edot < 0.0, np.where(t_big < ratio, t_big, ratio), t_big),
    )
    mu_t = np.where(t_r == 0.0, 1.0, trapmf(t_r, ta, tb, tc, td))
    x = y_pred - y_r
    if sym:
        ax = np.abs(x)
        mus = np.where(ax <= yc, 1.0, np.where(ax >= yd, 0.0, (yd - ax) / (yd - yc)))
    else:
        mus = trapmf(x, ya, yb, yc, yd)
    mu_y = np.add.reduce(mus, axis=1) / P
    J = np.where(mu_y < mu_t, mu_y, mu_t) if cmin else mu_t * mu_y
    Jc = np.where(1.0 < J, 1.0, J)
    Jc = np.where(0.0 > Jc, 0.0, Jc)
    trend = par[4, ix]
    em1 = math.expm1  # the C library's, as the single law (numpy's may be a SIMD one)
    num = np.array([em1(v) for v in (trend * (1.0 - Jc)).tolist()])
    den = np.array([em1(v) for v in trend.tolist()])
    with np.errstate(divide="ignore", invalid="ignore"):
        f = np.where(np.abs(trend) < 1e-9, 1.0 - Jc, num / den)
    lo = par[5, ix]
    u_prev_o[:] = u_prev
    h_c_o[:] = h_c
    yP0_o[:] = yP0
    y_pred_o[:] = y_pred
    J_o[:] = J
    alpha_o[:] = lo + (par[6, ix] - lo) * f
    v_plan = np.concatenate([y[:, None], y_pred[:, :-1]], axis=1)
    v_plan_o[:] = np.where(v_plan > 0.0, v_plan, 0.0)


def plan_ref(
    ix, y, y0_ref, y_r, ff, u_prev, yP0, ai, K, v_plan, tv, ev, Ke, cp, dU_shift, dU_last,
    lev_last, pending, gemv, lo_o, hi_o, w_o, lo_a_o, hi_a_o, ok_o, u_a_o,
) -> int:  # fmt: skip
    """Stage 2: the envelope's bounds [N] at the plan's speeds ``v_plan ≥ 0`` (one row
    per member; :func:`~train_envs.effort.bounds_arrays` with the tables' forces ``tv``,
    ``ev`` at those speeds and the constants ``Ke``) into ``lo_o``, ``hi_o``, then the
    plan; ``cp`` = M, the rate box, level form (1/0), classic law (1/0). Returns the
    number of members whose plan leaves the box or the envelope (their QP is due)."""
    M, du_rows, level, classic = cp.tolist()
    P, L = y_r.shape[1], K.shape[0]
    lo, hi = bounds_arrays(v_plan.reshape(-1), tv, ev, Ke)
    lo, hi = lo.reshape(v_plan.shape), hi.reshape(v_plan.shape)
    lo_o[:] = lo
    hi_o[:] = hi
    if level:
        w = ai * y[:, None] + (1.0 - ai) * y_r
    else:
        w = y_r - ai * (y0_ref - y)[:, None]
    dU = np.array([K.dot(x) for x in w - yP0]).reshape(-1, L)
    lev = np.cumsum(dU, axis=1) + u_prev[:, None]
    levels = np.concatenate([lev, np.repeat(lev[:, -1:], P - L, axis=1)], axis=1)
    lo_a = (lo - ff[:, None]) / M
    hi_a = (hi - ff[:, None]) / M
    ok = (np.maximum(dU.max(axis=1), -dU.min(axis=1)) <= du_rows) & np.all(
        (lo_a <= levels) & (levels <= hi_a), axis=1
    )
    if not classic:
        ok[:] = False
    dU_shift[ix, :-1] = dU[:, 1:]
    dU_last[ix[ok]] = dU[ok]
    lev_last[ix[ok]] = lev[ok]
    pending[ix[ok]] = True
    w_o[:] = w
    lo_a_o[:] = lo_a
    hi_a_o[:] = hi_a
    ok_o[:] = ok
    u_a_o[:] = lev[:, 0]
    return int(ok.shape[0] - np.count_nonzero(ok))


def _clip(x: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    x = np.where(lo > x, lo, x)
    return np.where(hi < x, hi, x)


def command_ref(ix, u_a, ff, lo, hi, u_prev_N, cc, ff_prev, u_o) -> None:
    """Stage 3: ``lo``, ``hi`` the envelope's bounds [N] at the measured speeds; ``cc``
    = M, the jerk bound per step, the rate bound per step (NaN: none)."""
    M, jerk, du = cc.tolist()
    u = u_a * M + ff
    if jerk == jerk:
        u = _clip(u, u_prev_N - jerk, u_prev_N + jerk)
    u = _clip(u, lo, hi)
    if du == du:
        u = _clip(u, u_prev_N - du, u_prev_N + du)
    ff_prev[ix] = ff
    u_o[:] = u


# ------------------------------------------------------------------ compiled sources
def _locate1(x, lo, h, n, hi):
    if x <= lo:
        return 0, 0.0
    if x >= hi:
        return n - 2, 1.0
    f = (x - lo) / h
    i = int(f) if f > 0.0 else 0
    i = i if i < n - 2 else n - 2
    w = f - i
    return i, (w if w < 1.0 else 1.0)


def _trap(x, a, b, c, d):
    up = 1.0 if x >= b else ((x - a) / (b - a) if b > a else 0.0)
    down = 1.0 if x <= c else ((d - x) / (d - c) if d > c else 0.0)
    m = up if up < down else down
    m = m if m < 1.0 else 1.0
    return m if m > 0.0 else 0.0


def front_loop(
    s, v, ri, V, S, F, H, spc, ffc, gp, gv, cp, ce, k0, k1, y0_o, y_r_o, ff_o,
) -> bool:  # fmt: skip
    """:func:`front_ref` member by member (the source of its compiled twin)."""
    for r in range(s.shape[0]):
        if not (math.isfinite(v[r]) and math.isfinite(s[r])):
            return False
    catchup, gain, c_max, hold = spc[0] != 0.0, spc[1], spc[2], spc[3]
    feed, track, lead = ffc[0] != 0.0, ffc[1] != 0.0, ffc[2]
    da, db, dc, kd, mG = ffc[3], ffc[4], ffc[5], ffc[6], ffc[7]
    P = y_r_o.shape[1]
    for r in range(s.shape[0]):
        i = ri[r]
        c = 0.0
        if catchup:
            c = gain * (S[i] - s[r])
            c = -c_max if -c_max > c else c
            c = c_max if c_max < c else c
        for k in range(P + 1):
            x = V[i, k] + c * F[i, k] if catchup else V[i, k]
            if H[i, k]:
                x = -hold
            if k == 0:
                y0_o[r] = x
            else:
                y_r_o[r, k - 1] = x
        if not feed:
            ff_o[r] = 0.0
            continue
        vr = v[r]
        theta = 0.0
        if track:
            s_ff = s[r] + (0.0 if 0.0 > vr else vr) * lead
            theta = equivalent_gradient_1(s_ff, gp, gv, cp, ce, k0, k1)
        av = abs(vr)
        res = math.copysign(da + db * av + dc * av * av, vr) if vr != 0 else 0.0
        ff_o[r] = res - kd * vr + mG * theta / 1000.0
    return True


def predict_loop(
    ix, y, y0_ref, y_r, ff, u_prev_N, started, e_prev, edot_s, u_prev2_s, ff_prev, yN0_s,
    dU_shift, par, a, A_dyn, Ch, rc, sc, gemv, u_prev_o, h_c_o, yP0_o, y_pred_o, J_o, alpha_o,
    v_plan_o,
) -> None:  # fmt: skip
    """:func:`predict_ref` member by member (the source of its compiled twin)."""
    kf, dt, h_min, M, k_davis, tail = sc[0], sc[1], sc[2], sc[3], sc[4], sc[5]
    N, P = yN0_s.shape[1], y_r.shape[1]
    Pm, L = A_dyn.shape[0], A_dyn.shape[1]
    yN1 = np.empty(N)
    out = np.empty(N)
    tmp = np.empty(Pm)
    mus = np.empty(P)
    n_e, n_c = int(rc[2]), int(rc[6])
    for r in range(ix.shape[0]):
        b = ix[r]
        yv = y[r]
        e = y0_ref[r] - yv
        first = not started[b]
        ep = e if first else e_prev[b]
        eo = edot_s[b]
        ed = eo + kf * ((e - ep) / dt - eo)
        edot_s[b] = ed
        e_prev[b] = e
        i, wa = _locate1(e * par[0, b], rc[0], rc[1], n_e, rc[3])
        j, wb = _locate1(ed * par[1, b], rc[4], rc[5], n_c, rc[7])
        a1 = 1.0 - wa
        b1 = 1.0 - wb
        dh = (a1 * b1) * Ch[i, j] + (a1 * wb) * Ch[i, j + 1]
        dh = dh + (wa * b1) * Ch[i + 1, j] + (wa * wb) * Ch[i + 1, j + 1]
        hc = par[2, b] + par[3, b] * dh
        hc = h_min if h_min > hc else hc
        hc = 1.0 if 1.0 < hc else hc
        up = (u_prev_N[r] - (ff[r] if first else ff_prev[b])) / M
        d = up - u_prev2_s[b]
        for k in range(N):
            yN1[k] = yN0_s[b, k] + a[k] * d
        e_c = yv - yN1[0]
        hce = hc * e_c
        for k in range(N - 1):
            out[k] = yN1[k + 1] + hce
        c1 = out[N - 2]
        c2 = out[N - 3] if N > 2 else yN1[0] + e_c
        out[N - 1] = c1 + tail * (c1 - c2)
        if first:
            for k in range(N):
                out[k] = yv
            u_prev2_s[b] = k_davis * yv / M
        else:
            u_prev2_s[b] = up
        for k in range(N):
            yN0_s[b, k] = out[k]
        started[b] = True
        dgemv_at(gemv, Pm, L, A_dyn, dU_shift[b], tmp)
        v_plan_o[r, 0] = yv if yv > 0.0 else 0.0
        for k in range(P):
            yP0_o[r, k] = out[k]
            yp = out[k] + tmp[k]
            y_pred_o[r, k] = yp
            if k < P - 1:
                v_plan_o[r, k + 1] = yp if yp > 0.0 else 0.0
        # satisfaction
        ae, aed = abs(e), abs(ed)
        if ae <= sc[6] and aed <= sc[7]:
            t_r = 0.0
        elif e * ed < 0.0:
            ratio = ae / aed
            t_r = sc[8] if sc[8] < ratio else ratio
        else:
            t_r = sc[8]
        mu_t = 1.0 if t_r == 0.0 else _trap(t_r, sc[9], sc[10], sc[11], sc[12])
        ya, yb, yc, yd = sc[13], sc[14], sc[15], sc[16]
        for k in range(P):
            x = y_pred_o[r, k] - y_r[r, k]
            if sc[18] != 0.0:
                ax = abs(x)
                mus[k] = 1.0 if ax <= yc else (0.0 if ax >= yd else (yd - ax) / (yd - yc))
            else:
                mus[k] = _trap(x, ya, yb, yc, yd)
        mu_y = np_sum(mus[:P]) / P
        if sc[17] != 0.0:
            J = mu_y if mu_y < mu_t else mu_t
        else:
            J = mu_t * mu_y
        Jc = 1.0 if 1.0 < J else J
        Jc = 0.0 if 0.0 > Jc else Jc
        g = par[4, b]
        f = 1.0 - Jc if abs(g) < 1e-9 else math.expm1(g * (1.0 - Jc)) / math.expm1(g)
        u_prev_o[r] = up
        h_c_o[r] = hc
        J_o[r] = J
        alpha_o[r] = par[5, b] + (par[6, b] - par[5, b]) * f


def plan_loop(
    ix, y, y0_ref, y_r, ff, u_prev, yP0, ai, K, v_plan, tv, ev, Ke, cp, dU_shift, dU_last,
    lev_last, pending, gemv, lo_o, hi_o, w_o, lo_a_o, hi_a_o, ok_o, u_a_o,
) -> int:  # fmt: skip
    """:func:`plan_ref` member by member (the source of its compiled twin)."""
    M, du_rows = cp[0], cp[1]
    P, L = y_r.shape[1], K.shape[0]
    lo_f, hi_f = bounds_loop(v_plan.reshape(-1), tv, ev, Ke)
    lo_o[:] = lo_f.reshape(v_plan.shape)
    hi_o[:] = hi_f.reshape(v_plan.shape)
    lo, hi = lo_o, hi_o
    fails = 0
    dv = np.empty(P)
    dU = np.empty(L)
    lev = np.empty(L)
    for r in range(ix.shape[0]):
        b = ix[r]
        yv = y[r]
        for k in range(P):
            ak = ai[r, k]
            if cp[2] != 0.0:
                wk = ak * yv + (1.0 - ak) * y_r[r, k]
            else:
                wk = y_r[r, k] - ak * (y0_ref[r] - yv)
            w_o[r, k] = wk
            dv[k] = wk - yP0[r, k]
        dgemv_at(gemv, L, P, K, dv, dU)
        acc = dU[0]
        mx = dU[0]
        mn = dU[0]
        lev[0] = acc + u_prev[r]
        for k in range(1, L):
            acc = acc + dU[k]
            lev[k] = acc + u_prev[r]
            mx = dU[k] if dU[k] > mx else mx
            mn = dU[k] if dU[k] < mn else mn
        m = mx if mx > -mn else -mn
        ok = m <= du_rows
        for k in range(P):
            la = (lo[r, k] - ff[r]) / M
            ha = (hi[r, k] - ff[r]) / M
            lo_a_o[r, k] = la
            hi_a_o[r, k] = ha
            lv = lev[k] if k < L else lev[L - 1]
            ok = ok and la <= lv and lv <= ha
        ok = ok and cp[3] != 0.0
        for k in range(L - 1):
            dU_shift[b, k] = dU[k + 1]
        if ok:
            for k in range(L):
                dU_last[b, k] = dU[k]
                lev_last[b, k] = lev[k]
            pending[b] = True
        ok_o[r] = ok
        u_a_o[r] = lev[0]
        fails += 0 if ok else 1
    return fails


def command_loop(ix, u_a, ff, lo, hi, u_prev_N, cc, ff_prev, u_o) -> None:
    """:func:`command_ref` member by member (the source of its compiled twin)."""
    M, jerk, du = cc[0], cc[1], cc[2]
    for r in range(ix.shape[0]):
        u = u_a[r] * M + ff[r]
        if jerk == jerk:
            j_lo = u_prev_N[r] - jerk
            j_hi = u_prev_N[r] + jerk
            u = j_lo if j_lo > u else u
            u = j_hi if j_hi < u else u
        u = lo[r] if lo[r] > u else u
        u = hi[r] if hi[r] < u else u
        if du == du:
            d_lo = u_prev_N[r] - du
            d_hi = u_prev_N[r] + du
            u = d_lo if d_lo > u else u
            u = d_hi if d_hi < u else u
        ff_prev[ix[r]] = ff[r]
        u_o[r] = u


def _has_dgemv() -> bool:
    return _jit.numpy_dgemv_address() != 0


_jit.register(
    FRONT,
    front_ref,
    source=front_loop,
    helpers={"bisect_right": _jit.bisect_right, "equivalent_gradient_1": equivalent_gradient_1},
)
_jit.register(
    PREDICT,
    predict_ref,
    source=predict_loop,
    helpers={"_locate1": _locate1, "_trap": _trap, "np_sum": np_sum, "dgemv_at": _jit.DGEMV},
    available=_has_dgemv,
)
_jit.register(
    PLAN,
    plan_ref,
    source=plan_loop,
    helpers={"dgemv_at": _jit.DGEMV, "bounds_loop": bounds_loop, **BOUNDS_HELPERS},
    available=_has_dgemv,
)
_jit.register(COMMAND, command_ref, source=command_loop)
