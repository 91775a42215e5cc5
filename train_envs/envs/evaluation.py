"""Evaluate a driver (fixed parameters, a policy, or the controller's defaults) on an env id.

This is the function the tuners and the agents call: it runs whole episodes through
the registered env and returns one row per episode with every metric of
:func:`train_envs.metrics.episode_metrics` plus the return and the episode length.
"""

from __future__ import annotations

import json
import os
import threading
from collections import OrderedDict
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
import pandas as pd

Driver = Mapping[str, float] | Callable[[np.ndarray], np.ndarray] | Any | None


class EnvCache:
    """A per-process pool of built envs, reused by :func:`evaluate` (``reuse_env=True``).

    Building an env (``gymnasium.make``: scenario, controller, QP set-up) costs as much
    as a short episode; a tuner evaluates thousands of parameter vectors on the same env
    id and config, so each worker process keeps the envs it built. An env is keyed by
    ``(env_id, config)`` (config as canonical JSON), taken out of the pool while an
    evaluation uses it (threads never share one) and put back afterwards; the pool
    holds at most ``maxsize`` idle envs, closing the least recently used beyond that.
    Reuse is exact: :meth:`TrainTuningEnv.reset` with a seed re-initialises everything
    an episode depends on, so an evaluation on a reused env equals one on a fresh env
    bit for bit (tested). An env whose evaluation raised is closed, not put back.
    """

    def __init__(self, maxsize: int = 4) -> None:
        if maxsize < 0:
            raise ValueError(f"maxsize must be >= 0, got {maxsize}")
        self.maxsize = int(maxsize)
        self._idle: OrderedDict[tuple[str, str], list[tuple[gym.Env, Any]]] = OrderedDict()
        self._lock = threading.Lock()
        self._pid = os.getpid()
        self.hits = 0
        self.misses = 0

    @staticmethod
    def key(env_id: str, config: Mapping[str, Any] | None) -> tuple[str, str] | None:
        """The cache key, or ``None`` if the config is not JSON-able (then no reuse)."""
        try:
            return env_id, json.dumps(dict(config or {}), sort_keys=True, allow_nan=True)
        except (TypeError, ValueError):
            return None

    @staticmethod
    def _registered(env_id: str) -> Any:
        return gym.registry.get(env_id.rsplit(":", 1)[-1])

    def _check_process(self) -> None:
        if os.getpid() != self._pid:  # forked child: the parent's lock and envs are not ours
            self._lock = threading.Lock()
            self._idle = OrderedDict()
            self._pid = os.getpid()

    def acquire(self, env_id: str, config: Mapping[str, Any] | None) -> gym.Env:
        """An env for ``(env_id, config)``, as good as newly made: an idle one of the
        pool if there is one, else a new one. Give it back with :meth:`release` (or close
        it)."""
        self._check_process()
        key = self.key(env_id, config)
        env = None
        if key is not None:
            stale = []
            with self._lock:
                entries = self._idle.get(key, [])
                while entries and env is None:
                    cand, spec = entries.pop()
                    if spec is self._registered(env_id):
                        env = cand
                    else:  # the id was registered anew since
                        stale.append(cand)
                if not entries:
                    self._idle.pop(key, None)
                if env is None:
                    self.misses += 1
                else:
                    self.hits += 1
            for old in stale:
                old.close()
        if env is None:
            return gym.make(env_id, config=dict(config or {}))
        renew = getattr(env.unwrapped, "renew_controller", None)
        if renew is not None:
            renew()  # what an episode leaves in the controller beyond its reset
        return env

    def release(self, env_id: str, config: Mapping[str, Any] | None, env: gym.Env) -> None:
        """Return an env obtained from :meth:`acquire` to the pool (LRU-bounded)."""
        self._check_process()
        key = self.key(env_id, config)
        if key is None or self.maxsize == 0:
            env.close()
            return
        evicted = []
        with self._lock:
            self._idle.setdefault(key, []).append((env, self._registered(env_id)))
            self._idle.move_to_end(key)
            while len(self) > self.maxsize:
                old_key = next(iter(self._idle))
                entries = self._idle[old_key]
                evicted.append(entries.pop(0)[0])
                if not entries:
                    del self._idle[old_key]
        for old in evicted:
            old.close()

    def clear(self) -> None:
        """Close and forget every idle env."""
        self._check_process()
        with self._lock:
            envs = [env for entries in self._idle.values() for env, _ in entries]
            self._idle.clear()
        for env in envs:
            env.close()

    def __len__(self) -> int:
        return sum(len(v) for v in self._idle.values())


#: the per-process pool :func:`evaluate` uses with ``reuse_env=True``
ENV_CACHE = EnvCache()


def clear_env_cache() -> None:
    """Close the envs :func:`evaluate` keeps for reuse in this process."""
    ENV_CACHE.clear()


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
    # the env's own defaults, not the controller's current values (a reused env's
    # controller still holds the last episode's parameters until the next reset)
    if hasattr(base, "default_params"):
        defaults = base.default_params()
    else:
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
    reuse_env: bool = False,
) -> pd.DataFrame:
    """Run ``driver`` on ``env_id`` for the given seeds; one DataFrame row per episode.

    ``seeds`` defaults to ``range(episodes)`` (``episodes`` defaults to 1). The same
    seeds give the same table. ``reuse_env=True`` takes the env from this process's
    :data:`ENV_CACHE` (built on first use) and puts it back afterwards instead of
    building and closing one; the table is the same bit for bit.
    """
    if seeds is None:
        seeds = range(episodes or 1)
    seeds = [int(s) for s in seeds]
    if reuse_env:
        env = ENV_CACHE.acquire(env_id, config)
    else:
        env = gym.make(env_id, config=dict(config or {}))
    rows = []
    ok = False
    try:
        policy = _policy_fn(env, driver)
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
        ok = True
    finally:
        if reuse_env and ok:
            ENV_CACHE.release(env_id, config, env)
        else:
            env.close()
    return pd.DataFrame(rows)


def _label(driver: Driver) -> str:
    if driver is None:
        return "defaults"
    if isinstance(driver, Mapping):
        return "params(" + ", ".join(f"{k}={v:.4g}" for k, v in driver.items()) + ")"
    return type(driver).__name__
