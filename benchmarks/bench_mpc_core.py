"""Benchmark of the linear-MPC QP engine (:mod:`train_envs.mpc`).

Runs closed-loop simulations and compares the median wall time of
``LinearMPC.solve()`` with OSQP's own ``info.solve_time`` (the ratio measures the
python overhead of the core), for both QP forms:

(a) 4 states (position, speed, traction lag, integral), 1 input, Delta-u form,
    soft speed bound, N = 10 (target wall/solve ratio <= 3.0);
(b) 12 states, 6 inputs (six-car train: 6 positions + 6 speeds, elastic
    couplers with soft +-5 cm extension limits, soft speed limits, gradient as a
    time-varying affine term), N = 3, 10, 20 (target ratio <= 2.0 at N = 10).

``--crossover`` adds the rows used to choose ``form="auto"`` (system (a) at
N = 20, 30 and a 2-state double integrator at N = 30).

Usage::

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_mpc_core.py [--steps 1000] [--crossover]

Not a test: it prints a table.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np
import osqp
import scipy.linalg as sla

from train_envs.mpc import LinearMPC


def c2d(Ac: np.ndarray, Bc: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Zero-order-hold discretisation via the matrix exponential."""
    n, m = Bc.shape
    M = np.zeros((n + m, n + m))
    M[:n, :n] = Ac
    M[:n, n:] = Bc
    E = sla.expm(M * dt)
    return E[:n, :n], E[:n, n:]


def system_a() -> dict:
    """Position/speed tracking with a first-order traction lag and an integrator."""
    dt, tau = 0.2, 0.5
    A = np.array([[1, dt, 0, 0], [0, 0.995, dt, 0], [0, 0, 1 - dt / tau, 0], [dt, 0, 0, 1.0]])
    B = np.array([[0.0], [0.0], [dt / tau], [0.0]])
    C = np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0]])
    return dict(
        A=A,
        B=B,
        C=C,
        Q=np.diag([1.0, 0.5]),
        R=np.array([[1.0]]),
        u_min=-1.0,
        u_max=1.0,
        du_min=-0.2,
        du_max=0.2,
        y_min=[-np.inf, -1.5],
        y_max=[np.inf, 1.5],
    )


def system_b(dt: float = 0.5) -> dict:
    """Six cars, each with its own traction input, coupled by spring-damper couplers.

    State: ``p_1..p_6`` (position of each car relative to its nominal place in the
    consist, i.e. coupler extension ``p_i - p_{i+1}``), then ``v_1..v_6`` (m/s).
    """
    nc = 6
    mass, k, c, c0 = 40e3, 2e5, 2e4, 1e3  # kg, N/m, N s/m, N s/m (linear resistance)
    a_max = 1.0  # m/s^2 per unit input
    K = np.zeros((nc, nc))
    for i in range(nc - 1):
        K[i, i] += 1
        K[i + 1, i + 1] += 1
        K[i, i + 1] -= 1
        K[i + 1, i] -= 1
    Ac = np.zeros((2 * nc, 2 * nc))
    Ac[:nc, nc:] = np.eye(nc)
    Ac[nc:, :nc] = -k / mass * K
    Ac[nc:, nc:] = -c / mass * K - c0 / mass * np.eye(nc)
    Bc = np.zeros((2 * nc, nc))
    Bc[nc:, :] = a_max * np.eye(nc)
    A, B = c2d(Ac, Bc, dt)
    # couplers: extension p_i - p_{i+1} stays within +-0.05 m (soft)
    H = np.zeros((2 * (nc - 1), 2 * nc))
    for i in range(nc - 1):
        H[i, i], H[i, i + 1] = 1.0, -1.0
        H[nc - 1 + i, i], H[nc - 1 + i, i + 1] = -1.0, 1.0
    h = np.full(2 * (nc - 1), 0.05)
    Q = np.diag([0.01] * nc + [1.0] * nc)
    return dict(
        A=A,
        B=B,
        C=None,
        Q=Q,
        R=0.5 * np.eye(nc),
        u_min=-1.0,
        u_max=1.0,
        du_min=-0.25,
        du_max=0.25,
        y_min=[-np.inf] * nc + [0.0] * nc,
        y_max=[np.inf] * nc + [22.0] * nc,
        H_x=H,
        h_x=h,
        dt=dt,
    )


def run_di(N: int, steps: int, form: str, seed: int = 0) -> dict:
    """Double integrator (position, speed), position steps, soft speed bound."""
    rng = np.random.default_rng(seed)
    dt = 0.2
    A = np.array([[1.0, dt], [0.0, 1.0]])
    B = np.array([[0.5 * dt * dt], [dt]])
    mpc = LinearMPC(
        A,
        B,
        Np=N,
        Q=np.diag([1.0, 0.1]),
        R=1.0,
        u_min=-1.0,
        u_max=1.0,
        du_min=-0.2,
        du_max=0.2,
        y_min=[-np.inf, -1.5],
        y_max=[np.inf, 1.5],
        form=form,
    )
    x, u = np.zeros(2), np.zeros(1)
    walls, solves, iters, fallbacks = [], [], [], 0
    for k in range(steps):
        target = 5.0 * np.sign(np.sin(2 * np.pi * k / 300.0))
        t0 = time.perf_counter()
        sol = mpc.solve(x, u, np.array([target, 0.0]))
        walls.append(time.perf_counter() - t0)
        solves.append(sol.solve_time_s)
        iters.append(sol.iterations)
        fallbacks += sol.fallback
        u = sol.u0
        x = A @ x + B @ u + 0.005 * rng.standard_normal(2)
    return summarize("di", 2, 1, N, mpc, walls, solves, iters, fallbacks)


