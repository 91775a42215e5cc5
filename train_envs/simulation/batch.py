"""The lockstep twin of :class:`~train_envs.simulation.loop.ClosedLoop`: B members at once.

:class:`BatchLoop` runs B closed loops of one scenario (each member its own plant, seed
and controller parameters) control step by control step: the plants step together
(:class:`~train_envs.plants.batch.BatchSingleCar` for single cars,
:class:`~train_envs.plants.batch_multi_car.BatchMultiCar` for multi-car trains), a
batched controller (:class:`BatchController`) computes every active member's command
with array operations (a controller without an array law runs member by member on its
single form: :class:`~.members.MemberControllers`; on multi-car trains with one input
per car, the commands are per-car rows), the ATP supervises each member
(:mod:`.supervision`), and the rows are recorded into one (steps × members) array per
column. A member whose episode is over (the runner's termination and truncation, or the
step cap) stops stepping; the others go on. Everything after the controller (the ATP and
the limit columns, :data:`SUPERVISE`; the record row; the plant step; the end-of-step
checks, :func:`done_arrays`) is one call of the registered twin :data:`STEP_END` (numpy
reference, compiled member loop) for single cars, of its numpy form for multi-car trains
:func:`cars_step_end` (the same supervision, record writer and end-of-episode checks,
:func:`episode_end`, plus the per-car commands and the coupler columns).
:meth:`BatchLoop.arrays` gives each member the columns of :meth:`ClosedLoop.arrays`,
:meth:`BatchLoop.metrics` its :func:`~train_envs.metrics.episode_metrics`. The runner
adds no arithmetic of its own: every value is the single runner's, member by member
(tested).
"""

from __future__ import annotations

import math
from bisect import bisect_right
from collections.abc import Mapping, Sequence
from typing import Protocol

import numpy as np

from train_envs import _jit
from train_envs.controllers.batch import common_time, per_time
from train_envs.lines.track import section_index
from train_envs.plants.batch import (
    CAR_STEP_HELPERS,
    BatchSingleCar,
    batch_car_step,
    batchable,
    run_batch,
)
from train_envs.plants.batch_multi_car import BatchMultiCar, batchable_multi, row_np_sum
from train_envs.plants.lookup import gradient_table
from train_envs.plants.multi_car import TrainPlant
from train_envs.plants.single_car import ST_STOPPED, ST_T, ST_Z0, ST_Z1
from train_envs.scenarios import Scenario
from train_envs.simulation.loop import (
    INFO_COLUMNS,
    final_row,
    initial_commands,
    record_columns,
    scenario_metrics,
)
from train_envs.simulation.supervision import (
    Supervision,
    coupler_excess_arrays,
    permitted_speed_fn,
    permitted_speed_table,
)

__all__ = [
    "STEP_END",
    "SUPERVISE",
    "BatchController",
    "BatchLoop",
    "batchable_member",
    "cars_step_end",
]

#: the record columns of a single-car member (the table columns of :data:`STEP_END`)
_COLUMNS = tuple(record_columns(1))


def batchable_member(plant: TrainPlant) -> bool:
    """Whether ``plant`` can be a member of a :class:`BatchLoop`: a single-car plant on
    the path :class:`~train_envs.plants.batch.BatchSingleCar` twins, or a multi-car one
    :class:`~train_envs.plants.batch_multi_car.BatchMultiCar` holds."""
    return batchable(plant) if plant.n == 1 else batchable_multi(plant)


