"""Fault cases of concurrent writers: one writer per study, stale leases taken over."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import optuna
import pytest
from study_watch import wait_for_trials

from tuners.lease import LEASES, StudyLease, StudyLockedError, lease_holder
from tuners.storage import open_storage

ROOT = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}
PID = "TrainEnvs/Stopping001PID-v0"
optuna.logging.set_verbosity(optuna.logging.WARNING)

SLOW = textwrap.dedent(
    """
    import sys
    from pymoo.problems import get_problem
    from tuners.problem import PymooTaskProblem
    from tuners.run import tune
    if __name__ == "__main__":
        p = PymooTaskProblem(get_problem("zdt1", n_var=4), delay_s=0.3, name="zdt1")
        tune(p, "mowoa", pop=4, iters=50, backend="serial", storage=sys.argv[1], study="s",
             seed=1)
    """
)


def test_second_writer_refused_then_stale_lease_taken_over(tmp_path):
    from pymoo.problems import get_problem

    from tuners.problem import PymooTaskProblem
    from tuners.run import tune

    dbfile = tmp_path / "runs.db"
    db = f"sqlite:///{dbfile}"
    script = tmp_path / "slow.py"
    script.write_text(SLOW)
    proc = subprocess.Popen([sys.executable, str(script), db], env=ENV, cwd=tmp_path)
    try:
        wait_for_trials(dbfile, 5, proc)
        prob = PymooTaskProblem(get_problem("zdt1", n_var=4), name="zdt1")
        with pytest.raises(
            StudyLockedError, match=rf"written by {socket.gethostname()}:{proc.pid}"
        ):
            tune(prob, storage=db, study="s", resume=True, backend="serial")
        info = lease_holder(open_storage(db), "s")
        assert info["live"] and info["holder"] == f"{socket.gethostname()}:{proc.pid}"
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(30)
    # the holder is dead: its lease is stale and the resume takes it over
    done = optuna.load_study(study_name="s", storage=db).user_attrs["tuner_config"]
    r = tune(prob, storage=db, study="s", resume=True, backend="serial", iters=3)
    assert (
        r.study_name == "s" and done["iters"] == 50 and lease_holder(open_storage(db), "s") is None
    )


def test_stale_heartbeat_of_another_host_is_taken_over_and_a_live_one_refused(tmp_path):
    st = open_storage(f"sqlite:///{tmp_path / 'x.db'}")
    held = StudyLease(st, "s").acquire()
    with pytest.raises(StudyLockedError, match="being written by"):
        StudyLease(st, "s").acquire()
    held.release()
    with st.engine.begin() as con:  # a writer elsewhere, silent for 10 minutes
        con.execute(
            LEASES.insert().values(
                study_name="s", holder="elsewhere:1/abc", heartbeat=time.time() - 600, started=0.0
            )
        )
    lease = StudyLease(st, "s").acquire()
    assert lease_holder(st, "s")["holder"] == f"{socket.gethostname()}:{os.getpid()}"
    lease.release()


def test_two_fresh_starts_at_once_one_refused_cleanly(tmp_path):
    db = f"sqlite:///{tmp_path / 'runs.db'}"
    argv = [sys.executable, "-m", "train_envs.cli", "tune", "--env", PID, "--pop", "4",
            "--iters", "2", "--backend", "serial", "--objectives", "itae", "stop",
            "--storage", db, "--study", "same", "--no-progress"]  # fmt: skip
    procs = [
        subprocess.Popen(
            argv, env=ENV, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )  # fmt: skip
        for _ in range(2)
    ]
    outs = [p.communicate(timeout=300) for p in procs]
    rcs = sorted(p.returncode for p in procs)
    errs = [e for _, e in outs]
    assert rcs == [0, 2], errs
    (err,) = [e for p, (_, e) in zip(procs, outs, strict=True) if p.returncode == 2]
    assert "Traceback" not in err and err.count("\n") == 1
    assert "being written by" in err or "already holds a run" in err


def test_delete_is_refused_while_a_run_holds_the_study(tmp_path):
    from tuners.storage import delete_study

    db = f"sqlite:///{tmp_path / 'x.db'}"
    optuna.create_study(study_name="s", storage=db)
    st = open_storage(db)
    held = StudyLease(st, "s").acquire()
    with pytest.raises(StudyLockedError, match="being written by"):
        delete_study("s", db)
    held.release()
    delete_study("s", db)
    assert optuna.get_all_study_names(storage=db) == []
