"""BatchMultiCar: every member equals its single TrainPlant stepped alone, bit for bit.

Members from the papers' multi-car scenarios (000: 6 cars, ideal actuators, per-car
forces, wind, gradient steps; the same with a lagged actuator, dead time and one
whole-train command; 002: 4 cars, Davis variation, aerodynamic drag on the lead car;
003: 8 cars, second-order actuators), with different masses, disturbance seeds, start
positions (gradient segments) and random command sequences that brake to a standstill
and pull away again, some members inactive at each step, one member replaced midway.
"""

from __future__ import annotations

import copy

import numpy as np
import pytest

from train_envs.plants import ActuatorParams, DavisVariation, TrainPlant
from train_envs.plants.batch_multi_car import (
    BatchMultiCar,
    _loop_vec,
    batchable_multi,
    batched_matvec_exact,
    row_np_sum,
    why_not_batchable_multi,
)
from train_envs.plants.energy import np_sum
from train_envs.scenarios import DisturbanceSpec, build_plant, get_scenario
from train_envs.trains import get_train

STEPS = 240  # control steps per case: two cycles of traction, braking to a stop, coasting
PHASE = 40


def _bits(x) -> np.ndarray:
    return np.ascontiguousarray(x, dtype=float).reshape(-1).view(np.int64)


