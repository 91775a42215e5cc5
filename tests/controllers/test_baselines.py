"""Fuzzy machinery, the Fuzzy-PID (paper 004's comparator) and the AFSMC (paper 000's)."""

from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np
import pytest

from train_envs.controllers import (
    AFSMCController,
    FuzzyPIDController,
    PIDController,
    make_controller,
)
from train_envs.controllers._common import (
    distribute,
    distribute_single,
    envelope_N,
    input_shares,
)
from train_envs.controllers.fuzzy import (
    NB,
    PB,
    TERMS,
    ZO,
    RuleBase1,
    RuleBase2,
    TriangularPartition,
    quantise,
    standard_partition,
    term_index,
    trapmf,
    trimf,
)
from train_envs.controllers.fuzzy_pid import DKD_TABLE, DKI_TABLE, DKP_TABLE
from train_envs.scenarios import get_scenario
from train_envs.simulation import ClosedLoop, simulate

RNG = np.random.default_rng(12345)
#: the classic "PD-like" diagonal table: output term = e term + ec term − 3 (saturated)
DIAGONAL = np.clip(np.add.outer(np.arange(7), np.arange(7)) - 3, 0, 6)


# ============================================================== fuzzy machinery
def test_standard_partition_is_a_partition_of_unity():
    p = standard_partition()
    assert TERMS == ("NB", "NM", "NS", "ZO", "PS", "PM", "PB")
    np.testing.assert_allclose(p.centres, np.arange(-3.0, 4.0))
    x = np.linspace(-6.0, 6.0, 2401)
    mu = p.memberships(x)
    np.testing.assert_allclose(mu.sum(axis=-1), 1.0, atol=1e-12)
    assert np.all(mu >= 0.0) and np.all(mu <= 1.0)
    assert np.all((mu > 0).sum(axis=-1) <= 2)  # at most two neighbouring terms fire
    # interior terms are triangles, the outer ones shoulders
    np.testing.assert_allclose(mu[:, ZO], trimf(x, -1.0, 0.0, 1.0), atol=1e-12)
    np.testing.assert_allclose(mu[:, NB], trapmf(x, -np.inf, -np.inf, -3.0, -2.0), atol=1e-12)
    np.testing.assert_allclose(mu[:, PB], trapmf(x, 2.0, 3.0, np.inf, np.inf), atol=1e-12)
    # the scalar locator agrees with the vectorised memberships
    for xi in RNG.uniform(-5, 5, 200):
        i, w = p.locate(float(xi))
        row = p.memberships(xi)
        assert row[i] == pytest.approx(1.0 - w) and row[i + 1] == pytest.approx(w)


def test_non_uniform_partition_and_shapes():
    p = TriangularPartition([-2.0, -0.5, 0.0, 1.0, 4.0])
    x = RNG.uniform(-5, 6, 500)
    np.testing.assert_allclose(p.memberships(x).sum(-1), 1.0, atol=1e-12)
    assert p.locate(0.5) == (2, pytest.approx(0.5))
    assert trimf(0.5, 0.0, 1.0, 2.0) == pytest.approx(0.5)
    assert trapmf(1.5, 0.0, 1.0, 2.0, 3.0) == pytest.approx(1.0)
    assert quantise(10.0, 1.0) == 3.0 and quantise(-0.5, 2.0) == -1.0
    assert term_index("pm") == 5
    with pytest.raises(ValueError, match="strictly increasing"):
        TriangularPartition([0.0, 0.0, 1.0])
    with pytest.raises(ValueError, match="unknown fuzzy term"):
        term_index("XL")


@pytest.mark.parametrize("inference", ["product", "min"])
def test_symmetric_table_gives_odd_output(inference):
    # odd symmetry of the table: T[6-i][6-j] = 6 - T[i][j]
    assert np.array_equal(DIAGONAL[::-1, ::-1], 6 - DIAGONAL)
    rb = RuleBase2(DIAGONAL, inference=inference)
    e = RNG.uniform(-4, 4, 300)
    ec = RNG.uniform(-4, 4, 300)
    np.testing.assert_allclose(rb.evaluate(-e, -ec), -rb.evaluate(e, ec), atol=1e-12)
    assert rb(0.0, 0.0) == pytest.approx(0.0, abs=1e-12)
    for a, b in zip(e[:50], ec[:50], strict=True):
        assert rb(-a, -b) == pytest.approx(-rb(a, b), abs=1e-12)


