"""Fault cases of the command line: every bad input is one ``error:`` line on stderr,
exit code 2, no traceback, found before any work starts, and no database is created
by a reader."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import optuna
import pytest

from train_envs import cli

ROOT = Path(__file__).resolve().parents[2]
PID = "TrainEnvs/Stopping001PID-v0"
TUNE = ["tune", "--env", PID, "--pop", "4", "--iters", "1", "--backend", "serial",
        "--no-progress", "--objectives", "itae", "stop"]  # fmt: skip


@pytest.fixture
def files(tmp_path):
    good = tmp_path / "good.db"
    optuna.create_study(study_name="s", storage=f"sqlite:///{good}")
    (tmp_path / "corrupt.db").write_bytes(b"this is not a database" * 100)
    raw = good.read_bytes()
    (tmp_path / "truncated.db").write_bytes(raw[: len(raw) // 3])
    (tmp_path / "afile").write_text("")
    return tmp_path


CASES = {
    "unknown env id": ["tune", "--env", "TrainEnvs/Nope-v0"],
    "config file missing": [*TUNE, "--config", "@{d}/missing.json"],
    "config not JSON": [*TUNE, "--config", "{{nope"],
    "config not an object": [*TUNE, "--config", "[1, 2]"],
    "storage URL scheme": [*TUNE, "--storage", "nodb://x"],
    "storage folder missing": [*TUNE, "--storage", "sqlite:///{d}/no/such/x.db"],
    "corrupt database": [*TUNE, "--storage", "sqlite:///{d}/corrupt.db"],
    "truncated database": [*TUNE, "--storage", "sqlite:///{d}/truncated.db"],
    "pop below objectives": [*TUNE, "--pop", "2", "--objectives", "itae", "stop", "comfort"],
    "pop below 2": [*TUNE, "--pop", "1"],
    "seeds empty range": [*TUNE, "--seeds", "5-1"],
    "seeds not integers": [*TUNE, "--seeds", "x"],
    "seeds negative": [*TUNE, "--seeds", "-1"],
    "holdout seeds": [*TUNE, "--holdout-seeds", "x"],
    "out folder not writable": [*TUNE, "--out", "{d}/afile/sub"],
    "unknown objective": [*TUNE, "--objectives", "itae", "nosuch"],
    "unknown constraint metric": [*TUNE, "--constraint", "nosuch=0"],
    "constraint limit": [*TUNE, "--constraint", "E_p_m=abc"],
    "constraint limit nan": [*TUNE, "--constraint", "E_p_m=nan"],
    "target weights count": [*TUNE, "--target-weights", "1", "2", "3"],
    "target weights nan": [*TUNE, "--target-weights", "nan", "1"],
    "target weights negative": [*TUNE, "--target-weights", "-1", "2"],
    "f-lower alone": [*TUNE, "--f-lower", "0", "0"],
    "resume missing study": ["tune", "--study", "nope", "--resume", "--storage", "sqlite:///{d}/good.db"],
    "show missing database": ["tune", "show", "s", "--storage", "sqlite:///{d}/missing.db"],
    "show missing study": ["tune", "show", "nope", "--storage", "sqlite:///{d}/good.db"],
    "list missing database": ["tune", "list", "--storage", "sqlite:///{d}/missing.db"],
    "evaluate missing database": [
        "evaluate", "--env", PID, "--params", "sqlite:///{d}/missing.db:s", "--episodes", "1",
    ],
    "evaluate bad seeds": ["evaluate", "--env", PID, "--controller", "defaults", "--seeds", "3-0"],
    "simulate bad param": ["simulate", "--param", "kp=abc"],
    "train hyperparameter type": [
        "train", "--env", PID, "--timesteps", "64", "--hyperparams", "n_steps=abc",
        "--out", "{d}/run", "--no-progress", "--no-tensorboard",
    ],
}  # fmt: skip


@pytest.mark.parametrize("case", list(CASES))
def test_bad_input_is_one_line_exit_2_before_work(files, capsys, monkeypatch, case):
    argv = [a.format(d=files) for a in CASES[case]]
    monkeypatch.chdir(files)  # the default storage would be ./tuning.db
    before = sorted(p.name for p in files.iterdir())
    assert cli.main(argv) == 2
    out, err = capsys.readouterr()
    assert err.startswith("error: ") and err.count("\n") == 1 and "Traceback" not in err, err
    after = sorted(p.name for p in files.iterdir())
    new = set(after) - set(before)
    assert not {n for n in new if n.endswith(".db")}, f"a database was created: {new}"


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes to read-only files")
def test_read_only_database_is_one_line(files, capsys):
    db = files / "ro.db"
    optuna.create_study(study_name="x", storage=f"sqlite:///{db}")
    db.chmod(0o444)
    assert cli.main([*TUNE, "--storage", f"sqlite:///{db}", "--study", "y"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1


def test_a_real_process_prints_no_traceback_and_debug_shows_it(tmp_path):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    argv = [sys.executable, "-m", "train_envs.cli"]
    bad = ["tune", "--env", PID, "--seeds", "5-1"]
    r = subprocess.run([*argv, *bad], env=env, cwd=tmp_path, capture_output=True, text=True)
    assert r.returncode == 2 and r.stderr == (
        "error: --seeds: range '5-1' is empty (write a-b with a <= b)\n"
    )
    r = subprocess.run([*argv, "--debug", *bad], env=env, cwd=tmp_path, capture_output=True,
                       text=True)  # fmt: skip
    assert r.returncode == 1 and "Traceback" in r.stderr
    r = subprocess.run([*argv, "--version"], env=env, cwd=tmp_path, capture_output=True, text=True)
    assert r.returncode == 0 and r.stdout.startswith("train-envs ")
    assert not list(tmp_path.iterdir())  # nothing written, no tuning.db
