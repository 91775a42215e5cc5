"""Evaluate on an env id: fixed parameters through the runner, or a driver step by step.

:func:`evaluate_env_params` runs fixed controller parameters over seeds on a registered
env id through the runner's :func:`train_envs.simulation.evaluate_params`, with the
env's own episodes (:class:`EnvEpisodes`: its reset's scenario draw and seeding, its
step cap); the tuners call it. :func:`evaluate` runs a driver (fixed parameters as a
constant action, a policy, or the controller's defaults) by stepping the env, so its
table also carries the return and the episode length; its seeds, rows and table are
the runner's (:func:`~train_envs.simulation.seed_list`,
:func:`~train_envs.simulation.episode_row`, :func:`~train_envs.simulation.metrics_table`).
Both can reuse the env across calls (:class:`EnvCache`).
"""

from __future__ import annotations

import json
import os
import threading
from collections import OrderedDict
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from typing import Any

import gymnasium as gym
import numpy as np
import pandas as pd

from train_envs.controllers.params import ParamSpace
from train_envs.simulation import (
    ClosedLoop,
    Episodes,
    episode_row,
    evaluate_params,
    metrics_table,
    seed_list,
)

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
    return ParamSpace(base.param_specs).encode_action(params, _env_defaults(base))


def _env_defaults(base: Any) -> dict[str, float]:
    # the env's own defaults, not the controller's current values (a reused env's
    # controller still holds the last episode's parameters until the next reset)
    if hasattr(base, "default_params"):
        return base.default_params()
    return base.controller.get_params()


class EnvEpisodes(Episodes):
    """The episodes of a built env, for :func:`~train_envs.simulation.evaluate_params`.

    :meth:`start` resets the env with the seed (its scenario draw, episode seed and
    default parameters), then sets the given native values of its exposed parameters
    (validated; the others keep the env's defaults) on the env's controller, as the
    env's first step would. Episodes end where the env's would
    (``max_episode_steps`` env steps of ``decision_interval`` control steps).
    """

    def __init__(self, env: gym.Env, *, ids: Mapping[str, Any] | None = None) -> None:
        base = env.unwrapped
        self.env = env
        self.space = ParamSpace(base.param_specs)
        self.defaults = _env_defaults(base)
        cfg = base.config
        cap = cfg["max_episode_steps"]
        self.ids = dict(ids or {})
        self.extra = {}
        self.max_steps = int(cap) * int(cfg["decision_interval"]) if cap else None

    def start(self, seed: int, params: Mapping[str, float] | None) -> ClosedLoop:
        values = non_default(self.space.complete(params or {}, self.defaults), self.defaults)
        self.env.reset(seed=seed)
        base = self.env.unwrapped
        if values is not None:
            # a reused env rebuilds a controller that ran other parameters
            # (TrainTuningEnv.renew_controller)
            base.set_native_params(values)
        return base.loop


def non_default(
    values: Mapping[str, float], defaults: Mapping[str, float]
) -> Mapping[str, float] | None:
    """``values``, or None where every one is its default (an episode then sets no
    parameters: the env's reset has set the defaults)."""
    return None if values == {n: defaults[n] for n in values} else values


def evaluate_env_params(
    env_id: str,
    params: Mapping[str, float] | None = None,
    *,
    seeds: Sequence[int] | Iterable[int] | None = None,
    episodes: int | None = None,
    config: Mapping[str, Any] | None = None,
    label: str | None = None,
    reuse_env: bool = False,
    frames: dict[int, pd.DataFrame] | None = None,
) -> pd.DataFrame:
    """Native parameter values on ``env_id`` over seeds; one row per episode.

    The runner's metrics table (:func:`~train_envs.simulation.evaluate_params`) with
    ``env`` and ``driver`` columns first. The values given are exactly those the
    controller runs with. ``reuse_env``: see :func:`evaluate`; ``frames``: see
    :func:`~train_envs.simulation.evaluate_params`.
    """
    params = dict(params or {})
    with _env(env_id, config, reuse_env) as env:
        source = EnvEpisodes(env, ids={"env": env_id, "driver": label or _label(params)})
        return evaluate_params(
            source, params, seeds=seeds, episodes=episodes, frames=frames, partial=False
        )


@contextmanager
def _env(env_id: str, config: Mapping[str, Any] | None, reuse_env: bool) -> Iterator[gym.Env]:
    """An env of ``env_id``: from :data:`ENV_CACHE` and put back after a run that did not
    fail (``reuse_env``), else made and closed."""
    if reuse_env:
        env = ENV_CACHE.acquire(env_id, config)
    else:
        env = gym.make(env_id, config=dict(config or {}))
    ok = False
    try:
        yield env
        ok = True
    finally:
        if reuse_env and ok:
            ENV_CACHE.release(env_id, config, env)
        else:
            env.close()


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
    seeds = seed_list(seeds, episodes)
    rows = []
    with _env(env_id, config, reuse_env) as env:
        policy = _policy_fn(env, driver)
        ids = {"env": env_id, "driver": label or _label(driver)}
        for i, seed in enumerate(seeds):
            obs, _ = env.reset(seed=seed)
            ret, n, done, info = 0.0, 0, False, {}
            while not done:
                obs, r, term, trunc, info = env.step(policy(obs))
                ret += r
                n += 1
                done = term or trunc
            rows.append(
                episode_row(
                    i,
                    seed,
                    env.unwrapped.scenario.name,
                    info.get("episode_metrics", {}),
                    ids=ids,
                    extra={"return": ret, "env_steps": n},
                )
            )
    return metrics_table(rows)


def _label(driver: Driver) -> str:
    if driver is None:
        return "defaults"
    if isinstance(driver, Mapping):
        return "params(" + ", ".join(f"{k}={v:.4g}" for k, v in driver.items()) + ")"
    return type(driver).__name__
