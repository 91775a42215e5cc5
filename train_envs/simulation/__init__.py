"""The closed-loop runner (:mod:`.loop`), its supervision (:mod:`.supervision`) and the
evaluation of parameters over seeds (:mod:`.evaluation`)."""

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
    SAFETY_COLUMNS,
    ClosedLoop,
    SimulationError,
    SimulationResult,
    run_to_end,
    simulate,
)
from train_envs.simulation.supervision import Supervision, permitted_speed_mps

__all__ = [
    "INFO_COLUMNS",
    "SAFETY_COLUMNS",
    "ClosedLoop",
    "EpisodeSource",
    "Episodes",
    "SimulationError",
    "SimulationResult",
    "Supervision",
    "episode_row",
    "evaluate_params",
    "metrics_table",
    "permitted_speed_mps",
    "run_to_end",
    "seed_list",
    "simulate",
]