def run_a(N: int, steps: int, form: str, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    sysd = system_a()
    A, B = sysd["A"], sysd["B"]
    mpc = LinearMPC(**sysd, Np=N, form=form)
    x = np.zeros(4)
    u = np.zeros(1)
    walls, solves, iters, fallbacks = [], [], [], 0
    for k in range(steps):
        # piecewise-constant position targets with speed reference 0
        target = 5.0 * np.sign(np.sin(2 * np.pi * k / 300.0))
        y_ref = np.tile([target, 0.0], (N, 1))
        t0 = time.perf_counter()
        sol = mpc.solve(x, u, y_ref)
        walls.append(time.perf_counter() - t0)
        solves.append(sol.solve_time_s)
        iters.append(sol.iterations)
        fallbacks += sol.fallback
        u = sol.u0
        x = A @ x + B @ u + 0.005 * rng.standard_normal(4)
    return summarize("a", 4, 1, N, mpc, walls, solves, iters, fallbacks)


def run_b(N: int, steps: int, form: str, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    sysd = system_b()
    dt = sysd.pop("dt")
    A, B = sysd["A"], sysd["B"]
    mpc = LinearMPC(**sysd, Np=N, form=form)
    nc = 6
    x = np.zeros(2 * nc)
    u = np.zeros(nc)
    # speed profile: accelerate to 20 m/s, cruise, brake, repeat
    period = 400

    def v_ref(t: float) -> float:
        s = t % period
        return min(20.0, 0.5 * s) if s < 300 else max(0.0, 20.0 - 0.5 * (s - 300))

    grade = 0.05 * np.sin(np.arange(10_000) / 150.0)  # gradient acceleration (m/s^2) along the line
    walls, solves, iters, fallbacks = [], [], [], 0
    p_ref = 0.0
    for k in range(steps):
        vr = np.array([v_ref(k + i + 1) for i in range(N)])
        pr = p_ref + np.cumsum(vr) * dt
        y_ref = np.zeros((N, 2 * nc))
        y_ref[:, :nc] = pr[:, None]
        y_ref[:, nc:] = vr[:, None]
        # affine term: gradient acceleration on every car over the horizon
        d = np.zeros((N, 2 * nc))
        d[:, nc:] = -dt * grade[k : k + N, None]
        t0 = time.perf_counter()
        sol = mpc.solve(x, u, y_ref, d=d)
        walls.append(time.perf_counter() - t0)
        solves.append(sol.solve_time_s)
        iters.append(sol.iterations)
        fallbacks += sol.fallback
        u = sol.u0
        x = A @ x + B @ u + d[0] + 0.002 * rng.standard_normal(2 * nc)
        p_ref += v_ref(k + 1) * dt
    return summarize("b", 12, 6, N, mpc, walls, solves, iters, fallbacks)


def summarize(name, n, m, N, mpc, walls, solves, iters, fallbacks) -> dict:
    w = np.median(walls) * 1e6
    s = np.median(solves) * 1e6
    auto = LinearMPC._auto_form(N, N, n, m)
    return dict(
        case=name,
        form=mpc.form + ("*" if mpc.form == auto else ""),
        mean_wall=float(np.mean(walls)) * 1e6,
        n=n,
        m=m,
        N=N,
        nv=mpc.n_variables,
        nA=mpc.n_constraints,
        wall=w,
        solve=s,
        ratio=w / s,
        overhead=w - s,
        iters=float(np.median(iters)),
        fallbacks=fallbacks,
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--forms", default="condensed,sparse", help="comma-separated QP forms")
    ap.add_argument("--crossover", action="store_true", help="add the form-selection rows")
    args = ap.parse_args()
    forms = args.forms.split(",")
    print(
        f"python {platform.python_version()}, numpy {np.__version__}, osqp {osqp.__version__}, "
        f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}, "
        f"{args.steps} closed-loop steps per row"
    )
    head = (
        f"{'case':4s} {'form':10s} {'n':>3s} {'m':>2s} {'N':>3s} {'vars':>5s} {'rows':>5s} "
        f"{'wall us':>9s} {'solve us':>9s} {'overhead us':>11s} {'ratio':>6s} "
        f"{'iters':>6s} {'mean wall us':>12s} {'fallb':>5s}"
    )
    print(head)
    print("-" * len(head))
    jobs = [(run_a, 10)] + [(run_b, N) for N in (3, 10, 20)]
    if args.crossover:
        jobs += [(run_a, 20), (run_a, 30), (run_di, 30)]
    for fn, N in jobs:
        for form in forms:
            r = fn(N, args.steps, form)
            print(
                f"{r['case']:4s} {r['form']:10s} {r['n']:3d} {r['m']:2d} {r['N']:3d} "
                f"{r['nv']:5d} {r['nA']:5d} {r['wall']:9.1f} {r['solve']:9.1f} "
                f"{r['overhead']:11.1f} {r['ratio']:6.2f} {r['iters']:6.0f} "
                f"{r['mean_wall']:12.1f} {r['fallbacks']:5d}",
                flush=True,
            )
    print("wall/solve = median wall time of solve() / median OSQP info.solve_time;")
    print("* = the form chosen by form='auto'")


if __name__ == "__main__":
    main()
