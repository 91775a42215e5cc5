"""Fault cases of resume: stored settings by default, a changed one refused by name, one
selected solution per study everywhere, missing studies, list and delete."""

from __future__ import annotations

import pandas as pd
import pytest

from train_envs import cli

PID = "TrainEnvs/Stopping001PID-v0"
FIRST = [
    "tune", "--env", PID, "--algo", "mowoa", "--pop", "4", "--iters", "2", "--backend",
    "serial", "--seeds", "0", "1", "--objectives", "itae", "stop", "--no-progress",
]  # fmt: skip


def _main(argv, capsys):
    rc = cli.main(argv)
    out, err = capsys.readouterr()
    return rc, out, err


def _selected_key(text: str, csv: pd.DataFrame) -> str:
    return csv.loc[csv["selected"], "key"].item()


@pytest.fixture
def study(tmp_path, capsys):
    db = f"sqlite:///{tmp_path / 'runs.db'}"
    rc, out, err = _main([*FIRST, "--storage", db, "--study", "dmc004"], capsys)
    assert rc == 0, err
    return db


def test_the_readme_resume_line_works(study, capsys):
    """`train-envs tune --env ... --storage ... --study ... --resume` (README): every
    option left out takes the stored value; nothing is re-run."""
    rc, out, err = _main(["tune", "--env", PID, "--storage", study, "--study", "dmc004",
                          "--resume", "--no-progress", "--backend", "serial"], capsys)  # fmt: skip
    assert rc == 0, err
    assert out.startswith("dmc004: 0 evaluations run")
    assert "pop 4, iters 2, seed 1, scenario seeds [0, 1]" in out


@pytest.mark.parametrize(
    "option",
    [
        ["--target-weights", "0.7", "0.3"],
        ["--normalization", "pareto"],
        ["--no-defaults"],
        ["--f-lower", "0", "0", "--f-upper", "100", "1"],
        ["--seeds", "0"],
        ["--objectives", "itae", "comfort"],
        ["--pop", "6"],
        ["--config", '{"max_episode_steps": 50}'],
        ["--constraint", "E_p_m=1"],
    ],
)
def test_a_changed_setting_is_refused_by_name(study, capsys, option):
    rc, out, err = _main(["tune", "--storage", study, "--study", "dmc004", "--resume",
                          "--no-progress", *option], capsys)  # fmt: skip
    name = option[0].lstrip("-").replace("-", "_")
    name = {"no_defaults": "include_defaults", "f_lower": "f_bounds", "constraint": "constraints",
            "objectives": "objectives"}.get(name, name)  # fmt: skip
    assert rc == 2 and err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith(f"error: cannot resume study 'dmc004': {name} (stored ")


def test_one_selected_solution_everywhere(study, tmp_path, capsys):
    """Report, `tune show`, the returned result and the CSV name the same selection."""
    from tuners.run import load_result, tune

    out_dir = tmp_path / "out"
    rc, out, err = _main(["tune", "--storage", study, "--study", "dmc004", "--resume",
                          "--iters", "3", "--backend", "serial", "--no-progress",
                          "--out", str(out_dir)], capsys)  # fmt: skip
    assert rc == 0, err
    csv = pd.read_csv(out_dir / "dmc004.csv")
    key = csv.loc[csv["selected"], "key"].item()
    assert load_result("dmc004", study).selected["key"] == key
    res = tune(PID, storage=study, study="dmc004", resume=True, backend="serial")
    assert res.selected["key"] == key and res.stats.run == 0
    rc, shown, _ = _main(["tune", "show", "dmc004", "--storage", study], capsys)
    assert rc == 0 and "iters 3" in shown  # the extended budget is what the study says
    sel = shown.split("Selected")[1].splitlines()[2].split()
    assert float(sel[0]) == pytest.approx(res.selected["kp"], rel=1e-4)


def test_missing_study_list_and_delete(study, capsys):
    rc, _, err = _main(["tune", "--storage", study, "--study", "nope", "--resume"], capsys)
    assert rc == 2 and "study 'nope' holds no run" in err
    rc, out, _ = _main(["tune", "list", "--storage", study], capsys)
    assert rc == 0 and "dmc004" in out and PID in out
    rc, out, _ = _main(["tune", "delete", "dmc004", "--storage", study], capsys)
    assert rc == 0 and "deleted study 'dmc004'" in out
    rc, out, _ = _main(["tune", "list", "--storage", study], capsys)
    assert rc == 0 and "no studies" in out
    rc, _, err = _main(["tune", "delete", "dmc004", "--storage", study], capsys)
    assert rc == 2 and "no study 'dmc004'" in err


def test_a_run_failing_before_its_first_evaluation_does_not_block_the_name(tmp_path):
    """An existing study with no evaluation and no checkpoint starts afresh."""
    import optuna

    from tuners.run import tune

    db = f"sqlite:///{tmp_path / 'runs.db'}"
    optuna.create_study(study_name="Stopping001PID-v0-mowoa-s1", storage=db)
    r = tune(PID, pop=4, iters=1, backend="serial", storage=db, objectives=["itae", "stop"])
    assert r.study_name == "Stopping001PID-v0-mowoa-s1" and len(r.evaluations) > 0
