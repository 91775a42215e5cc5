"""PPO training throughput (env steps/s) by vectorisation: DummyVecEnv ×1, SubprocVecEnv
×1 and ×2, DummyVecEnv ×4 against the native vector env ×4 (``--configs``).

Every configuration trains PPO for ``--timesteps`` env steps on each env id with the
same rollout size (``n_steps = rollout // n_envs``), no evaluation, no checkpoints and
no TensorBoard; the rate is env steps over ``model.learn`` wall time (PPO updates
included, env start-up excluded). Configurations are interleaved within each repeat so
that background load affects them alike; the table shows the median over repeats.

Usage::

    .venv/bin/python benchmarks/bench_agents.py [--timesteps 1024] [--repeats 2]
        [--configs dummy:1 native:4 ...]

``--env-share [--envs ...]``: PPO with the SB3 settings of ``agents/hyperparams/ppo.yml``
(one in-process env, VecNormalize, one torch thread) on each id and on a trivial env of
the same observation and action spaces (zero observations, zero reward, episodes of
the real env's mean length): env steps/s of ``learn`` and the share of its wall time
spent in the env's ``step`` and ``reset`` (timed by a wrapper), per id.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time

import gymnasium as gym
import numpy as np
import pandas as pd

from agents.training import VEC_KINDS, TrainConfig, train

ENVS = ("TrainEnvs/Stopping001PID-v0", "TrainEnvs/Urban004-v0")
CONFIGS = (("dummy", 1), ("subproc", 1), ("subproc", 2), ("dummy", 4), ("native", 4))
SHARE_ENVS = ("TrainEnvs/Stopping001-v0", "TrainEnvs/Section000-v0")


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


class _Timed(gym.Wrapper):
    """Accumulates the wall time of ``step`` and ``reset``; counts episodes."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.seconds = 0.0
        self.episodes = 0
        self.steps = 0

    def step(self, action):
        t0 = time.perf_counter()
        out = self.env.step(action)
        self.seconds += time.perf_counter() - t0
        self.steps += 1
        return out

    def reset(self, **kw):
        t0 = time.perf_counter()
        out = self.env.reset(**kw)
        self.seconds += time.perf_counter() - t0
        self.episodes += 1
        return out


class _TrivialEnv(gym.Env):
    """The spaces of a real env, zero observations and rewards, fixed episode length."""

    def __init__(self, observation_space, action_space, length: int) -> None:
        self.observation_space, self.action_space = observation_space, action_space
        self._length, self._k = max(1, int(length)), 0
        self._obs = np.zeros(observation_space.shape, observation_space.dtype)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self._k = 0
        return self._obs, {}

    def step(self, action):
        self._k += 1
        return self._obs, 0.0, False, self._k >= self._length, {}


def ppo_env_share(env_id: str, timesteps: int, seed: int = 0) -> dict[str, float]:
    """PPO env steps/s and the env's share of ``learn`` on ``env_id`` and a trivial twin."""
    import torch
    import yaml
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    import train_envs  # noqa: F401

    with open("agents/hyperparams/ppo.yml") as f:
        entries = yaml.safe_load(f)
    hp = dict(entries.get(env_id, entries["default"]))
    norm = hp.pop("normalize", {})
    policy = hp.pop("policy", "MlpPolicy")
    for k in ("n_timesteps", "n_envs", "env_kwargs"):
        hp.pop(k, None)
    torch.set_num_threads(1)
    out: dict[str, float] = {}
    real = _Timed(gym.make(env_id))
    for name, env in (("env", real), ("trivial", None)):
        if env is None:  # the trivial twin, episodes of the real env's mean length
            length = real.steps / max(real.episodes, 1)
            env = _Timed(_TrivialEnv(real.observation_space, real.action_space, length))
        venv = VecNormalize(DummyVecEnv([lambda env=env: env]), **norm)
        model = PPO(policy, venv, seed=seed, device="cpu", verbose=0, **hp)
        t0 = time.perf_counter()
        model.learn(timesteps)
        wall = time.perf_counter() - t0
        out[f"{name}_steps_per_s"] = timesteps / wall
        out[f"{name}_share"] = env.seconds / wall
    return out


def _config(text: str) -> tuple[str, int]:
    """``vec:n`` -> ``(vec, n)`` (an argparse type: anything else is a usage error)."""
    vec, _, n = text.partition(":")
    if vec not in VEC_KINDS or not n.isdigit() or int(n) < 1:
        raise argparse.ArgumentTypeError(
            f"{text!r}: expected VEC:N, VEC one of {', '.join(VEC_KINDS)} and N >= 1"
        )
    return vec, int(n)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--timesteps", type=int, default=1024, help="env steps per run")
    p.add_argument("--rollout", type=int, default=512, help="PPO rollout size (all envs)")
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--envs", nargs="+", default=None)
    p.add_argument("--env-share", action="store_true", help="PPO env share vs trivial env")
    p.add_argument(
        "--configs",
        nargs="+",
        type=_config,
        default=None,
        metavar="VEC:N",
        help=f"vectorisations as vec:n_envs (vec: {', '.join(VEC_KINDS)}); default "
        + " ".join(f"{v}:{n}" for v, n in CONFIGS),
    )
    args = p.parse_args(argv)
    configs = CONFIGS if args.configs is None else tuple(args.configs)
    if args.env_share:
        print(
            "| env id | PPO steps/s | env share of wall time | trivial env: PPO steps/s "
            f"| env share |  ({args.timesteps} steps, one env)"
        )
        print("|---|---:|---:|---:|---:|")
        for env_id in args.envs or list(SHARE_ENVS):
            r = ppo_env_share(env_id, args.timesteps)
            print(
                f"| {env_id} | {r['env_steps_per_s']:.0f} | {100 * r['env_share']:.0f} % | "
                f"{r['trivial_steps_per_s']:.0f} | {100 * r['trivial_share']:.0f} % |",
                flush=True,
            )
        load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
        print(f"({os.cpu_count()} CPU(s), load average {load:.1f} at the end)")
        return 0
    args.envs = args.envs or list(ENVS)
    rates: dict[tuple[str, str], list[float]] = {}
    t0 = time.perf_counter()
    for rep in range(args.repeats):
        for env_id in args.envs:
            for vec, n in configs:
                r = measure(env_id, vec, n, args.timesteps, args.rollout, seed=rep)
                rates.setdefault((env_id, f"{vec} x{n}"), []).append(r)
                print(f"  repeat {rep}: {env_id} {vec} x{n}: {r:.1f} steps/s", flush=True)
    rows = []
    for (env_id, cfg), vals in rates.items():
        rows.append({"env": env_id, "vec_env": cfg, "steps_per_s": statistics.median(vals)})
    df = pd.DataFrame(rows)
    table = df.pivot(index="env", columns="vec_env", values="steps_per_s")
    table = table[[f"{v} x{n}" for v, n in configs]]
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
