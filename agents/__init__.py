"""RL agents that set the inner controller's tuning parameters online, and their evaluation.

* :mod:`agents.training` — :func:`train` stable-baselines3 PPO / SAC / TD3 on any
  ``TrainEnvs/...`` id (vectorised envs, VecNormalize, held-out evaluation,
  checkpoints, TensorBoard) and :func:`load_policy`;
* :mod:`agents.hyperparameters` — the rl-zoo3-format YAML files
  ``agents/hyperparams/{ppo,sac,td3}.yml``;
* :mod:`agents.evaluation` — :func:`compare` policies, parameter sets and controllers
  on the same seeds, :func:`summary`, :func:`significance` (paired Wilcoxon),
  :func:`overlay_figure`;
* :mod:`agents.cli` — ``train-envs train`` and ``train-envs evaluate``.

torch and stable-baselines3 are imported only when a model is built or loaded.
"""

from agents.evaluation import (
    ControllerDriver,
    EnvCase,
    ParamsDriver,
    PolicyDriver,
    compare,
    format_summary,
    load_params,
    overlay_figure,
    significance,
    summary,
)
from agents.hyperparameters import ALGOS, resolve_hyperparams
from agents.training import TrainConfig, TrainResult, load_policy, train

__all__ = [
    "ALGOS",
    "ControllerDriver",
    "EnvCase",
    "ParamsDriver",
    "PolicyDriver",
    "TrainConfig",
    "TrainResult",
    "compare",
    "format_summary",
    "load_params",
    "load_policy",
    "overlay_figure",
    "resolve_hyperparams",
    "significance",
    "summary",
    "train",
]
