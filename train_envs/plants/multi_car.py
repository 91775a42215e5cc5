"""Multi-car (cascade mass-point) train with spring/damper couplers and actuator dynamics.

Equations (papers 000 eq. 1–3, 002 eq. 1–4, 003 eq. 1–5; cars numbered from the front,
i = 1..n, coupler j joins car j and car j+1)::

    ẋ_i = v_i
    m_i (1 + ρ) v̇_i = F_i + f_{i−1} − f_i − R_i(v_i) − m_i g θ(x_i)/1000 − m_i w(t)
    f_j = k (x_j − x_{j+1} − L) + d (v_j − v_{j+1})        (coupler force, tension > 0)

with f_0 = f_n = 0, L the rest spacing (coupler rest length + car length), R_i the
per-car Davis resistance (split in proportion to mass, or with the aerodynamic
``c v²`` term on the lead car only, as 002 and 003 assume), θ the equivalent gradient
(gradient + curves) under car i and w(t) a per-unit-mass disturbance.  The actuator
F_i (ideal, first or second order, with dead time T_d) follows
:mod:`train_envs.plants.actuator`; the commanded force is saturated by the car's share
of the traction/braking envelope (:meth:`train_envs.trains.TrainParams.max_traction_N`).

The couplers, kinematics and actuators form the linear part and are integrated
exactly (matrix exponential); Davis, gradient and disturbances are the nonlinear part
(:mod:`train_envs.plants.nonlinear`), integrated to second order (see
:mod:`train_envs.plants.integrator`). The simulation step ``dt_sim_s`` is independent
of the control period: :meth:`TrainPlant.step` advances by any multiple of it with the
command held.

Braking to a standstill: when the lead car's speed crosses zero the train is held
(brakes hold a stopped train); the crossing point is found inside the sub-step
(:func:`train_envs.plants.crossing.held_state`) so that the stopping position is
accurate to well under a millimetre. It moves again
when the net tractive force exceeds the gradient force, the disturbances and the Davis
constant term; a held train never leaves rest backwards.

Breakpoints: a sub-step whose predictor puts a car on another segment of the gradient
table (a gradient step, a curve start, a curve-resistance cut-off) takes the jump of
the gradient force at the instant the car reaches the breakpoint into account
(:mod:`train_envs.plants.crossing`), so the integrator stays second order across the
jumps of the nonlinear term; the Davis law of a train leaving rest acts forward from
its first sub-step.

The single-point train steps through one registered scalar loop
(:mod:`train_envs.plants.single_car`, compiled where numba is available); several
cars evaluate the nonlinear term and the energy integrals on Python floats around the
BLAS matrix products.  Every path performs the same IEEE operations in the same order
as the array formulation.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from collections.abc import Sequence

import numpy as np

from train_envs._jit import implementation
from train_envs.plants.actuator import ActuatorParams, linear_model
from train_envs.plants.crossing import held_state, jump_corrections
from train_envs.plants.energy import np_sum as _np_sum
from train_envs.plants.energy import power_sums
from train_envs.plants.integrator import ETD2Integrator
from train_envs.plants.lookup import PiecewiseLinear
from train_envs.plants.nonlinear import NonlinearTerm, Table
from train_envs.plants.physics import car_davis
from train_envs.plants.resistance import DavisVariation, Disturbance
from train_envs.plants.single_car import SINGLE_CAR_STEP
from train_envs.trains import G, TrainParams
from train_envs.validation import check_finite, check_nonnegative, check_range

__all__ = ["ActuatorParams", "TrainPlant", "_np_sum"]

_NO_DIST = np.zeros(1)  # placeholder array argument of the single-car step


class TrainPlant:
    """Cascade of ``n_cars`` mass points (n = 1 gives the single-point train).

    A train decelerating below ``HOLD_SPEED_MPS`` (1 cm/s) under a braking force is
    held at standstill (the holding brake of ATO stopping), which ends a stop that a
    controller would otherwise approach asymptotically.

    Args:
        train: physical parameters (``train.n_cars`` cars unless ``n_cars`` overrides).
        gradient_permil: callable s -> equivalent gradient [‰] (vectorised), e.g.
            ``track.equivalent_gradient_permil_at``; ``None`` for a level track.
        actuator: actuator dynamics and dead time.
        dt_sim_s: integration step; control periods must be multiples of it, and so must
            the dead time.
        disturbances: per-unit-mass resisting accelerations added on every car.
        davis_variation: bounded time variation of the Davis coefficients (002).
        input_mode: ``"total"`` (one command, the whole-train force, shared by mass) or
            ``"per_car"`` (one command per car).
        car_length_m: car length; the rest spacing is car length + coupler rest length.
    """

    HOLD_SPEED_MPS = 0.01

    def __init__(
        self,
        train: TrainParams,
        gradient_permil=None,
        *,
        n_cars: int | None = None,
        actuator: ActuatorParams | None = None,
        dt_sim_s: float = 0.01,
        disturbances: Sequence[Disturbance] = (),
        davis_variation: DavisVariation | None = None,
        input_mode: str = "total",
        car_length_m: float = 0.0,
    ) -> None:
        self.train = train
        n = train.n_cars if n_cars is None else int(n_cars)
        if n < 1:
            raise ValueError(f"n_cars must be >= 1, got {n_cars}")
        self.n = n
        self.actuator = actuator or ActuatorParams()
        self.h = check_range("dt_sim_s", dt_sim_s, 1e-5, 1.0)
        if input_mode not in ("total", "per_car"):
            raise ValueError(f"input_mode must be 'total' or 'per_car', got {input_mode!r}")
        self.input_mode = input_mode
        self.gradient_permil = gradient_permil
        self.disturbances = tuple(disturbances)
        self.davis_variation = davis_variation
        self.car_length_m = check_nonnegative("car_length_m", car_length_m)

        masses = np.array(train.car_masses if n == train.n_cars else (train.mass_kg / n,) * n)
        self.m = masses
        self.m_inertial = masses * (1.0 + train.rotating_mass_factor)
        self.share = masses / masses.sum()
        self.ca, self.cb, self.cc = car_davis(
            train.davis_a_N,
            train.davis_b_Ns_per_m,
            train.davis_c_Ns2_per_m2,
            self.share,
            train.lead_car_aero,
        )
        self.lead_aero = train.lead_car_aero
        self.k = train.coupler.stiffness_N_per_m
        self.d = train.coupler.damping_Ns_per_m
        self.spacing = train.coupler.rest_length_m + self.car_length_m

        delay_steps = self.actuator.dead_time_s / self.h
        if abs(delay_steps - round(delay_steps)) > 1e-6:
            raise ValueError(
                f"actuator.dead_time_s ({self.actuator.dead_time_s}) must be a multiple of "
                f"dt_sim_s ({self.h})"
            )
        self.delay_steps = int(round(delay_steps))

        self._nsub: dict[float, int] = {}  # sub-steps per step duration, validated
        self._build_linear()
        self.reset(0.0, 0.0)

    # ----------------------------------------------------------------- model
    def _build_linear(self) -> None:
        n, order = self.n, self.actuator.order
        A, B = linear_model(n, self.actuator, self.m_inertial, self.k, self.d)
        self.A, self.B = A, B
        self.nz = A.shape[0]
        iv = slice(n, 2 * n)
        self._integ = ETD2Integrator(A, B, self.h, nonlinear_rows=iv)
        self._zero_nl = np.zeros(n)
        self._offsets = np.arange(n) * self.spacing
        self._mg = self.m * (G / 1000.0)
        self._nl = NonlinearTerm(
            self.m,
            self.m_inertial,
            (self.ca, self.cb, self.cc),
            self.lead_aero,
            self._offsets,
            self._mg,
            self.disturbances,
            self.davis_variation,
        )
        self._nl_buf = np.zeros(1)
        self._share0 = float(self.share[0])
        self._share_l = self.share.tolist()
        self._nl_arr = np.zeros(n)  # work array of the multi-car float path
        self._grad_src: object = None
        self._grad_lists: Table | None = None
        # the lead car's acceleration read-out of a single car needs no matrix product:
        # its row of [A B] has one non-zero entry (m'^-1 on the force state, or on the
        # input for an ideal actuator), the other products being exact zeros
        self._lead_fast = n == 1 and self.davis_variation is None
        self._acc_coef = float(A[n, 2 * n]) if order else float(B[n, 0])
        # the single-car step (layout of its constants: plants.single_car.C_*)
        self._scalar_ok = n == 1 and self.davis_variation is None and self.actuator.order < 2
        self._kern = implementation(SINGLE_CAR_STEP)
        nl, ig = self._nl, self._integ
        self._kconst = np.concatenate(
            [
                [self.h, nl.a0, nl.b0, nl.c0, nl.mg0, nl.m0, nl.minv0],
                [self.HOLD_SPEED_MPS],
                ig.Phi.ravel(),
                ig.Gamma[:, 0],
                ig.P1[:, 0],
                ig.P2[:, 0],
            ]
        )

    def _grad_table(self) -> Table | None:
        """``(x, y0, slope)`` lists of the gradient look-up when it is a :class:`PiecewiseLinear`.

        The float paths evaluate that table in place (bisect on the lists, exactly what
        ``PiecewiseLinear.__call__`` does for one point); any other callable is called.
        """
        g = self.gradient_permil
        if g is not self._grad_src:
            self._grad_src = g
            self._grad_lists = (g._xl, g._y0l, g._sl) if type(g) is PiecewiseLinear else None
        return self._grad_lists

    def _nonlinear(self, z: np.ndarray, t: float) -> np.ndarray:
        """Nonlinear accelerations (rows of the speeds): −(Davis + gradient + w)/m'."""
        n = self.n
        if n == 1 and self.davis_variation is None:
            out = self._nl_buf
            out[0] = self._nl.single(float(z[0]), float(z[1]), t, self.gradient_permil)
            return out.copy()
        tab = self._grad_table()
        if self.gradient_permil is None or tab is not None:
            return np.array(self._nl_floats(z.tolist(), t, n))
        return self._nl.array(z, t, self.gradient_permil)

    def _nl_floats(
        self, z: list[float], t: float, cars: int, minus: list[float] | None = None
    ) -> list[float]:
        """:meth:`NonlinearTerm.floats` with this plant's gradient table (or none)."""
        tab = self._grad_table() if self.gradient_permil is not None else None
        return self._nl.floats(z, t, cars, tab, minus)

    # ------------------------------------------------------------- interface
    def reset(
        self,
        s0: float,
        v0: float,
        *,
        t0: float = 0.0,
        u0: float | Sequence[float] = 0.0,
        rng: np.random.Generator | None = None,
        speeds_mps: Sequence[float] | None = None,
    ) -> None:
        """Place the lead car at ``s0`` [m] with all cars at speed ``v0`` [m/s].

        The couplers start undeformed; the actuator starts at force ``u0`` (total or
        per car, as ``input_mode``) and the dead-time buffer is filled with it.
        ``speeds_mps`` optionally gives each car its own initial speed.
        """
        check_finite("s0", s0)
        check_range("v0", v0, 0.0, 200.0)
        rng = rng if rng is not None else np.random.default_rng()
        for dist in self.disturbances:
            dist.reset(rng)
        if self.davis_variation is not None:
            self.davis_variation.reset(rng)
        n = self.n
        z = np.zeros(self.nz)
        z[:n] = s0  # shifted coordinates: all equal when undeformed
        z[n : 2 * n] = v0
        if speeds_mps is not None:
            sp = np.asarray(speeds_mps, dtype=float).reshape(-1)
            if sp.size != n or not np.all(np.isfinite(sp)) or np.any(sp < 0):
                raise ValueError(f"speeds_mps must be {n} finite non-negative speeds, got {sp}")
            z[n : 2 * n] = sp
        w0 = self._split(u0)
        if self.actuator.order >= 1:
            z[2 * n : 3 * n] = w0
        self.z = z
        self.t = float(t0)
        self._buffer = np.tile(w0, (self.delay_steps + 1, 1))
        self._head = 0
        self._w_now: np.ndarray | float = w0.copy()
        self.stopped = v0 <= 0.0
        self.work_traction_J = 0.0
        self.work_brake_J = 0.0
        # last sub-step's traction powers F_i v_i: an array, or (float paths) a list/float
        self._p_last: np.ndarray | list[float] | float = (
            self._forces(z) * z[n : 2 * n] if self.actuator.order else w0 * z[n : 2 * n]
        )
        self.last_command = w0.copy()
        self.saturated = False

    @property
    def last_command(self) -> np.ndarray:
        """Saturated command per car [N] applied by the last :meth:`step`."""
        lc = self._last_command
        if type(lc) is float:  # the single-car path stores the float
            lc = self._last_command = np.array([lc])
        return lc

    @last_command.setter
    def last_command(self, value: np.ndarray | float) -> None:
        self._last_command = value

    def _split(self, u: float | Sequence[float]) -> np.ndarray:
        if self.input_mode == "total":
            arr = np.asarray(u, dtype=float)
            if arr.size != 1:
                raise ValueError(f"command must be a scalar in 'total' input mode, got {arr.shape}")
            val = float(arr.reshape(-1)[0])
            if not math.isfinite(val):
                raise ValueError(f"command u_N must be finite, got {val}")
            return val * self.share
        arr = np.asarray(u, dtype=float).reshape(-1)
        if arr.size == 1:
            arr = np.full(self.n, arr[0] / self.n)
        if arr.size != self.n:
            raise ValueError(f"command must have n_cars={self.n} entries, got {arr.size}")
        if not all(map(math.isfinite, arr.tolist())):  # (np.isfinite(arr).all(), cheaper)
            raise ValueError("command u_N must be finite")
        return arr

    def saturate(self, w: np.ndarray) -> np.ndarray:
        """Clip per-car commands to each car's share of the traction/brake envelope."""
        v = abs(float(self.z[self.n]))
        if type(w) is np.ndarray and w.shape == (self.n,):
            # per car on floats: lo_i = −B(v) share_i, hi_i = F(v) share_i,
            # out_i = min(max(w_i, lo_i), hi_i), as the array expressions below
            hi = self.train.max_traction_N(v)
            lo = -self.train.max_brake_N(v)
            out = []
            sat = False
            for wi, sh in zip(w.tolist(), self._share_l, strict=True):
                lo_i = lo * sh
                hi_i = hi * sh
                o = lo_i if wi < lo_i else wi
                if o > hi_i:
                    o = hi_i
                if o != wi:
                    sat = True
                out.append(o)
            self.saturated = sat
            return np.array(out)
        hi = self.train.max_traction_N(v) * self.share
        lo = -self.train.max_brake_N(v) * self.share
        out = np.minimum(np.maximum(w, lo), hi)
        self.saturated = bool(np.any(out != w))
        return out

    def _saturate_single(self, u: float | Sequence[float], v: float) -> float:
        """:meth:`_split` + :meth:`saturate` of a single car on floats (speed ``v``)."""
        if self.input_mode == "total" and isinstance(u, (float, int, np.floating, np.integer)):
            val = float(u)
            if not math.isfinite(val):
                raise ValueError(f"command u_N must be finite, got {val}")
            val = val * self._share0
        else:
            val = float(self._split(u)[0])
        v = abs(v)
        env = self.train.envelope  # (TrainParams.max_traction_N, max_brake_N)
        hi = env.traction_N(v) * self._share0
        lo = -env.brake_N(v) * self._share0
        out = lo if val < lo else val  # np.maximum(val, lo)
        if out > hi:  # np.minimum(., hi)
            out = hi
        self.saturated = out != val
        return out

    def _substeps(self, duration_s: float) -> int:
        """Number of sub-steps in ``duration_s`` (validated once per distinct duration)."""
        k = self._nsub.get(duration_s)
        if k is None:
            nsub = duration_s / self.h
            k = int(round(nsub))
            if k < 1 or abs(nsub - k) > 1e-6:
                raise ValueError(
                    f"duration_s ({duration_s}) must be a positive multiple of dt_sim_s ({self.h})"
                )
            self._nsub[duration_s] = k
        return k

    def step(self, u: float | Sequence[float], duration_s: float) -> None:
        """Apply command ``u`` [N] (held) for ``duration_s`` (a multiple of ``dt_sim_s``)."""
        k = self._substeps(duration_s)
        if self._scalar_ok and (self.gradient_permil is None or self._grad_table() is not None):
            z = self.z.tolist()
            w = self._saturate_single(u, z[1])
            self.last_command = w
            self._run_single(w, k, z)
            return
        w_cmd = self.saturate(self._split(u))
        self.last_command = w_cmd
        buf = self._buffer
        nb = buf.shape[0]
        if nb == 1:
            # no dead time: the input is held over the k sub-steps, Γ w is computed once
            self._w_now = w_cmd
            gw = self._integ.Gamma.dot(w_cmd)
            wl = w_cmd.tolist()
            for _ in range(k):
                self._substep(w_cmd, gw, wl)
            return
        for _ in range(k):
            # dead-time buffer: write the current command, read the one issued T_d ago
            buf[self._head] = w_cmd
            w = buf[(self._head + 1) % nb]
            self._head = (self._head + 1) % nb
            self._w_now = w
            self._substep(w)

    def _run_single(self, w_cmd: float, k: int, z: list[float] | None = None) -> None:
        """Single-car fast path of :meth:`step`: the registered single-car step
        (:mod:`train_envs.plants.single_car`, compiled where available).  The
        single-point train is the most simulated plant (every tuning evaluation and RL
        rollout of the point-mass scenarios); at three states numpy's per-call overhead
        dominates the general path.  Needs the gradient as a table (or none): see
        :meth:`step`."""
        order = self.actuator.order
        if z is None:
            z = self.z.tolist()
        pl = self._p_last
        st = np.array(
            [
                z[0],
                z[1],
                z[2] if order else 0.0,
                self.t,
                pl if type(pl) is float else float(pl[0]),
                1.0 if self.stopped else 0.0,
                w_cmd,
                0.0,
                0.0,
            ]
        )
        dists = self.disturbances
        wd = _NO_DIST
        if dists:  # the sums the loop adds at t_0 + j h (the times it reaches by t += h)
            tj, h = self.t, self.h
            sums = []
            for _ in range(k + 1):
                sums.append(self._nl.disturbance_sum(tj))
                tj += h
            wd = np.array(sums)
        g = self.gradient_permil
        tab = (g.x, g.y0, g.slope) if g is not None else (_NO_DIST,) * 3
        self._head = self._kern(
            st,
            self._buffer[:, 0],
            self._head,
            k,
            order,
            self._kconst,
            *tab,
            g is not None,
            wd,
            bool(dists),
        )
        z0, z1, z2, t, p_last, stopped, w, wt, wb = st.tolist()
        self.z = np.array([z0, z1, z2] if order else [z0, z1])
        self.t = t
        self.stopped = stopped != 0.0
        self._w_now = w
        self._p_last = p_last
        self.work_traction_J += wt
        self.work_brake_J += wb

    def _substep(
        self, w: np.ndarray, gw: np.ndarray | None = None, wl: list[float] | None = None
    ) -> None:
        """One ETD2 sub-step with input ``w`` (``gw = Γ w`` and ``wl = w.tolist()``
        optionally precomputed), energy bookkeeping and the standstill logic."""
        n, h = self.n, self.h
        z = self.z
        if self.stopped:
            if self._breakaway(w):
                self.stopped = False
            else:
                # held by the brakes: only the actuator states evolve
                z_new = self._integ.step(z, w, self.t, lambda _z, _t: self._zero_nl)
                z_new[:n] = z[:n]
                z_new[n : 2 * n] = 0.0
                self.z = z_new
                self.t += h
                self._p_last = np.zeros(n)
                return
        zl = z.tolist()
        grad = self.gradient_permil
        tab = self._grad_table() if grad is not None else None
        ig = self._integ
        t = self.t
        if grad is not None and tab is None:  # a callable: no breakpoints known
            z_new = ig.step(z, w, t, self._nonlinear, gw)
        elif self._lead_fast:
            # ETD2Integrator.step, with the predictor checked for a breakpoint crossing
            n0a = self._nonlinear(z, t)
            z_new = ig.Phi.dot(z) + (ig.Gamma.dot(w) if gw is None else gw) + ig.P1.dot(n0a)
            dn = self._nonlinear(z_new, t + h) - n0a
            if tab is not None:
                seg0 = bisect_right(tab[0], zl[0]) - 1
                seg1 = bisect_right(tab[0], float(z_new[0])) - 1
                if seg1 != seg0:
                    cj, dl = jump_corrections(self, z, w, z_new, [seg0], [seg1], n0a)
                    z_new = z_new + ig.P1.dot(cj)
                    dn = dn + dl
            z_new = z_new + ig.P2.dot(dn)
        else:
            # ETD2Integrator.step with the nonlinear term evaluated on floats (the same
            # matrix products and additions, in place where the operands are fresh)
            buf = self._nl_arr
            segs0: list[int] = []
            n0 = self._nl.floats(zl, t, n, tab, None, segs0)
            buf[:] = n0
            z_new = ig.Phi.dot(z)
            z_new += ig.Gamma.dot(w) if gw is None else gw
            z_new += ig.P1.dot(buf)  # z_new holds a here
            segs1: list[int] = []
            buf[:] = self._nl.floats(z_new.tolist(), t + h, n, tab, n0, segs1)  # n1 − n0
            if segs1 != segs0:
                cj, dl = jump_corrections(self, z, w, z_new, segs0, segs1, np.array(n0))
                z_new += ig.P1.dot(cj)
                buf += dl
            z_new += ig.P2.dot(buf)
        znl = z_new.tolist()
        v_old = zl[n]
        v_new = znl[n]
        # trapezoidal integration of the traction (F v > 0) and braking (F v < 0) powers
        if self.actuator.order == 0:
            if wl is None:
                w_now = self._w_now
                wl = [w_now] if type(w_now) is float else w_now.tolist()
            F = wl
        else:
            F = znl[2 * n : 3 * n]
        p0 = self._p_last
        if type(p0) is not list:
            p0 = [p0] if type(p0) is float else p0.tolist()
        p1, s_up, s_down = power_sums(p0, F, znl[n : 2 * n])
        self.work_traction_J += 0.25 * h * s_up
        self.work_brake_J += 0.25 * h * s_down
        self._p_last = p1
        held = held_state(self, z, z_new, w, v_old, v_new)
        if held is not None:
            z_new = held
            self.stopped = True
        self.z = z_new
        self.t += h

    def _forces(self, z: np.ndarray) -> np.ndarray:
        if self.actuator.order == 0:
            return self._forces_input()
        return z[2 * self.n : 3 * self.n]

    def _braking(self) -> bool:
        """True when the actual force is a braking force (or below the resistance)."""
        return float(np.sum(self._forces(self.z))) <= float(np.sum(self.ca))

    def _breakaway(self, w: np.ndarray) -> bool:
        """Whether a held train moves: the force exceeds gradient, disturbances and the
        Davis constant terms (a held train never leaves rest backwards)."""
        F = float(np.sum(w if self.actuator.order == 0 else self._forces(self.z)))
        grade = 0.0
        if self.gradient_permil is not None:
            x = self.z[: self.n] - self._offsets
            grade = float(np.sum(self.m * (G / 1000.0) * self.gradient_permil(x)))
        if self.disturbances:
            grade += self._nl.m_sum * self._nl.disturbance_sum(self.t)
        return F > grade + float(np.sum(self.ca))

    # ------------------------------------------------------------- read-outs
    @property
    def positions(self) -> np.ndarray:
        """Track position of each car [m] (lead car first)."""
        return self.z[: self.n] - self._offsets

    @property
    def speeds(self) -> np.ndarray:
        return self.z[self.n : 2 * self.n].copy()

    @property
    def s(self) -> float:
        """Lead-car position [m]."""
        return float(self.z[0])

    @property
    def v(self) -> float:
        """Lead-car speed [m/s]."""
        return float(self.z[self.n])

    @property
    def forces(self) -> np.ndarray:
        """Actual (post-actuator) force of each car [N]."""
        return np.array(self._forces(self.z), dtype=float)

    @property
    def force_total(self) -> float:
        return _np_sum(self._forces(self.z).tolist())  # float(np.sum(...))

    @property
    def accel(self) -> float:
        """Lead-car acceleration [m/s²] from the full model right now."""
        if self.stopped:
            return 0.0
        if self._lead_fast:
            return self._accel_single(self.z.tolist())
        z = self.z
        n = self.n
        # (A z + B w)[n]: the lead car's row of B has one entry, on its own input (ideal
        # actuator) or none, so B w contributes that product exactly, or zero
        dz = float(self.A.dot(z)[n])
        if self.actuator.order == 0:
            dz = dz + self._acc_coef * float(self._forces_input()[0])
        tab = self._grad_table()
        if self.gradient_permil is None or tab is not None:
            nl0 = self._nl_floats(z.tolist(), self.t, 1)[0]  # the lead car only
        else:
            nl0 = float(self._nonlinear(z, self.t)[0])
        return dz + nl0

    def _forces_input(self) -> np.ndarray:
        """The input currently applied (post dead time), as an array."""
        w = self._w_now
        if type(w) is float:  # stored by the single-car path
            w = self._w_now = np.array([w])
        return w

    def _accel_single(self, z: list[float]) -> float:
        """:attr:`accel` of a moving single car from its state list ``z``.

        ``A z + B w`` has one non-zero product in the speed row (see ``_acc_coef``), so
        the matrix products reduce exactly to that product.
        """
        if self.actuator.order:
            F = z[2]
        else:
            w = self._w_now
            F = w if type(w) is float else float(w[0])
        g = self.gradient_permil
        g = g.at if type(g) is PiecewiseLinear else g  # (the table at a float position)
        return self._acc_coef * F + self._nl.single(z[0], z[1], self.t, g)

    def _lead_state(self) -> tuple[float, float, float, float]:
        """``(t, s, v, accel)`` of the lead car: the scalar read-outs of one observation."""
        if self._lead_fast:
            z = self.z.tolist()
            return self.t, z[0], z[1], 0.0 if self.stopped else self._accel_single(z)
        z = self.z
        return self.t, float(z[0]), float(z[self.n]), self.accel

    def coupler_deformations(self) -> np.ndarray:
        """Extension of each coupler beyond its rest length [m] (n−1 values)."""
        q = self.z[: self.n]
        return q[:-1] - q[1:]

    def coupler_forces(self) -> np.ndarray:
        """Coupler forces [N], tension positive (n−1 values)."""
        v = self.z[self.n : 2 * self.n]
        return self.k * self.coupler_deformations() + self.d * (v[:-1] - v[1:])

    def mechanical_energy_J(self) -> float:
        """Kinetic energy (with rotating masses) + coupler spring energy [J]."""
        v = self.z[self.n : 2 * self.n]
        ke = 0.5 * float(np.sum(self.m_inertial * v * v))
        pe = 0.5 * self.k * float(np.sum(self.coupler_deformations() ** 2))
        return ke + pe

    def _coupler_extremes(self) -> tuple[float, float]:
        """Coupler force [N] and deformation [m] of largest magnitude (the first on ties).

        Floats for the runner's per-step record: the same values as
        ``cf[np.argmax(np.abs(cf))]`` of :meth:`coupler_forces` (resp. deformations).
        """
        n = self.n
        z = self.z.tolist()
        k, d = self.k, self.d
        f_max = q_max = 0.0
        a_f = a_q = -1.0
        for i in range(n - 1):
            q = z[i] - z[i + 1]
            f = k * q + d * (z[n + i] - z[n + i + 1])
            if abs(f) > a_f:
                f_max, a_f = f, abs(f)
            if abs(q) > a_q:
                q_max, a_q = q, abs(q)
        return f_max, q_max
