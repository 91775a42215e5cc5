"""The parameter space and the one evaluation of parameters over seeds."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

import train_envs  # noqa: F401 - registers the ids
from train_envs.controllers.base import TunableParam
from train_envs.controllers.params import ParamSpace
from train_envs.envs.evaluation import evaluate, evaluate_env_params, params_to_action
from train_envs.simulation import Episodes, evaluate_params, seed_list, simulate

PID_ENV = "TrainEnvs/Stopping001PID-v0"
SHORT = {"max_episode_steps": 30}

SPECS = (
    TunableParam("kp", 0.1, 10.0, 1.0, log=True),
    TunableParam("ki", 0.0, 2.0, 0.5),
    TunableParam("q", 1e-3, 1e3, 1.0, log=True),
)


def _equal_tables(a: pd.DataFrame, b: pd.DataFrame) -> None:
    assert list(a.columns) == list(b.columns)
    for c in a.columns:
        if a[c].dtype.kind == "f":
            assert np.array_equal(a[c].to_numpy(), b[c].to_numpy(), equal_nan=True), c
        else:
            assert a[c].tolist() == b[c].tolist(), c


# ---------------------------------------------------------------- ParamSpace
def test_action_encoding_is_the_specs_arithmetic():
    sp = ParamSpace(SPECS)
    rng = np.random.default_rng(0)
    for _ in range(50):
        unit = rng.uniform(-1.2, 1.2, 3).tolist()
        values = sp.decode_action(unit)
        assert values == {p.name: p.from_unit(u) for p, u in zip(SPECS, unit, strict=True)}
        act = sp.encode_action(values, {})
        assert act.dtype == np.float64
        assert act.tolist() == [p.to_unit(values[p.name]) for p in SPECS]


def test_decode_keeps_base_values_exactly():
    sp = ParamSpace(SPECS)
    base = {"kp": 1.0, "ki": 0.3, "q": 7.0}
    base_unit = sp.unit_of(base)
    assert sp.decode_action(base_unit, base_unit, base) == base


def test_tuner_variables():
    sp = ParamSpace(SPECS)
    xl, xu = sp.bounds("native")
    assert xl.tolist() == [-1.0, 0.0, -3.0] and xu.tolist() == [1.0, 2.0, 3.0]
    assert sp.bounds("unit")[0].tolist() == [-1.0] * 3
    assert sp.from_x([0.0, 1.0, 3.0], "native") == {"kp": 1.0, "ki": 1.0, "q": 1e3}
    assert sp.from_x([5.0, 5.0, 5.0], "native") == {"kp": 10.0, "ki": 2.0, "q": 1e3}
    x = sp.to_x({"kp": 2.0}, "native", {"kp": 1.0, "ki": 0.5, "q": 1.0})
    assert x.tolist() == [math.log10(2.0), 0.5, 0.0]
    assert sp.from_x(sp.to_x({"ki": 1.5}, "unit", {"kp": 1, "ki": 0, "q": 1}))["ki"] == (
        pytest.approx(1.5)
    )
    with pytest.raises(ValueError, match="space must be one of"):
        sp.bounds("cube")


def test_validation_names_parameter_and_range():
    sp = ParamSpace(SPECS)
    with pytest.raises(ValueError, match=r"param ki must lie in \[0.0, 2.0\], got 3.0"):
        sp.check({"ki": 3.0})
    with pytest.raises(ValueError, match="not tunable here; allowed"):
        sp.check({"kd": 1.0})
    with pytest.raises(ValueError, match="param q"):
        sp.check({"q": float("nan")})
    with pytest.raises(ValueError, match="unknown parameter"):
        ParamSpace.of(SPECS, ["kp", "kd"])
    assert ParamSpace.of(SPECS, ["q", "kp"]).names == ["q", "kp"]


# ----------------------------------------------------------- evaluate_params
def test_seed_list():
    assert seed_list() == [0]
    assert seed_list(episodes=3) == [0, 1, 2]
    assert seed_list(np.array([4, 2])) == [4, 2]


def test_evaluate_params_equals_simulate():
    frames: dict[int, pd.DataFrame] = {}
    df = evaluate_params(
        "paper001_stopping", {"kp": 2.0}, controller="pid", seeds=[0, 1], frames=frames
    )
    assert df["seed"].tolist() == [0, 1] and df["episode"].tolist() == [0, 1]
    assert sorted(frames) == [0, 1]
    for i, seed in enumerate((0, 1)):
        res = simulate("paper001_stopping", "pid", seed=seed, params={"kp": 2.0})
        for k, v in res.metrics.items():
            assert df.iloc[i][k] == v or (math.isnan(v) and math.isnan(df.iloc[i][k])), k
        pd.testing.assert_frame_equal(frames[seed], res.df)


def test_episodes_source_columns():
    src = Episodes("paper001_stopping", "pid", ids={"env": "x"}, extra={"r": 1.0}, max_steps=20)
    df = evaluate_params(src, seeds=[3])
    assert list(df.columns[:5]) == ["env", "episode", "seed", "scenario", "r"]
    with pytest.raises(ValueError, match="needs a controller"):
        evaluate_params("paper001_stopping")


def test_env_params_equal_the_env_stepped_with_the_action():
    """The runner's evaluation on an env equals stepping the env with the constant
    action whose decode gives the same values (reused env or not)."""
    import gymnasium as gym

    env = gym.make(PID_ENV, config=SHORT)
    sp = ParamSpace(env.unwrapped.param_specs)
    defaults = env.unwrapped.default_params()
    env.close()
    rng = np.random.default_rng(1)
    for p in [{}, sp.from_x(rng.uniform(-1, 1, len(sp))), sp.from_x(rng.uniform(-1, 1, len(sp)))]:
        # the values the env's decode of the action gives
        ran = sp.decode_action(
            sp.encode_action(p, defaults).tolist(), sp.unit_of(defaults), defaults
        )
        for reuse in (False, True):
            a = evaluate(PID_ENV, p, seeds=[0, 2], config=SHORT, reuse_env=reuse)
            b = evaluate_env_params(PID_ENV, ran, seeds=[0, 2], config=SHORT, reuse_env=reuse)
            _equal_tables(
                a.drop(columns=["return", "env_steps", "driver"]), b.drop(columns="driver")
            )


def test_env_params_validation():
    with pytest.raises(ValueError, match="not tunable here"):
        evaluate_env_params(PID_ENV, {"nope": 1.0}, config=SHORT)
    import gymnasium as gym

    env = gym.make(PID_ENV)
    try:
        with pytest.raises(ValueError, match="not tunable here"):
            params_to_action(env, {"nope": 1.0})
    finally:
        env.close()


def test_reused_env_rebuilds_a_controller_that_ran_other_values(monkeypatch):
    """An evaluation with non-default values marks the env, so that the env cache's
    next use rebuilds its controller (TrainTuningEnv.renew_controller)."""
    from train_envs.envs.evaluation import ENV_CACHE, clear_env_cache
    from train_envs.envs.train_env import TrainTuningEnv

    renewed = []
    renew = TrainTuningEnv.renew_controller

    def spy(self):
        renewed.append(renew(self))
        return renewed[-1]

    monkeypatch.setattr(TrainTuningEnv, "renew_controller", spy)
    clear_env_cache()
    evaluate_env_params(PID_ENV, {}, config=SHORT, reuse_env=True)
    evaluate_env_params(PID_ENV, {"kp": 2.0}, config=SHORT, reuse_env=True)
    evaluate_env_params(PID_ENV, {}, config=SHORT, reuse_env=True)
    assert renewed == [False, True]
    assert len(ENV_CACHE) == 1
    clear_env_cache()
