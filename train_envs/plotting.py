"""Plots: functions that take a run's DataFrame and return a matplotlib Figure."""

from __future__ import annotations

import io
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd
from matplotlib.figure import Figure


class ShownFigure(Figure):
    """A :class:`~matplotlib.figure.Figure` that Jupyter shows as a PNG by itself.

    The figures here are made without pyplot (no backend chosen, nothing kept alive by
    a global figure manager); ``_repr_png_`` lets IPython display one returned by a
    cell whether or not an inline backend is active.
    """

    def _repr_png_(self) -> bytes:
        buf = io.BytesIO()
        self.savefig(buf, format="png", bbox_inches="tight")
        return buf.getvalue()


def new_figure(
    figsize: tuple[float, float],
    nrows: int = 0,
    ncols: int = 1,
    *,
    layout: str | None = None,
    **kwargs: Any,
) -> tuple[Figure, Any]:
    """``(figure, axes)``: a :class:`ShownFigure` and its ``nrows × ncols`` axes
    (:meth:`Figure.subplots` with ``kwargs``; ``None`` for ``nrows = 0``, the caller adds
    its own). No backend is chosen or changed; a script saves with ``fig.savefig``."""
    fig = ShownFigure(figsize=figsize, layout=layout)
    return fig, (fig.subplots(nrows, ncols, **kwargs) if nrows else None)


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
    fig, (ax, axu) = new_figure((9, 6), 2, 1, sharex=True, gridspec_kw={"height_ratios": [3, 1.3]})
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


def comparison_figure(
    runs: Mapping[str, pd.DataFrame],
    *,
    x: str = "s_m",
    title: str = "",
    s_stop_m: float | None = None,
    zoom_m: float = 20.0,
) -> Figure:
    """Runs side by side, drawn so that their differences show.

    Panels: speed with the limit and the first run's reference [km/h]; each run's speed
    error ``v − v_ref`` [km/h] (curves that coincide above separate here); the command
    [kN]; and, with ``s_stop_m`` on a distance axis, a zoom on the last ``zoom_m`` metres
    before the stopping point with each run's final position error in cm in the legend.
    ``x`` is ``"s_m"`` (stopping tasks) or ``"t_s"`` (cruise tasks, which their papers
    plot against time).
    """
    if not runs:
        raise ValueError("runs must contain at least one labelled DataFrame")
    if x not in ("s_m", "t_s"):
        raise ValueError(f"x must be 's_m' or 't_s', got {x!r}")
    zoom = s_stop_m is not None and x == "s_m"
    ratios = [2.6, 1.3, 1.3] + ([1.8] if zoom else [])
    fig, axes = new_figure((9, 2.1 * sum(ratios)), len(ratios), 1, height_ratios=ratios)
    ax_v, ax_e, ax_u = axes[:3]
    for ax in axes[1:3]:
        ax.sharex(ax_v)
    first = next(iter(runs.values()))
    ax_v.plot(first[x], first["v_limit_mps"] * 3.6, color="red", lw=1.0, ls="--", label="limit")
    ax_v.plot(first[x], first["v_ref_mps"] * 3.6, color="black", lw=1.0, ls=":", label="reference")
    for i, (label, df) in enumerate(runs.items()):
        style = {"lw": 1.3, "ls": ("-", "--", "-.", ":")[i % 4], "label": label}
        ax_v.plot(df[x], df["v_mps"] * 3.6, **style)
        ax_e.plot(df[x], (df["v_mps"] - df["v_ref_mps"]) * 3.6, **style)
        ax_u.plot(df[x], df["u_cmd_N"] / 1e3, **style)
    ax_v.set(ylabel="speed [km/h]", title=title)
    ax_v.set_ylim(bottom=0)
    ax_e.set_ylabel("v − v_ref [km/h]")
    ax_u.set_ylabel("command [kN]")
    ax_u.set_xlabel("distance [m]" if x == "s_m" else "time [s]")
    for ax in (ax_e, ax_u):
        ax.axhline(0, color="grey", lw=0.6)
    ax_v.legend(loc="best", fontsize=8)
    if zoom:
        ax_z = axes[3]
        for i, (label, df) in enumerate(runs.items()):
            near = df[df["s_m"] > s_stop_m - zoom_m]
            err_cm = 100.0 * (float(df["s_m"].iloc[-1]) - s_stop_m)
            ax_z.plot(
                near["s_m"] - s_stop_m,
                near["v_mps"] * 3.6,
                lw=1.3,
                ls=("-", "--", "-.", ":")[i % 4],
                label=f"{label}: stops {err_cm:+.1f} cm",
            )
        ax_z.axvline(0.0, color="grey", lw=0.8)
        ax_z.set(xlabel="position − stopping point [m]", ylabel="speed [km/h]")
        ax_z.set_title(f"last {zoom_m:g} m", fontsize=9)
        ax_z.legend(loc="best", fontsize=8)
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.tight_layout()
    return fig


