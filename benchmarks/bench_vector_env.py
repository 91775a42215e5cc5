"""Env steps/s per member of the native vector env against Gymnasium's sync vector env.

Run: ``python benchmarks/bench_vector_env.py [--ids Urban004-v0 ...] [--sizes 1 8 40]
[--rounds 3] [--steps 100] [--cpu-time]``. For each env id and number of members B,
``gymnasium.make_vec(id, num_envs=B, vectorization_mode=...)`` is built once with
``"vector_entry_point"`` (:class:`train_envs.envs.vector_env.TrainTuningVectorEnv`: the
members in lockstep runners) and once with ``"sync"`` (B single envs stepped one after
the other); one round resets both with seed 0 and steps each ``--steps`` times under
the same uniformly random actions (one action per member and step, seeded, what PPO's
exploration sends; autoresets included), in alternating order from round to round.
Reported per (id, B): the median over rounds of the member-steps per second of each and
the median of the per-round ratios native / sync (the per-member throughput gain). One
untimed warm-up of both first (QP cores and compiled kernels built). ``--cpu-time``
times with the process CPU time.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import gymnasium as gym
import numpy as np

import train_envs  # noqa: F401 - registers the ids

IDS = ("Urban004-v0", "Stopping001PID-v0", "Yizhuang-v0")


def _rate(venv: gym.vector.VectorEnv, actions: np.ndarray, clock: Callable[[], float]) -> float:
    """Member-steps per second of ``venv`` over ``actions`` (steps, B, ...)."""
    venv.reset(seed=0)
    t0 = clock()
    for a in actions:
        venv.step(a)
    return actions.shape[0] * actions.shape[1] / (clock() - t0)


def run(
    env_id: str, B: int, rounds: int, steps: int, clock: Callable[[], float]
) -> dict[str, float]:
    envs = {
        mode: gym.make_vec(env_id, num_envs=B, vectorization_mode=mode)
        for mode in ("vector_entry_point", "sync")
    }
    space = envs["sync"].action_space
    space.seed(B)
    warm = np.stack([space.sample() for _ in range(5)])
    for venv in envs.values():
        _rate(venv, warm, clock)
    rates: dict[str, list[float]] = {mode: [] for mode in envs}
    ratios = []
    for r in range(rounds):
        actions = np.stack([space.sample() for _ in range(steps)])
        order = ("vector_entry_point", "sync") if r % 2 == 0 else ("sync", "vector_entry_point")
        got = {mode: _rate(envs[mode], actions, clock) for mode in order}
        for mode, v in got.items():
            rates[mode].append(v)
        ratios.append(got["vector_entry_point"] / got["sync"])
    for venv in envs.values():
        venv.close()
    return {
        "native": statistics.median(rates["vector_entry_point"]),
        "sync": statistics.median(rates["sync"]),
        "ratio": statistics.median(ratios),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ids", nargs="+", default=list(IDS))
    ap.add_argument("--sizes", nargs="+", type=int, default=[1, 8, 40])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--cpu-time", action="store_true")
    args = ap.parse_args()
    clock = time.process_time if args.cpu_time else time.perf_counter
    print(
        f"| env id | B | native [member-steps/s] | sync [member-steps/s] | native / sync |"
        f"  ({args.rounds} rounds of {args.steps} steps, random actions)"
    )
    print("|---|---:|---:|---:|---:|")
    for name in args.ids:
        env_id = name if "/" in name else f"TrainEnvs/{name}"
        for B in args.sizes:
            r = run(env_id, B, args.rounds, args.steps, clock)
            print(
                f"| {name} | {B} | {r['native']:.0f} | {r['sync']:.0f} | {r['ratio']:.2f} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
