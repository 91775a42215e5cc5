"""Fault cases of the tuner storage: a study holds data only; resume replays it exactly."""

from __future__ import annotations

import base64
import hashlib
import pickle
import re
import zlib
from pathlib import Path

import numpy as np
import optuna
import pytest
from pymoo.problems import get_problem

from tuners.problem import PymooTaskProblem
from tuners.run import TuneInterrupted, tune
from tuners.storage import CHECKPOINT_META, open_storage

ROOT = Path(__file__).resolve().parents[2]
optuna.logging.set_verbosity(optuna.logging.WARNING)


def _zdt() -> PymooTaskProblem:
    return PymooTaskProblem(get_problem("zdt1", n_var=4), name="zdt1")


KW = dict(pop=6, backend="serial", seed=3)


class _Payload:
    """Unpickling this creates a file: the proof that a pickle ran."""

    def __init__(self, path: str) -> None:
        self.path = path

    def __reduce__(self):
        return (Path(self.path).touch, ())


def test_no_pickle_in_the_tuners():
    """No module of the tuners can load code from storage."""
    pat = re.compile(r"\b(import pickle|from pickle|dill|cloudpickle|torch\.load|marshal\.loads)\b")
    hits = [
        f"{f.relative_to(ROOT)}:{i}"
        for f in sorted((ROOT / "tuners").rglob("*.py"))
        for i, line in enumerate(f.read_text().splitlines(), 1)
        if pat.search(line)
    ]
    assert hits == []


def test_crafted_pickle_checkpoint_does_not_run(tmp_path):
    """A pickle stored as checkpoint chunks (``tuner:ckpt:a:0``) is refused
    with a clear error and never unpickled."""
    db = f"sqlite:///{tmp_path / 'runs.db'}"
    tune(_zdt(), "mowoa", iters=2, storage=db, study="s", **KW)
    marker = tmp_path / "pwned"
    blob = base64.b64encode(zlib.compress(pickle.dumps(_Payload(str(marker))))).decode()
    st = open_storage(db)
    sid = st.get_study_id_from_name("s")
    st.set_study_system_attr(sid, "tuner:ckpt:a:0", blob)
    st.set_study_system_attr(
        sid,
        CHECKPOINT_META,
        {"slot": "a", "n_chunks": 1, "sha256": hashlib.sha256(blob.encode()).hexdigest()},
    )
    with pytest.raises(ValueError, match=r"not in checkpoint schema 2.*not loaded"):
        tune(_zdt(), "mowoa", iters=3, storage=db, study="s", resume=True, **KW)
    assert not marker.exists()


def test_checkpoint_is_plain_json_and_validated(tmp_path):
    db = f"sqlite:///{tmp_path / 'runs.db'}"
    tune(_zdt(), "mowoa", iters=2, storage=db, study="s", **KW)
    st = open_storage(db)
    sid = st.get_study_id_from_name("s")
    attrs = st.get_study_system_attrs(sid)
    meta = attrs[CHECKPOINT_META]
    assert meta["schema"] == 2 and meta["n_gen"] == 2 and meta["schedule"] == [[1, 2]]
    assert set(meta["state"]) == {"rng", "pop_X", "pop_F"}
    assert not [k for k in attrs if k.startswith("tuner:ckpt:")]
    st.set_study_system_attr(sid, CHECKPOINT_META, {**meta, "n_gen": "2"})
    with pytest.raises(ValueError, match="malformed"):
        tune(_zdt(), "mowoa", iters=3, storage=db, study="s", resume=True, **KW)
    # a replay that does not reach the stored state is refused, naming the study
    st.set_study_system_attr(sid, CHECKPOINT_META, {**meta, "state": {**meta["state"], "rng": "0"}})
    with pytest.raises(ValueError, match="replaying its 2 generations gave another"):
        tune(_zdt(), "mowoa", iters=3, storage=db, study="s", resume=True, **KW)


@pytest.mark.parametrize("algo", ["mowoa", "pso", "mopso", "nsga2", "moead"])
def test_interrupt_at_a_generation_boundary_then_resume_is_exact(tmp_path, algo):
    """Ctrl-C after generation 2 (of 4), resume: the uninterrupted run's result, bit for
    bit, with no evaluation run twice."""
    from pymoo.core.callback import Callback

    class StopAfter(Callback):
        def notify(self, algorithm):  # called at the end of a generation
            if algorithm.n_iter == 2:
                raise KeyboardInterrupt

    db = f"sqlite:///{tmp_path / 'runs.db'}"
    with pytest.raises(TuneInterrupted, match=r"interrupted after \d+ evaluations; resume with"):
        tune(_zdt(), algo, iters=4, storage=db, study="s", callback=StopAfter(), **KW)
    before = {
        t.user_attrs["tuner"]["key"] for t in optuna.load_study(study_name="s", storage=db).trials
    }
    resumed = tune(_zdt(), algo, storage=db, study="s", resume=True, backend="serial")
    reference = tune(_zdt(), algo, iters=4, storage=None, study="r", **KW)
    assert np.array_equal(resumed.pymoo_result.X, reference.pymoo_result.X)
    assert np.array_equal(resumed.pymoo_result.F, reference.pymoo_result.F)
    assert list(resumed.evaluations["key"]) == list(reference.evaluations["key"])
    assert resumed.stats.run == len(set(reference.evaluations["key"]) - before) > 0


def test_journal_storage_is_json_lines_with_one_writer_and_resumes_exactly(tmp_path):
    """``journal:PATH``: Optuna's journal file, JSON only; the lease refuses a second
    writer; list, show, resume and delete work as on SQLite."""
    import json

    from tuners.run import show
    from tuners.storage import (
        StudyLockedError,
        StudyStore,
        delete_study,
        list_studies,
        load_study,
        stored_run_config,
    )

    path = tmp_path / "runs.log"
    url = f"journal:{path}"
    first = tune(_zdt(), "mowoa", iters=2, storage=url, study="s", **KW)
    lines = path.read_text().splitlines()
    assert lines and all(isinstance(json.loads(line), dict) for line in lines)
    trials = load_study("s", url).trials
    assert len(trials) == len(first.evaluations) and (tmp_path / "runs.log.lease").is_file()
    assert "generations done 2" in show("s", url)
    _, cfg = stored_run_config("s", url)
    holder = StudyStore(url, "s", _zdt(), cfg, resume=True)
    try:
        with pytest.raises(StudyLockedError, match="is being written by"):
            tune(_zdt(), "mowoa", iters=3, storage=url, study="s", resume=True, **KW)
    finally:
        holder.close()
    resumed = tune(_zdt(), "mowoa", iters=3, storage=url, study="s", resume=True, **KW)
    reference = tune(_zdt(), "mowoa", iters=3, storage=None, study="r", **KW)
    assert np.array_equal(resumed.pymoo_result.F, reference.pymoo_result.F)
    assert list(resumed.evaluations["key"]) == list(reference.evaluations["key"])
    assert list(list_studies(url)["study"]) == ["s"]
    delete_study("s", url)
    assert list_studies(url).empty


def test_a_missing_journal_is_not_created_by_readers(tmp_path):
    from tuners.storage import check_storage, open_storage, stored_run_config

    url = f"journal:{tmp_path / 'none.log'}"
    assert stored_run_config("s", url) == (False, None)
    check_storage(url)
    with pytest.raises(ValueError, match="no database file"):
        open_storage(url, must_exist=True)
    with pytest.raises(ValueError, match="does not exist"):
        check_storage(f"journal:{tmp_path / 'no' / 'x.log'}")
    assert not (tmp_path / "none.log").exists()
