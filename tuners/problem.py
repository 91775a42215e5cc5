"""pymoo problems whose evaluations are closed-loop episodes (or any picklable task).

:class:`EnvTuningProblem` turns a registered env id into a pymoo ``Problem``:

* **variables** — the env's exposed tunable parameters (``param_specs``; a subset with
  ``params=``), searched either in the env's own action scale, the unit cube
  ``space="unit"`` (x ∈ [−1, 1]ⁿ, mapped by :meth:`TunableParam.from_unit`, i.e.
  log-uniform for ``log`` parameters; default), or in ``space="native"`` (x_i ∈
  [low, high], log10(value) ∈ [log10 low, log10 high] for ``log`` parameters); the
  mapping is :class:`train_envs.controllers.params.ParamSpace`'s, and the value of a
  point (:meth:`EnvTuningProblem.param_values`, what the study stores) is exactly the
  value the controller runs with;
* **objectives** — episode metrics of :func:`train_envs.envs.evaluation.evaluate_env_params`
  (the runner's :func:`~train_envs.simulation.evaluate_params`), each averaged
  over the scenario seeds: by default paper 004's five, ``itae`` (``ITAE_m_s``),
  ``stop`` (``E_p_m`` = |stopping error|), ``time`` (``time_error_s``), ``comfort``
  (``comfort_mean_abs_jerk_mps3``), ``energy`` (``energy_kWh``), dropping ``stop`` /
  ``time`` where the scenario has no stop / schedule; any metric column name works too;
* **constraints** — ``g_j = max over seeds of metric_j − limit_j ≤ 0``; by default
  ``max_overspeed_mps ≤ 0`` (a safety limit). ``constraint_mode="penalty"`` instead adds
  ``penalty · Σ max(0, g_j)`` to every objective (for algorithms without constraint
  handling, e.g. pymoo's MOEA/D);
* **failures** — an evaluation that still fails after the retries of the backend gets
  ``F = G = fail_value`` (1e10): infeasible, never selected, and the run goes on.

Each point becomes a picklable task (:class:`EnvTask`) run by :func:`run_task` in the
current process or a worker (tasks of one env several at once by
:meth:`EnvTask.run_batch`: the lockstep backend); :class:`TaskProblem` hands a whole batch to its
``runner`` (:class:`tuners.backends.Evaluations`: cache, backend, storage) when one is
attached, else runs the tasks serially here. :class:`PymooTaskProblem` wraps any pymoo
problem (ZDT1, a sphere, ...) the same way, for tests and benchmarks.
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
import os
import socket
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from pymoo.core.problem import Problem

from train_envs.controllers.params import SPACES, ParamSpace

OBJECTIVE_ALIASES: dict[str, str] = {
    "itae": "ITAE_m_s",
    "stop": "E_p_m",
    "time": "time_error_s",
    "comfort": "comfort_mean_abs_jerk_mps3",
    "energy": "energy_kWh",
}
DEFAULT_OBJECTIVES: tuple[str, ...] = ("itae", "stop", "time", "comfort", "energy")
DEFAULT_CONSTRAINTS: dict[str, float] = {"max_overspeed_mps": 0.0}
FAIL_VALUE = 1e10

__all__ = [
    "DEFAULT_CONSTRAINTS",
    "DEFAULT_OBJECTIVES",
    "EnvTask",
    "EnvTuningProblem",
    "FAIL_VALUE",
    "OBJECTIVE_ALIASES",
    "PymooTask",
    "PymooTaskProblem",
    "TaskProblem",
    "ConfigError",
    "finish_outcome",
    "metric_columns",
    "objective_column",
    "run_task",
]


class ConfigError(ValueError):
    """A task cannot run for a reason that is the same for every point (an unknown
    metric, an env that cannot be made): the run stops at the first one."""


def metric_columns(df: Any) -> list[str]:
    """The numeric metric columns of an episode table (what objectives can name)."""
    skip = ("seed", "episode")
    return sorted(c for c in df.columns if df[c].dtype.kind in "fiub" and c not in skip)


def objective_column(name: str) -> str:
    """Metric column of an objective alias (``itae`` → ``ITAE_m_s``); other names pass."""
    return OBJECTIVE_ALIASES.get(name.lower(), name)


def run_task(task: Any) -> dict[str, Any]:
    """Run one task (in this process or a worker): its outcome plus wall time and worker.

    The outcome is a dict with ``F`` and ``G`` (lists of floats) and optional
    ``metrics``; every value is a plain Python float so that it round-trips through
    JSON (the study) bit-exactly.
    """
    t0 = time.perf_counter()
    out = dict(task.run())
    return finish_outcome(out, time.perf_counter() - t0)


def finish_outcome(out: Mapping[str, Any], wall_time_s: float) -> dict[str, Any]:
    """A task's raw outcome as :func:`run_task` returns it: ``F``/``G`` as plain floats
    (``ValueError`` if one is not finite), the wall time and the worker."""
    out = dict(out)
    out["F"] = [float(v) for v in out["F"]]
    out["G"] = [float(v) for v in out.get("G", [])]
    if not all(math.isfinite(v) for v in out["F"] + out["G"]):
        raise ValueError(f"task returned a non-finite objective or constraint: {out}")
    out["wall_time_s"] = float(wall_time_s)
    out["worker"] = f"{socket.gethostname()}:{os.getpid()}"
    return out


@functools.lru_cache(maxsize=64)
def _env_batches(env_id: str, config_json: str) -> bool:
    from train_envs.envs.batch import supports_batch

    return supports_batch(env_id, json.loads(config_json))


# ------------------------------------------------------------------------ tasks
@dataclass(frozen=True)
class EnvTask:
    """Evaluate fixed controller parameters on ``env_id`` over ``seeds``.

    A metric that the env does not report is a :class:`ConfigError` (the same for every
    point: the backends fail fast on it instead of retrying).
    """

    env_id: str
    params: tuple[tuple[str, float], ...]
    seeds: tuple[int, ...]
    config_json: str
    objectives: tuple[str, ...]
    constraints: tuple[tuple[str, float], ...]

    def run(self) -> dict[str, Any]:
        import train_envs  # noqa: F401  (registers the ids in a fresh worker)
        from train_envs.envs.evaluation import evaluate_env_params

        # reuse_env: the worker process (pool worker, Dask worker or the driver itself
        # with the serial backend) keeps the env it built for this (env_id, config) and
        # resets it with each seed, which gives the table a fresh env gives, bit for bit
        df = evaluate_env_params(
            self.env_id,
            dict(self.params),
            seeds=list(self.seeds),
            config=json.loads(self.config_json),
            label="tuner",
            reuse_env=True,
        )
        return self.outcome(df)

    def batch_key(self) -> tuple[Any, ...] | None:
        """What the tasks of one lockstep batch share (all but the parameters), or None
        if the env's controller does not batch (:func:`train_envs.envs.batch.supports_batch`)."""
        if not _env_batches(self.env_id, self.config_json):
            return None
        rest = (self.seeds, self.config_json, self.objectives, self.constraints)
        return (type(self).__qualname__, self.env_id, *rest)

    @classmethod
    def run_batch(cls, tasks: Sequence[EnvTask]) -> list[dict[str, Any]]:
        """Raw outcomes of tasks sharing a :meth:`batch_key`, evaluated in one
        :func:`train_envs.envs.batch.evaluate_env_params_batch` call."""
        import train_envs  # noqa: F401  (registers the ids in a fresh worker)
        from train_envs.envs.batch import evaluate_env_params_batch

        first = tasks[0]
        frames = evaluate_env_params_batch(
            first.env_id,
            [dict(t.params) for t in tasks],
            seeds=list(first.seeds),
            config=json.loads(first.config_json),
        )
        return [t.outcome(df) for t, df in zip(tasks, frames, strict=True)]

    def outcome(self, df: Any) -> dict[str, Any]:
        """``F``, ``G`` and per-seed ``metrics`` of an episode table of this task."""
        cols = list(self.objectives) + [c for c, _ in self.constraints]
        missing = [c for c in cols if c not in df.columns]
        if missing:
            raise ConfigError(
                f"{self.env_id}: metric(s) {missing} not reported; available: {metric_columns(df)}"
            )
        F = [float(df[c].mean()) for c in self.objectives]
        G = [float(df[c].max()) - float(lim) for c, lim in self.constraints]
        metrics = {c: [float(v) for v in df[c]] for c in dict.fromkeys(cols)}
        return {"F": F, "G": G, "metrics": metrics}


