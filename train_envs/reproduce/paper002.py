"""Paper 002 (Xu et al. 2019): adaptive MPC against the non-adaptive MPC, same seeds.

``train-envs reproduce paper002`` runs ``adaptive_mpc`` and ``mpc002`` (the same MPC on
the nominal model, estimate frozen) on ``paper002_cruise`` — 4-car CRH-3, Table 2 speed
command, per-car forces within ±30 kN, Davis coefficients varying in time within 002's
bounds (|Δc0| ≤ 0.01 N/kg, |Δc1| ≤ 3.5e-4 N s/(m kg), |Δc2| ≤ 8e-6 N s²/(m² kg),
sinusoids of period 300 s with random phases drawn from the seed) — on the same
disturbance seeds, and prints one row per controller and seed plus the seed means, next
to the paper's claims: max speed error ≤ 2 m/s (adaptive) vs ≈ 8 m/s (non-adaptive),
coupler force ≤ 2 kN (adaptive).

Metrics (all cars, sampled at the 0.5 s control instants):

* ``max_ev_mps``: max over the run and the cars of |v_i − v_r|; ``rms_ev_mps`` its RMS;
* ``max_ev_feasible_mps``: the same outside the traction-limited window
  :data:`SATURATED_WINDOW_S` — the 40 → 70 m/s ramp needs 0.6 m/s² × 190 t = 114 kN plus
  10–25 kN of running resistance, more than the 4 × 30 kN available, so both controllers
  saturate and the lag there is set by physics, not by the model;
* ``max_ev_cruise_mps``: the same in the settled cruise phases :data:`CRUISE_WINDOWS_S`
  (Table 2's cruise phases without their first 60 s), where the steady resistance
  mismatch is what is left;
* ``max_coupler_force_kN`` / ``..._feasible_kN`` / ``..._cruise_kN`` (same three scopes),
  ``max_coupler_def_m``;
* ``max_est_error``: max one-step prediction error ‖x̃‖ (mm and m/s) after the first
  :data:`WARMUP_S` seconds; ``max_dR_error_kN``: max error of the estimated per-car
  running-resistance deviation (the learned bias, the physical content of Θ̂) against
  the plant's true deviation after the warm-up — the analogue of 002's tr(Θ̃ᵀΘ̃)
  (Fig. 7), which cannot be formed for a plant that is not the linear model;
* ``median_step_ms`` (wall time of one control step, controller + plant),
  ``median_ctrl_ms`` (the controller alone) and ``median_solve_ms`` (OSQP's own solve
  time).

:func:`run_paper002` returns the per-step trace used by :func:`paper002_figure`
(002 Fig. 7 and 9: estimation error over time and the speed errors of both controllers).
Write-up and the measured table: ``docs/papers/paper002.md``.
"""

from __future__ import annotations

import math
import os
import sys
import time
from collections.abc import Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor

import numpy as np
import pandas as pd

from train_envs.controllers import make_controller
from train_envs.scenarios import Scenario, get_scenario
from train_envs.simulation import ClosedLoop

#: the paper's claims (§4.3.1, Fig. 9, 10)
PAPER002 = {
    "adaptive_mpc": {"max_ev_mps": 2.0, "max_coupler_force_kN": 2.0},
    "mpc002": {"max_ev_mps": 8.0, "max_coupler_force_kN": math.nan},
}
#: traction-limited part of Table 2 (40 → 70 m/s ramp plus 30 s of recovery)
SATURATED_WINDOW_S = (400.0, 480.0)
#: cruise phases of Table 2, each without its first 60 s (settled cruise)
CRUISE_WINDOWS_S = ((160.0, 400.0), (510.0, 850.0), (960.0, 1200.0))
#: estimator warm-up excluded from the estimation-error maxima
WARMUP_S = 20.0
CONTROLLERS = ("adaptive_mpc", "mpc002")
DEFAULT_SEEDS = (0, 1, 2, 3, 4)


