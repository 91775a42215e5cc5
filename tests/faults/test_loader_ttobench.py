"""TTOBench loaders: units, plausibility bounds, the file name in load errors, user files
for real-line runs, and track overrides that would leave a stale reference."""

from __future__ import annotations

import json
import shutil
from importlib import resources

import gymnasium as gym
import numpy as np
import pytest

import train_envs  # noqa: F401  (registers the ids)
from train_envs.lines import Track, get_track
from train_envs.scenarios import get_scenario, real_line_scenario
from train_envs.trains import get_train, train_from_ttobench, train_from_ttobench_file

DATA = resources.files("train_envs") / "data" / "TTOBench"


def _track(**over):
    d = {
        "metadata": {"id": "T"},
        "stops": {"unit": "m", "values": [0, 2000]},
        "speed limits": {"units": {"position": "m", "velocity": "km/h"}, "values": [[0, 80]]},
        "curvatures": {
            "units": {"position": "m", "radius at start": "km", "radius at end": "km"},
            "values": [[0, "infinity", "infinity"], [500, 0.3, 0.3], [900, 0.3, 1.2]],
        },
    }
    d.update(over)
    return d


def _train(**over):
    d = json.loads((DATA / "trains" / "CN_Beijing_Subway.json").read_text())
    d.update(over)
    return d


def test_radius_at_end_uses_its_own_unit():
    t = Track.from_ttobench(_track())
    np.testing.assert_array_equal(t.curve_radius_start_m, [np.inf, 300.0, 300.0])
    np.testing.assert_array_equal(t.curve_radius_end_m, [np.inf, 300.0, 1200.0])
    raw = _track()
    raw["curvatures"]["units"]["radius at end"] = "m"
    raw["curvatures"]["values"] = [[0, 0.3, 300.0]]
    t = Track.from_ttobench(raw)
    assert t.curve_radius_start_m[0] == 300.0 and t.curve_radius_end_m[0] == 300.0
    # 600/R: 2 permil on the 300 m arc, not 2000
    assert t.curve_resistance_permil_at(700.0) == pytest.approx(2.0)


def test_percent_is_a_percentage():
    tr = train_from_ttobench(_train(rho={"value": 1.0, "unit": "%"}))
    assert tr.rotating_mass_factor == pytest.approx(0.01)
    eff = train_from_ttobench(_train(**{"efficiency traction": {"value": 90, "unit": "%"}}))
    assert eff.traction_efficiency == pytest.approx(0.9)
    with pytest.raises(ValueError, match=r"'efficiency traction' = 0\.009.*implausible"):
        train_from_ttobench(_train(**{"efficiency traction": {"value": 0.9, "unit": "%"}}))


def test_loss_map_without_full_load_rows_uses_its_highest_load():
    loco = json.loads((DATA / "trains" / "00_Loco_Dyn.json").read_text())
    full = train_from_ttobench(loco).traction_efficiency
    rows = loco["efficiency traction"]["values"]
    top = [r for r in rows if r[0] >= 100]
    # the same map with the 100 % rows relabelled 90 %, the rest dropped
    loco["efficiency traction"]["values"] = [[90.0, r[1], r[2]] for r in top]
    assert train_from_ttobench(loco).traction_efficiency == pytest.approx(full, rel=1e-12)
    loco["efficiency traction"]["values"] = []
    with pytest.raises(ValueError, match="loss map has no rows"):
        train_from_ttobench(loco)


@pytest.mark.parametrize(
    "over, match",
    [
        ({"stops": {"unit": "km", "values": [0, 22728]}}, r"22728 km is implausible"),
        (
            {"speed limits": {"units": {"velocity": "km/h"}, "values": [[0, 1e6]]}},
            r"1e\+06 km/h",
        ),
        ({"curvatures": {"units": {}, "values": [[0, 0.3, 0.3]]}}, r"radius of 0\.3 m"),
        ({"speed limits": [1, 2]}, r"'speed limits' must be an object"),
        ({"stops": {"values": "0 100"}}, r"'stops'.*list"),
    ],
)
def test_implausible_or_malformed_tracks_are_refused(over, match):
    with pytest.raises(ValueError, match=match):
        Track.from_ttobench(_track(**over))


@pytest.mark.parametrize(
    "over, match",
    [
        ({"mass": {"value": 1e9, "unit": "t"}}, r"'mass'.*implausible"),
        ({"max speed": {"value": 1e6, "unit": "km/h"}}, r"'max speed'.*implausible"),
        ({"max traction force": {"value": 310, "unit": "MN"}}, r"unsupported unit 'MN'"),
        ({"max traction force": {"value": 3.1e5, "unit": "kN"}}, r"implausible for a 278 t"),
        ({"rho": {"value": "x", "unit": "-"}}, r"'rho' must be"),
        ({"num coaches": {"value": 2.5, "unit": "-"}}, r"integer"),
    ],
)
def test_implausible_trains_are_refused(over, match):
    with pytest.raises(ValueError, match=match):
        train_from_ttobench(_train(**over))


def test_load_errors_name_the_file(tmp_path):
    bad = tmp_path / "broken.json"
    bad.write_text('{"stops": ')
    for load in (Track.from_ttobench, train_from_ttobench_file):
        with pytest.raises(ValueError, match="broken.json") as err:
            load(bad)
        assert "\n" not in str(err.value)
    with pytest.raises(ValueError, match="missing.json"):
        get_track(str(tmp_path / "missing.json"))
    implausible = tmp_path / "long.json"
    implausible.write_text(json.dumps(_track(stops={"unit": "km", "values": [0, 22728]})))
    with pytest.raises(ValueError, match=r"long\.json.*implausible"):
        Track.from_ttobench(implausible)


def test_real_line_runs_take_user_files(tmp_path):
    track = tmp_path / "my_line.json"
    train = tmp_path / "my_train.json"
    shutil.copy(str(DATA / "tracks" / "CN_Songjiazhuang_Yizhuang.json"), track)
    shutil.copy(str(DATA / "trains" / "CN_Beijing_Subway.json"), train)
    mine = real_line_scenario(str(track), train, 1, 2)
    shipped = real_line_scenario("CN_Songjiazhuang_Yizhuang", "CN_Beijing_Subway", 1, 2)
    assert mine.s_stop_m == shipped.s_stop_m and mine.train == shipped.train
    assert mine.scheduled_time_s == shipped.scheduled_time_s
    env = gym.make(
        "TrainEnvs/Yizhuang-v0",
        config={"real_line": {"track": str(track), "train": str(train), "sections": [(0, 1)]}},
    )
    env.reset(seed=0)
    assert env.unwrapped.scenario.s_stop_m == pytest.approx(
        float(np.diff(get_track("CN_Songjiazhuang_Yizhuang").stops_m[:2])[0])
    )
    assert get_train(str(train)) == get_train("CN_Beijing_Subway")


def test_track_override_needs_a_new_reference_and_stop():
    sc = get_scenario("paper004_urban")
    short = sc.track.section(0.0, 1000.0)
    with pytest.raises(ValueError, match=r"track needs reference and s_stop_m"):
        sc.with_overrides(track=short)
    with pytest.raises(ValueError, match=r"s_stop_m must lie in"):
        sc.with_overrides(track=short, reference=sc.reference, s_stop_m=2940.0)
    ok = sc.with_overrides(track=short, reference=sc.reference, s_stop_m=900.0)
    assert ok.s_stop_m == 900.0 and ok.track is short
