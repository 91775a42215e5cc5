"""``train-envs train`` and ``train-envs evaluate``: the agents' command line.

Usage::

    train-envs train --env TrainEnvs/Stopping001PID-v0 --algo ppo --timesteps 100000 \\
        --seed 0 --out runs/stop-ppo [--n-envs 2] [--vec dummy|subproc|native]
    train-envs evaluate --env TrainEnvs/Stopping001PID-v0 --policy runs/stop-ppo \\
        --params sqlite:///tuning.db:stop-mowoa --controller pid --episodes 5 --out out/eval

``add_agents_parsers(subparsers)`` adds both subcommands and sets ``func`` (an
``args -> int`` exit code) on the parsed namespace; ``train-envs`` finds it through the
``agents`` entry point of the group ``train_envs.cli``. Heavy imports happen only when a
command runs.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from train_envs.cli_args import json_object, key_values, parse_seeds

__all__ = ["add_agents_parsers", "cmd_evaluate", "cmd_train", "parse_seeds"]


def _json_arg(text: str | None, flag: str) -> dict[str, Any]:
    return json_object(text, flag) or {}


#: hyperparameters of SB3's PPO, SAC and TD3 that must be integers / numbers
INT_HYPERPARAMS = (
    "n_steps", "batch_size", "n_epochs", "buffer_size", "learning_starts", "gradient_steps",
    "n_envs", "n_timesteps", "policy_delay",
)  # fmt: skip
FLOAT_HYPERPARAMS = ("gamma", "gae_lambda", "vf_coef", "max_grad_norm", "tau")


def _overrides(items: list[str] | None) -> dict[str, Any]:
    """``key=value`` pairs; values are parsed as YAML scalars/flow collections; the
    integer and number hyperparameters are checked here (``ValueError`` naming them)."""
    import yaml

    out = key_values(items, "--hyperparams", yaml.safe_load)
    for key, val in out.items():
        if key in INT_HYPERPARAMS and (isinstance(val, bool) or not isinstance(val, int)):
            raise ValueError(f"--hyperparams {key}: {val!r} is not an integer")
        if key in FLOAT_HYPERPARAMS and (isinstance(val, bool) or not isinstance(val, int | float)):
            raise ValueError(f"--hyperparams {key}: {val!r} is not a number")
    return out


# ------------------------------------------------------------------------ train
def add_train_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    from agents.hyperparameters import ALGOS

    p = subparsers.add_parser(
        "train",
        help="train an RL policy (PPO, SAC, TD3) that sets the inner controller's parameters",
        description="Train a stable-baselines3 policy on an env id with the hyperparameters "
        "of agents/hyperparams/<algo>.yml (rl-zoo3 format), evaluation on held-out seeds, "
        "checkpoints and TensorBoard logs.",
    )
    p.add_argument("--env", required=True, help="registered env id, e.g. TrainEnvs/Urban004-v0")
    p.add_argument("--algo", default="ppo", choices=list(ALGOS), help="algorithm (default ppo)")
    p.add_argument(
        "--timesteps", type=int, default=None, help="env steps (default: the YAML n_timesteps)"
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default=None, help="run folder (default runs/<env>-<algo>-s<seed>)")
    p.add_argument("--n-envs", type=int, default=None, help="parallel envs (default: YAML)")
    p.add_argument(
        "--vec",
        default="dummy",
        choices=["dummy", "subproc", "native"],
        help="vectorisation: dummy (in-process), subproc (a process per env), native (the "
        "id's vector env, members in lockstep in one process)",
    )
    p.add_argument("--config", default=None, help="env config as JSON or @file.json")
    p.add_argument(
        "--hyperparams",
        nargs="+",
        metavar="KEY=VALUE",
        default=None,
        help="override YAML hyperparameters, e.g. n_steps=256 learning_rate=lin_3e-4",
    )
    p.add_argument("--hyperparams-file", default=None, help="YAML file instead of the packaged")
    p.add_argument("--eval-freq", type=int, default=None, help="env steps between evaluations")
    p.add_argument("--eval-episodes", type=int, default=5, help="held-out episodes per eval")
    p.add_argument("--eval-seed", type=int, default=10_000, help="first held-out seed")
    p.add_argument("--checkpoint-freq", type=int, default=None, help="env steps between saves")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--no-tensorboard", action="store_true", help="no TensorBoard logs")
    p.add_argument("--torch-threads", type=int, default=1)
    p.add_argument("--verbose", type=int, default=0, choices=[0, 1, 2])
    p.set_defaults(func=cmd_train)
    return p


def cmd_train(args: argparse.Namespace) -> int:
    from agents.training import TrainConfig, train

    cfg = TrainConfig(
        env_id=args.env,
        algo=args.algo,
        timesteps=args.timesteps,
        seed=args.seed,
        out=args.out,
        n_envs=args.n_envs,
        vec=args.vec,
        env_config=_json_arg(args.config, "--config"),
        hyperparams=_overrides(args.hyperparams),
        hyperparams_file=args.hyperparams_file,
        eval_freq=args.eval_freq,
        eval_episodes=args.eval_episodes,
        eval_seed=args.eval_seed,
        checkpoint_freq=args.checkpoint_freq,
        progress_bar=not args.no_progress,
        tensorboard=not args.no_tensorboard,
        torch_threads=args.torch_threads,
        verbose=args.verbose,
    )
    res = train(cfg)
    best = "n/a" if res.best_mean_reward is None else f"{res.best_mean_reward:.4g}"
    print(
        f"trained {cfg.algo} on {cfg.env_id}: {res.timesteps} steps with {res.n_envs} env(s) "
        f"in {res.wall_time_s:.1f} s ({res.steps_per_s:.1f} env steps/s), hyperparameters "
        f"'{res.hyperparams.source}', best held-out mean return {best}"
    )
    print(
        f"wrote {res.model_path}"
        + (f" and {res.vecnormalize_path}" if res.vecnormalize_path else "")
    )
    if res.best_model_path is not None:
        print(f"best model: {res.best_model_path}")
    return 0


# --------------------------------------------------------------------- evaluate
def add_evaluate_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "evaluate",
        help="compare policies, parameter sets and controllers on env ids (metrics, CSV, plots)",
        description="Run every driver (--policy, --params, --controller; each repeatable) on "
        "every --env and seed; print mean ± std per metric, paired Wilcoxon p-values against "
        "the baseline, and write CSVs and speed–distance overlays to --out.",
    )
    p.add_argument("--env", nargs="+", required=True, help="registered env id(s)")
    p.add_argument(
        "--policy", action="append", default=[], help="SB3 run folder or model .zip (repeatable)"
    )
    p.add_argument(
        "--params",
        action="append",
        default=[],
        help="parameter values: .json/.yml file or 'sqlite:///file.db:study' (repeatable)",
    )
    p.add_argument(
        "--controller",
        action="append",
        default=[],
        help="controller with default parameters: 'defaults' (the env's own) or a name",
    )
    p.add_argument("--episodes", type=int, default=None, help="episodes = seeds 0..K-1")
    p.add_argument("--seeds", nargs="+", default=None, help="seeds: 0 1 2, 0,1,2 or 0-4")
    p.add_argument("--config", default=None, help="env config as JSON or @file.json")
    p.add_argument(
        "--baseline", default=None, help="driver name for the Wilcoxon tests (default: first)"
    )
    p.add_argument("--metrics", nargs="+", default=None, help="metrics printed (default: main)")
    p.add_argument("--out", default=None, help="folder for episodes.csv, summary.csv, plots")
    p.set_defaults(func=cmd_evaluate)
    return p


#: metrics printed by default (those present)
MAIN_METRICS = (
    "return",
    "stop_error_m",
    "time_error_s",
    "E_v_mps",
    "ITAE_m_s",
    "comfort_mean_abs_jerk_mps3",
    "energy_kWh",
    "max_overspeed_mps",
    "command_switches",
)


def _drivers(args: argparse.Namespace) -> list[Any]:
    from agents.evaluation import ControllerDriver, ParamsDriver, PolicyDriver, load_params

    drivers: list[Any] = [PolicyDriver(p) for p in args.policy]
    for spec in args.params:
        name, values = load_params(spec)
        drivers.append(ParamsDriver("params:" + name, values))
    drivers += [ControllerDriver(c) for c in args.controller]
    if not drivers:
        raise ValueError("evaluate needs at least one --policy, --params or --controller")
    return drivers


def cmd_evaluate(args: argparse.Namespace) -> int:
    import pandas as pd

    from agents.evaluation import (
        EnvCase,
        compare,
        format_summary,
        overlay_figure,
        significance,
        summary,
    )

    seeds = parse_seeds(args.seeds)
    if seeds is None:
        n = 5 if args.episodes is None else args.episodes
        if n < 1:
            raise ValueError(f"--episodes must be >= 1, got {n}")
        seeds = list(range(n))
    elif args.episodes is not None and args.episodes != len(seeds):
        raise ValueError(f"--episodes {args.episodes} disagrees with {len(seeds)} --seeds")
    config = _json_arg(args.config, "--config")
    cases = [EnvCase(e, config) for e in args.env]
    drivers = _drivers(args)
    names = [d.name for d in drivers]
    baseline = args.baseline or names[0]
    if baseline not in names:
        raise ValueError(f"--baseline {baseline!r} is not a driver; drivers: {names}")
    df = compare(cases, drivers, seeds)
    table = summary(df)
    text = format_summary(table)
    shown = args.metrics or [m for m in MAIN_METRICS if m in text.columns]
    bad = [m for m in shown if m not in text.columns]
    if bad:
        raise ValueError(f"--metrics {bad} not in the results; available: {list(text.columns)}")
    sig = significance(df, baseline, shown) if len(drivers) > 1 else None
    with pd.option_context("display.width", 200, "display.max_columns", 50):
        for case in cases:
            print(f"\n{case.label} — seeds {seeds} (mean ± std over seeds)")
            print(text.loc[case.label, shown].T.to_string())
            if sig is not None and len(sig):
                s = sig[sig["env"] == case.label]
                piv = s.pivot(index="metric", columns="driver", values="p_value")
                piv = piv.loc[[m for m in shown if m in piv.index]]
                piv = piv[[n for n in names if n in piv.columns]]
                print(f"paired Wilcoxon p-values vs {baseline} (NaN: not meaningful)")
                print(piv.to_string(float_format=lambda v: f"{v:.3g}"))
    if args.out:
        import matplotlib.pyplot as plt

        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        files = [out / "episodes.csv", out / "summary.csv"]
        df.to_csv(files[0], index=False)
        flat = table.copy()
        flat.columns = [f"{m}_{s}" for m, s in flat.columns]
        flat.reset_index().to_csv(files[1], index=False)
        if sig is not None:
            files.append(out / "significance.csv")
            significance(df, baseline).to_csv(files[-1], index=False)
        for case in cases:
            stem = case.label.replace("/", "_")
            png = out / f"speed_distance_{stem}_seed{seeds[0]}.png"
            fig = overlay_figure(case, drivers, seeds[0])
            fig.savefig(png, dpi=110)
            plt.close(fig)
            files.append(png)
        for f in files:
            print(f"wrote {f}")
    return 0


def add_agents_parsers(subparsers: argparse._SubParsersAction) -> None:
    """Add ``train`` and ``evaluate`` to a ``train-envs`` subparsers object."""
    add_train_parser(subparsers)
    add_evaluate_parser(subparsers)


def main(argv: list[str] | None = None) -> int:
    """``python -m agents.cli ...`` is the ``train-envs`` command (:func:`train_envs.cli.main`)."""
    from train_envs.cli import main as cli_main

    return cli_main(argv)


if __name__ == "__main__":
    raise SystemExit(main())
