"""Physics tests of the plants against analytic or independent numerical solutions."""

import math
from dataclasses import replace

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from train_envs.plants import ActuatorParams, PointMassTrain, TrainPlant
from train_envs.trains import CouplerParams, TrainParams, get_train


def _plain_train(**kw) -> TrainParams:
    base = dict(
        name="test",
        mass_kg=400e3,
        davis_a_N=0.0,
        davis_b_Ns_per_m=0.0,
        davis_c_Ns2_per_m2=0.0,
        max_traction_force_N=1e7,
        max_brake_force_N=1e7,
    )
    base.update(kw)
    return TrainParams(**base)


def test_coasting_matches_davis_ode():
    """Coasting on level track: v(t) against an independent RK45 solve, rel. error < 1e-4."""
    tr = _plain_train(
        davis_a_N=4000.0, davis_b_Ns_per_m=60.0, davis_c_Ns2_per_m2=8.0, rotating_mass_factor=0.08
    )
    plant = TrainPlant(tr, None, n_cars=1, dt_sim_s=0.05)
    plant.reset(0.0, 30.0)
    ts, vs, ss = [0.0], [30.0], [0.0]
    for _ in range(100):
        plant.step(0.0, 1.0)
        ts.append(plant.t)
        vs.append(plant.v)
        ss.append(plant.s)
    me = tr.mass_kg * 1.08

    def rhs(t, y):
        v = y[1]
        return [v, -(4000.0 + 60.0 * v + 8.0 * v * v) / me]

    ref = solve_ivp(rhs, (0, 100), [0.0, 30.0], t_eval=ts, rtol=1e-12, atol=1e-12, method="DOP853")
    np.testing.assert_allclose(vs, ref.y[1], rtol=1e-4)
    np.testing.assert_allclose(ss[1:], ref.y[0][1:], rtol=1e-4)
    assert vs[-1] < 28.0  # it really decelerated


def test_constant_braking_stops_at_v2_over_2a():
    tr = _plain_train()
    a, v0 = 0.8, 25.0
    plant = TrainPlant(tr, None, n_cars=1, dt_sim_s=0.01)
    plant.reset(0.0, v0, u0=-tr.mass_kg * a)
    while not plant.stopped:
        plant.step(-tr.mass_kg * a, 0.2)
    expected = v0**2 / (2 * a)
    assert plant.stopped and plant.v == 0.0
    assert abs(plant.s - expected) / expected < 0.005
    assert abs(plant.s - expected) < 1e-3  # in fact far better than 0.5 %


def test_lag_dead_time_step_response_is_fopdt():
    """Force response to a command step = first-order-plus-dead-time response (001 eq. 1)."""
    tr = _plain_train()
    tau, td = 0.4, 1.0
    plant = PointMassTrain(tr, None, tau_s=tau, dead_time_s=td, dt_sim_s=0.01)
    plant.reset(0.0, 30.0, u0=0.0)
    f_cmd = -2e5
    t, f = [], []
    for _ in range(400):
        plant.step(f_cmd, 0.01)
        t.append(plant.t)
        f.append(plant.force_total)
    t = np.array(t)
    # the command issued at t=0 reaches the lag input at T_d
    expected = np.where(t > td, f_cmd * (1 - np.exp(-(t - td) / tau)), 0.0)
    np.testing.assert_allclose(f, expected, atol=1e-6 * abs(f_cmd))


def _two_car(damping=0.0):
    m = 64.8e3
    return _plain_train(
        mass_kg=2 * m,
        n_cars=2,
        coupler=CouplerParams(stiffness_N_per_m=1e7, damping_Ns_per_m=damping),
    )