def time_series_figure(df: pd.DataFrame, columns: list[str], *, title: str = "") -> Figure:
    """Stacked time series of the given DataFrame columns against ``t_s``."""
    fig, axes = new_figure((9, 1.8 * len(columns) + 1), len(columns), 1, sharex=True, squeeze=False)
    for ax, col in zip(axes[:, 0], columns, strict=True):
        ax.plot(df["t_s"], df[col], lw=1.0)
        ax.set_ylabel(col)
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("t_s")
    if title:
        axes[0, 0].set_title(title)
    fig.tight_layout()
    return fig


def parameter_schedule_figure(
    schedules: Mapping[str, pd.DataFrame],
    *,
    log: Sequence[str] = (),
    title: str = "",
) -> Figure:
    """The parameters an agent set at each env step: one panel per parameter.

    ``schedules`` maps a label (``"PPO"``, ``"defaults"``) to a DataFrame with one row
    per env step, an ``env_step`` column (else the row number) and one column per
    parameter (``info["params"]`` of each step); every label's parameters are drawn as
    steps held until the next decision, the later labels dashed. Parameters named in
    ``log`` get a log axis (the env's log-scaled weights).
    """
    if not schedules:
        raise ValueError("schedules must hold at least one labelled DataFrame")
    first = next(iter(schedules.values()))
    names = [c for c in first.columns if c != "env_step"]
    fig, axes = new_figure((9, 1.7 * len(names) + 0.8), len(names), 1, sharex=True, squeeze=False)
    for ax, name in zip(axes[:, 0], names, strict=True):
        for k, (label, df) in enumerate(schedules.items()):
            x = df["env_step"] if "env_step" in df else np.arange(len(df))
            ax.step(x, df[name], where="post", ls="-" if k == 0 else "--", label=label)
        if name in log:
            ax.set_yscale("log")
        ax.set_ylabel(name)
        ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=8)
    axes[-1, 0].set_xlabel("env step (decision)")
    if title:
        axes[0, 0].set_title(title)
    fig.tight_layout()
    return fig


def dmc_adjustment_figure(
    df: pd.DataFrame,
    *,
    title: str = "",
    alpha_bounds: tuple[float, float] | None = None,
    h_band: tuple[float, float] | None = None,
) -> Figure:
    """Paper 004's online adjustments over one run (004 §4.2–4.3), against time.

    Panels: speed and reference [km/h]; the speed error ``v_ref − v`` [km/h]; the fuzzy
    satisfaction index ``J`` with the softening factor ``α`` it sets (dashed: the
    ``alpha_bounds`` it moves between); the correction coefficient ``h_c`` (dashed: the
    ``h_band`` h_0 ± 3 k_h it can reach). Needs the DMC's recorded columns ``alpha``,
    ``h_c`` and ``J`` (``train_envs.simulation.INFO_COLUMNS``).
    """
    missing = [c for c in ("t_s", "v_mps", "v_ref_mps", "alpha", "h_c", "J") if c not in df]
    if missing:
        raise ValueError(f"dmc_adjustment_figure needs the columns {missing} (a DMC run)")
    run = df.iloc[:-1]  # the last row is the final state, not a control step
    t = run["t_s"]
    fig, axes = new_figure(
        (9, 8), 4, 1, sharex=True, gridspec_kw={"height_ratios": [2, 1, 1.4, 1.2]}
    )
    ax_v, ax_e, ax_a, ax_h = axes
    ax_v.plot(t, run["v_ref_mps"] * 3.6, color="black", lw=1.0, ls=":", label="reference")
    ax_v.plot(t, run["v_mps"] * 3.6, lw=1.3, label="train")
    ax_v.set_ylabel("speed [km/h]")
    ax_v.legend(loc="best", fontsize=8)
    ax_e.plot(t, (run["v_ref_mps"] - run["v_mps"]) * 3.6, lw=1.0, color="tab:purple")
    ax_e.axhline(0.0, color="grey", lw=0.6)
    ax_e.set_ylabel("error [km/h]")
    ax_a.plot(t, run["J"], lw=0.8, color="tab:gray", label="satisfaction J")
    ax_a.plot(t, run["alpha"], lw=1.3, color="tab:orange", label="softening α")
    if alpha_bounds is not None:
        for b in alpha_bounds:
            ax_a.axhline(b, color="tab:orange", lw=0.7, ls="--")
    ax_a.set_ylabel("J, α")
    ax_a.set_ylim(-0.05, 1.05)
    ax_a.legend(loc="best", fontsize=8)
    ax_h.plot(t, run["h_c"], lw=1.2, color="tab:green")
    if h_band is not None:
        for b in h_band:
            ax_h.axhline(b, color="tab:green", lw=0.7, ls="--")
    ax_h.set_ylabel("correction h_c")
    ax_h.set_xlabel("time [s]")
    for ax in axes:
        ax.grid(alpha=0.3)
    if title:
        ax_v.set_title(title)
    fig.tight_layout()
    return fig
