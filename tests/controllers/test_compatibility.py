"""Declared compatibility: every controller × scenario pair runs or is refused at
construction with its reason, and the supported pairs are sane with default parameters.

The short-horizon matrix (all of ``CONTROLLERS`` × all of ``SCENARIOS``, which hold the
two real lines, Yizhuang and Zürich) always runs. The whole-episode acceptance runs on
the undisturbed scenarios: a CI-sized subset by default (paper 001's stop and the Zürich
run), every scenario with ``TRAIN_ENVS_FULL_MATRIX=1`` (98 pairs, 26 min wall on the
shared 2-core machine at load 7–14; the measured table: ``docs/design/compatibility.md``).
"""

from __future__ import annotations

import os

import numpy as np
import pytest

from train_envs.controllers import (
    CONTROLLERS,
    Requirements,
    UnsupportedScenarioError,
    make_controller,
    requirements,
    scenario_defaults,
    unsupported_reason,
)
from train_envs.scenarios import SCENARIOS, DisturbanceSpec, get_scenario
from train_envs.simulation import ClosedLoop, simulate
from train_envs.simulation.supervision import DEFAULT_MARGIN_MPS

PAIRS = [(c, s) for s in SCENARIOS for c in CONTROLLERS]

#: control steps of the short-horizon run of a supported pair
SHORT_STEPS = 3

#: stop accuracy [m] and cruise tracking [m/s] every supported pair must reach
STOP_TOL_M = 0.5
CRUISE_EV_TOL_MPS = 1.0

#: supported pairs that miss the stop tolerance with default parameters (measured:
#: ``docs/design/compatibility.md``). Strict xfail: a pair that starts passing must leave.
KNOWN_MISSES = {
    ("fuzzy_pid", "paper004_urban"): "stops 0.76 m short; paper 004's comparator as reproduced",
    ("afsmc000", "zurich"): "stops 1.56 m long; speed-only sliding surface, no position loop",
}

#: the undisturbed scenarios of the acceptance test (the wind variants of paper 000
#: are its single section once the wind is removed)
UNDISTURBED = [
    s
    for s in SCENARIOS
    if s not in ("paper000_disturbance_constant", "paper000_disturbance_harmonic")
]
CI_SCENARIOS = ("paper001_stopping", "zurich")
FULL = os.environ.get("TRAIN_ENVS_FULL_MATRIX") == "1"


def test_every_controller_declares_its_requirements():
    for name in CONTROLLERS:
        req = requirements(name)
        assert isinstance(req, Requirements)
        assert req.description and "\n" not in req.description
        assert "\n" not in req.summary()
    with pytest.raises(ValueError, match="controller"):
        requirements("no_such_controller")


@pytest.mark.parametrize(("controller", "scenario"), PAIRS)
def test_pair_runs_or_is_refused_at_construction(controller, scenario):
    sc = get_scenario(scenario)
    reason = unsupported_reason(controller, sc)
    if reason is not None:
        assert "\n" not in reason and controller in reason and scenario in reason
        with pytest.raises(UnsupportedScenarioError) as err:
            make_controller(controller, sc)
        assert str(err.value) == reason
        with pytest.raises(UnsupportedScenarioError):
            simulate(sc, controller)
        return
    loop = ClosedLoop(sc, make_controller(controller, sc))
    loop.reset(seed=0)
    for _ in range(SHORT_STEPS):
        loop.step()
    df = loop.dataframe()
    assert len(df) >= SHORT_STEPS
    assert np.isfinite(df[["s_m", "v_mps", "u_cmd_N"]].to_numpy()).all()


