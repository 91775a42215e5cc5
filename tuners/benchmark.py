"""``train-envs benchmark``: the leaderboard with default or tuned parameters.

Usage::

    train-envs benchmark --scenarios paper001_stopping paper004_urban \\
        --controllers pid dmc sempc --seeds 0 --out DIR
    train-envs benchmark --seeds 0-4 --out results/benchmark            # every pair
    train-envs benchmark --scenarios real-lines --seeds 0-4 --out DIR   # station pairs
    train-envs benchmark --tuned --seeds 0-4 --out results/benchmark-tuned
    train-envs benchmark --disturbance none --seeds 0 --out DIR        # undisturbed runs

Default parameters: :func:`train_envs.benchmark.run_benchmark`. ``--disturbance``: what
the seeds draw over each scenario's own disturbance (a preset, ``load`` by default or
``none``, or a JSON object of ``DisturbanceSpec`` fields;
:mod:`train_envs.benchmark.disturbance`). With ``--tuned`` each supported pair's
controller parameters are first tuned by MOWOA on training seeds of its scenario under
the same disturbance, so tuning and evaluation see one distribution (:func:`tune_pair`;
:data:`BUDGETS`, ``small`` by default, ``full`` with ``--full-budget``), each tuning run
an Optuna study in ``<out>/studies/`` (one SQLite file per pair, so pairs tune in
parallel), reused on a re-run (resumed, answered from its stored evaluations); the
benchmark then evaluates the selected parameters on the benchmark seeds. A pair whose
tuning fails, or finds no point that keeps the speed limit on every training seed, is a
failed row with that reason.

Inputs are checked before any run; errors are one line, exit code 2
(:func:`train_envs.cli.main`). ``add_benchmark_parser(subparsers)`` adds the
subcommand; :func:`tuners.cli.add_tune_parser` calls it.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from train_envs.cli_args import parse_seeds, writable_folder

__all__ = [
    "BASE_ENV",
    "BUDGETS",
    "Budget",
    "add_benchmark_parser",
    "cmd_benchmark",
    "env_config",
    "tune_pair",
    "tuned_params",
]

#: the env id whose config is replaced by each pair's (scenario and controller)
BASE_ENV = "TrainEnvs/Stopping001PID-v0"


@dataclass(frozen=True)
class Budget:
    """A tuning budget: MOWOA population and generations (incl. the initial one), and
    the scenario seeds each evaluation averages over (disjoint from benchmark seeds)."""

    name: str
    pop: int
    iters: int
    train_seeds: tuple[int, ...]


BUDGETS: dict[str, Budget] = {
    "small": Budget("small", pop=5, iters=2, train_seeds=(1000,)),
    "full": Budget("full", pop=40, iters=100, train_seeds=(1000, 1001, 1002)),
}


def env_config(scenario: str, disturbance: str | None = None) -> dict[str, Any]:
    """The env config of a benchmark scenario (without the controller): a named
    scenario, or real-line mode on one station pair ``<line>_<i>_<j>``; with the
    benchmark disturbance (:func:`~train_envs.benchmark.resolve_disturbance`, default
    ``load``) over the scenario's own."""
    from train_envs.benchmark import benchmark_scenario, resolve_disturbance
    from train_envs.scenarios import list_scenarios

    dist = json.loads(resolve_disturbance(disturbance))
    extra = {"disturbance": dist} if dist else {}
    if scenario in list_scenarios():
        return {"scenario": scenario, **extra}
    sc = benchmark_scenario(scenario)
    return {
        **extra,
        "real_line": {
            "track": sc.extra["line"],
            "train": sc.train.name,
            "sections": [[int(sc.extra["from_stop"]), int(sc.extra["to_stop"])]],
        },
    }


def _error_line(exc: BaseException) -> str:
    from train_envs.cli import error_line

    return error_line(exc).removeprefix("error: ")


def tune_pair(
    scenario: str, controller: str, out: str, budget: Budget, disturbance: str | None = None
) -> dict[str, float] | str:
    """Tune one pair (or reuse its stored study) under the benchmark disturbance
    (:func:`~train_envs.benchmark.resolve_disturbance`, default ``load``); the selected
    parameters, or the reason (a string) why there are none. The study is
    ``<scenario>-<controller>-<budget>-d<hash>-<code>`` (hash of the disturbance) in
    ``<out>/studies/<scenario>--<controller>.db`` (a new code version or another
    disturbance tunes anew)."""
    import optuna

    from train_envs.benchmark import resolve_disturbance
    from train_envs.benchmark.run import params_hash
    from tuners.run import tune

    disturbance = resolve_disturbance(disturbance)

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    folder = Path(out) / "studies"
    folder.mkdir(parents=True, exist_ok=True)
    try:
        res = tune(
            BASE_ENV,
            "mowoa",
            budget.pop,
            budget.iters,
            backend="serial",
            storage=f"sqlite:///{folder / f'{scenario}--{controller}.db'}",
            study=f"{scenario}-{controller}-{budget.name}-d{params_hash(disturbance)[:6]}-{{code}}",
            resume="auto",
            seeds=budget.train_seeds,
            config={**env_config(scenario, disturbance), "controller": controller},
            progress=False,
        )
    except Exception as exc:  # noqa: BLE001 - the pair's row says why
        return f"tuning failed: {_error_line(exc)}"
    params = res.selected_params
    if params is None:
        return "tuning found no feasible parameters (max_overspeed_mps <= 0 on the training seeds)"
    return params