@pytest.mark.parametrize("inference", ["product", "min"])
def test_output_bounded_by_consequents_and_paths_agree(inference):
    table = RNG.integers(0, 7, size=(7, 7))
    cons = np.array([-5.0, -2.0, -1.0, 0.0, 0.5, 2.0, 7.0])
    rb = RuleBase2(table, consequents=cons, inference=inference, scale_e=2.0, scale_ec=0.5)
    e = RNG.uniform(-10, 10, 2000)
    ec = RNG.uniform(-20, 20, 2000)
    y = rb.evaluate(e, ec)
    used = cons[table]
    assert np.all(y >= used.min() - 1e-12) and np.all(y <= used.max() + 1e-12)
    scalar = np.array([rb(a, b) for a, b in zip(e[:300], ec[:300], strict=True)])
    np.testing.assert_allclose(scalar, y[:300], atol=1e-12)
    # at the term centres exactly one rule fires: the output is its consequent
    for i in range(7):
        for j in range(7):
            assert rb((i - 3) / 2.0, (j - 3) / 0.5) == pytest.approx(cons[table[i, j]])


@pytest.mark.parametrize("inference", ["product", "min"])
def test_monotone_table_gives_monotone_output(inference):
    # rows non-decreasing in the e term (DIAGONAL is monotone in both inputs)
    assert np.all(np.diff(DIAGONAL, axis=0) >= 0)
    rb = RuleBase2(DIAGONAL, inference=inference)
    e = np.linspace(-4, 4, 801)
    for ec in np.linspace(-4, 4, 17):
        y = rb.evaluate(e, np.full_like(e, ec))
        assert np.all(np.diff(y) >= -1e-12)


def test_product_inference_is_bilinear_interpolation():
    table = RNG.integers(0, 7, size=(7, 7))
    rb = RuleBase2(table)
    c = np.arange(-3.0, 4.0)[table]
    e, ec = 0.3, -1.6  # cell (3, 1), fractions 0.3 and 0.4
    expect = (0.7 * (0.6 * c[3, 1] + 0.4 * c[3, 2]) + 0.3 * (0.6 * c[4, 1] + 0.4 * c[4, 2]))
    assert rb(e, ec) == pytest.approx(expect)


def test_multi_output_and_single_input_rule_bases():
    rb = RuleBase2(np.stack([DIAGONAL, 6 - DIAGONAL]))
    y = rb(0.7, -0.2)
    assert y.shape == (2,) and y[0] == pytest.approx(-y[1])
    np.testing.assert_allclose(rb.evaluate([0.7], [-0.2])[0], y)
    r1 = RuleBase1(np.arange(7))  # identity table: y = sat(x)
    assert r1(1.25) == pytest.approx(1.25)
    assert r1(-9.0) == pytest.approx(-3.0)
    np.testing.assert_allclose(r1.evaluate([-9.0, 0.5, 2.5]), [-3.0, 0.5, 2.5])
    r2 = RuleBase1(np.stack([np.arange(7), np.full(7, PB)]), scale=0.5)
    np.testing.assert_allclose(r2(2.0), [1.0, 3.0])


def test_fuzzy_inputs_are_validated():
    rb = RuleBase2(DIAGONAL, names=("speed error", "error rate"))
    with pytest.raises(ValueError, match="speed error"):
        rb(float("nan"), 0.0)
    with pytest.raises(ValueError, match="error rate"):
        rb(0.0, float("inf"))
    with pytest.raises(ValueError, match="error rate"):
        rb.evaluate([0.0, 1.0], [0.0, float("nan")])
    with pytest.raises(ValueError, match="sigma"):
        RuleBase1(np.arange(7), name="sigma")(float("nan"))
    with pytest.raises(ValueError, match="shape"):
        RuleBase2(np.zeros((7, 6), int))
    with pytest.raises(ValueError, match="term indices"):
        RuleBase2(np.full((7, 7), 7))
    with pytest.raises(ValueError, match="inference"):
        RuleBase2(DIAGONAL, inference="max")


def test_one_evaluation_is_fast():
    rb = RuleBase2(np.stack([DKP_TABLE, DKI_TABLE, DKD_TABLE]))
    n = 3000
    t0 = time.perf_counter()
    for k in range(n):
        rb(0.001 * k - 1.5, 0.3)
    per_call = (time.perf_counter() - t0) / n
    assert per_call < 100e-6  # a few microseconds in practice; loose bound for slow CI


