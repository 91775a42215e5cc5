"""Per-member-step cost of the lockstep evaluation against B single evaluations.

Run: ``python benchmarks/bench_lockstep.py [--ids Urban004-v0 ...] [--sizes 1 8 40]
[--rounds 3] [--env-steps 60] [--cpu-time] [--split]``. For each env id and population size B,
B parameter vectors are drawn uniformly from the env's parameter box (seeded); one
round times :func:`train_envs.envs.batch.evaluate_env_params_batch` on all B, then the
B single :func:`~train_envs.envs.evaluation.evaluate_env_params` calls (``reuse_env``,
as the tuners call them), in alternating order from round to round, each on seed 0
with the episode capped at ``--env-steps`` env steps (0: whole episodes). Reported per
(id, B): the median over rounds of the cost per member and control step of each path
[µs] and the median of the per-round ratios single / lockstep (the per-member
throughput gain). One untimed warm-up of both paths first (envs, QP cores and the
compiled kernels built). ``--cpu-time`` times with the process CPU time.

``--split``: instead, where one lockstep evaluation of the largest B spends its time
(one warm-up, then one timed run with the DMC's QP step, the controller step, the QP
core's ``LinearMPC.solve`` and its OSQP call wrapped in timers): the QP members split
into the DMC's wrapping, the core's bookkeeping and the OSQP call, the batched law,
and the rest (runner, plant, metrics). The timers add a few % to the run.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import gymnasium as gym
import numpy as np

import train_envs  # noqa: F401 - registers the ids
from train_envs.envs.batch import evaluate_env_params_batch, supports_batch
from train_envs.envs.evaluation import evaluate_env_params

IDS = ("Urban004-v0", "Urban004FuzzyPID-v0", "Stopping001PID-v0")


def _params(env_id: str, n: int, seed: int) -> list[dict[str, float]]:
    specs = gym.make(env_id).unwrapped.param_specs
    rng = np.random.default_rng(seed)
    return [{s.name: s.from_unit(float(rng.uniform(-1, 1))) for s in specs} for _ in range(n)]


def run(
    env_id: str, B: int, rounds: int, env_steps: int, clock: Callable[[], float]
) -> dict[str, float]:
    cfg = {"max_episode_steps": env_steps} if env_steps else {}
    if not supports_batch(env_id, cfg):
        raise SystemExit(f"{env_id} has no lockstep path")
    plist = _params(env_id, B, seed=B)

    def lockstep():
        return evaluate_env_params_batch(env_id, plist, [0], config=cfg)

    def singles():
        return [
            evaluate_env_params(env_id, p, seeds=[0], config=cfg, label="tuner", reuse_env=True)
            for p in plist
        ]

    lockstep()
    steps = 0
    for p in plist:  # the warm-up of the single path; its frames count the control steps
        frames: dict = {}
        evaluate_env_params(
            env_id, p, seeds=[0], config=cfg, label="tuner", reuse_env=True, frames=frames
        )
        steps += len(frames[0]) - 1  # (the last row is the state after the last step)
    per_l, per_s, ratio = [], [], []
    for r in range(rounds):
        order = (lockstep, singles) if r % 2 == 0 else (singles, lockstep)
        times = {}
        for fn in order:
            t0 = clock()
            fn()
            times[fn] = clock() - t0
        per_l.append(times[lockstep] / steps * 1e6)
        per_s.append(times[singles] / steps * 1e6)
        ratio.append(times[singles] / times[lockstep])
    return {
        "lockstep_us": statistics.median(per_l),
        "single_us": statistics.median(per_s),
        "ratio": statistics.median(ratio),
        "steps": steps,
    }


def split(env_id: str, B: int, env_steps: int) -> None:
    """Print the time split of one lockstep evaluation of B members (see ``--split``)."""
    from train_envs.controllers.dmc.batch import BatchDMC
    from train_envs.mpc.linear_mpc import LinearMPC
    from train_envs.mpc.osqp_backend import _Backend

    cfg = {"max_episode_steps": env_steps} if env_steps else {}
    plist = _params(env_id, B, seed=B)
    evaluate_env_params_batch(env_id, plist, [0], config=cfg)
    acc: dict[str, list[float]] = {}

    def timed(cls: type, name: str) -> Callable[[], None]:
        fn = getattr(cls, name)
        cell = acc.setdefault(f"{cls.__name__}.{name}", [0.0, 0])

        def wrapper(*a, **k):
            t0 = time.perf_counter()
            try:
                return fn(*a, **k)
            finally:
                cell[0] += time.perf_counter() - t0
                cell[1] += 1

        setattr(cls, name, wrapper)
        return lambda: setattr(cls, name, fn)

    undo = [
        timed(BatchDMC, "compute"),
        timed(BatchDMC, "_qp_step"),
        timed(LinearMPC, "solve"),
        timed(_Backend, "step"),
    ]
    try:
        t0 = time.perf_counter()
        evaluate_env_params_batch(env_id, plist, [0], config=cfg)
        total = time.perf_counter() - t0
    finally:
        for u in undo:
            u()
    law, qp = acc["BatchDMC.compute"][0], acc["BatchDMC._qp_step"]
    core, osqp = acc["LinearMPC.solve"][0], acc["_Backend.step"][0]
    steps = int(acc["BatchDMC.compute"][1])
    rows = [
        ("QP members: DMC wrapping", qp[0] - core),
        ("QP members: LinearMPC bookkeeping", core - osqp),
        ("QP members: OSQP call", osqp),
        ("batched law (BatchDMC.compute less QP)", law - qp[0]),
        ("runner, plant, metrics", total - law),
    ]
    print(f"{env_id} B={B}: {total:.3f} s, {steps} population steps, {int(qp[1])} QP steps")
    for name, t in rows:
        print(f"  {name:<42} {t:8.3f} s {100 * t / total:5.1f} %")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ids", nargs="+", default=list(IDS))
    ap.add_argument("--sizes", nargs="+", type=int, default=[1, 8, 40])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--env-steps", type=int, default=60)
    ap.add_argument("--cpu-time", action="store_true")
    ap.add_argument("--split", action="store_true", help="the time split of the largest B")
    args = ap.parse_args()
    if args.split:
        for name in args.ids:
            split(name if "/" in name else f"TrainEnvs/{name}", max(args.sizes), args.env_steps)
        return
    clock = time.process_time if args.cpu_time else time.perf_counter
    print(
        f"{'env id':<24} {'B':>3} {'steps':>6} {'lockstep µs':>12} {'single µs':>10} {'ratio':>6}"
    )
    for name in args.ids:
        env_id = name if "/" in name else f"TrainEnvs/{name}"
        for B in args.sizes:
            r = run(env_id, B, args.rounds, args.env_steps, clock)
            print(
                f"{name:<24} {B:>3} {r['steps']:>6} {r['lockstep_us']:>12.1f} "
                f"{r['single_us']:>10.1f} {r['ratio']:>6.2f}",
                flush=True,
            )


if __name__ == "__main__":
    main()
