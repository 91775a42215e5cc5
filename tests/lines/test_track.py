"""Tests of train_envs.lines.track and train_envs.lines.catalog."""

from __future__ import annotations

import csv
import json
import math
from importlib import resources

import numpy as np
import pytest

from train_envs.lines import (
    DEFAULT_TRAIN_FOR_TRACK,
    Track,
    get_track,
    list_tracks,
    paper000_multi_section_track,
    paper001_track,
    paper002_track,
    paper004_track,
)
from train_envs.lines.catalog import PAPER_TRACKS, default_train_for_track, ttobench_track_ids
from train_envs.trains import KMH, G, list_trains

TRACK_DIR = resources.files("train_envs") / "data" / "TTOBench" / "tracks"


def _tracks_csv() -> dict[str, dict[str, str]]:
    rows = csv.DictReader((TRACK_DIR / "tracks.csv").read_text().splitlines())
    return {row["ID"]: row for row in rows}


def _simple(**overrides) -> Track:
    kw = dict(
        name="t",
        stops_m=[0.0, 1000.0],
        speed_limit_positions_m=[0.0, 300.0, 600.0],
        speed_limits_mps=[10.0, 20.0, 15.0],
        gradient_positions_m=[0.0, 500.0],
        gradients_permil=[5.0, -10.0],
    )
    kw.update(overrides)
    return Track(**kw)


# ------------------------------------------------------------------ TTOBench loading
@pytest.mark.parametrize("track_id", ttobench_track_ids())
def test_every_shipped_ttobench_track_loads_and_matches_the_summary_table(track_id: str) -> None:
    track = get_track(track_id)
    summary = _tracks_csv()[track_id]
    assert track.name == track_id
    assert track.length_m == pytest.approx(float(summary["Length [m]"]))
    assert len(track.stops_m) == int(summary["Num stops [-]"])
    assert track.stops_m[0] == 0.0 and np.all(np.diff(track.stops_m) > 0)
    v_lo, v_hi = float(summary["Min speed limit [km/h]"]), float(summary["Max speed limit [km/h]"])
    assert track.speed_limits_mps.min() == pytest.approx(v_lo * KMH)
    assert track.speed_limits_mps.max() == pytest.approx(v_hi * KMH)
    assert track.gradients_permil.min() == pytest.approx(float(summary["Min gradient [permil]"]))
    assert track.gradients_permil.max() == pytest.approx(float(summary["Max gradient [permil]"]))
    r_min = float(summary["Min (abs) radius [m]"])
    radii = np.abs(np.concatenate((track.curve_radius_start_m, track.curve_radius_end_m)))
    assert radii.min() == pytest.approx(r_min)
    # lookups agree with the raw JSON (km/h -> m/s at the boundary only)
    raw = json.loads((TRACK_DIR / f"{track_id}.json").read_text())
    for pos, kmh in raw["speed limits"]["values"]:
        assert track.speed_limit_at(float(pos)) == pytest.approx(kmh * KMH)
    for pos, permil in raw.get("gradients", {"values": []})["values"]:
        assert track.gradient_permil_at(float(pos)) == pytest.approx(permil)
    assert "TTOBench" in track.source


def test_curvatures_are_read_with_infinity_and_clothoids() -> None:
    track = get_track("CH_StGallen_Wil")
    # [0, 49.6): arc R = 502; [49.6, 125.6): clothoid 502 -> 3570; (330.2..393.1) left R 5700
    assert track.curvature_at(10.0) == pytest.approx(1 / 502)
    mid = 0.5 * (49.6 + 125.6)
    assert track.curvature_at(mid) == pytest.approx(0.5 * (1 / 502 + 1 / 3570))
    assert track.curvature_at(300.0) == 0.0
    assert track.curvature_at(350.0) == pytest.approx(-1 / 5700)
    assert np.isinf(track.curve_radius_end_m[5])  # "infinity" string in the JSON


def test_list_tracks_has_papers_and_every_ttobench_file() -> None:
    names = list_tracks()
    files = sorted(p.name[:-5] for p in TRACK_DIR.iterdir() if p.name.endswith(".json"))
    assert files and set(files) <= set(names)
    assert set(PAPER_TRACKS) <= set(names)
    assert len(names) == len(set(names)) == len(files) + len(PAPER_TRACKS)


def test_get_track_is_cached_and_immutable() -> None:
    a = get_track("CN_Songjiazhuang_Yizhuang")
    assert get_track("CN_Songjiazhuang_Yizhuang") is a
    with pytest.raises(ValueError):
        a.speed_limits_mps[0] = 1.0  # read-only array
    with pytest.raises(AttributeError):
        a.name = "x"  # type: ignore[misc]


