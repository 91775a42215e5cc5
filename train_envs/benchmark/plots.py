"""Figures of a benchmark: the leaderboard heatmap and the per-scenario overlays.

Both take DataFrames and return a Figure (:func:`train_envs.plotting.new_figure`; no
backend is chosen), which a script saves with ``fig.savefig``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from train_envs.benchmark.leaderboard import HEADLINE
from train_envs.labels import format_number
from train_envs.plotting import comparison_figure, new_figure

__all__ = ["heatmap_figure", "overlay_figure"]


def _column_scaled(grid: np.ndarray) -> np.ndarray:
    """Each column (scenario) mapped to [0, 1]: 0 its best (lowest) value, 1 its worst."""
    out = np.full_like(grid, np.nan)
    for j in range(grid.shape[1]):
        col = grid[:, j]
        ok = np.isfinite(col)
        if ok.any():
            lo, hi = col[ok].min(), col[ok].max()
            out[ok, j] = (col[ok] - lo) / (hi - lo) if hi > lo else 0.0
    return out


def heatmap_figure(board: pd.DataFrame, metrics: Sequence[str] | None = None) -> Figure:
    """Controllers × scenarios, one panel per headline metric (mean over seeds).

    Each cell shows the metric's value (units in the panel title); its colour places
    the value within its scenario (column), from the scenario's best (0) to its worst
    (1), since a metric's scale differs from one scenario to the next. Unsupported
    pairs are grey and marked ``n/a``, failed ones ``×``; a metric that a scenario does
    not have is blank.
    """
    metrics = [m for m in (metrics or HEADLINE) if m in board]
    if not metrics:
        raise ValueError(f"the leaderboard has none of the metrics {list(HEADLINE)}")
    scenarios = list(dict.fromkeys(board["scenario"]))
    controllers = list(dict.fromkeys(board["controller"]))
    ncols = min(2, len(metrics))
    nrows = math.ceil(len(metrics) / ncols)
    w = 1.6 + 0.5 * len(scenarios)
    h = 1.6 + 0.3 * len(controllers)
    fig, axes = new_figure((ncols * w + 1.5, nrows * h), nrows, ncols, squeeze=False)
    status = {(r.scenario, r.controller): r.status for r in board.itertuples(index=False)}
    for ax, m in zip(axes.flat, metrics, strict=False):
        grid = np.full((len(controllers), len(scenarios)), np.nan)
        for r in board.itertuples(index=False):
            grid[controllers.index(r.controller), scenarios.index(r.scenario)] = getattr(r, m)
        scaled = _column_scaled(grid)
        ax.set_facecolor("0.85")
        im = ax.imshow(
            np.ma.masked_invalid(scaled), cmap="viridis", vmin=0.0, vmax=1.0, aspect="auto"
        )
        for (sc, c), st in status.items():
            i, j = controllers.index(c), scenarios.index(sc)
            v = grid[i, j]
            text = (
                "n/a"
                if st == "unsupported"
                else "×"
                if st in ("failed", "missing")
                else format_number(v, 2)
                if np.isfinite(v)
                else ""
            )
            dark = np.isfinite(scaled[i, j]) and scaled[i, j] < 0.5
            ax.text(j, i, text, ha="center", va="center", fontsize=6, color="w" if dark else "k")
        label, unit = HEADLINE[m]
        ax.set_title(f"{label} [{unit}]", fontsize=9)
        ax.set_xticks(range(len(scenarios)), scenarios, rotation=60, ha="right", fontsize=7)
        ax.set_yticks(range(len(controllers)), controllers, fontsize=7)
        fig.colorbar(im, ax=ax, label="within scenario: best 0, worst 1", shrink=0.8)
    for ax in list(axes.flat)[len(metrics) :]:
        ax.set_visible(False)
    fig.tight_layout()
    return fig


def overlay_figure(
    runs: Mapping[str, pd.DataFrame], *, scenario: str, s_stop_m: float | None = None
) -> Figure:
    """One scenario's runs (label -> run DataFrame) overlaid: speed, speed error and
    command (:func:`train_envs.plotting.comparison_figure`), against distance on a
    stopping run (with a zoom on the stop), against time on a cruise run."""
    return comparison_figure(
        runs,
        x="s_m" if s_stop_m is not None else "t_s",
        title=f"{scenario}: every controller, first seed",
        s_stop_m=s_stop_m,
    )