def _true_deviation_kN(plant, t: float) -> np.ndarray:
    """The plant's running-resistance deviation per car at time ``t`` [kN]."""
    dv = plant.davis_variation
    n = plant.n
    if dv is None:
        return np.zeros(n)
    d0, d1, d2 = dv.deltas(t)
    v = np.abs(plant.speeds)
    dr = plant.m * (d0 + d1 * v)
    if plant.lead_aero:
        dr[0] += d2 * plant.m.sum() * v[0] ** 2
    else:
        dr += d2 * plant.m * v**2
    return dr / 1e3


def run_paper002(
    controller: str = "adaptive_mpc",
    seed: int = 0,
    *,
    scenario: Scenario | str = "paper002_cruise",
    t_max_s: float | None = None,
    params: Mapping[str, float] | None = None,
) -> pd.DataFrame:
    """One closed-loop run with the per-step trace of speeds, couplers and the estimator.

    Columns: ``t_s``, ``v_ref_mps``, ``ev_max_mps`` (max over cars of |v_i − v_r|),
    ``ev_lead_mps`` (v_1 − v_r, signed), ``coupler_force_kN`` / ``coupler_def_m``
    (largest magnitude, signed), ``u{i}_kN``, ``est_error`` (‖x̃‖), ``est_error_v``,
    ``dR_hat_total_kN``, ``dR_true_total_kN``, ``dR_error_kN`` (norm of the per-car
    difference), ``excitation_half_width_kN``, ``bound_clipped``, ``solve_time_s`` (OSQP),
    ``ctrl_wall_s`` (the controller's ``compute``), ``step_wall_s`` (controller + plant),
    ``fallback``.
    """
    sc = get_scenario(scenario) if isinstance(scenario, str) else scenario
    if t_max_s is not None:
        sc = sc.with_overrides(t_max_s=float(t_max_s))
    ctrl = make_controller(controller, sc, **dict(params or {}))
    loop = ClosedLoop(sc, ctrl)
    loop.reset(seed=seed)
    plant = loop.plant
    rows: list[dict[str, float]] = []
    while not loop.done:
        obs = loop.observe()
        v_ref = float(sc.reference.v_ref(obs.t_s, obs.s_m))
        ev = np.asarray(obs.speeds_mps) - v_ref
        cf = plant.coupler_forces()
        cd = plant.coupler_deformations()
        j = int(np.argmax(np.abs(cf)))
        dr_true = _true_deviation_kN(plant, obs.t_s)
        t0 = time.perf_counter()
        u, info = ctrl.compute(obs)
        t1 = time.perf_counter()
        loop.step(u)
        wall = time.perf_counter() - t0
        dr_hat = np.asarray(info.get("dR_hat_kN", np.zeros(plant.n)), float)
        row = {
            "t_s": obs.t_s,
            "v_ref_mps": v_ref,
            "ev_max_mps": float(np.max(np.abs(ev))),
            "ev_lead_mps": float(ev[0]),
            "coupler_force_kN": float(cf[j]) / 1e3,
            "coupler_def_m": float(cd[j]),
            "est_error": float(info.get("est_error", math.nan)),
            "est_error_v": float(info.get("est_error_v", math.nan)),
            "dR_hat_total_kN": float(dr_hat.sum()),
            "dR_true_total_kN": float(dr_true.sum()),
            "dR_error_kN": float(np.linalg.norm(dr_hat - dr_true)),
            "excitation_half_width_kN": float(info.get("excitation_half_width_kN", math.inf)),
            "bound_clipped": float(bool(info.get("bound_clipped", False))),
            "solve_time_s": float(info.get("solve_time_s", math.nan)),
            "ctrl_wall_s": t1 - t0,
            "step_wall_s": wall,
            "fallback": float(bool(info.get("fallback", False))),
        }
        for i, u in enumerate(loop.u_prev):
            row[f"u{i + 1}_kN"] = float(u) / 1e3
        rows.append(row)
    df = pd.DataFrame(rows)
    df.attrs.update(controller=controller, seed=seed, scenario=sc.name)
    return df


