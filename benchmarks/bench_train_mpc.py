"""MPC step cost on the papers' problems: wall time per step vs OSQP's own solve time.

Run: ``python benchmarks/bench_train_mpc.py [--episodes 3]``. For paper 001's
single-point problem (N = 10) and paper 000's 6-car problem (N = 3, 10, 20), whole
closed-loop scenarios, one untimed warm-up episode (the QP is built on first use) and
then ``--episodes`` timed ones; per control step we time the controller's ``compute``
(everything the MPC does: reference preview, affine terms, QP vector updates, OSQP,
result) and read OSQP's own ``solve_time`` from the same call.

Each problem runs twice. With OSQP at every step (``unconstrained_first=False``): the
medians of wall and OSQP time and their ratio, i.e. what the MPC costs around its
solver. As shipped (the exact unconstrained optimum first, OSQP only when a row binds):
the median and mean wall time per step and the share of steps that needed OSQP. Also
the share of steps whose solve failed (fallback).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from train_envs.controllers.train_mpc import MultiCarMPC, PointMassMPC
from train_envs.scenarios import get_scenario
from train_envs.simulation import ClosedLoop


def bench(scenario: str, ctrl, episodes: int = 3) -> dict[str, float]:
    sc = get_scenario(scenario)
    loop = ClosedLoop(sc, ctrl)
    walls, solves, fallbacks, osqp_steps = [], [], 0, 0
    compute = ctrl.compute
    for ep in range(episodes + 1):
        loop.reset(seed=0)
        while not loop.done:
            obs = loop.observe()
            t0 = time.perf_counter()
            u, info = compute(obs)
            wall = time.perf_counter() - t0
            loop.step(u)
            if ep:  # episode 0 is the warm-up
                walls.append(wall)
                solves.append(info["solve_time_s"])
                fallbacks += bool(info["fallback"])
                osqp_steps += info["iterations"] > 0
    w, s = np.median(walls), np.median(solves)
    return {
        "wall_us": 1e6 * w,
        "wall_mean_us": 1e6 * float(np.mean(walls)),
        "osqp_us": 1e6 * s,
        "ratio": w / s if s > 0 else float("nan"),
        "steps": len(walls),
        "osqp_share": osqp_steps / len(walls),
        "failed": fallbacks / len(walls),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=3, help="timed episodes per problem")
    args = ap.parse_args()
    cases = [
        ("paper001_stopping", "single-point, N=10", PointMassMPC, 10),
        ("paper000_single_section", "6-car SEMPC, N=3", MultiCarMPC, 3),
        ("paper000_single_section", "6-car SEMPC, N=10", MultiCarMPC, 10),
        ("paper000_single_section", "6-car SEMPC, N=20", MultiCarMPC, 20),
    ]
    print(
        "| problem | steps | OSQP every step: median wall/step [µs] | median OSQP [µs] | "
        "ratio | as shipped: median / mean wall/step [µs] | steps with OSQP | failed |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for scenario, label, cls, Np in cases:
        r = bench(scenario, cls(Np=Np, unconstrained_first=False), args.episodes)
        f = bench(scenario, cls(Np=Np), args.episodes)
        print(
            f"| {label} | {r['steps']} | {r['wall_us']:.0f} / {r['wall_mean_us']:.0f} | "
            f"{r['osqp_us']:.0f} | "
            f"{r['ratio']:.2f} | {f['wall_us']:.0f} / {f['wall_mean_us']:.0f} | "
            f"{100 * f['osqp_share']:.0f} % | "
            f"{100 * max(r['failed'], f['failed']):.2f} % |"
        )


if __name__ == "__main__":
    main()
