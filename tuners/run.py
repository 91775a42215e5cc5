"""``tune()``: search an env's controller parameters — parallel, persistent, resumable.

A run = a :class:`tuners.problem.EnvTuningProblem` (or any
:class:`~tuners.problem.TaskProblem`), a pymoo algorithm (``mowoa``, ``pso``,
``mopso``, pymoo's ``nsga2`` / ``moead`` as baselines, or an Optuna sampler
``optuna-tpe`` / ``optuna-nsga2`` / ``optuna-nsga3`` / ``optuna-gp``:
:mod:`tuners.optuna_samplers`), an evaluation backend
(:mod:`tuners.backends`) and an Optuna study (:mod:`tuners.storage`). Each generation is
one batch of evaluations; every finished evaluation is written to the study at once and
a checkpoint (plain data) after every generation, so ``resume=True`` continues a killed
run — the algorithm rebuilt from the stored settings and replayed from the stored
evaluations (:mod:`tuners.checkpoint`) — without re-running any finished evaluation and
ends with exactly the uninterrupted run's result. Settings left out on resume take the
stored values; a changed one is refused by name (:mod:`tuners.settings`); one process
writes a study at a time (:mod:`tuners.lease`). A run records the fingerprint of the code that
evaluates (:func:`tuners.storage.code_fingerprint`); resuming it with other code is
refused (its cached evaluations would answer for the new code) unless
``allow_code_change=True``. ``{code}`` in a study name stands for that fingerprint's
first 8 digits: a study per code version, resumable as long as the code is the same.

Budget: ``iters`` is pymoo's number of generations *including* the initial one, so a
run makes at most ``pop × iters`` evaluations (fewer distinct ones: repeated points are
answered from the cache).

Result (:class:`TuneResult`): the DataFrame of all evaluations, the Pareto set (feasible
non-dominated evaluations), and the selected solution — paper 004's pick: of the
``pop`` subproblem weight vectors the one closest in angle to ``target_weights``, and
the Pareto point minimising its Tchebycheff value (:func:`tuners.mowoa.select_by_cosine`).
The Tchebycheff values of the pick and of the report are relative to the run's ideal
point (best feasible value per objective) and, by default, scaled by the defaults'
distance to it, so that "better than the defaults in every weighted objective" means a
lower value (:func:`summarize`; ``f_bounds`` gives 004's fixed tolerance scale instead). With
``include_defaults`` (default) the controller's default parameters are the first point
of the initial population, so the run always contains — and can only improve on — them.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from pymoo.core.algorithm import Algorithm
from pymoo.core.callback import Callback

from train_envs.labels import format_table
from tuners.backends import EvalStats, Evaluations, default_backend, make_backend
from tuners.checkpoint import generations_done, replay, set_iters
from tuners.mowoa import (
    MOWOA,
    InitialSampling,
    nondominated,
    tchebycheff,
)
from tuners.optuna_samplers import OPTUNA_ALGORITHMS, OptunaSampler
from tuners.problem import EnvTuningProblem, TaskProblem
from tuners.pso import MOPSO, PSO
from tuners.selection import (
    NORMALIZATIONS,
    run_weight_vectors,
    summarize,
)
from tuners.settings import DEFAULTS, resolve_settings
from tuners.storage import (
    CONFIG_ATTR,
    StudyExistsError,
    StudyStore,
    checkpoint_info,
    code_fingerprint,
    drop_interrupted_frames,
    evaluations_frame,
    load_study,
    stored_run_config,
)

ALGORITHMS = ("mowoa", "pso", "mopso", "nsga2", "moead", *OPTUNA_ALGORITHMS)
#: algorithms with one weight vector per individual
DECOMPOSITION = ("mowoa", "mopso", "moead")
DEFAULT_STORAGE = "sqlite:///tuning.db"

__all__ = [
    "ALGORITHMS",
    "DEFAULT_STORAGE",
    "TuneInterrupted",
    "TuneResult",
    "load_result",
    "make_algorithm",
    "run_weight_vectors",
    "show",
    "summarize",
    "tune",
]


# ----------------------------------------------------------------- algorithms
def make_algorithm(
    algo: str,
    pop: int,
    problem: TaskProblem,
    *,
    target_weights: Sequence[float] | None = None,
    initial_X: np.ndarray | None = None,
    **kwargs: Any,
) -> Algorithm:
    """A pymoo algorithm by name; ``initial_X`` rows start the initial population.

    The decomposition algorithms (``mowoa``, ``mopso``, ``moead``) get
    :func:`run_weight_vectors` (the target is one of the subproblems) unless
    ``ref_dirs`` is given.
    """
    if algo in ("mowoa", "mopso", "moead") and problem.n_obj > 1:
        kwargs.setdefault("ref_dirs", run_weight_vectors(problem.n_obj, pop, target_weights))
    if algo in OPTUNA_ALGORITHMS:
        return OptunaSampler(algo, pop_size=pop, initial_X=initial_X, **kwargs)
    if algo == "mowoa":
        return MOWOA(pop_size=pop, initial_X=initial_X, **kwargs)
    if algo == "pso":
        return PSO(pop_size=pop, weights=target_weights, initial_X=initial_X, **kwargs)
    if algo == "mopso":
        return MOPSO(pop_size=pop, initial_X=initial_X, **kwargs)
    if algo == "nsga2":
        from pymoo.algorithms.moo.nsga2 import NSGA2

        return NSGA2(pop_size=pop, sampling=InitialSampling(initial_X), **kwargs)
    if algo == "moead":
        from pymoo.algorithms.moo.moead import ParallelMOEAD

        if problem.n_obj < 2:
            raise ValueError("moead needs at least two objectives")
        return ParallelMOEAD(
            kwargs.pop("ref_dirs"),
            n_neighbors=kwargs.pop("n_neighbors", max(2, int(np.ceil(0.2 * pop)))),
            sampling=InitialSampling(initial_X),
            **kwargs,
        )
    raise ValueError(f"algo must be one of {ALGORITHMS}, got {algo!r}")


@dataclass
class TuneResult:
    """Everything a tuning run produced.

    Attributes:
        study_name, storage: where the run lives (``storage`` None = in memory).
        problem: the task problem (for re-evaluation on other seeds).
        evaluations: one row per evaluation (see :func:`tuners.storage.evaluations_frame`)
            plus ``pareto``, ``selected``, ``tchebycheff`` and ``is_default``.
        pareto: the Pareto rows; selected: the selected row (or None if none feasible).
        objectives: objective column names; target_weights: normalised target weights.
        ideal, nadir: the normalisation of the Tchebycheff values and the selection
            (scale = nadir − ideal); normalization: how it was chosen (:func:`summarize`).
        pymoo_result: pymoo's ``Result`` (``res.X``, ``res.F``, ``res.opt``, ...).
        stats: evaluation counters (run, cached, failures, times).
        backend: the evaluation backend that ran (``""`` for a loaded result).
    """

    study_name: str
    storage: str | None
    problem: TaskProblem
    algo: str
    evaluations: pd.DataFrame
    pareto: pd.DataFrame
    selected: pd.Series | None
    objectives: list[str]
    target_weights: np.ndarray
    ideal: np.ndarray | None
    nadir: np.ndarray | None
    normalization: str = "auto"
    pymoo_result: Any = None
    stats: EvalStats = field(default_factory=EvalStats)
    wall_time_s: float = 0.0
    backend: str = ""

    @property
    def selected_params(self) -> dict[str, float] | None:
        """Controller parameters of the selected solution."""
        if self.selected is None:
            return None
        if self.problem is not None:
            return self.problem.param_values(np.asarray(self.selected["x"], float))
        # a result loaded from storage has no problem: read the stored settings
        cfg = load_study(self.study_name, self.storage).user_attrs.get(CONFIG_ATTR) or {}
        params = {
            str(k): float(v)
            for k, v in ((cfg.get("problem") or {}).get("fixed_params") or {}).items()
        }
        params.update({n: float(self.selected[n]) for n in cfg.get("param_names") or []})
        return params

    def to_csv(self, path: str | Path) -> Path:
        path = Path(path)
        self.evaluations.to_csv(path, index=False)
        return path

    def to_parquet(self, path: str | Path) -> Path:
        path = Path(path)
        df = self.evaluations.copy()
        for col in ("x", "seeds"):
            if col in df:
                df[col] = df[col].map(json.dumps)
        df.to_parquet(path, index=False)
        return path

    def tchebycheff_of(self, F: np.ndarray) -> np.ndarray:
        """Tchebycheff values of objective rows under this run's weights/normalisation."""
        return tchebycheff(np.atleast_2d(F), self.target_weights, self.ideal, self.nadir)

    def _points(self) -> dict[str, np.ndarray]:
        """The default point and, if any, the selected one (unit-cube coordinates)."""
        assert isinstance(self.problem, EnvTuningProblem)
        points = {"defaults": self.problem.default_x()}
        if self.selected is not None:
            points["selected"] = np.asarray(self.selected["x"], float)
        return points

    def compare_on_seeds(
        self, seeds: Sequence[int], points: Mapping[str, np.ndarray] | None = None
    ) -> pd.DataFrame:
        """Evaluate the selected solution and the defaults on other (held-out) seeds.

        Runs serially here. Returns one row per point with its mean objectives, worst
        constraint values and Tchebycheff value under this run's target weights and
        normalisation (lower is better).
        """
        if not isinstance(self.problem, EnvTuningProblem):
            raise TypeError("compare_on_seeds needs an EnvTuningProblem")
        prob = self.problem.with_seeds(seeds)
        if points is None:
            points = self._points()
        rows = []
        from tuners.problem import run_task

        for name, x in points.items():
            out = run_task(prob.make_task(np.asarray(x, float)))
            row = {"point": name, **dict(zip(self.objectives, out["F"], strict=True))}
            row.update({f"g:{n}": g for n, g in zip(prob.constr_names, out["G"], strict=True)})
            row["tchebycheff"] = float(self.tchebycheff_of(np.asarray(out["F"]))[0])
            row.update(prob.x_to_params(x))
            rows.append(row)
        return pd.DataFrame(rows)

    def trajectories(
        self, seed: int, points: Mapping[str, np.ndarray] | None = None
    ) -> dict[str, pd.DataFrame]:
        """Closed-loop runs (the runner's DataFrames) of the defaults and the selected point.

        Each point is run once on scenario ``seed`` with the env's episodes, exactly as the
        tuner evaluated it; use the result with
        :func:`train_envs.plotting.comparison_figure` for an overlay. Keys: ``defaults``
        and ``selected``, or ``selected (= defaults)`` when the selected point is the
        default point (its run is then the same).
        """
        import train_envs  # noqa: F401  (registers the ids)
        from train_envs.envs.evaluation import evaluate_env_params

        if not isinstance(self.problem, EnvTuningProblem):
            raise TypeError("trajectories needs an EnvTuningProblem")
        prob = self.problem
        if points is None:
            points = self._points()
            if "selected" in points and np.array_equal(points["selected"], points["defaults"]):
                # the same point runs the same episode: the name says why one curve of a
                # figure hides the other
                points["selected (= defaults)"] = points.pop("selected")
        out: dict[str, pd.DataFrame] = {}
        for name, x in points.items():
            frames: dict[int, pd.DataFrame] = {}
            evaluate_env_params(
                prob.env_id,
                prob.task_params(np.asarray(x, float)),
                seeds=[int(seed)],
                config=prob.config,
                frames=frames,
            )
            out[name] = frames[int(seed)]
        return out