def summarise_run(df: pd.DataFrame) -> dict[str, float]:
    """The reproduction metrics of one run (see the module docstring)."""
    t = df["t_s"].to_numpy()
    lo, hi = SATURATED_WINDOW_S
    feas = (t < lo) | (t >= hi)
    cru = np.zeros(t.size, dtype=bool)
    for a, b in CRUISE_WINDOWS_S:
        cru |= (t >= a) & (t < b)
    ev = df["ev_max_mps"].to_numpy()
    cf = np.abs(df["coupler_force_kN"].to_numpy())
    warm = t >= WARMUP_S
    est = df["est_error"].to_numpy()[warm]
    dre = df["dR_error_kN"].to_numpy()[warm]
    return {
        "max_ev_mps": float(ev.max()),
        "max_ev_feasible_mps": float(ev[feas].max()) if feas.any() else math.nan,
        "max_ev_cruise_mps": float(ev[cru].max()) if cru.any() else math.nan,
        "rms_ev_mps": float(np.sqrt(np.mean(ev**2))),
        "max_coupler_force_kN": float(cf.max()),
        "max_coupler_force_feasible_kN": float(cf[feas].max()) if feas.any() else math.nan,
        "max_coupler_force_cruise_kN": float(cf[cru].max()) if cru.any() else math.nan,
        "max_coupler_def_m": float(np.abs(df["coupler_def_m"]).max()),
        "max_est_error": float(np.nanmax(est)) if np.isfinite(est).any() else math.nan,
        "max_dR_error_kN": float(np.nanmax(dre)) if dre.size else math.nan,
        "bound_clipped_steps": float(df["bound_clipped"].sum()),
        "fallback_steps": float(df["fallback"].sum()),
        "median_step_ms": float(np.median(df["step_wall_s"]) * 1e3),
        "median_ctrl_ms": float(np.median(df["ctrl_wall_s"]) * 1e3),
        "median_solve_ms": float(np.nanmedian(df["solve_time_s"]) * 1e3),
    }


def _job(
    args: tuple[str, int, float | None, str, bool],
) -> tuple[str, int, dict[str, float], pd.DataFrame | None]:
    ctrl, seed, t_max, scenario, keep = args
    df = run_paper002(ctrl, seed, scenario=scenario, t_max_s=t_max)
    return ctrl, seed, summarise_run(df), df if keep else None


def compare_paper002(
    seeds: Sequence[int] = DEFAULT_SEEDS,
    *,
    t_max_s: float | None = None,
    workers: int | None = None,
    scenario: str = "paper002_cruise",
    traces: dict[str, pd.DataFrame] | None = None,
    progress: bool = False,
) -> pd.DataFrame:
    """Adaptive vs non-adaptive on the same seeds: one row per (controller, seed) + means.

    ``workers``: processes (default: ``min(cpu_count, runs)``; 1 = in this process).
    ``scenario``: ``"paper002_cruise"`` (Table 2's command) or
    ``"paper002_cruise_feasible"`` (the 40 → 70 m/s ramp within the traction envelope).
    ``traces``, if given, receives the first seed's trace per controller
    (:func:`run_paper002`); ``progress``: one line per finished run on stderr.
    """
    first = int(seeds[0]) if len(seeds) else None
    keep = traces is not None
    jobs = [
        (c, int(s), t_max_s, scenario, keep and int(s) == first) for s in seeds for c in CONTROLLERS
    ]
    if workers is None:
        workers = min(os.cpu_count() or 1, len(jobs))
    t0 = time.perf_counter()
    results = []

    def collect(it) -> None:
        for k, out in enumerate(it, 1):
            results.append(out)
            if progress:
                print(
                    f"  paper002 ({scenario}): {out[0]} seed {out[1]} done, {k}/{len(jobs)} "
                    f"({time.perf_counter() - t0:.0f} s)",
                    file=sys.stderr,
                )

    if workers <= 1:
        collect(_job(j) for j in jobs)
    else:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            collect(pool.map(_job, jobs))
    if traces is not None:
        traces.update({c: df for c, _, _, df in results if df is not None})
    rows = [{"controller": c, "seed": s, **m} for c, s, m, _ in results]
    df = pd.DataFrame(rows)
    means = df.drop(columns="seed").groupby("controller", sort=False).mean().reset_index()
    means.insert(1, "seed", "mean")
    worst = df.drop(columns="seed").groupby("controller", sort=False).max().reset_index()
    worst.insert(1, "seed", "max")
    out = pd.concat([df, means, worst], ignore_index=True)
    out["paper_max_ev_mps"] = out["controller"].map(lambda c: PAPER002[c]["max_ev_mps"])
    out["paper_max_coupler_force_kN"] = out["controller"].map(
        lambda c: PAPER002[c]["max_coupler_force_kN"]
    )
    return out


