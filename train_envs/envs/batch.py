"""Evaluate many parameter vectors of one env id at once (the tuners' lockstep backend).

:func:`evaluate_env_params_batch` returns, for each parameter mapping, the table
:func:`train_envs.envs.evaluation.evaluate_env_params` gives for it with
``label="tuner"`` and a reused env; :func:`supports_batch` says for which env ids the
lockstep path is the tuners' default (those whose inner controller is PID, Fuzzy-PID or
DMC). This module evaluates the members one after the other on the process's reused env.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import gymnasium as gym
import pandas as pd

from train_envs.envs.config import EnvConfig
from train_envs.envs.evaluation import evaluate_env_params

__all__ = ["evaluate_env_params_batch", "supports_batch"]

# inner controllers whose env ids take the lockstep path
_CONTROLLERS = ("pid", "fuzzy_pid", "dmc")


def supports_batch(env_id: str, config: Mapping | None = None) -> bool:
    """Whether ``env_id`` with ``config`` merged over its own has a batchable controller."""
    import train_envs  # noqa: F401  (registers the ids)

    spec = gym.registry.get(env_id.rsplit(":", 1)[-1])
    if spec is None:
        return False
    base = (spec.kwargs or {}).get("base_config")
    name = EnvConfig.resolve(base, config).controller.name
    return name in _CONTROLLERS


def evaluate_env_params_batch(
    env_id: str,
    params_list: Sequence[Mapping[str, float]],
    seeds: Sequence[int],
    config: Mapping | None = None,
) -> list[pd.DataFrame]:
    """One metrics table per parameter mapping (see module doc), in order."""
    return [
        evaluate_env_params(
            env_id, params, seeds=list(seeds), config=config, label="tuner", reuse_env=True
        )
        for params in params_list
    ]
