"""Figures in the style of the papers: functions that take DataFrames and return a Figure.

Used by ``train-envs reproduce paperNNN --out DIR`` (:mod:`train_envs.reproduce`).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import pandas as pd
from matplotlib.figure import Figure
from matplotlib.ticker import ScalarFormatter

from train_envs.plotting import new_figure


def paper002_figure(runs: Mapping[str, pd.DataFrame], *, title: str = "") -> Figure:
    """Paper 002 Fig. 7 and 9/10 for several controllers on the same seed.

    ``runs`` maps a label to a trace of :func:`train_envs.reproduce.paper002.run_paper002`
    (columns ``t_s``, ``est_error``, ``dR_hat_total_kN``, ``dR_true_total_kN``,
    ``dR_error_kN``, ``ev_max_mps``, ``coupler_force_kN``). Panels, top to bottom:

    1. norm of the one-step estimation error ‖x̃(k)‖ (002 Fig. 4/7), log scale;
    2. running-resistance deviation of the whole train: the plant's (true) and each
       controller's estimate (the nominal model's is 0), and the per-car estimation
       error ‖R̂_dev − R_dev‖ (the physical content of 002's tr(Θ̃ᵀΘ̃));
    3. speed error max_i |v_i − v_r| (002 Fig. 9);
    4. largest coupler force (002 Fig. 10).
    """
    if not runs:
        raise ValueError("runs must contain at least one labelled DataFrame")
    fig, axes = new_figure((10, 10), 4, 1, sharex=True)
    ax_e, ax_r, ax_v, ax_f = axes
    first = next(iter(runs.values()))
    ax_r.plot(first["t_s"], first["dR_true_total_kN"], color="black", lw=1.2, label="true (plant)")
    for label, df in runs.items():
        t = df["t_s"]
        est = df["est_error"].to_numpy(dtype=float)
        ax_e.semilogy(t, np.where(est > 0, est, np.nan), lw=0.9, label=label)
        (line,) = ax_r.plot(t, df["dR_hat_total_kN"], lw=1.0, label=f"{label}: estimate")
        ax_r.plot(
            t, df["dR_error_kN"], lw=0.8, ls=":", color=line.get_color(), label=f"{label}: error"
        )
        ax_v.plot(t, df["ev_max_mps"], lw=1.0, label=label)
        ax_f.plot(t, df["coupler_force_kN"], lw=0.8, label=label)
    ax_e.set_ylabel("‖x̃‖ (mm, m/s)")
    ax_e.set_title(title or "paper 002: estimation error, speed error and coupler force")
    ax_r.set_ylabel("resistance dev. [kN]")
    ax_v.set_ylabel("max |v_i − v_r| [m/s]")
    ax_f.set_ylabel("coupler force [kN]")
    ax_f.set_xlabel("t [s]")
    ax_f.axhline(2.0, color="grey", lw=0.6, ls="--")
    ax_f.axhline(-2.0, color="grey", lw=0.6, ls="--")
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend(loc="upper right", fontsize=7, ncol=2)
    fig.tight_layout()
    return fig


def multi_car_figure(df: pd.DataFrame, *, title: str = "") -> Figure:
    """A multi-car run against time (paper 000 Figs. 3–5): speed and reference [km/h],
    each car's command ``u{i}_cmd_N`` [kN], and the largest coupler force [kN]."""
    cars = sorted(
        (c for c in df.columns if c.startswith("u") and c.endswith("_cmd_N") and c != "u_cmd_N"),
        key=lambda c: int(c[1:].split("_")[0]),
    )
    if not cars or "coupler_force_max_N" not in df:
        raise ValueError(
            "multi_car_figure needs the per-car columns u1_cmd_N ... of a multi-car run"
        )
    fig, (ax_v, ax_u, ax_c) = new_figure((9, 8), 3, 1, sharex=True)
    t = df["t_s"]
    ax_v.plot(t, df["v_ref_mps"] * 3.6, "k:", lw=1.0, label="reference")
    ax_v.plot(t, df["v_mps"] * 3.6, lw=1.3, label="train")
    ax_v.set_ylabel("speed [km/h]")
    ax_v.legend(fontsize=8)
    for c in cars:
        ax_u.plot(t, df[c] / 1e3, lw=1.0, label=f"car {c[1:].split('_')[0]}")
    ax_u.set_ylabel("per-car command [kN]")
    ax_u.legend(ncol=min(len(cars), 8), fontsize=7)
    ax_c.plot(t, df["coupler_force_max_N"] / 1e3, lw=1.0, color="tab:red")
    ax_c.axhline(0.0, color="grey", lw=0.6)
    ax_c.set(ylabel="largest coupler force [kN]", xlabel="time [s]")
    return _finish(fig, (ax_v, ax_u, ax_c), title)


def paper001_horizon_figure(table: pd.DataFrame) -> Figure:
    """Paper 001 Fig. 11 from :func:`train_envs.reproduce.paper001.reproduce_paper001`'s
    table: mean |stopping error| [cm] and command switches per run against the horizon
    N for RMPC and RSMPC (one line style per resistance reading), PID dashed, the
    ±50 cm window dotted. Switches on a log axis: RSMPC's are far fewer."""
    fig, (ax_e, ax_s) = new_figure((10, 3.8), 1, 2)
    for k, reading in enumerate(dict.fromkeys(table["reading"])):
        part = table[table["reading"] == reading]
        ls = ("-", "--", ":")[k % 3]
        for i, name in enumerate(("RMPC", "RSMPC")):
            rows = part[part["controller"] == name]
            style = {"ls": ls, "marker": "o", "color": f"C{i}", "label": f"{name} ({reading})"}
            ax_e.plot(rows["N"].astype(int), rows["abs_err_mean_cm"], **style)
            ax_s.plot(rows["N"].astype(int), rows["switches"], **style)
        pid = part[part["controller"] == "PID"]
        if len(pid):
            kw = {"color": "grey", "ls": ls, "lw": 0.9, "label": f"PID ({reading})"}
            ax_e.axhline(float(pid["abs_err_mean_cm"].iloc[0]), **kw)
            ax_s.axhline(float(pid["switches"].iloc[0]), **kw)
    ax_e.axhline(50.0, color="red", lw=0.8, ls=":", label="±50 cm window")
    ax_e.set(xlabel="horizon N", ylabel="mean |stop error| [cm]", ylim=(0, None))
    ax_s.set(xlabel="horizon N", ylabel="command switches per run", yscale="log")
    ax_s.yaxis.set_major_formatter(ScalarFormatter())
    ax_s.yaxis.set_minor_formatter(ScalarFormatter())
    ax_e.set_title("stopping accuracy", fontsize=10)
    ax_s.set_title("command switches", fontsize=10)
    for ax in (ax_e, ax_s):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    return fig


def paper003_compensation_figure(runs: Mapping[str, pd.DataFrame], *, title: str = "") -> Figure:
    """Paper 003 Figs. 4–7 for its actuator cases against time: lead-car speed and
    reference [km/h]; each case's speed and total actual force minus the first case's
    (the ideal actuator) — what compensation removes (the curves themselves coincide
    at this scale)."""
    if not runs:
        raise ValueError("runs must contain at least one labelled DataFrame")
    ref = next(iter(runs.values()))
    fig, (ax_v, ax_d, ax_u) = new_figure((9, 8), 3, 1, sharex=True)
    ax_v.plot(ref["t_s"], ref["v_ref_mps"] * 3.6, "k:", lw=1.0, label="reference")
    for i, (label, df) in enumerate(runs.items()):
        style = {"lw": 1.2, "ls": ("-", "--", "-.", ":")[i % 4], "label": label}
        n = min(len(df), len(ref))
        ax_v.plot(df["t_s"], df["v_mps"] * 3.6, **style)
        diff = (df["v_mps"].to_numpy()[:n] - ref["v_mps"].to_numpy()[:n]) * 3.6
        ax_d.plot(df["t_s"].to_numpy()[:n], diff, **style)
        dF = (df["u_N"].to_numpy()[:n] - ref["u_N"].to_numpy()[:n]) / 1e3
        ax_u.plot(df["t_s"].to_numpy()[:n], dF, **style)
    ax_v.set_ylabel("lead-car speed [km/h]")
    ax_v.legend(fontsize=8)
    ax_d.axhline(0.0, color="grey", lw=0.6)
    ax_d.set_ylabel(f"speed − {next(iter(runs))} [km/h]", fontsize=8)
    ax_u.axhline(0.0, color="grey", lw=0.6)
    ax_u.set_ylabel(f"force − {next(iter(runs))} [kN]", fontsize=8)
    ax_u.set_xlabel("time [s]")
    return _finish(fig, (ax_v, ax_d, ax_u), title)


def _finish(fig: Figure, axes: tuple, title: str) -> Figure:
    """Grid on every panel, ``title`` on the first, tight layout."""
    for ax in axes:
        ax.grid(alpha=0.3)
    if title:
        axes[0].set_title(title)
    fig.tight_layout()
    return fig
