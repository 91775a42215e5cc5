"""PPO training throughput (env steps/s): DummyVecEnv ×1 vs SubprocVecEnv ×1 and ×2.

Every configuration trains PPO for ``--timesteps`` env steps on each env id with the
same rollout size (``n_steps = rollout // n_envs``), no evaluation, no checkpoints and
no TensorBoard; the rate is env steps over ``model.learn`` wall time (PPO updates
included, env start-up excluded). Configurations are interleaved within each repeat so
that background load affects them alike; the table shows the median over repeats.

Usage::

    .venv/bin/python benchmarks/bench_agents.py [--timesteps 1024] [--repeats 2]
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time

import pandas as pd

from agents.training import TrainConfig, train

ENVS = ("TrainEnvs/Stopping001PID-v0", "TrainEnvs/Urban004-v0")
CONFIGS = (("dummy", 1), ("subproc", 1), ("subproc", 2))


def measure(env_id: str, vec: str, n_envs: int, timesteps: int, rollout: int, seed: int) -> float:
    """Env steps/s of one PPO training run."""
    with tempfile.TemporaryDirectory() as tmp:
        res = train(
            TrainConfig(
                env_id=env_id,
                algo="ppo",
                timesteps=timesteps,
                seed=seed,
                out=tmp,
                n_envs=n_envs,
                vec=vec,
                hyperparams={"n_steps": rollout // n_envs, "batch_size": 64},
                eval_freq=0,
                checkpoint_freq=0,
                tensorboard=False,
            )
        )
    return res.steps_per_s


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--timesteps", type=int, default=1024, help="env steps per run")
    p.add_argument("--rollout", type=int, default=512, help="PPO rollout size (all envs)")
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--envs", nargs="+", default=list(ENVS))
    args = p.parse_args(argv)
    rates: dict[tuple[str, str], list[float]] = {}
    t0 = time.perf_counter()
    for rep in range(args.repeats):
        for env_id in args.envs:
            for vec, n in CONFIGS:
                r = measure(env_id, vec, n, args.timesteps, args.rollout, seed=rep)
                rates.setdefault((env_id, f"{vec} x{n}"), []).append(r)
                print(f"  repeat {rep}: {env_id} {vec} x{n}: {r:.1f} steps/s", flush=True)
    rows = []
    for (env_id, cfg), vals in rates.items():
        rows.append({"env": env_id, "vec_env": cfg, "steps_per_s": statistics.median(vals)})
    df = pd.DataFrame(rows)
    table = df.pivot(index="env", columns="vec_env", values="steps_per_s")
    table = table[[f"{v} x{n}" for v, n in CONFIGS]]
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(
        f"\nPPO training throughput [env steps/s], median of {args.repeats} repeat(s), "
        f"{args.timesteps} steps each, rollout {args.rollout}; {os.cpu_count()} CPU(s), "
        f"load average {load:.1f}; {time.perf_counter() - t0:.0f} s total"
    )
    print(table.to_string(float_format=lambda v: f"{v:.1f}"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
