"""Command-line interface: ``train-envs list | reproduce | simulate`` and the subcommands
that the packages built on train_envs register (``tune``; ``train``, ``evaluate``).

Those are found as entry points of the group ``train_envs.cli`` (see
:mod:`train_envs.cli_args`): each is a function ``add(subparsers)`` that adds its
subcommands and sets ``func`` (an ``args -> int`` exit code) on the parsed namespace.
Every error of a command is printed as one ``error:`` line on stderr with exit code 2
(``--debug``: the traceback instead); Ctrl-C ends with exit code 130.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import pandas as pd

from train_envs.cli_args import CLI_GROUP, key_values, registered

DESCRIPTION = (
    "Gymnasium environments for automatic train operation: list the catalogue, run "
    "closed-loop episodes, reproduce the papers' tables, tune and train."
)


def _parse_params(items: list[str] | None) -> dict[str, float]:
    return key_values(items, "--param", float, "key=value")


def cmd_list(args: argparse.Namespace) -> int:
    from train_envs.controllers import list_controllers, requirements
    from train_envs.lines import list_tracks
    from train_envs.scenarios import SCENARIOS
    from train_envs.trains import get_train, list_trains

    what = args.what
    if what in ("all", "scenarios"):
        print("Scenarios:")
        for name, fn in SCENARIOS.items():
            doc = (fn.__doc__ or "").strip().splitlines()[0]
            print(f"  {name:32s} {doc}")
    if what in ("all", "controllers"):
        print("Controllers:")
        for name in list_controllers():
            req = requirements(name)
            print(f"  {name:14s} {req.description}")
            print(f"  {'':14s}   needs: {req.summary()}")
    if what in ("all", "trains"):
        print("Trains:")
        for name in list_trains():
            t = get_train(name)
            print(
                f"  {name:24s} {t.mass_kg / 1e3:7.1f} t  {t.n_cars} car(s)  "
                f"v_max {t.max_speed_mps * 3.6:6.1f} km/h"
            )
    if what in ("all", "tracks"):
        print("Tracks:")
        for name in list_tracks():
            print(f"  {name}")
    if what in ("all", "envs"):
        cmd_envs(args)
    return 0


def cmd_simulate(args: argparse.Namespace) -> int:
    from train_envs.plotting import speed_distance_figure
    from train_envs.scenarios import get_scenario
    from train_envs.simulation import SimulationError, simulate

    sc = get_scenario(args.scenario)
    params = _parse_params(args.param)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    stem = f"{sc.name}_{args.controller}"
    try:
        res = simulate(sc, args.controller, seed=args.seed, params=params)
    except SimulationError as err:
        err.partial.df.to_csv(out / f"{stem}_partial.csv", index=False)
        print(
            f"error: {err}; partial run saved to {out / (stem + '_partial.csv')}", file=sys.stderr
        )
        return 1
    res.df.to_csv(out / f"{stem}.csv", index=False)
    fig = speed_distance_figure(
        res.df, title=f"{sc.name} — {args.controller}", s_stop_m=sc.s_stop_m
    )
    png = out / f"{stem}.png"
    fig.savefig(png, dpi=120)
    pngs = [png]
    if {"alpha", "h_c", "J"} <= set(res.df.columns):  # the DMC's online adjustments
        from train_envs.plotting import dmc_adjustment_figure

        p = res.params or {}
        adj = dmc_adjustment_figure(
            res.df,
            title=f"{sc.name} — {args.controller}: online softening and correction",
            alpha_bounds=(p["alpha_min"], p["alpha_max"]) if "alpha_min" in p else None,
            h_band=(p["h0"] - 3 * p["k_h"], p["h0"] + 3 * p["k_h"]) if "h0" in p else None,
        )
        pngs.append(out / f"{stem}_adjustments.png")
        adj.savefig(pngs[-1], dpi=120)
    from train_envs.labels import format_number

    table = pd.Series({k: format_number(v, 6) for k, v in res.metrics.items()}, name="value")
    print(
        f"Scenario {sc.name}, controller {args.controller}, seed {args.seed}, "
        f"{len(res.df)} rows, {res.wall_time_s:.2f} s wall"
    )
    print(table.to_frame().to_string())
    print(f"wrote {', '.join(map(str, pngs))} and {out / (stem + '.csv')}")
    return 0


def cmd_reproduce(args: argparse.Namespace) -> int:
    from train_envs.cli_args import writable_folder
    from train_envs.labels import format_table
    from train_envs.reproduce import get_reproduction, write_reproduction

    files: list[Path] = []
    if args.out:
        writable_folder(args.out)  # before any work: one error line
        df, files = write_reproduction(args.paper, args.out, seed=args.seed)
    else:
        df = get_reproduction(args.paper)(seed=args.seed)
    with pd.option_context("display.width", 200):
        print(format_table(df))
    if args.csv:
        df.to_csv(args.csv, index=False)
        files.append(Path(args.csv))
    for f in files:
        print(f"wrote {f}")
    return 0


def cmd_envs(_args: argparse.Namespace) -> int:
    import gymnasium as gym

    from train_envs.envs import ENV_SPECS, registered_ids

    print("Env ids (gymnasium.make(id, config={...})):")
    for env_id in registered_ids():
        env = gym.make(env_id)
        specs = env.unwrapped.param_specs
        print(f"  {env_id}: {ENV_SPECS[env_id][1]}")
        for p in specs:
            scale = "log" if p.log else "lin"
            print(
                f"      action {p.name:12s} [{p.low:g}, {p.high:g}] {scale}, default {p.default:g}"
            )
        env.close()
    return 0


def add_registered_commands(sub: argparse._SubParsersAction) -> list[str]:
    """Add the subcommands of every ``train_envs.cli`` entry point; returns their names.

    An entry point that cannot be imported is skipped with a one-line warning, so a
    missing optional dependency of one package leaves the other commands working.
    """
    added = []
    for name, ep in registered(CLI_GROUP).items():
        try:
            add = ep.load()
        except ImportError as exc:
            print(f"warning: train-envs: commands of {name!r} unavailable ({exc})", file=sys.stderr)
            continue
        add(sub)
        added.append(name)
    return added


def package_version() -> str:
    """The installed ``train-envs`` version (``unknown`` when run from a bare checkout)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("train-envs")
    except PackageNotFoundError:
        return "unknown"


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="train-envs", description=DESCRIPTION)
    p.add_argument("--version", action="version", version=f"train-envs {package_version()}")
    p.add_argument(
        "--debug", action="store_true", help="show the traceback of an error (default: one line)"
    )
    sub = p.add_subparsers(dest="command", required=True)
    pl = sub.add_parser("list", help="list scenarios, controllers, trains and tracks")
    pl.add_argument(
        "what",
        nargs="?",
        default="all",
        choices=["all", "scenarios", "controllers", "trains", "tracks", "envs"],
    )
    pl.set_defaults(func=cmd_list)
    add_registered_commands(sub)  # tune; train, evaluate
    pr = sub.add_parser("reproduce", help="print our results beside a paper's tables")
    from train_envs.reproduce import list_reproductions

    pr.add_argument("paper", choices=list_reproductions())
    pr.add_argument("--seed", type=int, default=0)
    pr.add_argument("--csv", default=None, help="also write the table to this CSV file")
    pr.add_argument(
        "--out",
        default=None,
        help="folder for the table (<paper>.csv) and the figures (<paper>_*.png)",
    )
    pr.set_defaults(func=cmd_reproduce)
    ps = sub.add_parser("simulate", help="run one closed-loop episode, print metrics, write a plot")
    ps.add_argument("--scenario", default="paper001_stopping")
    ps.add_argument("--controller", default="pid")
    ps.add_argument(
        "--param",
        action="append",
        metavar="KEY=VALUE",
        help="controller tuning parameter (repeatable)",
    )
    ps.add_argument("--seed", type=int, default=0)
    ps.add_argument("--out", default="out", help="output folder for the CSV and PNG")
    ps.set_defaults(func=cmd_simulate)
    return p


def error_line(exc: BaseException) -> str:
    """One line for an error: its message (a ``ValueError``'s as is, others typed)."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    if isinstance(exc, KeyError) and exc.args and isinstance(exc.args[0], str):
        text = exc.args[0]
    elif not isinstance(exc, ValueError):
        text = f"{type(exc).__name__}: {text}"
    return f"error: {text}"


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except KeyboardInterrupt as exc:
        if args.debug:
            raise
        print(str(exc) or "interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # noqa: BLE001 - every error: one line, exit code 2
        if args.debug:
            raise
        print(error_line(exc), file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
