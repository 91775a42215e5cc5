"""Step cost of paper 001's tube MPC ("rmpc") and robust self-triggered MPC ("rsmpc").

Run: ``python benchmarks/bench_robust_mpc.py [--horizons 3 5 10 15] [--episodes 2]``.

Part 1, controllers side by side: for each horizon N, three closed loops of paper 001's
stopping scenario under the unknown resistance (±0.05 m/s², seed 0) run in lockstep in
one process — the plain single-point ``mpc`` with the same horizon, ``rmpc`` and
``rsmpc`` — one control step of each in turn, so that machine load hits all three
alike.  A warm-up episode builds every QP first (the RSMPC family has N − 1 of them,
kept across episodes).  Per control step we time the controller's ``compute`` and read
OSQP's own ``solve_time`` (summed over the QPs of an RSMPC trigger).  Reported over
whole episodes: median and mean wall time per step, median OSQP time per step, the
ratio of the medians (and means) to ``mpc``; for RSMPC also the wall time per trigger
the hold lengths examined per trigger and how many of them were solved (the others
were rejected by the unconstrained lower bound without a solve).

Part 2, env throughput: ``gymnasium.make("TrainEnvs/Stopping001-v0")`` (rsmpc; and
with ``config={"controller": "rmpc"}``) with the constant default action: env steps
per second and the real-time factor (simulated seconds per wall second, plant and env
included); the first episode (QP builds) is reported apart from the warm ones.  The
PID env of the same scenario is the ceiling set by the plant and the env's own
bookkeeping.

BLAS is limited to one thread (the QP builds are small dense products; see
:func:`train_envs.mpc.blas.single_thread_blas`).
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402

import train_envs  # noqa: E402, F401
from train_envs.controllers import make_controller  # noqa: E402
from train_envs.envs import params_to_action  # noqa: E402
from train_envs.scenarios import DisturbanceSpec, get_scenario  # noqa: E402
from train_envs.simulation import ClosedLoop  # noqa: E402

NAMES = ("mpc", "rmpc", "rsmpc")


def _lockstep(N: int, episodes: int) -> dict[str, dict[str, float]]:
    sc = get_scenario("paper001_stopping").with_overrides(
        disturbance=DisturbanceSpec(random_bound_mps2=0.05)
    )
    ctrls = {
        "mpc": make_controller("mpc", sc, Np=N),
        "rmpc": make_controller("rmpc", sc, N=N),
        "rsmpc": make_controller("rsmpc", sc, N=N),
    }
    loops = {k: ClosedLoop(sc, c) for k, c in ctrls.items()}
    wall: dict[str, list[float]] = {k: [] for k in NAMES}
    osqp: dict[str, list[float]] = {k: [] for k in NAMES}
    trig_wall: list[float] = []
    qps: list[int] = []
    cands: list[int] = []
    closed: list[int] = []
    for ep in range(episodes + 1):  # episode 0: warm-up (QP builds), not timed
        for lp in loops.values():
            lp.reset(seed=0)
        while not all(lp.done for lp in loops.values()):
            for name, lp in loops.items():
                if lp.done:
                    continue
                obs = lp.observe()
                t0 = time.perf_counter()
                u, info = ctrls[name].compute(obs)
                dt = time.perf_counter() - t0
                lp.step(u)
                if ep == 0:
                    continue
                wall[name].append(dt)
                osqp[name].append(float(info.get("solve_time_s", 0.0)))
                if name == "rsmpc" and info.get("triggered"):
                    trig_wall.append(dt)
                    qps.append(int(info["qp_solves"]))
                    cands.append(int(info["candidates"]))
                    closed.append(int(info["closed_form"]))
    out: dict[str, dict[str, float]] = {}
    ref_med, ref_mean = float(np.median(wall["mpc"])), float(np.mean(wall["mpc"]))
    for name in NAMES:
        w = np.asarray(wall[name])
        out[name] = {
            "steps": w.size / episodes,
            "med_us": 1e6 * float(np.median(w)),
            "mean_us": 1e6 * float(w.mean()),
            "osqp_med_us": 1e6 * float(np.median(osqp[name])),
            "osqp_mean_us": 1e6 * float(np.mean(osqp[name])),
            "ratio_med": float(np.median(w)) / ref_med,
            "ratio_mean": float(w.mean()) / ref_mean,
        }
    out["rsmpc"]["trigger_med_us"] = 1e6 * float(np.median(trig_wall))
    out["rsmpc"]["trigger_mean_us"] = 1e6 * float(np.mean(trig_wall))
    out["rsmpc"]["qps_per_trigger"] = float(np.mean(qps))
    out["rsmpc"]["candidates_per_trigger"] = float(np.mean(cands))
    out["rsmpc"]["closed_per_trigger"] = float(np.mean(closed))
    out["rsmpc"]["triggers"] = len(trig_wall) / episodes
    return out


def _env_rtf(env_id: str, config: dict, episodes: int) -> list[dict[str, float]]:
    env = gym.make(env_id, config=config)
    base = env.unwrapped
    action = params_to_action(env, {})
    rows = []
    for ep in range(episodes + 1):
        env.reset(seed=ep)
        steps, done = 0, False
        t0 = time.perf_counter()
        while not done:
            _, _, term, trunc, _ = env.step(action)
            steps += 1
            done = term or trunc
        wall = time.perf_counter() - t0
        rows.append(
            {
                "episode": ep,
                "env_steps_per_s": steps / wall,
                "control_steps_per_s": base.loop.k / wall,
                "rtf": base.loop.plant.t / wall,
                "wall_s": wall,
            }
        )
    env.close()
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--horizons", type=int, nargs="*", default=[3, 5, 10, 15])
    ap.add_argument("--episodes", type=int, default=2, help="timed episodes per horizon")
    ap.add_argument("--env-episodes", type=int, default=3, help="warm env episodes")
    args = ap.parse_args()
    print(
        "| N | controller | median wall/step [µs] | mean wall/step [µs] | median OSQP/step [µs] "
        "| mean OSQP/step [µs] | median ratio to mpc | mean ratio to mpc |"
    )
    print("|---:|---|---:|---:|---:|---:|---:|---:|")
    trig_rows = []
    for N in args.horizons:
        r = _lockstep(N, args.episodes)
        for name in NAMES:
            x = r[name]
            print(
                f"| {N} | {name} | {x['med_us']:.0f} | {x['mean_us']:.0f} | "
                f"{x['osqp_med_us']:.0f} | {x['osqp_mean_us']:.0f} | {x['ratio_med']:.2f} | "
                f"{x['ratio_mean']:.2f} |"
            )
        trig_rows.append((N, r["rsmpc"]))
    print()
    print(
        "| N | RSMPC triggers/episode | hold lengths examined/trigger "
        "| decided in closed form/trigger | QPs solved/trigger "
        "| median wall/trigger [µs] | mean wall/trigger [µs] |"
    )
    print("|---:|---:|---:|---:|---:|---:|---:|")
    for N, x in trig_rows:
        print(
            f"| {N} | {x['triggers']:.0f} | {x['candidates_per_trigger']:.2f} | "
            f"{x['closed_per_trigger']:.2f} | {x['qps_per_trigger']:.2f} | "
            f"{x['trigger_med_us']:.0f} | {x['trigger_mean_us']:.0f} |"
        )
    print()
    print("Env throughput (default action, decision_interval 5; the PID env is the ceiling")
    print("set by plant + env bookkeeping):")
    print("| env | episode | env steps/s | control steps/s | real-time factor | wall [s] |")
    print("|---|---|---:|---:|---:|---:|")
    cases = [
        ("TrainEnvs/Stopping001-v0", {}, "Stopping001-v0 (rsmpc, N = 10)"),
        ("TrainEnvs/Stopping001-v0", {"controller": "rmpc"}, "Stopping001-v0 with rmpc, N = 10"),
        ("TrainEnvs/Stopping001PID-v0", {}, "Stopping001PID-v0 (pid)"),
    ]
    for env_id, config, label in cases:
        for row in _env_rtf(env_id, config, args.env_episodes):
            ep = "first (builds QPs)" if row["episode"] == 0 else str(row["episode"])
            print(
                f"| {label} | {ep} | {row['env_steps_per_s']:.0f} | "
                f"{row['control_steps_per_s']:.0f} | {row['rtf']:.0f} | {row['wall_s']:.3f} |"
            )


if __name__ == "__main__":
    main()
