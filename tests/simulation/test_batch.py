"""The lockstep path equals the single-member path member by member, bit for bit.

Batched plant (paper 001 with dead time and disturbances, 004, Yizhuang), batched
controllers (PID on 001, DMC and Fuzzy-PID on 004, DMC on 004 with effort tables, DMC on
Yizhuang) in the batched runner against :class:`ClosedLoop`, and
:func:`evaluate_env_params_batch` against :func:`evaluate_env_params` on the env ids.
Horizons are short (a step cap).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from simulation.test_evaluation import _equal_tables

import train_envs  # noqa: F401 - registers the ids
from train_envs import _jit
from train_envs.controllers import make_controller
from train_envs.controllers.batch import BatchFuzzyPID, BatchPID
from train_envs.controllers.dmc.batch import BatchDMC
from train_envs.effort import EffortCurve
from train_envs.envs.batch import evaluate_env_params_batch, supports_batch
from train_envs.envs.evaluation import evaluate_env_params
from train_envs.plants.batch import BATCH_ACCEL, BATCH_CAR_STEP, BatchSingleCar
from train_envs.scenarios import DisturbanceSpec, build_plant, get_scenario
from train_envs.simulation import ClosedLoop, run_to_end
from train_envs.simulation.batch import STEP_END, SUPERVISE, BatchLoop
from train_envs.simulation.members import MemberControllers

STEPS = 150  # control steps of the closed-loop comparisons


def _tabulated_004():
    """Paper 004's run on a train with traction and braking effort tables (the
    envelope's table terms in the batched law and the plant)."""
    sc = get_scenario("paper004_urban")
    traction = EffortCurve.from_pairs([(0.0, 240.0), (40.0, 230.0), (60.0, 170.0), (90.0, 110.0)])
    brake = EffortCurve.from_pairs([(0.0, 150.0), (20.0, 235.0), (70.0, 200.0), (90.0, 120.0)])
    train = dataclasses.replace(sc.train, traction_curve=traction, brake_curve=brake)
    return sc.with_overrides(train=train)


def _scenario(name):
    return _tabulated_004() if name == "paper004_tabulated" else get_scenario(name)


def _disturbed_001():
    sc = get_scenario("paper001_stopping")
    dist = DisturbanceSpec(wind="harmonic", random_bound_mps2=0.02, mass_factor_range=(0.95, 1.05))
    return sc.with_overrides(disturbance=dist)


@pytest.mark.parametrize("compiled", [True, False])
@pytest.mark.parametrize("name", ["paper001_disturbed", "paper004_urban", "yizhuang"])
def test_batch_plant_equals_single_plants(name, compiled):
    if compiled and not _jit.enabled():
        pytest.skip("numba disabled")
    sc = _disturbed_001() if name == "paper001_disturbed" else get_scenario(name)
    B = 4
    refs = [build_plant(sc, np.random.default_rng(s)) for s in range(B)]
    bp = BatchSingleCar([build_plant(sc, np.random.default_rng(s)) for s in range(B)])
    bp._kern = _jit.implementation(BATCH_CAR_STEP, compiled_twin=compiled)
    bp._accel = _jit.implementation(BATCH_ACCEL, compiled_twin=compiled)
    rng = np.random.default_rng(0)
    for k in range(120):
        u = rng.uniform(-1.0, 1.0, B) * 4e5 * (1.0 if k < 60 else -1.0)
        act = rng.uniform(size=B) > 0.2
        for b in np.flatnonzero(act):
            refs[b].step(float(u[b]), sc.dt_ctrl_s)
        bp.step(u, sc.dt_ctrl_s, act)
        acc = bp.accel()
        for b, p in enumerate(refs):
            assert (bp.t[b], bp.s[b], bp.v[b], acc[b]) == p._lead_state()
            assert (bp.work_traction_J[b], bp.work_brake_J[b]) == (
                p.work_traction_J,
                p.work_brake_J,
            )
            assert bp.force[b] == p.force_total and bool(bp.stopped[b]) == p.stopped
            if act[b]:
                assert bool(bp.saturated[b]) == p.saturated
    assert len({p.train.mass_kg for p in refs}) == B or name != "paper001_disturbed"


