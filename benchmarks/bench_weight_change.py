"""Cost of a parameter change next to one control step, per controller, in one process.

Run: ``python benchmarks/bench_weight_change.py [--steps 400] [--rounds 3]
[--controllers mpc ...] [--cpu-time] [--profile NAME] [--rebuild]``. For each controller on its
paper's scenario, a closed loop runs with a new random parameter vector before every
control step (uniform in the action's [−1, 1] units, mapped by
:meth:`TunableParam.from_unit`, seeded): the ``set_params`` call and the following
``compute`` are timed separately, alternating within the same loop. A second loop of
the same length at the default parameters gives the control step at constant weights.
Reported: the medians of ``set_params``, of ``compute`` under changing weights and of
``compute`` at constant weights, the ratio ``set_params`` / constant-weight step, and
the change cost: the mean of ``set_params + compute`` under changing weights minus the
mean constant-weight step, over the mean constant-weight step -- what a change really
costs, wherever the controller does the work (the tube MPCs defer it to the next step
that solves; the RSMPC's steps between triggers solve nothing) -- the acceptance
figure. One untimed warm-up episode first (QPs built on first use).
``--rounds R`` repeats both loops R times per controller (a new parameter sequence each
round, the controllers taken in turn within a round, so drifts of a shared machine hit
all alike) and reports the median over the rounds of every column. ``--cpu-time``
times with this thread's CPU time instead of the wall clock (stabler on a busy
machine). ``--profile NAME`` prints the cProfile of the changing-weight loop of one
controller instead. ``--rebuild`` times, for the tube MPCs, one change with the work
it defers done at once (every problem it holds re-weighted, its closed form made), per
problem: the cost of the weight path without the closed loop's noise.
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import statistics
import time
from collections.abc import Callable

import numpy as np

from train_envs.controllers import make_controller
from train_envs.scenarios import get_scenario
from train_envs.simulation import ClosedLoop

#: controller -> its paper's scenario
CASES: dict[str, str] = {
    "mpc": "paper001_stopping",
    "sempc": "paper000_single_section",
    "rmpc": "paper001_stopping",
    "rsmpc": "paper001_stopping",
    "adaptive_mpc": "paper002_cruise",
    "fuzzy_mpc": "paper003_cruise",
    "dmc": "paper004_urban",
}


def _loop(name: str) -> tuple[ClosedLoop, object]:
    sc = get_scenario(CASES[name])
    ctrl = make_controller(name, scenario=sc)
    loop = ClosedLoop(sc, ctrl)
    loop.reset(seed=0)
    while not loop.done:  # warm-up episode
        loop.step(ctrl.compute(loop.observe())[0])
    return loop, ctrl


def run(
    name: str, steps: int, seed: int = 0, clock: Callable[[], float] = time.perf_counter
) -> dict[str, float]:
    """Medians [µs] of set_params and compute (changing and constant weights), timed by
    ``clock``."""
    loop, ctrl = _loop(name)
    specs = ctrl.tunable_params()
    rng = np.random.default_rng(seed)
    t_set: list[float] = []
    t_step: list[float] = []
    loop.reset(seed=0)
    for _ in range(steps):
        if loop.done:
            loop.reset(seed=0)
        units = rng.uniform(-1.0, 1.0, len(specs))
        params = {p.name: p.from_unit(a) for p, a in zip(specs, units, strict=True)}
        obs = loop.observe()
        t0 = clock()
        try:
            ctrl.set_params(**params)
        except ValueError:  # a combination the controller refuses (dmc: alpha_min > max)
            continue
        t1 = clock()
        u, _ = ctrl.compute(obs)
        t2 = clock()
        loop.step(u)
        t_set.append(t1 - t0)
        t_step.append(t2 - t1)
    ctrl.set_params(**{p.name: p.default for p in specs})
    t_const: list[float] = []
    loop.reset(seed=0)
    for _ in range(steps):
        if loop.done:
            loop.reset(seed=0)
        obs = loop.observe()
        t1 = clock()
        u, _ = ctrl.compute(obs)
        t_const.append(clock() - t1)
        loop.step(u)
    med = statistics.median
    mean_const = statistics.fmean(t_const)
    const = med(t_const)
    return {
        "set_us": 1e6 * med(t_set),
        "step_us": 1e6 * med(t_step),
        "const_us": 1e6 * const,
        "ratio": med(t_set) / const,
        "change_ratio": (statistics.fmean(t_set) + statistics.fmean(t_step)) / mean_const - 1.0,
    }


def run_rebuild(name: str, changes: int, seed: int = 0) -> float:
    """Median thread CPU time [µs] of one parameter change of a tube MPC with its
    deferred work done at once: ``set_params``, then every problem it holds re-weighted
    and its closed form re-composed (``_problem(M)``, ``_explicit``), without a solve."""
    loop, ctrl = _loop(name)
    specs = ctrl.tunable_params()
    holds = sorted(ctrl._problems)
    rng = np.random.default_rng(seed)
    times: list[float] = []
    for _ in range(changes):
        units = rng.uniform(-1.0, 1.0, len(specs))
        params = {p.name: p.from_unit(a) for p, a in zip(specs, units, strict=True)}
        t0 = time.thread_time()
        ctrl.set_params(**params)
        for M in holds:
            ctrl._explicit(ctrl._problem(M))
        times.append(time.thread_time() - t0)
    return 1e6 * statistics.median(times) / len(holds)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=400, help="control steps per loop")
    ap.add_argument("--rounds", type=int, default=1, help="repetitions (median reported)")
    ap.add_argument("--controllers", nargs="*", default=list(CASES), choices=list(CASES))
    ap.add_argument("--profile", choices=list(CASES), help="profile one controller")
    ap.add_argument("--cpu-time", action="store_true", help="time with the thread's CPU time")
    ap.add_argument(
        "--rebuild",
        action="store_true",
        help="tube MPCs: CPU time of one change with every held problem rebuilt, per problem",
    )
    args = ap.parse_args()
    if args.rebuild:
        print("| controller | one change, per held problem [µs] |")
        print("|---|---:|")
        for name in [c for c in args.controllers if c in ("rmpc", "rsmpc")]:
            res = [run_rebuild(name, args.steps, seed=r) for r in range(args.rounds)]
            print(f"| `{name}` | {statistics.median(res):.0f} |", flush=True)
        return
    clock = time.thread_time if args.cpu_time else time.perf_counter
    if args.profile:
        prof = cProfile.Profile()
        prof.enable()
        run(args.profile, args.steps, clock=clock)
        prof.disable()
        pstats.Stats(prof).sort_stats("cumulative").print_stats(35)
        return
    print(
        "| controller | set_params [µs] | step, changing weights [µs] | "
        "step, constant weights [µs] | set / step | change / step, means |"
    )
    print("|---|---:|---:|---:|---:|---:|")
    rounds: dict[str, list[dict[str, float]]] = {name: [] for name in args.controllers}
    for r in range(args.rounds):
        for name in args.controllers:
            rounds[name].append(run(name, args.steps, seed=r, clock=clock))
    for name, res in rounds.items():
        m = {k: statistics.median(x[k] for x in res) for k in res[0]}
        print(
            f"| `{name}` | {m['set_us']:.0f} | {m['step_us']:.0f} | {m['const_us']:.0f} | "
            f"{m['ratio']:.2f} | {m['change_ratio']:.2f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
