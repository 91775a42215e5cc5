"""B single-point trains stepped together: the lockstep twin of the single-car plant.

:class:`BatchSingleCar` holds the states of B members of
:class:`~train_envs.plants.multi_car.TrainPlant` with one car (actuator order 0 or 1, no
Davis variation, gradient as a table or none): each member keeps its own train
(mass, Davis coefficients, envelope), disturbances and dead-time buffer. One
:meth:`BatchSingleCar.step` advances every active member by the same duration with its
own command; the ETD2 sub-steps are those of
:func:`train_envs.plants.single_car.run_single` (the equations are in
:mod:`train_envs.plants.multi_car` and :mod:`train_envs.plants.integrator`), run for
each member by the registered batch step :data:`BATCH_CAR_STEP` (compiled where numba
is available: one call for the whole population, which also clips each command to its
member's envelope and sums the work). The read-outs (position, speed, acceleration
from the twin :data:`BATCH_ACCEL`, force, work) are arrays over the members, computed
with the same IEEE operations as the single plant's float paths, so every member equals
its single plant bit for bit (tested).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from train_envs import _jit
from train_envs.plants.multi_car import TrainPlant
from train_envs.plants.physics import davis_signed_N, gradient_at
from train_envs.plants.single_car import (
    ST_STOPPED,
    ST_T,
    ST_W,
    ST_WB,
    ST_WT,
    ST_Z0,
    ST_Z1,
    ST_Z2,
    _crossing_time,
    _jumps,
    _nonlinear,
    run_single,
    single_car_step,
)

__all__ = [
    "BATCH_ACCEL",
    "BATCH_CAR_STEP",
    "CAR_STEP_HELPERS",
    "BatchSingleCar",
    "batch_car_step",
    "members_envelope",
    "run_batch",
]

#: the name of the batch step in :data:`train_envs._jit.TWINS`
BATCH_CAR_STEP = "plants.batch_car_step"


def run_batch(
    ST, BL, heads, active, k, order, C, XL, Y0L, SL, offs, has_tab, WD, has_dist, u, share,
    lo, hi, sat, work,
) -> None:  # fmt: skip
    """:func:`~train_envs.plants.single_car.run_single` for every active member ``b``:
    state row ``ST[b]``, buffer ``BL[b]``, head ``heads[b]``, constants ``C[b]``, the
    gradient table ``XL[offs[b]:offs[b+1]]`` (and ``Y0L``, ``SL``), disturbance sums
    ``WD[b]``, with the command ``u[b] share[b]`` clipped to the envelope ``[lo[b]
    share[b], hi[b] share[b]]`` first (``sat[b]``: whether it was clipped) and the
    step's traction and braking work added to ``work[0, b]``, ``work[1, b]`` after;
    updates ``ST``, ``BL``, ``heads``, ``sat`` and ``work`` in place."""
    for b in range(ST.shape[0]):
        if active[b]:
            val = u[b] * share[b]
            lo_b = lo[b] * share[b]
            hi_b = hi[b] * share[b]
            w = lo_b if val < lo_b else val
            w = hi_b if w > hi_b else w
            sat[b] = w != val
            ST[b, ST_W] = w
            o0 = offs[b]
            o1 = offs[b + 1]
            heads[b] = run_single(
                ST[b],
                BL[b],
                heads[b],
                k,
                order,
                C[b],
                XL[o0:o1],
                Y0L[o0:o1],
                SL[o0:o1],
                has_tab,
                WD[b],
                has_dist,
            )
            work[0, b] = work[0, b] + ST[b, ST_WT]
            work[1, b] = work[1, b] + ST[b, ST_WB]
            ST[b, ST_WT] = 0.0
            ST[b, ST_WB] = 0.0


def batch_car_step(
    ST, BL, heads, active, k, order, C, XL, Y0L, SL, offs, has_tab, WD, has_dist, u, share,
    lo, hi, sat, work,
) -> None:  # fmt: skip
    """:func:`run_batch` through the single car's reference step (Python floats), member
    by member: the reference of the compiled twin."""
    for b in np.flatnonzero(active).tolist():
        val = float(u[b]) * float(share[b])
        lo_b = float(lo[b]) * float(share[b])
        hi_b = float(hi[b]) * float(share[b])
        w = lo_b if val < lo_b else val
        w = hi_b if w > hi_b else w
        sat[b] = w != val
        o0, o1 = int(offs[b]), int(offs[b + 1])
        st = ST[b].copy()
        st[ST_W] = w
        bl = BL[b].copy()
        heads[b] = single_car_step(
            st,
            bl,
            int(heads[b]),
            k,
            order,
            C[b],
            XL[o0:o1],
            Y0L[o0:o1],
            SL[o0:o1],
            has_tab,
            WD[b],
            has_dist,
        )
        work[0, b] = float(work[0, b]) + float(st[ST_WT])
        work[1, b] = float(work[1, b]) + float(st[ST_WB])
        st[ST_WT] = 0.0
        st[ST_WB] = 0.0
        ST[b] = st
        BL[b] = bl


#: the functions :func:`run_batch` calls, by name (for the compiled loops that call it)
CAR_STEP_HELPERS = {
    "bisect_right": _jit.bisect_right,
    "davis_signed_N": davis_signed_N,
    "_nonlinear": _nonlinear,
    "_crossing_time": _crossing_time,
    "_jumps": _jumps,
    "run_single": run_single,
}
_jit.register(BATCH_CAR_STEP, batch_car_step, source=run_batch, helpers=CAR_STEP_HELPERS)


def accel_arrays(ST, order, K, XL, Y0L, SL, offs, has_tab, d, has_dist, g, out) -> None:
    """Each member's gradient [‰] at its position into ``g`` (its table ``XL[offs[b]:
    offs[b+1]]``, ``Y0L``, ``SL``, read by :func:`~train_envs.plants.physics.gradient_at`;
    0 without tables) and its acceleration
    ``F/m' + N(s, v, t)`` [m/s²] (0 when held) into ``out``, numpy form: the reference
    of :data:`BATCH_ACCEL`. ``K`` rows: Davis a, b, c per member, m g / 1000, m, 1/m',
    the force coefficient; ``d``: the members' disturbance sums."""
    v = ST[:, ST_Z1]
    if has_tab:
        for b in range(ST.shape[0]):  # (each member's own table)
            o0, o1 = offs[b], offs[b + 1]
            g[b] = gradient_at(XL[o0:o1], Y0L[o0:o1], SL[o0:o1], ST[b, ST_Z0])
    else:
        g[:] = 0.0
    a0, b0, c0, mg0, m0, minv0, acc_coef = K
    av = np.where(v >= 0.0, v, -v)
    f = a0 + b0 * av + c0 * av * av
    f = np.where(v >= 0, f, -f)
    if has_tab:
        f = f + mg0 * g
    if has_dist:
        f = f + m0 * d
    force = ST[:, ST_Z2] if order else ST[:, ST_W]
    acc = acc_coef * force + -f * minv0
    out[:] = np.where(ST[:, ST_STOPPED] != 0.0, 0.0, acc)


