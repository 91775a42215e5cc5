"""Tabulated tractive-effort curves in the reference profiles and the plant.

The test train is a diesel-hydraulic-like unit (ASSUMED numbers of plausible
magnitude, not a published vehicle): its tractive effort falls steeply in the first
converter stage and flattens in the second, far from the ``min(F, P/v)`` hyperbola.
"""

from __future__ import annotations

import numpy as np
import pytest
from dop853_min_time import min_running_time

from train_envs.effort import EffortCurve
from train_envs.lines import Track, minimum_time_profile, time_supplemented_profile
from train_envs.plants.actuator import ActuatorParams
from train_envs.plants.multi_car import TrainPlant
from train_envs.trains import KMH, TrainParams

#: (km/h, kN): converter stage 1 to 45 km/h, stage 2 above (a kink at the change)
DMU_CURVE_KMH_KN = [
    (0.0, 150.0),
    (10.0, 128.0),
    (25.0, 96.0),
    (45.0, 62.0),
    (60.0, 55.0),
    (80.0, 44.0),
    (100.0, 33.0),
    (120.0, 24.0),
    (140.0, 18.0),
]


#: the test unit's other parameters (SI units), a data table
DMU = {
    "name": "test_dmu", "mass_kg": 140e3, "rotating_mass_factor": 0.08,
    "davis_a_N": 2.2e3, "davis_b_Ns_per_m": 40.0, "davis_c_Ns2_per_m2": 6.0,
    "max_traction_force_N": 150e3, "max_brake_force_N": 120e3,
    "service_decel_mps2": 0.7, "max_speed_mps": 140 * KMH,
}  # fmt: skip


def dmu_train(**kw) -> TrainParams:
    curve = EffortCurve.from_pairs(DMU_CURVE_KMH_KN, "km/h", "kN")
    return TrainParams(**{**DMU, "traction_curve": curve, **kw})


#: a line with gradients and several limits (m, km/h) / (m, permil)
LIMITS = [(0.0, 80.0), (1800.0, 120.0), (4200.0, 70.0), (5200.0, 110.0), (8000.0, 90.0)]
GRADIENTS = [(0.0, 4.0), (1500.0, 12.0), (3000.0, -6.0), (4500.0, 0.0), (6500.0, 9.0)]
LENGTH = 9500.0


def section_track(name: str, length_m: float, limits_kmh, gradients_permil) -> Track:
    """A line from ``(start m, limit km/h)`` and ``(start m, gradient permil)`` sections."""
    return Track(
        name=name,
        stops_m=[0.0, length_m],
        speed_limit_positions_m=[p for p, _ in limits_kmh],
        speed_limits_mps=[v * KMH for _, v in limits_kmh],
        gradient_positions_m=[p for p, _ in gradients_permil],
        gradients_permil=[g for _, g in gradients_permil],
    )


def effort_line() -> Track:
    return section_track("effort_test_line", LENGTH, LIMITS, GRADIENTS)


def reference_time(train: TrainParams, limits_kmh=LIMITS) -> float:
    curve = np.array(DMU_CURVE_KMH_KN)
    vs, fs = curve[:, 0] * KMH, curve[:, 1] * 1e3

    def traction(v: float) -> float:
        return min(float(np.interp(v, vs, fs)), train.max_traction_force_N)

    return min_running_time(
        length_m=LENGTH,
        limit_sections=[(p, v * KMH) for p, v in limits_kmh],
        gradient_sections=GRADIENTS,
        traction_N=traction,
        davis=(train.davis_a_N, train.davis_b_Ns_per_m, train.davis_c_Ns2_per_m2),
        mass_kg=train.mass_kg,
        inertial_mass_kg=train.inertial_mass_kg,
        decel_mps2=train.service_decel_mps2,
        table_speeds=vs.tolist(),
    )


def test_tabulated_curve_min_time_matches_an_independent_dop853_solve() -> None:
    train = dmu_train()
    t_ref = reference_time(train)
    prof = minimum_time_profile(effort_line(), train, ds=1.0)
    rel = prof.running_time_s / t_ref - 1.0
    assert abs(rel) < 1e-3, f"library {prof.running_time_s:.3f} s, DOP853 {t_ref:.3f} s"
    # the hyperbolic fit through the curve's end points is a different train: the test
    # resolves the table (a fit of the same peak force and top power runs faster)
    fit = dmu_train(traction_curve=None, max_traction_power_W=18e3 * 140 * KMH)
    t_fit = minimum_time_profile(effort_line(), fit, ds=1.0).running_time_s
    assert abs(t_fit / prof.running_time_s - 1.0) > 1e-2


