"""Plots: functions that take a run's DataFrame and return a matplotlib Figure."""

from __future__ import annotations

from collections.abc import Mapping

import matplotlib

matplotlib.use("Agg", force=False)
import matplotlib.pyplot as plt  # noqa: E402
import pandas as pd  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402


def speed_distance_figure(
    runs: pd.DataFrame | Mapping[str, pd.DataFrame],
    *,
    title: str = "",
    s_stop_m: float | None = None,
) -> Figure:
    """Speed–distance picture: speed, reference, limit, gradient band and command.

    ``runs`` is one run's DataFrame or a mapping label → DataFrame (overlays).
    """
    if isinstance(runs, pd.DataFrame):
        runs = {"train": runs}
    fig, (ax, axu) = plt.subplots(
        2, 1, figsize=(9, 6), sharex=True, gridspec_kw={"height_ratios": [3, 1.3]}
    )
    first = next(iter(runs.values()))
    s = first["s_m"]
    ax.plot(s, first["v_limit_mps"] * 3.6, color="red", lw=1.0, ls="--", label="speed limit")
    ax.plot(s, first["v_ref_mps"] * 3.6, color="black", lw=1.0, ls=":", label="reference")
    for label, df in runs.items():
        ax.plot(df["s_m"], df["v_mps"] * 3.6, lw=1.4, label=label)
    if s_stop_m is not None:
        ax.axvline(s_stop_m, color="grey", lw=0.8)
    ax.set_ylabel("speed [km/h]")
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    if title:
        ax.set_title(title)
    # gradient band on a twin axis
    axg = ax.twinx()
    axg.fill_between(s, first["gradient_permil"], step="post", color="tab:green", alpha=0.12)
    axg.set_ylabel("gradient [‰]", color="tab:green")
    for label, df in runs.items():
        axu.plot(df["s_m"], df["u_cmd_N"] / 1e3, lw=1.0, label=label)
    axu.axhline(0, color="grey", lw=0.6)
    axu.set_ylabel("command [kN]")
    axu.set_xlabel("distance [m]")
    axu.grid(alpha=0.3)
    fig.tight_layout()
    return fig


def time_series_figure(df: pd.DataFrame, columns: list[str], *, title: str = "") -> Figure:
    """Stacked time series of the given DataFrame columns against ``t_s``."""
    fig, axes = plt.subplots(
        len(columns), 1, figsize=(9, 1.8 * len(columns) + 1), sharex=True, squeeze=False
    )
    for ax, col in zip(axes[:, 0], columns, strict=True):
        ax.plot(df["t_s"], df[col], lw=1.0)
        ax.set_ylabel(col)
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("t_s")
    if title:
        axes[0, 0].set_title(title)
    fig.tight_layout()
    return fig
