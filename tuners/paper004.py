"""Paper 004's tuning: PSO (MPC-PSO) and MOWOA (MPC-MOWOA) on the same budget.

:func:`reproduce_paper004` is ``train-envs reproduce paper004`` (the ``paper004`` entry
point of the group ``train_envs.reproduce``). It tunes the seven DMC parameters of 004
§3.4 on ``TrainEnvs/Urban004-v0`` twice with the **same budget** — PSO (004's MPC-PSO,
one objective: the Tchebycheff scalarisation under the target weights) and MOWOA (five
objectives, Tchebycheff decomposition, pick by cosine similarity) — over disturbed
training seeds, then hands both picks to :func:`train_envs.reproduce.paper004.compare_paper004`,
which evaluates them beside Fuzzy-PID and the default DMC on **held-out** seeds. The
setting (disturbance, constraints, tolerance scale) is that module's. Runs are stored
in an SQLite study (``out/reproduce/paper004.db``, one study per code version) and
resumed, so a killed reproduction loses nothing and a changed code starts afresh.
Write-up and measured table: ``docs/papers/paper004.md``.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import pandas as pd

from train_envs.reproduce.paper004 import (
    CONFIG,
    CONSTRAINTS,
    ENV_DMC,
    F_BOUNDS,
    HOLDOUT_SEEDS,
    compare_paper004,
)

__all__ = ["figures_paper004", "reproduce_paper004", "tune_paper004"]


def tune_paper004(
    algo: str, pop: int, iters: int, seeds: Sequence[int], storage: str | None, seed: int
):
    """One tuner's run on 004's setting (a :class:`tuners.run.TuneResult`), resumed."""
    from tuners.run import tune

    return tune(
        ENV_DMC,
        algo,
        pop,
        iters,
        storage=storage,
        # one study per code version: a table is never answered from evaluations that
        # older code made
        study=f"paper004-{algo}-{pop}x{iters}-s{seed}-{{code}}",
        resume="auto",
        seeds=seeds,
        config=CONFIG,
        constraints=CONSTRAINTS,
        f_bounds=F_BOUNDS,
        seed=seed,
        progress=True,
    )


def reproduce_paper004(
    seed: int = 0,
    *,
    pop: int = 16,
    iters: int = 8,
    train_seeds: Sequence[int] = (0, 1),
    holdout_seeds: Sequence[int] = HOLDOUT_SEEDS,
    storage: str | None = "sqlite:///out/reproduce/paper004.db",
    runs: dict[str, pd.DataFrame] | None = None,
) -> pd.DataFrame:
    """Held-out objectives of the four drivers and their change vs Fuzzy-PID (see module).

    ``seed`` seeds both tuners; ``pop × iters`` is each tuner's budget. ``runs``, if
    given, receives each tuner's evaluations (:attr:`tuners.run.TuneResult.evaluations`).
    """
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    if storage and storage.startswith("sqlite:///"):
        Path(storage.removeprefix("sqlite:///")).parent.mkdir(parents=True, exist_ok=True)
    tuned = {}
    for algo in ("pso", "mowoa"):
        res = tune_paper004(algo, pop, iters, train_seeds, storage, seed)
        if res.selected_params is None:
            raise RuntimeError(f"{algo}: no feasible solution in {pop} x {iters} evaluations")
        tuned[f"mpc_{algo}"] = res.selected_params
        if runs is not None:
            runs[algo] = res.evaluations
    out = compare_paper004(tuned, holdout_seeds)
    budget = f"{pop} x {iters} per tuner, train seeds {list(train_seeds)}"
    out.attrs = {"budget": budget, **out.attrs}
    return out


def figures_paper004(table: pd.DataFrame, runs: dict[str, pd.DataFrame]) -> dict:
    """MOWOA's Pareto matrix and parallel coordinates, and the hypervolume of each
    tuner's feasible set per generation (:mod:`tuners.plots`)."""
    from tuners import plots

    figs = {}
    if "mowoa" in runs:
        figs["mowoa_pareto"] = plots.pareto_front_figure(runs["mowoa"])
        figs["mowoa_parallel"] = plots.parallel_coordinates_figure(runs["mowoa"])
    for algo, df in runs.items():
        figs[f"{algo}_hypervolume"] = plots.hypervolume_figure(df)
    return figs
