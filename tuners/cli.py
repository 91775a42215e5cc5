"""``train-envs tune``: the tuners' command line.

Usage::

    train-envs tune --env TrainEnvs/Urban004-v0 --algo mowoa --pop 40 --iters 100 \\
        --workers 8 --storage sqlite:///runs.db --study urban004-mowoa [--resume]
    train-envs tune --study urban004-mowoa --storage sqlite:///runs.db --resume
    train-envs tune show urban004-mowoa --storage sqlite:///runs.db [--out results/]
    train-envs tune list --storage sqlite:///runs.db
    train-envs tune delete urban004-mowoa --storage sqlite:///runs.db

On ``--resume`` every option left out takes the study's stored value (:mod:`tuners.settings`).
Inputs (env id, seeds, storage, output folder, objectives and constraints, population)
are checked before any evaluation runs; errors are one line (:func:`train_envs.cli.main`).
``add_tune_parser(subparsers)`` adds the subcommand to an argparse subparsers object and
sets ``func`` (an ``args -> int`` exit code) on the parsed namespace; ``train-envs``
finds it through the ``tuners`` entry point of the group ``train_envs.cli``.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any

from train_envs.cli_args import json_object, key_values, parse_seeds, writable_folder

#: ``--algo`` choices (:data:`tuners.run.ALGORITHMS`, listed here so that the parser
#: imports neither pymoo nor Optuna)
ALGO_CHOICES = ("mowoa", "pso", "mopso", "nsga2", "moead")
ALGO_CHOICES += ("optuna-tpe", "optuna-nsga2", "optuna-nsga3", "optuna-gp")

__all__ = ["add_tune_parser", "cmd_delete", "cmd_list", "cmd_show", "cmd_tune", "write_outputs"]

DEFAULT_STORAGE = "sqlite:///tuning.db"  # = tuners.run.DEFAULT_STORAGE (no heavy import)


def _config(text: str | None) -> dict[str, Any] | None:
    return json_object(text, "--config")


def _finite(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise ValueError("the limit must be finite")
    return value


def _constraints(items: list[str] | None) -> dict[str, float] | None:
    return key_values(items, "--constraint", _finite, "METRIC=LIMIT") or None


def add_tune_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add ``tune`` (and ``tune show``) to ``subparsers``, and ``benchmark``
    (:func:`tuners.benchmark.add_benchmark_parser`); returns the ``tune`` parser."""
    from tuners.benchmark import add_benchmark_parser

    p = subparsers.add_parser(
        "tune",
        help="tune an env's controller parameters (MOWOA, PSO, NSGA-II, MOEA/D)",
        description="Search the inner controller's parameters of an env id over "
        "closed-loop episodes; every evaluation is stored in an Optuna study and the "
        "run can be resumed. `train-envs tune show <study>` prints a stored run.",
    )
    p.add_argument("--env", help="registered env id, e.g. TrainEnvs/Urban004FuzzyPID-v0")
    p.add_argument(
        "--algo",
        default=None,
        choices=ALGO_CHOICES,
        help="search algorithm (default mowoa; optuna-*: Optuna's samplers)",
    )
    p.add_argument("--pop", type=int, default=None, help="population size (default 40)")
    p.add_argument(
        "--iters", type=int, default=None, help="generations incl. the initial one (default 100)"
    )
    p.add_argument(
        "--workers", type=int, default=None, help="parallel workers (default: all cores)"
    )
    p.add_argument(
        "--backend",
        default=None,
        choices=["serial", "processes", "lockstep", "dask"],
        help="where evaluations run (default: lockstep for envs whose controller batches "
        "- PID, Fuzzy-PID, DMC -, else processes)",
    )
    p.add_argument("--dask-address", default=None, help="Dask scheduler, e.g. tcp://host:8786")
    p.add_argument(
        "--storage",
        default=DEFAULT_STORAGE,
        help=f"Optuna storage URL (default {DEFAULT_STORAGE}) or journal:PATH (an Optuna "
        "journal file: cheapest writes, a generation's evaluations written at once)",
    )
    p.add_argument(
        "--study",
        default=None,
        help="study name (default <env>-<algo>-s<seed>; '{code}' stands for the code "
        "fingerprint: one study per code version)",
    )
    p.add_argument(
        "--resume",
        action="store_const",
        const=True,
        default=False,
        help="continue the study (it must hold a run); options left out take its stored values",
    )
    p.add_argument(
        "--resume-or-start",
        dest="resume",
        action="store_const",
        const="auto",
        help="continue the study if it holds a run, else start it",
    )
    p.add_argument(
        "--allow-code-change",
        action="store_true",
        help="resume a study that other code started (refused by default: its cached "
        "evaluations would answer for this code)",
    )
    p.add_argument(
        "--seeds",
        nargs="+",
        default=None,
        help="scenario seeds per evaluation: 0 1 2, 0-4 (default 0)",
    )
    p.add_argument(
        "--objectives",
        nargs="+",
        default=None,
        help="itae stop time comfort energy (default: those the scenario has) or metric names",
    )
    p.add_argument(
        "--target-weights",
        nargs="+",
        type=float,
        default=None,
        help="weights of the final pick, one per objective (default: equal)",
    )
    p.add_argument(
        "--f-lower",
        nargs="+",
        type=float,
        default=None,
        help="lower tolerance bound per objective (with --f-upper: Tchebycheff scale)",
    )
    p.add_argument("--f-upper", nargs="+", type=float, default=None, help="upper bound each")
    p.add_argument(
        "--seed", type=int, default=None, help="random seed of the algorithm (default 1)"
    )
    p.add_argument("--config", default=None, help="env config as JSON or @file.json")
    p.add_argument("--params", nargs="+", default=None, help="parameters to search (default all)")
    p.add_argument("--space", default=None, choices=["unit", "native"], help="(default unit)")
    p.add_argument(
        "--constraint",
        action="append",
        metavar="METRIC=LIMIT",
        default=None,
        help="constraint: worst seed's metric <= limit (repeatable; default max_overspeed_mps=0)",
    )
    p.add_argument(
        "--normalization",
        default=None,
        choices=["auto", "defaults", "pareto"],
        help="scale of the final pick without --f-lower/--f-upper (default auto)",
    )
    p.add_argument(
        "--no-defaults",
        dest="include_defaults",
        action="store_const",
        const=False,
        default=None,
        help="do not seed the initial population with the default parameters",
    )
    p.add_argument("--max-retries", type=int, default=2, help="re-submissions of a failing run")
    p.add_argument(
        "--holdout-seeds",
        nargs="+",
        default=None,
        help="after the run, compare selected vs defaults on these scenario seeds",
    )
    p.add_argument("--out", default=None, help="folder for CSV/Parquet and plots")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_tune)

    sub = p.add_subparsers(dest="tune_command", metavar="{show,list,delete}")
    ps = sub.add_parser("show", help="print the Pareto set and selected solution of a study")
    ps.add_argument("study", help="study name")
    ps.add_argument("--storage", default=DEFAULT_STORAGE, help="Optuna storage URL")
    ps.add_argument("--out", default=None, help="folder for CSV/Parquet and plots")
    ps.add_argument("--max-rows", type=int, default=50, help="Pareto rows printed")
    ps.set_defaults(func=cmd_show)
    pl = sub.add_parser("list", help="list the studies of a storage")
    pl.add_argument("--storage", default=DEFAULT_STORAGE, help="Optuna storage URL")
    pl.set_defaults(func=cmd_list)
    pd_ = sub.add_parser("delete", help="delete a study (refused while a run writes it)")
    pd_.add_argument("study", help="study name")
    pd_.add_argument("--storage", default=DEFAULT_STORAGE, help="Optuna storage URL")
    pd_.set_defaults(func=cmd_delete)
    add_benchmark_parser(subparsers)
    return p


