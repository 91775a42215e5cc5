"""Gymnasium environments: the inner controller's tuning parameters as the action."""

from train_envs.envs.batch import evaluate_env_params_batch, supports_batch
from train_envs.envs.config import EnvConfig
from train_envs.envs.evaluation import (
    EnvEpisodes,
    evaluate,
    evaluate_env_params,
    params_to_action,
)
from train_envs.envs.registration import ENV_SPECS, register_envs, registered_ids
from train_envs.envs.reward import OBJECTIVES
from train_envs.envs.train_env import TrainTuningEnv
from train_envs.envs.vector_env import TrainTuningVectorEnv
from train_envs.envs.wrappers import VectorRewardWrapper

__all__ = [
    "ENV_SPECS",
    "OBJECTIVES",
    "EnvConfig",
    "EnvEpisodes",
    "TrainTuningEnv",
    "TrainTuningVectorEnv",
    "VectorRewardWrapper",
    "evaluate",
    "evaluate_env_params",
    "evaluate_env_params_batch",
    "params_to_action",
    "register_envs",
    "registered_ids",
    "supports_batch",
]
