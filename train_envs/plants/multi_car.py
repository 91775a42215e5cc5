"""Multi-car (cascade mass-point) train with spring/damper couplers and actuator dynamics.

Equations (papers 000 eq. 1–3, 002 eq. 1–4, 003 eq. 1–5; cars numbered from the front,
i = 1..n, coupler j joins car j and car j+1)::

    ẋ_i = v_i
    m_i (1 + ρ) v̇_i = F_i + f_{i−1} − f_i − R_i(v_i) − m_i g θ(x_i)/1000 − m_i w(t)
    f_j = k (x_j − x_{j+1} − L) + d (v_j − v_{j+1})        (coupler force, tension > 0)

with f_0 = f_n = 0, L the rest spacing (coupler rest length + car length), R_i the
per-car Davis resistance (split in proportion to mass, or with the aerodynamic
``c v²`` term on the lead car only, as 002 and 003 assume), θ the equivalent gradient
(gradient + curves) under car i and w(t) a per-unit-mass disturbance.

Actuator of car i, input w_i (the commanded force, saturated by the car's share of the
traction/braking envelope and delayed by the dead time T_d)::

    order 0 (ideal):        F_i = w_i(t − T_d)
    order 1 (001 eq. 1–2):  τ Ḟ_i = −F_i + w_i(t − T_d)
    order 2 (003 §2.2):     F̈_i + 2ζω_n Ḟ_i + ω_n² F_i = ω_n² w_i(t − T_d)

The couplers, kinematics and actuators form the linear part and are integrated
exactly (matrix exponential); Davis, gradient and disturbances are the nonlinear part,
integrated to second order (see :mod:`train_envs.plants.integrator`). The simulation
step ``dt_sim_s`` is independent of the control period: :meth:`step` advances by any
multiple of it with the command held.

Braking to a standstill: when the lead car's speed crosses zero the train is held
(brakes hold a stopped train); the crossing point is interpolated inside the sub-step
so that the stopping position is accurate to well under a millimetre. It moves again
when the net tractive force exceeds the gradient force plus the Davis constant term.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from train_envs.plants.integrator import ETD2Integrator
from train_envs.plants.resistance import DavisVariation, Disturbance
from train_envs.trains import G, TrainParams
from train_envs.validation import check_finite, check_nonnegative, check_positive, check_range


@dataclass(frozen=True)
class ActuatorParams:
    """Traction/braking actuator: ideal (0), first-order lag (1) or second order (2) + dead time."""

    order: int = 0
    tau_s: float = 0.4
    dead_time_s: float = 0.0
    omega_n_radps: float = 2.0
    zeta: float = 0.8

    def __post_init__(self) -> None:
        if self.order not in (0, 1, 2):
            raise ValueError(f"actuator.order must be 0, 1 or 2, got {self.order}")
        if self.order == 1:
            check_positive("actuator.tau_s", self.tau_s)
        check_nonnegative("actuator.dead_time_s", self.dead_time_s)
        if self.order == 2:
            check_positive("actuator.omega_n_radps", self.omega_n_radps)
            check_positive("actuator.zeta", self.zeta)


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
        # per-car Davis coefficients
        if train.lead_car_aero:
            self.ca = train.davis_a_N * self.share
            self.cb = train.davis_b_Ns_per_m * self.share
            self.cc = np.zeros(n)
            self.cc[0] = train.davis_c_Ns2_per_m2
        else:
            self.ca = train.davis_a_N * self.share
            self.cb = train.davis_b_Ns_per_m * self.share
            self.cc = train.davis_c_Ns2_per_m2 * self.share
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

        self._build_linear()
        self.reset(0.0, 0.0)

    # ----------------------------------------------------------------- model
    def _build_linear(self) -> None:
        n, order = self.n, self.actuator.order
        nz = 2 * n + n * order
        A = np.zeros((nz, nz))
        B = np.zeros((nz, n))
        iv = slice(n, 2 * n)
        A[:n, iv] = np.eye(n)
        # couplers on the shifted coordinates q_i = x_i + (i-1) L (rest deformation zero)
        Kc = np.zeros((n, n))
        for j in range(n - 1):
            Kc[j, j] -= 1.0
            Kc[j, j + 1] += 1.0
            Kc[j + 1, j] += 1.0
            Kc[j + 1, j + 1] -= 1.0
        minv = 1.0 / self.m_inertial
        A[iv, :n] = (self.k * Kc) * minv[:, None]
        A[iv, iv] = (self.d * Kc) * minv[:, None]
        if order == 0:
            B[iv, :] = np.diag(minv)
        elif order == 1:
            iF = slice(2 * n, 3 * n)
            A[iv, iF] = np.diag(minv)
            A[iF, iF] = -np.eye(n) / self.actuator.tau_s
            B[iF, :] = np.eye(n) / self.actuator.tau_s
        else:
            iF = slice(2 * n, 3 * n)
            iFd = slice(3 * n, 4 * n)
            w = self.actuator.omega_n_radps
            A[iv, iF] = np.diag(minv)
            A[iF, iFd] = np.eye(n)
            A[iFd, iF] = -(w**2) * np.eye(n)
            A[iFd, iFd] = -2 * self.actuator.zeta * w * np.eye(n)
            B[iFd, :] = (w**2) * np.eye(n)
        self.A, self.B = A, B
        self.nz = nz
        self._integ = ETD2Integrator(A, B, self.h, nonlinear_rows=iv)
        self._zero_nl = np.zeros(n)
        self._offsets = np.arange(n) * self.spacing
        self._mg = self.m * (G / 1000.0)
        self._ca0, self._cb0, self._cc0 = float(self.ca[0]), float(self.cb[0]), float(self.cc[0])
        self._mg0, self._m0 = float(self._mg[0]), float(self.m[0])
        self._minv0 = 1.0 / float(self.m_inertial[0])
        self._nl_buf = np.zeros(1)
        # float copies of the ETD2 matrices for the single-car fast path
        self._scalar_ok = n == 1 and self.davis_variation is None and self.actuator.order < 2
        ig = self._integ
        self._sc_mats = (
            ig.Phi.tolist(),
            ig.Gamma[:, 0].tolist(),
            ig.P1[:, 0].tolist(),
            ig.P2[:, 0].tolist(),
        )

    def _nonlinear(self, z: np.ndarray, t: float) -> np.ndarray:
        """Nonlinear accelerations (rows of the speeds): −(Davis + gradient + w)/m'."""
        n = self.n
        if n == 1 and self.davis_variation is None:
            return self._nonlinear_single(z, t)
        v = z[n : 2 * n]
        av = np.abs(v)
        ca, cb, cc = self.ca, self.cb, self.cc
        if self.davis_variation is not None:
            d0, d1, d2 = self.davis_variation.deltas(t)
            ca = ca + d0 * self.m
            cb = cb + d1 * self.m
            if self.lead_aero:
                cc = cc.copy()
                cc[0] += d2 * self.m.sum()
            else:
                cc = cc + d2 * self.m
        force = np.sign(v) * (ca + cb * av + cc * av * av)
        if self.gradient_permil is not None:
            x = z[:n] - self._offsets
            force = force + self._mg * self.gradient_permil(x)
        if self.disturbances:
            w = 0.0
            for dist in self.disturbances:
                w += dist.accel(t)
            force = force + self.m * w
        return -force / self.m_inertial

    def _nonlinear_single(self, z: np.ndarray, t: float) -> np.ndarray:
        """Scalar fast path of :meth:`_nonlinear` for the single-point train."""
        v = float(z[1])
        av = abs(v)
        f = self._ca0 + self._cb0 * av + self._cc0 * av * av
        f = f if v > 0 else (-f if v < 0 else 0.0)
        if self.gradient_permil is not None:
            f += self._mg0 * float(self.gradient_permil(float(z[0])))
        if self.disturbances:
            w = 0.0
            for dist in self.disturbances:
                w += dist.accel(t)
            f += self._m0 * w
        out = self._nl_buf
        out[0] = -f * self._minv0
        return out.copy()

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
        self._w_now = w0.copy()
        self.stopped = v0 <= 0.0
        self.work_traction_J = 0.0
        self.work_brake_J = 0.0
        self._p_last = self._forces(z) * z[n : 2 * n] if self.actuator.order else w0 * z[n : 2 * n]
        self.last_command = w0.copy()
        self.saturated = False

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
        if not np.all(np.isfinite(arr)):
            raise ValueError("command u_N must be finite")
        return arr

    def saturate(self, w: np.ndarray) -> np.ndarray:
        """Clip per-car commands to each car's share of the traction/brake envelope."""
        v = abs(float(self.z[self.n]))
        hi = self.train.max_traction_N(v) * self.share
        lo = -self.train.max_brake_N(v) * self.share
        out = np.minimum(np.maximum(w, lo), hi)
        self.saturated = bool(np.any(out != w))
        return out

    def step(self, u: float | Sequence[float], duration_s: float) -> None:
        """Apply command ``u`` [N] (held) for ``duration_s`` (a multiple of ``dt_sim_s``)."""
        nsub = duration_s / self.h
        k = int(round(nsub))
        if k < 1 or abs(nsub - k) > 1e-6:
            raise ValueError(
                f"duration_s ({duration_s}) must be a positive multiple of dt_sim_s ({self.h})"
            )
        w_cmd = self.saturate(self._split(u))
        self.last_command = w_cmd
        if self._scalar_ok:
            self._run_single(float(w_cmd[0]), k)
            return
        n = self.n
        buf = self._buffer
        nb = buf.shape[0]
        for _ in range(k):
            # dead-time buffer: write the current command, read the one issued T_d ago
            buf[self._head] = w_cmd
            w = buf[(self._head + 1) % nb] if nb > 1 else w_cmd
            self._head = (self._head + 1) % nb
            self._w_now = w
            self._substep(w)
        del n

    def _run_single(self, w_cmd: float, k: int) -> None:
        """Scalar fast path of :meth:`step` for a single car (same arithmetic in floats).

        The single-point train is the most simulated plant (every tuning evaluation
        and RL rollout of the point-mass scenarios); at three states numpy's per-call
        overhead dominates, so the ETD2 step is unrolled on Python floats here.
        ``tests/test_plants.py`` checks it against the general path.
        """
        order = self.actuator.order
        Phi, Gam, P1, P2 = self._sc_mats
        h = self.h
        grad = self.gradient_permil
        dists = self.disturbances
        ca, cb, cc = self._ca0, self._cb0, self._cc0
        mg, m0, minv = self._mg0, self._m0, self._minv0
        hold = self.HOLD_SPEED_MPS
        buf = self._buffer
        nb = buf.shape[0]
        z = self.z.tolist()
        t = self.t
        p_last = float(self._p_last[0])
        wt = wb = 0.0
        stopped = self.stopped

        def nl(s_: float, v_: float, t_: float) -> float:
            av = v_ if v_ >= 0.0 else -v_
            f = ca + cb * av + cc * av * av
            f = f if v_ > 0 else (-f if v_ < 0 else 0.0)
            if grad is not None:
                f += mg * float(grad(s_))
            if dists:
                wd = 0.0
                for dist in dists:
                    wd += dist.accel(t_)
                f += m0 * wd
            return -f * minv

        for _ in range(k):
            buf[self._head, 0] = w_cmd
            w = float(buf[(self._head + 1) % nb, 0]) if nb > 1 else w_cmd
            self._head = (self._head + 1) % nb
            nz = len(z)
            if stopped:
                F = w if order == 0 else z[2]
                g_f = mg * float(grad(z[0])) if grad is not None else 0.0
                if F > g_f + ca:
                    stopped = False
                else:
                    if order:
                        z[2] = Phi[2][2] * z[2] + Gam[2] * w
                    z[1] = 0.0
                    t += h
                    p_last = 0.0
                    continue
            n0 = nl(z[0], z[1], t)
            if nz == 3:  # unrolled: this line is the hottest of every point-mass episode
                z0, z1, z2 = z
                a = [
                    r[0] * z0 + r[1] * z1 + r[2] * z2 + g * w + p * n0
                    for r, g, p in zip(Phi, Gam, P1, strict=True)
                ]
            else:
                a = [
                    sum(Phi[i][j] * z[j] for j in range(nz)) + Gam[i] * w + P1[i] * n0
                    for i in range(nz)
                ]
            n1 = nl(a[0], a[1], t + h)
            dn = n1 - n0
            z_new = [ai + p2 * dn for ai, p2 in zip(a, P2, strict=True)]
            v_old, v_new = z[1], z_new[1]
            p1 = (w if order == 0 else z_new[2]) * v_new
            tot = p_last + p1
            mag = abs(p_last) + abs(p1)
            wt += 0.25 * h * (mag + tot)
            wb += 0.25 * h * (mag - tot)
            p_last = p1
            F_old = w if order == 0 else z[2]
            if v_old > 0.0 and 0.0 < v_new < hold and v_new < v_old and F_old <= ca:
                z_new[1] = 0.0
                stopped = True
            elif v_old > 0.0 and v_new <= 0.0:
                frac = v_old / (v_old - v_new)
                z_new[0] = z[0] + 0.5 * z[1] * frac * h
                z_new[1] = 0.0
                stopped = True
            z = z_new
            t += h
        self.z = np.array(z)
        self.t = t
        self.stopped = stopped
        self._w_now = np.array([w if k else self._w_now[0]])
        self._p_last = np.array([p_last])
        self.work_traction_J += wt
        self.work_brake_J += wb

    def _substep(self, w: np.ndarray) -> None:
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
        z_new = self._integ.step(z, w, self.t, self._nonlinear)
        v_old = z[n]
        v_new = z_new[n]
        # trapezoidal integration of the traction (F v > 0) and braking (F v < 0) powers
        p1 = self._forces(z_new) * z_new[n : 2 * n]
        p0 = self._p_last
        tot = p0 + p1
        mag = abs(p0) + abs(p1)
        self.work_traction_J += 0.25 * h * float((mag + tot).sum())
        self.work_brake_J += 0.25 * h * float((mag - tot).sum())
        self._p_last = p1
        if v_old > 0.0 and 0.0 < v_new < self.HOLD_SPEED_MPS and v_new < v_old and self._braking():
            # crawling to a halt under braking: the holding brake takes over
            z_new[n : 2 * n] = 0.0
            self.stopped = True
        elif v_old > 0.0 and v_new <= 0.0:
            # interpolate the stop inside the sub-step (constant deceleration)
            frac = v_old / (v_old - v_new)
            z_new[:n] = z[:n] + 0.5 * z[n : 2 * n] * frac * h
            z_new[n : 2 * n] = 0.0
            self.stopped = True
        self.z = z_new
        self.t += h

    def _forces(self, z: np.ndarray) -> np.ndarray:
        if self.actuator.order == 0:
            return self._w_now
        return z[2 * self.n : 3 * self.n]

    def _braking(self) -> bool:
        """True when the actual force is a braking force (or below the resistance)."""
        return float(np.sum(self._forces(self.z))) <= float(np.sum(self.ca))

    def _breakaway(self, w: np.ndarray) -> bool:
        F = float(np.sum(w if self.actuator.order == 0 else self._forces(self.z)))
        grade = 0.0
        if self.gradient_permil is not None:
            x = self.z[: self.n] - self._offsets
            grade = float(np.sum(self.m * (G / 1000.0) * self.gradient_permil(x)))
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
        return float(np.sum(self._forces(self.z)))

    @property
    def accel(self) -> float:
        """Lead-car acceleration [m/s²] from the full model right now."""
        dz = self.A @ self.z + self.B @ self._w_now
        return 0.0 if self.stopped else float(dz[self.n] + self._nonlinear(self.z, self.t)[0])

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