def accel_loop(ST, order, K, XL, Y0L, SL, offs, has_tab, d, has_dist, g, out) -> None:
    """:func:`accel_arrays` member by member (the source of its compiled twin)."""
    for b in range(ST.shape[0]):
        v = ST[b, ST_Z1]
        gb = 0.0
        if has_tab:
            o0, o1 = offs[b], offs[b + 1]
            gb = gradient_at(XL[o0:o1], Y0L[o0:o1], SL[o0:o1], ST[b, ST_Z0])
        g[b] = gb
        av = v if v >= 0.0 else -v
        f = K[0, b] + K[1, b] * av + K[2, b] * av * av
        f = f if v >= 0 else -f
        if has_tab:
            f = f + K[3, b] * gb
        if has_dist:
            f = f + K[4, b] * d[b]
        force = ST[b, ST_Z2] if order else ST[b, ST_W]
        acc = K[6, b] * force + -f * K[5, b]
        out[b] = 0.0 if ST[b, ST_STOPPED] != 0.0 else acc


#: the name of the population's acceleration read-out in :data:`train_envs._jit.TWINS`
BATCH_ACCEL = "plants.batch_accel"
_jit.register(
    BATCH_ACCEL,
    accel_arrays,
    source=accel_loop,
    helpers={"bisect_right": _jit.bisect_right, "gradient_at": gradient_at},
)


