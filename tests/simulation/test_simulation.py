"""Closed-loop runner, scenarios, metrics and CLI."""

import math

import numpy as np
import pandas as pd
import pytest

from train_envs.cli import main
from train_envs.controllers import PIDController, make_controller
from train_envs.controllers.base import Controller, TunableParam
from train_envs.metrics import episode_metrics
from train_envs.scenarios import get_scenario, list_scenarios
from train_envs.simulation import ClosedLoop, SimulationError, simulate

UNIT_COLUMNS = {"t_s", "s_m", "v_mps", "v_ref_mps", "s_ref_m", "v_limit_mps", "u_cmd_N", "u_N"}


@pytest.mark.parametrize("name", list_scenarios())
def test_every_scenario_builds_and_steps(name):
    sc = get_scenario(name)
    loop = ClosedLoop(sc, PIDController())
    loop.reset(seed=1)
    for _ in range(20):
        loop.step()
        if loop.done:
            break
    df = loop.dataframe()
    assert UNIT_COLUMNS <= set(df.columns)
    assert np.all(np.isfinite(df["v_mps"]))
    # the reference never exceeds the speed limit at the start of the run
    assert df["v_ref_mps"].iloc[0] <= df["v_limit_mps"].iloc[0] + 1e-6


def test_paper001_pid_stops_in_window_and_reports_metrics():
    res = simulate("paper001_stopping", "pid", seed=0)
    m = res.metrics
    assert abs(m["stop_error_m"]) < 0.5  # ATO stopping window of paper 001
    assert m["stopped"] == 1.0
    assert m["max_overspeed_mps"] == 0.0
    assert res.df["t_s"].is_monotonic_increasing
    assert m["command_switches"] > 0


def test_same_seed_same_result_and_different_seed_differs():
    sc = get_scenario("paper001_stopping").with_overrides(
        disturbance=get_scenario("paper001_stopping").disturbance.__class__(random_bound_mps2=0.05)
    )
    a = simulate(sc, "pid", seed=3).df
    b = simulate(sc, "pid", seed=3).df
    c = simulate(sc, "pid", seed=4).df
    pd.testing.assert_frame_equal(a, b)
    assert not np.allclose(a["v_mps"].to_numpy()[:150], c["v_mps"].to_numpy()[:150])


def test_parameters_change_between_steps_and_fixed_params_reproduce():
    sc = get_scenario("paper001_stopping")
    base = simulate(sc, PIDController(kp=0.5), seed=0).df
    loop = ClosedLoop(sc, PIDController())
    loop.reset(seed=0)
    while not loop.done:
        loop.controller.set_params(kp=0.5)  # what an env action does every step
        loop.step()
    pd.testing.assert_frame_equal(base, loop.dataframe())


class _Exploding(Controller):
    name = "exploding"
    PARAMS = (TunableParam("x", 0.0, 1.0, 0.5),)

    def compute(self, obs):
        if obs.t_s > 2.0:
            raise RuntimeError("boom")
        return np.array([0.0]), {}


def test_failure_keeps_the_partial_run():
    with pytest.raises(SimulationError) as err:
        simulate("paper001_stopping", _Exploding(), seed=0)
    partial = err.value.partial
    assert len(partial.df) >= 10
    assert "boom" in partial.error


def test_bad_inputs_name_the_field():
    with pytest.raises(ValueError, match="scenario"):
        get_scenario("no_such_scenario")
    with pytest.raises(ValueError, match="controller"):
        make_controller("no_such_controller")
    with pytest.raises(ValueError, match="kp"):
        PIDController(kp=-1.0)
    with pytest.raises(ValueError, match="dt_sim_s"):
        get_scenario("paper001_stopping", dt_sim_s=0.03)
    loop = ClosedLoop(get_scenario("paper001_stopping"), PIDController())
    loop.reset(seed=0)
    with pytest.raises(ValueError, match="non-finite"):
        loop.step(np.array([math.nan]))


def test_tunable_param_unit_mapping_roundtrip():
    p = TunableParam("w", 1e-3, 1e3, 1.0, log=True)
    for a in (-1.0, -0.3, 0.0, 0.7, 1.0):
        assert p.to_unit(p.from_unit(a)) == pytest.approx(a)
    assert p.from_unit(0.0) == pytest.approx(1.0)  # geometric mid-point
    assert p.from_unit(5.0) == pytest.approx(1e3)  # clipped


def test_metrics_on_a_hand_made_run():
    t = np.arange(0, 10.0, 1.0)
    df = pd.DataFrame(
        {
            "t_s": t,
            "s_m": t * 10,
            "v_mps": np.full(10, 10.0),
            "a_mps2": np.zeros(10),
            "v_ref_mps": np.full(10, 11.0),
            "s_ref_m": t * 10 + 2,
            "v_limit_mps": np.full(10, 10.5),
            "u_cmd_N": np.r_[np.zeros(5), np.ones(5) * 100.0],
            "u_N": np.zeros(10),
            "work_traction_J": np.linspace(0, 3.6e6, 10),
            "work_brake_J": np.zeros(10),
        }
    )
    m = episode_metrics(df, dt_s=1.0, s_stop_m=92.0, scheduled_time_s=8.0, traction_efficiency=0.9)
    assert m["E_v_mps"] == pytest.approx(1.0)
    assert m["E_x_m"] == pytest.approx(2.0)
    assert m["stop_error_m"] == pytest.approx(-2.0)
    assert m["time_error_s"] == pytest.approx(1.0)
    assert m["ITAE_m_s"] == pytest.approx(t.sum())
    assert m["command_switches"] == 1
    assert m["energy_kWh"] == pytest.approx(1 / 0.9)
    assert m["E_u_N2s"] == pytest.approx(5 * 100.0**2)
    assert m["max_overspeed_mps"] == 0.0


def test_cli_list_and_simulate(tmp_path, capsys):
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    assert (
        "paper001_stopping" in out
        and "CN_Beijing_Subway" in out
        and "CH_Stadelhofen_Altstetten" in out
    )
    assert (
        main(
            [
                "simulate",
                "--scenario",
                "paper001_stopping",
                "--controller",
                "pid",
                "--out",
                str(tmp_path),
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert "stop_error_m" in out
    assert (tmp_path / "paper001_stopping_pid.png").stat().st_size > 10_000
    assert main(["simulate", "--scenario", "nope"]) == 2
    assert "unknown scenario" in capsys.readouterr().err
    assert main(["simulate", "--param", "kp=abc"]) == 2
