"""Independent reference of the train plants: recorded commands replayed open loop
through scipy's DOP853 (``solve_ivp``), restarted at every breakpoint.

The model is written here from the equations of :mod:`train_envs.plants.multi_car`
(cars numbered from the front, actual positions ``x_i``, rest spacing ``L``)::

    ẋ_i = v_i
    m'_i v̇_i = F_i + f_{i−1} − f_i − σ_i (a_i + b_i σ_i v_i + c_i v_i²)
               − m_i g θ(x_i)/1000 − m_i w(t)
    f_j = k (x_j − x_{j+1} − L) + d (v_j − v_{j+1})
    τ Ḟ_i = −F_i + u_i(t − T_d)      (first-order actuator; F_i = u_i(t − T_d) when ideal)

with σ_i the direction of motion of car i (Davis resistance opposes it) and θ the
equivalent gradient (gradient + 600 |κ| curve resistance, 0 above a 10 km radius) of
:class:`train_envs.lines.track.Track`, evaluated from the track's sections, not from
the plant's table.  Every discontinuity of the right-hand side ends an integration
piece: a command change (``t_k + T_d``), a car crossing a gradient or curve section
start or a curve-resistance cut-off, a car's speed changing sign.  The standstill rules
are the plant's: the lead car reaching zero speed, or the hold speed (1 cm/s) under
braking, holds the train; a held train moves again when the net forward force
``Σ F_i − Σ m_i g θ_i/1000 − Σ m_i w(t)`` exceeds the Davis constant terms ``Σ a_i``.

:func:`record` runs one closed loop and keeps the applied (saturated, per car)
commands and the plant state after every control step; :func:`replay` integrates the
same commands; :func:`compare` gives the deviations.  ``python -m
tests.plants.dop853_replay`` prints the fidelity table of ``docs/fidelity.md``.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp

from train_envs.lines.track import CURVE_RESISTANCE_COEFF, CURVE_RESISTANCE_MAX_RADIUS_M
from train_envs.trains import G


@dataclass
class Recording:
    """Commands applied to a plant and the states it reached (one row per control step)."""

    plant: object
    track: object
    dt_s: float
    t0: float
    x0: np.ndarray  # actual car positions at the start
    v0: np.ndarray
    F0: np.ndarray  # actuator forces at the start (order 1)
    w0: np.ndarray  # the dead-time buffer's initial content per car
    stopped0: bool
    commands: np.ndarray  # (K, n) saturated per-car commands
    x: np.ndarray  # (K, n) positions after each step
    v: np.ndarray
    coupler_N: np.ndarray  # (K, n-1)


def record(scenario, controller: str | object, seed: int = 0, dt_sim_s: float | None = None):
    """Run ``controller`` on ``scenario`` to the end; the :class:`Recording` of its plant."""
    from train_envs.controllers import make_controller
    from train_envs.scenarios import get_scenario
    from train_envs.simulation import ClosedLoop

    sc = get_scenario(scenario) if isinstance(scenario, str) else scenario
    if dt_sim_s is not None:
        sc = sc.with_overrides(dt_sim_s=dt_sim_s)
    ctrl = make_controller(controller, sc) if isinstance(controller, str) else controller
    loop = ClosedLoop(sc, ctrl)
    loop.reset(seed=seed)
    p = loop.plant
    n = p.n
    x0, v0 = p.positions.copy(), p.speeds.copy()
    F0 = p.forces.copy()
    w0 = np.array(p._buffer[0], dtype=float)
    t0, stopped0 = p.t, p.stopped
    cmds, xs, vs, cfs = [], [], [], []
    while not loop.done:
        loop.step()
        cmds.append(np.array(p.last_command, dtype=float).reshape(n))
        xs.append(p.positions.copy())
        vs.append(p.speeds.copy())
        cfs.append(p.coupler_forces().copy())
    return Recording(
        p,
        sc.track,
        sc.dt_ctrl_s,
        t0,
        x0,
        v0,
        F0,
        w0,
        stopped0,
        np.array(cmds),
        np.array(xs),
        np.array(vs),
        np.array(cfs).reshape(len(xs), n - 1),
    )


def gradient_pieces(track) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(b, a, slope)``: the equivalent gradient is ``a[p] + slope[p] (x − b[p])`` on
    ``[b[p], b[p+1])``; ``b`` holds every section start and every point where a
    clothoid's radius crosses the cut-off (or its curvature zero)."""
    cut = 1.0 / CURVE_RESISTANCE_MAX_RADIUS_M
    pts = [0.0, *track.gradient_positions_m, *track.curve_positions_m, *track.stops_m]
    cp = list(track.curve_positions_m)
    ends = [*cp[1:], track.length_m]
    for p0, p1, r0, r1 in zip(
        cp, ends, track.curve_radius_start_m, track.curve_radius_end_m, strict=True
    ):
        k0 = 0.0 if math.isinf(r0) else 1.0 / r0
        k1 = 0.0 if math.isinf(r1) else 1.0 / r1
        if k0 == k1:
            continue
        for target in (-cut, 0.0, cut):
            f = (target - k0) / (k1 - k0)
            if 0.0 < f < 1.0:
                pts.append(p0 + f * (p1 - p0))
    b = np.unique(np.array(pts, dtype=float))
    b = b[b < track.length_m]
    right = np.append(b[1:], track.length_m)
    a = np.empty(b.size)
    slope = np.empty(b.size)
    for i, (lo, hi) in enumerate(zip(b, right, strict=True)):
        g = float(track.gradient_permil_at(0.5 * (lo + hi)))
        q1, q3 = lo + 0.25 * (hi - lo), lo + 0.75 * (hi - lo)
        k1, k3 = float(track.curvature_at(q1)), float(track.curvature_at(q3))
        if abs(0.5 * (k1 + k3)) < cut:  # straight for the curve resistance
            a[i], slope[i] = g, 0.0
        else:
            sgn = 1.0 if k1 + k3 > 0 else -1.0
            dk = (k3 - k1) / (q3 - q1)
            a[i] = g + CURVE_RESISTANCE_COEFF * sgn * (k1 - dk * (q1 - lo))
            slope[i] = CURVE_RESISTANCE_COEFF * sgn * dk
    # positions before the line hold its first value (the track clamps them)
    return np.concatenate(([-1e30], b, [np.inf])), np.append(a[0], a), np.append(0.0, slope)