def test_unknown_track_name_lists_choices() -> None:
    with pytest.raises(ValueError, match=r"unknown track 'nope'.*CN_Songjiazhuang_Yizhuang"):
        get_track("nope")


def test_default_train_for_every_track_is_a_known_train() -> None:
    trains = set(list_trains())
    for name in list_tracks():
        assert DEFAULT_TRAIN_FOR_TRACK[name] in trains
    assert DEFAULT_TRAIN_FOR_TRACK["CN_Songjiazhuang_Yizhuang"] == "CN_Beijing_Subway"
    assert DEFAULT_TRAIN_FOR_TRACK["CH_Fribourg_Bern"] == "CH_Stadler_FLIRT_TPF"
    assert DEFAULT_TRAIN_FOR_TRACK["SE_Vasteras_Kolback"] == "CH_Stadler_KISS"
    assert DEFAULT_TRAIN_FOR_TRACK["00_reference"] == "00_Loco_Dyn"
    assert default_train_for_track("paper001") == "paper001_hst"
    with pytest.raises(ValueError, match="unknown track"):
        default_train_for_track("nope")


# ------------------------------------------------------------------ validation
def test_speed_limit_positions_not_increasing_names_field_and_element() -> None:
    with pytest.raises(
        ValueError,
        match=r"track\.speed_limits positions must be strictly increasing: "
        r"element 2 \(300\.0\) follows 300\.0",
    ):
        _simple(speed_limit_positions_m=[0.0, 300.0, 300.0])


def test_gradient_positions_not_increasing() -> None:
    with pytest.raises(ValueError, match=r"track\.gradients positions must be strictly increasing"):
        _simple(gradient_positions_m=[0.0, 500.0, 400.0], gradients_permil=[0.0, 1.0, 2.0])


@pytest.mark.parametrize("bad", [-5.0, 0.0, math.nan, math.inf])
def test_non_positive_or_non_finite_speed_limit_rejected(bad: float) -> None:
    with pytest.raises(ValueError, match=r"track\.speed_limits values\[1\] \(m/s\)"):
        _simple(speed_limits_mps=[10.0, bad, 15.0])


def test_stops_and_length_validation() -> None:
    with pytest.raises(ValueError, match=r"track\.stops_m must start at 0"):
        _simple(stops_m=[10.0, 1000.0])
    with pytest.raises(ValueError, match=r"track\.stops_m must be strictly increasing"):
        _simple(stops_m=[0.0, 600.0, 500.0, 1000.0])
    with pytest.raises(ValueError, match=r"track\.stops_m needs at least 2 stops"):
        _simple(stops_m=[0.0])
    with pytest.raises(ValueError, match=r"speed_limits positions must lie in \[0, length_m"):
        _simple(speed_limit_positions_m=[0.0, 300.0, 1000.0])
    with pytest.raises(ValueError, match=r"track\.speed_limits positions must start at 0"):
        _simple(speed_limit_positions_m=[5.0, 300.0, 600.0])
    with pytest.raises(ValueError, match=r"one entry per position"):
        _simple(speed_limits_mps=[10.0, 20.0])


def test_gradient_and_radius_ranges_validated() -> None:
    with pytest.raises(ValueError, match=r"track\.gradients values\[1\] \(permil\)"):
        _simple(gradients_permil=[5.0, 250.0])
    with pytest.raises(ValueError, match=r"track\.curvatures radius_start\[0\] must be a non-zero"):
        _simple(
            curve_positions_m=[0.0],
            curve_radius_start_m=[0.0],
            curve_radius_end_m=[math.inf],
        )


def test_errors_name_the_track() -> None:
    with pytest.raises(ValueError, match=r"\[track 'mine'\]"):
        _simple(name="mine", speed_limits_mps=[10.0, -1.0, 15.0])


def test_from_ttobench_rejects_unknown_units() -> None:
    raw = json.loads((TRACK_DIR / "00_var_speed_limit_wind.json").read_text())
    raw["speed limits"]["units"]["velocity"] = "mph"
    with pytest.raises(ValueError, match=r"'speed limits'.*velocity unit 'mph'"):
        Track.from_ttobench(raw)


def test_from_ttobench_accepts_a_path() -> None:
    with resources.as_file(TRACK_DIR / "00_reference.json") as path:
        track = Track.from_ttobench(path)
    assert track.length_m == 48531.0
    assert track.speed_limit_at(100.0) == pytest.approx(140 * KMH)


