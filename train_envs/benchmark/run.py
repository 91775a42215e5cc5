"""Run the benchmark's cells through the runner, resumably: the tidy results table.

A cell is one closed-loop episode: (scenario, controller, parameters, disturbance,
seed), run by :func:`train_envs.simulation.simulate` (ATP supervision on, as
everywhere) on the scenario with the benchmark disturbance over its own
(:mod:`train_envs.benchmark.disturbance`; the seed draws it). Its record is one row of
the tidy table: ``scenario``, ``controller``, ``parameters`` (JSON of the parameters
set on the controller, ``{}`` = its defaults), ``params_hash``, ``disturbance`` (its
canonical JSON), ``seed``,
``status`` (``ok``, ``failed`` or ``unsupported``), ``error``, ``wall_time_s``,
``cpu_time_s`` (this process's CPU time: the cost without the machine's other load) and
every episode metric (:func:`train_envs.metrics.episode_metrics`: units in the names,
the safety costs ``atp_interventions``, ``overrun_m``, ``safety_cost``, ...).

Resumable: each finished cell is appended at once as one JSON line to
``<out>/cells.jsonl``, keyed by (scenario, controller, params_hash, disturbance,
seed); a cell
whose key is there is not run again (a failed one neither, unless ``retry_failed``).
A run killed part-way keeps every finished cell (a torn last line is ignored). A cell
that raises is recorded as failed with its one-line error; the others go on. The runs
of the first seed are kept as ``<out>/runs/<scenario>/<controller>-<hashes>.csv.gz``
for the overlays. One benchmark process writes a folder at a time.
"""

from __future__ import annotations

import hashlib
import json
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import Executor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

from train_envs.benchmark.disturbance import apply_disturbance
from train_envs.benchmark.matrix import benchmark_scenario, pair_reasons
from train_envs.controllers.requirements import UnsupportedScenarioError

__all__ = [
    "CELLS_FILE",
    "Cell",
    "CellStore",
    "params_hash",
    "params_json",
    "plan_cells",
    "run_cell",
    "run_cells",
    "trajectory_path",
]

CELLS_FILE = "cells.jsonl"
#: the identifying columns of the tidy table, in order
ID_COLUMNS = (
    "scenario",
    "controller",
    "parameters",
    "params_hash",
    "disturbance",
    "seed",
    "status",
    "error",
    "wall_time_s",
    "cpu_time_s",
)


def params_json(params: Mapping[str, float] | None) -> str:
    """Canonical JSON of controller parameters (sorted names, floats)."""
    return json.dumps({str(k): float(v) for k, v in sorted((params or {}).items())})


def params_hash(text: str) -> str:
    """12 hex digits of the SHA-256 of a :func:`params_json` text."""
    return hashlib.sha256(text.encode()).hexdigest()[:12]


@dataclass(frozen=True)
class Cell:
    """One episode of the benchmark; ``parameters`` is a :func:`params_json` text;
    ``keep_run``: write its trajectory (``trajectory`` file path) for the overlays;
    ``error``: a known failure recorded without running (e.g. a tuning that failed);
    ``disturbance``: the canonical JSON of the benchmark disturbance (``{}``: none)."""

    scenario: str
    controller: str
    parameters: str
    seed: int
    keep_run: str | None = None
    error: str | None = None
    disturbance: str = "{}"

    @property
    def key(self) -> CellKey:
        return (
            self.scenario,
            self.controller,
            params_hash(self.parameters),
            self.disturbance,
            int(self.seed),
        )


CellKey = tuple[str, str, str, str, int]


def _record_key(rec: Mapping[str, Any]) -> CellKey:
    return (
        rec["scenario"],
        rec["controller"],
        rec["params_hash"],
        rec.get("disturbance", "{}"),
        int(rec["seed"]),
    )


def trajectory_path(
    out: str | Path, scenario: str, controller: str, parameters: str, disturbance: str = "{}"
) -> Path:
    """Where the first seed's run of a (scenario, controller, parameters, disturbance)
    is kept."""
    name = f"{controller}-{params_hash(parameters)}-{params_hash(disturbance)[:6]}.csv.gz"
    return Path(out) / "runs" / scenario / name


def _error_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if isinstance(exc, ValueError) else f"{type(exc).__name__}: {text}"


def run_cell(cell: Cell) -> dict[str, Any]:
    """Run one cell; its record (never raises for an error of the run itself)."""
    from train_envs.simulation import simulate

    rec: dict[str, Any] = {
        "scenario": cell.scenario,
        "controller": cell.controller,
        "parameters": cell.parameters,
        "params_hash": params_hash(cell.parameters),
        "disturbance": cell.disturbance,
        "seed": int(cell.seed),
        "status": "ok",
        "error": "",
    }
    t0, c0 = time.perf_counter(), time.process_time()
    if cell.error is not None:
        return {
            **rec,
            "status": "failed",
            "error": cell.error,
            "wall_time_s": 0.0,
            "cpu_time_s": 0.0,
        }
    try:
        res = simulate(
            apply_disturbance(benchmark_scenario(cell.scenario), cell.disturbance),
            cell.controller,
            seed=cell.seed,
            params=json.loads(cell.parameters) or None,
        )
    except UnsupportedScenarioError as exc:
        rec.update(status="unsupported", error=_error_line(exc))
    except Exception as exc:  # noqa: BLE001 - a failing cell is recorded, the others go on
        rec.update(status="failed", error=_error_line(exc))
    else:
        rec.update({k: float(v) for k, v in res.metrics.items()})
        if cell.keep_run:
            path = Path(cell.keep_run)
            path.parent.mkdir(parents=True, exist_ok=True)
            res.df.to_csv(path, index=False)
    rec["wall_time_s"] = time.perf_counter() - t0
    rec["cpu_time_s"] = time.process_time() - c0
    return rec