class _Model:
    def __init__(self, rec: Recording) -> None:
        p = rec.plant
        self.n = p.n
        self.order = p.actuator.order
        if self.order > 1 or p.davis_variation is not None:
            raise NotImplementedError("reference: actuator order 0/1, no Davis variation")
        self.tau = p.actuator.tau_s
        self.m, self.mi = p.m, p.m_inertial
        self.ca, self.cb, self.cc = p.ca, p.cb, p.cc
        self.k, self.d, self.L = p.k, p.d, p.spacing
        self.dists = p.disturbances
        self.hold = p.HOLD_SPEED_MPS
        self.b, self.a, self.sl = gradient_pieces(rec.track)

    def theta(self, x: np.ndarray, seg: np.ndarray) -> np.ndarray:
        return self.a[seg] + self.sl[seg] * (x - self.b[seg])

    def wind(self, t: float) -> float:
        return float(sum(dd.accel(t) for dd in self.dists))

    def forces(self, y: np.ndarray, u: np.ndarray) -> np.ndarray:
        return u if self.order == 0 else y[2 * self.n : 3 * self.n]

    def rhs(self, t, y, u, seg, sgn, held):
        n = self.n
        out = np.zeros_like(y)
        if self.order:
            out[2 * n :] = (u - y[2 * n :]) / self.tau
        if held:
            return out
        x, v = y[:n], y[n : 2 * n]
        F = self.forces(y, u)
        f = self.k * (x[:-1] - x[1:] - self.L) + self.d * (v[:-1] - v[1:])
        acc = F.copy()
        acc[:-1] -= f
        acc[1:] += f
        acc -= sgn * self.ca + self.cb * v + sgn * self.cc * v * v
        acc -= self.m * G * 1e-3 * self.theta(x, seg)
        if self.dists:
            acc -= self.m * self.wind(t)
        out[:n] = v
        out[n : 2 * n] = acc / self.mi
        return out

    def net_forward(self, t, y, u, seg) -> float:
        """Net forward force of the held train beyond the Davis constant terms [N]."""
        x = y[: self.n]
        F = self.forces(y, u)
        grade = self.m * G * 1e-3 * self.theta(x, seg)
        return float(F.sum() - grade.sum() - self.m.sum() * self.wind(t) - self.ca.sum())