def members_envelope(
    groups: Sequence[tuple[object, np.ndarray]], v: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``(−B(v), F(v))`` of a population's members at their speeds ``v`` (one per
    member), from ``groups``: ``(train, member indices)`` per train the members run on
    (:meth:`TrainParams.envelope_N` once per train)."""
    if len(groups) == 1:
        return groups[0][0].envelope_N(v)
    lo = np.empty(v.shape[0])
    hi = np.empty(v.shape[0])
    for train, ix in groups:
        lo[ix], hi[ix] = train.envelope_N(v[ix])
    return lo, hi


def batchable(plant: TrainPlant) -> bool:
    """Whether ``plant`` steps on the single-car path that :class:`BatchSingleCar` twins."""
    g = plant.gradient_permil
    return (
        bool(plant._scalar_ok)
        and plant.input_mode == "total"
        and (g is None or plant._grad_table() is not None)
    )


class BatchSingleCar:
    """B reset single-car plants (:func:`batchable`) as one population.

    Args:
        plants: the members, each reset (its own train, disturbances, seed); they must
            share the sub-step ``h``, the actuator order, the dead-time buffer length and
            whether they have a gradient table. The plants themselves are not stepped.
    """

    def __init__(self, plants: Sequence[TrainPlant]) -> None:
        if not plants:
            raise ValueError("plants must hold at least one plant")
        p0 = plants[0]
        for i, p in enumerate(plants):
            if not batchable(p):
                raise ValueError(f"plants[{i}] is not a single-car plant with a gradient table")
            if (p.h, p.actuator.order, p._buffer.shape[0], p.gradient_permil is None) != (
                p0.h,
                p0.actuator.order,
                p0._buffer.shape[0],
                p0.gradient_permil is None,
            ):
                raise ValueError(f"plants[{i}] differs from plants[0] in step, actuator or table")
        self.plants = list(plants)
        B = self.B = len(plants)
        self.h = p0.h
        self.order = p0.actuator.order
        self.has_tab = p0.gradient_permil is not None
        self.has_dist = any(p.disturbances for p in plants)
        self.C = np.stack([p._kconst for p in plants])
        tabs = [
            (p.gradient_permil.x, p.gradient_permil.y0, p.gradient_permil.slope)
            if self.has_tab
            else (np.zeros(1),) * 3
            for p in plants
        ]
        self.offs = np.concatenate([[0], np.cumsum([len(t[0]) for t in tabs])]).astype(np.int64)
        self.XL, self.Y0L, self.SL = (np.concatenate([t[j] for t in tabs]) for j in range(3))
        #: the one gradient table of every member (None: several, or none)
        same = all(p.gradient_permil is p0.gradient_permil for p in plants)
        self.table = p0.gradient_permil if same else None
        self.BL = np.stack([p._buffer[:, 0] for p in plants])
        self.heads = np.array([p._head for p in plants], dtype=np.int64)
        # per-member constants of the read-outs (NonlinearTerm.single, the envelope)
        nl = [p._nl for p in plants]
        self.a0 = np.array([x.a0 for x in nl])
        self.b0 = np.array([x.b0 for x in nl])
        self.c0 = np.array([x.c0 for x in nl])
        self.mg0 = np.array([x.mg0 for x in nl])
        self.m0 = np.array([x.m0 for x in nl])
        self.minv0 = np.array([x.minv0 for x in nl])
        self.acc_coef = np.array([p._acc_coef for p in plants])
        self.share0 = np.array([p._share0 for p in plants])
        # members grouped by train (the envelope is a method of the train)
        groups: dict[int, list[int]] = {}
        for i, p in enumerate(plants):
            groups.setdefault(id(p.train), []).append(i)
        self._groups = [(plants[ix[0]].train, np.array(ix)) for ix in groups.values()]
        self.ST = np.zeros((B, 9))
        for i, p in enumerate(plants):
            self.ST[i] = self._state_row(p)
        #: the members' traction and braking work [J] (rows of one array)
        self._work = np.array(
            [[p.work_traction_J for p in plants], [p.work_brake_J for p in plants]], dtype=float
        )
        self.work_traction_J, self.work_brake_J = self._work[0], self._work[1]
        self.saturated = np.zeros(B, dtype=bool)
        self._kern = _jit.implementation(BATCH_CAR_STEP)
        self._accel = _jit.implementation(BATCH_ACCEL)
        self._zeros = np.zeros(B)
        self._set_accel_constants()
        self._WD0 = np.zeros((B, 1))

    def _set_accel_constants(self) -> None:
        """Rows a, b, c, m g / 1000, m, 1/m', F/m' coefficient of :data:`BATCH_ACCEL`."""
        self._ac = np.stack(
            [self.a0, self.b0, self.c0, self.mg0, self.m0, self.minv0, self.acc_coef]
        )

    def _state_row(self, p: TrainPlant) -> list[float]:
        """The state vector of :func:`run_single` of a reset plant ``p``."""
        z = p.z.tolist()
        pl = p._p_last
        w = p._w_now
        return [
            z[0], z[1], z[2] if self.order else 0.0, p.t,
            pl if type(pl) is float else float(pl[0]), 1.0 if p.stopped else 0.0,
            w if type(w) is float else float(w[0]), 0.0, 0.0,
        ]  # fmt: skip

    def load(self, b: int, plant: TrainPlant) -> None:
        """Make member ``b`` the reset ``plant`` (same gradient table, step and actuator
        as the member it replaces; its own train, disturbances and state)."""
        old = self.plants[b]
        if plant.gradient_permil is not old.gradient_permil or not batchable(plant):
            raise ValueError("load: the plant must share the member's gradient table")
        if (plant.h, plant.actuator.order, plant._buffer.shape[0]) != (
            self.h,
            self.order,
            self.BL.shape[1],
        ):
            raise ValueError("load: the plant differs in step, actuator or dead time")
        if plant.train is not old.train and len(self._groups) == 1:
            raise ValueError("load: the plant's train differs from the population's")
        self.plants[b] = plant
        self.has_dist = self.has_dist or bool(plant.disturbances)
        self.C[b] = plant._kconst
        self.BL[b] = plant._buffer[:, 0]
        self.heads[b] = plant._head
        nl = plant._nl
        self.a0[b], self.b0[b], self.c0[b] = nl.a0, nl.b0, nl.c0
        self.mg0[b], self.m0[b], self.minv0[b] = nl.mg0, nl.m0, nl.minv0
        self.acc_coef[b], self.share0[b] = plant._acc_coef, plant._share0
        self._set_accel_constants()
        self.ST[b] = self._state_row(plant)
        self.work_traction_J[b] = plant.work_traction_J
        self.work_brake_J[b] = plant.work_brake_J
        self.saturated[b] = False

    # ------------------------------------------------------------- read-outs
    @property
    def t(self) -> np.ndarray:
        return self.ST[:, ST_T]

    @property
    def s(self) -> np.ndarray:
        return self.ST[:, ST_Z0]

    @property
    def v(self) -> np.ndarray:
        return self.ST[:, ST_Z1]

    @property
    def stopped(self) -> np.ndarray:
        return self.ST[:, ST_STOPPED] != 0.0

    @property
    def force(self) -> np.ndarray:
        """The actual (post-actuator) force of each member [N]."""
        return self.ST[:, ST_Z2] if self.order else self.ST[:, ST_W]

    def accel(self) -> np.ndarray:
        """Lead-car acceleration of each member [m/s²] (0 when held), as
        :meth:`TrainPlant._accel_single`: ``F/m' + N(s, v, t)`` (:data:`BATCH_ACCEL`)."""
        return self.accel_gradient()[0]

    def accel_gradient(self) -> tuple[np.ndarray, np.ndarray]:
        """``(accel(), gradient(s))``: the accelerations and the gradients [‰] at the
        members' positions that they contain (zeros without a table)."""
        d = self._zeros
        if self.has_dist:
            d = np.array(
                [
                    p._nl.disturbance_sum(ti)
                    for p, ti in zip(self.plants, self.t.tolist(), strict=True)
                ]
            )
        out, g = np.empty(self.B), np.empty(self.B)
        self._accel(self.ST, self.order, self._ac, self.XL, self.Y0L, self.SL, self.offs,
                    self.has_tab, d, self.has_dist, g, out)  # fmt: skip
        return out, g

    def single_train(self) -> object | None:
        """The train of every member (None where the members run on several)."""
        return self._groups[0][0] if len(self._groups) == 1 else None

    def envelope(self, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(−B(v), F(v))`` of each member's own train at its speed ``v``."""
        return members_envelope(self._groups, v)

    # ------------------------------------------------------------- stepping
    def step(self, u: np.ndarray, duration_s: float, active: np.ndarray) -> None:
        """Apply the total commands ``u`` [N] (held, one per member) for ``duration_s``
        to the ``active`` members (a boolean mask); the others stay as they are."""
        head, tail = self.step_args(duration_s, active)
        self._kern(*head, np.ascontiguousarray(u, dtype=float), *tail)

    def step_args(self, duration_s: float, active: np.ndarray) -> tuple[tuple, tuple]:
        """The arguments of :data:`BATCH_CAR_STEP` for one :meth:`step` of ``duration_s``
        of the ``active`` members, before and after the commands ``u``: ``(ST, BL,
        heads, active, k, order, C, XL, Y0L, SL, offs, has_tab, WD, has_dist)`` and
        ``(share, lo, hi, sat, work)``, with the envelope read at the members' speeds
        and the disturbance sums of the sub-steps (a caller that runs the step inside
        its own compiled loop passes them on)."""
        k = self.plants[0]._substeps(duration_s)
        ST = self.ST
        lo, hi = self.envelope(np.abs(ST[:, ST_Z1]))
        WD = self._WD0
        if self.has_dist:
            WD = np.zeros((self.B, k + 1))
            for b in np.flatnonzero(active).tolist():
                p, tj = self.plants[b], float(ST[b, ST_T])
                for j in range(k + 1):
                    WD[b, j] = p._nl.disturbance_sum(tj)
                    tj += self.h
        head = (ST, self.BL, self.heads, active, k, self.order, self.C, self.XL, self.Y0L,
                self.SL, self.offs, self.has_tab, WD, self.has_dist)  # fmt: skip
        return head, (self.share0, lo, hi, self.saturated, self._work)
