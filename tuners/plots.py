"""Plots of a tuning run's evaluations DataFrame; every function returns a Figure.

The DataFrame is :attr:`tuners.run.TuneResult.evaluations` (or
:func:`tuners.run.load_result`'s): objective columns, parameter columns, ``feasible``,
``generation`` and, after :func:`tuners.run.summarize`, ``pareto`` / ``selected`` /
``tchebycheff``. Objective and parameter names default to ``df.attrs["objectives"]`` /
``df.attrs["params"]`` (set by :mod:`tuners.run`). Figures are built with
:class:`matplotlib.figure.Figure` (no pyplot state, safe headless and in workers).
"""

from __future__ import annotations

from collections.abc import Sequence

import matplotlib
import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from train_envs.labels import metric_label
from train_envs.plotting import new_figure
from tuners.mowoa import nondominated

__all__ = [
    "hypervolume_figure",
    "hypervolume_history",
    "parallel_coordinates_figure",
    "pareto_front_figure",
]


def _objectives(df: pd.DataFrame, objectives: Sequence[str] | None) -> list[str]:
    obj = list(objectives or df.attrs.get("objectives") or [])
    if not obj:
        raise ValueError("objective columns unknown: pass objectives=[...]")
    missing = [c for c in obj if c not in df.columns]
    if missing:
        raise KeyError(f"objective columns {missing} not in the DataFrame")
    return obj


def _feasible(df: pd.DataFrame) -> pd.DataFrame:
    return df[df["feasible"].astype(bool)] if "feasible" in df else df


def hypervolume_history(
    df: pd.DataFrame, objectives: Sequence[str] | None = None, ref_offset: float = 0.1
) -> pd.DataFrame:
    """Hypervolume of the feasible non-dominated set found up to each generation.

    Objectives are normalised by the final ideal point (best feasible values) and the
    final Pareto set's nadir point; the reference point is ``1 + ref_offset`` in every
    normalised objective (points beyond it add nothing). Columns: ``generation``,
    ``evaluations`` (cumulative), ``hypervolume``, ``n_pareto``.
    """
    from pymoo.indicators.hv import HV

    obj = _objectives(df, objectives)
    feas = _feasible(df)
    cols = ["generation", "evaluations", "hypervolume", "n_pareto"]
    if len(feas) == 0:
        return pd.DataFrame(columns=cols)
    F_all = feas[obj].to_numpy(float)
    ideal = F_all.min(axis=0)
    nadir = F_all[nondominated(F_all)].max(axis=0)
    scale = np.where(nadir > ideal, nadir - ideal, np.maximum(np.abs(ideal), 1.0))
    hv = HV(ref_point=np.full(len(obj), 1.0 + ref_offset))
    gens = sorted(int(g) for g in df["generation"].dropna().unique())
    rows = []
    for g in gens:
        upto = feas[feas["generation"] <= g]
        n_eval = int((df["generation"] <= g).sum())
        if len(upto) == 0:
            rows.append((g, n_eval, 0.0, 0))
            continue
        Fn = (upto[obj].to_numpy(float) - ideal) / scale
        nd = Fn[nondominated(Fn)]
        rows.append((g, n_eval, float(hv(nd)), len(nd)))
    return pd.DataFrame(rows, columns=cols)


def hypervolume_figure(
    df: pd.DataFrame, objectives: Sequence[str] | None = None, ref_offset: float = 0.1
) -> Figure:
    """Convergence: normalised hypervolume vs generation (see :func:`hypervolume_history`)."""
    h = hypervolume_history(df, objectives, ref_offset)
    fig, _ = new_figure((6, 4), layout="constrained")
    ax = fig.add_subplot()
    ax.plot(h["generation"], h["hypervolume"], marker="o")
    ax.set_xlabel("generation")
    ax.set_ylabel(f"hypervolume (normalised, ref {1 + ref_offset:g})")
    ax.set_title("Convergence of the feasible Pareto set")
    ax.grid(True, alpha=0.3)
    return fig


def pareto_front_figure(
    df: pd.DataFrame, objectives: Sequence[str] | None = None, max_pairs: int = 10
) -> Figure:
    """Scatter of every pair of objectives: all feasible evaluations, the Pareto set,
    the selected solution (star) and the defaults (cross)."""
    obj = _objectives(df, objectives)
    feas = _feasible(df)
    pairs = [(i, j) for i in range(len(obj)) for j in range(i + 1, len(obj))][:max_pairs]
    if not pairs:
        pairs = [(0, 0)]
    n = len(pairs)
    ncol = _grid_columns(n)
    nrow = int(np.ceil(n / ncol))
    fig, _ = new_figure((4.2 * ncol, 3.6 * nrow), layout="constrained")
    axes = fig.subplots(nrow, ncol, squeeze=False).ravel()
    par = feas[feas["pareto"]] if "pareto" in feas else feas.iloc[0:0]
    sel = feas[feas["selected"]] if "selected" in feas else feas.iloc[0:0]
    dflt = df[df["is_default"]] if "is_default" in df else df.iloc[0:0]
    for ax, (i, j) in zip(axes, pairs, strict=False):
        xi, yj = obj[i], obj[j]
        if i == j:  # a single objective: value vs evaluation index
            ax.plot(np.arange(len(feas)), feas[xi], ".", color="0.6", label="feasible")
            ax.set_xlabel("evaluation")
            ax.set_ylabel(metric_label(xi))
            continue
        ax.scatter(feas[xi], feas[yj], s=10, color="0.7", label="feasible")
        if len(par):
            ax.scatter(par[xi], par[yj], s=22, color="C0", label="Pareto set")
        if len(dflt):
            ax.scatter(dflt[xi], dflt[yj], s=60, marker="x", color="C3", label="defaults")
        if len(sel):
            ax.scatter(sel[xi], sel[yj], s=140, marker="*", color="C1", label="selected")
        ax.set_xlabel(metric_label(xi))
        ax.set_ylabel(metric_label(yj))
        ax.grid(True, alpha=0.3)
    for ax in axes[n:]:
        ax.set_visible(False)
    axes[0].legend(fontsize=8)
    fig.suptitle("Objectives of all feasible evaluations")
    return fig