def supervise_arrays(
    ix, s, v, pos, val, braking, interventions, sp, limit_o, brake_o, over_o, overrun_o,
) -> None:  # fmt: skip
    """The ATP and the record's limit columns of the members ``ix`` at positions ``s``
    and speeds ``v``, numpy form (the reference of :data:`SUPERVISE`): the permitted
    speed (the step function ``pos, val`` of
    :func:`~.supervision.permitted_speed_table`), the ATP brake (it starts above the
    limit plus the margin and holds while the speed exceeds the limit; ``braking`` and
    the count ``interventions`` over all members, updated), the overspeed
    ``max(v − limit, 0)`` and the overrun ``max(s − (s_stop + window), 0)``. ``sp`` =
    ATP on (1/0), margin, stop (1/0), s_stop + window."""
    atp, margin, has_stop, s_end = sp.tolist()
    limit = val[section_index(pos, s)]
    brake = np.zeros(s.shape, dtype=bool)
    if atp:
        was = braking[ix]
        start = ~was & (v > limit + margin)
        brake = np.where(was, v > limit, start)
        braking[ix] = brake
        interventions[ix] += start
    d = s - s_end
    limit_o[:] = limit
    brake_o[:] = brake
    over_o[:] = np.where(v - limit > 0.0, v - limit, 0.0)
    overrun_o[:] = np.where(d > 0.0, d, 0.0) if has_stop else 0.0


def supervise_loop(
    ix, s, v, pos, val, braking, interventions, sp, limit_o, brake_o, over_o, overrun_o,
) -> None:  # fmt: skip
    """:func:`supervise_arrays` member by member (the source of its compiled twin)."""
    atp, margin, has_stop, s_end = sp[0] != 0.0, sp[1], sp[2] != 0.0, sp[3]
    for r in range(s.shape[0]):
        b = ix[r]
        x, vr = s[r], v[r]
        i = bisect_right(pos, x) - 1
        lim = val[i if i > 0 else 0]
        brake = False
        if atp:
            if braking[b]:
                brake = vr > lim
            elif vr > lim + margin:
                brake = True
                interventions[b] += 1
            braking[b] = brake
        limit_o[r] = lim
        brake_o[r] = brake
        over_o[r] = vr - lim if vr - lim > 0.0 else 0.0
        d = x - s_end
        overrun_o[r] = (d if d > 0.0 else 0.0) if has_stop else 0.0


def done_arrays(ix, u, ST, u_prev, k, moved, terminated, truncated, done, dc) -> None:
    """After the plant step of the members ``ix`` (commands ``u``): the last command
    and the step count, then the runner's end of episode (:func:`episode_end` on the
    plant state rows ``ST``, :mod:`train_envs.plants.single_car` layout). Numpy form
    (:func:`done_loop` member by member; both run inside :data:`STEP_END`)."""
    st = ST[ix]
    episode_end(ix, u, st[:, ST_T], st[:, ST_Z0], st[:, ST_Z1], st[:, ST_STOPPED] != 0.0,
                u_prev, k, moved, terminated, truncated, done, dc)  # fmt: skip


def episode_end(ix, u, t, s, v, stopped, u_prev, k, moved, terminated, truncated, done, dc):
    """The members ``ix`` after their plant step (commands ``u``; times ``t``, lead-car
    positions ``s`` and speeds ``v``, held flags ``stopped``, one entry each): the last
    command and the step count, then the runner's end of episode (over all members,
    updated): terminated at rest after moving or beyond ``s_stop + overrun`` (stop
    scenarios), else at the end time; truncated at the end time or the table's last
    row. ``dc`` = stop (1/0), s_stop + overrun, t_max − 1e-9, the last step (the
    checks of :meth:`ClosedLoop._check_done`, numpy form)."""
    has_stop, s_end, t_end, k_last = dc.tolist()
    u_prev[ix] = u
    k[ix] += 1
    mv = moved[ix] | (v > 0.1)
    moved[ix] = mv
    if has_stop:
        term = (stopped & mv) | (s > s_end)
    else:
        term = t >= t_end
    trunc = ~term & ((t >= t_end) | (k[ix] >= k_last))
    terminated[ix] = term
    truncated[ix] = trunc
    done[ix] = term | trunc


