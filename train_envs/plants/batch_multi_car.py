"""B multi-car trains stepped together: the lockstep twin of the n-car plant.

:class:`BatchMultiCar` holds the states of B members of
:class:`~train_envs.plants.multi_car.TrainPlant` with the same number of cars ``n > 1``,
actuator order, dead-time buffer length, sub-step ``h`` and input mode (so the linear
model ``ż = A z + B w`` of :func:`train_envs.plants.actuator.linear_model` has the same
structure in every member); each member keeps its own train (car masses, Davis
coefficients, couplers, envelope), disturbances, Davis variation, gradient table,
dead-time buffer, state and seed-driven randomness. :meth:`BatchMultiCar.step`
advances every active member by the same duration with its own command.

Equations: those of :mod:`train_envs.plants.multi_car` (the cascade of mass points with
coupler forces and actuators; Davis resistance, gradient and disturbances as the
nonlinear part, :mod:`train_envs.plants.nonlinear`), integrated by the ETD2 sub-steps of
:mod:`train_envs.plants.integrator` with the breakpoint corrections and the standstill
rule of :mod:`train_envs.plants.crossing` and the work integrals of
:mod:`train_envs.plants.energy`.  One sub-step of a moving member::

    a     = Φ z + Γ w + P1 (N(z, t) + c)             P1 = h φ1(Ah), P2 = h φ2(Ah) on the
    z_+   = a + P2 (N(a, t + h) − N(z, t) + l)       speed rows; c, l: breakpoint jumps

(a held member: ``N ≡ 0``, then its positions are kept and its speeds set to zero).

Batched (array operations over the members; the state is the stack ``Z``, ``(B, n_z)``):

* the linear part: ``Φ z``, ``Γ w``, ``P1 n``, ``P2 n`` and the read-out ``A z``, each as
  one ``np.matmul`` of the matrices (a shared ``(1, r, c)`` copy where every member has
  the same bits, a ``(B, r, c)`` stack otherwise) with the ``(B, c, 1)`` stack of the
  vectors.  numpy runs that product as one BLAS ``gemv`` per member, the call of the
  single plant's ``M.dot(z)``; :func:`batched_matvec_exact` checks that on this BLAS
  (once per matrix shape) and the population falls back to one ``M.dot(z)`` per member
  where it does not hold;
* the nonlinear term on ``(B, n)`` arrays (Davis law and its sign, the gradient
  table's segment by ``searchsorted`` and its value, disturbance and Davis-variation
  terms); the segment test for breakpoint crossings; the split and saturation of the
  commands; the dead-time buffers ``(B, n_buf, n)``; the breakaway test of held members
  and the stop test of moving ones; the traction/braking work (the car powers summed in
  the order of :func:`~train_envs.plants.energy.power_sums`, see :func:`row_np_sum`);
* the Davis-variation deviations ``δ(t)`` of a step's sub-step times (one ``np.sin``
  over all members and times, where :func:`batched_sin_exact` confirms that numpy's
  sine gives the bits of the single plant's three-element call; else per member).

Per member (Python, the single plant's own code or calls):

* the disturbance sums at a step's ``k + 1`` sub-step times (each member's own
  disturbance objects; the single plant evaluates them ``2k`` times);
* a sub-step in which a car crosses a breakpoint of the gradient table
  (:func:`train_envs.plants.crossing.jump_corrections` on the member's plant) and the
  sub-step in which a moving member is brought to a standstill (the state at the stop
  instant τ inside the sub-step, a fresh ETD2 step of length τ as
  :func:`train_envs.plants.crossing.stop_inside`): rare events.

Tolerance: none.  Every array operation is the IEEE operation of the single plant's
float path, in the same order (numpy's element-wise ``+ − × ÷`` round like Python's),
and the matrix products are the same BLAS calls, so every member equals its single
plant stepped alone bit for bit: times, positions, speeds, actuator states, forces,
coupler forces, accelerations, work, held flags, commands and saturation flags (tested;
the measured deviation is 0).

Not batched (rejected, with the reason from :func:`why_not_batchable_multi`): a
gradient given as an arbitrary callable (only a
:class:`~train_envs.plants.lookup.PiecewiseLinear` table or a level track: a callable's
breakpoints are unknown and the single plant steps it on another path) and single-car
plants (:class:`~train_envs.plants.batch.BatchSingleCar` twins those).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from train_envs.plants.batch import members_envelope
from train_envs.plants.crossing import jump_corrections
from train_envs.plants.integrator import ETD2Integrator
from train_envs.plants.lookup import PiecewiseLinear
from train_envs.plants.multi_car import TrainPlant
from train_envs.plants.resistance import DavisVariation

__all__ = [
    "BatchMultiCar",
    "batchable_multi",
    "batched_matvec_exact",
    "batched_sin_exact",
    "row_np_sum",
    "why_not_batchable_multi",
]


# ------------------------------------------------------------------- helpers
def row_np_sum(X: np.ndarray) -> np.ndarray:
    """:func:`~train_envs.plants.energy.np_sum` (numpy's order of summation) of every row
    of ``X`` (``(B, n)``): the same additions on columns, so each result equals
    ``float(np.sum(X[b]))`` bit for bit.  Up to 7 terms left to right (a cumulative
    sum, which numpy computes strictly in order), up to 128 in 8 interleaved partial
    sums combined pairwise."""
    B, n = X.shape
    if n < 8:
        return np.cumsum(X, axis=1)[:, -1]
    if n > 128:
        return np.array([np.sum(row) for row in X], dtype=float)
    m = n - n % 8
    r = np.cumsum(X[:, :m].reshape(B, m // 8, 8), axis=1)[:, -1, :]  # r_j, j = 0..7
    r = r[:, 0::2] + r[:, 1::2]  # (r0 + r1), (r2 + r3), (r4 + r5), (r6 + r7)
    res = (r[:, 0] + r[:, 1]) + (r[:, 2] + r[:, 3])
    for i in range(m, n):
        res += X[:, i]
    return res


def _matmul_vec(M: np.ndarray, X: np.ndarray) -> np.ndarray:
    """``M[b] @ X[b]`` for every row (``M``: ``(1 or B, r, c)``, ``X``: ``(B, c)``)."""
    return np.matmul(M, np.ascontiguousarray(X)[:, :, None])[:, :, 0]


def _loop_vec(M: np.ndarray, X: np.ndarray) -> np.ndarray:
    """:func:`_matmul_vec` as one ``M.dot(x)`` per member (the single plant's calls)."""
    X = np.ascontiguousarray(X)
    if M.shape[0] == 1:
        m0 = M[0]
        return np.array([m0.dot(x) for x in X])
    return np.array([m.dot(x) for m, x in zip(M, X, strict=True)])


def _same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    return a.shape == b.shape and bool(np.all(a.view(np.int64) == b.view(np.int64)))


_EXACT: dict[tuple, bool] = {}


def batched_matvec_exact(M: np.ndarray, members: int = 9) -> bool:
    """Whether the stacked product of the matrices ``M`` (``(1 or B, r, c)``) gives the
    bits of ``M[b].dot(x)``, the single plant's product, on this numpy and BLAS:
    checked on random vectors of widely spread magnitudes (BLAS picks its kernel by
    the dimensions and strides, not by the values; cached per shape)."""
    M = np.ascontiguousarray(M, dtype=float)
    key = (M.shape[0] == 1, M.shape[1], M.shape[2])
    hit = _EXACT.get(key)
    if hit is None:
        rng = np.random.default_rng(12345)
        nb = max(members, M.shape[0]) if M.shape[0] == 1 else M.shape[0]
        hit = True
        for _ in range(3):
            X = rng.normal(size=(nb, M.shape[2])) * 10.0 ** rng.uniform(-4, 6, (nb, M.shape[2]))
            hit = hit and _same_bits(_matmul_vec(M, X), _loop_vec(M, X))
        _EXACT[key] = hit
    return hit


_SIN: list[bool] = []


def batched_sin_exact() -> bool:
    """Whether ``np.sin`` of a ``(N, 3)`` array gives, row by row, the bits of ``np.sin``
    of each three-element row (the single plant's :meth:`DavisVariation.deltas`)."""
    if not _SIN:
        rng = np.random.default_rng(54321)
        X = rng.uniform(-10.0, 3000.0, (4096, 3)) * 10.0 ** rng.uniform(-3, 1, (4096, 1))
        rows = np.array([np.sin(x) for x in X])
        _SIN.append(_same_bits(np.sin(X), rows) and _same_bits(np.sin(X[:5]), rows[:5]))
    return _SIN[0]


def why_not_batchable_multi(plant: TrainPlant) -> str | None:
    """Why :class:`BatchMultiCar` cannot hold ``plant`` (None: it can)."""
    if not isinstance(plant, TrainPlant):
        return f"not a TrainPlant: {type(plant).__name__}"
    if plant.n < 2:
        return "a single-car plant (n_cars = 1): plants.batch.BatchSingleCar twins those"
    g = plant.gradient_permil
    if g is not None and type(g) is not PiecewiseLinear:
        return (
            "its gradient is a callable, not a PiecewiseLinear table (the breakpoints are "
            "unknown and the single plant steps it on another path)"
        )
    return None


def batchable_multi(plant: TrainPlant) -> bool:
    """Whether ``plant`` can be a member of a :class:`BatchMultiCar`: a multi-car
    :class:`TrainPlant` with a gradient table or a level track (any actuator order,
    dead time, input mode, disturbances and Davis variation)."""
    return why_not_batchable_multi(plant) is None


def _structure(p: TrainPlant) -> tuple:
    """What the members of one population share."""
    return (p.n, p.actuator.order, p.nz, p._buffer.shape[0], p.h, p.input_mode,
            p.gradient_permil is None)  # fmt: skip


def _matrices(p: TrainPlant) -> tuple[np.ndarray, ...]:
    """Φ, Γ, P1, P2 of the plant's integrator and its A (the acceleration read-out)."""
    ig = p._integ
    return ig.Phi, ig.Gamma, ig.P1, ig.P2, p.A


_TWO_PI = 2 * math.pi  # (DavisVariation.deltas: 2 * math.pi * t / T, left to right)


# ------------------------------------------------------------------- the batch
class BatchMultiCar:
    """B multi-car plants (:func:`batchable_multi`) as one population.

    Args:
        plants: the members (reset, or stepped: their state is read as it is); they
            must share the number of cars, actuator order, dead-time buffer length,
            sub-step ``h``, input mode and whether they have a gradient table.  The
            plants themselves are not stepped: they lend their constants, gradient
            tables, disturbances and Davis variation (pure functions of time once
            reset); :meth:`sync_plant` writes a member's state back into its plant.
    """

    def __init__(self, plants: Sequence[TrainPlant]) -> None:
        if not plants:
            raise ValueError("plants must hold at least one plant")
        p0 = plants[0]
        for i, p in enumerate(plants):
            why = why_not_batchable_multi(p)
            if why is not None:
                raise ValueError(f"plants[{i}] is not batchable: {why}")
            if _structure(p) != _structure(p0):
                raise ValueError(
                    f"plants[{i}] differs from plants[0] in cars, actuator order, dead time, "
                    "step, input mode or gradient table presence"
                )
        self.plants = list(plants)
        self.B = B = len(plants)
        self.n = n = p0.n
        self.order = p0.actuator.order
        self.nz = p0.nz
        self.h = p0.h
        self.nb = p0._buffer.shape[0]
        self.input_mode = p0.input_mode
        self.has_tab = p0.gradient_permil is not None
        # per-member constants: rows of (B, n) or (B,) arrays
        for name in ("M", "MI", "CA", "CB", "CC", "MG", "OFF", "SHARE", "MCC"):
            setattr(self, name, np.zeros((B, n)))
        for name in ("MSUM", "CASUM", "KC", "DC", "HOLD", "ACC"):
            setattr(self, name, np.zeros(B))
        self._hd = np.zeros(B, dtype=bool)  # the members with disturbances
        self._hdv = np.zeros(B, dtype=bool)  # the members with a Davis variation
        # the state
        self.Z = np.zeros((B, self.nz))
        self._t = np.zeros(B)
        self._stopped = np.zeros(B, dtype=bool)
        self.PL = np.zeros((B, n))  # the last sub-step's car powers F_i v_i
        self.WNOW = np.zeros((B, n))  # the input applied now (after the dead time)
        #: the saturated command per car [N] applied by the last step, ``(B, n)``
        self.last_command = np.zeros((B, n))
        #: whether the last step's command was clipped to the envelope
        self.saturated = np.zeros(B, dtype=bool)
        #: the members' traction and braking work [J]
        self.work_traction_J = np.zeros(B)
        self.work_brake_J = np.zeros(B)
        self.BUF = np.zeros((B, self.nb, n))
        self.heads = np.zeros(B, dtype=np.int64)
        self._set_matrices()
        for b, p in enumerate(self.plants):
            self._set_member(b, p)
        self._update_groups()

    # ------------------------------------------------------------- members
    def _set_matrices(self) -> None:
        """Φ, Γ, P1, P2, A: one shared copy where every member has the same bits, else a
        stack; and the product that gives the single plant's bits."""
        per = [_matrices(p) for p in self.plants]
        mats = []
        for j in range(len(per[0])):
            m0 = per[0][j]
            if all(x[j].tobytes() == m0.tobytes() for x in per):
                mats.append(np.ascontiguousarray(m0)[None])
            else:
                mats.append(np.ascontiguousarray(np.stack([x[j] for x in per])))
        self._mats = mats
        #: whether every member has the same linear model (one copy of the matrices)
        self.shared_matrices = all(m.shape[0] == 1 for m in mats)
        #: whether the products run as stacked matmuls (else one ``dot`` per member)
        self.stacked_products = all(batched_matvec_exact(m) for m in mats)
        self._mv = _matmul_vec if self.stacked_products else _loop_vec

    def _set_member(self, b: int, p: TrainPlant) -> None:
        nl = p._nl
        n = self.n
        self.M[b], self.MI[b] = p.m, p.m_inertial
        self.CA[b], self.CB[b], self.CC[b] = p.ca, p.cb, p.cc
        self.MG[b], self.OFF[b], self.SHARE[b] = p._mg, p._offsets, p.share
        self.MSUM[b] = nl.m_sum
        # δc multiplies the whole mass on the lead car alone (aero term there), else m_i
        self.MCC[b] = p.m
        if p.lead_aero:
            self.MCC[b] = 0.0
            self.MCC[b, 0] = nl.m_sum
        self.CASUM[b] = float(np.sum(p.ca))
        self.KC[b], self.DC[b] = p.k, p.d
        self.HOLD[b] = p.HOLD_SPEED_MPS
        self.ACC[b] = p._acc_coef
        self._hd[b] = bool(p.disturbances)
        self._hdv[b] = p.davis_variation is not None
        # the state, as the plant holds it
        self.Z[b] = p.z
        self._t[b] = p.t
        self._stopped[b] = p.stopped
        pl = p._p_last
        self.PL[b] = [pl] * n if type(pl) is float else np.asarray(pl, dtype=float)
        self.WNOW[b] = p._forces_input()
        self.last_command[b] = p.last_command
        self.saturated[b] = p.saturated
        self.work_traction_J[b] = p.work_traction_J
        self.work_brake_J[b] = p.work_brake_J
        self.BUF[b] = p._buffer
        self.heads[b] = p._head

    def _update_groups(self) -> None:
        tabs: dict[int, list[int]] = {}
        trains: dict[int, list[int]] = {}
        for i, p in enumerate(self.plants):
            if self.has_tab:
                tabs.setdefault(id(p.gradient_permil), []).append(i)
            trains.setdefault(id(p.train), []).append(i)
        self._tab_groups = [(self.plants[ix[0]].gradient_permil, ix) for ix in tabs.values()]
        self._train_groups = [(self.plants[ix[0]].train, np.array(ix)) for ix in trains.values()]
        #: the one gradient table of every member (None: several, or none)
        self.table = self._tab_groups[0][0] if len(self._tab_groups) == 1 else None
        # the members whose Davis deviations are computed as arrays (DavisVariation's
        # sinusoid, where np.sin over many rows keeps the bits), the others by call
        vec = batched_sin_exact()
        self._dv_arr = np.zeros(self.B, dtype=bool)
        self._dv_period = np.ones(self.B)
        self._dv_phase = np.zeros((self.B, 3))
        self._dv_delta = np.zeros((self.B, 3))
        for b, p in enumerate(self.plants):
            d = p.davis_variation
            if vec and type(d) is DavisVariation and d.mode == "sinusoid":
                self._dv_arr[b] = True
                self._dv_period[b] = d.period_s
                self._dv_phase[b] = d._phase
                self._dv_delta[b] = d.delta_c0, d.delta_c1, d.delta_c2
        #: whether any member has disturbances (resp. a Davis variation)
        self.has_dist = bool(self._hd.any())
        self.has_dv = bool(self._hdv.any())
        self._all_consts: _Consts | None = None

    def load(self, b: int, plant: TrainPlant) -> None:
        """Make member ``b`` the plant ``plant`` (its own train, disturbances, Davis
        variation, gradient table and state; the same structure as the population)."""
        why = why_not_batchable_multi(plant)
        if why is not None:
            raise ValueError(f"load: the plant is not batchable: {why}")
        if _structure(plant) != _structure(self.plants[b]):
            raise ValueError(
                "load: the plant differs in cars, actuator order, dead time, step, input mode "
                "or gradient table presence"
            )
        self.plants[b] = plant
        if not self.shared_matrices or any(
            m[0].tobytes() != x.tobytes() for m, x in zip(self._mats, _matrices(plant), strict=True)
        ):
            self._set_matrices()
        self._set_member(b, plant)
        self._update_groups()

    def sync_plant(self, b: int) -> TrainPlant:
        """Write member ``b``'s state into its plant (which then steps on alone exactly
        as the member would) and return the plant."""
        p = self.plants[b]
        p.z = self.Z[b].copy()
        p.t = float(self._t[b])
        p.stopped = bool(self._stopped[b])
        p._p_last = self.PL[b].tolist()
        p._w_now = self.WNOW[b].copy()
        p.last_command = self.last_command[b].copy()
        p.saturated = bool(self.saturated[b])
        p.work_traction_J = float(self.work_traction_J[b])
        p.work_brake_J = float(self.work_brake_J[b])
        p._buffer = self.BUF[b].copy()
        p._head = int(self.heads[b])
        return p

    # ------------------------------------------------------------- read-outs
    @property
    def t(self) -> np.ndarray:
        return self._t

    @property
    def s(self) -> np.ndarray:
        """Lead-car position of each member [m]."""
        return self.Z[:, 0]

    @property
    def v(self) -> np.ndarray:
        """Lead-car speed of each member [m/s]."""
        return self.Z[:, self.n]

    @property
    def stopped(self) -> np.ndarray:
        """Whether each member is held at standstill."""
        return self._stopped.copy()

    @property
    def positions(self) -> np.ndarray:
        """Track position of each car [m], ``(B, n)``."""
        return self.Z[:, : self.n] - self.OFF

    @property
    def speeds(self) -> np.ndarray:
        """Speed of each car [m/s], ``(B, n)``."""
        return self.Z[:, self.n : 2 * self.n].copy()

    @property
    def forces(self) -> np.ndarray:
        """Actual (post-actuator) force of each car [N], ``(B, n)``."""
        n = self.n
        return (self.WNOW if self.order == 0 else self.Z[:, 2 * n : 3 * n]).copy()

    @property
    def force(self) -> np.ndarray:
        """Actual total force of each member [N] (:attr:`TrainPlant.force_total`)."""
        return row_np_sum(self.forces)

    def coupler_deformations(self) -> np.ndarray:
        """Extension of each coupler beyond its rest length [m], ``(B, n − 1)``."""
        q = self.Z[:, : self.n]
        return q[:, :-1] - q[:, 1:]

    def coupler_forces(self) -> np.ndarray:
        """Coupler forces [N], tension positive, ``(B, n − 1)``."""
        v = self.Z[:, self.n : 2 * self.n]
        dq = self.coupler_deformations()
        return self.KC[:, None] * dq + self.DC[:, None] * (v[:, :-1] - v[:, 1:])

    def mechanical_energy_J(self) -> np.ndarray:
        """:meth:`TrainPlant.mechanical_energy_J` of each member [J]."""
        v = self.Z[:, self.n : 2 * self.n]
        ke = 0.5 * row_np_sum(self.MI * v * v)
        pe = 0.5 * self.KC * row_np_sum(self.coupler_deformations() ** 2)
        return ke + pe

    def coupler_extremes(self) -> tuple[np.ndarray, np.ndarray]:
        """Coupler force [N] and deformation [m] of largest magnitude of each member (the
        first on ties): :meth:`TrainPlant._coupler_extremes`."""
        f, q = self.coupler_forces(), self.coupler_deformations()
        r = np.arange(self.B)
        return f[r, np.argmax(np.abs(f), axis=1)], q[r, np.argmax(np.abs(q), axis=1)]

    def accel(self) -> np.ndarray:
        """Lead-car acceleration of each member [m/s²] (0 when held): the single plant's
        :attr:`TrainPlant.accel`, ``(A z)_n (+ B_n w) + N_1(z, t)``."""
        return self.accel_gradient()[0]

    def accel_gradient(self) -> tuple[np.ndarray, np.ndarray]:
        """``(accel(), gradient(s))``: the accelerations and the gradients [‰] at the
        members' lead-car positions (zeros without a table)."""
        n = self.n
        acc = self._mv(self._mats[4], self.Z)[:, n]
        if self.order == 0:
            acc = acc + self.ACC * self.WNOW[:, 0]
        c = self._consts(np.arange(self.B))
        wd, dv = self._series(c, self._t[:, None])
        coefs = None
        if c.any_dv:
            coefs = tuple(x[:, 0] for x in self._coefficients(c, dv))
        jg = self._grad(c, self.Z)
        nl = self._nonlinear(c, self.Z, jg, wd[:, 0], coefs)
        acc = np.where(self._stopped, 0.0, acc + nl[:, 0])
        g = jg[1][:, 0].copy() if jg is not None else np.zeros(self.B)
        return acc, g

    def lead_state(self, b: int) -> tuple[float, float, float, float]:
        """``(t, s, v, accel)`` of member ``b`` (:meth:`TrainPlant._lead_state`)."""
        return (float(self._t[b]), float(self.Z[b, 0]), float(self.Z[b, self.n]),
                float(self.accel()[b]))  # fmt: skip

    def single_train(self) -> object | None:
        """The train of every member (None where the members run on several)."""
        return self._train_groups[0][0] if len(self._train_groups) == 1 else None

    def envelope(self, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(−B(v), F(v))`` of each member's own (whole) train at its speed ``v``
        (vectorised :meth:`TrainParams.envelope_N`, as :meth:`BatchSingleCar.envelope`)."""
        return members_envelope(self._train_groups, np.asarray(v, dtype=float))

    # ------------------------------------------------------------- the model
    def _consts(self, ix: np.ndarray) -> _Consts:
        """The constants of the members ``ix`` (cached for the whole population)."""
        if ix.size == self.B:
            if self._all_consts is None:
                self._all_consts = _Consts(self, np.arange(self.B))
            return self._all_consts
        return _Consts(self, ix)

    def _series(self, c: _Consts, T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The disturbance sums ``(len, k + 1)`` and Davis deviations ``(len, k + 1, 3)``
        of the members of ``c`` at the times ``T`` (``(len, k + 1)``), each as its plant
        computes them (:meth:`NonlinearTerm.disturbance_sum`, :meth:`DavisVariation.deltas`)."""
        ix = c.ix
        wd = np.zeros(T.shape)
        dv = np.zeros((*T.shape, 3))
        if c.any_dist:
            for i in np.flatnonzero(c.hd[:, 0]).tolist():
                ts = T[i].tolist()
                sums = [0.0] * len(ts)  # w = 0.0; w += accel(t), in the disturbances' order
                for dist in self.plants[int(ix[i])].disturbances:
                    acc = dist.accel
                    sums = [w + acc(t) for w, t in zip(sums, ts, strict=True)]
                wd[i] = sums
        if c.any_dv:
            arr = self._dv_arr[ix]
            if arr.any():
                r = np.flatnonzero(arr)
                b = ix[r]
                # sin(2π t / T + φ_j) δ_j (DavisVariation.deltas, elementwise)
                arg = (_TWO_PI * T[r]) / self._dv_period[b][:, None]
                s = np.sin(arg[:, :, None] + self._dv_phase[b][:, None, :])
                dv[r] = s * self._dv_delta[b][:, None, :]
            for i in np.flatnonzero(c.hdv[:, 0] & ~arr).tolist():
                dvar = self.plants[int(ix[i])].davis_variation
                dv[i] = [dvar.deltas(t) for t in T[i].tolist()]
        return wd, dv

    @staticmethod
    def _grad(c: _Consts, Zs: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """Table segment and gradient [‰] under each car of the members of ``c`` (states
        ``Zs``): ``PiecewiseLinear`` on arrays, ``bisect_right − 1`` of the float path
        (``searchsorted`` past the sentinel); None without tables."""
        if not c.tabs:
            return None
        n = c.OFF.shape[1]
        X = Zs[:, :n] - c.OFF
        if len(c.tabs) == 1:
            tab, xs, _ = c.tabs[0]
            J = xs.searchsorted(X, side="right")
            return J, tab.y0[J] + tab.slope[J] * (X - tab.x[J])
        J = np.zeros(X.shape, dtype=np.int64)
        g = np.zeros(X.shape)
        for tab, xs, rows in c.tabs:
            x = X[rows]
            j = xs.searchsorted(x, side="right")
            J[rows] = j
            g[rows] = tab.y0[j] + tab.slope[j] * (x - tab.x[j])
        return J, g

    def _coefficients(self, c: _Consts, dv: np.ndarray) -> tuple[np.ndarray, ...]:
        """The Davis coefficients ``(a_i, b_i, c_i)`` of the members of ``c`` at the times
        of the deviations ``dv`` (``(len, k + 1, 3)``), each ``(len, k + 1, n)``:
        ``a_i + δa m_i``, ``b_i + δb m_i``, ``c_i + δc m_i`` (``c_1 + δc M`` on the lead car
        alone where the aerodynamic term sits there), as :meth:`NonlinearTerm.floats`."""
        out = []
        for j, (base, mult) in enumerate(((c.CA, c.M), (c.CB, c.M), (c.CC, c.MCC))):
            var = base[:, None, :] + dv[:, :, j : j + 1] * mult[:, None, :]
            if not c.all_dv:
                var = np.where(c.hdv[:, :, None], var, base[:, None, :])
            out.append(var)
        return tuple(out)

    def _nonlinear(
        self,
        c: _Consts,
        Zs: np.ndarray,
        jg: tuple[np.ndarray, np.ndarray] | None,
        wd: np.ndarray | None,
        coefs: tuple[np.ndarray, ...] | None,
        minus: np.ndarray | None = None,
    ) -> np.ndarray:
        """``N(z, t) (− minus)`` of the members of ``c`` (states ``Zs``, table segments and
        gradients ``jg``, disturbance sums ``wd`` and Davis coefficients ``coefs`` at their
        times, None: none or constant): :meth:`NonlinearTerm.floats` on arrays, the same
        operations per element."""
        n = self.n
        V = Zs[:, n : 2 * n]
        CA, CB, CC = (c.CA, c.CB, c.CC) if coefs is None else coefs
        pos = V >= 0.0
        # davis_signed_N: |v| (its v if v >= 0 else −v differs from abs at v = −0 only,
        # where a + b (∓0) + c (∓0)(∓0) has the same bits unless a is −0: c.abs_ok)
        av = np.abs(V) if c.abs_ok else np.where(pos, V, -V)
        f = CA + CB * av + CC * av * av
        f = np.where(pos, f, -f)
        if jg is not None:
            f = f + c.MG * jg[1]
        if c.all_dist:
            f = f + c.M * wd[:, None]
        elif c.any_dist:
            f = np.where(c.hd, f + c.M * wd[:, None], f)
        out = -f / c.MI
        if minus is not None:
            out -= minus
        return out

    def _breakaway(
        self, c: _Consts, z: np.ndarray, W: np.ndarray, jg, wd: np.ndarray
    ) -> np.ndarray:
        """:meth:`TrainPlant._breakaway` of the members of ``c``: whether the force exceeds
        the gradient force, the disturbances and the Davis constant terms."""
        n = self.n
        F = row_np_sum(W if self.order == 0 else z[:, 2 * n : 3 * n])
        grade = np.zeros(z.shape[0]) if jg is None else row_np_sum(c.MG * jg[1])
        if c.any_dist:
            grade = np.where(c.hd[:, 0], grade + c.MSUM * wd, grade)
        return F > grade + c.CASUM

    def _stop_inside(self, b: int, z: np.ndarray, w: np.ndarray, t: float, tau: float):
        """:func:`train_envs.plants.crossing.stop_inside` of member ``b`` from ``z`` at
        ``t`` (its plant's nonlinear term, a pure function of state and time)."""
        p = self.plants[b]
        n = self.n
        ig = ETD2Integrator(p.A, p.B, tau, nonlinear_rows=slice(n, 2 * n))
        n0 = p._nonlinear(z, t)
        a = ig.Phi.dot(z) + ig.Gamma.dot(w) + ig.P1.dot(n0)
        return a + ig.P2.dot(p._nonlinear(a, t + tau) - n0)

    # ------------------------------------------------------------- stepping
    def _commands(self, u, ix: np.ndarray) -> np.ndarray:
        """The commands of the members ``ix`` per car (:meth:`TrainPlant._split`)."""
        n = self.n
        u = np.asarray(u, dtype=float)
        if u.ndim == 0 or u.shape[0] != self.B:
            raise ValueError(f"u must hold one command per member ({self.B}), got {u.shape}")
        if u.ndim == 2 and u.shape[1] == 1:
            u = u[:, 0]
        ua = u[ix]
        if not np.isfinite(ua).all():
            raise ValueError("command u_N must be finite")
        if ua.ndim == 1:
            if self.input_mode == "total":
                return ua[:, None] * self.SHARE[ix]
            return np.repeat((ua / n)[:, None], n, axis=1)
        if ua.ndim == 2 and ua.shape[1] == n and self.input_mode == "per_car":
            return ua.copy()
        raise ValueError(f"u must be (B,) or, in 'per_car' input mode, (B, {n}); got {u.shape}")

    def step(self, u, duration_s: float, active: np.ndarray | None = None) -> None:
        """Apply the commands ``u`` [N] (held) for ``duration_s`` to the ``active`` members
        (a boolean mask; all if None); the others stay as they are.  ``u``: ``(B,)``, one
        per member (the whole train's force in ``"total"`` input mode, split evenly over
        the cars in ``"per_car"`` mode), or ``(B, n)`` per car in ``"per_car"`` mode."""
        if active is None:
            ix = np.arange(self.B)
        else:
            ix = np.flatnonzero(np.asarray(active, dtype=bool))
        if ix.size == 0:
            return
        k = self.plants[int(ix[0])]._substeps(duration_s)
        n, h = self.n, self.h
        Wc = self._commands(u, ix)
        # saturation: each car's share of its train's envelope at the lead car's speed
        # (the array form of the single plant's scalar envelope, equal to it bit for bit)
        lo, hi = self.envelope(np.abs(self.Z[:, n]))
        lo, hi = lo[ix], hi[ix]
        sh = self.SHARE[ix]
        LO = lo[:, None] * sh
        HI = hi[:, None] * sh
        Ws = np.where(Wc < LO, LO, Wc)
        Ws = np.where(Ws > HI, HI, Ws)
        self.saturated[ix] = (Ws != Wc).any(axis=1)
        self.last_command[ix] = Ws
        st = _Local(self, ix)
        c = st.c = self._consts(ix)
        # the sub-step times t_0 + j h (t += h, in order) and the time series there
        wd = coefs = None
        if c.any_dist or c.any_dv:
            steps = np.full((ix.size, k + 1), h)
            steps[:, 0] = st.t
            wd, dv = self._series(c, np.cumsum(steps, axis=1))
            if c.any_dv:
                coefs = self._coefficients(c, dv)
        mats = (
            self._mats
            if ix.size == self.B
            else [m if m.shape[0] == 1 else m[ix] for m in self._mats]
        )
        if self.nb == 1:
            st.W = Ws
            gw = self._mv(mats[1], Ws)
            for j in range(k):
                self._substep(st, mats, gw, wd, coefs, j)
        else:
            rows = np.arange(ix.size)
            buf, head = st.buf, st.head
            for j in range(k):
                buf[rows, head] = Ws  # write the command, read the one issued T_d ago
                head = (head + 1) % self.nb
                st.W = buf[rows, head]
                self._substep(st, mats, self._mv(mats[1], st.W), wd, coefs, j)
            st.head = head
        st.store(self)

    def _substep(self, st: _Local, mats, gw, wd, coefs, j: int) -> None:
        """Sub-step ``j`` of the members of ``st`` (:meth:`TrainPlant._substep`): ``gw =
        Γ w``, ``wd`` the disturbance sums and ``coefs`` the Davis coefficients at the
        step's sub-step times (None: none, constant)."""
        n, h = self.n, self.h
        c = st.c
        z, W = st.z, st.W
        Phi, _, P1, P2, _ = mats
        wd0 = wd1 = co0 = co1 = None
        if wd is not None:
            wd0, wd1 = wd[:, j], wd[:, j + 1]
        if coefs is not None:
            co0 = tuple(x[:, j] for x in coefs)
            co1 = tuple(x[:, j + 1] for x in coefs)
        jg0 = self._grad(c, z)
        stop = st.stop
        held = None
        if stop.any():
            stop &= ~self._breakaway(c, z, W, jg0, wd0)
            if stop.any():
                held = stop.copy()
        N0 = self._nonlinear(c, z, jg0, wd0, co0)
        if held is not None:  # held by the brakes: only the actuator states evolve
            N0[held] = 0.0
        a = self._mv(Phi, z)
        a += gw
        a += self._mv(P1, N0)
        jg1 = self._grad(c, a)
        dN = self._nonlinear(c, a, jg1, wd1, co1, N0)
        if held is not None:
            dN[held] = 0.0
        if jg0 is not None:  # a car on another table segment: the jump corrections
            cross = (jg1[0] != jg0[0]).any(axis=1)
            if held is not None:
                cross &= ~held
            if cross.any():
                J0, J1 = jg0[0], jg1[0]
                for i in np.flatnonzero(cross).tolist():
                    p = self.plants[int(c.ix[i])]
                    cj, dl = jump_corrections(
                        p, z[i], W[i], a[i], J0[i].tolist(), J1[i].tolist(), N0[i]
                    )
                    a[i] += p._integ.P1.dot(cj)
                    dN[i] += dl
        z_new = a + self._mv(P2, dN)
        # the traction and braking work (energy.power_sums: p = F v per car; the terms
        # |p0| + |p1| ± (p0 + p1) are never −0, so 0.0 + Σ is the plain running sum)
        F = W if self.order == 0 else z_new[:, 2 * n : 3 * n]
        p1 = F * z_new[:, n : 2 * n]
        p0 = st.pl
        tot = p0 + p1
        mag = np.abs(p0) + np.abs(p1)
        s_up = row_np_sum(mag + tot)
        s_down = row_np_sum(mag - tot)
        qh = 0.25 * h
        if held is None:
            st.wt += qh * s_up
            st.wb += qh * s_down
        else:
            moving = ~held
            st.wt = np.where(moving, st.wt + qh * s_up, st.wt)
            st.wb = np.where(moving, st.wb + qh * s_down, st.wb)
            p1[held] = 0.0
        st.pl = p1
        # the standstill rule (crossing.held_state), with the forces of the old state
        v_old = z[:, n]
        v_new = z_new[:, n]
        hold = c.HOLD
        may = (v_new < hold) | (v_new <= 0.0)  # (only these can be held now)
        if held is not None:
            may &= ~held
        if may.any():
            brk = row_np_sum(W if self.order == 0 else z[:, 2 * n : 3 * n]) <= c.CASUM
            c1 = may & (v_old > 0.0) & (v_new > 0.0) & (v_new < v_old) & brk
            c2 = may & ~c1 & (v_new <= 0.0)
            now = c1 | c2
            if now.any():
                rest = c2 & (v_old <= 0.0)  # left rest and rolled back: stays where it was
                z_new[rest, :n] = z[rest, :n]
                vo, vn, tl = v_old.tolist(), v_new.tolist(), st.t.tolist()
                hl, bl = hold.tolist(), brk.tolist()
                for i in np.flatnonzero(now & ~rest).tolist():
                    if c1[i]:  # crawling below the hold speed under braking
                        tau = h * max(vo[i] - hl[i], 0.0) / (vo[i] - vn[i])
                    else:  # the lead car's speed reaches zero inside the sub-step
                        target = hl[i] if vo[i] > hl[i] and bl[i] else 0.0
                        tau = h * (vo[i] - target) / (vo[i] - vn[i])
                    z_new[i] = self._stop_inside(int(c.ix[i]), z[i].copy(), W[i].copy(), tl[i], tau)
                z_new[now, n : 2 * n] = 0.0
                stop |= now
        if held is not None:
            z_new[held, :n] = z[held, :n]
            z_new[held, n : 2 * n] = 0.0
        st.z = z_new
        st.t = st.t + h


class _Consts:
    """The per-member constants of the members ``ix`` (rows gathered once per step)."""

    _NAMES = ("CA", "CB", "CC", "M", "MI", "MG", "OFF", "MCC", "MSUM", "CASUM", "HOLD")

    def __init__(self, bp: BatchMultiCar, ix: np.ndarray) -> None:
        self.ix = ix
        full = ix.size == bp.B
        for name in self._NAMES:
            arr = getattr(bp, name)
            setattr(self, name, arr if full else arr[ix])
        hd, hdv = bp._hd[ix], bp._hdv[ix]
        self.hd = hd[:, None]
        self.hdv = hdv[:, None]
        self.any_dist = bool(hd.any())
        self.all_dist = bool(hd.all())
        self.any_dv = bool(hdv.any())
        self.all_dv = bool(hdv.all())
        ca = self.CA
        self.abs_ok = not bool(np.any((ca == 0.0) & np.signbit(ca)))
        # the gradient tables: (table, its segment starts past the sentinel, rows)
        rows = {b: i for i, b in enumerate(ix.tolist())}
        self.tabs = []
        for tab, members in bp._tab_groups:
            r = [rows[b] for b in members if b in rows]
            if r:
                self.tabs.append((tab, np.ascontiguousarray(tab.x[1:]), np.array(r)))


class _Local:
    """The state of the members stepped by one :meth:`BatchMultiCar.step` (their rows,
    gathered once and stored back at the end)."""

    c: _Consts

    def __init__(self, bp: BatchMultiCar, ix: np.ndarray) -> None:
        self.ix = ix
        self.z = bp.Z[ix]
        self.t = bp._t[ix]
        self.stop = bp._stopped[ix]
        self.pl = bp.PL[ix]
        self.wt = bp.work_traction_J[ix]
        self.wb = bp.work_brake_J[ix]
        self.buf = bp.BUF[ix]
        self.head = bp.heads[ix]
        self.W = bp.WNOW[ix]

    def store(self, bp: BatchMultiCar) -> None:
        ix = self.ix
        bp.Z[ix] = self.z
        bp._t[ix] = self.t
        bp._stopped[ix] = self.stop
        bp.PL[ix] = self.pl
        bp.work_traction_J[ix] = self.wt
        bp.work_brake_J[ix] = self.wb
        bp.BUF[ix] = self.buf
        bp.heads[ix] = self.head
        bp.WNOW[ix] = self.W
