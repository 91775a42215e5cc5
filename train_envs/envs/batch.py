"""Evaluate a population of parameter vectors on one env id in lockstep.

:func:`evaluate_env_params_batch` returns, for each parameter vector, the table
:func:`train_envs.envs.evaluation.evaluate_env_params` gives for it (same columns, same
rows, same order); :func:`supports_batch` says whether an env id and config has the
batched path. There, every (parameter vector, seed) pair is one member of a
:class:`~train_envs.simulation.batch.BatchLoop`: the env's reset for the seed gives the
scenario and the episode seed (its plant draw), the env's controller validates and
completes the parameters, and the members run together (the batched controllers of
:data:`BATCHED`). Elsewhere it runs the single evaluations one after the other.
Tolerance and design: ``docs/design/lockstep.md``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
import pandas as pd

from train_envs.controllers.base import Controller
from train_envs.controllers.batch import BatchFuzzyPID, BatchPID, rules_batchable
from train_envs.controllers.dmc.batch import BatchDMC, batchable_dmc
from train_envs.controllers.dmc.controller import DMCController
from train_envs.controllers.fuzzy_pid import FuzzyPIDController
from train_envs.controllers.params import ParamSpace
from train_envs.controllers.pid import PIDController
from train_envs.envs.evaluation import EnvCache, _env, _env_defaults, evaluate_env_params
from train_envs.plants.batch import batchable
from train_envs.scenarios import build_plant
from train_envs.simulation import episode_row, metrics_table
from train_envs.simulation.batch import BatchLoop

__all__ = ["BATCHED", "evaluate_env_params_batch", "supports_batch"]


def _dmc(env: Any, params: Sequence[Mapping[str, float]], pool: Callable[[int], Controller]):
    return BatchDMC(env.controller, params, pool)


def _pid(env: Any, params: Sequence[Mapping[str, float]], pool: Callable[[int], Controller]):
    return BatchPID(env.controller, params)


def _fuzzy_pid(env: Any, params: Sequence[Mapping[str, float]], pool: Any):
    return BatchFuzzyPID(env.controller, params)


#: controller class -> (whether a reset instance batches, the batched controller's builder
#: ``(env, member params, QP pool) -> BatchController``)
BATCHED: dict[type, tuple[Callable[[Any], bool], Callable[..., Any]]] = {
    DMCController: (batchable_dmc, _dmc),
    PIDController: (lambda c: True, _pid),
    FuzzyPIDController: (lambda c: rules_batchable(c.rules) and c._single, _fuzzy_pid),
}

#: per env key: the controllers members solve their QPs on (built on first use)
_POOLS: dict[tuple[str, str], list[Controller]] = {}


def _supported(env: gym.Env) -> bool:
    base = env.unwrapped
    entry = BATCHED.get(type(base.controller))
    loop = base.loop
    return (
        entry is not None
        and loop.plant is not None
        and entry[0](base.controller)
        and batchable(loop.plant)
        and base.scenario.control_context().n_inputs == 1
        and not loop.supervision.end_on_violation
    )


def supports_batch(env_id: str, config: Mapping[str, Any] | None = None) -> bool:
    """Whether ``env_id`` with ``config`` has a batched (lockstep) evaluation."""
    key = EnvCache.key(env_id, config)
    if key is None:
        return False
    try:
        with _env(env_id, config, True) as env:
            if env.unwrapped.loop.plant is None:
                env.reset(seed=0)
            return _supported(env)
    except gym.error.Error:
        return False


def _pool(key: tuple[str, str], base: Any) -> Callable[[int], Controller]:
    ctrls = _POOLS.setdefault(key, [])

    def get(b: int) -> Controller:
        while len(ctrls) <= b:
            ctrls.append(base._make_controller())
        return ctrls[b]

    return get


def _plants(sc: Any, episode_seeds: Sequence[int]) -> list[Any]:
    """The members' plants: one per episode seed (a plant with disturbances, which keep
    a state, is built for every member)."""
    built: dict[int, Any] = {}
    out = []
    for seed in episode_seeds:
        plant = built.get(seed)
        if plant is None or plant.disturbances:
            plant = build_plant(sc, np.random.default_rng(seed))
            built[seed] = plant
        out.append(plant)
    return out


def evaluate_env_params_batch(
    env_id: str,
    params_list: Sequence[Mapping[str, float]],
    seeds: Sequence[int],
    config: Mapping[str, Any] | None = None,
) -> list[pd.DataFrame]:
    """One metrics table per parameter vector, each over ``seeds``.

    Element ``i`` equals ``evaluate_env_params(env_id, params_list[i], seeds=seeds,
    config=config, label="tuner", reuse_env=True)``: the same columns and rows, values
    to ~1e-12 relative (``docs/design/lockstep.md``). A failing member (a non-finite
    command, an invalid parameter) raises for the whole population.
    """
    seeds = [int(s) for s in seeds]
    params_list = [dict(p or {}) for p in params_list]
    if not params_list:
        return []
    key = EnvCache.key(env_id, config)
    if key is None or not supports_batch(env_id, config):
        return [
            evaluate_env_params(
                env_id, p, seeds=seeds, config=config, label="tuner", reuse_env=True
            )
            for p in params_list
        ]
    with _env(env_id, config, True) as env:
        base = env.unwrapped
        space = ParamSpace(base.param_specs)
        defaults = _env_defaults(base)
        cap = base.config["max_episode_steps"]
        max_steps = int(cap) * int(base.config["decision_interval"]) if cap else None
        ids = {"env": env_id, "driver": "tuner"}
        # every (parameter vector, seed) pair is a member; members of one scenario
        # (all of them, unless the env draws a scenario per seed) run in lockstep
        groups: dict[int, tuple[Any, list[tuple[int, int, int]], list[dict[str, float]]]] = {}
        for j, seed in enumerate(seeds):
            env.reset(seed=seed)
            sc = base.scenario
            ep_seed = base.loop.seed
            group = groups.setdefault(id(sc), (sc, [], []))
            for i, p in enumerate(params_list):
                base.set_native_params(space.complete(p, defaults))
                group[1].append((i, j, ep_seed))
                group[2].append(base.controller.get_params())
        rows: list[list[dict[str, Any] | None]] = [[None] * len(seeds) for _ in params_list]
        for sc, members, full in groups.values():
            if base.scenario is not sc:  # the controller's structure for sc
                env.reset(seed=seeds[members[0][1]])
            plants = _plants(sc, [m[2] for m in members])
            ctrl = BATCHED[type(base.controller)][1](base, full, _pool(key, base))
            loop = BatchLoop(sc, plants, ctrl, base.loop.supervision, max_steps)
            loop.run()
            for b, (i, j, _) in enumerate(members):
                rows[i][j] = episode_row(j, seeds[j], sc.name, loop.metrics(b), ids=ids)
        return _split_tables(rows)


def _split_tables(rows: Sequence[Sequence[Mapping[str, Any]]]) -> list[pd.DataFrame]:
    """:func:`metrics_table` of each member's rows, made as one table of all rows and
    cut into equal slices (one pandas construction instead of one per member; the
    metrics are floats and the ids strings in every row, so each slice has the dtypes
    its own table would have)."""
    n = len(rows[0])
    flat = metrics_table([row for member in rows for row in member])
    return [flat.iloc[i * n : (i + 1) * n].reset_index(drop=True) for i in range(len(rows))]