def test_fuzzy_pid_tables_are_even_and_gains_bounded():
    for t in (DKP_TABLE, DKI_TABLE, DKD_TABLE):
        assert t.shape == (7, 7)
        assert np.array_equal(t[::-1, ::-1], t)  # direction-independent gain changes
    # large error → larger K_p and smaller K_i than at zero error
    assert DKP_TABLE[0, 3] > DKP_TABLE[3, 3] and DKI_TABLE[0, 3] < DKI_TABLE[3, 3]
    c = FuzzyPIDController()
    p = c.get_params()
    for e, ec in RNG.uniform(-3, 3, size=(300, 2)):
        kp, ki, kd = c.gains(e, ec)
        assert abs(kp - p["kp0"]) <= p["dkp"] + 1e-12 and kp >= 0
        assert ki >= 0 and ki <= p["ki0"] + p["dki"] + 1e-12
        assert kd >= 0 and kd <= p["kd0"] + p["dkd"] + 1e-12
    assert c.gains(5.0, 0.0)[0] == pytest.approx(p["kp0"] + p["dkp"])  # e = PB, ec = ZO → PB


# ============================================================== closed loop
@pytest.fixture(scope="module")
def runs():
    """One seed-0 run per (scenario, controller) pair, shared by the tests below."""
    out = {}
    for sc in ("paper001_stopping", "paper004_urban"):
        for name in ("pid", "fuzzy_pid", "afsmc"):
            # the PIDs as conditional-integration speed PIDs (paper 004's comparator as
            # reproduced), not their timetable defaults
            opts = {
                "pid": {"integrate_saturated": False, "ki": 0.05},
                "fuzzy_pid": {"integrate_saturated": False},
            }.get(name, {})
            out[sc, name] = simulate(sc, make_controller(name, get_scenario(sc), **opts), seed=0)
    return out


def test_registered_by_name():
    assert isinstance(make_controller("fuzzy_pid"), FuzzyPIDController)
    assert isinstance(make_controller("afsmc", lambda_=0.3), AFSMCController)
    assert make_controller("afsmc").get_params()["lambda_"] == 0.1


@pytest.mark.parametrize("name", ["fuzzy_pid", "afsmc"])
def test_paper001_stops_within_the_window(runs, name):
    m = runs["paper001_stopping", name].metrics
    assert abs(m["stop_error_m"]) < 0.5  # paper 001's ±50 cm window (measured ≤ 0.09 m)
    assert m["stopped"] == 1.0
    assert m["max_overspeed_mps"] == 0.0
    # smoother than the plain PID on this delayed loop (measured 0.085 / 0.064 vs 0.114)
    assert m["comfort_mean_abs_jerk_mps3"] < runs["paper001_stopping", "pid"].metrics[
        "comfort_mean_abs_jerk_mps3"
    ]


def test_paper004_speed_tracking_fuzzy_pid(runs):
    """Same structure as ``pid`` plus bounded gain corrections: E_v within 10 % of PID's.

    Measured: 0.0550 vs 0.0533 m/s. Most of either is the traction-limited start
    (the reference accelerates at the train's limit; ~0.04 m/s of E_v is lost in the
    first 20 s by every controller).
    """
    fz = runs["paper004_urban", "fuzzy_pid"].metrics
    pid = runs["paper004_urban", "pid"].metrics
    assert fz["E_v_mps"] < 1.1 * pid["E_v_mps"]
    assert fz["stopped"] == 1.0


def test_paper004_tracking_afsmc_trades_speed_for_position(runs):
    """AFSMC tracks position on time references: E_x and the stop error collapse, E_v rises.

    After the traction-limited start every controller is ≈ 7.8 m behind s_ref; the PID
    never recovers it (stops 7.6 m short), the AFSMC catches up at ≤ 0.2 m/s above
    v_ref, which costs about that deficit / running time ≈ 0.04 m/s of E_v. Measured:
    E_v 0.094 vs 0.053 m/s (PID), E_x 1.35 vs 7.4 m, stop error 0.11 m vs −7.6 m. Bound:
    E_v < 2 × PID's, E_x < 0.25 × PID's.
    """
    af = runs["paper004_urban", "afsmc"].metrics
    pid = runs["paper004_urban", "pid"].metrics
    assert af["E_v_mps"] < 2.0 * pid["E_v_mps"]
    assert af["E_x_m"] < 0.25 * pid["E_x_m"]
    assert abs(af["stop_error_m"]) < 0.5 < abs(pid["stop_error_m"])


