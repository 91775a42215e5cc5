"""Evaluate a population of parameter vectors on one env id in lockstep.

:func:`evaluate_env_params_batch` returns, for each parameter vector, the table
:func:`train_envs.envs.evaluation.evaluate_env_params` gives for it (same columns, same
rows, same order); :func:`supports_batch` says whether an env id and config has the
batched path. There, every (parameter vector, seed) pair is one member of a
:class:`~train_envs.simulation.batch.BatchLoop`: the env's reset for the seed gives the
scenario and the episode seed (its plant draw), the env's controller validates and
completes the parameters, and the members run together (the batched controllers of
:data:`BATCHED`, or each member on its own controller: :func:`lockstep_builder`, the
multi-car ids' controllers with one input per car among them). Where the batched runner
does not apply (a plant it does not batch, ``end_on_violation``) it runs the single
evaluations one after the other.
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
from train_envs.envs.evaluation import (
    EnvCache,
    _env,
    _env_defaults,
    evaluate_env_params,
    non_default,
)
from train_envs.scenarios import build_plant
from train_envs.simulation import episode_row, metrics_table
from train_envs.simulation.batch import BatchLoop, batchable_member
from train_envs.simulation.members import MemberControllers

__all__ = ["BATCHED", "evaluate_env_params_batch", "lockstep_builder", "supports_batch"]


def _dmc(env: Any, params: Sequence[Mapping[str, float]], pool: Callable[[int], Controller]):
    return BatchDMC(env.controller, params, pool)


def _pid(env: Any, params: Sequence[Mapping[str, float]], pool: Callable[[int], Controller]):
    return BatchPID(env.controller, params)


def _fuzzy_pid(env: Any, params: Sequence[Mapping[str, float]], pool: Any):
    return BatchFuzzyPID(env.controller, params)


def _members(env: Any, params: Sequence[Mapping[str, float]], pool: Callable[[int], Controller]):
    return MemberControllers([pool(b) for b in range(len(params))])


#: controller class -> (whether a reset instance batches, the batched controller's builder
#: ``(env, member params, QP pool) -> BatchController``); every other controller (and a
#: configuration these laws do not cover) runs member by member on its own single form
#: (:func:`lockstep_builder`)
BATCHED: dict[type, tuple[Callable[[Any], bool], Callable[..., Any]]] = {
    DMCController: (batchable_dmc, _dmc),
    PIDController: (lambda c: True, _pid),
    FuzzyPIDController: (lambda c: rules_batchable(c.rules) and c._single, _fuzzy_pid),
}


def lockstep_builder(ctrl: Controller, n_cars: int = 1) -> Callable[..., Any]:
    """The batched controller's builder ``(env, member params, pool) -> BatchController``
    for a reset ``ctrl`` on trains of ``n_cars`` cars: its array law (:data:`BATCHED`,
    single-car laws) where it has one for this configuration, else
    :class:`~train_envs.simulation.members.MemberControllers` over the pool's
    controllers (``pool(b)``: member ``b``'s own controller, reset with its
    parameters)."""
    entry = BATCHED.get(type(ctrl)) if n_cars == 1 else None
    return entry[1] if entry is not None and entry[0](ctrl) else _members


#: per env key: the controllers members solve their QPs on (built on first use)
_POOLS: dict[tuple[str, str], list[Controller]] = {}


def _supported(env: gym.Env) -> bool:
    base = env.unwrapped
    loop = base.loop
    return (
        loop.plant is not None
        and batchable_member(loop.plant)
        and not loop.supervision.end_on_violation
    )


def supports_batch(
    env_id: str, config: Mapping[str, Any] | None = None, *, array_law: bool = False
) -> bool:
    """Whether ``env_id`` with ``config`` has a batched (lockstep) evaluation: a plant
    the lockstep runner batches (:func:`~train_envs.simulation.batch.batchable_member`:
    single-car, or multi-car with one whole-train input or one per car) without
    ``end_on_violation``. ``array_law=True`` asks in addition for a controller with an
    array law (:data:`BATCHED`), where the members share the control step too; the
    others run member by member on their single forms, where only the runner and the
    plant are shared (``docs/design/lockstep.md``)."""
    key = EnvCache.key(env_id, config)
    if key is None:
        return False
    try:
        with _env(env_id, config, True) as env:
            if env.unwrapped.loop.plant is None:
                env.reset(seed=0)
            if not _supported(env):
                return False
            base = env.unwrapped
            return not array_law or _builder(base) is not _members
    except gym.error.Error:
        return False


def _builder(base: Any) -> Callable[..., Any]:
    """:func:`lockstep_builder` of the env ``base``'s controller and plant."""
    return lockstep_builder(base.controller, base.loop.plant.n)


def _pool(key: tuple[str, str], base: Any) -> Callable[[int], Controller]:
    ctrls = _POOLS.setdefault(key, [])

    def get(b: int) -> Controller:
        while len(ctrls) <= b:
            ctrls.append(base._make_controller())
        return ctrls[b]

    return get


def _fresh(base: Any, values: Sequence[Mapping[str, float] | None]) -> Callable[[int], Controller]:
    """Member ``b``'s controller as a single evaluation on a fresh env runs it: made,
    holding the base parameters, reset on the scenario's context, then given its
    parameters (``values[b]``; None: the defaults, no call)."""
    ctx = base.loop.ctx
    base_params = base.action_type.base_params

    def get(b: int) -> Controller:
        ctrl = base._make_controller()
        ctrl.set_params(**base_params)
        ctrl.reset(ctx)
        if values[b] is not None:
            ctrl.set_params(**values[b])
        return ctrl

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
        groups: dict[int, tuple[Any, list[tuple[int, int, int]], list[dict[str, float]], list]] = {}
        for j, seed in enumerate(seeds):
            env.reset(seed=seed)
            sc = base.scenario
            ep_seed = base.loop.seed
            group = groups.setdefault(id(sc), (sc, [], [], []))
            for i, p in enumerate(params_list):
                values = space.complete(p, defaults)
                base.set_native_params(values)
                group[1].append((i, j, ep_seed))
                group[2].append(base.controller.get_params())
                group[3].append(non_default(values, defaults))  # (as EnvEpisodes.start)
        rows: list[list[dict[str, Any] | None]] = [[None] * len(seeds) for _ in params_list]
        for sc, members, full, values in groups.values():
            if base.scenario is not sc:  # the controller's structure for sc
                env.reset(seed=seeds[members[0][1]])
            plants = _plants(sc, [m[2] for m in members])
            build = _builder(base)
            pool = _fresh(base, values) if build is _members else _pool(key, base)
            ctrl = build(base, full, pool)
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
