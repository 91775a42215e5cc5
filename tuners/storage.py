"""Persistence of a tuning run in an Optuna study: evaluations, checkpoints, resume.

Layout of the study (any Optuna RDB storage: an SQLite file — ``sqlite:///tuning.db`` is
:func:`tuners.run.tune`'s default —, a PostgreSQL/MySQL URL; ``journal:PATH``, Optuna's
journal file, whose writes cost the driver ~50× less CPU (:class:`JournalStudyStorage`);
or in memory), readable by ``optuna-dashboard sqlite:///tuning.db`` (or ``PATH``):

* directions: ``minimize`` for every objective; ``study.metric_names`` = objective names;
* study user attr ``tuner_config``: the run settings (:mod:`tuners.settings`);
* **one trial per finished evaluation** (written as soon as it finishes):
  ``params`` = the controller's parameter values (FloatDistribution with the spec's
  bounds and log scale), ``values`` = the objective vector (mean over the seeds), the
  constraint values g_j under Optuna's own constraints key (system attr
  ``constraints``, a list in ``constraint_names`` order — what Optuna's samplers write,
  so ``study.best_trials`` and optuna-dashboard honour feasibility), user attr
  ``generation`` and one packed user attr ``tuner`` = {``key`` (cache key), ``x`` (the
  exact search-space vector), ``F``, ``G``, ``seeds``, ``metrics`` (per-seed values),
  ``generation``, ``batch_index``, ``wall_time_s``, ``worker``}. An evaluation that
  failed by its own error on every retry is one trial in state FAIL with
  ``final=True``, its ``error`` and the worst-value ``F``/``G`` it was given; every
  retried attempt is an extra FAIL trial with ``retried=True``;
* study system attr ``tuner:checkpoint``: the checkpoint after each generation, plain
  JSON (:data:`CHECKPOINT_SCHEMA`): generations and evaluations done, the termination
  schedule, and digests of the algorithm's random generator and population.

Nothing in a study is code: resume rebuilds the algorithm from the stored settings and
replays the stored generations with every evaluation answered from the cache
(:func:`tuners.checkpoint.replay`) — the algorithms are deterministic given the seed
and the evaluation results, whose floats round-trip exactly through JSON — and checks
the replayed state against the checkpoint's digests. The resumed run ends with exactly
the uninterrupted run's result. A writer holds the study's lease (:mod:`tuners.lease`).
"""

from __future__ import annotations

import datetime
import hashlib
import json
import os
import time
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import optuna
import pandas as pd
from optuna.distributions import FloatDistribution
from optuna.storages import JournalStorage
from optuna.storages.journal import JournalFileBackend
from optuna.storages.journal._file import get_lock_file
from optuna.study._constrained_optimization import _CONSTRAINTS_KEY
from optuna.trial import TrialState

from tuners.lease import StudyLease, StudyLockedError, lease_holder
from tuners.problem import TaskProblem

CONFIG_ATTR = "tuner_config"
TRIAL_ATTR = "tuner"  # one packed user attr per trial (each attr is a DB row: ~2 ms)
CHECKPOINT_META = "tuner:checkpoint"
CHECKPOINT_SCHEMA = 2
JOURNAL_PREFIX = "journal:"  # storage "journal:PATH": Optuna's journal file at PATH
LEGACY_CHUNK_PREFIX = "tuner:ckpt:"  # pickled algorithm chunks: refused, never loaded
CODE_HISTORY_ATTR = "tuner_code_history"  # code fingerprints of a run resumed across versions
#: packages whose code and data decide what an evaluation returns
CODE_PACKAGES = ("train_envs", "tuners")
_CODE_FP: str | None = None