@dataclass(frozen=True)
class PymooTask:
    """Evaluate one point of a (picklable) pymoo problem; ``delay_s`` emulates cost."""

    problem: Problem
    x: tuple[float, ...]
    delay_s: float = 0.0

    def run(self) -> dict[str, Any]:
        if self.delay_s > 0:
            time.sleep(self.delay_s)
        out = self.problem.evaluate(np.array([self.x]), return_as_dictionary=True)
        F = np.asarray(out["F"], float).reshape(-1)
        G = out.get("G")
        G = [] if G is None else np.asarray(G, float).reshape(-1).tolist()
        return {"F": F.tolist(), "G": G}


# --------------------------------------------------------------------- problems
class TaskProblem(Problem):
    """A pymoo ``Problem`` whose points are evaluated as independent picklable tasks.

    Subclasses define :meth:`make_task`, :meth:`fingerprint`, :meth:`param_values` and
    :meth:`param_distributions`. ``runner`` (set by :func:`tuners.run.tune`) receives
    whole batches: ``runner.evaluate(problem, X, generation=...)`` → outcomes.
    """

    def __init__(
        self,
        *,
        n_var: int,
        xl: np.ndarray,
        xu: np.ndarray,
        var_names: Sequence[str],
        obj_names: Sequence[str],
        constr_names: Sequence[str] = (),
        constraint_mode: str = "constraint",
        penalty: float = 1e3,
        fail_value: float = FAIL_VALUE,
    ) -> None:
        if constraint_mode not in ("constraint", "penalty"):
            raise ValueError(
                f"constraint_mode must be 'constraint' or 'penalty', got {constraint_mode!r}"
            )
        self.var_names = list(var_names)
        self.obj_names = list(obj_names)
        self.constr_names = list(constr_names)
        self.constraint_mode = constraint_mode
        self.penalty = float(penalty)
        self.fail_value = float(fail_value)
        n_ieq = len(self.constr_names) if constraint_mode == "constraint" else 0
        super().__init__(
            n_var=n_var,
            n_obj=len(self.obj_names),
            n_ieq_constr=n_ieq,
            xl=np.asarray(xl, float),
            xu=np.asarray(xu, float),
            requires_kwargs=True,
        )
        self.runner: Any = None
        self._fp_hash: str | None = None

    # -------------------------------------------------------------- subclass API
    def make_task(self, x: np.ndarray) -> Any:
        raise NotImplementedError

    def fingerprint(self) -> dict[str, Any]:
        """JSON-able identity of the problem (what makes two evaluations comparable)."""
        raise NotImplementedError

    def param_values(self, x: np.ndarray) -> dict[str, float]:
        """Human-facing parameter values of ``x`` (stored as the Optuna params)."""
        return {n: float(v) for n, v in zip(self.var_names, x, strict=True)}

    def param_distributions(self) -> dict[str, tuple[float, float, bool]]:
        """name → (low, high, log) of :meth:`param_values`."""
        return {
            n: (float(lo), float(hi), False)
            for n, lo, hi in zip(self.var_names, self.xl, self.xu, strict=True)
        }

    # ------------------------------------------------------------------ shared
    def fingerprint_hash(self) -> str:
        if self._fp_hash is None:
            blob = json.dumps(self.fingerprint(), sort_keys=True, default=str)
            self._fp_hash = hashlib.sha256(blob.encode()).hexdigest()
        return self._fp_hash

    def key(self, x: np.ndarray) -> str:
        """Cache key: problem fingerprint (env, seeds, objectives, ...) + the exact x."""
        h = hashlib.sha256(self.fingerprint_hash().encode())
        h.update(np.ascontiguousarray(np.asarray(x, dtype=np.float64)).tobytes())
        return h.hexdigest()[:32]

    def failure_outcome(self, error: str) -> dict[str, Any]:
        """Outcome of an evaluation that failed for good: infeasible, worst values."""
        return {
            "F": [self.fail_value] * self.n_obj,
            "G": [self.fail_value] * len(self.constr_names),
            "failed": True,
            "error": error,
        }

    def outcome_arrays(self, outcome: Mapping[str, Any]) -> tuple[np.ndarray, np.ndarray]:
        """(F, G) as pymoo sees them (penalty mode folds G into F)."""
        F = np.asarray(outcome["F"], float)
        G = np.asarray(outcome.get("G", []), float)
        if self.constraint_mode == "penalty":
            if outcome.get("failed"):
                return np.full(self.n_obj, self.fail_value), np.zeros(0)
            F = F + self.penalty * float(np.sum(np.maximum(G, 0.0)))
            return F, np.zeros(0)
        return F, G

    def _evaluate(self, X: np.ndarray, out: dict[str, Any], *args: Any, **kwargs: Any) -> None:
        algorithm = kwargs.get("algorithm")
        generation = getattr(algorithm, "n_iter", None)
        if self.runner is not None:
            outcomes = self.runner.evaluate(self, X, generation=generation)
        else:
            outcomes = [run_task(self.make_task(x)) for x in X]
        FG = [self.outcome_arrays(o) for o in outcomes]
        out["F"] = np.array([f for f, _ in FG], dtype=float)
        if self.n_ieq_constr:
            out["G"] = np.array([g for _, g in FG], dtype=float)

    def __getstate__(self) -> dict[str, Any]:
        state = dict(super().__getstate__())
        state["runner"] = None  # backends, stores and caches stay in the driver
        return state