def _grid_columns(n: int, max_cols: int = 5) -> int:
    """Columns of a grid for ``n`` panels with no empty cell where a divisor allows it
    (the one closest to a 5:3 aspect), else the fewest empty cells."""
    options = range(1, min(n, max_cols) + 1)
    return min(options, key=lambda c: ((-n) % c, abs(c / np.ceil(n / c) - 5 / 3)))


def parallel_coordinates_figure(
    df: pd.DataFrame, columns: Sequence[str] | None = None, only_pareto: bool = True
) -> Figure:
    """Parallel coordinates of parameters and objectives, the Pareto set coloured by its
    Tchebycheff value (colour bar), the selected solution bold.

    Each axis is scaled from its smallest to its largest value (log scale where the
    values are positive and span more than two decades, as the log-scaled weights do);
    the axis values are written at its bottom, middle and top.
    """
    if columns is None:
        columns = list(df.attrs.get("params") or []) + _objectives(df, None)
    cols = [c for c in columns if c in df.columns]
    if not cols:
        raise ValueError("no columns to plot")
    data = _feasible(df)
    if only_pareto and "pareto" in data and data["pareto"].any():
        data = data[data["pareto"]]
    V = data[cols].to_numpy(float)
    lo, hi = np.nanmin(V, axis=0), np.nanmax(V, axis=0)
    logs = (lo > 0) & (hi > 100 * lo)
    W = np.where(logs, np.log10(np.where(V > 0, V, 1.0)), V)
    wlo, whi = (
        np.where(logs, np.log10(np.where(logs, lo, 1.0)), lo),
        np.where(logs, np.log10(np.where(logs, hi, 1.0)), hi),
    )
    Vn = (W - wlo) / np.where(whi > wlo, whi - wlo, 1.0)
    fig, _ = new_figure((max(7.0, 1.25 * len(cols)), 5.0), layout="constrained")
    ax = fig.add_subplot()
    xs = np.arange(len(cols))
    t = data["tchebycheff"].to_numpy(float) if "tchebycheff" in data else np.zeros(len(data))
    t = np.nan_to_num(t, nan=np.nanmax(t) if np.isfinite(t).any() else 0.0)
    norm = matplotlib.colors.Normalize(float(t.min()), float(t.max()) if np.ptp(t) else 1.0)
    cmap = matplotlib.colormaps["viridis"]
    sel = data["selected"].to_numpy(bool) if "selected" in data else np.zeros(len(data), bool)
    for k in np.argsort(-t, kind="stable"):  # best (lowest) drawn last, on top
        ax.plot(xs, Vn[k], color=cmap(norm(t[k])), alpha=0.7, lw=1.0)
    for k in np.flatnonzero(sel):
        ax.plot(xs, Vn[k], color="C3", lw=2.5, label="selected")
    for x, a, b, lg in zip(xs, lo, hi, logs, strict=True):
        mid = np.sqrt(a * b) if lg else 0.5 * (a + b)
        d = next((d for d in range(3, 7) if len({f"{v:.{d}g}" for v in (a, mid, b)}) == 3), 6)
        for y, v in ((0.0, a), (0.5, mid), (1.0, b)):
            ax.annotate(
                f"{v:.{d}g}",
                (x, y),
                xytext=(3, 0),
                textcoords="offset points",
                fontsize=7,
                va="center",
                color="0.2",
                bbox={"boxstyle": "round,pad=0.1", "fc": "white", "ec": "none", "alpha": 0.8},
                zorder=5,
            )
    ax.vlines(xs, 0.0, 1.0, color="0.6", lw=0.8)
    labels = [metric_label(c) + (" (log)" if lg else "") for c, lg in zip(cols, logs, strict=True)]
    ax.set_xticks(xs, labels, rotation=30, ha="right")
    ax.set_yticks([])
    ax.set_xlim(-0.3, len(cols) - 0.4)
    ax.set_ylim(-0.05, 1.05)
    what = "Pareto set" if only_pareto else "Feasible evaluations"
    ax.set_title(f"{what}: parameters and objectives (each axis from its min to its max)")
    if sel.any():
        ax.legend(fontsize=8, loc="upper left")
    sm = matplotlib.cm.ScalarMappable(norm=norm, cmap=cmap)
    fig.colorbar(sm, ax=ax, pad=0.01, label="Tchebycheff value (lower is better)")
    return fig
