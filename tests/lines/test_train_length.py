"""Train length: a higher limit applies only once the rear has cleared the lower one."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from dop853_min_time import min_running_time
from test_effort_curves import section_track

from train_envs.lines import Track, minimum_time_profile, time_supplemented_profile
from train_envs.lines.limits import (
    effective_limit_at,
    effective_limit_fn,
    effective_limit_sections,
)
from train_envs.trains import KMH, TrainParams

LENGTH_M = 400.0  # a long train (e.g. a 16-car double unit or a freight train)
LINE_M = 6000.0
#: track limits (m, km/h): a rise, a drop, a rise
LIMITS = [(0.0, 60.0), (1500.0, 100.0), (3500.0, 80.0), (4000.0, 120.0)]
#: the same limits for the 400 m train, worked out by hand: 100 from 1500 + 400, the
#: drop at its own position (the head enters it), 120 from 4000 + 400
LIMITS_400 = [(0.0, 60.0), (1900.0, 100.0), (3500.0, 80.0), (4400.0, 120.0)]
GRADIENTS = [(0.0, 3.0), (2500.0, -2.0), (4200.0, 6.0)]


def _track() -> Track:
    return section_track("limit_steps", LINE_M, LIMITS, GRADIENTS)


#: the long train's parameters (SI units), a data table
LONG_EMU = {
    "name": "long_emu", "mass_kg": 400e3, "rotating_mass_factor": 0.06,
    "davis_a_N": 5e3, "davis_b_Ns_per_m": 60.0, "davis_c_Ns2_per_m2": 9.0,
    "max_traction_force_N": 300e3, "max_traction_power_W": 4e6,
    "max_brake_force_N": 300e3, "service_decel_mps2": 0.6,
}  # fmt: skip


def _train(length_m: float) -> TrainParams:
    return TrainParams(**LONG_EMU, length_m=length_m)


def test_effective_limit_table_is_the_rear_clearance_rule() -> None:
    pos, val = effective_limit_sections(
        np.array([p for p, _ in LIMITS]), np.array([v for _, v in LIMITS]), LENGTH_M
    )
    assert pos.tolist() == [p for p, _ in LIMITS_400]
    assert val.tolist() == [v for _, v in LIMITS_400]
    track = _track()
    # brute force: the lowest track limit under the train, head at s
    s = np.linspace(0.0, LINE_M, 6001)
    under = np.array(
        [track.speed_limit_at(np.linspace(max(x - LENGTH_M, 0.0), x, 4001)).min() for x in s]
    )
    fn = effective_limit_fn(track, LENGTH_M)
    np.testing.assert_array_equal(fn(s), under)
    assert [fn(float(x)) for x in s] == under.tolist()
    point = effective_limit_fn(track, 0.0)  # a point train: the track's own limits
    np.testing.assert_array_equal(point(s), track.speed_limit_at(s))
    assert [point(float(x)) for x in s] == [track.speed_limit_at(float(x)) for x in s]
    np.testing.assert_array_equal(effective_limit_at(track, 0.0, s), track.speed_limit_at(s))
    with pytest.raises(ValueError, match="length_m"):
        effective_limit_sections(np.zeros(1), np.ones(1), -1.0)
    with pytest.raises(ValueError, match="length_m"):
        _train(-5.0)


@pytest.mark.parametrize("length_m", [0.0, LENGTH_M])
def test_long_train_min_time_matches_an_independent_solve(length_m: float) -> None:
    train = _train(length_m)
    sections = LIMITS_400 if length_m else LIMITS
    t_ref = min_running_time(
        length_m=LINE_M,
        limit_sections=[(p, v * KMH) for p, v in sections],
        gradient_sections=GRADIENTS,
        traction_N=lambda v: min(300e3, 4e6 / v) if v > 0 else 300e3,
        davis=(5e3, 60.0, 9.0),
        mass_kg=train.mass_kg,
        inertial_mass_kg=train.inertial_mass_kg,
        decel_mps2=train.service_decel_mps2,
    )
    prof = minimum_time_profile(_track(), train, ds=1.0)
    assert prof.running_time_s == pytest.approx(t_ref, rel=1e-3)


def test_long_train_profile_respects_every_limit_under_the_train() -> None:
    track, train = _track(), _train(LENGTH_M)
    point = minimum_time_profile(track, _train(0.0), ds=1.0)
    for prof in (
        minimum_time_profile(track, train, ds=1.0),
        time_supplemented_profile(track, train, 1.1 * point.running_time_s, ds=1.0),
        time_supplemented_profile(track, train, 1.1 * point.running_time_s, ds=1.0, method="coast"),
    ):
        s = np.union1d(np.linspace(0.0, LINE_M, 12001), prof.s_m)
        v = prof.v_at_s(s)
        rear = np.maximum(s - LENGTH_M, 0.0)
        # at the head and at the rear: every part of the train is under its limit
        assert np.all(v <= track.speed_limit_at(s) + 1e-9)
        assert np.all(v <= track.speed_limit_at(rear) + 1e-9)
        # the higher limit is not taken before the rear clears the lower one
        assert prof.v_at_s(1899.0) <= 60 * KMH + 1e-9
        assert prof.v_at_s(4399.0) <= 80 * KMH + 1e-9
    # the rule costs running time against the point train
    t_long = minimum_time_profile(track, train, ds=1.0).running_time_s
    assert t_long > point.running_time_s * 1.005


def test_observation_previews_the_limit_governing_the_train() -> None:
    """The env's ``limit_ahead_i`` features and the scenario's limit read the
    rear-clearance rule for the train's length (Section000: 80 km/h from 1200 m, 100 km/h
    again from 1800 m)."""
    import gymnasium as gym

    env = gym.make("TrainEnvs/Section000-v0")
    env.reset(seed=0)
    b = env.unwrapped
    sc = b.scenario
    long = sc.with_overrides(train=replace(sc.train, length_m=120.0))
    obs_type = b.observation_type
    obs_type.bind(long, b.loop)
    b.loop.plant.reset(1850.0, 20.0)
    obs = obs_type.observe()
    names = b.observation_names
    lim = np.array([obs[i] for i, n in enumerate(names) if n.startswith("limit_ahead_")])
    offsets = np.linspace(0.0, float(b.config["preview_m"]), lim.size)
    v_scale = obs_type._v_scale
    expected = effective_limit_fn(sc.track, 120.0)(1850.0 + offsets) / v_scale
    np.testing.assert_allclose(lim, expected.astype(np.float32), rtol=1e-6)
    # head at 1850 m, rear at 1730 m: still under the 80 km/h section
    assert lim[0] == pytest.approx(80 * KMH / v_scale, rel=1e-6)
    assert sc.track.speed_limit_at(1850.0) == pytest.approx(100 * KMH)
    # the runner's recorded limit (and the controllers' observation) read the same rule
    assert long.speed_limit_at(1850.0) == pytest.approx(80 * KMH)
    assert long.speed_limit_at(1925.0) == sc.speed_limit_at(1925.0) == pytest.approx(100 * KMH)
    env.close()