def tuned_params(
    scenarios: Sequence[str],
    controllers: Sequence[str],
    out: str | Path,
    budget: Budget,
    *,
    executor: Any = None,
    unsupported: Mapping[tuple[str, str], str] | None = None,
    progress: bool = True,
    disturbance: str | None = None,
) -> dict[tuple[str, str], dict[str, float] | str]:
    """:func:`tune_pair` for every supported pair (on ``executor`` if given) under the
    benchmark disturbance (:func:`~train_envs.benchmark.resolve_disturbance`, default
    ``load``)."""
    from train_envs.benchmark import pair_reasons, resolve_disturbance

    disturbance = resolve_disturbance(disturbance)
    if unsupported is None:
        unsupported = pair_reasons(scenarios, controllers, disturbance)
    pairs = [(s, c) for s in scenarios for c in controllers if (s, c) not in unsupported]
    out = str(out)
    results: dict[tuple[str, str], dict[str, float] | str] = {}
    run = map if executor is None else executor.map
    n = len(pairs)
    outcomes = run(
        tune_pair,
        [s for s, _ in pairs],
        [c for _, c in pairs],
        [out] * n,
        [budget] * n,
        [disturbance] * n,
    )
    for k, ((s, c), res) in enumerate(zip(pairs, outcomes, strict=True)):
        results[s, c] = res
        if progress:
            what = "ok" if isinstance(res, dict) else res
            print(f"[tune {k + 1}/{len(pairs)}] {s} {c}: {what}", file=sys.stderr, flush=True)
    return results


def _executor(workers: int) -> Any:
    """A spawn-context process pool of ``workers`` single-threaded workers, or None."""
    if workers <= 1:
        return None
    import concurrent.futures as cf
    import multiprocessing as mp
    import os

    from tuners.backends import _init_worker

    return cf.ProcessPoolExecutor(
        max_workers=workers,
        mp_context=mp.get_context("spawn"),
        initializer=_init_worker,
        initargs=(1, os.getpid()),
    )


def add_benchmark_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add ``benchmark`` to ``subparsers``; returns its parser."""
    p = subparsers.add_parser(
        "benchmark",
        help="every controller on every scenario it can run: one leaderboard",
        description="Run controllers x scenarios x seeds through the runner (resumable: "
        "finished cells in --out are not run again) and write results.csv, "
        "leaderboard.csv/.md, heatmap.png and overlays/.",
    )
    p.add_argument(
        "--scenarios",
        nargs="+",
        default=None,
        help="scenario names, station pairs <line>_<i>_<j>, or sets: all, real-lines (default all)",
    )
    p.add_argument("--controllers", nargs="+", default=None, help="(default: every controller)")
    p.add_argument(
        "--seeds", nargs="+", default=None, help="disturbance seeds: 0 1 2, 0-4 (default 0)"
    )
    p.add_argument(
        "--disturbance",
        default=None,
        help="what the seeds draw over each scenario's own disturbance: load (default: "
        "mass x U(0.9, 1.15), resistance disturbance +-0.03 m/s^2), none, or a JSON object "
        "of DisturbanceSpec fields",
    )
    p.add_argument(
        "--tuned",
        action="store_true",
        help="tune each pair by MOWOA on training seeds first (studies in --out/studies)",
    )
    p.add_argument(
        "--full-budget",
        action="store_true",
        help=f"with --tuned: pop {BUDGETS['full'].pop}, {BUDGETS['full'].iters} generations, "
        f"{len(BUDGETS['full'].train_seeds)} training seeds (default: pop "
        f"{BUDGETS['small'].pop}, {BUDGETS['small'].iters} generations, "
        f"{len(BUDGETS['small'].train_seeds)} seed)",
    )
    p.add_argument("--out", default="benchmark", help="output folder (default ./benchmark)")
    p.add_argument("--workers", type=int, default=1, help="parallel processes (default 1)")
    p.add_argument("--retry-failed", action="store_true", help="run failed cells again")
    p.add_argument("--no-figures", action="store_true", help="tables only")
    p.add_argument("--no-progress", action="store_true", help="no progress output")
    p.set_defaults(func=cmd_benchmark)
    return p


def cmd_benchmark(args: argparse.Namespace) -> int:
    from train_envs.benchmark import (
        pair_reasons,
        resolve_controllers,
        resolve_disturbance,
        resolve_scenarios,
    )
    from train_envs.benchmark.outputs import run_benchmark

    if args.workers < 1:
        raise ValueError(f"--workers must be >= 1, got {args.workers}")
    if args.full_budget and not args.tuned:
        raise ValueError("--full-budget goes with --tuned")
    seeds = parse_seeds(args.seeds) or [0]
    scenarios = resolve_scenarios(args.scenarios)
    controllers = resolve_controllers(args.controllers)
    disturbance = resolve_disturbance(args.disturbance)
    out = writable_folder(args.out)
    executor = _executor(args.workers)
    try:
        params = None
        if args.tuned:
            budget = BUDGETS["full" if args.full_budget else "small"]
            params = tuned_params(
                scenarios,
                controllers,
                out,
                budget,
                executor=executor,
                unsupported=pair_reasons(scenarios, controllers, disturbance),
                progress=not args.no_progress,
                disturbance=disturbance,
            )
        res = run_benchmark(
            out,
            scenarios,
            controllers,
            seeds,
            disturbance=disturbance,
            params=params,
            executor=executor,
            progress=not args.no_progress,
            retry_failed=args.retry_failed,
            figures=not args.no_figures,
        )
    finally:
        if executor is not None:
            executor.shutdown(wait=True, cancel_futures=True)
    counts = res.board["status"].value_counts().to_dict()
    print(
        f"{len(res.board)} pairs ({', '.join(f'{n} {k}' for k, n in counts.items())}); "
        f"{res.cells_run} runs made, {len(res.table) - res.cells_run} from {out}"
    )
    for f in res.files:
        print(f"wrote {f}")
    return 0