class EnvTuningProblem(TaskProblem):
    """Tune the inner controller of a registered env id over closed-loop episodes.

    Args:
        env_id: a registered id (``"TrainEnvs/Urban004FuzzyPID-v0"``; a ``module:`` prefix
            works as with ``gymnasium.make``).
        objectives: aliases (``itae``, ``stop``, ``time``, ``comfort``, ``energy``) or
            metric columns; default: 004's five, minus those the scenario cannot report.
        seeds: scenario seeds; each objective is the mean over them.
        config: env config merged over the id's (e.g. disturbances).
        params: names of the tunable parameters to search (default: all exposed).
        fixed_params: values of non-searched parameters (default: controller defaults).
        space: ``"unit"`` (x ∈ [−1, 1]ⁿ, the env's action scale) or ``"native"``.
        constraints: metric column → upper limit (default ``max_overspeed_mps ≤ 0``).
        constraint_mode: ``"constraint"`` (pymoo inequality constraints) or ``"penalty"``.
        penalty: penalty factor of ``"penalty"`` mode.
        fail_value: objective/constraint value of an evaluation that failed for good.
    """

    def __init__(
        self,
        env_id: str,
        *,
        objectives: Sequence[str] | None = None,
        seeds: Sequence[int] = (0,),
        config: Mapping[str, Any] | None = None,
        params: Sequence[str] | None = None,
        fixed_params: Mapping[str, float] | None = None,
        space: str = "unit",
        constraints: Mapping[str, float] | None = None,
        constraint_mode: str = "constraint",
        penalty: float = 1e3,
        fail_value: float = FAIL_VALUE,
    ) -> None:
        import gymnasium as gym

        import train_envs  # noqa: F401  (registers the ids)

        if space not in SPACES:
            raise ValueError(f"space must be 'unit' or 'native', got {space!r}")
        self.env_id = env_id
        self.config = json.loads(json.dumps(dict(config or {})))  # JSON-able copy
        self.seeds = tuple(int(s) for s in seeds)
        if not self.seeds:
            raise ValueError("need at least one scenario seed")
        self.space = space
        env = gym.make(env_id, config=dict(self.config))
        try:
            base = env.unwrapped
            if base.config["action_mode"] != "absolute":
                raise ValueError("tuning needs the env's action_mode='absolute'")
            specs = {p.name: p for p in base.param_specs}
            self.defaults = dict(base.default_params())
            scenario = base.scenario
        finally:
            env.close()
        names = list(specs) if params is None else list(params)
        unknown = [n for n in names if n not in specs]
        if unknown or not names:
            raise ValueError(f"params {unknown or names} not tunable here; allowed: {list(specs)}")
        self.param_space = ParamSpace.of(specs.values(), names)
        self.specs = self.param_space.specs
        self.fixed_params = {k: float(v) for k, v in (fixed_params or {}).items()}
        bad = [k for k in self.fixed_params if k not in specs or k in names]
        if bad:
            raise ValueError(f"fixed_params {bad} must be exposed and not searched")
        if objectives is None:
            objectives = [
                o
                for o in DEFAULT_OBJECTIVES
                if not (o == "time" and scenario.scheduled_time_s is None)
                and not (o == "stop" and scenario.s_stop_m is None)
            ]
        cols = [objective_column(o) for o in objectives]
        if len(set(cols)) != len(cols) or not cols:
            raise ValueError(f"objectives must be distinct and non-empty, got {objectives}")
        self.objective_columns = tuple(cols)
        cons = DEFAULT_CONSTRAINTS if constraints is None else constraints
        self.constraints = tuple((str(k), float(v)) for k, v in cons.items())
        xl, xu = self.param_space.bounds(space)
        super().__init__(
            n_var=len(names),
            xl=xl,
            xu=xu,
            var_names=names,
            obj_names=cols,
            constr_names=[c for c, _ in self.constraints],
            constraint_mode=constraint_mode,
            penalty=penalty,
            fail_value=fail_value,
        )

    # -------------------------------------------------------------- mapping
    def x_to_params(self, x: np.ndarray) -> dict[str, float]:
        """Controller parameter values of a point (searched ones only)."""
        return self.param_space.from_x(x, self.space)

    def params_to_x(self, params: Mapping[str, float]) -> np.ndarray:
        """Inverse of :meth:`x_to_params` (missing names: the controller defaults)."""
        return self.param_space.to_x(params, self.space, self.defaults)

    def task_params(self, x: np.ndarray) -> dict[str, float]:
        """Every parameter value an evaluation of ``x`` runs with: fixed and searched."""
        return {**self.fixed_params, **self.x_to_params(x)}

    def default_x(self) -> np.ndarray:
        """The point of the controller's default parameters."""
        return self.params_to_x(self.defaults)

    def param_values(self, x: np.ndarray) -> dict[str, float]:
        return self.x_to_params(x)

    def param_distributions(self) -> dict[str, tuple[float, float, bool]]:
        return {p.name: (float(p.low), float(p.high), bool(p.log)) for p in self.specs}

    # ---------------------------------------------------------------- tasks
    def make_task(self, x: np.ndarray) -> EnvTask:
        params = self.task_params(x)
        return EnvTask(
            env_id=self.env_id,
            params=tuple(sorted(params.items())),
            seeds=self.seeds,
            config_json=json.dumps(self.config, sort_keys=True),
            objectives=self.objective_columns,
            constraints=self.constraints,
        )

    def fingerprint(self) -> dict[str, Any]:
        return {
            "kind": "env",
            "env_id": self.env_id,
            "config": self.config,
            "seeds": list(self.seeds),
            "space": self.space,
            "params": [(p.name, p.low, p.high, p.log) for p in self.specs],
            "fixed_params": self.fixed_params,
            "objectives": list(self.objective_columns),
            "constraints": [list(c) for c in self.constraints],
            "constraint_mode": self.constraint_mode,
            "penalty": self.penalty,
        }

    def check_metrics(self) -> None:
        """``ValueError`` naming the objectives/constraints the env does not report.

        Runs one env step of the defaults (the columns of the metrics table do not depend
        on the episode's length), so a misspelt name fails before any work starts.
        """
        from train_envs.envs.evaluation import evaluate_env_params

        df = evaluate_env_params(
            self.env_id,
            self.task_params(self.default_x()),
            seeds=[self.seeds[0]],
            config={**self.config, "max_episode_steps": 1},
            label="check",
        )
        available = metric_columns(df)
        for kind, names in (
            ("objectives", self.objective_columns),
            ("constraints", [c for c, _ in self.constraints]),
        ):
            bad = [n for n in names if n not in available]
            if bad:
                raise ValueError(
                    f"{kind} {bad} are not metrics of {self.env_id}; aliases "
                    f"{sorted(OBJECTIVE_ALIASES)}, metrics {available}"
                )

    def with_seeds(self, seeds: Sequence[int]) -> EnvTuningProblem:
        """The same problem on other scenario seeds (e.g. held-out ones)."""
        return EnvTuningProblem(
            self.env_id,
            objectives=list(self.objective_columns),
            seeds=seeds,
            config=self.config,
            params=[p.name for p in self.specs],
            fixed_params=self.fixed_params,
            space=self.space,
            constraints=dict(self.constraints),
            constraint_mode=self.constraint_mode,
            penalty=self.penalty,
            fail_value=self.fail_value,
        )