def done_loop(ix, u, ST, u_prev, k, moved, terminated, truncated, done, dc) -> None:
    """:func:`done_arrays` member by member (the source of its compiled twin)."""
    has_stop, s_end, t_end, k_last = dc[0] != 0.0, dc[1], dc[2], dc[3]
    for r in range(ix.shape[0]):
        b = ix[r]
        u_prev[b] = u[r]
        k[b] += 1
        t, x, vr = ST[b, ST_T], ST[b, ST_Z0], ST[b, ST_Z1]
        mv = moved[b] or vr > 0.1
        moved[b] = mv
        if has_stop:
            term = (ST[b, ST_STOPPED] != 0.0 and mv) or x > s_end
        else:
            term = t >= t_end
        trunc = (not term) and (t >= t_end or k[b] >= k_last)
        terminated[b] = term
        truncated[b] = trunc
        done[b] = term or trunc


#: the name of the runner's supervision twin in :data:`_jit.TWINS` (tested on its own;
#: the runner calls it inside :data:`STEP_END`)
SUPERVISE = "simulation.batch_supervise"
_jit.register(
    SUPERVISE, supervise_arrays, source=supervise_loop, helpers={"bisect_right": _jit.bisect_right}
)


def step_end_arrays(
    ix, u, t, s, v, a, grad, u_N, v_ref, s_ref, info_rows, icols, table, k, pos, val, braking,
    interventions, sp, lo_brake, ST, BL, heads, active, ksub, order, C, XL, Y0L, SL, offs, has_tab,
    WD, has_dist, share, lo, hi, sat, work, u_prev, moved, terminated, truncated, done, dc, cap,
) -> int:  # fmt: skip
    """The runner's end of one control step of the members ``ix`` with the controller's
    commands ``u``, numpy form (the reference of :data:`STEP_END`). Returns -1, changing
    nothing, where a command is not finite; else, after
    the ATP and the limit columns (:func:`supervise_arrays`; a braking member's command
    replaced by ``lo_brake[b]``, the lower envelope bound of the scenario's train at
    its speed), the record row of each member (the columns of ``_COLUMNS`` from ``t …
    u_N``, ``v_ref`` and ``s_ref`` one per member or one for all; the limit columns;
    the plant's work and saturation before the step; then the info rows ``info_rows``
    into the table columns ``icols``) at its step ``k[b]`` of ``table`` (steps ×
    columns × members), the plant step (:func:`~train_envs.plants.batch.batch_car_step`,
    arguments ``ST … has_dist`` and ``share … work`` of
    :meth:`~train_envs.plants.batch.BatchSingleCar.step_args`, inactive members'
    commands 0) and the end-of-step checks (:func:`done_arrays`), the number of the
    members ``ix`` whose episode goes on (not done, fewer than ``cap`` steps; ``cap``
    < 0: no cap)."""
    if not np.isfinite(u).all():
        return -1
    n = ix.shape[0]
    limit, over, overrun = np.empty(n), np.empty(n), np.empty(n)
    brake = np.empty(n, dtype=bool)
    supervise_arrays(ix, s, v, pos, val, braking, interventions, sp, limit, brake, over, overrun)
    u = np.where(brake, lo_brake[ix], u)
    v_ref, s_ref = np.broadcast_to(v_ref, (n,)), np.broadcast_to(s_ref, (n,))
    row = [t, s, v, a, v_ref, s_ref, limit, grad, u, u_N, work[0, ix], work[1, ix], sat[ix],
           brake, over, overrun]  # fmt: skip
    record_rows(table, k, ix, row, info_rows, icols)
    uf = np.zeros(ST.shape[0])
    uf[ix] = u
    batch_car_step(ST, BL, heads, active, ksub, order, C, XL, Y0L, SL, offs, has_tab, WD,
                   has_dist, uf, share, lo, hi, sat, work)  # fmt: skip
    done_arrays(ix, u, ST, u_prev, k, moved, terminated, truncated, done, dc)
    live = ~done[ix] if cap < 0 else ~done[ix] & (k[ix] < cap)
    return int(np.count_nonzero(live))