def test_refusal_names_the_requirement():
    cases = {
        ("sempc", "paper001_stopping"): "multi-car",
        ("adaptive_mpc", "paper000_single_section"): "cruise task",
        ("adaptive_mpc", "paper003_cruise"): "no actuator dynamics",
        ("sempc", "paper003_cruise"): "order-2 actuator",
        ("fuzzy_mpc", "zurich"): "multi-car",
    }
    for (c, s), words in cases.items():
        assert words in unsupported_reason(c, get_scenario(s))
    per_car = get_scenario("paper002_cruise").with_overrides(input_mode="total")
    assert "input_mode" in unsupported_reason("sempc", per_car)
    assert unsupported_reason("sempc", get_scenario("paper000_single_section")) is None
    # without a scenario nothing is checked (the controller checks its context at reset)
    assert make_controller("sempc").name == "sempc"


def test_scenario_defaults_leave_the_own_paper_scenarios_alone():
    yz = get_scenario("yizhuang")
    assert scenario_defaults("pid", yz) == {"integrate_saturated": True}
    assert make_controller("pid", yz).integrate_saturated
    assert not make_controller("pid", yz, integrate_saturated=False).integrate_saturated
    # paper 001 is pid's own scenario (and distance-indexed), paper 004 fuzzy_pid's
    assert scenario_defaults("pid", get_scenario("paper001_stopping")) == {}
    assert scenario_defaults("fuzzy_pid", get_scenario("paper004_urban")) == {}
    assert scenario_defaults("fuzzy_pid", yz) == {"integrate_saturated": True}
    # cruise runs have no stop to make the position lag up for
    assert scenario_defaults("pid", get_scenario("paper003_cruise")) == {}
    assert scenario_defaults("mpc", yz) == {}


def test_integrating_through_saturation_recovers_the_start_lag():
    """On a time-indexed stop, ∫e dt is the lag behind the timetable: conditional
    integration forgets what was lost at the saturated start and stops short by it."""
    sc = get_scenario("yizhuang")
    derived = simulate(sc, "pid", seed=0)  # integrate_saturated=True by default here
    cond = simulate(sc, make_controller("pid", sc, integrate_saturated=False), seed=0)
    assert abs(derived.metrics["stop_error_m"]) <= STOP_TOL_M
    assert cond.metrics["stop_error_m"] < -1.0


def test_requirements_validate_their_fields():
    with pytest.raises(ValueError, match="cars"):
        Requirements("x", cars="two")
    with pytest.raises(ValueError, match="tasks"):
        Requirements("x", tasks=("parking",))
    with pytest.raises(ValueError, match="max_actuator_order"):
        Requirements("x", max_actuator_order=3)


def _acceptance_pairs():
    scenarios = UNDISTURBED if FULL else CI_SCENARIOS
    out = []
    for s in scenarios:
        sc = get_scenario(s)
        for c in CONTROLLERS:
            if unsupported_reason(c, sc) is not None:
                continue
            marks = ()
            if (c, s) in KNOWN_MISSES:
                marks = pytest.mark.xfail(strict=True, reason=KNOWN_MISSES[(c, s)])
            out.append(pytest.param(c, s, marks=marks, id=f"{c}@{s}"))
    return out


@pytest.mark.parametrize(("controller", "scenario"), _acceptance_pairs())
def test_supported_pair_is_sane_with_defaults(controller, scenario):
    """Undisturbed, default parameters: the stop within 0.5 m, never above the limit by
    the ATP margin; cruise runs track within 1 m/s on average."""
    sc = get_scenario(scenario).with_overrides(disturbance=DisturbanceSpec())
    m = simulate(sc, controller, seed=0).metrics
    assert m["max_overspeed_mps"] <= DEFAULT_MARGIN_MPS
    assert m["atp_interventions"] == 0
    if sc.s_stop_m is not None:
        assert abs(m["stop_error_m"]) <= STOP_TOL_M
    else:
        assert m["E_v_mps"] <= CRUISE_EV_TOL_MPS


def test_list_controllers_prints_description_and_requirements(capsys):
    from train_envs.cli import main

    assert main(["list", "controllers"]) == 0
    out = capsys.readouterr().out
    for name in CONTROLLERS:
        req = requirements(name)
        assert f"{name:14s} {req.description}" in out
        assert req.summary() in out
