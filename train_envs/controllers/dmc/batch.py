"""B DMC controllers of paper 004 in lockstep: the laws of one step over arrays.

:class:`BatchDMC` runs the step of :class:`~.controller.DMCController` (classic law
with the online correction h_c, satisfaction J, softening α and feedforward; the
equations are in :mod:`.laws`, :mod:`.prediction` and :mod:`.setpoint`) for B members
that share the structure (train, horizons, weights, timing) and the control instant,
each with its own seven tunable parameters and its own state. The law runs in the
four stages of :mod:`.batch_law` (registered twins: a numpy reference and a compiled
member loop; the setpoint preview's time part comes from
:meth:`~.setpoint.SetpointPreview.time_row`, once per distinct time), with the single
controller's operations and its matrix-vector products
``A ΔU`` and ``K e_w`` (numpy's own ``dgemv``): every member equals its single
controller bit for bit (tested). A member whose plan leaves the rate box or the
envelope solves its QP on its own :class:`~.qp.DMCProblem` (OSQP, as the single
controller), with the warm start the single controller would have.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from train_envs import _jit
from train_envs.controllers.batch import common_time, rules_batchable
from train_envs.controllers.dmc.batch_law import COMMAND, FRONT, PLAN, PREDICT
from train_envs.controllers.dmc.controller import DMCController
from train_envs.controllers.dmc.qp import UNCONSTRAINED_INFO

__all__ = ["BatchDMC", "batchable_dmc"]


def batchable_dmc(ctrl: DMCController) -> bool:
    """Whether a reset ``ctrl`` has a lockstep twin here: one whole-train input, a
    time-indexed profile read through its scalar methods, a uniform rule partition and
    P ≤ 128 (the stages' pairwise mean)."""
    sp = ctrl._setpoint
    return (
        ctrl._single
        and sp.scalar
        and ctrl.rules.single
        and rules_batchable(ctrl.rules)
        and ctrl.P <= 128
    )


class BatchDMC:
    """B members of one DMC structure.

    Args:
        ref: a :class:`DMCController` reset on the context (its structure and constants).
        params: each member's full parameter values (``ref.get_params()`` form).
        qp_pool: callable ``b -> DMCController`` giving member ``b``'s own controller for
            its QP steps (reset on the context before its first QP of an episode).
        compiled_twin: the stages of :mod:`.batch_law` compiled (True), their numpy
            references (False) or the process's choice (None,
            :func:`train_envs._jit.implementation`).
    """

    def __init__(
        self,
        ref: DMCController,
        params: Sequence[Mapping[str, float]],
        qp_pool: Any,
        compiled_twin: bool | None = None,
    ) -> None:
        if not batchable_dmc(ref):
            raise ValueError("this DMC configuration has no lockstep twin (see batchable_dmc)")
        self.ref = ref
        self.B = len(params)
        self.p = {n: np.array([float(p[n]) for p in params]) for n in params[0]}
        self._derived()
        self._qp_pool = qp_pool
        self._steps = np.arange(1, ref.P + 1)
        self._constants()
        self._front = _jit.implementation(FRONT, compiled_twin=compiled_twin)
        self._predict = _jit.implementation(PREDICT, compiled_twin=compiled_twin)
        self._plan = _jit.implementation(PLAN, compiled_twin=compiled_twin)
        self._command = _jit.implementation(COMMAND, compiled_twin=compiled_twin)
        self._gemv = _jit.numpy_dgemv_address()
        self._work: dict[int, tuple[np.ndarray, ...]] = {}
        self.reset()

    def _constants(self) -> None:
        """The structure's constants in the stages' array form (:mod:`.batch_law`)."""
        ref = self.ref
        pe, pc = ref.rules.pe, ref.rules.pc
        self._rc = np.array([pe._lo, pe._h, pe.n, pe._hi, pc._lo, pc._h, pc.n, pc._hi], float)
        self._Ch = np.ascontiguousarray(ref.rules.C[0], dtype=float)
        sh = ref.satisfaction_shape
        a, b, c, d = sh.y_trap
        sym = a == -d and b == -c and b - a == d - c and b > a
        self._sc = np.array(
            [ref._kf, ref.ctx.dt_s, ref.h_min, ref.M, ref.k_davis, ref.tail_ratio,
             sh.e_tol, sh.edot_tol, sh.t_big, *sh.t_trap, *sh.y_trap,
             1.0 if sh.combine == "min" else 0.0, 1.0 if sym else 0.0],
            dtype=float,
        )  # fmt: skip
        self._a = np.ascontiguousarray(ref.a, dtype=float)
        self._A_dyn = np.ascontiguousarray(ref.A_dyn, dtype=float)
        self._K = np.ascontiguousarray(ref.qp.K, dtype=float)
        self._envelope = ref.ctx.train.envelope
        level = 1.0 if ref.reference_form == "level" else 0.0
        classic = 1.0 if ref.classic_law else 0.0
        self._cp = np.array([ref.M, float(ref.qp.du_rows), level, classic])
        sp, tr = ref._setpoint, ref.ctx.train
        self._spc = np.array([1.0 if sp.catchup else 0.0, sp.gain, sp.c_max, sp.hold])
        track = ref.ctx.track if ref._has_track else None
        self._ffc = np.array(
            [1.0 if ref.feedforward else 0.0, 0.0 if track is None else 1.0, ref._ff_lead,
             tr.davis_a_N, tr.davis_b_Ns_per_m, tr.davis_c_Ns2_per_m2, ref.k_davis, ref._mG],
            dtype=float,
        )  # fmt: skip
        self._track = (np.zeros(1),) * 6 if track is None else track.section_arrays()
        self._row0 = np.zeros(self.B, dtype=np.int64)
        self._info0 = np.tile(np.asarray(UNCONSTRAINED_INFO, dtype=float), (self.B, 1))
        self._no_fade = np.zeros((1, ref.P + 1))
        nan = math.nan
        jerk = nan if ref._jerk_du is None else ref._jerk_du
        du = nan if ref._du_step is None else ref._du_step
        self._cc = np.array([ref.M, jerk, du])

    def _derived(self, b: int | None = None) -> None:
        """The per-member values of the parameters ``p``: all members, or member ``b``
        alone (the same values, without touching the others)."""
        col = self.p
        # (the lower bound min(α_min, α_max) of alpha_order="clip", as _on_params_changed)
        if b is not None:
            self.a_lo[b] = min(col["alpha_min"][b].item(), col["alpha_max"][b].item())
            self.par[:, b] = [row[b] for row in self._par_rows]
            return
        self.k_e, self.k_ec = col["k_e"], col["k_ec"]
        self.h0, self.k_h = col["h0"], col["k_h"]
        lo, hi = col["alpha_min"].tolist(), col["alpha_max"].tolist()
        self.a_lo = np.array([min(a, b) for a, b in zip(lo, hi, strict=True)])
        self.a_hi = col["alpha_max"]
        self.trend = col["alpha_trend"]
        #: rows k_e, k_ec, h0, k_h, γ, α_lo, α_hi (the stages' parameter matrix)
        self._par_rows = (self.k_e, self.k_ec, self.h0, self.k_h, self.trend, self.a_lo,
                          self.a_hi)  # fmt: skip
        self.par = np.stack(self._par_rows)

    def set_params(self, b: int, params: Mapping[str, float]) -> None:
        """Member ``b``'s parameters (the full set, as ``get_params`` gives it)."""
        for n, val in params.items():
            self.p[n][b] = float(val)
        self._derived(b)

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
    def _time_rows(
        self, t: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(ri, V, S, F, H)`` of :data:`~.batch_law.FRONT`: the time rows of
        :meth:`SetpointPreview.time_row` at the members' distinct times ``t`` (one in
        lockstep) and each member's row."""
        sp = self.ref._setpoint
        t0 = common_time(t)
        if t0 is not None:  # in lockstep
            v, s_ref, fade, held = sp.time_row(t0)
            F = fade[None] if fade is not None else self._no_fade
            return self._row0[: t.shape[0]], v[None], np.array([s_ref]), F, held[None]
        ut, inv = np.unique(t, return_inverse=True)
        parts = [sp.time_row(x) for x in ut.tolist()]
        F = np.stack([r[2] for r in parts]) if sp.catchup else self._no_fade
        return (
            inv.reshape(-1).astype(np.int64),
            np.stack([r[0] for r in parts]),
            np.array([r[1] for r in parts]),
            F,
            np.stack([r[3] for r in parts]),
        )

    # ------------------------------------------------------------------ step
    def compute(
        self, ix: np.ndarray, t: np.ndarray, s: np.ndarray, v: np.ndarray, u_prev_N: np.ndarray
    ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """One control step of members ``ix`` (indices) at their times ``t`` with
        positions ``s``, speeds ``v`` and the commands applied last ``u_prev_N`` (each
        of length ``len(ix)``); returns their commands [N] and info columns."""
        y = v
        n = len(ix)
        vec = np.empty((7, n))  # one block for the per-member outputs of the stages
        y0_ref, ff, u_prev, h_c, J, alpha, u_a = vec
        # the stages' work rows (none of them leaves this call): one block per size
        y_r, yP0, y_pred, v_plan, w, lo_a, hi_a, lo, hi = self._work_rows(n)
        if not self._front(s, y, *self._time_rows(t), self._spc, self._ffc, *self._track,
                           y0_ref, y_r, ff):  # fmt: skip
            raise ValueError("measured speed v_mps / position s_m must be finite")
        self._predict(
            ix, y, y0_ref, y_r, ff, u_prev_N, self.started, self.e_prev, self.edot,
            self.u_prev2, self.ff_prev, self.yN0, self.dU_shift, self.par, self._a,
            self._A_dyn, self._Ch, self._rc, self._sc, self._gemv,
            u_prev, h_c, yP0, y_pred, J, alpha, v_plan,
        )  # fmt: skip
        ai = alpha[:, None] ** self._steps  # numpy's power, as the single law
        ok = np.empty(n, dtype=bool)
        # the envelope at the plan's speeds (the measured one, then the predictions)
        env = self._envelope
        tv, ev = env.table_forces(v_plan.reshape(-1))
        fails = self._plan(
            ix, y, y0_ref, y_r, ff, u_prev, yP0, ai, self._K, v_plan, tv, ev, env.constants,
            self._cp, self.dU_shift, self._dU_last, self._lev_last, self._pending, self._gemv,
            lo, hi, w, lo_a, hi_a, ok, u_a,
        )  # fmt: skip
        info = self._info0[:n].copy()
        if fails:
            for r in np.flatnonzero(~ok).tolist():  # the QP, member by member
                b = int(ix[r])
                u_a[r], info[r], self.dU_shift[b, :-1] = self._qp_step(
                    b, w[r], yP0[r], u_prev.item(r), lo_a[r], hi_a[r]
                )
        if (y >= 0.0).all():  # |y| is the plan's first speed
            lo_y, hi_y = lo[:, 0], hi[:, 0]
        else:
            lo_y, hi_y = self._envelope.bounds(y)
        u = np.empty(n)
        self._command(ix, u_a, ff, lo_y, hi_y, u_prev_N, self._cc, self.ff_prev, u)
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

    def _work_rows(self, n: int) -> tuple[np.ndarray, ...]:
        """Nine (n, P) arrays for the stages' intermediate rows of ``n`` members (kept
        per ``n``: they are overwritten every step, never returned)."""
        rows = self._work.get(n)
        if rows is None:
            rows = self._work[n] = tuple(np.empty((9, n, self.ref.P)))
        return rows

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
        sol = qp.optimise(w, yP0, u_prev, lo, hi)
        U = sol.U[:, 0]
        fields = np.array(
            [sol.solve_time_s, sol.iterations, float(sol.fallback), sol.slack_max, sol.status_val],
            dtype=float,
        )
        return float(sol.u0[0]), fields, U[1:] - U[:-1]
