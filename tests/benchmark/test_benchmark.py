"""The benchmark: a CI-sized matrix, the leaderboard's statistics, resume, failures,
unsupported rows, the disturbance the seeds draw, the real-line set and the
``train-envs benchmark`` command."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from train_envs import cli
from train_envs.benchmark import (
    DISTURBANCES,
    apply_disturbance,
    benchmark_scenario,
    leaderboard,
    real_line_pairs,
    resolve_disturbance,
    resolve_scenarios,
    run_benchmark,
)
from train_envs.benchmark.leaderboard import HEADLINE, mean_ci95
from train_envs.benchmark.run import CELLS_FILE
from train_envs.lines import get_track
from train_envs.scenarios import get_scenario
from train_envs.simulation import simulate

STOP = "paper001_stopping"
LOAD = resolve_disturbance("load")


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    """pid and dmc on paper 001 over two seeds, adaptive_mpc unsupported there."""
    out = tmp_path_factory.mktemp("bench")
    res = run_benchmark(out, [STOP], ["pid", "dmc", "adaptive_mpc"], [0, 1], progress=False)
    return out, res


def test_tidy_table_holds_every_cell_and_metric(small):
    _, res = small
    t = res.table
    assert len(t) == 4  # 2 supported controllers x 2 seeds; the unsupported pair has no cells
    assert set(zip(t["controller"], t["seed"], strict=True)) == {
        ("pid", 0), ("pid", 1), ("dmc", 0), ("dmc", 1)
    }  # fmt: skip
    assert (t["status"] == "ok").all() and (t["parameters"] == "{}").all()
    for col in ("scenario", "controller", "parameters", "seed", "E_p_m", "ITAE_m_s",
                "safety_cost", "atp_interventions", "overrun_m", "max_overspeed_mps"):  # fmt: skip
        assert col in t, col
    assert (t["disturbance"] == LOAD).all()
    # a cell is the runner's episode on the disturbed scenario: the same metrics as simulate()
    ref = simulate(apply_disturbance(get_scenario(STOP), LOAD), "pid", seed=1).metrics
    row = t[(t["controller"] == "pid") & (t["seed"] == 1)].iloc[0]
    assert row["E_p_m"] == ref["E_p_m"] and row["safety_cost"] == ref["safety_cost"]
    # the seeds draw the disturbance: two seeds of one pair are two episodes
    for c in ("pid", "dmc"):
        a, b = t[t["controller"] == c]["energy_kWh"]
        assert a != b, c


def test_leaderboard_one_row_per_pair_with_t_interval(small):
    _, res = small
    b = res.board.set_index("controller")
    assert list(res.board["controller"]) == ["pid", "dmc", "adaptive_mpc"]
    assert b.loc["adaptive_mpc", "status"] == "unsupported"
    assert b.loc["adaptive_mpc", "note"].startswith("unsupported: ")
    assert "multi-car" in b.loc["adaptive_mpc", "note"]
    t = res.table[res.table["controller"] == "dmc"]
    x = t["E_v_mps"].to_numpy()
    half = stats.t.ppf(0.975, len(x) - 1) * np.std(x, ddof=1) / np.sqrt(len(x))
    assert b.loc["dmc", "E_v_mps"] == pytest.approx(x.mean(), rel=1e-12)
    assert b.loc["dmc", "E_v_mps_ci95"] == pytest.approx(half, rel=1e-9)
    assert b.loc["dmc", "n_seeds"] == 2 and b.loc["dmc", "E_v_mps_ci95"] > 0
    assert b.loc["dmc", "disturbance"] == "load"
    # ranked by the stop error on a stopping run
    ranked = res.board.dropna(subset=["rank"]).sort_values("rank")
    assert ranked["E_p_m"].is_monotonic_increasing


def test_outputs_written(small):
    out, res = small
    for name in ("results.csv", "leaderboard.csv", "leaderboard.md", "heatmap.png"):
        assert (out / name).stat().st_size > 0, name
    assert (out / "overlays" / f"{STOP}.png").exists()
    assert len(pd.read_csv(out / "leaderboard.csv")) == 3
    md = (out / "leaderboard.md").read_text()
    assert f"### {STOP}" in md and "unsupported: " in md


def test_resume_runs_nothing_again(small):
    out, res = small
    lines = (out / CELLS_FILE).read_text().splitlines()
    again = run_benchmark(out, [STOP], ["pid", "dmc", "adaptive_mpc"], [0, 1], progress=False)
    assert again.cells_run == 0
    assert (out / CELLS_FILE).read_text().splitlines() == lines
    pd.testing.assert_frame_equal(again.table, res.table)


def test_resume_after_a_torn_line_and_a_new_seed(tmp_path):
    run_benchmark(tmp_path, [STOP], ["pid"], [0], progress=False, figures=False)
    with (tmp_path / CELLS_FILE).open("a") as f:
        f.write('{"scenario": "paper001_st')  # a run killed while writing
    res = run_benchmark(tmp_path, [STOP], ["pid"], [0, 2], progress=False, figures=False)
    assert res.cells_run == 1 and list(res.table["seed"]) == [0, 2]


def test_failing_cell_is_recorded_and_the_others_run(tmp_path):
    params = {(STOP, "pid"): {"nope": 1.0}, (STOP, "tracking"): "tuning failed: no reason"}
    res = run_benchmark(
        tmp_path, [STOP], ["pid", "tracking", "dmc"], [0], params=params, progress=False
    )
    b = res.board.set_index("controller")
    assert (
        b.loc["pid", "status"] == "failed" and "no tunable parameter 'nope'" in b.loc["pid", "note"]
    )
    assert b.loc["tracking", "note"] == "failed (1/1): tuning failed: no reason"
    assert b.loc["dmc", "status"] == "ok" and b.loc["dmc", "E_p_m"] < 0.5
    rec = [json.loads(x) for x in (tmp_path / CELLS_FILE).read_text().splitlines()]
    assert [r["status"] for r in rec] == ["failed", "failed", "ok"]
    assert json.loads(rec[0]["parameters"]) == {"nope": 1.0}


def test_no_disturbance_reproduces_the_named_scenario_in_its_own_cells(small, tmp_path):
    out, _ = small
    (tmp_path / CELLS_FILE).write_text((out / CELLS_FILE).read_text())
    res = run_benchmark(
        tmp_path, [STOP], ["pid"], [0, 1], disturbance="none", progress=False, figures=False
    )
    assert res.cells_run == 2  # the load cells in the folder are not taken for these
    t = res.table
    assert (t["disturbance"] == "{}").all() and res.board.iloc[0]["disturbance"] == "none"
    ref = simulate(STOP, "pid", seed=0).metrics
    assert t.iloc[0]["E_p_m"] == ref["E_p_m"] and t.iloc[0]["energy_kWh"] == ref["energy_kWh"]
    assert t.iloc[0]["energy_kWh"] == t.iloc[1]["energy_kWh"]  # deterministic scenario


def test_disturbance_merges_over_the_scenario_own():
    wind = get_scenario("paper000_disturbance_constant")
    sc = apply_disturbance(wind, LOAD)
    assert sc.disturbance.wind == "constant" and sc.disturbance.w0_mps2 == wind.disturbance.w0_mps2
    assert sc.disturbance.mass_factor_range == tuple(DISTURBANCES["load"]["mass_factor_range"])
    assert sc.disturbance.random_bound_mps2 == 0.03
    assert apply_disturbance(wind, resolve_disturbance("none")) is wind
    text = resolve_disturbance('{"random_bound_mps2": 0.01, "mass_factor_range": [1, 1.1]}')
    assert text == resolve_disturbance({"mass_factor_range": (1, 1.1), "random_bound_mps2": 0.01})


def test_pairs_are_checked_under_the_benchmark_disturbance():
    from train_envs.benchmark import pair_reasons

    sec, wind = ["paper000_single_section"], resolve_disturbance('{"wind": "constant"}')
    assert pair_reasons(sec, ["fuzzy_mpc"]) == {}
    assert "persistent disturbance" in pair_reasons(sec, ["fuzzy_mpc"], wind)[sec[0], "fuzzy_mpc"]


@pytest.mark.parametrize(
    "spec,needle",
    [
        ("heavy", "preset (load, none)"),
        ('{"mass_factor": [1, 2]}', "unknown field(s) mass_factor"),
        ('{"random_bound_mps2": 5}', "disturbance.random_bound_mps2"),
        ('{"mass_factor_range": [1.2, 1.0]}', "disturbance.mass_factor_range[1]"),
        ("{nope", "not a JSON object"),
    ],
)
def test_bad_disturbance_is_one_line(spec, needle):
    with pytest.raises(ValueError, match="disturbance") as exc:
        resolve_disturbance(spec)
    assert needle in str(exc.value) and "\n" not in str(exc.value)


def test_mean_ci95_edge_cases():
    assert mean_ci95([2.0]) == (2.0, pytest.approx(np.nan, nan_ok=True))
    assert mean_ci95([1.0, 1.0, 1.0]) == (1.0, 0.0)
    m, h = mean_ci95([1.0, 3.0])
    assert m == 2.0 and h == pytest.approx(stats.t.ppf(0.975, 1) * 1.0)
    assert np.isnan(mean_ci95([])[0])


def test_leaderboard_partial_pair():
    table = pd.DataFrame({
        "scenario": ["a"] * 3, "controller": ["x"] * 3, "parameters": ["{}"] * 3,
        "seed": [0, 1, 2], "status": ["ok", "ok", "failed"], "error": ["", "", "boom"],
        "E_v_mps": [1.0, 2.0, np.nan],
    })  # fmt: skip
    row = leaderboard(table).iloc[0]
    assert row["status"] == "partial" and row["n_seeds"] == 2
    assert row["E_v_mps"] == 1.5 and row["note"] == "failed (1/3): boom"
    assert set(HEADLINE) & set(leaderboard(table).columns) == {"E_v_mps"}


def test_real_line_set_is_every_station_pair():
    pairs = real_line_pairs()
    n = {
        line: len(get_track(get_scenario(line).extra["line"]).stops_m) - 1
        for line in ("yizhuang", "zurich")
    }
    assert len(pairs) == sum(n.values()) == len(set(pairs))
    assert pairs[0] == "yizhuang_0_1" and pairs[-1] == f"zurich_{n['zurich'] - 1}_{n['zurich']}"
    assert resolve_scenarios(["real-lines", "yizhuang_0_1"]) == pairs
    a, b = benchmark_scenario("yizhuang_0_1"), get_scenario("yizhuang")
    assert (a.s_stop_m, a.scheduled_time_s, a.train.name) == (
        b.s_stop_m,
        b.scheduled_time_s,
        b.train.name,
    )
    sc = benchmark_scenario("zurich_2_3")
    assert sc.extra["from_stop"] == 2 and sc.name == "zurich_2_3"


@pytest.mark.parametrize("name", ["nope", "yizhuang_0_99", "paper001_stopping_0_1"])
def test_unknown_scenario_names(name):
    with pytest.raises(ValueError):
        resolve_scenarios([name])


def test_cli_line_writes_one_row_per_pair(tmp_path, capsys):
    argv = ["benchmark", "--scenarios", STOP, "paper004_urban", "--controllers", "pid", "dmc",
            "sempc", "--seeds", "0", "--out", str(tmp_path), "--no-progress"]  # fmt: skip
    assert cli.main(argv) == 0
    board = pd.read_csv(tmp_path / "leaderboard.csv")
    pairs = set(zip(board["scenario"], board["controller"], strict=True))
    assert len(board) == 6 and pairs == {
        (s, c) for s in (STOP, "paper004_urban") for c in ("pid", "dmc", "sempc")
    }
    assert "6 pairs" in capsys.readouterr().out


@pytest.mark.parametrize(
    "extra,needle",
    [
        (["--scenarios", "nope"], "unknown scenario 'nope'"),
        (["--controllers", "nope"], "unknown controller 'nope'"),
        (["--seeds", "5-1"], "--seeds"),
        (["--full-budget"], "--full-budget goes with --tuned"),
        (["--workers", "0"], "--workers"),
        (["--disturbance", '{"wind": "gale"}'], "disturbance.wind"),
        (["--disturbance", "heavy"], "disturbance must be a preset"),
    ],
)
def test_cli_errors_are_one_line(tmp_path, capsys, extra, needle):
    assert cli.main(["benchmark", "--out", str(tmp_path / "o"), *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and needle in err and len(err.splitlines()) == 1
    assert not (tmp_path / "o" / CELLS_FILE).exists()


def test_publish_replaces_the_block(small, tmp_path):
    from train_envs.benchmark.publish import publish

    out, _ = small
    doc = tmp_path / "doc.md"
    doc.write_text("intro\n<!-- leaderboard:default -->\nold\n<!-- /leaderboard:default -->\nend\n")
    publish("default", out, doc)
    text = doc.read_text()
    assert text.startswith("intro\n") and text.endswith("end\n") and "\nold\n" not in text
    summary = "3 pairs (2 ok, 1 unsupported); default parameters; disturbance load; seeds [0, 1]"
    assert summary in text
    with pytest.raises(ValueError, match="no block"):
        publish("tuned", out, doc)
