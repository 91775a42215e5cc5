"""Fault cases of the evaluation backends: an evaluation fails only by its own error."""

from __future__ import annotations

import hashlib
import os
import signal
import subprocess
import sys
import textwrap
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import optuna
import pytest
from pymoo.problems import get_problem
from study_watch import wait_for_trials

# kept light: pool workers import this module to unpickle the tasks below
from tuners.problem import ConfigError, PymooTask, PymooTaskProblem

ROOT = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}
PID = "TrainEnvs/Stopping001PID-v0"
optuna.logging.set_verbosity(optuna.logging.WARNING)


@dataclass(frozen=True)
class KilledOnce(PymooTask):
    """SIGKILLs its own worker on its first attempt when ``kill`` (a death from outside)."""

    marker_dir: str = ""
    kill: bool = False

    def run(self):
        if self.kill:
            marker = Path(self.marker_dir) / hashlib.sha1(np.asarray(self.x).tobytes()).hexdigest()
            if not marker.exists():
                marker.touch()
                os.kill(os.getpid(), signal.SIGKILL)
        return super().run()


class KilledProblem(PymooTaskProblem):
    def __init__(self, marker_dir: Path, every: int = 3) -> None:
        super().__init__(get_problem("zdt1", n_var=4), name="zdt1")
        Path(marker_dir).mkdir(parents=True, exist_ok=True)
        self.marker_dir, self.every = str(marker_dir), every

    def make_task(self, x):
        h = int(hashlib.sha1(np.asarray(x, np.float64).tobytes()).hexdigest(), 16)
        return KilledOnce(
            self.inner, tuple(map(float, x)), 0.0, self.marker_dir, h % self.every == 0
        )


@dataclass(frozen=True)
class Task:
    """``mode``: ok | die (always kills its worker) | config (a ConfigError) | raise."""

    mode: str = "ok"
    marker_dir: str = ""

    def run(self):
        if self.marker_dir:
            (Path(self.marker_dir) / f"{self.mode}-{time.monotonic_ns()}").touch()
        if self.mode == "die":
            os._exit(9)
        if self.mode == "config":
            raise ConfigError("metric 'nope' not reported")
        if self.mode == "raise":
            raise RuntimeError("boom")
        time.sleep(0.05)
        return {"F": [1.0], "G": []}


def test_killed_workers_do_not_change_the_result():
    """Pool workers SIGKILLed while evaluating: same Pareto set as an undisturbed run,
    no failed evaluation, nothing charged."""
    import tempfile

    from tuners.run import tune

    with tempfile.TemporaryDirectory() as d:
        kw = dict(pop=6, iters=2, storage=None, seed=4)
        r = tune(KilledProblem(Path(d)), "mowoa", backend="processes", workers=2, **kw)
    clean = tune(PymooTaskProblem(get_problem("zdt1", n_var=4), name="zdt1"), "mowoa",
                 backend="serial", **kw)  # fmt: skip
    assert r.stats.worker_deaths > 0
    assert (
        r.stats.failed_attempts == r.stats.failed_final == 0 and not r.evaluations["failed"].any()
    )
    assert np.array_equal(r.pymoo_result.F, clean.pymoo_result.F)
    assert sorted(r.pareto["key"]) == sorted(clean.pareto["key"])


def test_a_task_that_kills_its_worker_fails_alone_and_nobody_else(tmp_path):
    from tuners.backends import Failure, ProcessBackend

    tasks = [Task("ok"), Task("die"), Task("ok"), Task("ok"), Task("ok")]
    with ProcessBackend(workers=2, max_retries=1) as be:
        errors = []
        out = be.run(tasks, on_error=lambda i, a, e, f: errors.append((i, a, f)))
    assert [type(o).__name__ for o in out] == ["dict", "Failure", "dict", "dict", "dict"]
    assert isinstance(out[1], Failure) and out[1].attempts == 2
    assert "alone" in out[1].error and {i for i, _, _ in errors} == {1}


@pytest.mark.parametrize("backend", ["serial", "processes"])
def test_a_configuration_error_fails_fast_without_retries(tmp_path, backend):
    from tuners.backends import make_backend

    be = make_backend(backend, workers=1, max_retries=3)
    try:
        with pytest.raises(ConfigError, match="metric 'nope'"):
            be.run([Task("config", str(tmp_path))])
    finally:
        be.close()
    assert len(list(tmp_path.glob("config-*"))) == 1  # one attempt, no retry