# ------------------------------------------------------------------ lookups
def test_section_boundaries_belong_to_the_new_section() -> None:
    t = _simple()
    assert t.speed_limit_at(299.999) == 10.0
    assert t.speed_limit_at(300.0) == 20.0
    assert t.speed_limit_at(-5.0) == 10.0  # clamped before the start
    assert t.speed_limit_at(5000.0) == 15.0  # clamped after the end
    assert t.gradient_permil_at(500.0) == -10.0


def test_scalar_and_vector_lookups_agree() -> None:
    track = get_track("CH_StGallen_Wil")
    x = np.linspace(-10.0, track.length_m + 10.0, 3001)
    x = np.concatenate((x, track.breakpoints_m()))
    for method in (
        track.speed_limit_at,
        track.gradient_permil_at,
        track.curvature_at,
        track.equivalent_gradient_permil_at,
    ):
        vec = np.asarray(method(x))
        sca = np.array([method(float(v)) for v in x])
        np.testing.assert_allclose(vec, sca, rtol=0, atol=1e-15)
    vec = track.gradient_force_N(x, 1e5)
    sca = np.array([track.gradient_force_N(float(v), 1e5) for v in x])
    np.testing.assert_allclose(vec, sca, rtol=1e-14, atol=1e-9)


def test_equivalent_gradient_uses_600_over_r() -> None:
    t = Track(
        name="curvy",
        stops_m=[0.0, 1000.0],
        speed_limit_positions_m=[0.0],
        speed_limits_mps=[20.0],
        gradient_positions_m=[0.0],
        gradients_permil=[5.0],
        curve_positions_m=[0.0, 100.0, 200.0, 300.0, 400.0, 500.0],
        curve_radius_start_m=[math.inf, 600.0, 600.0, -300.0, 20_000.0, math.inf],
        curve_radius_end_m=[math.inf, 600.0, -300.0, -300.0, 20_000.0, math.inf],
    )
    assert t.equivalent_gradient_permil_at(50.0) == pytest.approx(5.0)  # straight
    assert t.equivalent_gradient_permil_at(150.0) == pytest.approx(5.0 + 600 / 600)  # R = 600
    assert t.equivalent_gradient_permil_at(350.0) == pytest.approx(5.0 + 600 / 300)  # left-hand
    assert t.curvature_at(350.0) == pytest.approx(-1 / 300)
    assert t.equivalent_gradient_permil_at(450.0) == pytest.approx(5.0)  # R > 10 km ignored
    # clothoid 600 -> -300: curvature linear in s, 1/600 at 200 m to -1/300 at 300 m
    k_mid = 0.5 * (1 / 600 - 1 / 300)
    assert t.curvature_at(250.0) == pytest.approx(k_mid)
    assert t.curve_resistance_permil_at(250.0) == pytest.approx(600 * abs(k_mid))
    # force: m g sin(atan(i/1000)) + m g w_c/1000
    m = 2.0e5
    expected = m * G * (math.sin(math.atan(5e-3)) + 1e-3)
    assert t.gradient_force_N(150.0, m) == pytest.approx(expected)
    assert t.gradient_force_N(150.0, m, include_curves=False) == pytest.approx(
        m * G * math.sin(math.atan(5e-3))
    )


def test_downhill_force_is_negative() -> None:
    t = _simple()
    assert t.gradient_force_N(700.0, 1e5) == pytest.approx(-1e5 * G * math.sin(math.atan(0.01)))


def test_next_stop_after() -> None:
    track = get_track("CN_Songjiazhuang_Yizhuang")
    assert track.next_stop_after(0.0) == 2631.0
    assert track.next_stop_after(2630.0) == 2631.0
    assert track.next_stop_after(2631.0) == 3906.0
    assert track.next_stop_after(2631.0 - 1e-9) == 3906.0  # within the default tolerance
    assert track.next_stop_after(22728.0) is None


# ------------------------------------------------------------------ sections
def test_section_rebases_positions_and_keeps_properties() -> None:
    full = get_track("CN_Songjiazhuang_Yizhuang")
    a, b = 2631.0, 6272.0
    sec = full.section(a, b)
    assert sec.length_m == pytest.approx(b - a)
    np.testing.assert_allclose(sec.stops_m, [0.0, 3906.0 - a, b - a])
    assert sec.speed_limit_positions_m[0] == 0.0
    x = np.linspace(0.0, b - a, 5001)
    np.testing.assert_array_equal(sec.speed_limit_at(x), full.speed_limit_at(x + a))
    np.testing.assert_array_equal(sec.gradient_permil_at(x), full.gradient_permil_at(x + a))
    assert np.all(sec.speed_limit_positions_m < sec.length_m)
    assert sec.name == "CN_Songjiazhuang_Yizhuang[2631-6272]"


