"""Figures that take DataFrames: what they draw (train_envs.plotting)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from train_envs.plotting import parameter_schedule_figure


def test_parameter_schedule_draws_each_parameter_held_per_decision():
    ppo = pd.DataFrame({"env_step": [0, 1, 2], "q_s": [0.1, 1.0, 10.0], "r_du": [5.0, 6.0, 7.0]})
    dflt = pd.DataFrame({"env_step": [0, 1, 2], "q_s": [0.1] * 3, "r_du": [10.0] * 3})
    fig = parameter_schedule_figure({"PPO": ppo, "defaults": dflt}, log=["q_s"])
    axes = fig.axes
    assert [a.get_ylabel() for a in axes] == ["q_s", "r_du"]
    assert axes[0].get_yscale() == "log" and axes[1].get_yscale() == "linear"
    lines = axes[0].get_lines()
    assert [ln.get_label() for ln in lines] == ["PPO", "defaults"]
    assert lines[0].get_drawstyle() == "steps-post"
    np.testing.assert_array_equal(lines[0].get_ydata(), ppo["q_s"])
    assert lines[1].get_linestyle() == "--"


def test_parameter_schedule_needs_a_schedule():
    with pytest.raises(ValueError, match="schedules"):
        parameter_schedule_figure({})