def test_undamped_coupler_energy_and_frequency_at_control_period():
    """Two cars, k = 1e7 N/m, 64.8 t: energy kept within 1 % over 60 s with a 0.2 s step,
    and the deformation follows (Δv/ω) sin(ω t) with ω = sqrt(2k/m)."""
    tr = _two_car()
    plant = TrainPlant(tr, None, dt_sim_s=0.2)  # step = control period of paper 000 (0.2 s)
    dv = 0.05
    plant.reset(0.0, 10.0, speeds_mps=[10.0 + dv, 10.0])
    e0 = plant.mechanical_energy_J()
    omega = math.sqrt(2 * 1e7 / 64.8e3)
    defs, ts, energies = [], [], []
    for _ in range(300):
        plant.step(0.0, 0.2)
        defs.append(plant.coupler_deformations()[0])
        ts.append(plant.t)
        energies.append(plant.mechanical_energy_J())
    assert max(abs(e - e0) for e in energies) / e0 < 0.01
    np.testing.assert_allclose(
        defs, dv / omega * np.sin(omega * np.array(ts)), atol=1e-6 * dv / omega * 1e3
    )
    # an independent frequency estimate from a fine-step run (zero crossings)
    fine = TrainPlant(tr, None, dt_sim_s=0.001)
    fine.reset(0.0, 10.0, speeds_mps=[10.0 + dv, 10.0])
    x = []
    for _ in range(20000):
        fine.step(0.0, 0.001)
        x.append(fine.coupler_deformations()[0])
    x = np.array(x)
    crossings = np.nonzero(np.diff(np.sign(x)) != 0)[0]
    period = 2 * np.mean(np.diff(crossings)) * 0.001
    assert abs(2 * math.pi / period - omega) / omega < 2e-3


def test_damped_coupler_dissipates():
    tr = _two_car(damping=5e4)
    plant = TrainPlant(tr, None, dt_sim_s=0.05)
    plant.reset(0.0, 10.0, speeds_mps=[10.05, 10.0])
    e0 = plant.mechanical_energy_J()
    for _ in range(100):
        plant.step(0.0, 0.2)
    assert plant.mechanical_energy_J() < e0
    assert abs(plant.coupler_deformations()[0]) < 1e-6


def test_steady_cruise_each_car_force_equals_its_resistance():
    """002 eq. (4): at equilibrium u_i equals car i's resistance (aero on the lead car)."""
    tr = get_train("paper002_crh3")
    plant = TrainPlant(tr, None, dt_sim_s=0.05, input_mode="per_car")
    v = 50.0
    forces = plant.ca + plant.cb * v + plant.cc * v * v
    assert forces[0] > forces[1]  # lead car carries the aerodynamic drag
    plant.reset(0.0, v, u0=forces)
    for _ in range(200):
        plant.step(forces, 0.5)
    np.testing.assert_allclose(plant.speeds, v, atol=1e-8)
    np.testing.assert_allclose(plant.coupler_forces(), 0.0, atol=1e-3)


def test_second_order_actuator_settles_to_command():
    tr = get_train("paper003_shinkansen")
    act = ActuatorParams(order=2, omega_n_radps=2.0, zeta=0.8)
    plant = TrainPlant(tr, None, actuator=act, dt_sim_s=0.05, input_mode="per_car")
    plant.reset(0.0, 40.0)
    cmd = np.full(8, 2e4)
    for _ in range(100):
        plant.step(cmd, 0.5)
    np.testing.assert_allclose(plant.forces, cmd, rtol=1e-6)


def test_gradient_force_decelerates_as_mg_theta():
    tr = _plain_train()
    plant = TrainPlant(
        tr, lambda s: np.full_like(np.asarray(s, float), 10.0), n_cars=1, dt_sim_s=0.01
    )
    plant.reset(0.0, 20.0)
    plant.step(0.0, 1.0)
    assert plant.v == pytest.approx(20.0 - 9.81 * 0.010, rel=1e-9)


def test_envelope_saturates_command():
    tr = replace(_plain_train(), max_traction_force_N=1e5, max_traction_power_W=1e6)
    plant = TrainPlant(tr, None, n_cars=1, dt_sim_s=0.01)
    plant.reset(0.0, 20.0)
    plant.step(1e6, 0.01)
    assert plant.saturated
    assert plant.force_total == pytest.approx(5e4)  # P/v = 1e6/20