def _result_from_frame(
    df: pd.DataFrame,
    problem: TaskProblem | None,
    study_name: str,
    storage: str | None,
    algo: str,
    objectives: list[str],
    target_weights: Sequence[float] | None,
    default_key: str | None = None,
    params: Sequence[str] | None = None,
    n_weights: int = 40,
    f_bounds: tuple[Sequence[float], Sequence[float]] | None = None,
    normalization: str = "auto",
) -> TuneResult:
    pareto, selected, ideal, nadir = summarize(
        df, objectives, target_weights, n_weights, f_bounds, normalization, default_key
    )
    m = len(objectives)
    w = np.full(m, 1.0 / m) if target_weights is None else np.asarray(target_weights, float)
    df["is_default"] = (df["key"] == default_key) if len(df) and default_key else False
    df.attrs["objectives"] = list(objectives)
    df.attrs["params"] = list(params or [])
    return TuneResult(
        study_name=study_name,
        storage=storage,
        problem=problem,
        algo=algo,
        evaluations=df,
        pareto=pareto,
        selected=selected,
        objectives=objectives,
        target_weights=w / w.sum(),
        ideal=ideal,
        nadir=nadir,
        normalization=df.attrs.get("normalization", normalization),
    )


# ----------------------------------------------------------------------- tune
def tune(
    env_id: str | TaskProblem,
    algo: str | None = None,
    pop: int | None = None,
    iters: int | None = None,
    *,
    workers: int | None = None,
    backend: str | None = None,
    dask_address: str | None = None,
    dask_client: Any = None,
    storage: str | Any | None = DEFAULT_STORAGE,
    study: str | None = None,
    resume: bool | str = False,
    seeds: Sequence[int] | None = None,
    objectives: Sequence[str] | None = None,
    target_weights: Sequence[float] | None = None,
    f_bounds: tuple[Sequence[float], Sequence[float]] | None = None,
    normalization: str | None = None,
    seed: int | None = None,
    config: Mapping[str, Any] | None = None,
    params: Sequence[str] | None = None,
    space: str | None = None,
    constraints: Mapping[str, float] | None = None,
    include_defaults: bool | None = None,
    max_retries: int = 2,
    algo_kwargs: Mapping[str, Any] | None = None,
    progress: bool = False,
    callback: Callback | None = None,
    on_evaluation: Callable[[str, dict[str, Any], int | None], None] | None = None,
    allow_code_change: bool = False,
) -> TuneResult:
    """Tune the controller of ``env_id`` (or optimise any TaskProblem); see module doc.

    A setting left as ``None`` takes its default in a new study (shown in brackets)
    and the stored value on resume; on resume a setting given with another value is
    refused, except ``iters`` (:mod:`tuners.settings`).

    Args:
        env_id: registered env id, or a ready :class:`TaskProblem` (then ``seeds``,
            ``objectives``, ``config``, ``params``, ``space``, ``constraints`` are unused);
            on resume of an env study ``None`` takes the stored env id.
        algo: ``mowoa`` | ``pso`` | ``mopso`` | ``nsga2`` | ``moead`` | an Optuna
            sampler of :data:`tuners.optuna_samplers.OPTUNA_ALGORITHMS` [mowoa].
        pop, iters: population size [40] and generations incl. the initial one [100].
        workers, backend, dask_address, dask_client: evaluation backend
            (``serial`` | ``processes`` | ``lockstep`` | ``dask``; default
            :func:`tuners.backends.default_backend`: ``lockstep`` for an env whose
            controller batches, else ``processes``; workers default: all cores).
        storage: Optuna storage URL (default ``sqlite:///tuning.db``), or
            ``journal:PATH`` (:func:`tuners.storage.open_storage`); None = in memory.
        study: study name (default ``<env>-<algo>-s<seed>``).
        resume: ``True``: continue the study (an error if it holds no run);
            ``"auto"``: continue it if it holds one, else start it; ``False``: start it
            (an error if it holds a run).
        seeds: scenario seeds averaged per evaluation [0].
        objectives: objective aliases / metric columns (default: 004's five available).
        target_weights: weights of the final pick and of ``pso`` (default: equal).
        f_bounds: (lower, upper) per objective: 004's tolerance bounds; the Tchebycheff
            scale becomes upper − lower (algorithms and final pick); default adaptive.
        normalization: scale of the final pick and reported Tchebycheff values when
            ``f_bounds`` is not given: ``auto`` | ``defaults`` | ``pareto``
            (:func:`summarize`) [auto].
        seed: random seed of the algorithm [1].
        config, params, space, constraints: see :class:`EnvTuningProblem`.
        include_defaults: start the initial population with the default parameters [True].
        max_retries: re-submissions of an evaluation that failed by its own error.
        algo_kwargs: extra keyword arguments of the algorithm.
        progress: show a progress bar (generation, evaluations/s, best Tchebycheff value
            under the target weights, normalised by the first generation's range).
        callback: pymoo callback called after every generation (not the replayed ones).
        on_evaluation: called with (key, outcome, generation) after each new evaluation.
        allow_code_change: resume a study that other code started (its evaluations and
            cache are kept as they are; the code fingerprints are recorded).

    Raises:
        TuneInterrupted: on Ctrl-C (a ``KeyboardInterrupt``), after the pool is stopped;
            it says how many evaluations the study holds and how to resume.
    """
    t_start = time.perf_counter()
    if resume not in (True, False, "auto"):
        raise ValueError(f"resume must be True, False or 'auto', got {resume!r}")
    given = {
        "algo": algo,
        "pop": pop,
        "iters": iters,
        "seed": seed,
        "seeds": None if seeds is None else [int(s) for s in seeds],
        "objectives": None if objectives is None else list(objectives),
        "constraints": None if constraints is None else dict(constraints),
        "config": None if config is None else dict(config),
        "params": None if params is None else list(params),
        "space": space,
        "target_weights": None if target_weights is None else list(target_weights),
        "f_bounds": f_bounds,
        "normalization": normalization,
        "include_defaults": include_defaults,
        "algo_kwargs": None if algo_kwargs is None else dict(algo_kwargs),
    }
    code = code_fingerprint()
    if isinstance(env_id, TaskProblem):
        env_name = getattr(env_id, "env_id", getattr(env_id, "name_", type(env_id).__name__))
    else:
        env_name = env_id
    study_name = (
        study
        or f"{str(env_name).split('/')[-1]}-{algo or DEFAULTS['algo']}-s"
        f"{DEFAULTS['seed'] if seed is None else seed}"
    ).replace("{code}", code[:8])
    has_run, stored = stored_run_config(study_name, storage)
    if resume is True and not has_run:
        where = storage if isinstance(storage, str) else "this storage"
        raise ValueError(
            f"--resume: study {study_name!r} holds no run in {where} (see `train-envs tune "
            "list`); leave out --resume to start it"
        )
    resuming = bool(resume) and has_run
    if not resuming and has_run:
        raise StudyExistsError(
            f"study {study_name!r} already holds a run; pass resume=True (--resume) to "
            "continue it or choose another study name"
        )
    s = resolve_settings(given, stored if resuming else None, study_name)
    if env_name is None:
        env_name = env_id = (stored or {}).get("env_id")
    elif resuming and not isinstance(env_id, TaskProblem) and stored.get("env_id") != env_id:
        raise ValueError(
            f"cannot resume study {study_name!r}: env_id (stored {stored.get('env_id')!r}, "
            f"given {env_id!r})"
        )
    algo, pop, iters, seed = s["algo"], int(s["pop"]), int(s["iters"]), int(s["seed"])
    normalization = s["normalization"]
    if normalization not in NORMALIZATIONS:
        raise ValueError(f"normalization must be one of {NORMALIZATIONS}, got {normalization!r}")
    if algo not in ALGORITHMS:
        raise ValueError(f"algo must be one of {ALGORITHMS}, got {algo!r}")
    if pop < 2 or iters < 1:
        raise ValueError(f"need pop >= 2 and iters >= 1, got pop={pop}, iters={iters}")
    mode = "penalty" if algo == "moead" else "constraint"
    if isinstance(env_id, TaskProblem):
        problem = env_id
        if algo == "moead" and problem.n_ieq_constr:
            raise ValueError("moead has no constraint handling: build the problem in penalty mode")
    else:
        problem = EnvTuningProblem(
            env_id,
            objectives=s["objectives"],
            seeds=s["seeds"],
            config=s["config"],
            params=s["params"],
            space=s["space"],
            constraints=s["constraints"],
            constraint_mode=mode,
        )
    be = make_backend(
        backend or default_backend(problem),
        workers,
        address=dask_address,
        client=dask_client,
        max_retries=max_retries,
    )
    be.start()  # the workers start while the driver checks the problem and opens the study
    try:
        if not resuming and not isinstance(env_id, TaskProblem):
            problem.check_metrics()  # unknown metric names: one error here, before any work
        m = problem.n_obj
        target_weights, f_bounds = s["target_weights"], s["f_bounds"]
        if target_weights is not None and len(target_weights) != m:
            raise ValueError(
                f"target_weights needs {m} values ({problem.obj_names}), got {target_weights}"
            )
        if f_bounds is not None and any(len(b) != m for b in f_bounds):
            raise ValueError(f"f_bounds needs (lower, upper) with {m} values each, got {f_bounds}")
        if algo in DECOMPOSITION and 2 < m and pop < m:
            raise ValueError(
                f"pop {pop} is below the {m} objectives: {algo} gives each individual one weight "
                f"vector and needs at least one per objective (pop >= {m}), or use fewer objectives"
            )
        weights = list(np.full(m, 1.0 / m) if target_weights is None else target_weights)
        initial_X = None
        default_key = None
        if s["include_defaults"] and hasattr(problem, "default_x"):
            initial_X = problem.default_x()[None, :]
            default_key = problem.key(initial_X[0])
        run_config = {
            "env_id": str(env_name),
            "algo": algo,
            "pop": pop,
            "iters": iters,
            "seed": seed,
            "seeds": list(getattr(problem, "seeds", []) or []),
            "objective_names": list(problem.obj_names),
            "constraint_names": list(problem.constr_names),
            "param_names": list(problem.var_names),
            "target_weights": [float(v) for v in weights],
            "f_bounds": None if f_bounds is None else [list(map(float, b)) for b in f_bounds],
            "normalization": normalization,
            "include_defaults": bool(s["include_defaults"]),
            "algo_kwargs": dict(s["algo_kwargs"] or {}),
            "fingerprint": problem.fingerprint_hash(),
            "problem": problem.fingerprint(),
            "default_key": default_key,
            "code": code,
        }
        if resuming and stored.get("fingerprint") != run_config["fingerprint"]:
            old, new = stored.get("problem") or {}, run_config["problem"]
            keys = sorted(k for k in set(old) | set(new) if old.get(k) != new.get(k))
            raise ValueError(
                f"cannot resume study {study_name!r}: the problem differs in "
                + "; ".join(f"{k} (stored {old.get(k)!r}, now {new.get(k)!r})" for k in keys)
            )
        checks = ("fingerprint", "algo", "pop", "seed") + (() if allow_code_change else ("code",))
        store = StudyStore(
            storage, study_name, problem, run_config, resume=resuming, check_keys=checks
        )
        try:
            return _run(
                store,
                problem,
                run_config,
                initial_X,
                weights,
                f_bounds,
                storage,
                backend=be,
                progress=progress,
                callback=callback,
                on_evaluation=on_evaluation,
                t_start=t_start,
            )
        except KeyboardInterrupt as exc:  # (one before the loop: a resume's first read)
            drop_interrupted_frames(exc)
            raise
        finally:
            store.close()
    except BaseException:
        be.terminate()  # (workers that may still be starting)
        raise
    finally:
        be.close()


