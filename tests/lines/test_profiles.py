"""Tests of train_envs.lines.profiles (reference speed profiles)."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from train_envs.lines import (
    DEFAULT_TRAIN_FOR_TRACK,
    SpeedProfile,
    Track,
    constant_decel_profile,
    get_track,
    minimum_time_profile,
    paper002_speed_command,
    paper003_speed_command,
    piecewise_speed_command,
    time_supplemented_profile,
)
from train_envs.lines.catalog import ttobench_track_ids
from train_envs.trains import KMH, TrainParams, get_train


def _level_track(length: float = 3000.0, limit: float = 100.0, gradient: float = 0.0) -> Track:
    return Track(
        name="level",
        stops_m=[0.0, length],
        speed_limit_positions_m=[0.0],
        speed_limits_mps=[limit],
        gradient_positions_m=[0.0],
        gradients_permil=[gradient],
    )


def _ideal_train(force_N: float = 1e5, mass_kg: float = 1e5, decel: float = 0.8) -> TrainParams:
    """Constant traction force, no resistance, no speed limit: analytic kinematics."""
    return TrainParams(
        name="ideal",
        mass_kg=mass_kg,
        davis_a_N=0.0,
        davis_b_Ns_per_m=0.0,
        davis_c_Ns2_per_m2=0.0,
        max_traction_force_N=force_N,
        max_brake_force_N=force_N,
        service_decel_mps2=decel,
    )


def _eval_points(track: Track, a: float, b: float, n: int = 20001) -> np.ndarray:
    bp = track.breakpoints_m()
    return np.union1d(np.linspace(a, b, n), bp[(bp >= a) & (bp <= b)])


def _check_min_time_profile(track: Track, train: TrainParams, a: float, b: float, prof) -> None:
    where = f"{track.name} [{a}, {b}]"
    assert prof.s_m[0] == a, where
    assert abs(prof.s_m[-1] - b) <= 0.01 and prof.v_mps[-1] == 0.0, where
    assert prof.v_mps[0] == 0.0 and np.all(prof.v_mps[1:-1] > 0.0), where
    x = _eval_points(track, a, b)
    v = prof.v_at_s(x)
    excess = v - track.speed_limit_at(x)
    worst = x[excess.argmax()]
    assert excess.max() <= 1e-9, f"{where}: limit exceeded by {excess.max()} at {worst} m"
    assert v.max() <= train.max_speed_mps + 1e-9, where
    # every limit drop is reached at the lower speed by the section start
    drops = np.nonzero(np.diff(track.speed_limits_mps) < 0)[0] + 1
    for k in drops:
        p = track.speed_limit_positions_m[k]
        if a < p < b:
            assert prof.v_at_s(float(p)) <= track.speed_limits_mps[k] + 1e-9, where
    # accelerations are physically achievable: traction at the segment start speed, and
    # braking no harder than the service deceleration
    s, vn = prof.s_m, prof.v_mps
    a_seg = np.diff(vn**2) / (2.0 * np.diff(s))
    mid = 0.5 * (s[:-1] + s[1:])
    f_track = track.gradient_force_N(mid, train.mass_kg)
    a_trac = np.array(
        [train.max_traction_N(v0) - train.resistance_N(v0) for v0 in vn[:-1]]
    ) - f_track
    a_trac = np.minimum(a_trac / train.inertial_mass_kg, train.max_accel_mps2)
    up = a_seg > 0
    assert np.all(a_seg[up] <= a_trac[up] + 1e-9), where
    assert a_seg.min() >= -train.service_decel_mps2 - 1e-9, where
    assert np.all(np.diff(prof.t_s) > 0) and math.isfinite(prof.running_time_s), where


# ------------------------------------------------------------------ minimum time
def test_min_time_profile_on_every_ttobench_station_pair() -> None:
    start = time.perf_counter()
    n = 0
    for name in ttobench_track_ids():
        track = get_track(name)
        train = get_train(DEFAULT_TRAIN_FOR_TRACK[name])
        for a, b in track.station_pairs:
            prof = minimum_time_profile(track, train, a, b, ds=2.0)
            _check_min_time_profile(track, train, a, b, prof)
            n += 1
    assert n == sum(len(get_track(t).stops_m) - 1 for t in ttobench_track_ids()) == 31
    assert time.perf_counter() - start < 20.0


@pytest.mark.parametrize("name", ["paper000_section", "paper000_multi_section", "paper004"])
def test_min_time_profile_on_paper_lines(name: str) -> None:
    track = get_track(name)
    train = get_train(DEFAULT_TRAIN_FOR_TRACK[name])
    for a, b in track.station_pairs:
        _check_min_time_profile(track, train, a, b, minimum_time_profile(track, train, a, b))


def test_min_time_matches_analytic_triangle_and_trapezoid() -> None:
    train = _ideal_train(force_N=1e5, mass_kg=1e5, decel=0.8)  # a = 1 m/s^2, b = 0.8
    acc, dec, length = 1.0, 0.8, 3000.0
    # no cruise: v_peak^2 = 2 L a b / (a + b), T = v_peak (1/a + 1/b)
    v_peak = math.sqrt(2 * length * acc * dec / (acc + dec))
    prof = minimum_time_profile(_level_track(length, 100.0), train, ds=1.0)
    assert prof.v_mps.max() == pytest.approx(v_peak, rel=1e-3)
    assert prof.running_time_s == pytest.approx(v_peak / acc + v_peak / dec, rel=1e-3)
    # cruise at the limit V: T = L/V + V/(2a) + V/(2b)
    vlim = 20.0
    prof = minimum_time_profile(_level_track(length, vlim), train, ds=1.0)
    expected = length / vlim + vlim / (2 * acc) + vlim / (2 * dec)
    assert prof.running_time_s == pytest.approx(expected, rel=1e-4)
    # the acceleration phase is exact: v^2 = 2 a s
    assert prof.v_at_s(50.0) == pytest.approx(math.sqrt(2 * acc * 50.0), rel=1e-12)


def test_min_time_brakes_before_a_limit_drop() -> None:
    track = Track(
        name="drop",
        stops_m=[0.0, 4000.0],
        speed_limit_positions_m=[0.0, 2000.0],
        speed_limits_mps=[25.0, 10.0],
    )
    train = _ideal_train(decel=0.5)
    prof = minimum_time_profile(track, train, ds=1.0)
    s_brake = 2000.0 - (25.0**2 - 10.0**2) / (2 * 0.5)  # 1475 m
    assert prof.v_at_s(s_brake - 1.0) == pytest.approx(25.0)
    assert prof.v_at_s(2000.0) == pytest.approx(10.0)
    assert prof.v_at_s(1800.0) == pytest.approx(math.sqrt(10.0**2 + 2 * 0.5 * 200.0))


def test_min_time_converges_with_the_grid_step() -> None:
    track = get_track("CN_Songjiazhuang_Yizhuang")
    train = get_train("CN_Beijing_Subway")
    t1 = minimum_time_profile(track, train, 0.0, 2631.0, ds=1.0).running_time_s
    t_fine = minimum_time_profile(track, train, 0.0, 2631.0, ds=0.25).running_time_s
    assert t1 == pytest.approx(t_fine, rel=2e-3)


def test_margin_start_speed_and_defaults() -> None:
    track = get_track("CN_Songjiazhuang_Yizhuang")
    train = get_train("CN_Beijing_Subway")
    prof = minimum_time_profile(track, train, 2631.0, ds=2.0, margin_mps=2.0)
    assert prof.s_m[-1] == 3906.0  # default: next stop
    x = _eval_points(track, 2631.0, 3906.0)
    assert np.all(prof.v_at_s(x) <= track.speed_limit_at(x) - 2.0 + 1e-9)
    fast = minimum_time_profile(track, train, 1000.0, 2631.0, v0=10.0)
    assert fast.v_mps[0] == 10.0
    by_name = minimum_time_profile("paper001", "paper001_hst")
    assert by_name.s_m[-1] == 400.0 and by_name.v_mps.max() <= 20.0
    np.testing.assert_array_equal(by_name.v_limit_mps, np.full(by_name.s_m.size, 20.0))


def test_min_time_argument_errors() -> None:
    track = _level_track(1000.0, 20.0)
    train = _ideal_train()
    with pytest.raises(ValueError, match="v0 must lie in"):
        minimum_time_profile(track, train, v0=25.0)
    with pytest.raises(ValueError, match="margin_mps must be below"):
        minimum_time_profile(track, train, margin_mps=20.0)
    with pytest.raises(ValueError, match=r"s_stop \(100.0\) must be greater than s_start"):
        minimum_time_profile(track, train, s_start=500.0, s_stop=100.0)
    with pytest.raises(ValueError, match="ds must lie in"):
        minimum_time_profile(track, train, ds=0.0)


def test_min_time_reports_a_gradient_the_train_cannot_climb() -> None:
    weak = _ideal_train(force_N=1e3, mass_kg=1e5)
    with pytest.raises(ValueError, match=r"cannot climb.*s = 1\.0 m \(gradient 5\.0 permil\)"):
        minimum_time_profile(_level_track(1000.0, 20.0, gradient=5.0), weak)


# ------------------------------------------------------------------ time supplement
SUPPLEMENT_CASES = [
    ("CN_Songjiazhuang_Yizhuang", 0.0, 2631.0),
    ("CH_Stadelhofen_Altstetten", 1690.0, 3530.0),
    ("paper004", 0.0, 2940.0),
    ("paper000_section", 0.0, 3000.0),
]


@pytest.mark.parametrize("method", ["cruise_cap", "coast"])
@pytest.mark.parametrize("name,a,b", SUPPLEMENT_CASES)
@pytest.mark.parametrize("extra", [(1.0, 5.0), (1.25, 0.0)])
def test_time_supplemented_meets_schedule_and_is_never_faster(
    name: str, a: float, b: float, method: str, extra: tuple[float, float]
) -> None:
    track = get_track(name)
    train = get_train(DEFAULT_TRAIN_FOR_TRACK[name])
    fastest = minimum_time_profile(track, train, a, b)
    scheduled = fastest.running_time_s * extra[0] + extra[1]
    prof = time_supplemented_profile(track, train, scheduled, a, b, method=method)
    assert abs(prof.running_time_s - scheduled) <= 0.5
    x = _eval_points(track, a, b)
    assert np.all(prof.v_at_s(x) <= fastest.v_at_s(x) + 1e-9)
    assert np.all(prof.v_at_s(x) <= track.speed_limit_at(x) + 1e-9)
    assert prof.s_m[-1] == b and prof.v_mps[-1] == 0.0
    assert method.split("_")[0] in prof.label


def test_time_supplemented_below_minimum_raises() -> None:
    track = get_track("paper004")
    train = get_train("paper004_btype_metro")
    t_min = minimum_time_profile(track, train).running_time_s
    with pytest.raises(ValueError, match=rf"scheduled_time_s \(100\.00 s\).*{t_min:.2f} s"):
        time_supplemented_profile(track, train, 100.0)
    with pytest.raises(ValueError, match="unknown method 'fast'"):
        time_supplemented_profile(track, train, 200.0, method="fast")


def test_time_supplemented_at_minimum_time_is_the_minimum_profile() -> None:
    track = get_track("paper004")
    train = get_train("paper004_btype_metro")
    fastest = minimum_time_profile(track, train)
    prof = time_supplemented_profile(track, train, fastest.running_time_s)
    np.testing.assert_array_equal(prof.v_mps, fastest.v_mps)


def test_coasting_that_cannot_absorb_the_supplement_raises() -> None:
    hill = Track(
        name="hill",
        stops_m=[0.0, 3000.0],
        speed_limit_positions_m=[0.0],
        speed_limits_mps=[20.0],
        gradient_positions_m=[0.0, 1500.0, 2500.0],
        gradients_permil=[0.0, 25.0, 0.0],
    )
    train = get_train("CN_Beijing_Subway")
    t_min = minimum_time_profile(hill, train).running_time_s
    with pytest.raises(ValueError, match="cannot be reached by coasting.*cruise_cap"):
        time_supplemented_profile(hill, train, 3 * t_min, method="coast")
    prof = time_supplemented_profile(hill, train, 3 * t_min, method="cruise_cap")
    assert abs(prof.running_time_s - 3 * t_min) <= 0.5


def test_coasting_segments_use_no_traction() -> None:
    track = _level_track(3000.0, 20.0)
    train = get_train("CN_Beijing_Subway")
    t_min = minimum_time_profile(track, train).running_time_s
    prof = time_supplemented_profile(track, train, t_min + 10.0, method="coast")
    s, v = prof.s_m, prof.v_mps
    a_seg = np.diff(v**2) / (2 * np.diff(s))
    a_coast = -np.array([train.resistance_N(x) for x in v[:-1]]) / train.inertial_mass_kg
    s_c = float(prof.label.split("coast from ")[1].split(" m")[0])
    after = np.nonzero((s[:-1] >= s_c) & (a_seg > -train.service_decel_mps2 + 1e-6))[0]
    coasting = after[:-1]  # the last one is the crossover onto the braking curve
    assert coasting.size > 100 and np.all(np.diff(coasting) == 1)
    np.testing.assert_allclose(a_seg[coasting], a_coast[coasting], rtol=1e-9, atol=1e-12)
    assert np.all(a_seg[coasting[-1] + 2 :] == pytest.approx(-train.service_decel_mps2))


# ------------------------------------------------------------------ paper references
def test_constant_decel_profile_matches_the_formula() -> None:
    prof = constant_decel_profile(v0=20.0, s0=0.0, s_stop=400.0, decel=0.5)
    assert "braking point 0 m" in prof.label  # 20^2 / (2 * 0.5) = 400: brakes from 0 m
    s = np.linspace(0.0, 400.0, 4001)
    np.testing.assert_allclose(prof.v_at_s(s), np.sqrt(2 * 0.5 * (400.0 - s)), atol=1e-12)
    assert prof.running_time_s == pytest.approx(40.0)  # v0 / b
    t = np.linspace(0.0, 40.0, 401)
    np.testing.assert_allclose(prof.v_at_t(t), 20.0 - 0.5 * t, atol=1e-12)
    np.testing.assert_allclose(prof.s_at_t(t), 20.0 * t - 0.25 * t**2, atol=1e-9)
    np.testing.assert_allclose(prof.t_at_s(s), (20.0 - np.sqrt(400.0 - s)) / 0.5, atol=1e-9)


def test_constant_decel_profile_with_cruise() -> None:
    prof = constant_decel_profile(v0=15.0, s0=0.0, s_stop=400.0, decel=0.5, ds=10.0)
    s_brake = 400.0 - 15.0**2 / (2 * 0.5)  # 175 m
    assert prof.v_at_s(s_brake) == 15.0
    s = np.linspace(0.0, 400.0, 801)
    np.testing.assert_allclose(
        prof.v_at_s(s), np.minimum(15.0, np.sqrt(2 * 0.5 * (400.0 - s))), atol=1e-12
    )
    assert prof.running_time_s == pytest.approx(s_brake / 15.0 + 15.0 / 0.5)


def test_paper002_speed_command_values() -> None:
    cmd = paper002_speed_command()
    t = np.array([0.0, 50.0, 100.0, 250.0, 400.0, 425.0, 450.0, 600.0, 875.0, 900.0, 1200.0])
    expected = [0.0, 20.0, 40.0, 40.0, 40.0, 55.0, 70.0, 70.0, 60.0, 50.0, 50.0]
    np.testing.assert_allclose(cmd.v_at_t(t), expected, atol=1e-12)
    assert cmd.s_at_t(100.0) == pytest.approx(2000.0)
    assert cmd.s_at_t(400.0) == pytest.approx(14000.0)
    assert cmd.s_at_t(1200.0) == pytest.approx(62750.0)
    assert cmd.running_time_s == pytest.approx(1200.0)
    assert cmd.v_at_t(1500.0) == 50.0  # held after the end
    assert get_track("paper002").length_m > cmd.length_m


def test_paper002_feasible_ramp_stays_within_the_traction_envelope() -> None:
    from train_envs.trains import get_train

    cmd = paper002_speed_command(ramp_end_s=470.0)
    assert cmd.v_at_t(435.0) == pytest.approx(55.0)
    tr = get_train("paper002_crh3")
    a_ramp = 30.0 / 70.0
    # available acceleration at the end of the ramp (70 m/s): envelope minus resistance
    a_avail = (tr.max_traction_N(70.0) - tr.resistance_N(70.0)) / tr.inertial_mass_kg
    assert a_ramp <= 0.85 * a_avail
    # Table 2's own ramp is not feasible for this train
    assert 30.0 / 50.0 > a_avail
    with pytest.raises(ValueError, match="ramp_end_s"):
        paper002_speed_command(ramp_end_s=300.0)


def test_paper003_speed_command_values() -> None:
    cmd = paper003_speed_command()
    ramp_up = (200.0 - 150.0) * KMH / 0.15
    assert cmd.v_at_t(50.0) == pytest.approx(150 * KMH)
    assert cmd.v_at_t(100.0) == pytest.approx(150 * KMH)
    assert cmd.v_at_t(100.0 + ramp_up / 2) == pytest.approx(175 * KMH)
    assert cmd.v_at_t(100.0 + ramp_up) == pytest.approx(200 * KMH)
    assert cmd.v_at_t(999.0) == pytest.approx(200 * KMH)
    assert cmd.v_at_t(1500.0) == pytest.approx(170 * KMH)
    assert cmd.t_s[-1] == pytest.approx(2000.0)
    assert np.abs(cmd.a_mps2).max() == pytest.approx(0.15)
    assert get_track("paper003").length_m > cmd.length_m


def test_piecewise_speed_command_validation() -> None:
    with pytest.raises(ValueError, match="breakpoints times must be strictly increasing"):
        piecewise_speed_command([(0.0, 0.0), (10.0, 5.0), (10.0, 8.0)])
    with pytest.raises(ValueError, match="standstill"):
        piecewise_speed_command([(0.0, 0.0), (10.0, 0.0), (20.0, 5.0)])
    with pytest.raises(ValueError, match=r"breakpoints\[1\] speed"):
        piecewise_speed_command([(0.0, 1.0), (10.0, -5.0)])


# ------------------------------------------------------------------ SpeedProfile
def test_speed_profile_validation() -> None:
    with pytest.raises(ValueError, match=r"SpeedProfile\.s_m must be strictly increasing"):
        SpeedProfile(np.array([0.0, 2.0, 1.0]), np.array([0.0, 1.0, 0.0]))
    with pytest.raises(ValueError, match=r"SpeedProfile\.v_mps must be finite and >= 0"):
        SpeedProfile(np.array([0.0, 1.0]), np.array([1.0, -1.0]))
    with pytest.raises(ValueError, match="0 at both ends of segment 1"):
        SpeedProfile(np.array([0.0, 1.0, 2.0, 3.0]), np.array([1.0, 0.0, 0.0, 1.0]))


def test_interpolation_is_consistent_and_exact() -> None:
    prof = minimum_time_profile("CN_Songjiazhuang_Yizhuang", "CN_Beijing_Subway", ds=2.0)
    t = np.linspace(0.0, prof.running_time_s, 5001)
    s = prof.s_at_t(t)
    assert np.all(np.diff(s) >= 0)
    np.testing.assert_allclose(prof.t_at_s(s), t, atol=1e-6)
    np.testing.assert_allclose(prof.v_at_t(t), prof.v_at_s(s), atol=1e-6)
    # scalar fast paths agree with the vectorised ones
    for ti, si in zip(t[::250], s[::250], strict=True):
        assert prof.s_at_t(float(ti)) == pytest.approx(si, abs=1e-9)
        assert prof.v_at_t(float(ti)) == pytest.approx(prof.v_at_t(np.array([ti]))[0], abs=1e-12)
        assert prof.v_at_s(float(si)) == pytest.approx(prof.v_at_s(np.array([si]))[0], abs=1e-12)
        assert prof.t_at_s(float(si)) == pytest.approx(prof.t_at_s(np.array([si]))[0], abs=1e-9)
    # the node times are the exact constant-acceleration ones: dt = 2 ds / (v0 + v1)
    dt = 2 * np.diff(prof.s_m) / (prof.v_mps[:-1] + prof.v_mps[1:])
    np.testing.assert_allclose(np.diff(prof.t_s), dt, rtol=1e-9)


def test_to_dataframe_columns_and_values() -> None:
    prof = minimum_time_profile("paper004", "paper004_btype_metro")
    df = prof.to_dataframe()
    assert list(df.columns) == ["s_m", "v_mps", "t_s", "a_mps2", "v_limit_mps"]
    assert len(df) == prof.s_m.size
    assert df["a_mps2"].max() <= get_train("paper004_btype_metro").max_accel_mps2 + 1e-9
    assert df["a_mps2"].iloc[-1] == pytest.approx(-0.8)  # service braking into the stop
    assert np.all(df["v_mps"] <= df["v_limit_mps"] + 1e-9)


def test_sv_on_table_is_sv_at_t_on_the_segment_table() -> None:
    from train_envs.controllers.tube import stage
    from train_envs.lines.speed_profile import sv_on_table

    assert stage.sv_on_table is sv_on_table  # the tube stage reads the same function
    prof = minimum_time_profile("CN_Songjiazhuang_Yizhuang", "CN_Beijing_Subway", ds=2.0)
    t = np.linspace(-5.0, prof.running_time_s + 5.0, 2001)
    s, v = prof.sv_at_t(t)
    np.testing.assert_allclose(s, prof.s_at_t(t), rtol=0, atol=1e-9)
    np.testing.assert_allclose(v, prof.v_at_t(t), rtol=0, atol=1e-9)
    s2, v2 = sv_on_table(prof.t_s, prof._seg_tbl, t)
    np.testing.assert_array_equal(s2, s)
    np.testing.assert_array_equal(v2, v)
