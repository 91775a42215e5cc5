"""Figures in the style of the papers: functions that take DataFrames and return a Figure."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

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