def record_rows(table, k, ix, row, info_rows, icols) -> None:
    """The record row of each member ``ix`` at its step ``k[b]`` of ``table`` (steps ×
    columns × members): the columns ``row`` (one entry per member each) into the
    table's first columns, the info rows ``info_rows`` into the columns ``icols``."""
    vals = np.concatenate([np.array(row, dtype=float), info_rows])
    cols = np.concatenate([np.arange(len(row)), icols])
    table[k[ix][None, :], cols[:, None], ix[None, :]] = vals


def step_end_loop(
    ix, u, t, s, v, a, grad, u_N, v_ref, s_ref, info_rows, icols, table, k, pos, val, braking,
    interventions, sp, lo_brake, ST, BL, heads, active, ksub, order, C, XL, Y0L, SL, offs, has_tab,
    WD, has_dist, share, lo, hi, sat, work, u_prev, moved, terminated, truncated, done, dc, cap,
) -> int:  # fmt: skip
    """:func:`step_end_arrays` member by member (the source of its compiled twin)."""
    n = ix.shape[0]
    for r in range(n):
        if not math.isfinite(u[r]):
            return -1
    limit, over, overrun = np.empty(n), np.empty(n), np.empty(n)
    brake = np.empty(n, dtype=np.bool_)
    supervise_loop(ix, s, v, pos, val, braking, interventions, sp, limit, brake, over, overrun)
    uo = np.empty(n)
    uf = np.zeros(ST.shape[0])
    m = info_rows.shape[0]
    one_ref = 1 if v_ref.shape[0] == 1 else 0
    for r in range(n):
        b = ix[r]
        ur = lo_brake[b] if brake[r] else u[r]
        uo[r] = ur
        uf[b] = ur
        kb = k[b]
        table[kb, 0, b] = t[r]
        table[kb, 1, b] = s[r]
        table[kb, 2, b] = v[r]
        table[kb, 3, b] = a[r]
        table[kb, 4, b] = v_ref[r if one_ref == 0 else 0]
        table[kb, 5, b] = s_ref[r if one_ref == 0 else 0]
        table[kb, 6, b] = limit[r]
        table[kb, 7, b] = grad[r]
        table[kb, 8, b] = ur
        table[kb, 9, b] = u_N[r]
        table[kb, 10, b] = work[0, b]
        table[kb, 11, b] = work[1, b]
        table[kb, 12, b] = 1.0 if sat[b] else 0.0
        table[kb, 13, b] = 1.0 if brake[r] else 0.0
        table[kb, 14, b] = over[r]
        table[kb, 15, b] = overrun[r]
        for j in range(m):
            table[kb, icols[j], b] = info_rows[j, r]
    run_batch(ST, BL, heads, active, ksub, order, C, XL, Y0L, SL, offs, has_tab, WD, has_dist,
              uf, share, lo, hi, sat, work)  # fmt: skip
    done_loop(ix, uo, ST, u_prev, k, moved, terminated, truncated, done, dc)
    live = 0
    for r in range(n):
        b = ix[r]
        if not done[b] and (cap < 0 or k[b] < cap):
            live += 1
    return live


#: the name of the runner's end of a control step in :data:`_jit.TWINS` (supervision,
#: record, plant step, end-of-episode checks in one call)
STEP_END = "simulation.batch_step_end"
_jit.register(
    STEP_END,
    step_end_arrays,
    source=step_end_loop,
    helpers={
        "supervise_loop": supervise_loop,
        "done_loop": done_loop,
        "run_batch": run_batch,
        **CAR_STEP_HELPERS,
    },
)


