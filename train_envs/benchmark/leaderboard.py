"""The leaderboard: one row per (scenario, controller) pair of a benchmark.

Each supported pair gets, per headline metric (:data:`HEADLINE`), the mean over its
seeds and the half-width of the 95 % confidence interval of that mean, Student's t
interval ``mean ± t_{0.975, n−1} · s / √n`` (:func:`scipy.stats.t.interval`; NaN for
one seed, 0 when every seed gives the same value). ``status``: ``ok`` (every seed
ran), ``partial`` (some failed: the statistics are over those that ran), ``failed``,
or ``unsupported`` with ``note`` = ``"unsupported: <reason>"``; ``disturbance``: the
benchmark disturbance of its runs (preset name or JSON). Within a scenario the
pairs are ranked (``rank``, 1 = best) by the scenario's primary metric: the stop error
``E_p_m`` on stopping runs, the mean speed error ``E_v_mps`` on cruise runs.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd
from scipy import stats

from train_envs.benchmark.disturbance import disturbance_label
from train_envs.labels import format_number

__all__ = ["HEADLINE", "leaderboard", "leaderboard_markdown", "mean_ci95", "primary_metric"]

#: headline metric -> (label, unit) for tables and plots
HEADLINE: dict[str, tuple[str, str]] = {
    "E_p_m": ("stop error |s_end − s_stop|", "m"),
    "time_error_s": ("punctuality error", "s"),
    "E_v_mps": ("mean |v_ref − v|", "m/s"),
    "energy_kWh": ("traction energy", "kWh"),
    "comfort_mean_abs_jerk_mps3": ("mean |jerk|", "m/s³"),
    "max_overspeed_mps": ("max overspeed", "m/s"),
    "safety_cost": ("safety cost", "m/s·s + s + m"),
}


def mean_ci95(values: Sequence[float]) -> tuple[float, float]:
    """(mean, half-width of the 95 % t interval of the mean) of the finite values."""
    x = np.asarray([v for v in values if v is not None and math.isfinite(v)], float)
    if not len(x):
        return math.nan, math.nan
    mean = float(np.mean(x))
    if len(x) < 2:
        return mean, math.nan
    sem = float(stats.sem(x))
    if sem == 0.0:
        return mean, 0.0
    lo, hi = stats.t.interval(0.95, len(x) - 1, loc=mean, scale=sem)
    return mean, float(hi - lo) / 2.0


def primary_metric(table: pd.DataFrame) -> str:
    """``E_p_m`` if the runs stop at a mark (the column has values), else ``E_v_mps``."""
    return "E_p_m" if "E_p_m" in table and table["E_p_m"].notna().any() else "E_v_mps"


def _status(n_ok: int, n: int) -> str:
    return "ok" if n_ok == n else "failed" if n_ok == 0 else "partial"


def leaderboard(
    table: pd.DataFrame,
    unsupported: Mapping[tuple[str, str], str] | None = None,
    pairs: Sequence[tuple[str, str]] | None = None,
) -> pd.DataFrame:
    """The leaderboard of a tidy results table (:func:`train_envs.benchmark.run.run_cells`).

    ``unsupported``: (scenario, controller) -> reason of the pairs not run; ``pairs``:
    the order of the rows (default: the table's pairs, then the unsupported ones).
    """
    unsupported = dict(unsupported or {})
    if pairs is None:
        seen = list(dict.fromkeys(zip(table["scenario"], table["controller"], strict=True)))
        pairs = seen + [p for p in unsupported if p not in seen]
    groups = {k: g for k, g in table.groupby(["scenario", "controller"], sort=False)}
    rows = []
    for sc, c in pairs:
        row: dict[str, object] = {"scenario": sc, "controller": c}
        if (sc, c) in unsupported:
            row.update(status="unsupported", n_seeds=0, note=f"unsupported: {unsupported[sc, c]}")
            rows.append(row)
            continue
        g = groups.get((sc, c))
        if g is None:
            row.update(status="missing", n_seeds=0, note="not run")
            rows.append(row)
            continue
        ok = g[g["status"] == "ok"]
        errors = g.loc[g["status"] != "ok", "error"]
        row.update(
            status=_status(len(ok), len(g)),
            n_seeds=len(ok),
            note="" if not len(errors) else f"failed ({len(errors)}/{len(g)}): {errors.iloc[0]}",
            parameters=g["parameters"].iloc[0],
        )
        if "disturbance" in g:
            row["disturbance"] = disturbance_label(str(g["disturbance"].iloc[0]))
        for m in HEADLINE:
            if m in ok and ok[m].notna().any():
                row[m], row[f"{m}_ci95"] = mean_ci95(ok[m].tolist())
        rows.append(row)
    board = pd.DataFrame(rows)
    stat_cols = [c for m in HEADLINE for c in (m, f"{m}_ci95") if c in board]
    fixed = ["scenario", "controller", "status", "n_seeds", "note", "parameters", "disturbance"]
    board = board[[c for c in fixed if c in board] + stat_cols]
    board["rank"] = np.nan
    for _, g in board.groupby("scenario", sort=False):
        ran = g[g["status"].isin(["ok", "partial"])]
        key = primary_metric(ran)
        if len(ran) and key in ran:
            board.loc[ran.index, "rank"] = ran[key].rank(method="min")
    return board


def _cell(row: pd.Series, m: str) -> str:
    mean = row.get(m)
    if mean is None or not isinstance(mean, float) or math.isnan(mean):
        return ""
    ci = row.get(f"{m}_ci95")
    half = "" if ci is None or math.isnan(ci) else f" ± {format_number(ci, 2)}"
    return format_number(mean, 3) + half


def leaderboard_markdown(board: pd.DataFrame, metrics: Sequence[str] | None = None) -> str:
    """The leaderboard as Markdown: one table per scenario, ranked pairs first."""
    metrics = [m for m in (metrics or HEADLINE) if m in board]
    head = [
        "rank",
        "controller",
        *(f"{HEADLINE[m][0]} [{HEADLINE[m][1]}]".replace("|", "\\|") for m in metrics),
    ]
    out = []
    for sc, g in board.groupby("scenario", sort=False):
        g = g.sort_values("rank", na_position="last", kind="stable")
        used = [m for m in metrics if g[m].notna().any()]
        cols = ["rank", "controller", *(head[2 + metrics.index(m)] for m in used), "note"]
        out += [f"### {sc}", "", "| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
        for _, row in g.iterrows():
            rank = "" if math.isnan(row["rank"]) else str(int(row["rank"]))
            cells = [rank, row["controller"], *(_cell(row, m) for m in used)]
            note = str(row.get("note") or "").replace("|", "/")
            out.append("| " + " | ".join([*cells, note]) + " |")
        out.append("")
    return "\n".join(out)
