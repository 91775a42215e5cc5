"""Config merge rules and bad env inputs: every one a one-line ValueError naming the
field (the cases of issue 18's hostile-user run)."""

from __future__ import annotations

import math

import gymnasium as gym
import pytest

import train_envs  # noqa: F401  (registers the ids)
from train_envs.envs import EnvConfig, params_to_action
from train_envs.envs.config import merge

PID_ID = "TrainEnvs/Stopping001PID-v0"


def test_user_mappings_merge_over_the_id_defaults():
    # Urban004 fixes alpha_order = "clip": a user's other controller argument keeps it
    env = gym.make("TrainEnvs/Urban004-v0", config={"controller_params": {"k_e": 0.5}})
    assert env.unwrapped.config["controller_params"] == {"alpha_order": "clip", "k_e": 0.5}
    # a partial real_line keeps the id's track and train
    env = gym.make("TrainEnvs/Yizhuang-v0", config={"real_line": {"sections": [(1, 2)]}})
    rl = env.unwrapped.config["real_line"]
    assert rl["track"] == "CN_Songjiazhuang_Yizhuang" and rl["sections"] == [(1, 2)]
    env.reset(seed=0)
    assert env.unwrapped.scenario.extra["from_stop"] == 1
    # a value replaces; nested mappings merge key by key
    assert merge({"a": {"x": 1, "y": 2}, "b": 1}, {"a": {"y": 3}, "b": None}) == {
        "a": {"x": 1, "y": 3},
        "b": None,
    }
    cfg = EnvConfig.resolve({"reward_weights": {"jerk": 0.5}})
    assert cfg.reward.weights["jerk"] == 0.5 and cfg.reward.weights["tracking"] == 1.0


@pytest.mark.parametrize(
    "config, match",
    [
        ({"reward_weights": {"tracking": math.nan}}, r"reward\.weights.*finite"),
        ({"reward_weights": {"stop": math.inf}}, r"reward\.weights.*finite"),
        ({"preview_m": math.nan}, r"preview_m.*finite"),
        ({"delta_scale": math.nan}, r"delta_scale.*finite"),
        ({"decision_interval": 2.7}, r"decision_interval.*integer"),
        ({"max_episode_steps": 0}, r"max_episode_steps.*integer >= 1"),
        ({"scenario_overrides": {"u0": 1e12}}, r"scenario_overrides.*u0.*must lie in"),
        ({"scenario_overrides": {"overrun_m": -100.0}}, r"scenario_overrides.*overrun_m"),
        ({"scenario_overrides": {"n_cars": 3}}, r"scenario_overrides.*n_cars.*1 cars"),
        ({"scenario_overrides": {"v0_mps": "fast"}}, r"scenario_overrides.*v0_mps.*number"),
        ({"scenario_overrides": {"t_max_s": math.inf}}, r"scenario_overrides.*t_max_s"),
        ({"scenario_overrides": {"s0_m": 1e6}}, r"scenario_overrides.*s0_m"),
        ({"scenario_overrides": {"speed": 1}}, r"unknown scenario field.*speed"),
        ({"disturbance": {"w0_mps2": math.nan}}, r"disturbance.*w0_mps2.*finite"),
        ({"disturbance": {"mass_factor_range": 1.2}}, r"disturbance.*mass_factor_range.*pair"),
        ({"controller_params": {"kp": "x"}}, r"config controller \(pid"),
        ({"real_line": {"track": "CN_Songjiazhuang_Yizhuang", "train": 5}}, r"train must be"),
        (
            {"real_line": {"track": "a", "train": "b", "time_supplement": math.nan}},
            r"time_supplement.*\[0, 1\]",
        ),
        ({"real_line": {"track": "a", "train": "b", "sections": [(2, 1)]}}, r"sections"),
        ({"supervision": {"end_on_violation": 1}}, r"end_on_violation must be true or false"),
    ],
)
def test_bad_inputs_raise_one_line_errors_naming_the_field(config, match):
    with pytest.raises(ValueError, match=match) as err:
        gym.make(PID_ID, config=config)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("jerk", [0.0, -1.0, math.nan])
def test_a_zero_or_invalid_mpc_jerk_limit_is_refused(jerk):
    # jerk_max = 0 would pin the command at its start value: the train never moves
    with pytest.raises(ValueError, match=r"jerk_max must") as err:
        env = gym.make("TrainEnvs/Yizhuang-v0", config={"controller_params": {"jerk_max": jerk}})
        env.reset(seed=0)
    assert "\n" not in str(err.value)


def test_real_line_sections_beyond_the_last_stop_are_refused_at_make():
    with pytest.raises(ValueError, match=r"real_line.*sections \[\(0, 99\)\]"):
        gym.make("TrainEnvs/Yizhuang-v0", config={"real_line": {"sections": [(0, 99)]}})


def test_action_bounds_narrow_a_parameter_range():
    env = gym.make(PID_ID, config={"action_bounds": {"kp": (0.5, 2.0)}}).unwrapped
    spec = {p.name: p for p in env.param_specs}["kp"]
    assert (spec.low, spec.high) == (0.5, 2.0)
    env.reset(seed=0)
    i = [p.name for p in env.param_specs].index("kp")
    for a, want in ((-1.0, 0.5), (1.0, 2.0)):
        action = params_to_action(env, {})
        action[i] = a
        _, _, _, _, info = env.step(action)
        assert info["params"]["kp"] == pytest.approx(want)


@pytest.mark.parametrize(
    "bounds, match",
    [
        ({"kp": (2.0, 1.0)}, r"action_bounds.*low < high"),
        ({"kp": (math.nan, 1.0)}, r"action_bounds.*finite"),
        ({"kp": (0.0, 1e9)}, r"inside the controller's range"),
        ({"zz": (0.0, 1.0)}, r"no tunable parameter 'zz'"),
    ],
)
def test_bad_action_bounds_are_refused(bounds, match):
    with pytest.raises(ValueError, match=match):
        gym.make(PID_ID, config={"action_bounds": bounds})


def test_a_policy_runs_in_the_env_config_it_was_trained_in():
    from types import SimpleNamespace

    from agents.evaluation import EnvCase, PolicyDriver

    trained = {"action_mode": "delta", "disturbance": {"random_bound_mps2": 0.05}}
    driver = PolicyDriver("unused", name="p")
    driver._policy = SimpleNamespace(config={"env_id": PID_ID, "env_config": trained})
    case = driver.trained_case(EnvCase(PID_ID, {"disturbance": {"random_hold_s": 2.0}}))
    assert case.config == {
        "action_mode": "delta",
        "disturbance": {"random_bound_mps2": 0.05, "random_hold_s": 2.0},
    }
    cfg = case.make().unwrapped.settings
    assert cfg.action.mode == "delta" and cfg.scenario.disturbance["random_bound_mps2"] == 0.05
    # another id: the case as given
    other = EnvCase("TrainEnvs/Urban004-v0")
    assert driver.trained_case(other) is other
