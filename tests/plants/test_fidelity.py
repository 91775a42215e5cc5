"""Plant fidelity: open-loop replays against an independent DOP853 integration, the
order of the step across gradient breakpoints, the curve-resistance cut-off, standstill.

Figures and the command that measures them: ``docs/fidelity.md``.
"""

from __future__ import annotations

import numpy as np
import pytest
from dop853_replay import compare, record

from train_envs.lines.track import Track
from train_envs.plants import ActuatorParams, TrainPlant
from train_envs.plants.lookup import PiecewiseLinear, gradient_table
from train_envs.scenarios import build_plant, get_scenario, list_scenarios
from train_envs.simulation import ClosedLoop
from train_envs.trains import get_train


def test_paper001_pid_replay_matches_dop853_within_2_mm():
    """Paper 001's PID stop (lag + dead time, gradient steps 12/28/−6 ‰) replayed at the
    default 0.05 s sub-step: within 2 mm and 1 mm/s of DOP853 (rtol 1e-10)."""
    c = compare(record("paper001_stopping", "pid"))
    assert c["ds_m"] <= 2e-3
    assert c["dv_mps"] <= 1e-3


@pytest.mark.parametrize("scenario", ["paper000_single_section", "paper000_disturbance_harmonic"])
def test_paper000_sempc_replay_matches_dop853(scenario):
    """Paper 000's 6-car SEMPC runs (couplers k = 1e7 N/m) from rest to the stop, with
    and without the harmonic wind: positions within 5 mm, coupler forces within 2 % of
    their peak."""
    c = compare(record(scenario, "sempc"))
    assert c["ds_m"] <= 5e-3
    assert c["df_share"] <= 0.02


def _gradient_step_run(h: float, n_cars: int, t_end: float = 12.0) -> np.ndarray:
    """Positions of every car after coasting against a braking force over two gradient
    steps (0 → 30 → −10 ‰), sub-step ``h``."""
    track = Track(
        name="steps",
        stops_m=np.array([0.0, 1000.0]),
        speed_limit_positions_m=np.array([0.0]),
        speed_limits_mps=np.array([30.0]),
        gradient_positions_m=np.array([0.0, 60.3, 151.7]),
        gradients_permil=np.array([0.0, 30.0, -10.0]),
    )
    train = get_train("paper000_dtype_metro") if n_cars > 1 else get_train("paper001_hst")
    plant = TrainPlant(
        train, gradient_table(track), n_cars=n_cars, actuator=ActuatorParams(order=0),
        dt_sim_s=h, car_length_m=2.0,
    )  # fmt: skip
    plant.reset(0.0, 20.0)
    u = -0.05 * train.mass_kg
    for _ in range(int(round(t_end / 0.2))):
        plant.step(u, 0.2)
    return plant.positions


@pytest.mark.parametrize("n_cars", [1, 3])
def test_no_first_order_error_at_gradient_steps(n_cars):
    """Against the same plant at a 32 times finer sub-step, the positions after
    crossing two gradient steps stay within 10 µm at 0.05 s and 0.025 s (measured:
    0.02 µm and 5 µm for 1 and 3 cars).  A step that integrates across the jumps errs
    by ``½ Δa h`` in speed per jump: 12–24 mm here, halving with ``h``."""
    ref = _gradient_step_run(0.05 / 32, n_cars)
    for h in (0.05, 0.025):
        assert np.max(np.abs(_gradient_step_run(h, n_cars) - ref)) < 1e-5


def test_curve_resistance_cut_off_is_a_breakpoint():
    """A clothoid from straight to R = 500 m crosses the 10 km cut-off 5 m in: the table
    jumps there from 0 to 0.06 ‰ instead of interpolating across, and agrees with the
    track's equivalent gradient everywhere else."""
    track = Track(
        name="clothoid",
        stops_m=np.array([0.0, 1000.0]),
        speed_limit_positions_m=np.array([0.0]),
        speed_limits_mps=np.array([30.0]),
        curve_positions_m=np.array([0.0, 200.0, 300.0, 400.0]),
        curve_radius_start_m=np.array([np.inf, np.inf, 500.0, np.inf]),
        curve_radius_end_m=np.array([np.inf, 500.0, 500.0, np.inf]),
    )
    cut = 200.0 + 100.0 * (1e-4 / (1.0 / 500.0))
    assert cut in track.resistance_breakpoints_m().tolist()
    tab = gradient_table(track)
    assert isinstance(tab, PiecewiseLinear)
    assert tab(cut - 1e-9) == 0.0
    assert tab(cut) == pytest.approx(0.06, rel=1e-9)
    s = np.linspace(0.0, 999.0, 4001)
    s = s[np.abs(s - cut) > 1e-6]
    np.testing.assert_allclose(tab(s), track.equivalent_gradient_permil_at(s), atol=1e-12)