def test_batch_plant_rejects_a_multi_car_plant():
    sc = get_scenario("paper003_cruise")
    with pytest.raises(ValueError, match="single-car"):
        BatchSingleCar([build_plant(sc, np.random.default_rng(0))])


def _members(ctrl_name, sc, params_list, **ctrl_kw):
    ctrls = []
    for p in params_list:
        c = make_controller(ctrl_name, sc, **ctrl_kw)
        c.set_params(**p)
        ctrls.append(c)
    return ctrls


def _single_arrays(sc, ctrl, seed):
    loop = ClosedLoop(sc, ctrl)
    loop.reset(seed=seed)
    run_to_end(loop, STEPS)
    return loop.arrays(), loop.metrics()


def _assert_members_equal(loop: BatchLoop, singles) -> None:
    """Every member's columns and metrics equal its single closed loop's, bit for bit."""
    for b, (arrays, metrics) in enumerate(singles):
        got = loop.arrays(b)
        assert set(got) == set(arrays)
        for name, col in arrays.items():
            if name != "solve_time_s":  # (a wall-clock time)
                assert np.array_equal(got[name], col, equal_nan=True), (b, name)
        assert loop.metrics(b) == metrics


CASES = [
    ("pid", "paper001_stopping", [{}, {"kp": 2.0, "ki": 0.3, "kd": 0.5}, {"kp": 0.05}]),
    # a time-indexed stop: the PIDs integrate in every step (the derived defaults)
    ("pid", "yizhuang", [{}, {"kp": 0.6, "ki": 0.09}]),
    ("fuzzy_pid", "paper004_urban", [{}, {"kp0": 3.0, "ke": 30.0, "dkp": 2.0}, {"kd0": 1.5}]),
    (
        "dmc",
        "paper004_urban",
        [{}, {"k_e": 300.0, "k_h": 0.3, "alpha_trend": -5.0}, {"alpha_max": 0.0, "h0": 0.1}],
    ),
    ("dmc", "yizhuang", [{}, {"alpha_min": 0.9, "alpha_max": 0.95, "k_ec": 500.0}]),
    ("dmc", "paper004_tabulated", [{}, {"k_e": 300.0, "alpha_min": 0.6}]),
]


@pytest.mark.parametrize("compiled", [True, False])
@pytest.mark.parametrize(("ctrl_name", "scenario", "params_list"), CASES)
def test_batch_loop_equals_closed_loops(ctrl_name, scenario, params_list, compiled):
    if compiled and not _jit.enabled():
        pytest.skip("numba disabled")
    sc = _scenario(scenario)
    kw = {"alpha_order": "clip"} if ctrl_name == "dmc" else {}
    seeds = [0, 5, 0, 5][: len(params_list)]
    singles = [
        _single_arrays(sc, c, s)
        for c, s in zip(_members(ctrl_name, sc, params_list, **kw), seeds, strict=True)
    ]
    ref = make_controller(ctrl_name, sc, **kw)
    ref.reset(sc.control_context())
    full = [c.get_params() for c in _members(ctrl_name, sc, params_list, **kw)]
    pool = _members(ctrl_name, sc, [{}] * len(params_list), **kw)
    qp_steps = []
    if ctrl_name == "dmc":
        # the DMC's stages: compiled twins or numpy references
        ctrl = BatchDMC(ref, full, pool.__getitem__, compiled_twin=compiled)
        orig = ctrl._qp_step
        ctrl._qp_step = lambda b, *a: (qp_steps.append(b), orig(b, *a))[1]
    else:
        ctrl = (BatchPID if ctrl_name == "pid" else BatchFuzzyPID)(ref, full)
    plants = [build_plant(sc, np.random.default_rng(s)) for s in seeds]
    loop = BatchLoop(sc, plants, ctrl, max_steps=STEPS)
    # the runner's end of step (supervision, record, plant step, checks) and the plant's
    # read-out: compiled twins or numpy references
    loop._end = _jit.implementation(STEP_END, compiled_twin=compiled)
    loop.plant._accel = _jit.implementation(BATCH_ACCEL, compiled_twin=compiled)
    loop.run()
    _assert_members_equal(loop, singles)
    if ctrl_name == "dmc" and scenario == "paper004_urban":
        assert qp_steps, "the QP path of a member was not exercised"