def replay(rec: Recording, rtol: float = 1e-10) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Positions, speeds and coupler forces of the reference after every control step."""
    md = _Model(rec)
    p = rec.plant
    n, h = md.n, p.h
    K = rec.commands.shape[0]
    kc = int(round(rec.dt_s / h))
    D = p.delay_steps
    # sub-step indices where the applied input changes (D + k kc) or a row is due
    out_j = [(k + 1) * kc for k in range(K)]
    grid = sorted(set(out_j) | {D + k * kc for k in range(K)} | {0})
    grid = [j for j in grid if j <= out_j[-1]]

    def u_at(j: int) -> np.ndarray:  # input applied on sub-step j onwards
        k = (j - D) // kc
        return rec.w0 if j < D else rec.commands[min(k, K - 1)]

    y = np.concatenate([rec.x0, rec.v0] + ([rec.F0] if md.order else []))
    seg = np.searchsorted(md.b, rec.x0, side="right") - 1
    sgn = np.ones(n)
    held = rec.stopped0
    atol = np.full(y.size, 1e-11)
    if md.order:
        atol[2 * n :] = 1e-6
    res_x, res_v, res_f = {}, {}, {}
    for ja, jb in zip(grid[:-1], grid[1:], strict=True):
        ta, tb = rec.t0 + ja * h, rec.t0 + jb * h
        u = u_at(ja)
        while ta < tb:
            if held and md.net_forward(ta, y, u, seg) > 0.0:
                held, sgn = False, np.ones(n)
            events = []
            if held:
                ev = lambda t, yy, *_, u=u, seg=seg: md.net_forward(t, yy, u, seg)  # noqa: E731
                ev.terminal, ev.direction = True, 1
                events.append(("release", -1, ev))
            else:
                for i in range(n):
                    fw = lambda t, yy, *_, i=i, b=md.b[seg[i] + 1]: yy[i] - b  # noqa: E731
                    fw.terminal, fw.direction = True, 1
                    bw = lambda t, yy, *_, i=i, b=md.b[seg[i]]: yy[i] - b  # noqa: E731
                    bw.terminal, bw.direction = True, -1
                    sv = lambda t, yy, *_, i=i: yy[n + i]  # noqa: E731
                    sv.terminal, sv.direction = True, -sgn[i]
                    events += [("fwd", i, fw), ("bwd", i, bw), ("sign", i, sv)]
                if y[n] > md.hold * (1 + 1e-9):
                    hs = lambda t, yy, *_: yy[n] - md.hold  # noqa: E731
                    hs.terminal, hs.direction = True, -1
                    events.append(("hold", 0, hs))
            sol = solve_ivp(
                md.rhs,
                (ta, tb),
                y,
                method="DOP853",
                rtol=rtol,
                atol=atol,
                events=[e[2] for e in events],
                args=(u, seg, sgn, held),
            )
            if sol.status != 1:
                ta, y = tb, sol.y[:, -1].copy()
                continue
            hit = min(
                ((sol.t_events[q][0], q) for q in range(len(events)) if sol.t_events[q].size),
                key=lambda e: e[0],
            )
            te, q = hit
            kind, i, _ = events[q]
            y = sol.y_events[q][0].copy()
            ta = te
            if kind == "release":
                held, sgn = False, np.ones(n)
            elif kind == "fwd":
                seg = seg.copy()
                seg[i] += 1
            elif kind == "bwd":
                seg = seg.copy()
                seg[i] -= 1
            elif kind == "sign" and i == 0 and sgn[0] > 0:
                held = True
                y[n : 2 * n] = 0.0
            elif kind == "sign":
                sgn = sgn.copy()
                sgn[i] = -sgn[i]
            elif kind == "hold" and float(md.forces(y, u).sum()) <= float(md.ca.sum()):
                held = True
                y[n : 2 * n] = 0.0
        if jb in out_j:
            x, v = y[:n], y[n : 2 * n]
            res_x[jb], res_v[jb] = x.copy(), v.copy()
            res_f[jb] = md.k * (x[:-1] - x[1:] - md.L) + md.d * (v[:-1] - v[1:])
    return (
        np.array([res_x[j] for j in out_j]),
        np.array([res_v[j] for j in out_j]),
        np.array([res_f[j] for j in out_j]).reshape(K, n - 1),
    )


def compare(rec: Recording, rtol: float = 1e-10) -> dict[str, float]:
    """Largest deviations of the plant from the reference over the run: position [m]
    and speed [m/s] of every car, coupler force [N] and that as a share of the peak."""
    x, v, f = replay(rec, rtol)
    out = {
        "ds_m": float(np.max(np.abs(rec.x - x))),
        "dv_mps": float(np.max(np.abs(rec.v - v))),
        "steps": float(x.shape[0]),
    }
    if f.size:
        peak = float(np.max(np.abs(f)))
        out["df_N"] = float(np.max(np.abs(rec.coupler_N - f)))
        out["df_share"] = out["df_N"] / peak
        out["peak_N"] = peak
    return out


#: the fidelity checks of docs/fidelity.md: (scenario, controller)
CASES = (
    ("paper001_stopping", "pid"),
    ("paper000_single_section", "sempc"),
    ("paper000_disturbance_harmonic", "sempc"),
    ("paper000_disturbance_constant", "sempc"),
)


def main(argv: list[str]) -> None:
    dt = float(argv[0]) if argv else None
    print(
        "| scenario | controller | steps | max Δs [mm] | max Δv [mm/s] | max Δf [kN] | Δf / peak |"
    )
    print("|---|---|---|---|---|---|---|")
    for name, ctrl in CASES:
        c = compare(record(name, ctrl, dt_sim_s=dt))
        df = f"{c['df_N'] / 1e3:.2f} | {100 * c['df_share']:.2f} %" if "df_N" in c else "– | –"
        print(
            f"| {name} | {ctrl} | {c['steps']:.0f} | {1e3 * c['ds_m']:.3f} | "
            f"{1e3 * c['dv_mps']:.3f} | {df} |"
        )


if __name__ == "__main__":
    main(sys.argv[1:])