def _ramp_from_rest(name: str) -> tuple[np.ndarray, np.ndarray]:
    """Lead-car positions and speeds of a scenario's plant started at rest, with its
    disturbances, under a braking command for 2 s and then traction rising from 0 to
    the full envelope over 10 s."""
    sc = get_scenario(name).with_overrides(v0_mps=0.0)
    plant = build_plant(sc, np.random.default_rng(0))
    n_in = sc.n_cars if sc.input_mode == "per_car" else 1
    f_max = sc.train.max_traction_N(0.0)
    s, v = [plant.s], [plant.v]
    for k in range(int(round(12.0 / sc.dt_ctrl_s))):
        t = k * sc.dt_ctrl_s
        u = -0.3 * sc.train.max_brake_N(0.0) if t < 2.0 else f_max * min((t - 2.0) / 10.0, 1.0)
        plant.step(np.full(n_in, u / n_in) if n_in > 1 else u, sc.dt_ctrl_s)
        s.append(plant.s)
        v.append(plant.v)
    return np.array(s), np.array(v)


@pytest.mark.parametrize("name", list_scenarios())
def test_no_roll_back_at_start(name):
    """In every scenario a train leaving rest (its disturbances on, wind included) never
    moves backwards: it is held until the traction overcomes gradient, wind and the
    Davis constant term, then moves forward."""
    s, v = _ramp_from_rest(name)
    assert np.all(v >= 0.0)
    assert np.all(np.diff(s) >= 0.0)
    assert s[-1] > s[0] + 1.0  # it did start


@pytest.mark.parametrize("name", ["paper000_disturbance_constant", "paper000_disturbance_harmonic"])
def test_closed_loop_start_in_wind_does_not_roll_back(name):
    """The wind scenarios' own controller start: the lead car's position never falls
    below its start (a plant that releases the train from rest without counting the
    wind rolls it back 0.7 mm at 7 mm/s, docs/fidelity.md)."""
    from train_envs.controllers import make_controller

    sc = get_scenario(name)
    loop = ClosedLoop(sc, make_controller("sempc", sc))
    loop.reset(seed=0)
    s = []
    for _ in range(50):
        loop.step()
        s.append(loop.plant.s)
        assert loop.plant.v >= 0.0
    assert min(s) >= sc.s0_m
    assert s[-1] > sc.s0_m


def test_paper001_resistance_readings():
    """Paper 001's unitless ``5.4 + 0.0098 v + 0.00163 v²``: N/kN with v in m/s (default)
    or N/t with v in km/h, 4.2× lower at 20 m/s and 8.8× lower at 5 m/s; the scenario
    option builds the other reading, and its PID run still stops in the ±0.5 m window."""
    from train_envs.scenarios import paper001_stopping, paper001_train
    from train_envs.simulation import simulate

    kn, nt = paper001_train("N/kN"), paper001_train("N/t")
    assert kn is get_train("paper001_hst")
    assert kn.resistance_N(20.0) == pytest.approx(490 * 9.81 * (5.4 + 0.196 + 0.652))
    assert nt.resistance_N(20.0) == pytest.approx(490 * (5.4 + 0.0098 * 72 + 0.00163 * 72**2))
    assert kn.resistance_N(20.0) / nt.resistance_N(20.0) == pytest.approx(4.21, abs=0.01)
    assert kn.resistance_N(5.0) / nt.resistance_N(5.0) == pytest.approx(8.82, abs=0.01)
    sc = paper001_stopping(resistance_reading="N/t")
    assert sc.train is not kn and sc.train.davis_a_N == pytest.approx(5.4 * 490)
    assert abs(simulate(sc, "pid", seed=0).metrics["stop_error_m"]) <= 0.5
    with pytest.raises(ValueError, match="resistance_reading"):
        paper001_train("kN")