def test_profile_accelerations_stay_within_the_table() -> None:
    train, track = dmu_train(), effort_line()
    prof = minimum_time_profile(track, train, ds=2.0)
    s, v = prof.s_m, prof.v_mps
    a_seg = np.diff(v**2) / (2.0 * np.diff(s))
    mid = 0.5 * (s[:-1] + s[1:])
    table = np.interp(v[:-1], *np.array(DMU_CURVE_KMH_KN).T * [[KMH], [1e3]])
    res = np.array([train.resistance_N(x) for x in v[:-1]])
    a_max = (table - res - track.gradient_force_N(mid, train.mass_kg)) / train.inertial_mass_kg
    up = a_seg > 0
    assert np.all(a_seg[up] <= a_max[up] + 1e-9)
    # and the profile uses it: full traction wherever it accelerates below the caps
    assert np.max(a_max[up] - a_seg[up]) >= 0.0
    assert np.median((a_max[up] - a_seg[up]) / a_max[up]) < 1e-6


def test_time_supplemented_profile_with_a_table_meets_the_schedule() -> None:
    train, track = dmu_train(), effort_line()
    t_min = minimum_time_profile(track, train, ds=2.0).running_time_s
    for method in ("cruise_cap", "coast"):
        prof = time_supplemented_profile(track, train, 1.08 * t_min, ds=2.0, method=method)
        assert prof.running_time_s == pytest.approx(1.08 * t_min, abs=0.05)


@pytest.mark.parametrize("order", [0, 1])
def test_plant_never_exceeds_the_table(order: int) -> None:
    """Full-traction commands: the command applied is the table's value at the speed it
    is issued at, never above it; the actual force is that command (ideal actuator) or
    its first-order lag, a convex combination of the saturated commands so far (and of
    its initial 0), so never above the largest of them."""
    train = dmu_train(max_speed_mps=1e3)
    curve = train.traction_curve
    plant = TrainPlant(
        train,
        None,
        n_cars=1,
        dt_sim_s=0.01,
        actuator=ActuatorParams(order=order, tau_s=0.3 if order else 0.4, dead_time_s=0.0),
    )
    plant.reset(0.0, 0.0)
    cmd_max = 0.0
    for _ in range(3000):  # 600 s
        v0 = plant.v
        plant.step(1e7, 0.2)
        assert plant.saturated
        limit = curve(v0)
        cmd = float(np.sum(plant.last_command))
        assert cmd <= limit
        assert cmd == pytest.approx(limit, rel=1e-12)
        cmd_max = max(cmd_max, cmd)
        if order == 0:
            assert plant.force_total == cmd
        else:
            assert 0.0 <= plant.force_total <= cmd_max * (1 + 1e-12)
    # the run follows dv/dt = (T(v) − R(v)) / M' (an independent DOP853 solve of the
    # same 600 s at full traction; the plant holds each 0.2 s command at T(v_k))
    from scipy.integrate import solve_ivp

    xs, fs = np.array(curve.speeds_mps), np.array(curve.forces_N)

    def rhs(_t, y):
        return [(np.interp(y[0], xs, fs) - train.resistance_N(y[0])) / train.inertial_mass_kg]

    sol = solve_ivp(rhs, (0.0, 600.0), [0.0], method="DOP853", rtol=1e-10, atol=1e-10)
    assert plant.v == pytest.approx(float(sol.y[0, -1]), rel=5e-4)


def test_tabulated_single_car_paths_agree() -> None:
    """With traction and brake tables, the single-car float path equals the general
    numpy path, and its compiled twin equals the Python step bit for bit (the tables
    enter through the saturated command, the same in all three)."""
    from train_envs._jit import enabled, implementation
    from train_envs.plants.lookup import gradient_table
    from train_envs.plants.single_car import SINGLE_CAR_STEP

    brake = EffortCurve.from_pairs([(0.0, 0.0), (8.0, 90.0), (60.0, 110.0), (140.0, 45.0)])
    train = dmu_train(brake_curve=brake, max_friction_brake_force_N=30e3)
    grad = gradient_table(effort_line())
    act = ActuatorParams(order=1, tau_s=0.4, dead_time_s=0.6)

    def make() -> TrainPlant:
        p = TrainPlant(train, grad, n_cars=1, dt_sim_s=0.01, actuator=act)
        p.reset(100.0, 0.0)
        return p

    fast, slow = make(), make()
    slow._scalar_ok = False
    assert fast._scalar_ok
    comp = None
    if enabled():
        comp = make()
        comp._kern = implementation(SINGLE_CAR_STEP, compiled_twin=True)
        fast._kern = implementation(SINGLE_CAR_STEP, compiled_twin=False)
    rng = np.random.default_rng(5)
    for k in range(900):
        u = float(rng.uniform(-1.3, 1.3)) * 150e3 if k < 600 else (-3e5 if k < 750 else 3e5)
        v = fast.v
        for p in (fast, slow) if comp is None else (fast, slow, comp):
            p.step(u, 0.2)
        expect = min(max(u, -train.max_brake_N(v)), train.max_traction_N(v))
        assert fast.last_command == expect
        # (the general path's state agrees to rounding, so its speed and command too)
        assert float(slow.last_command[0]) == pytest.approx(expect, rel=1e-11, abs=1e-6)
        np.testing.assert_allclose(fast.z, slow.z, rtol=1e-12, atol=1e-9)
        assert fast.stopped == slow.stopped
        if comp is not None:
            assert comp.z.tolist() == fast.z.tolist(), k
            assert (comp.t, comp.stopped) == (fast.t, fast.stopped)
