"""Generalisation study: PPO trained on the Yizhuang line, evaluated elsewhere.

Two PPO policies set the linear MPC's weights (``q_s``, ``q_v``, ``r_du``) online:

* ``ppo-nominal`` — trained on ``TrainEnvs/Yizhuang-v0`` as registered;
* ``ppo-dr`` — trained with domain randomisation: the env config's ``disturbance``
  draws the train mass factor from ``--mass-range`` and the Davis-resistance factor
  from ``--davis-range`` at every reset (:class:`train_envs.scenarios.DisturbanceSpec`).

Both are compared with the MPC's default parameters (``mpc-defaults``) on held-out
seeds of: the training line (nominal and perturbed), the Zürich line, and the paper
scenarios run with the same controller (``config={"controller": "mpc"}``, so that the
observation and action spaces match the policy's). The table gives mean ± std per
(env, driver); the p-values are paired Wilcoxon signed-rank tests against the defaults
on the same seeds (NaN where not meaningful, e.g. deterministic scenarios).

Usage (the full study; a quick check: ``--timesteps 1024 --seeds 0-1 --eval-freq 0``)::

    .venv/bin/python benchmarks/generalisation_study.py --timesteps 200000 \\
        --seeds 0-9 --n-envs 2 --vec subproc --out out/generalisation
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import pandas as pd

from agents.cli import parse_seeds
from agents.evaluation import (
    ControllerDriver,
    EnvCase,
    PolicyDriver,
    compare,
    format_summary,
    overlay_figure,
    significance,
    summary,
)
from agents.training import TrainConfig, train

TRAIN_ENV = "TrainEnvs/Yizhuang-v0"
METRICS = (
    "return",
    "E_p_m",
    "time_error_s",
    "E_v_mps",
    "comfort_mean_abs_jerk_mps3",
    "energy_kWh",
    "max_overspeed_mps",
)


def eval_cases(disturbance: dict) -> list[EnvCase]:
    """Where the policies are evaluated (all with the linear MPC as inner controller)."""
    mpc = {"controller": "mpc", "controller_params": {}}
    return [
        EnvCase(TRAIN_ENV, {}, "Yizhuang (train line)"),
        EnvCase(TRAIN_ENV, {"disturbance": disturbance}, "Yizhuang perturbed"),
        EnvCase("TrainEnvs/Zurich-v0", {}, "Zurich"),
        EnvCase("TrainEnvs/Urban004-v0", mpc, "paper004 urban (mpc)"),
        EnvCase("TrainEnvs/Stopping001PID-v0", mpc, "paper001 stopping (mpc)"),
        EnvCase("TrainEnvs/Section000-v0", mpc, "paper000 section (mpc)"),
    ]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--timesteps", type=int, default=200_000, help="PPO env steps per policy")
    p.add_argument("--seeds", nargs="+", default=["100-109"], help="held-out evaluation seeds")
    p.add_argument("--train-seed", type=int, default=0)
    p.add_argument("--n-envs", type=int, default=None, help="training envs (default: YAML)")
    p.add_argument("--vec", default="dummy", choices=["dummy", "subproc"])
    p.add_argument(
        "--eval-freq", type=int, default=None, help="EvalCallback period (0: off; default T/5)"
    )
    p.add_argument("--use-best", action="store_true", help="evaluate EvalCallback's best model")
    p.add_argument("--mass-range", nargs=2, type=float, default=[0.8, 1.2])
    p.add_argument("--davis-range", nargs=2, type=float, default=[0.7, 1.3])
    p.add_argument("--out", default="out/generalisation")
    p.add_argument("--skip-training", action="store_true", help="reuse the runs in --out")
    args = p.parse_args(argv)
    seeds = parse_seeds(args.seeds) or [100]
    out = Path(args.out)
    disturbance = {
        "mass_factor_range": list(args.mass_range),
        "davis_factor_range": list(args.davis_range),
    }
    t0 = time.perf_counter()
    runs = {
        "ppo-nominal": ({}, out / "ppo-nominal"),
        "ppo-dr": (
            {"disturbance": disturbance},
            out / "ppo-dr",
        ),
    }
    for name, (config, folder) in runs.items():
        if args.skip_training:
            continue
        res = train(
            TrainConfig(
                env_id=TRAIN_ENV,
                algo="ppo",
                timesteps=args.timesteps,
                seed=args.train_seed,
                out=folder,
                n_envs=args.n_envs,
                vec=args.vec,
                env_config=config,
                eval_freq=args.eval_freq,
                eval_episodes=3,
                progress_bar=False,
            )
        )
        print(
            f"trained {name}: {res.timesteps} steps, {res.learn_time_s:.0f} s "
            f"({res.steps_per_s:.1f} steps/s)",
            flush=True,
        )
    t_train = time.perf_counter() - t0
    drivers = [
        PolicyDriver(folder / "best" if args.use_best else folder, name=name)
        for name, (_c, folder) in runs.items()
    ] + [ControllerDriver("defaults", name="mpc-defaults")]
    cases = eval_cases(disturbance)
    df = compare(cases, drivers, seeds)
    out.mkdir(parents=True, exist_ok=True)
    df.to_csv(out / "episodes.csv", index=False)
    shown = [m for m in METRICS if m in df.columns]
    table = summary(df, shown)
    flat = table.copy()
    flat.columns = [f"{m}_{s}" for m, s in flat.columns]
    flat.reset_index().to_csv(out / "summary.csv", index=False)
    sig = significance(df, "mpc-defaults", shown)
    sig.to_csv(out / "significance.csv", index=False)
    fig = overlay_figure(cases[2], drivers, seeds[0])
    fig.savefig(out / "speed_distance_zurich.png", dpi=110)
    with pd.option_context("display.width", 250, "display.max_columns", 50):
        print(
            f"\nGeneralisation study: PPO {args.timesteps} steps on {TRAIN_ENV}, eval seeds "
            f"{seeds} (mean ± std); training {t_train:.0f} s, total "
            f"{time.perf_counter() - t0:.0f} s"
        )
        print(format_summary(table, digits=3).to_string())
        piv = sig.pivot_table(
            index=["env", "driver"], columns="metric", values="p_value", sort=False, dropna=False
        )
        print("\npaired Wilcoxon p-values vs mpc-defaults (NaN: not meaningful)")
        print(piv[[m for m in shown if m in piv.columns]].to_string(float_format="{:.3g}".format))
    print(
        f"\nwrote {out / 'episodes.csv'}, summary.csv, significance.csv, speed_distance_zurich.png"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
