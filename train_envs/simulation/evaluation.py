"""Evaluate a controller with given parameters over seeds: the metrics table.

:func:`evaluate_params` is the one evaluation of fixed parameters: for every seed it
starts an episode (:class:`Episodes`: a scenario and a controller, or an env's reset
through :class:`train_envs.envs.evaluation.EnvEpisodes`), runs the closed loop to its
end with :func:`~train_envs.simulation.loop.run_to_end`, and appends one row
(:func:`episode_row`). The table (:func:`metrics_table`) has one row per seed: the
identifying columns, ``episode``, ``seed``, ``scenario``, then every metric of
:func:`train_envs.metrics.episode_metrics` (units in the names: ``_m``, ``_mps``, ``_s``,
``_kWh``, ...). An evaluation driven by a policy that acts every env step
(:func:`train_envs.envs.evaluate`) steps the env instead, but builds its seeds
(:func:`seed_list`), rows and table with the same functions.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import Any, Protocol

import pandas as pd

from train_envs.controllers.base import Controller
from train_envs.scenarios import Scenario
from train_envs.simulation.loop import ClosedLoop, run_to_end
from train_envs.simulation.supervision import Supervision

__all__ = [
    "EpisodeSource",
    "Episodes",
    "episode_row",
    "evaluate_params",
    "metrics_table",
    "seed_list",
]


def seed_list(
    seeds: Sequence[int] | Iterable[int] | None = None, episodes: int | None = None
) -> list[int]:
    """The seeds of an evaluation: ``seeds`` as ints, or ``range(episodes)`` (default 1)."""
    if seeds is None:
        seeds = range(episodes or 1)
    return [int(s) for s in seeds]


def episode_row(
    episode: int,
    seed: int,
    scenario: str,
    metrics: Mapping[str, float],
    *,
    ids: Mapping[str, Any] | None = None,
    extra: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """One row of the metrics table: ``ids``, ``episode``, ``seed``, ``scenario``,
    ``extra`` (e.g. the env's ``return``), then the episode metrics."""
    return {
        **(ids or {}),
        "episode": int(episode),
        "seed": int(seed),
        "scenario": scenario,
        **(extra or {}),
        **metrics,
    }


def metrics_table(rows: Sequence[Mapping[str, Any]]) -> pd.DataFrame:
    """The metrics table of :func:`episode_row` rows (one per seed, in order)."""
    return pd.DataFrame(list(rows))


class EpisodeSource(Protocol):
    """What :func:`evaluate_params` needs of its episodes."""

    ids: Mapping[str, Any]
    extra: Mapping[str, Any]
    max_steps: int | None

    def start(self, seed: int, params: Mapping[str, float] | None) -> ClosedLoop: ...


class Episodes:
    """Where an evaluation's episodes come from: a scenario and a controller.

    :meth:`start` returns a reset :class:`ClosedLoop` with the parameters in force.
    Here the parameters are set on the controller before the reset, and a controller
    given by name is built anew for each episode, as :func:`simulate` does. ``ids``
    and ``extra`` are constant columns of every row; ``max_steps`` caps the control
    steps of an episode (``None``: the scenario's own end); ``supervision``: the ATP
    settings (default: ATP on).
    """

    def __init__(
        self,
        scenario: Scenario | str,
        controller: Controller | str,
        *,
        ids: Mapping[str, Any] | None = None,
        extra: Mapping[str, Any] | None = None,
        max_steps: int | None = None,
        supervision: Supervision | None = None,
    ) -> None:
        from train_envs.scenarios import get_scenario

        self.scenario = get_scenario(scenario) if isinstance(scenario, str) else scenario
        self.controller = controller
        self.ids = dict(ids or {})
        self.extra = dict(extra or {})
        self.max_steps = max_steps
        self.supervision = supervision

    def start(self, seed: int, params: Mapping[str, float] | None) -> ClosedLoop:
        from train_envs.controllers import make_controller

        ctrl = self.controller
        if isinstance(ctrl, str):
            ctrl = make_controller(ctrl, self.scenario)
        if params:
            ctrl.set_params(**params)
        loop = ClosedLoop(self.scenario, ctrl, self.supervision)
        loop.reset(seed=seed)
        return loop


def evaluate_params(
    source: EpisodeSource | Scenario | str,
    params: Mapping[str, float] | None = None,
    *,
    controller: Controller | str | None = None,
    seeds: Sequence[int] | Iterable[int] | None = None,
    episodes: int | None = None,
    frames: dict[int, pd.DataFrame] | None = None,
    partial: bool = True,
) -> pd.DataFrame:
    """Run the controller with ``params`` over the seeds; the metrics table.

    Args:
        source: an :class:`EpisodeSource` (e.g. :class:`Episodes`), or a scenario (or
            its name) with ``controller``.
        params: native parameter values (``None``: the controller's own).
        seeds, episodes: see :func:`seed_list`.
        frames: if given, receives seed → the run's DataFrame (the runner's columns).
        partial: a failing run raises :class:`~train_envs.simulation.SimulationError`
            with its partial result (``False``: the original exception).
    """
    if isinstance(source, (Scenario, str)):
        if controller is None:
            raise ValueError("evaluate_params needs a controller with a scenario")
        source = Episodes(source, controller)
    elif controller is not None:
        raise ValueError("evaluate_params: the episode source holds the controller")
    rows = []
    for i, seed in enumerate(seed_list(seeds, episodes)):
        loop = source.start(seed, params)
        run_to_end(loop, source.max_steps, partial=partial)
        rows.append(
            episode_row(
                i, seed, loop.scenario.name, loop.metrics(), ids=source.ids, extra=source.extra
            )
        )
        if frames is not None:
            frames[seed] = loop.dataframe()
    return metrics_table(rows)