#: compact column names of the printed table (full names: :func:`compare_paper002`)
SHORT_COLUMNS = {
    "controller": "controller",
    "seed": "seed",
    "max_ev_mps": "max_ev",
    "max_ev_feasible_mps": "max_ev_unsat",
    "max_ev_cruise_mps": "max_ev_cruise",
    "rms_ev_mps": "rms_ev",
    "max_coupler_force_kN": "max_Fc_kN",
    "max_coupler_force_feasible_kN": "max_Fc_unsat",
    "max_coupler_force_cruise_kN": "max_Fc_cruise",
    "max_coupler_def_m": "max_def_m",
    "max_est_error": "max_est_err",
    "max_dR_error_kN": "max_dR_err_kN",
    "median_step_ms": "step_ms",
    "median_solve_ms": "solve_ms",
    "paper_max_ev_mps": "paper_max_ev",
    "paper_max_coupler_force_kN": "paper_Fc_kN",
}


def reproduce_paper002(
    seed: int = 0, runs: dict[str, pd.DataFrame] | None = None, progress: bool = True
) -> pd.DataFrame:
    """Adaptive vs non-adaptive MPC on seeds ``seed .. seed+4`` beside 002's claims.

    Run on Table 2's command and on its traction-feasible variant (column ``command``).

    Speeds in m/s, forces in kN; ``_unsat`` outside the traction-limited window
    :data:`SATURATED_WINDOW_S`, ``_cruise`` in :data:`CRUISE_WINDOWS_S` (see the module
    docstring). Rows: each (controller, seed), then the seed means and maxima.
    ``runs``, if given, receives the traces of seed ``seed`` under ``"<scenario>/<controller>"``;
    ``progress``: one line per finished run on stderr.
    """
    parts = []
    for scenario in ("paper002_cruise", "paper002_cruise_feasible"):
        traces: dict[str, pd.DataFrame] | None = None if runs is None else {}
        full = compare_paper002(
            tuple(range(seed, seed + 5)), scenario=scenario, traces=traces, progress=progress
        )
        if runs is not None and traces is not None:
            runs.update({f"{scenario}/{c}": df for c, df in traces.items()})
        part = full[list(SHORT_COLUMNS)].rename(columns=SHORT_COLUMNS)
        part.insert(0, "command", "Table 2" if scenario == "paper002_cruise" else "feasible")
        parts.append(part)
    return pd.concat(parts, ignore_index=True)


def figures_paper002(table: pd.DataFrame, runs: Mapping[str, pd.DataFrame]) -> dict:
    """Per command: estimation error, resistance estimate, speed error and coupler force
    of both controllers against time (002 Figs. 7, 9, 10; :func:`paper002_figure`)."""
    from train_envs.plots_papers import paper002_figure

    figs = {}
    for scenario in dict.fromkeys(k.split("/")[0] for k in runs):
        both = {k.split("/")[1]: df for k, df in runs.items() if k.startswith(scenario + "/")}
        figs[scenario.removeprefix("paper002_")] = paper002_figure(both, title=scenario)
    return figs
