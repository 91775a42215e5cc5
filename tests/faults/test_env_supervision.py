"""Supervised runs: the ATP brake, the per-step safety cost and its episode sum, ending
an episode at a violation, and clear errors for steps out of order."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.error import ResetNeeded

import train_envs  # noqa: F401  (registers the ids)
from train_envs.controllers import make_controller
from train_envs.envs import TrainTuningEnv, params_to_action
from train_envs.scenarios import get_scenario
from train_envs.simulation import ClosedLoop, Supervision
from train_envs.simulation.supervision import DEFAULT_MARGIN_MPS

PID_ID = "TrainEnvs/Stopping001PID-v0"


def _full_traction_run(supervision: Supervision, seconds: float = 30.0):
    """Paper 001's train (limit 20 m/s, start 20 m/s) under full traction."""
    sc = get_scenario("paper001_stopping")
    loop = ClosedLoop(sc, make_controller("pid", sc), supervision)
    loop.reset(seed=0)
    u = np.array([sc.train.max_traction_N(0.0)])
    while not loop.done and loop.plant.t < seconds:
        loop.step(u)
    return sc, loop, loop.dataframe()


def test_atp_brakes_above_the_margin_and_releases_at_the_limit():
    sc, loop, df = _full_traction_run(Supervision())
    lim, v = df["v_limit_mps"].to_numpy(), df["v_mps"].to_numpy()
    atp = df["atp_brake"].to_numpy()[:-1]
    v, lim = v[:-1], lim[:-1]
    # trips exactly where the speed first exceeds limit + margin ...
    first = int(np.argmax(v > lim + DEFAULT_MARGIN_MPS))
    assert atp[:first].sum() == 0 and atp[first] == 1
    # ... commands the full braking envelope while it brakes ...
    braking = atp == 1
    expected = -np.array([sc.train.max_brake_N(x) for x in v[braking]])
    np.testing.assert_allclose(df["u_cmd_N"].to_numpy()[:-1][braking], expected, rtol=1e-12)
    # ... and holds only while the speed is above the limit
    assert np.all(v[braking] > lim[braking])
    m = loop.metrics()
    assert m["atp_interventions"] >= 1 and m["atp_brake_time_s"] > 0
    assert m["safety_cost"] > 0


def test_atp_bounds_the_overspeed_that_traction_alone_reaches():
    _, _, on = _full_traction_run(Supervision())
    _, _, off = _full_traction_run(Supervision(atp=False))
    over_on = float(on["overspeed_mps"].max())
    over_off = float(off["overspeed_mps"].max())
    assert off["atp_brake"].sum() == 0
    # 1 s dead time + 0.4 s lag: the overshoot past the margin is what 1.07 m/s² adds in
    # about 2 s, far below the unsupervised run's
    assert over_on < DEFAULT_MARGIN_MPS + 2.5 < over_off


def _episode(env, action):
    costs, viol, comps = [], [], []
    done = False
    while not done:
        _, _, term, trunc, info = env.step(action)
        costs.append(info["cost"])
        viol.append(info["objectives"]["violation"])
        comps.append(info["cost_components"])
        done = term or trunc
    return costs, viol, comps, info


@pytest.mark.parametrize("env_id", [PID_ID, "TrainEnvs/Section000-v0"])
def test_step_costs_sum_to_the_episode_safety_cost(env_id):
    # the golden non-default action: an overrun of the stop window (Stopping001PID) or
    # an overspeed with an ATP intervention and a 50 m overrun (Section000)
    env = gym.make(env_id)
    env.reset(seed=0)
    n = env.action_space.shape[0]
    action = np.array([(0.35, -0.6, 0.8, -0.2, 0.5, -0.9)[i % 6] for i in range(n)])
    costs, viol, comps, info = _episode(env, action)
    m = info["episode_metrics"]
    assert all(c >= 0 and math.isfinite(c) for c in costs)
    assert sum(costs) == pytest.approx(m["safety_cost"], rel=1e-9)
    assert m["safety_cost"] > 0 and m["overrun_m"] > 0
    for c, v, parts in zip(costs, viol, comps, strict=True):
        assert c == pytest.approx(sum(parts.values()), rel=1e-12, abs=0)
        assert v >= c - 1e-12  # the violation objective contains the safety cost
    if env_id == "TrainEnvs/Section000-v0":
        assert m["atp_interventions"] >= 1


def test_a_safe_episode_costs_nothing():
    env = gym.make(PID_ID)
    env.reset(seed=0)
    costs, _, _, info = _episode(env, params_to_action(env, {}))
    assert costs == [0.0] * len(costs) and info["episode_metrics"]["safety_cost"] == 0.0


def test_end_on_violation_terminates_at_the_first_violation():
    cfg = {"supervision": {"end_on_violation": True}}
    env = gym.make("TrainEnvs/Section000-v0", config=cfg)
    env.reset(seed=0)
    n = env.action_space.shape[0]
    action = np.array([(0.35, -0.6, 0.8, -0.2, 0.5, -0.9)[i % 6] for i in range(n)])
    costs, _, _, info = _episode(env, action)
    assert info["safety_violation"] and costs[-1] > 0
    # it ended in the env step of the first violation (here the ATP trip)
    df = env.unwrapped.loop.dataframe().iloc[:-1]
    first = int(df["atp_brake"].to_numpy().argmax())
    assert df["atp_brake"].iloc[first] == 1 and df["overrun_m"].max() == 0.0
    assert len(df) - first <= env.unwrapped.config["decision_interval"]


def test_step_before_reset_and_after_the_end_raise_reset_needed():
    env = TrainTuningEnv({"controller": "pid", "max_episode_steps": 2})
    with pytest.raises(ResetNeeded, match=r"before reset\(\)"):
        env.step(env.action_space.sample())
    env.reset(seed=0)
    a = params_to_action(env, {})
    env.step(a)
    _, _, term, trunc, _ = env.step(a)
    assert trunc and not term
    with pytest.raises(ResetNeeded, match="episode is over"):
        env.step(a)
    env.reset(seed=1)
    env.step(a)  # a reset makes it usable again


def test_supervision_settings_are_validated():
    for cfg, match in [
        ({"supervision": {"margin_mps": math.nan}}, r"supervision.*margin_mps.*\[0, 20\]"),
        ({"supervision": {"margin_mps": -1.0}}, r"margin_mps"),
        ({"supervision": {"atp": "yes"}}, r"supervision\.atp must be true or false"),
        ({"supervision": {"brake": 1}}, r"unknown config episode\.supervision.*brake"),
    ]:
        with pytest.raises(ValueError, match=match):
            gym.make(PID_ID, config=cfg)