@pytest.mark.parametrize(
    "kwargs, field",
    [
        (dict(mass_kg=-1.0), "mass_kg"),
        (dict(davis_a_N=float("nan")), "davis_a_N"),
        (dict(rotating_mass_factor=2.0), "rotating_mass_factor"),
    ],
)
def test_bad_train_parameters_name_the_field(kwargs, field):
    with pytest.raises(ValueError, match=field):
        _plain_train(**kwargs)


def test_nan_command_and_bad_step_rejected():
    plant = TrainPlant(_plain_train(), None, n_cars=1, dt_sim_s=0.01)
    plant.reset(0.0, 10.0)
    with pytest.raises(ValueError, match="u_N"):
        plant.step(float("nan"), 0.01)
    with pytest.raises(ValueError, match="dt_sim_s"):
        plant.step(0.0, 0.015)
    with pytest.raises(ValueError, match="dead_time_s"):
        PointMassTrain(_plain_train(), None, dead_time_s=0.015, dt_sim_s=0.01)


@pytest.mark.parametrize("scenario", ["paper001_stopping", "paper004_urban", "yizhuang"])
def test_single_car_fast_path_equals_general_path(scenario):
    """The unrolled float path of the single-point plant reproduces the numpy path."""
    from train_envs.scenarios import build_plant, get_scenario

    sc = get_scenario(scenario).with_overrides(
        disturbance=get_scenario(scenario).disturbance.__class__(random_bound_mps2=0.05)
    )
    fast = build_plant(sc, np.random.default_rng(1))
    slow = build_plant(sc, np.random.default_rng(1))
    slow._scalar_ok = False
    assert fast._scalar_ok
    rng = np.random.default_rng(0)
    for k in range(400):
        u = float(rng.uniform(-1, 1)) * sc.train.max_brake_N(0.0) * (0.2 if k < 300 else 1.0)
        fast.step(u, sc.dt_ctrl_s)
        slow.step(u, sc.dt_ctrl_s)
        np.testing.assert_allclose(fast.z, slow.z, rtol=1e-12, atol=1e-9)
        assert fast.stopped == slow.stopped
    assert fast.work_traction_J == pytest.approx(slow.work_traction_J, rel=1e-12)
    assert fast.work_brake_J == pytest.approx(slow.work_brake_J, rel=1e-12)


@pytest.mark.parametrize(
    "scenario, wind",
    [("paper001_stopping", None), ("paper004_urban", "harmonic"), ("yizhuang", None)],
)
def test_compiled_single_car_step_equals_the_python_one_bit_for_bit(scenario, wind):
    """The single-car step compiled (numba) and the same function run as plain Python
    give the same numbers exactly: states, time, standstill, energies, dead-time buffer,
    over braking to a standstill, breakaway and random and harmonic disturbances."""
    from train_envs._jit import enabled, implementation
    from train_envs.plants.single_car import SINGLE_CAR_STEP
    from train_envs.scenarios import build_plant, get_scenario

    if not enabled():
        pytest.skip("numba unavailable or disabled")

    base = get_scenario(scenario)
    spec = base.disturbance.__class__(random_bound_mps2=0.05, wind=wind)
    sc = base.with_overrides(disturbance=spec)
    comp = build_plant(sc, np.random.default_rng(1))
    ref = build_plant(sc, np.random.default_rng(1))
    comp._kern = implementation(SINGLE_CAR_STEP, compiled_twin=True)
    ref._kern = implementation(SINGLE_CAR_STEP, compiled_twin=False)
    rng = np.random.default_rng(0)
    stops = 0
    for k in range(650):
        u = float(rng.uniform(-1, 1)) * sc.train.max_brake_N(0.0) * (0.2 if k < 300 else 1.0)
        if 380 <= k < 560:
            u = -sc.train.max_brake_N(0.0)  # to a standstill, then away again
        elif k >= 560:
            u = sc.train.max_traction_N(0.0)
        comp.step(u, sc.dt_ctrl_s)
        ref.step(u, sc.dt_ctrl_s)
        assert comp.z.tolist() == ref.z.tolist(), k
        assert (comp.t, comp.stopped, comp._head) == (ref.t, ref.stopped, ref._head)
        assert (comp.work_traction_J, comp.work_brake_J) == (ref.work_traction_J, ref.work_brake_J)
        stops += comp.stopped
    assert stops > 0 and not comp.stopped
    assert comp._buffer.tolist() == ref._buffer.tolist()