@pytest.mark.parametrize("ctrl_name", ["dmc", "fuzzy_pid", "pid"])
def test_a_members_new_parameters_give_the_state_of_a_batch_built_with_them(ctrl_name):
    """``set_params(b, ...)`` updates member ``b``'s derived values alone; they equal
    those of a batch built with every member's parameters (bit for bit)."""
    sc = _scenario("paper004_urban")
    kw = {"alpha_order": "clip"} if ctrl_name == "dmc" else {}
    ref = make_controller(ctrl_name, sc, **kw)
    ref.reset(sc.control_context())
    specs = ref.tunable_params()
    rng = np.random.default_rng(7)

    def draw() -> dict[str, float]:
        return {
            q.name: q.from_unit(float(u))
            for q, u in zip(specs, rng.uniform(-1, 1, len(specs)), strict=True)
        }

    params = [draw() for _ in range(5)]

    def make(ps):
        if ctrl_name == "dmc":
            pool = _members(ctrl_name, sc, [{}] * len(ps), **kw)
            return BatchDMC(ref, ps, pool.__getitem__)
        return (BatchPID if ctrl_name == "pid" else BatchFuzzyPID)(ref, ps)

    batch = make(params)
    for _ in range(20):
        b = int(rng.integers(len(params)))
        params[b] = draw()
        batch.set_params(b, params[b])
    fresh = make(params)
    names = {"dmc": ("par", "a_lo"), "fuzzy_pid": ("scales",), "pid": ()}[ctrl_name]
    for key in fresh.p:
        assert batch.p[key].tobytes() == fresh.p[key].tobytes(), key
    for name in names:
        got, want = getattr(batch, name), getattr(fresh, name)
        assert np.asarray(got).tobytes() == np.asarray(want).tobytes(), name


@pytest.mark.parametrize(
    ("env_id", "params_list"),
    [
        ("TrainEnvs/Urban004-v0", [{}, {"k_h": 0.3, "k_e": 200.0}, {"alpha_min": 0.9}]),
        ("TrainEnvs/Stopping001PID-v0", [{"kp": 3.0}, {}]),
        ("TrainEnvs/Urban004FuzzyPID-v0", [{"dki": 0.5}, {"kp0": 0.02}]),
        # each member on its own controller (no array law); Yizhuang draws a section
        # per seed: one lockstep group per section
        ("TrainEnvs/Stopping001-v0", [{"beta": 8.0}, {}, {"r_du": 0.5}]),
        ("TrainEnvs/Yizhuang-v0", [{}, {"q_v": 1e3, "r_du": 0.01}]),
    ],
)
def test_evaluate_env_params_batch_equals_the_single_evaluations(env_id, params_list):
    cfg = {"max_episode_steps": 30}
    seeds = [0, 2]
    assert supports_batch(env_id, cfg)
    got = evaluate_env_params_batch(env_id, params_list, seeds, config=cfg)
    assert len(got) == len(params_list)
    for p, table in zip(params_list, got, strict=True):
        exp = evaluate_env_params(env_id, p, seeds=seeds, config=cfg, label="tuner", reuse_env=True)
        _equal_tables(table, exp)