def test_section_cuts_clothoids_consistently() -> None:
    full = get_track("CH_StGallen_Wil")
    a, b = 80.0, 185.0  # both ends inside clothoids (49.6-125.6 and 172.5-198.5)
    sec = full.section(a, b)
    x = np.linspace(0.0, b - a, 2001)
    np.testing.assert_allclose(sec.curvature_at(x), full.curvature_at(x + a), atol=1e-12)
    np.testing.assert_allclose(
        sec.equivalent_gradient_permil_at(x), full.equivalent_gradient_permil_at(x + a), atol=1e-9
    )


def test_section_argument_validation() -> None:
    t = _simple()
    with pytest.raises(ValueError, match="section s_to"):
        t.section(100.0, 2000.0)
    with pytest.raises(ValueError, match="must be greater than s_from"):
        t.section(500.0, 400.0)


def test_to_dataframe_covers_the_track() -> None:
    track = get_track("CH_StGallen_Wil")
    df = track.to_dataframe()
    assert list(df.columns)[:4] == ["start_m", "end_m", "length_m", "v_limit_mps"]
    assert df["start_m"].iloc[0] == 0.0 and df["end_m"].iloc[-1] == track.length_m
    np.testing.assert_allclose(df["start_m"].to_numpy()[1:], df["end_m"].to_numpy()[:-1])
    assert df["length_m"].sum() == pytest.approx(track.length_m)
    assert set(df["v_limit_kmh"].round(6)) == set(np.round(track.speed_limits_mps / KMH, 6))


# ------------------------------------------------------------------ paper lines
def test_paper001_track_matches_the_paper() -> None:
    t = paper001_track()
    assert t.length_m == 400.0 and list(t.stops_m) == [0.0, 400.0]
    assert t.speed_limit_at(200.0) == 20.0
    assert t.gradient_permil_at(100.0) == 12.0
    assert t.gradient_permil_at(200.0) == 28.0
    assert t.gradient_permil_at(350.0) == -6.0


def test_paper_lines_have_documented_sources() -> None:
    for name, ctor in PAPER_TRACKS.items():
        t = ctor()
        assert t.name == name
        doc = (ctor.__doc__ or "").lower()
        assert t.source and "source" in doc and "assum" in doc
    multi = paper000_multi_section_track()
    np.testing.assert_array_equal(multi.stops_m, [0.0, 14687.0, 25279.0, 33086.0])
    assert multi.speed_limits_mps.max() < 45.8  # below the paper's over-speed protection
    hs = paper002_track()
    assert hs.length_m == 70_000.0 and hs.speed_limit_at(1.0) == 80.0
    d12 = paper004_track()
    assert d12.length_m == 2940.0
    assert np.all(np.abs(d12.gradients_permil) <= 30.0)
    assert d12.speed_limits_mps.max() == pytest.approx(80 * KMH)


@pytest.mark.parametrize(
    "track_id", ["paper004", "paper000_multi_section", *ttobench_track_ids()[:4]]
)
def test_equivalent_gradient_twins_equal_the_scalar_lookups(track_id: str) -> None:
    from train_envs import _jit
    from train_envs.lines.track import EQUIVALENT_GRADIENT

    tr = get_track(track_id)
    end = float(tr.stops_m[-1])
    edges = np.concatenate([tr.gradient_positions_m, tr.curve_positions_m, tr._cv_end_arr])
    x = np.concatenate(
        [np.random.default_rng(0).uniform(-50.0, end + 50.0, 3000), edges, edges - 1e-9]
    )
    args = tr.section_arrays()
    ref = _jit.implementation(EQUIVALENT_GRADIENT, compiled_twin=False)(x, *args)
    scalar = [tr.gradient_permil_at(s) + tr.curve_resistance_permil_at(s) for s in x.tolist()]
    assert ref.tolist() == scalar
    assert tr.equivalent_gradient_permil_at(x).tolist() == scalar
    assert tr.equivalent_gradient_permil_at(x.reshape(-1, 2)).reshape(-1).tolist() == scalar
    if _jit.enabled():
        fast = _jit.implementation(EQUIVALENT_GRADIENT, compiled_twin=True)(x, *args)
        assert np.array_equal(fast, ref)
