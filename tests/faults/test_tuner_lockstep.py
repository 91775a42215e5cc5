"""Fault cases of the lockstep backend: a chunk's members fail only by their own error,
a worker death re-runs only what it lost, and a resumed lockstep run is the
uninterrupted one."""

from __future__ import annotations

import hashlib
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import optuna
import pytest
from pymoo.problems import get_problem

# kept light: pool workers import this module to unpickle the tasks below
from tuners.problem import PymooTask

PID = "TrainEnvs/Stopping001PID-v0"
optuna.logging.set_verbosity(optuna.logging.WARNING)
ZDT = get_problem("zdt1", n_var=4)


@dataclass(frozen=True)
class ChunkTask(PymooTask):
    """A batchable ZDT1 point; ``mode``: ok | raise (its batch always raises, the member
    alone raises on its first attempt) | die (kills its worker on its chunk's first run,
    once the other chunk has finished). Each member evaluated leaves a ``ran-`` file."""

    marker_dir: str = ""
    mode: str = "ok"

    @property
    def tag(self) -> str:
        return hashlib.sha1(np.asarray(self.x).tobytes()).hexdigest()[:12]

    def batch_key(self):
        return ("chunk-test", self.marker_dir)

    @classmethod
    def run_batch(cls, tasks):
        d = Path(tasks[0].marker_dir)
        if any(t.mode == "raise" for t in tasks):
            raise RuntimeError("a member broke the batch")
        for t in tasks:
            if t.mode == "die" and not (d / f"died-{t.tag}").exists():
                deadline = time.time() + 60  # the other chunk's three members first
                while len(list(d.glob("ran-*"))) < 3 and time.time() < deadline:
                    time.sleep(0.05)
                time.sleep(2.0)  # its result reaches the driver before this death
                (d / f"died-{t.tag}").touch()
                os._exit(9)
        return [t.evaluate() for t in tasks]

    def run(self):
        if self.mode == "raise":
            marker = Path(self.marker_dir) / f"raised-{self.tag}"
            if not marker.exists():
                marker.touch()
                raise RuntimeError("injected failure")
        return self.evaluate()

    def evaluate(self):
        (Path(self.marker_dir) / f"ran-{self.tag}-{time.monotonic_ns()}").touch()
        return PymooTask.run(self)


def _tasks(tmp_path, modes):
    xs = np.linspace(0.1, 0.9, len(modes))
    pairs = zip(xs, modes, strict=True)
    return [ChunkTask(ZDT, (float(x), 0.5, 0.5, 0.5), 0.0, str(tmp_path), m) for x, m in pairs]


def _runs(tmp_path, task) -> int:
    return len(list(tmp_path.glob(f"ran-{task.tag}-*")))


def test_chunks_are_one_per_worker_and_other_tasks_go_alone():
    from tuners.backends import LockstepBackend

    be = LockstepBackend(workers=3)
    keyed = [ChunkTask(ZDT, (0.1 * i, 0.5, 0.5, 0.5)) for i in range(8)]
    plain = [PymooTask(ZDT, (0.5, 0.5, 0.5, 0.5))]
    groups = be._groups(keyed + plain, list(range(9)))
    assert groups == [[0, 1, 2], [3, 4, 5], [6, 7], [8]]


def test_a_failing_member_does_not_fail_its_chunk_mates(tmp_path):
    from tuners.backends import Failure, LockstepBackend

    tasks = _tasks(tmp_path, ["ok", "raise", "ok", "ok", "ok", "ok"])
    errors = []
    with LockstepBackend(workers=2, max_retries=1) as be:
        out = be.run(tasks, on_error=lambda i, a, e, f: errors.append((i, a, f)))
    assert all(isinstance(o, dict) for o in out)
    assert errors == [(1, 1, False)]  # charged once, then it succeeded alone
    expected = [PymooTask.run(t) for t in tasks]
    assert [o["F"] for o in out] == [e["F"] for e in expected]
    assert [_runs(tmp_path, t) for t in tasks] == [1] * 6

    (tmp_path / "b").mkdir()
    tasks = _tasks(tmp_path / "b", ["ok", "raise", "ok"])
    with LockstepBackend(workers=1, max_retries=0) as be:
        out = be.run(tasks)
    assert isinstance(out[1], Failure) and "injected failure" in out[1].error
    assert isinstance(out[0], dict) and isinstance(out[2], dict)


