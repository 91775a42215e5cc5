"""``--tuned``: one pair tuned by MOWOA on training seeds, its study reused on a re-run,
the selected parameters evaluated by the benchmark; the env config of a pair."""

from __future__ import annotations

import json

import gymnasium as gym
import optuna
import pytest

from train_envs.benchmark import (
    apply_disturbance,
    benchmark_scenario,
    resolve_disturbance,
    run_benchmark,
)
from tuners.benchmark import BASE_ENV, BUDGETS, Budget, env_config, tuned_params

STOP = "paper001_stopping"
TINY = Budget("tiny", pop=4, iters=1, train_seeds=(1000,))  # paper 001: four objectives


def _trials(out):
    (db,) = (out / "studies").glob("*.db")
    (summary,) = optuna.get_all_study_summaries(f"sqlite:///{db}")
    return summary.n_trials


def test_tuned_pair_is_stored_reused_and_benchmarked(tmp_path):
    params = tuned_params([STOP], ["pid", "adaptive_mpc"], tmp_path, TINY, progress=False)
    assert list(params) == [(STOP, "pid")]  # the unsupported pair is not tuned
    p = params[STOP, "pid"]
    assert isinstance(p, dict) and set(p) >= {"kp", "ki", "kd"}
    n = _trials(tmp_path)
    assert 1 <= n <= TINY.pop
    again = tuned_params([STOP], ["pid"], tmp_path, TINY, progress=False)
    assert again == params and _trials(tmp_path) == n  # reused, nothing evaluated again
    res = run_benchmark(tmp_path, [STOP], ["pid"], [0], params=params, progress=False)
    row = res.table.iloc[0]
    assert row["status"] == "ok" and json.loads(row["parameters"]) == pytest.approx(p)


def test_budgets():
    small, full = BUDGETS["small"], BUDGETS["full"]
    assert small.pop * small.iters < full.pop * full.iters
    assert not set(small.train_seeds) & set(range(5))  # disjoint from benchmark seeds 0-4


@pytest.mark.parametrize("name", ["zurich_1_2", "paper004_urban", "paper000_disturbance_harmonic"])
def test_env_config_gives_the_benchmark_scenario(name):
    """The tuning env runs the scenario the benchmark evaluates, its disturbance included."""
    load = resolve_disturbance("load")
    env = gym.make(BASE_ENV, config={**env_config(name, load), "controller": "pid"})
    try:
        sc = env.unwrapped.scenario
    finally:
        env.close()
    ref = benchmark_scenario(name)
    assert (sc.s_stop_m, sc.scheduled_time_s, sc.t_max_s) == (
        ref.s_stop_m,
        ref.scheduled_time_s,
        ref.t_max_s,
    )
    assert sc.track.length_m == ref.track.length_m and sc.train.name == ref.train.name
    assert sc.disturbance == apply_disturbance(ref, load).disturbance != ref.disturbance
    assert "disturbance" not in env_config(name, resolve_disturbance("none"))
