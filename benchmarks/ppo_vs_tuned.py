"""PPO scheduler vs default vs MOWOA-tuned parameters on held-out seeds (001 and 004 envs).

For each env id (default ``TrainEnvs/Stopping001-v0``, paper 001 stopping with the RSMPC
inner controller, and ``TrainEnvs/Urban004-v0``, paper 004 with DMC):

1. trains PPO with :func:`agents.training.train` (the YAML hyperparameters of
   ``agents/hyperparams/ppo.yml``, seed 0) for ``--timesteps`` env steps and records the
   wall time; the model kept is ``best/`` (best mean return of the ``EvalCallback`` on
   the validation seeds 10000-10004, disjoint from the held-out seeds) or the final one;
2. gets MOWOA-tuned parameters: Urban004-v0 reuses the study ``paper004-mowoa-16x8-s0``
   of ``train-envs reproduce paper004`` (``sqlite:///out/reproduce/paper004.db``) if it
   exists, else tunes with the same settings into ``<out>/tuning.db``; Stopping001-v0 is
   tuned here (``--tune-pop`` × ``--tune-iters``, training seeds 0 and 1, resumed from
   ``<out>/tuning.db``) on the objectives that :class:`tuners.problem.EnvTuningProblem`
   keeps for a stopping scenario without a timetable (ITAE, |stop error|, comfort,
   energy) with the constraints overspeed ≤ 0 and |stop error| ≤ 2 m;
3. evaluates the three drivers (PPO policy, defaults, MOWOA) on the same held-out seeds
   and the same env config (004's disturbances: mass ×[0.9, 1.15], bounded random
   resistance ±0.03 m/s², so that the seeds differ) with :func:`agents.evaluation.compare`,
   prints the summary (mean ± std) and Wilcoxon tests against the defaults, and writes
   ``<env>_episodes.csv``, ``<env>_summary.csv``, ``<env>_significance.csv``,
   ``<env>_overlay.png`` and ``results.md`` (Markdown tables for the README) into ``--out``.

Usage::

    .venv/bin/python benchmarks/ppo_vs_tuned.py --timesteps 20000 --holdout 100-109
    .venv/bin/python benchmarks/ppo_vs_tuned.py --envs TrainEnvs/Urban004-v0 \\
        --timesteps 300 --holdout 100 101 --out out/ppo_vs_tuned/smoke     # smoke run
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

ENVS = ("TrainEnvs/Stopping001-v0", "TrainEnvs/Urban004-v0")
#: 004's disturbed runs (as train_envs.reproduce.paper004.CONFIG): the same for all drivers
CONFIG = {"disturbance": {"mass_factor_range": [0.9, 1.15], "random_bound_mps2": 0.03}}
PAPER004_DB = "sqlite:///out/reproduce/paper004.db"
#: the study `train-envs reproduce paper004` writes (one per code version, see tuners.run)
PAPER004_STUDY = "paper004-mowoa-16x8-s0-{code}"
#: metric column → (label, higher is better)
METRICS = {
    "E_p_m": ("stop error E_p [m]", False),
    "ITAE_m_s": ("ITAE [m·s]", False),
    "time_error_s": ("time error [s]", False),
    "comfort_mean_abs_jerk_mps3": ("comfort: mean abs jerk [m/s³]", False),
    "energy_kWh": ("energy [kWh]", False),
    "command_switches": ("command switches", False),
    "max_overspeed_mps": ("max overspeed [m/s]", False),
    "return": ("return", True),
}
DRIVERS = ("defaults", "mowoa", "ppo")


def parse_seeds(items: list[str]) -> list[int]:
    """``["100-109"]`` or ``["100", "101"]`` (or comma lists) → seed list."""
    seeds: list[int] = []
    for item in items:
        for part in str(item).split(","):
            part = part.strip()
            if not part:
                continue
            if "-" in part[1:]:
                a, b = part.split("-", 1)
                seeds.extend(range(int(a), int(b) + 1))
            else:
                seeds.append(int(part))
    if not seeds:
        raise SystemExit("--holdout: no seeds")
    return seeds


def short(env_id: str) -> str:
    return env_id.split("/")[-1]


# -------------------------------------------------------------------------- training
def train_ppo(env_id: str, timesteps: int, out: Path, vec: str, reuse: bool) -> dict[str, Any]:
    """Train PPO (or reuse a finished run); the run record with its wall time."""
    from agents.training import TrainConfig, train

    run = out / "runs" / f"{short(env_id)}-ppo-s0"
    record_file = run / "train_record.json"
    if reuse and record_file.is_file() and (run / "model.zip").is_file():
        rec = json.loads(record_file.read_text())
        if rec.get("timesteps_requested") == timesteps:
            print(f"[{short(env_id)}] reusing the PPO run in {run}")
            return rec
    print(f"[{short(env_id)}] training PPO for {timesteps} env steps ({vec}) ...", flush=True)
    res = train(
        TrainConfig(
            env_id=env_id,
            algo="ppo",
            timesteps=timesteps,
            seed=0,
            out=run,
            vec=vec,
            env_config=CONFIG,
            checkpoint_freq=0,
            eval_freq=max(timesteps // 5, 1024),  # not more often than once per rollout
            tensorboard=False,
        )
    )
    rec = {
        "env_id": env_id,
        "run": str(run),
        "timesteps_requested": timesteps,
        "timesteps": res.timesteps,
        "n_envs": res.n_envs,
        "vec": vec,
        "wall_time_s": res.wall_time_s,
        "learn_time_s": res.learn_time_s,
        "steps_per_s": res.steps_per_s,
        "best_mean_reward": res.best_mean_reward,
        "model": str(res.best_model_path or res.model_path),
    }
    record_file.write_text(json.dumps(rec, indent=2) + "\n")
    print(
        f"[{short(env_id)}] PPO: {res.timesteps} steps in {res.wall_time_s:.0f} s wall "
        f"({res.steps_per_s:.1f} steps/s), best eval return {res.best_mean_reward}",
        flush=True,
    )
    return rec


# -------------------------------------------------------------------------- tuning
def _study_exists(storage: str, study: str) -> bool:
    import optuna

    path = storage.removeprefix("sqlite:///")
    if storage.startswith("sqlite:///") and not Path(path).is_file():
        return False
    try:
        names = {s.study_name for s in optuna.get_all_study_summaries(storage)}
    except Exception:  # noqa: BLE001  (an unreadable storage = no study)
        return False
    return study in names


def mowoa_params(
    env_id: str, out: Path, pop: int, iters: int, workers: int | None
) -> tuple[dict[str, float], str]:
    """(MOWOA-selected parameters, where they come from)."""
    import optuna

    from tuners.run import tune

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    storage = f"sqlite:///{out / 'tuning.db'}"
    if env_id == "TrainEnvs/Urban004-v0":
        from agents.evaluation import load_params
        from train_envs.reproduce import paper004
        from tuners.storage import code_fingerprint

        reproduced = PAPER004_STUDY.replace("{code}", code_fingerprint()[:8])
        if _study_exists(PAPER004_DB, reproduced):
            # load_result(...).selected_params needs the problem; load_params rebuilds it
            _, params = load_params(f"{PAPER004_DB}:{reproduced}")
            return params, f"study {reproduced} in {PAPER004_DB} (16 × 8, seeds 0, 1)"
        study = "urban004-mowoa-16x8-s0-{code}"
        t0 = time.perf_counter()
        res = tune(
            env_id,
            "mowoa",
            16,
            8,
            storage=storage,
            study=study,
            resume=True,
            seeds=(0, 1),
            config=paper004.CONFIG,
            constraints=paper004.CONSTRAINTS,
            f_bounds=paper004.F_BOUNDS,
            seed=0,
            workers=workers,
        )
        wall = time.perf_counter() - t0
        src = f"study {res.study_name} in {storage} (16 × 8, seeds 0, 1, {wall:.0f} s)"
    else:
        study = f"{short(env_id).lower()}-mowoa-{pop}x{iters}-s0-{{code}}"
        t0 = time.perf_counter()
        res = tune(
            env_id,
            "mowoa",
            pop,
            iters,
            storage=storage,
            study=study,
            resume=True,
            seeds=(0, 1),
            config=CONFIG,
            constraints={"max_overspeed_mps": 0.0, "E_p_m": 2.0},
            seed=0,
            workers=workers,
        )
        src = (
            f"study {res.study_name} in {storage} ({pop} × {iters}, seeds 0, 1, objectives "
            f"{', '.join(res.objectives)}, {time.perf_counter() - t0:.0f} s)"
        )
    if res.selected_params is None:
        raise SystemExit(f"{env_id}: MOWOA found no feasible solution ({src})")
    return dict(res.selected_params), src


# -------------------------------------------------------------------------- evaluation
def markdown_table(df: pd.DataFrame, sig: pd.DataFrame, metrics: list[str]) -> str:
    """metric | defaults | MOWOA | PPO | p (MOWOA vs defaults) | p (PPO vs defaults)."""
    head = "| metric | defaults | MOWOA | PPO | p MOWOA vs def. | p PPO vs def. | best |"
    lines = [head, "|" + "---|" * 7]
    for col in metrics:
        label, higher = METRICS[col]
        means = {d: df.loc[df["driver"] == d, col].astype(float) for d in DRIVERS}
        cells = []
        for d in DRIVERS:
            x = means[d]
            cells.append(f"{x.mean():.4g} ± {x.std():.2g}" if x.notna().any() else "n/a")
        ps = []
        for d in ("mowoa", "ppo"):
            row = sig[(sig["driver"] == d) & (sig["metric"] == col)]
            p = float(row["p_value"].iloc[0]) if len(row) else np.nan
            ps.append(f"{p:.3g}" if np.isfinite(p) else "–")
        m = {d: means[d].mean() for d in DRIVERS}
        vals = [v for v in m.values() if np.isfinite(v)]
        best_v = (max if higher else min)(vals) if vals else np.nan
        tied = [d for d in DRIVERS if np.isfinite(m[d]) and np.isclose(m[d], best_v, rtol=1e-3)]
        best = "tie" if len(tied) == len(DRIVERS) else " / ".join(tied)
        lines.append(f"| {label} | " + " | ".join(cells + ps) + f" | {best} |")
    return "\n".join(lines)


def evaluate_env(
    env_id: str, policy: str, params: dict[str, float], seeds: list[int], out: Path
) -> tuple[pd.DataFrame, pd.DataFrame, list[str]]:
    from agents.evaluation import (
        ControllerDriver,
        EnvCase,
        ParamsDriver,
        PolicyDriver,
        compare,
        format_summary,
        overlay_figure,
        significance,
        summary,
    )

    case = EnvCase(env_id, CONFIG, name=short(env_id))
    drivers = [
        ControllerDriver("defaults", name="defaults"),
        ParamsDriver("mowoa", params),
        PolicyDriver(policy, name="ppo"),
    ]
    t0 = time.perf_counter()
    df = compare([case], drivers, seeds)
    metrics = [c for c in METRICS if c in df.columns and df[c].notna().any()]
    summ = summary(df, metrics)
    sig = significance(df, "defaults", metrics)
    tag = short(env_id)
    df.to_csv(out / f"{tag}_episodes.csv", index=False)
    summ.to_csv(out / f"{tag}_summary.csv")
    sig.to_csv(out / f"{tag}_significance.csv", index=False)
    with pd.option_context("display.width", 200, "display.max_columns", 30):
        print(f"\n== {env_id}: held-out seeds {seeds} ({time.perf_counter() - t0:.0f} s)")
        print(format_summary(summ).T.to_string())
        print(sig[["driver", "metric", "median_diff", "p_value", "note"]].to_string(index=False))
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = overlay_figure(case, drivers, seeds[0])
    fig.savefig(out / f"{tag}_overlay.png", dpi=120, bbox_inches="tight")
    plt.close(fig)
    return df, sig, metrics


# -------------------------------------------------------------------------- main
def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--envs", nargs="+", default=list(ENVS), help="env ids")
    ap.add_argument(
        "--timesteps",
        nargs="+",
        type=int,
        default=[20_000],
        help="PPO env steps per env (one value for all, or one per env)",
    )
    ap.add_argument("--holdout", nargs="+", default=["100-109"], help="held-out seeds")
    ap.add_argument("--out", type=Path, default=Path("out/ppo_vs_tuned"))
    ap.add_argument("--vec", choices=("dummy", "subproc"), default="subproc")
    ap.add_argument("--tune-pop", type=int, default=12)
    ap.add_argument("--tune-iters", type=int, default=5)
    ap.add_argument("--tune-workers", type=int, default=2)
    ap.add_argument("--reuse", action="store_true", help="reuse finished PPO runs in --out")
    args = ap.parse_args(argv)

    import train_envs  # noqa: F401  (registers the ids)

    seeds = parse_seeds(args.holdout)
    steps = args.timesteps
    if len(steps) == 1:
        steps = steps * len(args.envs)
    if len(steps) != len(args.envs):
        raise SystemExit("--timesteps: one value, or one per env")
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    t_all = time.perf_counter()
    hw = f"{os.cpu_count()} CPU cores ({platform.processor() or platform.machine()}), no GPU"
    md = [
        "# PPO scheduler vs default vs MOWOA-tuned parameters",
        "",
        f"Held-out seeds {seeds[0]}–{seeds[-1]} ({len(seeds)} episodes per driver), env "
        f"config `{json.dumps(CONFIG)}` for every driver; Wilcoxon signed-rank p-values vs "
        f"the defaults (paired by seed). Hardware: {hw}, shared with another job.",
        "",
    ]
    records = {}
    for env_id, n in zip(args.envs, steps, strict=True):
        t_env = time.perf_counter()
        rec = train_ppo(env_id, n, out, args.vec, args.reuse)
        params, src = mowoa_params(env_id, out, args.tune_pop, args.tune_iters, args.tune_workers)
        print(f"[{short(env_id)}] MOWOA parameters from {src}: {params}", flush=True)
        df, sig, metrics = evaluate_env(env_id, rec["model"], params, seeds, out)
        records[env_id] = {**rec, "mowoa_source": src, "mowoa_params": params}
        md += [
            f"## {env_id}",
            "",
            f"PPO (`agents/hyperparams/ppo.yml`, seed 0, {rec['n_envs']} {rec['vec']} envs): "
            f"{rec['timesteps']} env steps, {rec['wall_time_s'] / 60:.1f} min wall "
            f"({rec['steps_per_s']:.0f} steps/s), model `{rec['model']}`. "
            f"MOWOA: {src}; parameters "
            + ", ".join(f"{k}={v:.4g}" for k, v in params.items())
            + ".",
            "",
            markdown_table(df, sig, metrics),
            "",
            f"![{short(env_id)} overlay]({short(env_id)}_overlay.png)",
            "",
        ]
        print(f"[{short(env_id)}] done in {time.perf_counter() - t_env:.0f} s", flush=True)
    (out / "results.md").write_text("\n".join(md))
    (out / "runs.json").write_text(json.dumps(records, indent=2, default=str) + "\n")
    print("\n" + "\n".join(md))
    print(f"total {time.perf_counter() - t_all:.0f} s; wrote {out / 'results.md'}")


if __name__ == "__main__":
    main()