def test_afsmc_adaptive_parameters_stay_bounded_by_projection():
    # constant 0.2 m/s² head wind on the 6-car metro: θ wants to grow past a small bound
    theta_max = 0.05
    ctrl = AFSMCController(theta_max_mps2=theta_max, gamma=1.0)
    loop = ClosedLoop(get_scenario("paper000_disturbance_constant"), ctrl)
    loop.reset(seed=0)
    peak = 0.0
    while not loop.done:
        info = loop.step()
        assert np.all(np.abs(ctrl.theta) <= theta_max + 1e-12)
        assert info["theta_abs_max"] == pytest.approx(float(np.max(np.abs(ctrl.theta))))
        peak = max(peak, float(np.max(np.abs(ctrl.theta))))
    assert peak == pytest.approx(theta_max)  # the projection was active
    # default bound over a whole urban run
    ctrl = AFSMCController()
    loop = ClosedLoop(get_scenario("paper004_urban"), ctrl)
    loop.reset(seed=0)
    while not loop.done:
        loop.step()
        assert np.all(np.abs(ctrl.theta) <= ctrl.theta_max + 1e-12)
    assert np.all(np.isfinite(ctrl.theta))


def _check_envelope_and_rate(res, sc):
    ctx = sc.control_context()
    tr = ctx.train
    df = res.df.iloc[:-1]  # the last row is the final state, not a command
    v = df["v_mps"].to_numpy()
    hi = np.array([tr.max_traction_N(x) for x in v])
    lo = -np.array([tr.max_brake_N(x) for x in v])
    u = df["u_cmd_N"].to_numpy()
    tol = 1e-6 * tr.max_traction_force_N
    assert np.all(u <= hi + tol) and np.all(u >= lo - tol)
    if ctx.n_inputs > 1:
        share = input_shares(ctx)
        cars = np.column_stack([df[f"u{i + 1}_cmd_N"].to_numpy() for i in range(ctx.n_inputs)])
        np.testing.assert_allclose(cars.sum(axis=1), u, rtol=1e-9, atol=1e-6)
        assert np.all(cars <= share * hi[:, None] + tol)
        assert np.all(cars >= share * lo[:, None] - tol)
        # per-input rate limit, including the step from the scenario's initial command
        prev = np.vstack([np.full(ctx.n_inputs, sc.initial_command().sum() / ctx.n_inputs), cars])
        assert np.all(np.abs(np.diff(prev, axis=0)) <= ctx.du_max_Nps * ctx.dt_s + 1e-6)
    elif math.isfinite(ctx.du_max_Nps):
        assert np.all(np.abs(np.diff(u)) <= ctx.du_max_Nps * ctx.dt_s + 1e-6)


@pytest.mark.parametrize("name", ["fuzzy_pid", "afsmc"])
def test_commands_respect_envelope_and_rate_limits(runs, name):
    sc = get_scenario("paper000_single_section")  # 6 cars, per-car inputs, 6e4 N/s per car
    res = simulate(sc, name, seed=0)
    _check_envelope_and_rate(res, sc)
    assert res.metrics["stopped"] == 1.0
    for scn in ("paper001_stopping", "paper004_urban"):
        _check_envelope_and_rate(runs[scn, name], get_scenario(scn))


def test_whole_train_force_is_split_by_car_mass():
    sc = get_scenario("paper000_single_section")
    masses = (70e3, 60e3, 64.8e3, 64.8e3, 64.8e3, 64.8e3)
    train = replace(sc.train, mass_kg=sum(masses), car_masses_kg=masses)
    ctx = replace(sc.control_context(), train=train, du_max_Nps=math.inf)
    shares = input_shares(ctx)
    np.testing.assert_allclose(shares, np.array(masses) / sum(masses))
    u = distribute(ctx, 1e5, 10.0, np.zeros(6), shares)
    np.testing.assert_allclose(u, 1e5 * shares)
    # beyond the envelope every car is clipped to its share of it
    u = distribute(ctx, 1e9, 10.0, np.zeros(6), shares)
    np.testing.assert_allclose(u, train.max_traction_N(10.0) * shares)
    one = replace(ctx, n_inputs=1)
    np.testing.assert_allclose(input_shares(one), [1.0])


