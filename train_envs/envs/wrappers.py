"""Wrappers: vector (multi-objective) reward in the MO-Gymnasium convention."""

from __future__ import annotations

from collections.abc import Sequence

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from train_envs.envs.reward import OBJECTIVES


class VectorRewardWrapper(gym.Wrapper):
    """Return the per-objective rewards ``−c_i`` as a vector instead of their weighted sum.

    Follows MO-Gymnasium: the wrapper exposes ``reward_space`` (a Box of the objective
    count) and ``step`` returns a ``np.ndarray`` reward. ``objectives`` selects and
    orders the components (default: all of :data:`OBJECTIVES`, unweighted). The scalar
    reward of the wrapped env is kept in ``info["scalar_reward"]``.
    """

    def __init__(self, env: gym.Env, objectives: Sequence[str] = OBJECTIVES) -> None:
        super().__init__(env)
        for name in objectives:
            if name not in OBJECTIVES:
                raise ValueError(f"unknown objective {name!r}; allowed: {OBJECTIVES}")
        self.objectives = tuple(objectives)
        n = len(self.objectives)
        self.reward_space = spaces.Box(-np.inf, 0.0, shape=(n,), dtype=np.float32)
        self.reward_dim = n

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        costs = info["objectives"]
        vec = -np.array([costs[k] for k in self.objectives], dtype=np.float32)
        info = dict(info, scalar_reward=reward)
        return obs, vec, terminated, truncated, info
