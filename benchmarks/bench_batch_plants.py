"""Member-steps per second of the batched plants against B single plants.

Run: ``python benchmarks/bench_batch_plants.py [--scenarios paper000_single_section ...]
[--sizes 1 8 40] [--rounds 3] [--steps 120] [--cpu-time]``. For each scenario and
number of members B, B plants are built from the scenario (seeds 0..B-1: their own
disturbances and mass draws) and stepped ``--steps`` control steps under the same
commands twice: once as B single :class:`~train_envs.plants.multi_car.TrainPlant`
objects one after the other, once as one batch
(:class:`~train_envs.plants.batch_multi_car.BatchMultiCar` for multi-car trains,
:class:`~train_envs.plants.batch.BatchSingleCar` for one car), the order swapped from
round to round. The commands hold the speed with a random jitter per member and step,
with a braking phase to a standstill and a pull-away (seeded, the same for both).
Reported per (scenario, B): the median over rounds of the member-steps per second of
each and the median of the per-round ratios batch / single. ``--cpu-time`` times with
the process CPU time.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import numpy as np

from train_envs.plants.batch import BatchSingleCar
from train_envs.plants.batch_multi_car import BatchMultiCar
from train_envs.scenarios import build_plant, get_scenario

SCENARIOS = ("paper000_single_section", "paper002_cruise", "paper003_cruise", "paper001_stopping")


def _plants(name: str, B: int) -> list:
    sc = get_scenario(name)
    return [build_plant(sc, np.random.default_rng(seed)) for seed in range(B)]


def _commands(name: str, B: int, steps: int, seed: int) -> np.ndarray:
    """(steps, B) whole-train commands [N]: hold, brake to a stop, pull away."""
    sc = get_scenario(name)
    tr = sc.train
    hold = tr.resistance_N(max(sc.v0_mps, 10.0))
    rng = np.random.default_rng(seed)
    out = np.empty((steps, B))
    for k in range(steps):
        phase = (k // 40) % 3
        if phase == 0:
            base = hold * rng.uniform(0.8, 1.6, B)
        elif phase == 1:
            base = -tr.max_brake_N(5.0) * rng.uniform(0.6, 1.0, B)
        else:
            base = tr.max_traction_N(0.0) * rng.uniform(0.1, 0.5, B)
        out[k] = base
    return out


def _per_member(sc, u: float):
    """The command of one single plant in its input mode."""
    if sc.input_mode == "per_car":
        return np.full(sc.n_cars, u / sc.n_cars)
    return u


def _rate_single(name: str, U: np.ndarray, clock: Callable[[], float]) -> float:
    sc = get_scenario(name)
    plants = _plants(name, U.shape[1])
    dt = sc.dt_ctrl_s
    cmds = [[_per_member(sc, float(x)) for x in row] for row in U]
    t0 = clock()
    for row in cmds:
        for p, u in zip(plants, row, strict=True):
            p.step(u, dt)
    return U.size / (clock() - t0)


def _rate_batch(name: str, U: np.ndarray, clock: Callable[[], float]) -> float:
    sc = get_scenario(name)
    plants = _plants(name, U.shape[1])
    batch = BatchMultiCar(plants) if sc.n_cars > 1 else BatchSingleCar(plants)
    dt = sc.dt_ctrl_s
    active = np.ones(U.shape[1], dtype=bool)
    t0 = clock()
    for row in U:
        batch.step(row, dt, active)
    return U.size / (clock() - t0)


def run(name: str, B: int, rounds: int, steps: int, clock: Callable[[], float]) -> dict:
    _rate_single(name, _commands(name, B, 5, 99), clock)  # warm-up (compiled kernels)
    _rate_batch(name, _commands(name, B, 5, 99), clock)
    rates: dict[str, list[float]] = {"single": [], "batch": []}
    ratios = []
    for r in range(rounds):
        U = _commands(name, B, steps, r)
        order = ("single", "batch") if r % 2 == 0 else ("batch", "single")
        got = {w: (_rate_single if w == "single" else _rate_batch)(name, U, clock) for w in order}
        for w, v in got.items():
            rates[w].append(v)
        ratios.append(got["batch"] / got["single"])
    med = statistics.median
    return {
        "scenario": name,
        "B": B,
        "single": med(rates["single"]),
        "batch": med(rates["batch"]),
        "ratio": med(ratios),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenarios", nargs="*", default=list(SCENARIOS))
    ap.add_argument("--sizes", nargs="*", type=int, default=[1, 8, 40])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--steps", type=int, default=120, help="control steps per round")
    ap.add_argument("--cpu-time", action="store_true", help="process CPU time")
    args = ap.parse_args()
    clock = time.process_time if args.cpu_time else time.perf_counter
    print("| scenario | B | single [member-steps/s] | batch [member-steps/s] | batch / single |")
    print("|---|---:|---:|---:|---:|")
    for name in args.scenarios:
        for B in args.sizes:
            r = run(name, B, args.rounds, args.steps, clock)
            print(
                f"| {name} | {B} | {r['single']:.0f} | {r['batch']:.0f} | {r['ratio']:.2f} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
