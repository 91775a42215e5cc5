"""The force envelope: effort tables, the hyperbola as their special case, the readers."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from train_envs.effort import EffortCurve, ForceEnvelope
from train_envs.trains import KMH, get_train, list_trains, train_from_ttobench

#: a diesel-hydraulic-like tractive effort (km/h, kN) and an electric brake that fades
#: out below 8 km/h (ASSUMED test numbers)
TRACTION = [(0.0, 150.0), (10.0, 128.0), (25.0, 96.0), (45.0, 62.0), (80.0, 44.0), (140.0, 18.0)]
BRAKE = [(0.0, 0.0), (8.0, 90.0), (60.0, 110.0), (100.0, 70.0), (140.0, 45.0)]


def _tabulated(**kw):
    tr = get_train("paper004_btype_metro")
    return replace(
        tr,
        traction_curve=EffortCurve.from_pairs(TRACTION),
        brake_curve=EffortCurve.from_pairs(BRAKE),
        **kw,
    )


SPEEDS = np.concatenate([[0.0, -0.0, 1e-12, 0.3], np.linspace(-5.0, 60.0, 651)])
SPEEDS = np.concatenate([SPEEDS, np.array([r[0] for r in TRACTION + BRAKE]) * KMH])


def test_curve_interpolates_the_table_and_holds_its_ends() -> None:
    c = EffortCurve.from_pairs(TRACTION, "km/h", "kN")
    vs = np.array([r[0] for r in TRACTION]) * KMH
    fs = np.array([r[1] for r in TRACTION]) * 1e3
    x = np.linspace(0.0, 60.0, 2001)
    np.testing.assert_allclose(c(x), np.interp(x, vs, fs), rtol=1e-13)
    assert c(vs).tolist() == fs.tolist()  # exact at the table speeds
    assert [c(float(v)) for v in x] == c(x).tolist()  # scalar == array, bit for bit
    assert c(1e3) == 18e3
    late = EffortCurve((5.0, 10.0), (100.0, 50.0))
    assert late(0.0) == 100.0 and late(7.5) == 75.0


@pytest.mark.parametrize(
    "speeds,forces,match",
    [
        ((), (), "at least 1"),
        ((0.0, 1.0), (1.0,), "as many"),
        ((0.0, 0.0), (1.0, 1.0), "strictly increasing"),
        ((-1.0, 1.0), (1.0, 1.0), "speeds_mps"),
        ((0.0, math.inf), (1.0, 1.0), "speeds_mps"),
        ((0.0, 1.0), (1.0, -1.0), "forces_N"),
        ((0.0, 1.0), (1.0, math.nan), "forces_N"),
    ],
)
def test_curve_rejects_bad_tables(speeds, forces, match) -> None:
    with pytest.raises(ValueError, match=match):
        EffortCurve(speeds, forces)


def test_bad_units_and_bad_train_fields_are_rejected() -> None:
    with pytest.raises(ValueError, match="speed_unit"):
        EffortCurve.from_pairs(TRACTION, speed_unit="mph")
    with pytest.raises(ValueError, match="force_unit"):
        EffortCurve.from_pairs(TRACTION, force_unit="lbf")
    tr = get_train("paper001_hst")
    with pytest.raises(ValueError, match="traction_curve"):
        replace(tr, traction_curve=[(0.0, 1.0)])
    with pytest.raises(ValueError, match="traction_curve"):
        replace(tr, traction_curve=EffortCurve((0.0,), (0.0,)))


def test_constant_table_is_the_hyperbolic_envelope_bit_for_bit() -> None:
    """The constant-force/constant-power train is the one-point table of the same object."""
    for name in list_trains():
        tr = get_train(name)
        one = replace(
            tr,
            traction_curve=EffortCurve((0.0,), (tr.max_traction_force_N,)),
            brake_curve=EffortCurve((0.0,), (tr.max_brake_force_N,)),
        )
        assert one.envelope_N(SPEEDS)[0].tolist() == tr.envelope_N(SPEEDS)[0].tolist(), name
        assert one.envelope_N(SPEEDS)[1].tolist() == tr.envelope_N(SPEEDS)[1].tolist(), name
        for v in SPEEDS.tolist():
            assert one.max_traction_N(v) == tr.max_traction_N(v), name
            assert one.max_brake_N(v) == tr.max_brake_N(v), name
        for lo, hi in [(0.0, 0.0), (0.0, 20.0), (5.0, 7.0)]:
            assert one.envelope_box(lo, hi) == tr.envelope_box(lo, hi), name


def test_tabulated_envelope_scalar_list_and_array_agree() -> None:
    tr = _tabulated()
    lo, hi = tr.envelope_N(SPEEDS)
    lo_l, hi_l = tr.envelope_lists(SPEEDS.tolist())
    assert lo_l == lo.tolist() and hi_l == hi.tolist()
    assert [tr.max_traction_N(v) for v in SPEEDS.tolist()] == hi.tolist()
    assert [-tr.max_brake_N(v) for v in SPEEDS.tolist()] == lo.tolist()
    lo0, hi0 = tr.envelope_N(np.float64(3.0))
    assert (float(lo0), float(hi0)) == (-tr.max_brake_N(3.0), tr.max_traction_N(3.0))


@pytest.mark.parametrize("name", list_trains())
def test_every_train_has_one_envelope_scalar_and_array(name) -> None:
    """The plant saturates with the scalar envelope, the batched plants and the
    controllers read the array form: the same numbers bit for bit for every catalogue
    train, on a dense grid of speeds (the acceleration limit ``M' a_max + R(v)`` of the
    TTOBench trains and paper 004's metro included)."""
    tr = get_train(name)
    v = np.concatenate([SPEEDS, np.linspace(0.0, 1.2 * min(tr.max_speed_mps, 120.0), 20001)])
    lo, hi = tr.envelope_N(v)
    assert [tr.max_traction_N(x) for x in v.tolist()] == hi.tolist()
    assert [-tr.max_brake_N(x) for x in v.tolist()] == lo.tolist()


def test_tabulated_envelope_is_the_min_of_its_terms() -> None:
    """F = min(F_t, T, P/v, M' a_max + R), B = min(min(F_b, E, P_b/v) + F_fric, M' d_max)."""
    tr = _tabulated()
    v = np.abs(SPEEDS)
    tv = np.interp(v, *np.array(TRACTION).T * [[KMH], [1e3]])
    ev = np.interp(v, *np.array(BRAKE).T * [[KMH], [1e3]])
    with np.errstate(divide="ignore"):
        f = np.minimum.reduce(
            [
                np.full(v.shape, tr.max_traction_force_N),
                tv,
                np.where(v > 0, tr.max_traction_power_W / v, np.inf),
                tr.inertial_mass_kg * tr.max_accel_mps2
                + np.array([abs(tr.resistance_N(x)) for x in v]),
            ]
        )
        b = np.minimum(
            np.minimum.reduce(
                [
                    np.full(v.shape, tr.max_brake_force_N),
                    ev,
                    np.where(v > 0, tr.max_brake_power_W / v, np.inf),
                ]
            )
            + tr.max_friction_brake_force_N,
            tr.inertial_mass_kg * tr.max_decel_mps2,
        )
    lo, hi = tr.envelope_N(SPEEDS)
    np.testing.assert_allclose(hi, f, rtol=1e-12)
    np.testing.assert_allclose(-lo, b, rtol=1e-12)
    # the brake fades out at standstill: friction only there
    assert tr.max_brake_N(0.0) == min(tr.max_friction_brake_force_N, tr.inertial_mass_kg)


def test_tabulated_box_lies_inside_the_envelope() -> None:
    rng = np.random.default_rng(3)
    tr = _tabulated()
    # without the comfort limits, so that the tables govern
    bare = replace(tr, max_accel_mps2=math.inf, max_decel_mps2=math.inf)
    for t in (tr, bare):
        cases = [(0.0, 0.0), (0.0, 3.0), (2.0, 2.3), (0.0, 40.0), (12.5, 12.5)]
        cases += [tuple(sorted(rng.uniform(0.0, 45.0, 2))) for _ in range(200)]
        for v_lo, v_hi in cases:
            lo_b, hi_b = t.envelope_box(v_lo, v_hi)
            v = np.concatenate([[v_lo, v_hi], np.linspace(v_lo, v_hi, 401)])
            lo, hi = t.envelope_N(v)
            assert np.all(lo <= lo_b) and np.all(hi >= hi_b), (v_lo, v_hi)
            # and tight: within the table's 8-ulp margin of the sampled extremes
            assert hi_b >= hi.min() - 1e-9 * hi.max() - 1e-3
    # a box over the brake's fade-out spans its standstill value
    assert bare.envelope_box(0.0, 5.0)[0] == -bare.max_friction_brake_force_N


def test_traction_fraction_scales_the_table() -> None:
    tr = _tabulated()
    ref = tr.with_traction_fraction(0.8)
    assert ref.traction_curve.forces_N == tuple(0.8 * f for f in tr.traction_curve.forces_N)
    assert ref.max_traction_force_N == 0.8 * tr.max_traction_force_N
    assert ref.brake_curve == tr.brake_curve
    with pytest.raises(ValueError, match="traction_fraction"):
        tr.with_traction_fraction(0.0)


def test_envelope_object_is_shared_and_reports_its_peak() -> None:
    tr = _tabulated()
    assert isinstance(tr.envelope, ForceEnvelope) and tr.envelope is tr.envelope
    assert tr.envelope.tabulated and not get_train("paper001_hst").envelope.tabulated
    assert tr.envelope.peak_traction_N() == min(tr.max_traction_force_N, 150e3)


def test_csv_reader(tmp_path) -> None:
    p = tmp_path / "curve.csv"
    p.write_text("speed_kmh,force_kN\n# a comment\n0,150\n\n10, 128\n25,96\n")
    c = EffortCurve.from_csv(p)
    assert c.speeds_mps == (0.0, 10 * KMH, 25 * KMH)
    assert c.forces_N == (150e3, 128e3, 96e3)
    p.write_text("0,150000\n20,100000\n")
    c = EffortCurve.from_csv(p, speed_unit="m/s", force_unit="N")
    assert c.speeds_mps == (0.0, 20.0) and c.forces_N == (150e3, 100e3)
    p.write_text("v,F\n0,1\nfast,2\n")
    with pytest.raises(ValueError, match="row 3"):
        EffortCurve.from_csv(p)
    p.write_text("v,F\n")
    with pytest.raises(ValueError, match="no \\(speed, force\\) rows"):
        EffortCurve.from_csv(p)


def test_ttobench_document_with_tables_and_length() -> None:
    from importlib import resources

    ref = (
        resources.files("train_envs") / "data" / "TTOBench" / "trains" / "CH_Stadler_FLIRT_TPF.json"
    )
    doc = json.loads(ref.read_text())
    plain = train_from_ttobench(doc)
    assert plain.traction_curve is None and plain.length_m == 0.0
    assert plain == get_train("CH_Stadler_FLIRT_TPF")
    doc["traction effort curve"] = {
        "units": {"velocity": "km/h", "force": "kN"},
        "values": [[0, 200], [60, 156], [160, 58.5]],
    }
    doc["reg braking effort curve"] = {
        "units": {"velocity": "m/s", "force": "N"},
        "values": [[0, 0], [2, 200000], [44.5, 58500]],
    }
    doc["length"] = {"unit": "m", "value": 74.1}
    tr = train_from_ttobench(doc)
    assert tr.traction_curve.speeds_mps == (0.0, 60 * KMH, 160 * KMH)
    assert tr.traction_curve.forces_N == (200e3, 156e3, 58.5e3)
    assert tr.brake_curve.forces_N == (0.0, 200e3, 58.5e3)
    assert tr.length_m == 74.1
    assert tr.traction_curve(30 * KMH) == pytest.approx(178e3, rel=1e-12)
    # here the comfort limit M' a_max + R(v) (1.1 m/s^2) is below the table
    m_a = tr.inertial_mass_kg * 1.1 + tr.resistance_N(30 * KMH)
    assert tr.max_traction_N(30 * KMH) == pytest.approx(min(178e3, m_a), rel=1e-12)
    bad = dict(doc, length={"unit": "ft", "value": 3})
    with pytest.raises(ValueError, match="length"):
        train_from_ttobench(bad)
    bad = dict(doc, **{"traction effort curve": {"values": [[0, 1]]}})
    with pytest.raises(ValueError, match="traction effort curve"):
        train_from_ttobench(bad)
    bad = dict(
        doc,
        **{
            "traction effort curve": {
                "units": {"velocity": "km/h", "force": "kN"},
                "values": [[0, 1, 2]],
            }
        },
    )
    with pytest.raises(ValueError, match="rows"):
        train_from_ttobench(bad)


def test_envelope_rejects_bad_limits() -> None:
    with pytest.raises(ValueError, match="brake_force_N"):
        ForceEnvelope(traction_force_N=1e5, brake_force_N=-1.0)
    with pytest.raises(ValueError, match="traction_power_W"):
        ForceEnvelope(traction_force_N=1e5, brake_force_N=1e5, traction_power_W=0.0)


def test_envelope_bounds_twins_are_equal_bit_for_bit() -> None:
    from train_envs import _jit
    from train_envs.effort import BOUNDS

    speeds = np.abs(np.concatenate([SPEEDS, np.random.default_rng(3).uniform(0, 40, 2000)]))
    envelopes = [
        _tabulated().envelope,
        _tabulated(max_friction_brake_force_N=2e4).envelope,
        get_train("paper004_btype_metro").envelope,
        ForceEnvelope(3e5, 2e5),
        ForceEnvelope(3e5, 2e5, traction_power_W=2e6, accel_force_N=2.8e5, davis=(1e3, 20.0, 3.0),
                      brake_power_W=3e6, friction_brake_N=1e4, decel_force_N=2.5e5),
    ]  # fmt: skip
    ref = _jit.implementation(BOUNDS, compiled_twin=False)
    for env in envelopes:
        T, E = env._t[1], env._b[1]
        tv = np.zeros(0) if T is None else np.asarray(T(speeds), float)
        ev = np.zeros(0) if E is None else np.asarray(E(speeds), float)
        lo, hi = ref(speeds, tv, ev, env._k)
        assert lo.tolist() == [-env.brake_N(v) for v in speeds.tolist()]
        assert hi.tolist() == [env.traction_N(v) for v in speeds.tolist()]
        lo2, hi2 = env.bounds(speeds.reshape(-1, 2))
        assert lo2.reshape(-1).tolist() == lo.tolist() and hi2.reshape(-1).tolist() == hi.tolist()
        if _jit.enabled():
            lo_c, hi_c = _jit.implementation(BOUNDS, compiled_twin=True)(speeds, tv, ev, env._k)
            assert np.array_equal(lo_c, lo) and np.array_equal(hi_c, hi)