DRIVER = textwrap.dedent(
    """
    import os, sys, time
    from dataclasses import dataclass
    from pathlib import Path
    from pymoo.problems import get_problem
    from tuners.problem import PymooTask, PymooTaskProblem
    from tuners.run import tune

    @dataclass(frozen=True)
    class Slow(PymooTask):
        def run(self):
            Path(sys.argv[1], f"started-{os.getpid()}").touch()
            time.sleep(60)
            return super().run()

    class SlowProblem(PymooTaskProblem):
        def make_task(self, x):
            return Slow(self.inner, tuple(map(float, x)))

    if __name__ == "__main__":
        p = SlowProblem(get_problem("zdt1", n_var=4), name="zdt1")
        tune(p, "mowoa", pop=4, iters=2, backend="processes", workers=2, storage=None)
    """
)


def test_driver_kill_leaves_no_process_after_10_s(tmp_path):
    psutil = pytest.importorskip("psutil")
    script = tmp_path / "driver.py"
    script.write_text(DRIVER)
    proc = subprocess.Popen([sys.executable, str(script), str(tmp_path)], env=ENV, cwd=tmp_path)
    driver = psutil.Process(proc.pid)
    deadline = time.time() + 180
    while time.time() < deadline and len(list(tmp_path.glob("started-*"))) < 2:
        time.sleep(0.2)
    kids = driver.children(recursive=True)  # pool workers and the resource tracker
    assert len(list(tmp_path.glob("started-*"))) == 2, "the workers never started a task"
    proc.send_signal(signal.SIGKILL)
    proc.wait(10)

    def alive(p):
        try:
            return p.status() != psutil.STATUS_ZOMBIE
        except psutil.NoSuchProcess:
            return False

    t0 = time.time()
    while time.time() - t0 < 10 and any(alive(p) for p in kids):
        time.sleep(0.2)
    left = [p.pid for p in kids if alive(p)]
    for pid in left:  # clean up before failing
        os.kill(pid, signal.SIGKILL)
    assert len(kids) >= 2 and left == []


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_ctrl_c_is_one_line_and_exit_130(tmp_path):
    dbfile = tmp_path / "runs.db"
    # a budget far beyond what runs before the interrupt (the lockstep default is fast)
    argv = [sys.executable, "-m", "train_envs.cli", "tune", "--env", PID, "--pop", "6",
            "--iters", "5000", "--workers", "2", "--objectives", "itae", "stop", "--storage",
            f"sqlite:///{dbfile}", "--study", "c", "--no-progress"]  # fmt: skip
    # SIGINT as a terminal delivers it, even when this suite runs as a background job
    # (which starts with SIGINT ignored, and a child inherits that)
    proc = subprocess.Popen(argv, env=ENV, cwd=tmp_path, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=_default_sigint)  # fmt: skip
    wait_for_trials(dbfile, 3, proc, timeout=180)
    os.killpg(proc.pid, signal.SIGINT)  # as a terminal does: the whole process group
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "Traceback" not in err and err.count("\n") == 1
    assert (
        err.startswith("interrupted after ") and "evaluations; resume with: train-envs tune" in err
    )
    assert "--study c" in err and "--resume" in err


def test_ctrl_c_inside_a_read_of_the_study_does_not_block_its_last_writes(tmp_path):
    """A Ctrl-C that lands while SQLAlchemy reads the study leaves the interrupted
    frames holding an open cursor (a shared lock on SQLite): the lease release and the
    study's last writes must not wait the 60 s busy timeout on it."""
    import sqlalchemy as sa

    from tuners.lease import lease_holder
    from tuners.run import TuneInterrupted, tune
    from tuners.storage import open_storage

    storage = open_storage(f"sqlite:///{tmp_path / 'runs.db'}")
    problem = PymooTaskProblem(get_problem("bnh"), name="bnh")
    seen = {"evaluations": 0}

    def count(key, outcome, generation):
        seen["evaluations"] += 1

    def interrupt_a_read(conn, cursor, statement, *args):
        if seen["evaluations"] >= 7 and statement.lstrip().upper().startswith("SELECT"):
            sa.event.remove(storage.engine, "after_cursor_execute", interrupt_a_read)
            raise KeyboardInterrupt  # as Ctrl-C does, between two rows of a read

    sa.event.listen(storage.engine, "after_cursor_execute", interrupt_a_read)
    t0 = time.perf_counter()
    with pytest.raises(TuneInterrupted):
        tune(problem, "pso", pop=5, iters=50, backend="serial", storage=storage,
             study="c", seed=1, on_evaluation=count)  # fmt: skip
    assert time.perf_counter() - t0 < 30  # the busy timeout alone is 60 s
    assert lease_holder(storage, "c") is None  # released, not left to go stale
