"""Evaluate a driver (fixed parameters, a policy, or the controller's defaults) on an env id.

This is the function the tuners and the agents call: it runs whole episodes through
the registered env and returns one row per episode with every metric of
:func:`train_envs.metrics.episode_metrics` plus the return and the episode length.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
import pandas as pd

Driver = Mapping[str, float] | Callable[[np.ndarray], np.ndarray] | Any | None


def params_to_action(env: gym.Env, params: Mapping[str, float]) -> np.ndarray:
    """The constant absolute-mode action that sets the given parameter values.

    Parameters the env exposes but ``params`` omits keep the controller's defaults. The
    action is float64 (the env accepts it) so that it maps back onto the parameters to
    floating-point precision; a float32 cast would move them by ~1e-7 relative.
    """
    base = env.unwrapped
    specs = base.param_specs
    unknown = set(params) - {p.name for p in specs}
    if unknown:
        raise ValueError(
            f"params {sorted(unknown)} are not actions of this env; allowed: "
            f"{[p.name for p in specs]}"
        )
    defaults = base.controller.get_params()
    return np.array(
        [p.to_unit(p.check(params.get(p.name, defaults[p.name]))) for p in specs], dtype=np.float64
    )


def _policy_fn(env: gym.Env, driver: Driver) -> Callable[[np.ndarray], np.ndarray]:
    if driver is None:
        return _policy_fn(env, {})
    if isinstance(driver, Mapping):
        if env.unwrapped.config["action_mode"] != "absolute":
            raise ValueError("fixed-parameter evaluation needs action_mode='absolute'")
        action = params_to_action(env, driver)
        return lambda _obs: action
    if hasattr(driver, "predict"):  # stable-baselines3 model
        return lambda obs: driver.predict(obs, deterministic=True)[0]
    if callable(driver):
        return driver
    raise TypeError(
        f"driver must be a params mapping, a policy callable or an SB3 model, got {driver!r}"
    )


def evaluate(
    env_id: str,
    driver: Driver = None,
    *,
    episodes: int | None = None,
    seeds: Sequence[int] | Iterable[int] | None = None,
    config: Mapping[str, Any] | None = None,
    label: str | None = None,
) -> pd.DataFrame:
    """Run ``driver`` on ``env_id`` for the given seeds; one DataFrame row per episode.

    ``seeds`` defaults to ``range(episodes)`` (``episodes`` defaults to 1). The same
    seeds give the same table.
    """
    if seeds is None:
        seeds = range(episodes or 1)
    seeds = [int(s) for s in seeds]
    env = gym.make(env_id, config=dict(config or {}))
    policy = _policy_fn(env, driver)
    rows = []
    try:
        for i, seed in enumerate(seeds):
            obs, _ = env.reset(seed=seed)
            ret, n, done, info = 0.0, 0, False, {}
            while not done:
                obs, r, term, trunc, info = env.step(policy(obs))
                ret += r
                n += 1
                done = term or trunc
            rows.append(
                {
                    "env": env_id,
                    "driver": label or _label(driver),
                    "episode": i,
                    "seed": seed,
                    "scenario": env.unwrapped.scenario.name,
                    "return": ret,
                    "env_steps": n,
                    **info.get("episode_metrics", {}),
                }
            )
    finally:
        env.close()
    return pd.DataFrame(rows)


def _label(driver: Driver) -> str:
    if driver is None:
        return "defaults"
    if isinstance(driver, Mapping):
        return "params(" + ", ".join(f"{k}={v:.4g}" for k, v in driver.items()) + ")"
    return type(driver).__name__