def code_fingerprint() -> str:
    """16 hex digits of SHA-256 over the source and data files of :data:`CODE_PACKAGES`.

    Stored with every run (``run_config["code"]``): a study resumed by other code would
    mix evaluations made by two versions of the controllers or plants (and answer new
    points from a cache of old ones), so :func:`tuners.run.tune` refuses that unless
    told otherwise.  Computed once per process (~20 ms).
    """
    global _CODE_FP
    if _CODE_FP is None:
        import importlib.util

        h = hashlib.sha256()
        for pkg in CODE_PACKAGES:
            spec = importlib.util.find_spec(pkg)
            if spec is None or not spec.submodule_search_locations:
                continue
            root = Path(next(iter(spec.submodule_search_locations)))
            files = sorted(
                f
                for f in root.rglob("*")
                if f.is_file() and f.suffix in (".py", ".json", ".csv", ".yml", ".yaml")
            )
            for f in files:
                h.update(f"{pkg}/{f.relative_to(root).as_posix()}\0".encode())
                h.update(f.read_bytes())
        _CODE_FP = h.hexdigest()[:16]
    return _CODE_FP


__all__ = [
    "CHECKPOINT_SCHEMA",
    "JOURNAL_PREFIX",
    "JournalStudyStorage",
    "StudyExistsError",
    "StudyLockedError",
    "StudyStore",
    "check_storage",
    "checkpoint_info",
    "delete_study",
    "drop_interrupted_frames",
    "evaluations_frame",
    "list_studies",
    "load_study",
    "open_storage",
    "stored_run_config",
]


class StudyExistsError(ValueError):
    """The study already holds a run and ``resume`` was not requested."""


def _sqlite_path(url: str) -> Path | None:
    """The file of an ``sqlite:///`` URL or a ``journal:PATH`` (None: in memory or a server)."""
    if url.startswith(JOURNAL_PREFIX):
        return Path(url[len(JOURNAL_PREFIX) :])
    if not url.startswith("sqlite:"):
        return None
    rest = url.split(":///", 1)[1] if ":///" in url else ""
    rest = rest.split("?", 1)[0]
    return None if rest in ("", ":memory:") else Path(rest)