class CellStore:
    """The finished cells of a folder (``cells.jsonl``), appended one line per cell."""

    def __init__(self, out: str | Path) -> None:
        self.path = Path(out) / CELLS_FILE
        self.records: dict[CellKey, dict[str, Any]] = {}
        if self.path.exists():
            for line in self.path.read_text().splitlines():
                try:
                    rec = json.loads(line)
                except json.JSONDecodeError:  # a torn last line of a killed run
                    continue
                rec.setdefault("disturbance", "{}")
                self.records[_record_key(rec)] = rec

    def has(self, cell: Cell, retry_failed: bool = False) -> bool:
        rec = self.records.get(cell.key)
        return rec is not None and not (retry_failed and rec["status"] == "failed")

    def add(self, rec: dict[str, Any]) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with self.path.open("a") as f:
            f.write(json.dumps(rec) + "\n")
        self.records[_record_key(rec)] = rec

    def table(self, cells: Sequence[Cell]) -> pd.DataFrame:
        """The tidy table of ``cells`` (those recorded), in their order."""
        rows = [self.records[c.key] for c in cells if c.key in self.records]
        df = pd.DataFrame(rows)
        if not len(df):
            return pd.DataFrame(columns=list(ID_COLUMNS))
        ids = [c for c in ID_COLUMNS if c in df]
        return df[[*ids, *(c for c in df.columns if c not in ID_COLUMNS)]]


def _progress(total: int, enabled: bool) -> Callable[[dict[str, Any]], None]:
    """A per-cell progress callback: a tqdm bar on a terminal, else one line per cell."""
    if not enabled:
        return lambda rec: None
    if sys.stderr.isatty():
        from tqdm.auto import tqdm

        bar = tqdm(total=total, desc="benchmark", unit="run")

        def tick(rec: dict[str, Any]) -> None:
            bar.set_postfix_str(f"{rec['scenario']}/{rec['controller']} s{rec['seed']}")
            bar.update()
            if bar.n >= total:
                bar.close()

        return tick
    count = [0]

    def line(rec: dict[str, Any]) -> None:
        count[0] += 1
        err = f" {rec['error'][:80]}" if rec["status"] != "ok" else ""
        print(
            f"[{count[0]}/{total}] {rec['scenario']} {rec['controller']} seed {rec['seed']}: "
            f"{rec['status']} ({rec['wall_time_s']:.1f} s){err}",
            file=sys.stderr,
            flush=True,
        )

    return line


def plan_cells(
    out: str | Path,
    scenarios: Sequence[str],
    controllers: Sequence[str],
    seeds: Sequence[int],
    params: Mapping[tuple[str, str], Mapping[str, float] | str] | None = None,
    unsupported: Mapping[tuple[str, str], str] | None = None,
    disturbance: str = "{}",
) -> list[Cell]:
    """Every cell of the matrix, pairs in scenario-major order, seeds within a pair.

    ``params``: (scenario, controller) -> parameters, or a string = the pair's known
    error (every seed is recorded failed with it); missing pairs run their defaults.
    ``unsupported`` (default: :func:`~train_envs.benchmark.matrix.pair_reasons`): the
    pairs not run; they have no cells. ``disturbance``: the canonical JSON of the
    benchmark disturbance (:func:`~train_envs.benchmark.disturbance.resolve_disturbance`).
    """
    if unsupported is None:
        unsupported = pair_reasons(scenarios, controllers)
    cells = []
    for sc in scenarios:
        for c in controllers:
            if (sc, c) in unsupported:
                continue
            p = (params or {}).get((sc, c))
            error = p if isinstance(p, str) else None
            text = params_json(None if isinstance(p, str) else p)
            for k, seed in enumerate(seeds):
                keep = str(trajectory_path(out, sc, c, text, disturbance)) if k == 0 else None
                cells.append(Cell(sc, c, text, int(seed), keep, error, disturbance))
    return cells


def run_cells(
    cells: Sequence[Cell],
    out: str | Path,
    *,
    executor: Executor | None = None,
    progress: bool = True,
    retry_failed: bool = False,
) -> tuple[pd.DataFrame, int]:
    """Run the cells not yet in ``<out>/cells.jsonl``; (tidy table of all, cells run).

    ``executor``: where cells run (e.g. a ``ProcessPoolExecutor``); default: here, one
    after the other. Records are written by this process as each cell finishes.
    """
    store = CellStore(out)
    todo = [c for c in cells if not store.has(c, retry_failed)]
    tick = _progress(len(todo), progress and bool(todo))
    if executor is None:
        for cell in todo:
            rec = run_cell(cell)
            store.add(rec)
            tick(rec)
    else:
        futures = [executor.submit(run_cell, cell) for cell in todo]
        for fut in as_completed(futures):
            rec = fut.result()
            store.add(rec)
            tick(rec)
    return store.table(cells), len(todo)
