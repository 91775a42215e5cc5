"""Env throughput: env steps/s, real-time factor, and where the step time goes.

Run: ``python benchmarks/bench_envs.py [--episodes 2] [--ids ...] [--noise 0.05]``. For
every registered id with its default controller (constant default action; with
``--noise s`` the default action plus Gaussian noise of std ``s`` in the action's [−1, 1]
units at every step, seeded: parameters that change at every env step, as under a
stochastic RL policy): env steps per second, the real-time
factor (simulated seconds per wall second), and where the wall time goes, measured by
wrapping the calls: the controller's ``compute`` (for the MPCs this contains OSQP's own
solve time, reported separately), the plant step, the closed-loop runner around them
(observation, recording of the trajectory row, termination checks: what a plain
``simulate`` pays too) and the env's own overhead (action mapping, observation
features, reward, info) = the rest. One untimed warm-up episode runs first (QP
construction on first use is a one-off cost).

``--side-by-side [--steps 300] [--rounds 5]``: per id, env steps/s at the constant
default action and under a new uniformly random action at every step (what an RL
agent's exploration sends), measured alternately in the same process (the order
flips every round; one warm-up episode of each first), with the median per-round ratio
random / constant; each round runs ``--steps`` env steps (episodes restart as needed,
reset time included). A third policy, "held random", draws a random action like the
random one but holds it for ``--hold`` env steps (default 50): it pays for the values
of random parameters (a controller may work harder at some weights than at its
defaults: shorter holds, more constrained steps) with almost none of the cost of
changing them, so random / held random is the share lost to the changes themselves and
held random / constant the share lost to the parameters' values. The three take turns
within a round (the order rotates every round).

``--osqp-tail [--steps 300]``: per id, the solve times of every QP solve that ran OSQP
or the exact finish first (``MPCSolution.solve_time_s``: OSQP plus the exact finish;
the RSMPC's candidates one by one) at the constant default action and under random
actions: how many of them the exact finish settled without OSQP, the 99th percentile
and the maximum, how many took more than 2 ms, the 99th percentile of the call's
thread CPU time, the ADMM iterations (99th percentile, maximum, solves at the
iteration cap: figures that do not depend on the machine's load), the solves finished
exactly by DAQP (a finish that ends in an infeasibility verdict counts too), the
median time per call of OSQP's part and of the finish, and the fallback commands.

``--compare OLD NEW [--rounds 5]`` runs the benchmark on two source trees (each a
directory holding ``train_envs``) in subprocesses, alternating the order every round,
and prints the median env steps/s of each and their ratio NEW/OLD per id.
``--cpu-time`` measures with the process's CPU time instead of the wall clock (stabler
on a shared machine; the real-time factor is then per CPU second).
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import os
import statistics
import subprocess
import sys
import time
from collections.abc import Sequence

import gymnasium as gym
import numpy as np

import train_envs  # noqa: F401
from train_envs.envs import params_to_action, registered_ids
from train_envs.mpc.osqp_backend import osqp_settings_with

#: the clock of every measurement (``--cpu-time``: this process's CPU time)
_clock = time.perf_counter


def bench(env_id: str, episodes: int, noise: float = 0.0) -> dict[str, float]:
    env = gym.make(env_id)
    base = env.unwrapped
    ctrl = base.controller
    plant_time = ctrl_time = solve_time = loop_time = 0.0
    orig_compute = ctrl.compute

    def timed_compute(obs):
        nonlocal ctrl_time, solve_time
        t0 = _clock()
        out = orig_compute(obs)
        ctrl_time += _clock() - t0
        solve_time += float(out[1].get("solve_time_s", 0.0))
        return out

    # one untimed episode first: controllers build their QPs on first use and keep them
    # (RSMPC: one per hold length), which a training run pays once, not per episode
    warm_action = params_to_action(env, {})
    env.reset(seed=10_000)
    done = False
    while not done:
        _, _, term, trunc, _ = env.step(warm_action)
        done = term or trunc
    ctrl.compute = timed_compute
    loop = base.loop
    orig_loop_step = loop.step

    def timed_loop_step(*args, **kw):
        nonlocal loop_time
        t0 = _clock()
        out = orig_loop_step(*args, **kw)
        loop_time += _clock() - t0
        return out

    loop.step = timed_loop_step
    rng = np.random.default_rng(0)
    steps = 0
    sim_s = 0.0
    wall = 0.0
    for ep in range(episodes):
        env.reset(seed=ep)
        plant = base.loop.plant
        orig_step = plant.step

        def timed_step(u, d, _orig=orig_step):
            nonlocal plant_time
            t0 = _clock()
            _orig(u, d)
            plant_time += _clock() - t0

        plant.step = timed_step
        action = params_to_action(env, {})
        t0 = _clock()
        done = False
        while not done:
            a = action
            if noise > 0.0:
                a = np.clip(action + noise * rng.standard_normal(action.shape), -1.0, 1.0)
                a = a.astype(np.float32)
            _, _, term, trunc, _ = env.step(a)
            steps += 1
            done = term or trunc
        wall += _clock() - t0
        sim_s += plant.t
    env.close()
    return {
        "env": env_id,
        "env_steps_per_s": steps / wall,
        "real_time_factor": sim_s / wall,
        "controller_share": ctrl_time / wall,
        "osqp_share": solve_time / wall,
        "plant_share": plant_time / wall,
        "runner_share": max(0.0, loop_time - ctrl_time - plant_time) / wall,
        "env_overhead_share": max(0.0, 1.0 - loop_time / wall),
        "env_overhead_us_per_step": max(0.0, wall - loop_time) / steps * 1e6,
    }


def _rate(env: gym.Env, actions: Sequence[np.ndarray], seed: int) -> float:
    """Env steps/s over the steps of ``actions``, drawn before the clock starts (a
    policy's cost is not the env's: ``Box.sample`` alone takes ~19 µs, a tenth of a PID
    env step)."""
    env.reset(seed=seed)
    t0 = _clock()
    for a in actions:
        _, _, term, trunc, _ = env.step(a)
        if term or trunc:
            env.reset(seed=seed)
    return len(actions) / (_clock() - t0)


def draw_actions(space: gym.Space, steps: int, hold: int = 1) -> list[np.ndarray]:
    """``steps`` actions: random draws of ``space`` (seeded by the caller), each held
    for ``hold`` steps (1: a new action every step)."""
    out: list[np.ndarray] = []
    while len(out) < steps:
        out.extend([space.sample()] * hold)
    return out[:steps]


def side_by_side(ids: list[str], steps: int, rounds: int, hold: int = 50) -> None:
    """Constant-, held-random- and random-action env steps/s per id, in turns, with the
    ratios random / constant and random / held random."""
    print(
        f"| env id | constant action [steps/s] | held random, {hold} steps [steps/s] | "
        f"random action [steps/s] | random / constant | random / held random | "
        f" ({rounds} rounds of {steps} steps)"
    )
    print("|---|---:|---:|---:|---:|---:|")
    names = ("constant", "held", "random")
    for env_id in ids:
        env = gym.make(env_id)
        space = env.action_space
        space.seed(0)
        held_space = copy.deepcopy(space)  # its own stream of held actions
        held_space.seed(1)
        a0 = params_to_action(env, {})
        draws = {
            "constant": lambda n, a0=a0: [a0] * n,
            "held": lambda n, sp=held_space: draw_actions(sp, n, hold),
            "random": lambda n, sp=space: draw_actions(sp, n),
        }
        for name in names:  # warm-up: QPs built on first use
            _rate(env, draws[name](steps // 4 + 1), seed=10_000)
        rates: dict[str, list[float]] = {name: [] for name in names}
        for r in range(rounds):
            for name in names[r % 3 :] + names[: r % 3]:
                rates[name].append(_rate(env, draws[name](steps), seed=r))
        env.close()
        med = statistics.median
        to_const = [b / a for a, b in zip(rates["constant"], rates["random"], strict=True)]
        to_held = [b / a for a, b in zip(rates["held"], rates["random"], strict=True)]
        print(
            f"| {env_id} | {med(rates['constant']):.0f} | {med(rates['held']):.0f} | "
            f"{med(rates['random']):.0f} | {med(to_const):.2f} | {med(to_held):.2f} |",
            flush=True,
        )


def osqp_tail(ids: list[str], steps: int) -> None:
    """OSQP solve-time tail per id at constant and random actions, per QP solve.

    Every :meth:`LinearMPC.solve` that ran OSQP or the exact finish first counts (the
    RSMPC's candidates one by one; "exact first": settled by the finish with no ADMM
    iteration): its solve time (OSQP plus the exact finish, wall clock, so it grows with the
    machine's load) and the thread CPU time of the whole call (less sensitive to the
    load), the ADMM iterations (independent of the load): their 99th percentile and
    maximum, the solves at OSQP's iteration cap (``max_iter``; a solve that needed the
    rescue cascade counts its iterations in all), the solves finished exactly by DAQP,
    the median time per call of OSQP's part and of the finish (the same solves: one
    process, interleaved) and the fallback commands.
    """
    from train_envs.mpc import recovery
    from train_envs.mpc.linear_mpc import LinearMPC

    max_iter = int(osqp_settings_with(None)["max_iter"])
    print(
        f"| env id | action | QP solves | exact first | p99 [ms] | max [ms] | > 2 ms "
        f"| CPU p99 [ms] | iterations p99 | iterations max | at the cap | finished exactly "
        f"| OSQP / finish median [ms] | fallbacks |  ({steps} steps)"
    )
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    rows: list[tuple[float, float, float, float, float]] = []
    finish = [0.0, 0.0]  # time of the last finish, count of the finishes
    solve, exact = LinearMPC.solve, getattr(recovery._RecoveryMixin, "_exact", None)

    def timed_solve(self, *args, **kwargs):
        finish[0] = 0.0
        c0 = time.thread_time()
        sol = solve(self, *args, **kwargs)
        cpu = time.thread_time() - c0
        if sol.solve_time_s > 0.0:
            rows.append(
                (sol.solve_time_s, cpu, float(sol.iterations), float(sol.fallback), finish[0])
            )
        return sol

    def timed_exact(self, x, y):
        t0 = time.perf_counter()
        out = exact(self, x, y)
        finish[0] = time.perf_counter() - t0
        return out

    LinearMPC.solve = timed_solve
    if exact is not None:
        recovery._RecoveryMixin._exact = timed_exact
    try:
        for env_id in ids:
            env = gym.make(env_id)
            space = env.action_space
            space.seed(0)
            acts = {"constant": [params_to_action(env, {})] * steps}
            acts["random"] = draw_actions(space, steps)
            for name, act in acts.items():
                rows.clear()
                _rate(env, act, seed=0)
                a = np.array(rows).reshape(-1, 5) * [1e3, 1e3, 1, 1, 1e3]
                t, cpu, it, f = a[:, 0], a[:, 1], a[:, 2], a[:, 4]
                fin = f > 0.0
                t_osqp = float(np.median(t - f)) if t.size else 0.0
                t_fin = float(np.median(f[fin])) if fin.any() else 0.0
                p99 = float(np.percentile(t, 99)) if t.size else 0.0
                c99 = float(np.percentile(cpu, 99)) if t.size else 0.0
                it99 = float(np.percentile(it, 99)) if it.size else 0.0
                print(
                    f"| {env_id} | {name} | {t.size} | {int(np.sum(it == 0))} | {p99:.2f} | "
                    f"{t.max(initial=0.0):.2f} | "
                    f"{int(np.sum(t > 2.0))} | {c99:.2f} | {it99:.0f} | "
                    f"{it.max(initial=0.0):.0f} | {int(np.sum(it >= max_iter))} | "
                    f"{int(fin.sum())} | {t_osqp:.2f} / {t_fin:.2f} | "
                    f"{int(np.sum(a[:, 3] > 0))} |",
                    flush=True,
                )
            env.close()
    finally:
        LinearMPC.solve = solve
        if exact is not None:
            recovery._RecoveryMixin._exact = exact


def compare(
    old: str,
    new: str,
    ids: list[str] | None,
    episodes: int,
    noise: float,
    rounds: int,
    cpu_time: bool = False,
) -> None:
    """Median env steps/s of two source trees, measured in alternating subprocesses."""
    trees = {"old": os.path.abspath(old), "new": os.path.abspath(new)}
    rates: dict[str, dict[str, list[float]]] = {"old": {}, "new": {}}
    overhead: dict[str, dict[str, list[float]]] = {"old": {}, "new": {}}
    args = ["--json", "--episodes", str(episodes), "--noise", str(noise)]
    if cpu_time:
        args.append("--cpu-time")
    if ids:
        args += ["--ids", *ids]
    for r in range(rounds):
        for which in ("old", "new") if r % 2 == 0 else ("new", "old"):
            env = dict(os.environ, PYTHONPATH=trees[which])
            out = subprocess.run(
                [sys.executable, os.path.abspath(__file__), *args],
                env=env,
                capture_output=True,
                text=True,
                check=True,
                cwd=trees[which],
            ).stdout
            for row in json.loads(out.strip().splitlines()[-1]):
                rates[which].setdefault(row["env"], []).append(row["env_steps_per_s"])
                us = row["env_overhead_us_per_step"]
                overhead[which].setdefault(row["env"], []).append(us)
                print(
                    f"round {r} {which} {row['env']} {row['env_steps_per_s']:.0f}", file=sys.stderr
                )
    # every order occurs equally often over an even number of rounds: the geometric mean
    # of the per-round ratios cancels a bias of the position in the pair
    print(
        f"| env id | old steps/s | new steps/s | new/old median | new/old geo. mean "
        f"| env overhead old / new [µs/step] |  ({rounds} rounds)"
    )
    print("|---|---:|---:|---:|---:|---:|")
    for env_id, old_rates in rates["old"].items():
        new_rates = rates["new"][env_id]
        ratios = [b / a for a, b in zip(old_rates, new_rates, strict=True)]
        geo = math.exp(statistics.fmean(math.log(x) for x in ratios))
        print(
            f"| {env_id} | {statistics.median(old_rates):.0f} | "
            f"{statistics.median(new_rates):.0f} | {statistics.median(ratios):.3f} | "
            f"{geo:.3f} | {statistics.median(overhead['old'][env_id]):.0f} / "
            f"{statistics.median(overhead['new'][env_id]):.0f} |"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--episodes", type=int, default=2)
    ap.add_argument("--ids", nargs="*", default=None)
    ap.add_argument("--noise", type=float, default=0.0, help="action noise std (RL-like)")
    ap.add_argument("--json", action="store_true", help="print the rows as one JSON line")
    ap.add_argument("--compare", nargs=2, metavar=("OLD", "NEW"), help="two source trees")
    ap.add_argument("--rounds", type=int, default=5, help="--compare: alternating rounds")
    ap.add_argument("--cpu-time", action="store_true", help="measure process CPU time")
    ap.add_argument("--side-by-side", action="store_true", help="constant vs random action per id")
    ap.add_argument("--steps", type=int, default=300, help="--side-by-side: steps per round")
    ap.add_argument("--hold", type=int, default=50, help="--side-by-side: held-random hold")
    ap.add_argument("--osqp-tail", action="store_true", help="OSQP solve-time tail per id")
    args = ap.parse_args()
    if args.cpu_time:
        global _clock
        _clock = time.process_time
    if args.compare:
        compare(*args.compare, args.ids, args.episodes, args.noise, args.rounds, args.cpu_time)
        return
    ids = args.ids or registered_ids()
    if args.osqp_tail:
        osqp_tail(ids, args.steps)
        return
    if args.side_by_side:
        side_by_side(ids, args.steps, args.rounds, args.hold)
        return
    rows = [bench(env_id, args.episodes, args.noise) for env_id in ids]
    if args.json:
        print(json.dumps(rows))
        return
    print(
        "| env id | env steps/s | real-time factor | controller | of which OSQP | plant "
        "| runner | env overhead |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        print(
            f"| {r['env']} | {r['env_steps_per_s']:.0f} | {r['real_time_factor']:.0f} | "
            f"{100 * r['controller_share']:.0f} % | {100 * r['osqp_share']:.0f} % | "
            f"{100 * r['plant_share']:.0f} % | {100 * r['runner_share']:.0f} % | "
            f"{100 * r['env_overhead_share']:.0f} % |"
        )


if __name__ == "__main__":
    main()