class _HeldJournalFile(JournalFileBackend):
    """An Optuna journal file whose ``fsync`` can be held: between :meth:`hold` and
    :meth:`flush` each append is written (under the file's lock) and handed to the
    operating system at once, and made durable by one ``fsync`` at :meth:`flush`."""

    def __init__(self, path: str) -> None:
        super().__init__(path)
        self._holding = False
        self._unsynced = False

    def append_logs(self, logs: list[dict[str, Any]]) -> None:
        if not self._holding:
            super().append_logs(logs)
            return
        text = "".join(json.dumps(log, separators=(",", ":")) + "\n" for log in logs)
        with get_lock_file(self._lock), open(self._file_path, "ab") as f:
            f.write(text.encode("utf-8"))
        self._unsynced = True

    def hold(self) -> None:
        """Append without ``fsync`` until :meth:`flush`."""
        self._holding = True

    def flush(self) -> None:
        """``fsync`` what was appended since :meth:`hold` and stop holding."""
        self._holding = False
        if self._unsynced:
            fd = os.open(self._file_path, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
            self._unsynced = False


class JournalStudyStorage(JournalStorage):
    """Optuna's journal storage on the file ``path`` (JSON lines, one per operation) with
    the write lease (:mod:`tuners.lease`) in the SQLite file ``path + ".lease"`` beside it.

    :meth:`hold` / :meth:`flush`: a batch's appends share one ``fsync``.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._file = _HeldJournalFile(str(self.path))
        super().__init__(self._file)
        import sqlalchemy

        self.engine = sqlalchemy.create_engine(
            f"sqlite:///{self.path}.lease", connect_args={"timeout": 60}
        )

    def hold(self) -> None:
        self._file.hold()

    def flush(self) -> None:
        self._file.flush()


def open_storage(
    storage: str | optuna.storages.BaseStorage | None, *, must_exist: bool = False
) -> optuna.storages.BaseStorage:
    """An Optuna storage: ``None`` = in memory, ``journal:PATH`` = Optuna's journal file
    (:class:`JournalStudyStorage`), any other URL = RDB (SQLite waits for locks).

    ``must_exist``: an SQLite URL or journal whose file is missing is a ``ValueError``
    (readers such as ``tune show`` never create one). A URL that cannot be opened
    (unknown scheme, not a database, a missing folder) is a ``ValueError`` naming it.
    """
    if storage is None:
        return optuna.storages.InMemoryStorage()
    if isinstance(storage, optuna.storages.BaseStorage):
        return storage
    url = str(storage)
    path = _sqlite_path(url)
    if path is not None:
        if must_exist and not path.is_file():
            raise ValueError(f"storage {url}: no database file {path}")
        if not path.parent.is_dir():
            raise ValueError(f"storage {url}: folder {path.parent} does not exist")
    if url.startswith(JOURNAL_PREFIX):
        if path is None or path.is_dir() or not path.name:
            raise ValueError(f"storage {url!r}: journal:PATH needs a file path")
        try:
            return JournalStudyStorage(path)
        except (ValueError, OSError, UnicodeDecodeError) as exc:
            raise ValueError(f"storage {url!r} cannot be opened: {exc}") from exc
    kwargs: dict[str, Any] = {}
    if url.startswith("sqlite"):
        kwargs["engine_kwargs"] = {"connect_args": {"timeout": 60}}
    import sqlalchemy.exc

    for attempt in range(5):
        try:
            return optuna.storages.RDBStorage(url, **kwargs)
        except (sqlalchemy.exc.OperationalError, sqlalchemy.exc.IntegrityError) as exc:
            # two processes creating the tables of a new database at once: the loser
            # sees "table ... already exists" or a duplicate schema version; opening
            # again finds the tables
            race = isinstance(exc, sqlalchemy.exc.IntegrityError) or "already exists" in str(exc)
            if race and attempt < 4:
                time.sleep(0.2)
                continue
            error: Exception = exc
        except (sqlalchemy.exc.SQLAlchemyError, ImportError, ValueError, RuntimeError) as exc:
            error = exc
        msg = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise ValueError(f"storage {url!r} cannot be opened: {msg}") from error
    raise AssertionError("unreachable")


def check_storage(storage: str) -> None:
    """``ValueError`` if ``storage`` cannot be opened; a new SQLite file is not created
    here (only its folder is checked)."""
    path = _sqlite_path(storage)
    if path is not None and not path.exists():
        if not path.parent.is_dir():
            raise ValueError(f"storage {storage}: folder {path.parent} does not exist")
        return
    open_storage(storage)


def _study_names(st: optuna.storages.BaseStorage) -> list[str]:
    return [s.study_name for s in st.get_all_studies()]


def load_study(study_name: str, storage: str | optuna.storages.BaseStorage) -> optuna.Study:
    """Open an existing study (``KeyError`` naming the available ones if absent)."""
    st = open_storage(storage, must_exist=True)
    names = _study_names(st)
    if study_name not in names:
        raise KeyError(f"no study {study_name!r} in {storage}; studies: {names}")
    return optuna.load_study(study_name=study_name, storage=st)


def stored_run_config(
    study_name: str, storage: str | optuna.storages.BaseStorage | None
) -> tuple[bool, dict[str, Any] | None]:
    """(study exists and holds evaluations or a checkpoint, its ``tuner_config``).

    Creates no database: a missing SQLite file holds no study.
    """
    path = _sqlite_path(storage) if isinstance(storage, str) else None
    if path is not None and not path.is_file():
        return False, None
    st = open_storage(storage)
    try:
        sid = st.get_study_id_from_name(study_name)
    except KeyError:
        return False, None
    cfg = st.get_study_user_attrs(sid).get(CONFIG_ATTR)
    has_run = bool(st.get_all_trials(sid, deepcopy=False)) or bool(
        st.get_study_system_attrs(sid).get(CHECKPOINT_META)
    )
    return has_run, cfg


def checkpoint_info(
    study_name: str, storage: str | optuna.storages.BaseStorage
) -> dict[str, Any] | None:
    """Metadata of a study's last checkpoint (generation, evaluations, time) or None."""
    st = open_storage(storage, must_exist=True)
    return st.get_study_system_attrs(st.get_study_id_from_name(study_name)).get(CHECKPOINT_META)


def list_studies(storage: str | optuna.storages.BaseStorage) -> pd.DataFrame:
    """One row per study: name, env, algo, generations done / iters, evaluations, writer."""
    st = open_storage(storage, must_exist=True)
    rows = []
    for s in st.get_all_studies():
        sid = s._study_id
        cfg = st.get_study_user_attrs(sid).get(CONFIG_ATTR) or {}
        ckpt = st.get_study_system_attrs(sid).get(CHECKPOINT_META) or {}
        trials = st.get_all_trials(sid, deepcopy=False, states=(TrialState.COMPLETE,))
        lease = lease_holder(st, s.study_name)
        rows.append(
            {
                "study": s.study_name,
                "env": cfg.get("env_id"),
                "algo": cfg.get("algo"),
                "generations": ckpt.get("n_gen", 0),
                "iters": cfg.get("iters"),
                "evaluations": len(trials),
                "writer": lease["holder"] if lease and lease["live"] else "",
            }
        )
    return pd.DataFrame(
        rows, columns=["study", "env", "algo", "generations", "iters", "evaluations", "writer"]
    )


def delete_study(study_name: str, storage: str | optuna.storages.BaseStorage) -> None:
    """Delete a study; refused (``StudyLockedError``) while a live run writes it."""
    st = open_storage(storage, must_exist=True)
    if study_name not in _study_names(st):
        raise KeyError(f"no study {study_name!r} in {storage}; studies: {_study_names(st)}")
    with StudyLease(st, study_name):
        optuna.delete_study(study_name=study_name, storage=st)


def _jsonable(obj: Any) -> Any:
    return json.loads(json.dumps(obj, default=lambda o: np.asarray(o).tolist()))


def drop_interrupted_frames(exc: BaseException) -> BaseException:
    """Drop the traceback of an interrupt (Ctrl-C) before the study is written again.

    A ``KeyboardInterrupt`` raised while SQLAlchemy reads the study keeps the frames it
    unwound, and with them a cursor whose statement is still open: on SQLite that
    connection holds a shared lock, so the next write of this process (releasing the
    lease, a last trial) waits the whole busy timeout (60 s). Without the frames the
    cursor is finalised at once. Returns ``exc``.
    """
    exc.__traceback__ = None
    return exc


class StudyStore:
    """Writes evaluations and checkpoints of one run to an Optuna study.

    Takes the study's write lease first (:class:`tuners.lease.StudyLease`; released by
    :meth:`close`), then creates or opens the study.

    Args:
        storage: Optuna storage URL or object; ``None`` = in memory.
        study_name: the study (one per run).
        problem: the task problem (names, distributions, fingerprint).
        run_config: JSON-able run settings stored as the study's ``tuner_config``.
        resume: continue an existing study; without it a study that holds evaluations
            or a checkpoint is an error (:class:`StudyExistsError`); one that holds
            neither (a run that stopped before its first evaluation) is started afresh.
        check_keys: ``run_config`` keys that must match the stored ones on resume.
    """

    def __init__(
        self,
        storage: str | optuna.storages.BaseStorage | None,
        study_name: str,
        problem: TaskProblem,
        run_config: Mapping[str, Any],
        *,
        resume: bool = False,
        check_keys: tuple[str, ...] = ("fingerprint", "algo", "pop", "seed"),
    ) -> None:
        self.storage = open_storage(storage)
        self.study_name = study_name
        self.problem = problem
        self.run_config = _jsonable(dict(run_config))
        self.lease: StudyLease | None = StudyLease(self.storage, study_name).acquire()
        try:
            self._open(problem, resume, check_keys)
        except BaseException as exc:
            if isinstance(exc, KeyboardInterrupt):
                drop_interrupted_frames(exc)
            self.close()
            raise
        self.distributions = {
            name: FloatDistribution(lo, hi, log=log)
            for name, (lo, hi, log) in problem.param_distributions().items()
        }

    def _open(self, problem: TaskProblem, resume: bool, check_keys: tuple[str, ...]) -> None:
        study_name = self.study_name
        has_run, stored = stored_run_config(study_name, self.storage)
        try:
            self.study_id = self.storage.get_study_id_from_name(study_name)
            exists = True
        except KeyError:
            exists = False
        if exists and not has_run:  # nothing to keep (a start that stopped early): afresh
            self.storage.delete_study(self.study_id)
            exists = False
        if exists:
            study = optuna.load_study(study_name=study_name, storage=self.storage)
            if not resume and has_run:
                raise StudyExistsError(
                    f"study {study_name!r} already holds a run; pass resume=True (--resume) to "
                    "continue it or choose another study name"
                )
            if stored is not None:
                diff = {
                    k: (stored.get(k), self.run_config.get(k))
                    for k in check_keys
                    if stored.get(k) != self.run_config.get(k)
                }
                if "code" in diff:
                    old_code, new_code = diff["code"]
                    raise ValueError(
                        f"cannot resume study {study_name!r}: it was run by other code (code "
                        f"fingerprint stored {old_code}, now {new_code}), so its evaluations "
                        "and cache do not answer for this code; use another study name "
                        "('{code}' in the name gives one per code version) or pass "
                        "allow_code_change=True (--allow-code-change) to continue anyway"
                    )
                if diff:
                    raise ValueError(
                        f"cannot resume study {study_name!r}: settings differ (stored, now): {diff}"
                    )
                now = self.run_config.get("code")
                if now is not None and stored.get("code") != now:  # allowed: record it
                    seen = list(study.user_attrs.get(CODE_HISTORY_ATTR) or [stored.get("code")])
                    study.set_user_attr(CODE_HISTORY_ATTR, [*seen, now])
                if stored != self.run_config:  # e.g. more iterations: the study says so
                    study.set_user_attr(CONFIG_ATTR, self.run_config)
            else:
                study.set_user_attr(CONFIG_ATTR, self.run_config)
            self.resumed = stored is not None
        else:
            study = optuna.create_study(
                storage=self.storage,
                study_name=study_name,
                directions=["minimize"] * problem.n_obj,
            )
            self.study_id = self.storage.get_study_id_from_name(study_name)
            if problem.n_obj > 1:
                with warnings.catch_warnings():  # experimental API since Optuna 3.2
                    warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
                    study.set_metric_names(list(problem.obj_names))
            study.set_user_attr(CONFIG_ATTR, self.run_config)
            self.resumed = False
        self.study = study

    # ------------------------------------------------------------- evaluations
    def _attrs(
        self, key: str, x: np.ndarray, generation: int | None, batch_index: int
    ) -> dict[str, Any]:
        seeds = getattr(self.problem, "seeds", None)
        return {
            "key": key,
            "x": [float(v) for v in np.asarray(x, float)],
            "generation": None if generation is None else int(generation),
            "batch_index": int(batch_index),
            "seeds": None if seeds is None else list(seeds),
        }

    def record(
        self,
        problem: TaskProblem,
        key: str,
        x: np.ndarray,
        outcome: Mapping[str, Any],
        generation: int | None,
        batch_index: int,
    ) -> None:
        """Write one finished evaluation (a failed-for-good one as a final FAIL trial)."""
        rec = self._attrs(key, x, generation, batch_index)
        rec.update(
            F=list(outcome["F"]),
            G=list(outcome.get("G", [])),
            wall_time_s=float(outcome.get("wall_time_s", 0.0)),
            worker=outcome.get("worker"),
        )
        if "metrics" in outcome:
            rec["metrics"] = outcome["metrics"]
        ua: dict[str, Any] = {"generation": rec["generation"], TRIAL_ATTR: rec}
        params = problem.param_values(x)
        if outcome.get("failed"):
            rec.update(final=True, error=outcome.get("error"), attempts=outcome.get("attempts"))
            ua["error"] = outcome.get("error")
            trial = optuna.trial.create_trial(
                state=TrialState.FAIL,
                params=params,
                distributions=self.distributions,
                user_attrs=ua,
            )
        else:
            G = [float(g) for g in outcome.get("G", [])]
            if len(G) != len(problem.constr_names):
                raise ValueError(
                    f"outcome has {len(G)} constraint values, expected "
                    f"{len(problem.constr_names)} ({problem.constr_names})"
                )
            trial = optuna.trial.create_trial(
                values=list(outcome["F"]),
                params=params,
                distributions=self.distributions,
                user_attrs=ua,
                system_attrs={_CONSTRAINTS_KEY: G} if G else None,
            )
            if trial.datetime_complete is not None:
                trial.datetime_start = trial.datetime_complete - datetime.timedelta(
                    seconds=rec["wall_time_s"]
                )
        self.study.add_trial(trial)

    def record_failure(
        self,
        problem: TaskProblem,
        key: str,
        x: np.ndarray,
        error: str,
        attempt: int,
        generation: int | None,
        batch_index: int,
    ) -> None:
        """Write one failed attempt that is being retried (a FAIL trial, ``retried``)."""
        rec = self._attrs(key, x, generation, batch_index)
        rec.update(retried=True, attempt=int(attempt), error=str(error))
        trial = optuna.trial.create_trial(
            state=TrialState.FAIL,
            params=problem.param_values(x),
            distributions=self.distributions,
            user_attrs={"generation": rec["generation"], "error": str(error), TRIAL_ATTR: rec},
        )
        self.study.add_trial(trial)

    def load_cache(self) -> dict[str, dict[str, Any]]:
        """key → outcome of every finished evaluation in the study (for resume)."""
        cache: dict[str, dict[str, Any]] = {}
        for t in self.study.get_trials(deepcopy=False):
            ua = t.user_attrs.get(TRIAL_ATTR) or {}
            if "key" not in ua or "F" not in ua:
                continue
            if t.state == TrialState.COMPLETE or ua.get("final"):
                out = {
                    "F": list(ua["F"]),
                    "G": list(ua.get("G", [])),
                    "wall_time_s": ua.get("wall_time_s", 0.0),
                    "worker": ua.get("worker"),
                }
                if "metrics" in ua:
                    out["metrics"] = ua["metrics"]
                if ua.get("final"):
                    out.update(failed=True, error=ua.get("error"), attempts=ua.get("attempts"))
                cache.setdefault(ua["key"], out)
        return cache

    # -------------------------------------------------------------- checkpoint
    def save_checkpoint(self, algorithm: Any, schedule: list[list[int]], **info: Any) -> dict:
        """Write the checkpoint of ``algorithm`` after a generation (plain JSON data).

        ``schedule`` = ``[[first generation, iters], ...]``: the termination each stored
        generation ran under (an extended run has several). Returns the metadata.
        """
        meta = {
            "schema": CHECKPOINT_SCHEMA,
            "n_gen": int(algorithm.n_iter) - 1 if algorithm.n_iter else 0,
            "n_eval": int(algorithm.evaluator.n_eval),
            "schedule": [[int(g), int(n)] for g, n in schedule],
            "state": algorithm_state(algorithm),
            "saved_at": datetime.datetime.now().isoformat(timespec="seconds"),
            **_jsonable(info),
        }
        self.storage.set_study_system_attr(self.study_id, CHECKPOINT_META, meta)
        return meta

    def checkpoint_info(self) -> dict[str, Any] | None:
        return self.storage.get_study_system_attrs(self.study_id).get(CHECKPOINT_META)

    def load_checkpoint(self) -> dict[str, Any] | None:
        """The validated checkpoint metadata, or None if the study has none."""
        return read_checkpoint(self.storage, self.study_id, self.study_name)

    def hold(self) -> None:
        """Start holding the writes of a batch (journal storage; RDB writes stream)."""
        if isinstance(self.storage, JournalStudyStorage):
            self.storage.hold()

    def flush(self) -> None:
        """Write what :meth:`hold` kept back, in one append."""
        if isinstance(self.storage, JournalStudyStorage):
            self.storage.flush()

    def close(self) -> None:
        """Write what is held and release the write lease (idempotent)."""
        self.flush()
        if self.lease is not None:
            self.lease.release()


def algorithm_state(algorithm: Any) -> dict[str, str]:
    """SHA-256 digests of the state a replay must reproduce: the random generator and
    the population's X and F (16 hex digits each)."""
    rng = getattr(algorithm, "random_state", None)
    rng_state = json.dumps(rng.bit_generator.state, sort_keys=True) if rng is not None else ""
    out = {"rng": hashlib.sha256(rng_state.encode()).hexdigest()[:16]}
    pop = getattr(algorithm, "pop", None)
    for name in ("X", "F"):
        arr = None if pop is None or len(pop) == 0 else pop.get(name)
        raw = b"" if arr is None else np.ascontiguousarray(np.asarray(arr, float)).tobytes()
        out[f"pop_{name}"] = hashlib.sha256(raw).hexdigest()[:16]
    return out


def read_checkpoint(
    storage: optuna.storages.BaseStorage, study_id: int, study_name: str
) -> dict[str, Any] | None:
    """Checkpoint metadata of a study, validated; ``ValueError`` naming what is wrong.

    A checkpoint in any other form — such as pickled algorithm chunks under
    ``tuner:ckpt:*`` — is refused and never loaded: a pickle runs code.
    """
    attrs = storage.get_study_system_attrs(study_id)
    meta = attrs.get(CHECKPOINT_META)
    legacy = sorted(k for k in attrs if k.startswith(LEGACY_CHUNK_PREFIX))
    where = f"checkpoint of study {study_name!r}"
    if legacy or (meta is not None and meta.get("schema") != CHECKPOINT_SCHEMA):
        found = (
            f"pickled algorithm chunks {legacy[0]}" if legacy else f"schema {meta.get('schema')!r}"
        )
        raise ValueError(
            f"{where} is not in checkpoint schema {CHECKPOINT_SCHEMA} (found {found}); it is "
            "not loaded (a pickle can run code): start a new study, or delete this one "
            "(`train-envs tune delete`)"
        )
    if meta is None:
        return None
    ok = (
        isinstance(meta.get("n_gen"), int)
        and meta["n_gen"] >= 0
        and isinstance(meta.get("n_eval"), int)
        and isinstance(meta.get("state"), dict)
        and all(isinstance(v, str) for v in meta["state"].values())
        and isinstance(meta.get("schedule"), list)
        and len(meta["schedule"]) >= 1
        and all(
            isinstance(s, list) and len(s) == 2 and all(isinstance(v, int) and v >= 1 for v in s)
            for s in meta["schedule"]
        )
    )
    if not ok:
        raise ValueError(f"{where} is malformed (n_gen, n_eval, schedule or state): {meta}")
    return meta


# --------------------------------------------------------------------- results
def evaluations_frame(study: optuna.Study) -> pd.DataFrame:
    """One row per evaluation of a tuner study (retried attempts left out).

    Columns: ``trial``, ``generation``, ``batch_index``, the parameters (by name), the
    objectives (by metric name), ``g:<constraint>``, ``cv`` (Σ max(0, g)), ``feasible``,
    ``failed``, ``error``, ``wall_time_s``, ``worker``, ``seeds``, ``key`` and ``x``.
    Rows are ordered by generation and position in the generation's batch.
    """
    cfg = study.user_attrs.get(CONFIG_ATTR, {}) or {}
    obj_names = (
        cfg.get("objective_names")
        or study.metric_names
        or [f"f{i + 1}" for i in range(len(study.directions))]
    )
    constr_names = cfg.get("constraint_names") or []
    rows = []
    for t in study.get_trials(deepcopy=False):
        ua = t.user_attrs.get(TRIAL_ATTR) or {}
        if "F" not in ua or not (t.state == TrialState.COMPLETE or ua.get("final")):
            continue
        G = list(ua.get("G", []))
        row: dict[str, Any] = {
            "trial": t.number,
            "generation": ua.get("generation"),
            "batch_index": ua.get("batch_index"),
        }
        row.update(t.params)
        row.update(dict(zip(obj_names, ua["F"], strict=False)))
        names = constr_names or [f"g{i + 1}" for i in range(len(G))]
        row.update({f"g:{n}": g for n, g in zip(names, G, strict=False)})
        cv = float(np.sum(np.maximum(np.asarray(G, float), 0.0))) if G else 0.0
        row.update(
            cv=cv,
            feasible=(cv <= 0.0) and not ua.get("final", False),
            failed=bool(ua.get("final", False)),
            error=ua.get("error"),
            wall_time_s=ua.get("wall_time_s"),
            worker=ua.get("worker"),
            seeds=ua.get("seeds"),
            key=ua.get("key"),
            x=ua.get("x"),
        )
        rows.append(row)
    df = pd.DataFrame(rows)
    if len(df):
        df = df.drop_duplicates("key", keep="first")
        df = df.sort_values(["generation", "batch_index", "trial"], na_position="first")
        df = df.reset_index(drop=True)
    return df
