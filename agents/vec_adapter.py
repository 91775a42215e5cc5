"""A stable-baselines3 ``VecEnv`` over a Gymnasium ``VectorEnv`` (next-step autoreset).

SB3 expects the same-step convention: the step that ends an episode returns the first
observation of the next one, with the last one in ``infos[i]["terminal_observation"]``
(and ``TimeLimit.truncated``). :class:`GymnasiumVecEnv` gets it from a vector env with
Gymnasium 1.x's next-step autoreset (e.g.
:class:`train_envs.envs.vector_env.TrainTuningVectorEnv`) by resetting the members that
ended right away with ``reset(options={"reset_mask": done})``, so the vector env's own
autoreset never triggers. Seeds set with :meth:`seed` apply to the next reset, member
``i`` getting ``seed + i``, as SB3's ``DummyVecEnv`` does.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices

__all__ = ["GymnasiumVecEnv"]


def _member_info(infos: dict[str, Any], i: int) -> dict[str, Any]:
    """Member ``i``'s entries of a Gymnasium vector info dict (``_key`` masks)."""
    out = {}
    for key, val in infos.items():
        if key.startswith("_"):
            continue
        mask = infos.get("_" + key)
        if mask is not None and not mask[i]:
            continue
        out[key] = _member_info(val, i) if isinstance(val, dict) else val[i]
    return out


class GymnasiumVecEnv(VecEnv):
    """SB3's ``VecEnv`` interface over ``venv`` (a ``gymnasium.vector.VectorEnv``)."""

    def __init__(self, venv: gym.vector.VectorEnv) -> None:
        self.venv = venv
        #: the vector env's spec (SB3's ``VecMonitor`` names its id in the file header)
        self.spec = getattr(venv, "spec", None)
        super().__init__(venv.num_envs, venv.single_observation_space, venv.single_action_space)
        self._actions: np.ndarray | None = None

    def reset(self) -> np.ndarray:
        seeds = self._seeds if any(s is not None for s in self._seeds) else None
        obs, infos = self.venv.reset(seed=seeds)
        self.reset_infos = [_member_info(infos, i) for i in range(self.num_envs)]
        self._reset_seeds()
        self._reset_options()
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]:
        obs, rewards, terms, truncs, infos = self.venv.step(self._actions)
        dones = terms | truncs
        out = [_member_info(infos, i) for i in range(self.num_envs)]
        if dones.any():
            for i in np.flatnonzero(dones).tolist():
                out[i]["terminal_observation"] = obs[i].copy()
                out[i]["TimeLimit.truncated"] = bool(truncs[i] and not terms[i])
            reset_obs, reset_infos = self.venv.reset(options={"reset_mask": dones})
            obs = np.where(dones[:, None], reset_obs, obs)
            for i in np.flatnonzero(dones).tolist():
                self.reset_infos[i] = _member_info(reset_infos, i)
        return obs, rewards.astype(np.float32), dones, out

    def close(self) -> None:
        self.venv.close()

    def _indices(self, indices: VecEnvIndices) -> Sequence[int]:
        if indices is None:
            return range(self.num_envs)
        return [indices] if isinstance(indices, int) else list(indices)

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        return [getattr(self.venv, attr_name) for _ in self._indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        setattr(self.venv, attr_name, value)

    def env_method(
        self, method_name: str, *method_args: Any, indices: VecEnvIndices = None, **kwargs: Any
    ) -> list[Any]:
        method = getattr(self.venv, method_name)
        return [method(*method_args, **kwargs) for _ in self._indices(indices)]

    def env_is_wrapped(self, wrapper_class: type, indices: VecEnvIndices = None) -> list[bool]:
        return [False for _ in self._indices(indices)]