def test_a_config_without_the_batched_path_runs_the_single_evaluations():
    env_id = "TrainEnvs/Stopping001PID-v0"
    cfg = {"max_episode_steps": 20, "supervision": {"end_on_violation": True}}
    assert not supports_batch(env_id, cfg)
    got = evaluate_env_params_batch(env_id, [{}, {"kp": 0.1}], [1], config=cfg)
    for p, table in zip([{}, {"kp": 0.1}], got, strict=True):
        exp = evaluate_env_params(env_id, p, seeds=[1], config=cfg, label="tuner", reuse_env=True)
        _equal_tables(table, exp)


def test_invalid_parameters_raise_as_the_single_evaluation_does():
    env_id = "TrainEnvs/Stopping001PID-v0"
    with pytest.raises(ValueError, match="kp"):
        evaluate_env_params(env_id, {"kp": -1.0}, seeds=[0], config={"max_episode_steps": 2})
    with pytest.raises(ValueError, match="kp"):
        evaluate_env_params_batch(env_id, [{}, {"kp": -1.0}], [0], {"max_episode_steps": 2})


@pytest.mark.skipif(not _jit.enabled(), reason="numba disabled")
def test_supervision_twin_equals_its_reference_through_brake_starts_and_holds():
    rng = np.random.default_rng(4)
    pos, val = np.array([0.0, 300.0, 800.0]), np.array([12.0, 20.0, 8.0])
    B = 64
    ix = np.sort(rng.choice(B, 40, replace=False))
    state = {c: (np.zeros(B, dtype=bool), np.zeros(B, dtype=np.int64)) for c in (True, False)}
    for step in range(30):
        s = rng.uniform(-50.0, 1200.0, ix.size)
        v = rng.uniform(0.0, 25.0, ix.size)
        sp = np.array([1.0 if step % 7 else 0.0, 0.5, 1.0 if step % 2 else 0.0, 1000.0])
        out = {}
        for compiled in (True, False):
            fn = _jit.implementation(SUPERVISE, compiled_twin=compiled)
            o = [np.empty(ix.size), np.empty(ix.size, dtype=bool), np.empty(ix.size),
                 np.empty(ix.size)]  # fmt: skip
            fn(ix, s, v, pos, val, *state[compiled], sp, *o)
            out[compiled] = o
        for a, b in zip(out[True], out[False], strict=True):
            assert np.array_equal(a, b)
        assert all(np.array_equal(a, b) for a, b in zip(*state.values(), strict=True))
    assert state[True][1].sum() > 0 and state[True][0].any()


#: controllers without an array law, each member on its own (single-car scenarios)
MEMBER_CASES = [
    ("mpc", "paper001_stopping", [{}, {"q_s": 2.0, "r_du": 0.05}, {"q_v": 500.0}]),
    ("rsmpc", "paper001_stopping", [{}, {"beta": 8.0, "r_du": 0.5}]),
    ("rmpc", "paper001_stopping", [{"r_du": 1.0}, {}]),
    ("mpc", "yizhuang", [{}, {"q_v": 1e3, "r_du": 0.01}]),
    ("afsmc", "paper004_urban", [{}, {}]),
]


@pytest.mark.parametrize(("ctrl_name", "scenario", "params_list"), MEMBER_CASES)
def test_member_controllers_in_the_batch_loop_equal_closed_loops(ctrl_name, scenario, params_list):
    sc = get_scenario(scenario)
    seeds = [0, 5, 0][: len(params_list)]
    singles = [
        _single_arrays(sc, c, s)
        for c, s in zip(_members(ctrl_name, sc, params_list), seeds, strict=True)
    ]
    ctrls = _members(ctrl_name, sc, params_list)
    for c in ctrls:
        c.reset(sc.control_context())
    plants = [build_plant(sc, np.random.default_rng(s)) for s in seeds]
    loop = BatchLoop(sc, plants, MemberControllers(ctrls), max_steps=STEPS)
    loop.run()
    _assert_members_equal(loop, singles)
