"""Persistence of a tuning run in an Optuna study: evaluations, checkpoints, resume.

Layout of the study (any Optuna storage: an SQLite file — ``sqlite:///tuning.db`` is
:func:`tuners.run.tune`'s default —, a PostgreSQL/MySQL URL, or in memory), readable by
``optuna-dashboard sqlite:///tuning.db``:

* directions: ``minimize`` for every objective; ``study.metric_names`` = objective names;
* study user attr ``tuner_config``: the run settings (env id, algorithm, population,
  iterations, seed, objectives, seeds, target weights, problem fingerprint);
* **one trial per finished evaluation** (written as soon as it finishes):
  ``params`` = the controller's parameter values (FloatDistribution with the spec's
  bounds and log scale), ``values`` = the objective vector (mean over the seeds),
  ``constraints`` (Optuna's feasibility, shown by the dashboard) = g_j, user attr
  ``generation`` and one packed user attr ``tuner`` = {``key`` (cache key), ``x`` (the
  exact search-space vector), ``F``, ``G``, ``seeds``, ``metrics`` (per-seed values),
  ``generation``, ``batch_index``, ``wall_time_s``, ``worker``}. An evaluation that
  failed on every retry is one trial in state FAIL with ``final=True``, its ``error``
  (also a top-level user attr) and the worst-value ``F``/``G`` it was given; every
  retried attempt is an extra FAIL trial with ``retried=True`` (so
  :func:`evaluations_frame` has each evaluation exactly once, and the errors are kept);
* study system attrs ``tuner:checkpoint`` (metadata) and ``tuner:ckpt:<slot>:<i>``
  (chunks of the zlib-compressed, base64-encoded pickle of the pymoo algorithm after
  each generation; two slots alternate so that a kill while writing leaves the previous
  checkpoint intact; the SHA-256 in the metadata is verified on load). The algorithm is
  pickled without its problem, callback and display, which are re-attached on resume.

Resume: the algorithm is restored from the last checkpoint (its random generator
included) and every finished evaluation is loaded into the cache of
:class:`tuners.backends.Evaluations`, keyed by problem fingerprint + the exact x. The
restored algorithm proposes the same points as the uninterrupted run did, finished ones
are answered from the cache (their floats round-trip exactly through JSON), and the
resumed run ends with exactly the uninterrupted run's result.
"""

from __future__ import annotations

import base64
import datetime
import hashlib
import json
import pickle
import warnings
import zlib
from collections.abc import Mapping
from typing import Any

import numpy as np
import optuna
import pandas as pd
from optuna.distributions import FloatDistribution
from optuna.trial import TrialState

from tuners.problem import TaskProblem

CONFIG_ATTR = "tuner_config"
TRIAL_ATTR = "tuner"  # one packed user attr per trial (each attr is a DB row: ~2 ms)
CHECKPOINT_META = "tuner:checkpoint"
CODE_HISTORY_ATTR = "tuner_code_history"  # code fingerprints of a run resumed across versions
CHUNK_CHARS = 60_000  # below MySQL's TEXT limit
#: algorithm attributes that are not pickled into a checkpoint
DETACHED = ("problem", "callback", "display", "history")
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
        from pathlib import Path

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
    "StudyExistsError",
    "StudyStore",
    "checkpoint_info",
    "evaluations_frame",
    "load_study",
    "open_storage",
]


class StudyExistsError(ValueError):
    """The study already holds a run and ``resume`` was not requested."""


def open_storage(storage: str | optuna.storages.BaseStorage | None) -> optuna.storages.BaseStorage:
    """An Optuna storage: ``None`` = in memory, a URL = RDB (SQLite waits for locks)."""
    if storage is None:
        return optuna.storages.InMemoryStorage()
    if isinstance(storage, optuna.storages.BaseStorage):
        return storage
    kwargs: dict[str, Any] = {}
    if str(storage).startswith("sqlite"):
        kwargs["engine_kwargs"] = {"connect_args": {"timeout": 60}}
    return optuna.storages.RDBStorage(str(storage), **kwargs)


def load_study(study_name: str, storage: str | optuna.storages.BaseStorage) -> optuna.Study:
    """Open an existing study (``KeyError`` naming the available ones if absent)."""
    st = open_storage(storage)
    names = [s.study_name for s in optuna.get_all_study_summaries(st)]
    if study_name not in names:
        raise KeyError(f"no study {study_name!r} in {storage}; studies: {names}")
    return optuna.load_study(study_name=study_name, storage=st)