def _run(
    store: StudyStore,
    problem: TaskProblem,
    cfg: dict[str, Any],
    initial_X: np.ndarray | None,
    weights: list[float],
    f_bounds: Any,
    storage: Any,
    *,
    backend: Any,
    progress: bool,
    callback: Callback | None,
    on_evaluation: Callable[[str, dict[str, Any], int | None], None] | None,
    t_start: float,
) -> TuneResult:
    """The generation loop of :func:`tune` on an opened store (replay, run, result)."""
    algo, pop, iters, seed = cfg["algo"], cfg["pop"], cfg["iters"], cfg["seed"]
    study_name = store.study_name
    checkpoint = store.load_checkpoint() if store.resumed else None
    cache = store.load_cache() if store.resumed else {}
    be = backend
    bar = None
    t_loop = time.perf_counter()

    def _on_evaluation(key: str, outcome: dict[str, Any], generation: int | None) -> None:
        if bar is not None:  # live rate within long generations
            rate = evals.stats.run / max(time.perf_counter() - t_loop, 1e-9)
            bar.set_postfix(gen=generation, evals=evals.stats.run, evals_per_s=f"{rate:.2f}")
        if on_evaluation is not None:
            on_evaluation(key, outcome, generation)

    evals = Evaluations(be, store, cache, on_evaluation=_on_evaluation)
    problem.runner = evals
    kw = dict(cfg["algo_kwargs"] or {})
    if f_bounds is not None and algo in ("mowoa", "mopso", "pso"):
        kw.setdefault("f_bounds", f_bounds)
    schedule = [[1, iters]] if checkpoint is None else [list(s) for s in checkpoint["schedule"]]
    algorithm = make_algorithm(
        algo, pop, problem, target_weights=weights, initial_X=initial_X, **kw
    )
    algorithm.setup(
        problem,
        termination=("n_gen", schedule[0][1]),
        seed=seed,
        verbose=False,
        callback=callback if callback is not None else Callback(),
    )
    try:
        if checkpoint is not None:
            replay(algorithm, checkpoint, study_name)
            if schedule[-1][1] != iters:  # a resume with another budget
                schedule.append([generations_done(algorithm) + 1, iters])
            set_iters(algorithm, iters)
        bar_ref: dict[str, np.ndarray] = {}  # frozen normalisation of the bar's best value
        if progress:
            from tqdm.auto import tqdm

            done = generations_done(algorithm)
            bar = tqdm(total=iters, initial=min(done, iters), desc=study_name, unit="gen")
        t_loop = time.perf_counter()
        while algorithm.has_next():
            algorithm.next()
            t_ck = time.perf_counter()
            store.save_checkpoint(algorithm, schedule)
            if store.lease is not None:
                store.lease.check()
            evals.stats.checkpoint_time_s += time.perf_counter() - t_ck
            if bar is not None:
                rate = evals.stats.run / max(time.perf_counter() - t_loop, 1e-9)
                bar.update(1)
                bar.set_postfix(
                    gen=generations_done(algorithm),
                    evals=evals.stats.run,
                    evals_per_s=f"{rate:.2f}",
                    best=f"{_best_scalar(evals.cache, weights, f_bounds, bar_ref):.4g}",
                )
        res = algorithm.result()
    except KeyboardInterrupt as exc:
        drop_interrupted_frames(exc)  # else an open cursor blocks the study's last writes
        be.terminate()
        n = len(store.load_cache())
        raise TuneInterrupted(study_name, storage, n) from exc
    finally:
        if bar is not None:
            bar.close()
        be.close()
        problem.runner = None

    df = evaluations_frame(store.study)
    out = _result_from_frame(
        df,
        problem,
        study_name,
        storage if isinstance(storage, str) or storage is None else repr(storage),
        algo,
        list(problem.obj_names),
        weights,
        cfg["default_key"],
        list(problem.var_names),
        pop,
        f_bounds,
        cfg["normalization"],
    )
    out.pymoo_result = res
    out.stats = evals.stats
    out.backend = be.name
    out.wall_time_s = time.perf_counter() - t_start
    return out


