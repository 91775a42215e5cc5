"""Labels with units, printed numbers and the tuning figures' layout."""

from __future__ import annotations

import numpy as np
import pandas as pd

from train_envs.labels import format_number, format_table, metric_label
from tuners import plots


def test_metric_labels_carry_units():
    assert metric_label("ITAE_m_s") == "ITAE [m·s]"  # position error × time, not milliseconds
    assert metric_label("energy_kWh") == "energy [kWh]"
    assert metric_label("max_coupler_force_kN") == "max coupler force [kN]"  # by suffix
    assert metric_label("whatever") == "whatever"


def test_printed_numbers_have_no_roundoff_noise_and_no_g_prefix():
    assert format_number(1.009e-11) == "0" and format_number(-3e-12) == "0"
    assert format_number(475.603739) == "475.6" and format_number(np.nan) == "NaN"
    t = pd.DataFrame({"point": ["a"], "ITAE_m_s": [1.0], "g:time_error_s": [-4.6]})
    text = format_table(t, bounds={"time_error_s": 5.0})
    assert "g:" not in text and "time_error_s (≤ 5)" in text and "0.4" in text
    assert "time_error_s margin" in format_table(t)


def _frame(n_obj: int) -> pd.DataFrame:
    rng = np.random.default_rng(0)
    obj = [f"f{i}_m" for i in range(n_obj)]
    df = pd.DataFrame(rng.random((30, n_obj)), columns=obj)
    df["p_log"] = 10 ** rng.uniform(-1, 3, 30)
    df["feasible"] = True
    df["pareto"] = np.arange(30) < 10
    df["selected"] = np.arange(30) == 0
    df["tchebycheff"] = rng.random(30)
    df.attrs.update(objectives=obj, params=["p_log"])
    return df


def test_pareto_matrix_fills_its_grid_and_labels_units():
    for m, panels in ((2, 1), (3, 3), (4, 6), (5, 10)):
        fig = plots.pareto_front_figure(_frame(m))
        axes = fig.get_axes()
        assert len(axes) == panels and all(ax.get_visible() for ax in axes)
        assert all("[m]" in ax.get_xlabel() for ax in axes)


def test_parallel_coordinates_has_colour_bar_and_axis_values():
    fig = plots.parallel_coordinates_figure(_frame(3))
    ax, cbar = fig.get_axes()
    assert "Tchebycheff" in cbar.get_ylabel()
    texts = [t.get_text() for t in ax.texts]
    assert len(texts) == 3 * 4  # bottom, middle, top of every axis
    assert "p_log (log)" in [t.get_text() for t in ax.get_xticklabels()]