def cars_step_end(
    plant, dt, act, ix, u, t, s, v, a, grad, u_N, v_ref, s_ref, info_rows, icols, table, k,
    pos, val, braking, interventions, sp, train, climits, u_prev, moved, terminated, truncated,
    done, dc, cap,
) -> int:  # fmt: skip
    """:func:`step_end_arrays` for multi-car members (``plant``: the
    :class:`~train_envs.plants.batch_multi_car.BatchMultiCar`, stepped by ``dt`` for the
    members ``act``): the commands ``u`` are one whole-train input per member, ``(n,)``,
    or one per car, ``(n, n_cars)``. The operations and their order are
    :meth:`ClosedLoop.step`'s per member: -1 (nothing changed) where a command is not
    finite; else the ATP and the limit columns (:func:`supervise_arrays`; a braking
    member's command replaced by the ATP's brake ``−B(v)`` of the scenario's ``train``,
    split per car by the member's mass shares), the record row (the columns of
    :func:`~.loop.record_columns`: the total command, the per-car commands, the coupler
    extremes and their excess over the limits ``climits`` before the step), the plant
    step and the end-of-step checks (:func:`episode_end`); returns the number of the
    members ``ix`` whose episode goes on."""
    if not np.isfinite(u).all():
        return -1
    n = ix.shape[0]
    limit, over, overrun = np.empty(n), np.empty(n), np.empty(n)
    brake = np.empty(n, dtype=bool)
    supervise_arrays(ix, s, v, pos, val, braking, interventions, sp, limit, brake, over, overrun)
    share = plant.SHARE[ix]
    per_input = u.ndim == 2
    if brake.any():  # the ATP overrides the command
        lo = train.envelope_N(v[brake])[0]
        u = u.copy()
        u[brake] = lo[:, None] * share[brake] if per_input else lo
    # the record: Σ u (the numpy sum of the single runner), the per-car commands (the
    # whole-train input split by mass shares where there is one input)
    cars = u if per_input else u[:, None] * share
    u_cmd = row_np_sum(u) if per_input else u
    f, q = (x[ix] for x in plant.coupler_extremes())
    excess = coupler_excess_arrays(f, q, *climits)
    v_ref, s_ref = np.broadcast_to(v_ref, (n,)), np.broadcast_to(s_ref, (n,))
    row = [t, s, v, a, v_ref, s_ref, limit, grad, u_cmd, u_N, plant.work_traction_J[ix],
           plant.work_brake_J[ix], plant.saturated[ix], *cars.T, f, q, brake, over, overrun,
           excess]  # fmt: skip
    record_rows(table, k, ix, row, info_rows, icols)
    uf = np.zeros((plant.B, *u.shape[1:]))
    uf[ix] = u
    plant.step(uf, dt, act)
    episode_end(ix, u, plant.t[ix], plant.s[ix], plant.v[ix], plant._stopped[ix], u_prev, k,
                moved, terminated, truncated, done, dc)  # fmt: skip
    live = ~done[ix] if cap < 0 else ~done[ix] & (k[ix] < cap)
    return int(np.count_nonzero(live))


class BatchController(Protocol):
    """What :class:`BatchLoop` needs of a batched controller. One whose
    ``needs_plant_state`` is true also gets the members' accelerations and actual
    forces, ``compute(ix, t, s, v, u_prev_N, a, force_N)``, and on multi-car members
    their cars' positions, speeds and forces, ``compute(..., cars=(positions, speeds,
    forces))`` (:class:`~.members.MemberControllers`). ``u_prev_N`` (and the commands
    returned) hold one entry per member, or a row of ``n_inputs`` where the scenario
    has several inputs."""

    def reset(self, ix: np.ndarray | None = None) -> None: ...

    def compute(
        self, ix: np.ndarray, t: np.ndarray, s: np.ndarray, v: np.ndarray, u_prev_N: np.ndarray
    ) -> tuple[np.ndarray, Mapping[str, np.ndarray]]: ...