def write_outputs(result: Any, out: str | Path) -> list[Path]:
    """CSV, Parquet (if pyarrow is there) and PNG plots of a result into folder ``out``."""
    from tuners import plots

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    stem = result.study_name.replace("/", "_")
    files = [result.to_csv(out / f"{stem}.csv")]
    try:
        files.append(result.to_parquet(out / f"{stem}.parquet"))
    except ImportError as exc:  # no parquet engine
        print(f"note: no Parquet export ({exc})", file=sys.stderr)
    df = result.evaluations
    if len(df) and df["feasible"].any():
        for name, fn in (
            ("pareto", plots.pareto_front_figure),
            ("parallel", plots.parallel_coordinates_figure),
            ("hypervolume", plots.hypervolume_figure),
        ):
            path = out / f"{stem}_{name}.png"
            fn(df).savefig(path, dpi=110)
            files.append(path)
    return files


def _check_inputs(args: argparse.Namespace) -> dict[str, Any]:
    """Parse and check every input that can be checked before work starts."""
    import gymnasium as gym

    import train_envs  # noqa: F401  (registers the ids)

    if not args.env and not args.resume:
        raise ValueError("tune needs --env (or --resume of a study, or `tune show <study>`)")
    if args.env and args.env not in gym.registry:
        ids = sorted(i for i in gym.registry if i.startswith("TrainEnvs/"))
        raise ValueError(f"--env: {args.env!r} is not a registered env id; ids: {ids}")
    if (args.f_lower is None) != (args.f_upper is None):
        raise ValueError("--f-lower and --f-upper go together")
    for flag, vals in (
        ("--target-weights", args.target_weights),
        ("--f-lower", args.f_lower),
        ("--f-upper", args.f_upper),
    ):
        if vals is not None and not all(math.isfinite(v) for v in vals):
            raise ValueError(f"{flag}: values must be finite, got {vals}")
    if args.target_weights is not None and (
        min(args.target_weights) < 0 or sum(args.target_weights) <= 0
    ):
        raise ValueError(
            f"--target-weights: values >= 0 with a positive sum, got {args.target_weights}"
        )
    for flag, val, low in (
        ("--pop", args.pop, 2),
        ("--iters", args.iters, 1),
        ("--workers", args.workers, 1),
        ("--max-retries", args.max_retries, 0),
    ):
        if val is not None and val < low:
            raise ValueError(f"{flag} must be >= {low}, got {val}")
    out = {
        "seeds": parse_seeds(args.seeds),
        "holdout": parse_seeds(args.holdout_seeds, "--holdout-seeds"),
        "config": _config(args.config),
        "constraints": _constraints(args.constraint),
        "f_bounds": None if args.f_lower is None else (args.f_lower, args.f_upper),
    }
    if args.out:
        writable_folder(args.out)
    from tuners.storage import check_storage

    check_storage(args.storage)  # a bad URL or an unreadable file: an error now
    return out


