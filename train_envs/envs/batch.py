"""Evaluate a population of parameter vectors on one env id in lockstep.

:func:`evaluate_env_params_batch` returns, for each parameter vector, the table
:func:`train_envs.envs.evaluation.evaluate_env_params` gives for it (same columns, same
rows); :func:`supports_batch` says whether an env id and config has a batched path.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import pandas as pd

from train_envs.envs.evaluation import evaluate_env_params

__all__ = ["evaluate_env_params_batch", "supports_batch"]


def supports_batch(env_id: str, config: Mapping[str, Any] | None = None) -> bool:
    """Whether ``env_id`` with ``config`` has a batched (lockstep) evaluation."""
    return False


def evaluate_env_params_batch(
    env_id: str,
    params_list: Sequence[Mapping[str, float]],
    seeds: Sequence[int],
    config: Mapping[str, Any] | None = None,
) -> list[pd.DataFrame]:
    """One metrics table per parameter vector, each over ``seeds``.

    Element ``i`` equals ``evaluate_env_params(env_id, params_list[i], seeds=seeds,
    config=config, label="tuner", reuse_env=True)``.
    """
    return [
        evaluate_env_params(
            env_id, params, seeds=seeds, config=config, label="tuner", reuse_env=True
        )
        for params in params_list
    ]