class BatchLoop:
    """B closed loops of ``scenario`` in lockstep.

    Single-car members step on :class:`~train_envs.plants.batch.BatchSingleCar` with the
    end of step in the compiled twin :data:`STEP_END`; multi-car members on
    :class:`~train_envs.plants.batch_multi_car.BatchMultiCar` with its numpy form
    :func:`cars_step_end` (one whole-train input or one per car). Everything else (the
    read-outs, the controller call, the references, the info columns, the results) is
    one code for both.

    Args:
        scenario: the scenario of every member (:func:`batchable_member` plants).
        plants: the members' reset plants (:func:`~train_envs.scenarios.build_plant`).
        controller: the batched controller of the B members, reset for the episode.
        supervision: the ATP settings (``end_on_violation`` is not supported here).
        max_steps: the step cap (control steps; ``None``: the scenario's own end).
    """

    def __init__(
        self,
        scenario: Scenario,
        plants: Sequence[TrainPlant],
        controller: BatchController,
        supervision: Supervision | None = None,
        max_steps: int | None = None,
    ) -> None:
        self.supervision = Supervision() if supervision is None else supervision
        if self.supervision.end_on_violation:
            raise ValueError("BatchLoop: supervision.end_on_violation is not supported")
        self.scenario = sc = scenario
        #: the number of cars and of inputs (commands per member) of every member
        self.n_cars = plants[0].n if plants else 1
        self.n_inputs = sc.control_context().n_inputs
        self._multi = self.n_cars > 1
        if not self._multi and self.n_inputs != 1:
            raise ValueError("BatchLoop needs a single-car scenario with one whole-train input")
        self.plant = BatchMultiCar(plants) if self._multi else BatchSingleCar(plants)
        self.controller = controller
        #: whether the controller's compute takes the accelerations and actual forces
        self._plant_state = bool(getattr(controller, "needs_plant_state", False))
        self.B = B = len(plants)
        self.dt = sc.dt_ctrl_s
        self.n_max = int(math.ceil(sc.t_max_s / self.dt)) + 2
        self.max_steps = max_steps
        u0 = initial_commands(sc, self.n_inputs)
        #: the command an episode starts from (a float, or a row of n_inputs)
        self._u0 = float(u0[0]) if self.n_inputs == 1 else u0
        self.u_prev = np.full(B, self._u0) if self.n_inputs == 1 else np.tile(u0, (B, 1))
        self.k = np.zeros(B, dtype=np.int64)
        self.done = np.zeros(B, dtype=bool)
        self.terminated = np.zeros(B, dtype=bool)
        self.truncated = np.zeros(B, dtype=bool)
        self._moved = np.full(B, sc.v0_mps > 0.1)
        self._braking = np.zeros(B, dtype=bool)
        self.atp_interventions = np.zeros(B, dtype=np.int64)
        self._window = sc.stop_window()
        self._limit = permitted_speed_fn(sc)
        self._limit_table = permitted_speed_table(sc)
        sv = self.supervision
        has_stop = sc.s_stop_m is not None
        self._sp = np.array(
            [1.0 if sv.atp else 0.0, sv.margin_mps, 1.0 if has_stop else 0.0,
             sc.s_stop_m + self._window if has_stop else 0.0]
        )  # fmt: skip
        self._dc = np.array(
            [1.0 if has_stop else 0.0, sc.s_stop_m + sc.overrun_m if has_stop else 0.0,
             sc.t_max_s - 1e-9, float(self.n_max - 1)]
        )  # fmt: skip
        self._end = _jit.implementation(STEP_END)
        cp = sc.train.coupler
        self._coupler_lim = (cp.max_force_N, cp.max_deformation_m)
        #: whether every member's episode goes on (then a step needs no mask of its own)
        self._all_live = False
        self._act_all = np.ones(B, dtype=bool)
        self._ix_all = np.arange(B)
        self._grad = gradient_table(sc.track)
        # one (steps, columns, members) table: the runner's columns, then INFO_COLUMNS
        names = record_columns(self.n_cars)
        self._table = np.full((self.n_max, len(names) + len(INFO_COLUMNS), B), np.nan)
        self._data = {name: self._table[:, j, :] for j, name in enumerate(names)}
        n0 = len(names)
        self._info_all = {key: self._table[:, n0 + j, :] for j, key in enumerate(INFO_COLUMNS)}
        self._info_index = {key: n0 + j for j, key in enumerate(INFO_COLUMNS)}
        #: the info columns the controller has given (in INFO_COLUMNS order)
        self._info: dict[str, np.ndarray] = {}
        self._cols: dict[tuple[str, ...], tuple[list[str], np.ndarray]] = {}
        #: the last control step's fallback, slack_max, iterations per member (NaN: none)
        self._last = np.full((B, 3), np.nan)

    def reset_member(self, b: int, plant: TrainPlant) -> None:
        """Start a new episode of member ``b`` on the reset ``plant`` (its controller
        state reset too); the other members go on."""
        sc = self.scenario
        self.plant.load(b, plant)
        self.controller.reset(np.array([b]))
        self.u_prev[b] = self._u0
        self.k[b] = 0
        self.done[b] = self.terminated[b] = self.truncated[b] = False
        self._moved[b] = sc.v0_mps > 0.1
        self._braking[b] = False
        self.atp_interventions[b] = 0
        self._last[b] = np.nan
        self._table[:, :, b] = np.nan
        self._all_live = False

    def _active(self) -> np.ndarray:
        act = ~self.done
        if self.max_steps is not None:
            act &= self.k < self.max_steps
        return act

    # ------------------------------------------------------------------ run
    def step(self, mask: np.ndarray | None = None) -> np.ndarray:
        """One control period of every active member (of ``mask``, if given); returns
        the mask stepped. Members may be at different steps of their episodes."""
        if self._all_live and mask is None:  # every member goes on (the last step said)
            act, ix = self._act_all, self._ix_all
        else:
            act = self._active()
            if mask is not None:
                act &= mask
            ix = np.flatnonzero(act)
            if ix.size == 0:
                return act
        p, sc = self.plant, self.scenario
        full = ix.size == self.B
        sel = slice(None) if full else ix  # (the members' own rows, without a gather)
        t = p.t[ix]
        s, v = p.s[ix], p.v[ix]
        a_all, g_all = p.accel_gradient()
        a = a_all[sel]
        # the record's gradient: the plant's own reading where it is the same table
        grad = g_all[sel] if p.table is self._grad else self._grad(s)
        u_N = p.force[ix]
        if not self._plant_state:
            u, info = self.controller.compute(ix, t, s, v, self.u_prev[ix])
        elif self._multi:  # (single controllers: the observation's a, F and cars too)
            cars = (p.positions[sel], p.speeds[sel], p.forces[sel])
            u, info = self.controller.compute(ix, t, s, v, self.u_prev[ix], a, u_N, cars=cars)
        else:
            u, info = self.controller.compute(ix, t, s, v, self.u_prev[ix], a, u_N)
        u = np.asarray(u, dtype=float)
        v_ref, s_ref = self._reference(t, s)
        keys, icols = self._columns(tuple(info))
        n = ix.size
        info_rows = np.array([info[key] for key in keys], dtype=float) if keys else np.empty((0, n))
        pos, val = self._limit_table
        cap = -1 if self.max_steps is None else self.max_steps
        if self._multi:
            live = cars_step_end(p, self.dt, act, ix, u, t, s, v, a, grad, u_N, v_ref, s_ref,
                                 info_rows, icols, self._table, self.k, pos, val, self._braking,
                                 self.atp_interventions, self._sp, sc.train, self._coupler_lim,
                                 self.u_prev, self._moved, self.terminated, self.truncated,
                                 self.done, self._dc, cap)  # fmt: skip
        else:
            head, tail = p.step_args(self.dt, act)
            # the ATP's brake: the scenario's train's lower bound (the plant's reading
            # where every member runs on that train; unused without the ATP)
            if not self.supervision.atp or p.single_train() is sc.train:
                lo_brake = tail[1]
            else:
                lo_brake = sc.train.envelope_N(p.ST[:, ST_Z1])[0]
            live = self._end(ix, u, t, s, v, a, grad, u_N, v_ref, s_ref, info_rows, icols,
                             self._table, self.k, pos, val, self._braking, self.atp_interventions,
                             self._sp, lo_brake, *head, *tail, self.u_prev, self._moved,
                             self.terminated, self.truncated, self.done, self._dc,
                             cap)  # fmt: skip
        if live < 0:
            raise ValueError(f"batched controller returned a non-finite command {u}")
        self._all_live = live == self.B
        if "fallback" in info:  # what an env step reports of the last control step
            for j, key in enumerate(("fallback", "slack_max", "iterations")):
                if key in info:
                    self._last[sel, j] = info[key]
        return act.copy() if act is self._act_all else act

    def _columns(self, given: tuple[str, ...]) -> tuple[list[str], np.ndarray]:
        """(the info keys recorded, in INFO_COLUMNS order; their table columns) for the
        info keys ``given`` by the controller (once per set of keys)."""
        out = self._cols.get(given)
        if out is None:
            keys = [key for key in INFO_COLUMNS if key in given]
            for key in keys:
                if key not in self._info:
                    self._info = {
                        c: self._info_all[c] for c in INFO_COLUMNS if c in self._info or c == key
                    }
            cols = np.array([self._info_index[key] for key in keys], dtype=np.int64)
            out = self._cols[given] = (keys, cols)
        return out

    def last_info(self, b: int) -> dict[str, float]:
        """Member ``b``'s fallback, slack_max and iterations of its last control step
        (what an env step reports; empty where the controller gives none)."""
        out: dict[str, float] = {}
        for key, x in zip(
            ("fallback", "slack_max", "iterations"), self._last[b].tolist(), strict=True
        ):
            if x == x:
                out[key] = int(x) if key == "iterations" else x
        return out

    def _reference(self, t: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The reference speed and position of each member (at its time or position),
        or one of each for all members where they are in lockstep."""
        ref = self.scenario.reference
        if ref.mode == "distance":
            return np.array([ref.v_ref(0.0, x) for x in s.tolist()]), per_time(t, ref.s_ref)
        t0 = common_time(t)
        if t0 is not None:  # in lockstep: one value for all members
            vs = np.array(ref.at_time(t0))
            return vs[:1], vs[1:]
        vs = per_time(t, ref.at_time)
        return vs[:, 0], vs[:, 1]

    def run(self) -> None:
        """Step until every member's episode is over (or capped)."""
        while self._active().any():
            self.step()

    # ------------------------------------------------------------------ results
    def arrays(self, b: int) -> dict[str, np.ndarray]:
        """Member ``b``'s columns as :meth:`ClosedLoop.arrays` gives them."""
        k = int(self.k[b])
        cols = {**self._data, **self._info}
        if k == 0:
            return {name: arr[:0, b].copy() for name, arr in cols.items()}
        p = self.plant
        coupler = None
        if self._multi:
            f, q = p.coupler_extremes()
            coupler = (float(f[b]), float(q[b]), *self._coupler_lim)
        state = (float(p.t[b]), float(p.s[b]), float(p.v[b]), float(p.accel()[b]))
        last = final_row(
            self.scenario, self._limit, self.scenario.gradient_at, self._window, state,
            float(np.sum(self.u_prev[b])), float(np.sum(p.forces[b])) if self._multi
            else float(p.force[b]), float(p.work_traction_J[b]), float(p.work_brake_J[b]),
            coupler,
        )  # fmt: skip
        out = {}
        for name, arr in cols.items():
            col = np.empty(k + 1)
            col[:k] = arr[:k, b]
            col[k] = last.get(name, np.nan)
            out[name] = col
        return out

    def metrics(self, b: int) -> dict[str, float]:
        """Member ``b``'s :func:`~train_envs.metrics.episode_metrics`."""
        return scenario_metrics(self.scenario, self.arrays(b))
