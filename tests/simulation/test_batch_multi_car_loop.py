"""The lockstep runner on multi-car members equals the single closed loop, bit for bit.

:class:`BatchLoop` on :class:`~train_envs.plants.batch_multi_car.BatchMultiCar` members,
each on its own controller (:class:`MemberControllers`: the per-car-input SEMPC,
adaptive MPC and fuzzy LMI MPC, and a whole-train-input MPC on a multi-car train),
against :class:`ClosedLoop` (every recorded column, the final row, the metrics), and
:func:`evaluate_env_params_batch` against :func:`evaluate_env_params` on the multi-car
env ids. Short horizons (a step cap, a shortened end time) except one whole stopping
episode.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from simulation.test_evaluation import _equal_tables

import train_envs  # noqa: F401 - registers the ids
from train_envs.controllers import make_controller
from train_envs.envs.batch import evaluate_env_params_batch, supports_batch
from train_envs.envs.evaluation import evaluate_env_params
from train_envs.plants.batch_multi_car import BatchMultiCar
from train_envs.scenarios import build_plant, get_scenario
from train_envs.simulation import ClosedLoop, run_to_end
from train_envs.simulation.batch import BatchLoop
from train_envs.simulation.members import MemberControllers


def _controllers(name, sc, params_list):
    out = []
    for p in params_list:
        c = make_controller(name, sc)
        c.set_params(**p)
        out.append(c)
    return out


def _single(sc, ctrl, seed, steps):
    loop = ClosedLoop(sc, ctrl)
    loop.reset(seed=seed)
    run_to_end(loop, steps)
    return loop.arrays(), loop.metrics()


def _batch_loop(name, sc, params_list, seeds, steps):
    ctrls = _controllers(name, sc, params_list)
    for c in ctrls:
        c.reset(sc.control_context())
    plants = [build_plant(sc, np.random.default_rng(s)) for s in seeds]
    return BatchLoop(sc, plants, MemberControllers(ctrls), max_steps=steps)


def _assert_members_equal(loop, singles):
    for b, (arrays, metrics) in enumerate(singles):
        got = loop.arrays(b)
        assert list(got) == list(arrays)  # (the same columns in the same order)
        for name, col in arrays.items():
            if name != "solve_time_s":  # (a wall-clock time)
                assert np.array_equal(got[name], col, equal_nan=True), (b, name)
        assert loop.metrics(b) == metrics


def _tight_couplers(sc):
    """``sc`` with coupler limits the run exceeds (the coupler_excess column nonzero)."""
    cp = dataclasses.replace(sc.train.coupler, max_force_N=2e4, max_deformation_m=0.005)
    return sc.with_overrides(train=dataclasses.replace(sc.train, coupler=cp))


def _scenario(case):
    if case == "paper000_whole":  # a whole stopping episode (terminated at rest)
        return get_scenario("paper000_single_section")
    if case == "paper002_short":  # a cruise ended by its (shortened) end time
        return get_scenario("paper002_cruise").with_overrides(t_max_s=30.0)
    if case == "paper003_atp":  # above the limit + margin: the ATP brakes, per car
        return _tight_couplers(get_scenario("paper003_cruise").with_overrides(v0_mps=72.0))
    if case == "paper000_total":  # one whole-train input on a multi-car train, the ATP on
        sc = get_scenario("paper000_single_section")
        return sc.with_overrides(input_mode="total", v0_mps=30.0)
    raise KeyError(case)


CASES = [
    ("sempc", "paper000_whole", [{}, {"q_v": 50.0}, {"r_du": 0.1}], None),
    ("adaptive_mpc", "paper002_short", [{}, {"lam": 0.03}, {"q_v": 3.0, "r_u": 1.0}], None),
    ("fuzzy_mpc", "paper003_atp", [{}, {"q_v": 2.0}, {"c1": 2.6, "c2": 2.9}], 100),
    ("mpc", "paper000_total", [{}, {"q_v": 500.0}, {"r_du": 0.5}], 120),
]


@pytest.mark.parametrize(("ctrl_name", "case", "params_list", "steps"), CASES)
def test_member_controllers_on_multi_car_members_equal_closed_loops(
    ctrl_name, case, params_list, steps
):
    sc = _scenario(case)
    seeds = [0, 1, 2]
    singles = [
        _single(sc, c, s, steps)
        for c, s in zip(_controllers(ctrl_name, sc, params_list), seeds, strict=True)
    ]
    loop = _batch_loop(ctrl_name, sc, params_list, seeds, steps)
    assert isinstance(loop.plant, BatchMultiCar)
    loop.run()
    _assert_members_equal(loop, singles)
    if case in ("paper003_atp", "paper000_total"):  # (what the cases are there for)
        assert (loop.atp_interventions > 0).all()
    if case == "paper003_atp":
        assert all(np.nanmax(loop.arrays(b)["coupler_excess"]) > 0.0 for b in range(3))
    if case == "paper000_whole":
        assert loop.terminated.all()


def test_multi_car_members_at_different_steps_equal_closed_loops():
    """Members stepped under random masks (at different steps of their episodes, so the
    references are read per member) equal their single loops run as far."""
    sc = _tight_couplers(get_scenario("paper003_cruise"))
    params_list, seeds = [{}, {"q_v": 5.0}, {"r_e": 0.1}], [3, 4, 5]
    loop = _batch_loop("fuzzy_mpc", sc, params_list, seeds, 60)
    rng = np.random.default_rng(1)
    while not (loop.k >= 60).all():
        loop.step(rng.uniform(size=3) < 0.6)
    loop.step(np.array([True, False, True]))  # (a capped member is not stepped)
    ctrls = _controllers("fuzzy_mpc", sc, params_list)
    singles = [_single(sc, c, s, 60) for c, s in zip(ctrls, seeds, strict=True)]
    _assert_members_equal(loop, singles)


MULTI_CAR_IDS = [
    ("TrainEnvs/Section000-v0", [{}, {"q_v": 50.0, "r_du": 1e-3}, {"q_s": 3.0, "q_dx": 1e5}]),
    ("TrainEnvs/Cruise002-v0", [{}, {"lam": 0.03, "r_u": 1.0}, {"q_v": 2.0, "q_xi": 10.0}]),
    ("TrainEnvs/Cruise003-v0", [{}, {"c1": 2.6, "c2": 2.9}, {"q_v": 2.0, "r_e": 0.1}]),
]


@pytest.mark.parametrize(("env_id", "params_list"), MULTI_CAR_IDS)
def test_evaluate_env_params_batch_equals_the_single_evaluations_on_multi_car_ids(
    env_id, params_list
):
    cfg = {"max_episode_steps": 12}
    seeds = [0, 3]
    assert supports_batch(env_id, cfg)
    # members on their own controllers: the tuner's default stays the process pool
    assert not supports_batch(env_id, cfg, array_law=True)
    got = evaluate_env_params_batch(env_id, params_list, seeds, config=cfg)
    assert len(got) == len(params_list)
    for p, table in zip(params_list, got, strict=True):
        exp = evaluate_env_params(env_id, p, seeds=seeds, config=cfg, label="tuner", reuse_env=True)
        _equal_tables(table, exp)
    # (the parameters differ in effect: not three copies of one run)
    assert len({float(t["ITAE_m_s"].iloc[0]) for t in got}) == len(params_list)


def test_the_tuner_keeps_the_process_pool_for_the_multi_car_ids():
    from tuners.backends import default_backend
    from tuners.problem import EnvTuningProblem

    assert default_backend(EnvTuningProblem("TrainEnvs/Cruise003-v0")) == "processes"