def test_envelope_lists_equal_the_vectorised_envelope_bit_for_bit():
    from train_envs.trains import list_trains

    v = np.concatenate([[0.0, -0.0, 1e-12, 0.3], np.linspace(-5.0, 120.0, 251)])
    for name in list_trains():
        tr = get_train(name)
        lo, hi = tr.envelope_N(v)
        lo_l, hi_l = tr.envelope_lists(v.tolist())
        assert lo_l == lo.tolist() and hi_l == hi.tolist(), name


def test_envelope_box_lies_inside_the_envelope_over_the_interval():
    """envelope_box(v_lo, v_hi): lo >= −B(v) and hi <= F(v) at every speed of the
    interval (dense samples, both ends included), and it is the envelope itself when the
    interval is a single speed."""
    from train_envs.trains import list_trains

    rng = np.random.default_rng(11)
    for name in list_trains():
        tr = get_train(name)
        for v_lo, v_hi in [(0.0, 0.0), (0.0, 3.0), (0.0, 60.0), (12.0, 14.0), (25.0, 25.0)] + [
            tuple(sorted(rng.uniform(0.0, 50.0, 2))) for _ in range(20)
        ]:
            lo_b, hi_b = tr.envelope_box(v_lo, v_hi)
            v = np.concatenate([[v_lo, v_hi], np.linspace(v_lo, v_hi, 201)])
            lo, hi = tr.envelope_N(v)
            assert np.all(lo <= lo_b) and np.all(hi >= hi_b), (name, v_lo, v_hi)
            if v_lo == v_hi:
                assert (lo_b, hi_b) == (float(lo[0]), float(hi[0])), name


def test_physics_laws():
    """The laws of plants.physics: values, sign for reverse motion, the three bracketings
    agreeing to rounding, the slope, the per-car split and the coupler Laplacian."""
    from train_envs.lines import get_track
    from train_envs.plants.lookup import gradient_table
    from train_envs.plants.physics import (
        car_davis,
        coupler_matrix,
        davis_horner_N,
        davis_N,
        davis_signed_N,
        davis_slope,
        davis_sq_N,
        gradient_at,
    )

    a, b, c = 3000.0, 40.0, 6.5
    for v in (0.0, 0.3, 12.0, 33.3):
        r = a + b * v + c * v * v
        assert davis_N(a, b, c, v) == r
        assert davis_sq_N(a, b, c, v) == pytest.approx(r, rel=1e-15)
        assert davis_horner_N(a, b, c, v) == pytest.approx(r, rel=1e-15)
        assert davis_signed_N(a, b, c, -v) == (-r if v else r)  # 0: leaving rest, forward
        assert davis_signed_N(a, b, c, v) == r
    v = np.linspace(0.0, 40.0, 9)
    assert davis_N(a, b, c, v).tolist() == [davis_N(a, b, c, x) for x in v.tolist()]
    assert davis_slope(b, c, 10.0) == pytest.approx(
        (davis_N(a, b, c, 10.0 + 1e-4) - davis_N(a, b, c, 10.0 - 1e-4)) / 2e-4
    )
    share = np.array([0.5, 0.25, 0.25])
    ca, cb, cc = car_davis(a, b, c, share, True)
    assert ca.tolist() == [1500.0, 750.0, 750.0] and cb.sum() == b and cc.tolist() == [c, 0, 0]
    assert car_davis(a, b, c, share, False)[2].tolist() == (c * share).tolist()
    K = coupler_matrix(4)
    assert K.sum(axis=1).tolist() == [0.0] * 4 and np.array_equal(K, K.T)
    assert K.diagonal().tolist() == [-1.0, -2.0, -2.0, -1.0]
    tab = gradient_table(get_track("paper004"))
    for s in (-5.0, 0.0, 123.4, 900.0, 1e7):
        assert gradient_at(tab._xl, tab._y0l, tab._sl, s) == tab(s) == float(tab(np.array([s]))[0])
