"""Reproductions of the papers' tables: our closed-loop numbers beside the published ones.

``train-envs reproduce paper000`` runs SEMPC, plain MPC (no terminal cost) and AFSMC on
our single-section and disturbance scenarios and prints E_u, E_v, E_x (the paper's
E_d) and E_p next to paper 000's Tables 2 and 4. The paper's line is unpublished, so
absolute values differ (our assumed section is shorter, the reference is planned with
a traction margin); the claims checked are the orderings and the stopping accuracy
(SEMPC below 0.1 m and below MPC).

Paper 000's AFSMC comparator is ``afsmc000``, the adaptive fuzzy sliding-mode
controller on the speed surface σ = e_v (000 gives no law; its E_x of 57–90 m rules out
position feedback). Our library AFSMC (``afsmc``, sliding surface with position
feedback) is added as an extra row per scenario, with no paper numbers beside it.
Write-up and the measured table: ``docs/papers/paper000.md``.
"""

from __future__ import annotations

from math import nan
from typing import Any

import pandas as pd

from train_envs.simulation import simulate

#: paper 000, Table 2 (single section) and Table 4 (constant / harmonic disturbance);
#: ``afsmc`` (ours, position feedback) has no counterpart in the paper
PAPER000 = {
    ("paper000_single_section", "sempc"): (1.8197, 1.9123, 3.3014, 0.004),
    ("paper000_single_section", "mpc000"): (1.8117, 1.9365, 3.7862, 5.596),
    ("paper000_single_section", "afsmc000"): (1.6799, 2.4046, 89.5023, 74.098),
    ("paper000_single_section", "afsmc"): (nan, nan, nan, nan),
    ("paper000_disturbance_constant", "sempc"): (1.7776, 0.0165, 0.1093, 0.0881),
    ("paper000_disturbance_constant", "mpc000"): (1.9669, 0.0280, 0.8296, 0.6645),
    ("paper000_disturbance_constant", "afsmc000"): (5.5444, 0.7494, 65.5300, 31.7175),
    ("paper000_disturbance_constant", "afsmc"): (nan, nan, nan, nan),
    ("paper000_disturbance_harmonic", "sempc"): (1.5465, 0.0165, 0.0046, 0.00005),
    ("paper000_disturbance_harmonic", "mpc000"): (1.7782, 0.1159, 0.8340, 0.3180),
    ("paper000_disturbance_harmonic", "afsmc000"): (2.7902, 0.6655, 56.8689, 25.6186),
    ("paper000_disturbance_harmonic", "afsmc"): (nan, nan, nan, nan),
}


def reproduce_paper000(seed: int = 0, runs: dict[Any, pd.DataFrame] | None = None) -> pd.DataFrame:
    """Our E_u [1e12 N² s], E_v [m/s], E_x [m], E_p [m] beside paper 000's.

    ``runs``, if given, receives each run's DataFrame under ``(scenario, controller)``.
    """
    rows = []
    for (scenario, ctrl), paper in PAPER000.items():
        res = simulate(scenario, ctrl, seed=seed)
        m = res.metrics
        if runs is not None:
            runs[scenario, ctrl] = res.df
        rows.append(
            {
                "scenario": scenario.removeprefix("paper000_"),
                "controller": ctrl,
                "E_u_1e12_ours": m["E_u_N2s"] / 1e12,
                "E_u_1e12_paper": paper[0],
                "E_v_mps_ours": m["E_v_mps"],
                "E_v_mps_paper": paper[1],
                "E_x_m_ours": m["E_x_m"],
                "E_x_m_paper": paper[2],
                "E_p_m_ours": m["E_p_m"],
                "E_p_m_paper": paper[3],
                "max_rate_Nps": m["max_rate_Nps"],
                "max_coupler_def_m": m["max_coupler_deformation_m"],
            }
        )
    return pd.DataFrame(rows)


def figures_paper000(table: pd.DataFrame, runs: dict[Any, pd.DataFrame]) -> dict[str, Any]:
    """Per scenario: SEMPC, MPC and AFSMC compared (speed error, command, stop zoom);
    SEMPC's per-car commands and coupler force on the single section."""
    from train_envs.plots_papers import multi_car_figure
    from train_envs.plotting import comparison_figure
    from train_envs.scenarios import get_scenario

    figs: dict[str, Any] = {}
    for scenario in dict.fromkeys(sc for sc, _ in PAPER000):
        sc = get_scenario(scenario)
        ctrls = {
            c: runs[scenario, c] for c in ("sempc", "mpc000", "afsmc000") if (scenario, c) in runs
        }
        if ctrls:
            name = scenario.removeprefix("paper000_")
            figs[f"compare_{name}"] = comparison_figure(ctrls, s_stop_m=sc.s_stop_m, title=scenario)
    if ("paper000_single_section", "sempc") in runs:
        figs["cars_single_section_sempc"] = multi_car_figure(
            runs["paper000_single_section", "sempc"],
            title="paper000_single_section, SEMPC: per-car commands and couplers",
        )
    return figs