def _same(a, b) -> bool:
    """Equal bit for bit (signed zeros included)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return a.shape == b.shape and bool(np.array_equal(_bits(a), _bits(b)))


def _case(name: str):
    """(scenario, start positions, disturbance seeds) of a case."""
    if name == "paper000_wind_masses":
        sc = get_scenario("paper000_disturbance_harmonic")
        dist = DisturbanceSpec(
            wind="harmonic", w0_mps2=0.1, w1_mps2=0.1, random_bound_mps2=0.02,
            mass_factor_range=(0.9, 1.1),
        )  # fmt: skip
        return sc.with_overrides(disturbance=dist), (0.0, 392.0, 893.0, 1247.0, 1696.0)
    if name == "paper000_lag_dead_time_total":
        sc = get_scenario("paper000_disturbance_harmonic")
        return sc.with_overrides(
            disturbance=DisturbanceSpec(wind="constant", w0_mps2=0.2),
            actuator=ActuatorParams(order=1, tau_s=0.4, dead_time_s=0.4),
            input_mode="total",
        ), (0.0, 395.0, 896.0, 1249.0)
    if name == "paper002_davis_variation":
        sc = get_scenario("paper002_cruise")
        dist = DisturbanceSpec(davis_variation=True, mass_factor_range=(0.95, 1.05))
        return sc.with_overrides(disturbance=dist, v0_mps=3.0), (0.0, 100.0, 2000.0)
    if name == "paper003_second_order":
        sc = get_scenario("paper003_cruise")
        dist = DisturbanceSpec(wind="harmonic", w0_mps2=0.05, w1_mps2=0.05)
        return sc.with_overrides(disturbance=dist, v0_mps=5.0), (0.0, 50.0, 500.0, 5000.0)
    raise KeyError(name)


def _plant(sc, s0: float, seed: int) -> TrainPlant:
    return build_plant(sc.with_overrides(s0_m=s0), np.random.default_rng(seed))


def _command(rng, k: int, B: int, n: int, per_car: bool, umax: float, bmax: float):
    """Traction, braking to a standstill, then small forces of either sign (so that held
    members stay held or pull away), per member, with a jitter (per car) that sometimes
    exceeds the envelope."""
    phase = (k // PHASE) % 3
    if phase == 0:
        base = rng.uniform(0.2, 0.8, B) * umax
    elif phase == 1:
        base = -rng.uniform(0.7, 1.0, B) * bmax
    else:
        base = rng.uniform(-0.3, 0.3, B) * umax
    if per_car:
        return base[:, None] / n * rng.uniform(0.5, 1.5, (B, n))
    return base * rng.uniform(0.8, 1.4, B)


def _assert_member(bp: BatchMultiCar, b: int, p: TrainPlant, acc: np.ndarray, what: str):
    t, s, v, a = p._lead_state()
    assert _same([bp.t[b], bp.s[b], bp.v[b], acc[b]], [t, s, v, a]), what
    assert _same(bp.Z[b], p.z), what  # positions, speeds, actuator states
    assert _same(bp.positions[b], p.positions), what
    assert _same(bp.speeds[b], p.speeds), what
    assert _same(bp.forces[b], p.forces) and _same(bp.force[b], p.force_total), what
    assert _same(bp.coupler_forces()[b], p.coupler_forces()), what
    assert _same(bp.coupler_deformations()[b], p.coupler_deformations()), what
    assert _same(bp.work_traction_J[b], p.work_traction_J), what
    assert _same(bp.work_brake_J[b], p.work_brake_J), what
    assert bool(bp.stopped[b]) == p.stopped and bool(bp.saturated[b]) == p.saturated, what
    assert _same(bp.last_command[b], p.last_command), what


CASES = [
    "paper000_wind_masses",
    "paper000_lag_dead_time_total",
    "paper002_davis_variation",
    "paper003_second_order",
]


@pytest.mark.parametrize("name", CASES)
def test_members_equal_their_single_plants_bit_for_bit(name):
    sc, starts = _case(name)
    B = len(starts)
    refs = [_plant(sc, s0, seed) for seed, s0 in enumerate(starts)]
    bp = BatchMultiCar([_plant(sc, s0, seed) for seed, s0 in enumerate(starts)])
    p0 = refs[0]
    n, per_car = p0.n, sc.input_mode == "per_car"
    assert batchable_multi(p0) and bp.stacked_products == all(
        batched_matvec_exact(m) for m in bp._mats
    )
    if sc.disturbance.mass_factor_range[1] > sc.disturbance.mass_factor_range[0]:
        assert not bp.shared_matrices  # each member its own masses: stacked matrices
    umax, bmax = p0.train.max_traction_N(0.0), p0.train.max_brake_N(0.0)
    rng = np.random.default_rng(7)
    stops = restarts = inactive = clipped = 0
    tab = p0.gradient_permil
    seg0 = [np.searchsorted(tab.x, p.positions, side="right") for p in refs]
    for k in range(STEPS):
        if k == STEPS // 2:  # a new episode for member 1: another seed, mass and start
            refs[1] = _plant(sc, starts[-1] + 3.0, 100)
            bp.load(1, _plant(sc, starts[-1] + 3.0, 100))
            seg0[1] = np.searchsorted(tab.x, refs[1].positions, side="right")
        u = _command(rng, k, B, n, per_car, umax, bmax)
        act = rng.uniform(size=B) > 0.25
        before = bp.Z.copy(), bp.t.copy(), bp.work_traction_J.copy()
        for b in np.flatnonzero(act).tolist():
            was = refs[b].stopped
            refs[b].step(u[b], sc.dt_ctrl_s)
            stops += (not was) and refs[b].stopped
            restarts += was and not refs[b].stopped
        bp.step(u, sc.dt_ctrl_s, act)
        clipped += int(bp.saturated[act].sum())
        off = ~act
        inactive += int(off.sum())
        assert _same(bp.Z[off], before[0][off]) and _same(bp.t[off], before[1][off])
        assert _same(bp.work_traction_J[off], before[2][off])
        acc = bp.accel()
        for b, p in enumerate(refs):
            _assert_member(bp, b, p, acc, f"{name} step {k} member {b}")
    acc_g, grad = bp.accel_gradient()
    f_max, q_max = bp.coupler_extremes()
    for b, p in enumerate(refs):
        assert _same(acc_g[b], p._lead_state()[3])
        assert _same(grad[b], p.gradient_permil(p.positions[:1])[0])
        assert _same(bp.mechanical_energy_J()[b], p.mechanical_energy_J())
        assert _same([f_max[b], q_max[b]], list(p._coupler_extremes()))
    # the run went through what it is meant to test
    assert stops >= B and restarts >= 1 and inactive > 0 and clipped > 0, (
        stops,
        restarts,
        inactive,
        clipped,
    )
    if name.startswith("paper000"):  # cars crossed gradient breakpoints
        crossed = [
            not np.array_equal(s, np.searchsorted(tab.x, p.positions, side="right"))
            for s, p in zip(seg0, refs, strict=True)
        ]
        assert sum(crossed) >= 2
    # a member written back into its plant steps on alone as the single plant does
    p = bp.sync_plant(2)
    for k in range(20):
        u = _command(rng, k, B, n, per_car, umax, bmax)[2]
        p.step(u, sc.dt_ctrl_s)
        refs[2].step(u, sc.dt_ctrl_s)
    assert _same(p.z, refs[2].z) and p.stopped == refs[2].stopped
    assert _same(
        [p.work_traction_J, p.work_brake_J], [refs[2].work_traction_J, refs[2].work_brake_J]
    )


def test_stop_inside_a_sub_step_and_hold():
    """Strong braking from a crawl: the lead car's stop falls inside a sub-step (the
    held state at the stop instant, couplers deformed), then the brakes hold."""
    sc, starts = _case("paper003_second_order")
    sc = sc.with_overrides(v0_mps=0.3)
    refs = [_plant(sc, s0, seed) for seed, s0 in enumerate(starts)]
    bp = BatchMultiCar([_plant(sc, s0, seed) for seed, s0 in enumerate(starts)])
    u = np.full((len(starts), refs[0].n), -6e4)
    for _k in range(12):
        for b, p in enumerate(refs):
            p.step(u[b], sc.dt_ctrl_s)
        bp.step(u, sc.dt_ctrl_s)
        acc = bp.accel()
        for b, p in enumerate(refs):
            _assert_member(bp, b, p, acc, f"member {b}")
    assert bp.stopped.all() and not np.all(bp.coupler_deformations() == 0.0)


def test_fallbacks_random_walk_davis_variation_and_per_member_products():
    """Davis deviations by each member's own call (random walk), the linear part as one
    ``M.dot(z)`` per member (the path where the stacked product would not be exact) and
    a gradient table per member."""
    sc = get_scenario("paper002_cruise")
    train = sc.train

    def plant(seed):
        p = TrainPlant(
            train.with_mass_factor(1.0 + 0.02 * seed),
            build_plant(sc, np.random.default_rng(0)).gradient_permil,
            n_cars=train.n_cars,
            dt_sim_s=sc.dt_sim_s,
            davis_variation=DavisVariation(mode="random_walk", period_s=30.0),
            input_mode="per_car",
        )
        p.reset(0.0, 2.0, rng=np.random.default_rng(seed))
        return p

    refs = [plant(s) for s in range(3)]
    bp = BatchMultiCar([copy.deepcopy(p) for p in refs])  # (each with its own table copy)
    assert not bp._dv_arr.any() and len(bp._tab_groups) == 3
    bp._mv = _loop_vec
    rng = np.random.default_rng(5)
    umax, bmax = train.max_traction_N(0.0), train.max_brake_N(0.0)
    for k in range(80):
        u = _command(rng, k + 20, 3, bp.n, True, umax, bmax)
        act = rng.uniform(size=3) > 0.3
        for b in np.flatnonzero(act).tolist():
            refs[b].step(u[b], sc.dt_ctrl_s)
        bp.step(u, sc.dt_ctrl_s, act)
        acc = bp.accel()
        for b, p in enumerate(refs):
            _assert_member(bp, b, p, acc, f"step {k} member {b}")
    assert bp.stopped.any()


def test_row_np_sum_is_numpys_sum():
    rng = np.random.default_rng(0)
    for n in [*range(1, 21), 33, 130]:
        X = rng.normal(size=(6, n)) * 10.0 ** rng.uniform(-3, 6, (6, n))
        got = row_np_sum(X)
        assert _same(got, [np.sum(row) for row in X]), n
        if n <= 128:
            assert _same(got, [np_sum(row.tolist()) for row in X]), n


def test_linear_part_is_the_single_plants_product():
    sc, starts = _case("paper000_wind_masses")
    bp = BatchMultiCar([_plant(sc, s0, seed) for seed, s0 in enumerate(starts)])
    X = np.random.default_rng(1).normal(size=(bp.B, bp.nz)) * 1e3
    for M, name in zip(bp._mats, ("Phi", "Gamma", "P1", "P2", "A"), strict=True):
        x = X[:, : M.shape[2]]
        assert _same(bp._mv(M, x), _loop_vec(M, x)), name
        for b, p in enumerate(bp.plants):
            ref = getattr(p._integ, name) if name != "A" else p.A
            assert _same(bp._mv(M, x)[b], ref.dot(np.ascontiguousarray(x[b]))), name


def test_rejects_what_it_does_not_batch():
    single = build_plant(get_scenario("paper001_stopping"), np.random.default_rng(0))
    assert not batchable_multi(single)
    assert "single-car" in why_not_batchable_multi(single)
    with pytest.raises(ValueError, match="single-car"):
        BatchMultiCar([single])
    train = get_train("paper000_dtype_metro")
    curvy = TrainPlant(train, lambda s: 0.0 * s, n_cars=train.n_cars)
    assert not batchable_multi(curvy) and "callable" in why_not_batchable_multi(curvy)
    sc0, _ = _case("paper000_wind_masses")
    sc2, _ = _case("paper002_davis_variation")
    a, b = _plant(sc0, 0.0, 0), _plant(sc2, 0.0, 0)
    with pytest.raises(ValueError, match="differs"):
        BatchMultiCar([a, b])
    bp = BatchMultiCar([a])
    with pytest.raises(ValueError, match="differs"):
        bp.load(0, b)
    with pytest.raises(ValueError):
        BatchMultiCar([])


def test_bad_commands_raise():
    sc, starts = _case("paper000_lag_dead_time_total")  # whole-train commands
    bp = BatchMultiCar([_plant(sc, s0, seed) for seed, s0 in enumerate(starts)])
    with pytest.raises(ValueError, match="finite"):
        bp.step(np.array([1e4, np.nan, 0.0, 0.0]), sc.dt_ctrl_s)
    with pytest.raises(ValueError, match="one command per member"):
        bp.step(np.zeros(3), sc.dt_ctrl_s)
    with pytest.raises(ValueError, match="per_car"):
        bp.step(np.zeros((4, bp.n)), sc.dt_ctrl_s)
    with pytest.raises(ValueError, match="multiple"):
        bp.step(np.zeros(4), 0.03)