class TuneInterrupted(KeyboardInterrupt):
    """Ctrl-C stopped :func:`tune`; the study keeps every finished evaluation."""

    def __init__(self, study_name: str, storage: Any, n_evaluations: int) -> None:
        self.study_name, self.storage, self.n_evaluations = study_name, storage, n_evaluations
        where = f" --storage {storage}" if isinstance(storage, str) else ""
        super().__init__(
            f"interrupted after {n_evaluations} evaluations; resume with: train-envs tune "
            f"--study {study_name}{where} --resume"
        )


def _best_scalar(
    cache: Mapping[str, Mapping[str, Any]],
    weights: Sequence[float],
    f_bounds: tuple[Sequence[float], Sequence[float]] | None = None,
    ref: dict[str, np.ndarray] | None = None,
) -> float:
    """Best Tchebycheff value so far for the progress bar.

    The normalisation is frozen at the first call (in ``ref``) so that the shown value
    can only go down.
    """
    F = [o["F"] for o in cache.values() if not o.get("failed") and max(o.get("G") or [0]) <= 0]
    if not F:
        return float("nan")
    F = np.asarray(F, float)
    ref = {} if ref is None else ref
    if "ideal" not in ref:
        ideal = F.min(axis=0)
        nadir = F[nondominated(F)].max(axis=0)
        nadir = np.where(nadir > ideal, nadir, F.max(axis=0))
        if f_bounds is not None:
            nadir = ideal + (np.asarray(f_bounds[1], float) - np.asarray(f_bounds[0], float))
        ref.update(ideal=ideal, nadir=nadir)
    w = np.asarray(weights, float)
    return float(np.min(tchebycheff(F, w / w.sum(), ref["ideal"], ref["nadir"])))


