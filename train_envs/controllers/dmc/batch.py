"""B DMC controllers of paper 004 in lockstep: the laws of one step over arrays.

:class:`BatchDMC` runs the step of :class:`~.controller.DMCController` (classic law
with the online correction h_c, satisfaction J, softening α and feedforward; the
equations are in :mod:`.laws`, :mod:`.prediction` and :mod:`.setpoint`) for B members
that share the structure (train, horizons, weights, timing) and the control instant,
each with its own seven tunable parameters and its own state. Every law is evaluated
elementwise over the members with the single controller's operations, and the two
small matrix-vector products ``A ΔU`` and ``K e_w`` stay the single controller's
products, member by member: every member equals its single controller bit for bit
(tested). A member whose plan leaves the rate box or the envelope solves its QP on
its own :class:`~.qp.DMCProblem` (OSQP, as the single controller), with the warm start
the single controller would have.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from train_envs.controllers.batch import (
    clip_like,
    per_time,
    resistance_array,
    rule_outputs,
    rules_batchable,
)
from train_envs.controllers.dmc.controller import DMCController
from train_envs.controllers.dmc.qp import UNCONSTRAINED_INFO
from train_envs.controllers.fuzzy import trapmf

__all__ = ["BatchDMC", "batchable_dmc"]


def batchable_dmc(ctrl: DMCController) -> bool:
    """Whether a reset ``ctrl`` has a lockstep twin here: one whole-train input, a
    time-indexed profile read through its scalar methods, a uniform rule partition."""
    sp = ctrl._setpoint
    return ctrl._single and sp.scalar and ctrl.rules.single and rules_batchable(ctrl.rules)


class BatchDMC:
    """B members of one DMC structure.

    Args:
        ref: a :class:`DMCController` reset on the context (its structure and constants).
        params: each member's full parameter values (``ref.get_params()`` form).
        qp_pool: callable ``b -> DMCController`` giving member ``b``'s own controller for
            its QP steps (reset on the context before its first QP of an episode).
    """

    def __init__(
        self,
        ref: DMCController,
        params: Sequence[Mapping[str, float]],
        qp_pool: Any,
    ) -> None:
        if not batchable_dmc(ref):
            raise ValueError("this DMC configuration has no lockstep twin (see batchable_dmc)")
        self.ref = ref
        self.B = len(params)
        self.p = {n: np.array([float(p[n]) for p in params]) for n in params[0]}
        self._derived()
        self._qp_pool = qp_pool
        self._steps = np.arange(1, ref.P + 1)
        self.reset()

    def _derived(self) -> None:
        col = self.p
        self.k_e, self.k_ec = col["k_e"], col["k_ec"]
        self.h0, self.k_h = col["h0"], col["k_h"]
        # (the lower bound min(α_min, α_max) of alpha_order="clip", as _on_params_changed)
        lo, hi = col["alpha_min"].tolist(), col["alpha_max"].tolist()
        self.a_lo = np.array([min(a, b) for a, b in zip(lo, hi, strict=True)])
        self.a_hi = col["alpha_max"]
        self.trend = col["alpha_trend"]

    def set_params(self, b: int, params: Mapping[str, float]) -> None:
        """Member ``b``'s parameters (the full set, as ``get_params`` gives it)."""
        for n, val in params.items():
            self.p[n][b] = float(val)
        self._derived()

    def reset(self, ix: np.ndarray | None = None) -> None:
        """Start an episode for members ``ix`` (all by default): the state of a reset
        controller (its QP core reset before its next QP)."""
        if ix is not None:
            for name in ("started", "dU_shift", "u_prev2", "ff_prev", "e_prev", "edot", "_pending"):
                getattr(self, name)[ix] = 0
            self._qp_ready.difference_update(np.asarray(ix).tolist())
            return
        B, ref = self.B, self.ref
        self.started = np.zeros(B, dtype=bool)
        self.yN0 = np.zeros((B, ref.N))
        self.dU_shift = np.zeros((B, ref.L))
        self.u_prev2 = np.zeros(B)
        self.ff_prev = np.zeros(B)
        self.e_prev = np.zeros(B)
        self.edot = np.zeros(B)
        #: the last classic plan per member, adopted by its QP core before its next QP
        self._dU_last = np.zeros((B, ref.L))
        self._lev_last = np.zeros((B, ref.L))
        self._pending = np.zeros(B, dtype=bool)
        self._qp_ready: set[int] = set()

    # ------------------------------------------------------------------ laws
    def _feedforward(self, s: np.ndarray, v: np.ndarray) -> np.ndarray:
        ref = self.ref
        if not ref.feedforward:
            return np.zeros(s.shape)
        ctx, tr = ref.ctx, ref.ctx.train
        s_ff = s + np.where(0.0 > v, 0.0, v) * ref._ff_lead
        if ref._has_track:
            theta = np.asarray(ctx.track.equivalent_gradient_permil_at(s_ff), dtype=float)
        else:
            theta = np.zeros(s.shape)
        return resistance_array(tr, v) - ref.k_davis * v + ref._mG * theta / 1000.0

    def _preview(self, t: float) -> np.ndarray:
        """Row ``[v_0, v_1 … v_P, s_ref, hold_0, hold_1 … hold_P]`` of the profile at time
        ``t`` (hold flags 1.0 where the stop hold replaces the preview)."""
        sp = self.ref._setpoint
        prof = sp.profile
        v_prev = prof.sample_sv(t, sp.dt_s, sp.horizon)[1]
        hold = [0.0] * (sp.horizon + 1)
        if sp.hold > 0.0 and t + sp._dtk[-1] >= sp.t_end:
            hold = [1.0 if t >= sp.t_end else 0.0] + [
                1.0 if t + d >= sp.t_end else 0.0 for d in sp._dtk
            ]
        return np.array([prof.v_at_t(t), *v_prev, prof.s_at_t(t) if sp.catchup else 0.0, *hold])

    def _setpoint(self, t: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(y_r(k), y_r(k+1 … k+P)) of :class:`~.setpoint.SetpointPreview` per member."""
        sp = self.ref._setpoint
        n = sp.horizon + 1
        rows = per_time(t, self._preview)
        vv = rows[:, :n]
        if sp.catchup:
            c = sp.gain * (rows[:, n] - s)
            c = np.where(-sp.c_max > c, -sp.c_max, c)
            c = np.where(sp.c_max < c, sp.c_max, c)
            q = vv / sp.fade
            y_all = vv + c[:, None] * np.where(q < 1.0, q, 1.0)
        else:
            y_all = vv.copy()
        held = rows[:, n + 1 :] != 0.0
        if held.any():
            y_all[held] = -sp.hold
        return y_all[:, 0], y_all[:, 1:]

    def _satisfaction(
        self, e: np.ndarray, edot: np.ndarray, y_pred: np.ndarray, y_r: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """(t_r, J) of :func:`~.laws.satisfaction` over the members."""
        sh = self.ref.satisfaction_shape
        ae, aed = np.abs(e), np.abs(edot)
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = ae / aed
        t_r = np.where(
            (ae <= sh.e_tol) & (aed <= sh.edot_tol),
            0.0,
            np.where(e * edot < 0.0, np.where(sh.t_big < ratio, sh.t_big, ratio), sh.t_big),
        )
        mu_t = np.where(t_r == 0.0, 1.0, trapmf(t_r, *sh.t_trap))
        a, b, c, d = sh.y_trap
        x = y_pred - y_r
        if a == -d and b == -c and b - a == d - c and b > a:
            ax = np.abs(x)
            mus = np.where(ax <= c, 1.0, np.where(ax >= d, 0.0, (d - ax) / (d - c)))
        else:
            mus = trapmf(x, a, b, c, d)
        mu_y = np.add.reduce(mus, axis=1) / mus.shape[1]
        J = np.where(mu_y < mu_t, mu_y, mu_t) if sh.combine == "min" else mu_t * mu_y
        return t_r, J

    def _alpha(self, J: np.ndarray, ix: np.ndarray) -> np.ndarray:
        J = np.where(1.0 < J, 1.0, J)
        J = np.where(0.0 > J, 0.0, J)
        trend = self.trend[ix]
        # expm1 member by member with math.expm1, as the single law: numpy's array expm1
        # may take a SIMD routine (AVX-512) whose last bits differ from the C library's
        em1 = math.expm1
        num = np.array([em1(x) for x in (trend * (1.0 - J)).tolist()])
        den = np.array([em1(x) for x in trend.tolist()])
        with np.errstate(divide="ignore", invalid="ignore"):
            f = np.where(np.abs(trend) < 1e-9, 1.0 - J, num / den)
        lo = self.a_lo[ix]
        return lo + (self.a_hi[ix] - lo) * f

    @staticmethod
    def _matvec(A: np.ndarray, X: np.ndarray) -> np.ndarray:
        """``A x`` for every row ``x`` of ``X``: the single controller's matrix-vector
        product row by row (one matrix product over the rows may sum in another order,
        and the closed loop amplifies a last-bit difference to ~1e-6 within an episode)."""
        out = np.empty((X.shape[0], A.shape[0]))
        for r, x in enumerate(X):
            out[r] = A.dot(x)
        return out

    # ------------------------------------------------------------------ step
    def compute(
        self, ix: np.ndarray, t: np.ndarray, s: np.ndarray, v: np.ndarray, u_prev_N: np.ndarray
    ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """One control step of members ``ix`` (indices) at their times ``t`` with
        positions ``s``, speeds ``v`` and the commands applied last ``u_prev_N`` (each
        of length ``len(ix)``); returns their commands [N] and info columns."""
        ref = self.ref
        M, P = ref.M, ref.P
        y = v
        if not np.all(np.isfinite(y)) or not np.all(np.isfinite(s)):
            raise ValueError("measured speed v_mps / position s_m must be finite")
        y0_ref, y_r = self._setpoint(t, s)
        e = y0_ref - y
        first = ~self.started[ix]
        e_prev = np.where(first, e, self.e_prev[ix])
        edot_old = self.edot[ix]
        edot = edot_old + ref._kf * ((e - e_prev) / ref.ctx.dt_s - edot_old)
        self.edot[ix] = edot
        self.e_prev[ix] = e
        dh = rule_outputs(ref.rules, e, edot, self.k_e[ix], self.k_ec[ix])[0]
        h_c = self.h0[ix] + self.k_h[ix] * dh
        h_c = np.where(ref.h_min > h_c, ref.h_min, h_c)
        h_c = np.where(1.0 < h_c, 1.0, h_c)
        ff = self._feedforward(s, y)

        # prediction vector (first step: the flat equilibrium vector)
        yN0 = self.yN0[ix]
        u_prev2 = self.u_prev2[ix]
        u_prev = (u_prev_N - np.where(first, ff, self.ff_prev[ix])) / M
        yN1 = yN0 + ref.a * (u_prev - u_prev2)[:, None]
        e_c = y - yN1[:, 0]
        out = np.empty_like(yN1)
        out[:, :-1] = yN1[:, 1:] + (h_c * e_c)[:, None]
        c1 = out[:, -2]
        c2 = out[:, -3] if ref.N > 2 else yN1[:, 0] + e_c
        out[:, -1] = c1 + ref.tail_ratio * (c1 - c2)
        if first.any():
            out[first] = y[first, None]
            u_prev2 = np.where(first, ref.k_davis * y / M, u_prev)
            e_c = np.where(first, 0.0, e_c)
        else:
            u_prev2 = u_prev
        self.yN0[ix] = out
        self.u_prev2[ix] = u_prev2
        self.started[ix] = True
        yP0 = out[:, :P]

        # satisfaction, softening, softened reference
        dU_shift = self.dU_shift[ix]
        y_pred = yP0 + self._matvec(ref.A_dyn, dU_shift)
        t_r, J = self._satisfaction(e, edot, y_pred, y_r)
        alpha = self._alpha(J, ix)
        ai = alpha[:, None] ** self._steps
        if ref.reference_form == "level":
            w = ai * y[:, None] + (1.0 - ai) * y_r
        else:
            w = y_r - ai * (y0_ref - y)[:, None]

        # the classic plan, else the QP member by member
        v_plan = np.concatenate([y[:, None], y_pred[:, :-1]], axis=1)
        v_plan = np.where(v_plan > 0.0, v_plan, 0.0)
        dU = self._matvec(ref.qp.K, w - yP0)
        lev = np.cumsum(dU, axis=1) + u_prev[:, None]
        tr = ref.ctx.train
        lo, hi = tr.envelope_N(v_plan)
        levels = np.concatenate([lev, np.repeat(lev[:, -1:], P - ref.L, axis=1)], axis=1)
        lo_a = (lo - ff[:, None]) / M
        hi_a = (hi - ff[:, None]) / M
        ok = (np.maximum(dU.max(axis=1), -dU.min(axis=1)) <= ref.qp.du_rows) & np.all(
            (lo_a <= levels) & (levels <= hi_a), axis=1
        )
        if not ref.classic_law:
            ok[:] = False
        u_a = lev[:, 0].copy()
        dU_shift[:, :-1] = dU[:, 1:]
        n = len(ix)
        info = np.tile(np.array(UNCONSTRAINED_INFO, dtype=float), (n, 1))
        if ref.classic_law:
            self._dU_last[ix[ok]] = dU[ok]
            self._lev_last[ix[ok]] = lev[ok]
            self._pending[ix[ok]] = True
        for r in np.flatnonzero(~ok).tolist():
            u_a[r], info[r], dU_shift[r, :-1] = self._qp_step(
                int(ix[r]), w[r], yP0[r], float(u_prev[r]), lo_a[r], hi_a[r]
            )
        self.dU_shift[ix] = dU_shift

        # command: comfort jerk limit, envelope, rate limit
        u = u_a * M + ff
        if ref._jerk_du is not None:
            u = clip_like(u, u_prev_N - ref._jerk_du, u_prev_N + ref._jerk_du)
        if np.all(y >= 0.0):  # |y| is the first speed of the plan
            lo_y, hi_y = lo[:, 0], hi[:, 0]
        else:
            lo_y, hi_y = tr.envelope_N(y)
        u = clip_like(u, lo_y, hi_y)
        if ref._du_step is not None:
            u = clip_like(u, u_prev_N - ref._du_step, u_prev_N + ref._du_step)
        self.ff_prev[ix] = ff
        return u, {
            "alpha": alpha,
            "h_c": h_c,
            "J": J,
            "solve_time_s": info[:, 0],
            "iterations": info[:, 1],
            "fallback": info[:, 2],
            "slack_max": info[:, 3],
            "status_val": info[:, 4],
        }

    def _qp_step(
        self, b: int, w: np.ndarray, yP0: np.ndarray, u_prev: float, lo: np.ndarray, hi: np.ndarray
    ) -> tuple[float, np.ndarray, np.ndarray]:
        """Member ``b``'s QP step on its own core: (u_a, solver fields, moves 2 … L)."""
        ctrl: DMCController = self._qp_pool(b)
        if b not in self._qp_ready:
            ctrl.reset(self.ref.ctx)
            self._qp_ready.add(b)
        qp = ctrl.qp
        if self._pending[b]:
            qp.core.adopt_unconstrained(self._dU_last[b].copy(), self._lev_last[b].reshape(-1, 1))
            self._pending[b] = False
        sol = qp.optimise(w.tolist(), yP0.tolist(), u_prev, lo.tolist(), hi.tolist())
        U = sol.U[:, 0]
        fields = np.array(
            [sol.solve_time_s, sol.iterations, float(sol.fallback), sol.slack_max, sol.status_val],
            dtype=float,
        )
        return float(sol.u0[0]), fields, U[1:] - U[:-1]
