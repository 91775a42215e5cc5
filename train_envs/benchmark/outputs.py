"""The benchmark in one call: run the matrix and write its files.

:func:`run_benchmark` resolves the scenarios and controllers, finds the unsupported
pairs, runs the cells not yet stored in ``out`` under the benchmark disturbance
(:mod:`train_envs.benchmark.disturbance`, ``load`` by default) through
:mod:`train_envs.benchmark.run` and writes :func:`write_outputs`' files:

* ``results.csv`` — the tidy table, one row per cell (scenario, controller, parameters,
  disturbance, seed, status, every metric incl. the safety costs);
* ``leaderboard.csv`` and ``leaderboard.md`` — one row per pair (mean ± 95 % CI of
  the headline metrics, or ``unsupported: reason``);
* ``heatmap.png`` — controllers × scenarios, one headline metric per panel;
* ``overlays/<scenario>.png`` — every controller's first-seed run on the scenario.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from concurrent.futures import Executor
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from train_envs.benchmark.disturbance import resolve_disturbance
from train_envs.benchmark.leaderboard import leaderboard, leaderboard_markdown
from train_envs.benchmark.matrix import (
    benchmark_scenario,
    pair_reasons,
    resolve_controllers,
    resolve_scenarios,
)
from train_envs.benchmark.plots import heatmap_figure, overlay_figure
from train_envs.benchmark.run import params_json, plan_cells, run_cells, trajectory_path

__all__ = ["BenchmarkResult", "run_benchmark", "write_outputs"]


@dataclass
class BenchmarkResult:
    """A benchmark's tables: ``table`` (tidy, one row per cell), ``board`` (one row per
    pair); ``cells_run``: cells run by this call (the rest came from ``out``);
    ``disturbance``: the canonical JSON of the benchmark disturbance."""

    out: Path
    scenarios: list[str]
    controllers: list[str]
    seeds: list[int]
    table: pd.DataFrame
    board: pd.DataFrame
    cells_run: int
    unsupported: dict[tuple[str, str], str] = field(default_factory=dict)
    files: list[Path] = field(default_factory=list)
    disturbance: str = "{}"


def run_benchmark(
    out: str | Path,
    scenarios: Sequence[str] | None = None,
    controllers: Sequence[str] | None = None,
    seeds: Sequence[int] = (0,),
    *,
    disturbance: str | Mapping[str, object] | None = None,
    params: Mapping[tuple[str, str], Mapping[str, float] | str] | None = None,
    executor: Executor | None = None,
    progress: bool = True,
    retry_failed: bool = False,
    figures: bool = True,
) -> BenchmarkResult:
    """Run every (scenario, controller, seed) cell not yet stored in ``out``; write the files.

    Args:
        out: the folder of the stored cells and the outputs (created).
        scenarios: names or sets (default ``all``, see :mod:`train_envs.benchmark.matrix`).
        controllers: names (default: every controller).
        seeds: disturbance seeds, one episode each.
        disturbance: the benchmark disturbance the seeds draw, over each scenario's own:
            a preset (``load``, the default; ``none``), a JSON object text or a mapping
            of ``DisturbanceSpec`` fields (:mod:`train_envs.benchmark.disturbance`).
        params: (scenario, controller) -> parameters to run instead of the defaults,
            or a string: the pair's known error (e.g. its tuning failed).
        executor: where the cells run (default: this process, one after the other).
        progress: a progress bar (or one line per cell when stderr is not a terminal).
        retry_failed: run again the cells stored as failed.
        figures: write the heatmap and the overlays.
    """
    out = Path(out)
    scs = resolve_scenarios(scenarios)
    ctrls = resolve_controllers(controllers)
    seeds = [int(s) for s in seeds]
    if not seeds:
        raise ValueError("seeds: need at least one seed")
    dist = resolve_disturbance(disturbance)
    unsupported = pair_reasons(scs, ctrls, dist)
    cells = plan_cells(out, scs, ctrls, seeds, params, unsupported, dist)
    table, n_run = run_cells(
        cells, out, executor=executor, progress=progress, retry_failed=retry_failed
    )
    pairs = [(sc, c) for sc in scs for c in ctrls]
    board = leaderboard(table, unsupported, pairs)
    res = BenchmarkResult(
        out, scs, ctrls, seeds, table, board, n_run, unsupported, disturbance=dist
    )
    res.files = write_outputs(res, params=params, figures=figures)
    return res


def write_outputs(
    res: BenchmarkResult,
    *,
    params: Mapping[tuple[str, str], Mapping[str, float] | str] | None = None,
    figures: bool = True,
) -> list[Path]:
    """Write the tables and figures of ``res`` into ``res.out``; the paths written."""
    out = res.out
    out.mkdir(parents=True, exist_ok=True)
    files = [out / "results.csv", out / "leaderboard.csv", out / "leaderboard.md"]
    res.table.to_csv(files[0], index=False)
    res.board.to_csv(files[1], index=False)
    files[2].write_text(leaderboard_markdown(res.board))
    if not figures or not len(res.table):
        return files
    fig = heatmap_figure(res.board)
    files.append(out / "heatmap.png")
    fig.savefig(files[-1], dpi=110)
    for sc in res.scenarios:
        runs = {}
        for c in res.controllers:
            p = (params or {}).get((sc, c))
            text = params_json(None if isinstance(p, str) else p)
            path = trajectory_path(out, sc, c, text, res.disturbance)
            if (sc, c) not in res.unsupported and path.exists():
                runs[c] = pd.read_csv(path)
        if runs:
            fig = overlay_figure(runs, scenario=sc, s_stop_m=benchmark_scenario(sc).s_stop_m)
            files.append(out / "overlays" / f"{sc}.png")
            files[-1].parent.mkdir(exist_ok=True)
            fig.savefig(files[-1], dpi=100)
    return files