def cmd_tune(args: argparse.Namespace) -> int:
    import optuna

    from tuners.run import TuneInterrupted, show, tune

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    inp = _check_inputs(args)
    try:
        res = tune(
            args.env,
            args.algo,
            args.pop,
            args.iters,
            workers=args.workers,
            backend=args.backend,
            dask_address=args.dask_address,
            storage=args.storage,
            study=args.study,
            resume=args.resume,
            allow_code_change=args.allow_code_change,
            seeds=inp["seeds"],
            objectives=args.objectives,
            target_weights=args.target_weights,
            f_bounds=inp["f_bounds"],
            seed=args.seed,
            config=inp["config"],
            params=args.params,
            space=args.space,
            constraints=inp["constraints"],
            normalization=args.normalization,
            include_defaults=args.include_defaults,
            max_retries=args.max_retries,
            progress=not args.no_progress,
        )
    except TuneInterrupted as exc:
        print(str(exc), file=sys.stderr)
        return 130
    st = res.stats
    print(
        f"{res.study_name}: {st.run} evaluations run, {st.cached} answered from the cache, "
        f"{st.failed_attempts} failed attempts, {res.wall_time_s:.1f} s"
    )
    print(show(res.study_name, args.storage))
    holdout = inp["holdout"]
    if holdout:
        from train_envs.labels import format_table

        table = res.compare_on_seeds(holdout)
        print(f"Held-out seeds {holdout}:")
        bounds = dict(getattr(res.problem, "constraints", ()))
        print(format_table(table, digits=5, bounds=bounds))
    if args.out:
        for f in write_outputs(res, args.out):
            print(f"wrote {f}")
        if holdout and res.selected is not None:
            from train_envs.plotting import comparison_figure

            seed = holdout[0]
            runs = res.trajectories(seed)
            env_id = getattr(res.problem, "env_id", args.env)
            fig = comparison_figure(
                runs,
                title=f"{env_id}: defaults vs selected, held-out seed {seed}",
                s_stop_m=_stop_of(env_id, getattr(res.problem, "config", None), seed),
            )
            path = Path(args.out) / f"{res.study_name.replace('/', '_')}_speed_distance.png"
            fig.savefig(path, dpi=110)
            print(f"wrote {path}")
    return 0


def _stop_of(env_id: str, config: Any, seed: int) -> float | None:
    """The stopping point of the env's episode ``seed`` (None for a cruise)."""
    import gymnasium as gym

    env = gym.make(env_id, config=config)
    try:
        env.reset(seed=seed)
        return env.unwrapped.scenario.s_stop_m
    finally:
        env.close()


def _study_name(name: str) -> str:
    from tuners.storage import code_fingerprint

    return name.replace("{code}", code_fingerprint()[:8])


def cmd_show(args: argparse.Namespace) -> int:
    from tuners.run import load_result, show

    args.study = _study_name(args.study)
    if args.out:
        writable_folder(args.out)
    print(show(args.study, args.storage, max_rows=args.max_rows))
    if args.out:
        for f in write_outputs(load_result(args.study, args.storage), args.out):
            print(f"wrote {f}")
    return 0


def cmd_list(args: argparse.Namespace) -> int:
    import pandas as pd

    from tuners.storage import list_studies

    df = list_studies(args.storage)
    if not len(df):
        print(f"no studies in {args.storage}")
        return 0
    with pd.option_context("display.width", 200, "display.max_colwidth", 60):
        print(df.to_string(index=False))
    return 0


def cmd_delete(args: argparse.Namespace) -> int:
    from tuners.storage import delete_study

    name = _study_name(args.study)
    delete_study(name, args.storage)
    print(f"deleted study {name!r} from {args.storage}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """``python -m tuners.cli ...`` is the ``train-envs`` command (:func:`train_envs.cli.main`)."""
    from train_envs.cli import main as cli_main

    return cli_main(argv)


if __name__ == "__main__":
    raise SystemExit(main())
