"""The closed-loop runner (:mod:`.loop`) and the evaluation of parameters over seeds
(:mod:`.evaluation`)."""

from train_envs.simulation.evaluation import (
    Episodes,
    EpisodeSource,
    episode_row,
    evaluate_params,
    metrics_table,
    seed_list,
)
from train_envs.simulation.loop import (
    INFO_COLUMNS,
    ClosedLoop,
    SimulationError,
    SimulationResult,
    run_to_end,
    simulate,
)

__all__ = [
    "INFO_COLUMNS",
    "ClosedLoop",
    "EpisodeSource",
    "Episodes",
    "SimulationError",
    "SimulationResult",
    "episode_row",
    "evaluate_params",
    "metrics_table",
    "run_to_end",
    "seed_list",
    "simulate",
]