# ------------------------------------------------------------------ show/load
def load_result(study: str, storage: str = DEFAULT_STORAGE) -> TuneResult:
    """Rebuild a :class:`TuneResult` (without the problem/pymoo result) from a study."""
    st = load_study(study, storage)
    cfg = st.user_attrs.get(CONFIG_ATTR) or {}
    objectives = cfg.get("objective_names") or st.metric_names
    df = evaluations_frame(st)
    return _result_from_frame(
        df,
        None,
        study,
        storage,
        cfg.get("algo", "?"),
        list(objectives),
        cfg.get("target_weights"),
        cfg.get("default_key"),
        cfg.get("param_names"),
        int(cfg.get("pop", 40)),
        cfg.get("f_bounds"),
        cfg.get("normalization", "auto"),
    )


def show(study: str, storage: str = DEFAULT_STORAGE, max_rows: int = 50) -> str:
    """Text report of a study: settings, Pareto set, selected solution, defaults."""
    r = load_result(study, storage)
    st = load_study(study, storage)
    cfg = st.user_attrs.get(CONFIG_ATTR) or {}
    ckpt = checkpoint_info(study, storage) or {}
    df = r.evaluations
    params = cfg.get("param_names") or []
    cols = [c for c in params + r.objectives + ["tchebycheff"] if c in df.columns]
    lines = [
        f"study {study} ({storage}): env {cfg.get('env_id')}, algo {cfg.get('algo')}, "
        f"pop {cfg.get('pop')}, iters {cfg.get('iters')}, seed {cfg.get('seed')}, "
        f"scenario seeds {cfg.get('seeds')}",
        f"generations done {ckpt.get('n_gen', '?')}, evaluations {len(df)} "
        f"({int(df['failed'].sum()) if len(df) else 0} failed, "
        f"{int((~df['feasible']).sum()) if len(df) else 0} infeasible), "
        f"target weights {np.round(r.target_weights, 4).tolist()}, "
        f"normalisation {r.normalization}",
    ]
    lines.append(f"Pareto set ({len(r.pareto)} solutions):")
    if len(r.pareto):
        lines.append(format_table(r.pareto[cols].head(max_rows), digits=5))
    if r.selected is not None:
        lines.append("Selected (cosine similarity to the target weights):")
        lines.append(format_table(r.selected[cols].to_frame().T.infer_objects(), digits=5))
    dflt = df[df["is_default"]] if "is_default" in df else df.iloc[0:0]
    if len(dflt):
        lines.append("Defaults:")
        lines.append(format_table(dflt[cols], digits=5))
    return "\n".join(lines)