def checkpoint_info(
    study_name: str, storage: str | optuna.storages.BaseStorage
) -> dict[str, Any] | None:
    """Metadata of a study's last checkpoint (generation, evaluations, time) or None."""
    st = open_storage(storage)
    return st.get_study_system_attrs(st.get_study_id_from_name(study_name)).get(CHECKPOINT_META)


def _jsonable(obj: Any) -> Any:
    return json.loads(json.dumps(obj, default=lambda o: np.asarray(o).tolist()))


class StudyStore:
    """Writes evaluations and checkpoints of one run to an Optuna study.

    Args:
        storage: Optuna storage URL or object; ``None`` = in memory.
        study_name: the study (one per run).
        problem: the task problem (names, distributions, fingerprint).
        run_config: JSON-able run settings stored as the study's ``tuner_config``.
        resume: continue an existing study; without it an existing non-empty study is
            an error (:class:`StudyExistsError`).
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
        try:
            self.study_id = self.storage.get_study_id_from_name(study_name)
            exists = True
        except KeyError:
            exists = False
        if exists:
            study = optuna.load_study(study_name=study_name, storage=self.storage)
            stored = study.user_attrs.get(CONFIG_ATTR)
            if not resume and (stored is not None or len(study.trials) > 0):
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
        self.distributions = {
            name: FloatDistribution(lo, hi, log=log)
            for name, (lo, hi, log) in problem.param_distributions().items()
        }

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
            cons = dict(zip(problem.constr_names, outcome.get("G", []), strict=True))
            trial = optuna.trial.create_trial(
                values=list(outcome["F"]),
                params=params,
                distributions=self.distributions,
                user_attrs=ua,
                constraints=cons or None,
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
    def save_checkpoint(self, algorithm: Any, **info: Any) -> int:
        """Pickle ``algorithm`` (without problem/callback/display) into the study.

        Returns the number of characters written.
        """
        saved = {k: algorithm.__dict__.get(k) for k in DETACHED if k in algorithm.__dict__}
        try:
            for k in saved:
                algorithm.__dict__[k] = [] if k == "history" else None
            raw = pickle.dumps(algorithm, protocol=pickle.HIGHEST_PROTOCOL)
        finally:
            algorithm.__dict__.update(saved)
        blob = base64.b64encode(zlib.compress(raw, 6)).decode("ascii")
        attrs = self.storage.get_study_system_attrs(self.study_id)
        prev = attrs.get(CHECKPOINT_META) or {}
        slot = "b" if prev.get("slot") == "a" else "a"
        chunks = [blob[i : i + CHUNK_CHARS] for i in range(0, len(blob), CHUNK_CHARS)]
        for i, chunk in enumerate(chunks):
            self.storage.set_study_system_attr(self.study_id, f"tuner:ckpt:{slot}:{i}", chunk)
        meta = {
            "slot": slot,
            "n_chunks": len(chunks),
            "sha256": hashlib.sha256(blob.encode()).hexdigest(),
            "n_gen": int(algorithm.n_iter) - 1 if algorithm.n_iter else 0,
            "n_eval": int(algorithm.evaluator.n_eval),
            "saved_at": datetime.datetime.now().isoformat(timespec="seconds"),
            **_jsonable(info),
        }
        self.storage.set_study_system_attr(self.study_id, CHECKPOINT_META, meta)
        return len(blob)

    def checkpoint_info(self) -> dict[str, Any] | None:
        return self.storage.get_study_system_attrs(self.study_id).get(CHECKPOINT_META)

    def load_checkpoint(self) -> Any | None:
        """The last checkpointed algorithm (detached parts set to None), or None."""
        attrs = self.storage.get_study_system_attrs(self.study_id)
        meta = attrs.get(CHECKPOINT_META)
        if not meta:
            return None
        slot = meta["slot"]
        blob = "".join(attrs[f"tuner:ckpt:{slot}:{i}"] for i in range(meta["n_chunks"]))
        if hashlib.sha256(blob.encode()).hexdigest() != meta["sha256"]:
            raise ValueError(f"checkpoint of study {self.study_name!r} is corrupt (hash mismatch)")
        return pickle.loads(zlib.decompress(base64.b64decode(blob)))


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
