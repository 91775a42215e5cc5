"""The benchmark: every controller on every scenario it can run, one leaderboard.

:func:`run_benchmark` runs the matrix (:mod:`.matrix`: scenarios and sets, supported
pairs) over disturbance seeds (:mod:`.disturbance`: what they draw) through the runner,
resumably (:mod:`.run`), and writes the tidy table, the leaderboard
(:mod:`.leaderboard`), the heatmap and the overlays (:mod:`.plots`) into its folder
(:mod:`.outputs`). :mod:`.publish` puts a leaderboard into ``docs/benchmark.md``. Tuned
parameters and the ``train-envs benchmark`` command are in :mod:`tuners.benchmark`.
"""

from train_envs.benchmark.disturbance import (
    DEFAULT_DISTURBANCE,
    DISTURBANCES,
    apply_disturbance,
    resolve_disturbance,
)
from train_envs.benchmark.leaderboard import HEADLINE, leaderboard, leaderboard_markdown
from train_envs.benchmark.matrix import (
    SCENARIO_SETS,
    benchmark_scenario,
    pair_reasons,
    real_line_pairs,
    resolve_controllers,
    resolve_scenarios,
)
from train_envs.benchmark.outputs import BenchmarkResult, run_benchmark, write_outputs
from train_envs.benchmark.plots import heatmap_figure, overlay_figure

__all__ = [
    "DEFAULT_DISTURBANCE",
    "DISTURBANCES",
    "HEADLINE",
    "SCENARIO_SETS",
    "BenchmarkResult",
    "apply_disturbance",
    "benchmark_scenario",
    "heatmap_figure",
    "leaderboard",
    "leaderboard_markdown",
    "overlay_figure",
    "pair_reasons",
    "real_line_pairs",
    "resolve_disturbance",
    "resolve_controllers",
    "resolve_scenarios",
    "run_benchmark",
    "write_outputs",
]