def test_a_worker_death_re_runs_only_what_it_lost(tmp_path):
    from tuners.backends import LockstepBackend

    tasks = _tasks(tmp_path, ["ok", "ok", "ok", "ok", "die", "ok"])  # chunks 0-2, 3-5
    errors = []
    with LockstepBackend(workers=2) as be:
        out = be.run(tasks, on_error=lambda i, a, e, f: errors.append(i))
        assert be.restarts == 1
    assert errors == [] and all(isinstance(o, dict) for o in out)
    assert [o["F"] for o in out] == [PymooTask.run(t)["F"] for t in tasks]
    # the finished chunk is not run again; the lost one ran once, after the death
    assert [_runs(tmp_path, t) for t in tasks] == [1] * 6


def test_a_configuration_error_in_a_chunk_stops_the_run():
    from tuners.backends import LockstepBackend
    from tuners.problem import ConfigError, EnvTuningProblem

    p = EnvTuningProblem(PID, objectives=["itae", "nope"], config={"max_episode_steps": 2})
    tasks = [p.make_task(p.default_x()), p.make_task(np.zeros(p.n_var))]
    with LockstepBackend(workers=1, max_retries=3) as be, pytest.raises(ConfigError, match="nope"):
        be.run(tasks)


def test_lockstep_is_the_default_where_the_controller_batches():
    from tuners.backends import default_backend
    from tuners.problem import EnvTuningProblem, PymooTaskProblem

    assert default_backend(EnvTuningProblem(PID)) == "lockstep"
    assert default_backend(EnvTuningProblem("TrainEnvs/Stopping001-v0")) == "processes"
    assert default_backend(PymooTaskProblem(ZDT)) == "processes"


@pytest.mark.parametrize("storage", ["sqlite", "journal"])
def test_interrupted_lockstep_run_resumes_to_the_uninterrupted_one(tmp_path, storage):
    """Ctrl-C after generation 2 (of 3), resume (lockstep, the default here): the
    uninterrupted lockstep run's result bit for bit, nothing run twice."""
    from pymoo.core.callback import Callback

    from tuners.run import TuneInterrupted, tune
    from tuners.storage import load_study

    class StopAfter(Callback):
        def notify(self, algorithm):
            if algorithm.n_iter == 2:
                raise KeyboardInterrupt

    url = {"sqlite": f"sqlite:///{tmp_path / 'runs.db'}", "journal": f"journal:{tmp_path / 'j'}"}
    kw = dict(pop=4, seed=2, seeds=[0], objectives=["itae", "stop"], workers=2)
    with pytest.raises(TuneInterrupted):
        tune(PID, "mowoa", iters=3, storage=url[storage], study="s", callback=StopAfter(), **kw)
    before = {t.user_attrs["tuner"]["key"] for t in load_study("s", url[storage]).trials}
    resumed = tune(PID, "mowoa", storage=url[storage], study="s", resume=True, workers=2)
    assert resumed.backend == "lockstep" and resumed.stats.worker_deaths == 0
    reference = tune(PID, "mowoa", iters=3, storage=None, study="r", **kw)
    assert np.array_equal(resumed.pymoo_result.X, reference.pymoo_result.X)
    assert np.array_equal(resumed.pymoo_result.F, reference.pymoo_result.F)
    assert list(resumed.evaluations["key"]) == list(reference.evaluations["key"])
    assert resumed.selected["key"] == reference.selected["key"]
    assert resumed.stats.run == len(set(reference.evaluations["key"]) - before) > 0