class PymooTaskProblem(TaskProblem):
    """Any picklable pymoo problem as a task problem (ZDT1, a sphere, ...).

    ``delay_s`` sleeps in every evaluation to emulate an expensive simulation.
    """

    def __init__(self, problem: Problem, *, delay_s: float = 0.0, name: str | None = None):
        self.inner = problem
        self.delay_s = float(delay_s)
        self.name_ = name or type(problem).__name__
        xl, xu = problem.bounds()
        super().__init__(
            n_var=problem.n_var,
            xl=xl,
            xu=xu,
            var_names=[f"x{i}" for i in range(problem.n_var)],
            obj_names=[f"f{i + 1}" for i in range(problem.n_obj)],
            constr_names=[f"g{i + 1}" for i in range(problem.n_ieq_constr)],
        )

    def make_task(self, x: np.ndarray) -> PymooTask:
        return PymooTask(self.inner, tuple(float(v) for v in x), self.delay_s)

    def fingerprint(self) -> dict[str, Any]:
        return {
            "kind": "pymoo",
            "name": self.name_,
            "n_var": self.n_var,
            "n_obj": self.n_obj,
            "xl": self.xl.tolist(),
            "xu": self.xu.tolist(),
        }

    def _calc_pareto_front(self, *args: Any, **kwargs: Any) -> Any:
        return self.inner.pareto_front(*args, **kwargs)