def test_distribute_single_equals_distribute_with_one_input():
    sc = get_scenario("paper001_stopping")
    ctx = replace(sc.control_context(), n_inputs=1, du_max_Nps=5e4)
    lo, hi = envelope_N(ctx.train, 12.0)
    du = ctx.du_max_Nps * ctx.dt_s
    for u in (-1e9, -3e4, 0.0, 2e4, 1e9):
        for prev in (-1e5, 0.0, 3e4):
            ref = distribute(ctx, u, 12.0, np.array([prev]), np.ones(1))
            assert distribute_single(lo, hi, u, prev, du) == float(ref[0])
    assert distribute_single(lo, hi, 1e9, 0.0, None) == hi


@pytest.mark.parametrize(
    ("name", "change"),
    [("fuzzy_pid", {"kp0": 0.3}), ("fuzzy_pid", {"ke": 20.0}), ("afsmc", {"gamma": 1.0}),
     ("afsmc", {"k_s": 0.5})],
)
def test_set_params_changes_behaviour(runs, name, change):
    base = runs["paper001_stopping", name].df
    ctrl = make_controller(name)
    ctrl.set_params(**change)
    assert ctrl.get_params()[next(iter(change))] == next(iter(change.values()))
    other = simulate("paper001_stopping", ctrl, seed=0).df
    n = min(len(base), len(other))
    assert not np.allclose(base["u_cmd_N"].to_numpy()[:n], other["u_cmd_N"].to_numpy()[:n])


@pytest.mark.parametrize(
    ("cls", "bad"),
    [
        (FuzzyPIDController, {"kp0": -1.0}),
        (FuzzyPIDController, {"ke": 0.0}),
        (FuzzyPIDController, {"kec": float("nan")}),
        (FuzzyPIDController, {"dkp": 50.0}),
        (AFSMCController, {"lambda_": 0.0}),
        (AFSMCController, {"gamma": 100.0}),
        (AFSMCController, {"phi": -0.1}),
        (AFSMCController, {"k_s": float("inf")}),
    ],
)
def test_bad_params_raise_naming_the_parameter(cls, bad):
    (key,) = bad
    with pytest.raises(ValueError, match=key):
        cls(**bad)
    c = cls()
    with pytest.raises(ValueError, match=key):
        c.set_params(**bad)


def test_bad_options_and_unknown_params_raise():
    with pytest.raises(ValueError, match="no tunable parameter 'kp'"):
        FuzzyPIDController(kp=1.0)
    with pytest.raises(ValueError, match="theta_max_mps2"):
        AFSMCController(theta_max_mps2=0.0)
    with pytest.raises(ValueError, match="sigma_span_mps"):
        AFSMCController(sigma_span_mps=float("nan"))
    with pytest.raises(ValueError, match="inference"):
        FuzzyPIDController(inference="sum")


def test_nan_measurement_is_reported_by_name():
    sc = get_scenario("paper001_stopping")
    loop = ClosedLoop(sc, FuzzyPIDController())
    obs = loop.reset(seed=0)
    obs.v_mps = float("nan")
    with pytest.raises(ValueError, match="fuzzy input e"):
        loop.controller.compute(obs)


def test_pid_refactor_kept_behaviour(runs):
    # regression value of pid.py on paper001 (pinned when pid.py moved to _common;
    # 0.043275 on the plant that is exact at gradient steps, 0.043736 before)
    m = runs["paper001_stopping", "pid"].metrics
    assert m["stop_error_m"] == pytest.approx(0.043275, abs=1e-5)
    assert isinstance(make_controller("pid"), PIDController)


def test_afsmc_speed_surface_is_the_speed_error_and_has_no_position_feedback():
    sc = get_scenario("paper000_disturbance_constant")
    ctrl = make_controller("afsmc000")
    assert ctrl.name == "afsmc000" and ctrl.surface == "speed"
    loop = ClosedLoop(sc, ctrl)
    loop.reset(seed=0)
    while not loop.done:
        info = loop.step()
        assert info["sigma"] == info["error"]
    # under a constant head wind the position error drifts without position feedback,
    # while the library AFSMC (position surface) holds the stop
    speed, pos = loop.result().metrics, simulate(sc, "afsmc", seed=0).metrics
    assert speed["E_p_m"] > 10 * pos["E_p_m"]
    with pytest.raises(ValueError, match="surface"):
        AFSMCController(surface="position+speed")
