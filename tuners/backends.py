"""Evaluation backends (serial, processes, lockstep, Dask) and the batch evaluator.

One setting picks where the closed-loop episodes run:

* ``"serial"`` — in the driver process, one after the other;
* ``"processes"`` — a :class:`~concurrent.futures.ProcessPoolExecutor` with the
  *spawn* start method (safe with threads, BLAS and the notebook), ``workers`` processes
  (default: all cores) with one BLAS/OpenMP thread each; the pool lives for the whole
  run;
* ``"lockstep"`` — the same pool, each worker evaluating one chunk of the batch in one
  :func:`train_envs.envs.batch.evaluate_env_params_batch` call (:class:`LockstepBackend`);
  :func:`tuners.run.tune`'s default where the env's controller batches;
* ``"dask"`` — a Dask distributed cluster: ``address`` of a running scheduler
  (``tcp://host:8786``; the workers need this package installed), an existing
  ``client``, or, with neither, a :class:`distributed.LocalCluster` of ``workers``
  single-threaded processes. Tasks go out with ``client.submit``.

Failure accounting — an evaluation fails only by its own error:

* a task that raises is recorded (``on_error``) and re-submitted, up to ``max_retries``
  times; a task that fails ``max_retries + 1`` times is returned as :class:`Failure`
  (the problem turns it into an infeasible worst-value outcome);
* a :class:`~tuners.problem.ConfigError` (or an ``ImportError``) is the same for every
  point: it is not retried, the batch stops and the error is raised at once;
* a worker process that dies breaks the pool (``BrokenProcessPool``), which cannot tell
  which task killed it: the pool restarts and every task in flight is re-submitted
  without being charged. A task in flight at two breaks is then run alone; a break
  while it is alone is its own failure (an attempt). So deaths from outside (``kill``,
  the OOM killer hitting a neighbour) never make an evaluation fail;
* workers ignore SIGINT (Ctrl-C stops the driver, which stops the pool) and exit
  within a second when the driver dies (a daemon thread watches ``os.getppid()``);
* on Dask a lost worker's tasks are rescheduled by the scheduler itself (up to
  ``distributed.scheduler.allowed-failures``, then they fail like an exception here).

:class:`Evaluations` is what a :class:`tuners.problem.TaskProblem` calls per batch: it
answers points already evaluated (same problem fingerprint and bit-identical x) from
its cache — loaded from the study when resuming — runs the rest on the backend, and
writes every finished evaluation to the store as soon as it finishes (a journal study
makes the batch's writes durable with one ``fsync`` at its end). If every
evaluation fails before any has ever succeeded (a misconfiguration: unknown metric,
unimportable env, a script without the ``if __name__ == "__main__":`` guard that the
spawn start method needs), it raises instead of filling the study with failures.
"""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing as mp
import os
import signal
import threading
import time
import traceback
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tuners.problem import ConfigError, TaskProblem, finish_outcome, run_task

OnResult = Callable[[int, dict[str, Any]], None]
OnError = Callable[[int, int, str, bool], None]

__all__ = [
    "BACKENDS",
    "Backend",
    "DaskBackend",
    "Evaluations",
    "Failure",
    "LockstepBackend",
    "PointError",
    "ProcessBackend",
    "SerialBackend",
    "default_backend",
    "make_backend",
    "run_chunk",
]


@dataclass(frozen=True)
class Failure:
    """A task that failed on every attempt."""

    error: str
    attempts: int


#: task errors that are the same for every point: no retry, the run stops
FATAL_ERRORS: tuple[type[BaseException], ...] = (ConfigError, ImportError)


def _describe(exc: BaseException) -> str:
    tb = "".join(traceback.format_exception_only(type(exc), exc)).strip()
    return tb[-2000:]


class Backend(ABC):
    """Runs a batch of tasks; streams results and errors to callbacks, retries failures."""

    name = "backend"

    def __init__(self, max_retries: int = 2) -> None:
        if max_retries < 0:
            raise ValueError(f"max_retries must be >= 0, got {max_retries}")
        self.max_retries = int(max_retries)

    @property
    def workers(self) -> int:
        return 1

    @abstractmethod
    def run(
        self,
        tasks: Sequence[Any],
        on_result: OnResult | None = None,
        on_error: OnError | None = None,
    ) -> list[dict[str, Any] | Failure]:
        """Run ``tasks``; ``on_result(i, outcome)`` as each finishes, ``on_error(i, attempt,
        error, final)`` for every failed attempt. Returns outcomes in task order."""

    def start(self) -> None:  # noqa: B027 - optional hook, no workers by default
        """Start the workers now, so that their imports overlap what the driver does
        before the first batch (by default nothing: no workers)."""

    def close(self) -> None:  # noqa: B027 - optional hook, nothing to release by default
        """Release workers (idempotent)."""

    def terminate(self) -> None:
        """Stop at once (Ctrl-C); by default the same as :meth:`close`."""
        self.close()

    def __enter__(self) -> Backend:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _failed(self, i: int, attempts: list[int], err: str, on_error: OnError | None) -> bool:
        """Count a failed attempt of task ``i``; True if it should be re-submitted."""
        attempts[i] += 1
        final = attempts[i] > self.max_retries
        if on_error is not None:
            on_error(i, attempts[i], err, final)
        return not final


class SerialBackend(Backend):
    """Evaluate in the calling process (a crash of the process ends the run)."""

    name = "serial"

    def run(self, tasks, on_result=None, on_error=None):
        results: list[dict[str, Any] | Failure] = []
        attempts = [0] * len(tasks)
        for i, task in enumerate(tasks):
            while True:
                try:
                    out = run_task(task)
                except FATAL_ERRORS:
                    raise
                except Exception as exc:  # noqa: BLE001 - any task error is retried
                    err = _describe(exc)
                    if self._failed(i, attempts, err, on_error):
                        continue
                    results.append(Failure(err, attempts[i]))
                    break
                if on_result is not None:
                    on_result(i, out)
                results.append(out)
                break
        return results


_THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS")


def _watch_parent(parent: int, interval_s: float = 0.5) -> None:
    """Exit this worker when its parent process is gone (re-parented to another pid)."""
    while True:
        time.sleep(interval_s)
        if os.getppid() != parent:
            os._exit(0)


def _init_worker(threads: int | None, parent: int) -> None:
    """Worker initializer: ignore SIGINT, exit with the driver, cap BLAS/OpenMP threads.

    Ctrl-C reaches the whole process group; the driver handles it and stops the pool,
    so the workers ignore it (no traceback per worker). A daemon thread ends the worker
    when the driver dies (``kill -9`` included): ``os.getppid()`` changes to the
    re-parenting process. ``threads``: see :func:`_limit_worker_threads`.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if os.getppid() != parent:  # the driver died while this worker started
        os._exit(0)
    threading.Thread(target=_watch_parent, args=(parent,), daemon=True).start()
    if threads:
        _limit_worker_threads(threads)


def _limit_worker_threads(threads: int) -> None:
    """Cap BLAS/OpenMP threads (processes x threads <= cores).

    Without it every worker's OpenBLAS starts one thread per core and ``workers``
    processes oversubscribe the machine (on 2 cores the pool was no faster than serial).
    Uses threadpoolctl for libraries already loaded, environment variables for later ones.
    """
    for var in _THREAD_VARS:
        os.environ[var] = str(threads)
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - optional
        return
    threadpool_limits(threads)


class ProcessBackend(Backend):
    """A spawn-context ProcessPoolExecutor, restarted if a worker dies.

    Args:
        workers: processes (default: all cores).
        max_retries: re-submissions of a failing task.
        start_method: multiprocessing start method (``"spawn"``: safe with threads).
        threads_per_worker: BLAS/OpenMP threads in each worker (default 1).
    """

    name = "processes"

    def __init__(
        self,
        workers: int | None = None,
        max_retries: int = 2,
        start_method: str = "spawn",
        threads_per_worker: int | None = 1,
    ) -> None:
        super().__init__(max_retries)
        self._workers = int(workers or os.cpu_count() or 1)
        if self._workers < 1:
            raise ValueError(f"workers must be >= 1, got {workers}")
        self.start_method = start_method
        self.threads_per_worker = threads_per_worker
        self._pool: cf.ProcessPoolExecutor | None = None
        self.restarts = 0

    @property
    def workers(self) -> int:
        return self._workers

    def _get_pool(self) -> cf.ProcessPoolExecutor:
        if self._pool is None:
            self._pool = cf.ProcessPoolExecutor(
                max_workers=self._workers,
                mp_context=mp.get_context(self.start_method),
                initializer=_init_worker,
                initargs=(self.threads_per_worker, os.getpid()),
            )
        return self._pool

    def start(self) -> None:
        pool = self._get_pool()
        # a task while no worker is idle starts one: one no-op per worker starts them all
        # (each imports the library as it unpickles its initializer)
        for _ in range(self._workers):
            pool.submit(os.getpid)

    def _restart(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
        self._pool = None
        self.restarts += 1

    def _groups(self, tasks: Sequence[Any], batch: list[int]) -> list[list[int]]:
        """The task indices of ``batch`` submitted together: here one task each."""
        return [[i] for i in batch]

    def run(self, tasks, on_result=None, on_error=None):
        results: list[Any] = [None] * len(tasks)
        attempts = [0] * len(tasks)
        breaks = [0] * len(tasks)  # pool breaks a task was in flight at (not charged)
        todo = list(range(len(tasks)))
        while todo:
            suspects = [i for i in todo if breaks[i] >= 2]
            batch = suspects[:1] if suspects else todo  # a suspect runs alone
            pool = self._get_pool()
            futures: dict[cf.Future, list[int]] = {}
            try:
                for group in self._groups(tasks, batch):
                    if len(group) == 1:
                        fut = pool.submit(run_task, tasks[group[0]])
                    else:
                        fut = pool.submit(run_chunk, [tasks[i] for i in group])
                    futures[fut] = group
                broken = False
            except BrokenProcessPool:
                broken = True  # submitted ones fail below; the rest stay in ``todo``
            retry: list[int] = []
            died: list[int] = []
            pending = set(futures)

            def failed(i: int, err: str, retry: list[int] = retry) -> None:
                if self._failed(i, attempts, err, on_error):
                    retry.append(i)
                else:
                    results[i] = Failure(err, attempts[i])

            try:
                while pending:
                    done, pending = cf.wait(pending, return_when=cf.FIRST_COMPLETED)
                    for fut in sorted(done, key=lambda f: futures[f][0]):
                        group = futures[fut]
                        exc = fut.exception()
                        if exc is None:
                            out = fut.result()
                            items = out if len(group) > 1 else [out]
                            for i, item in zip(group, items, strict=True):
                                if isinstance(item, PointError):
                                    failed(i, item.error)
                                    continue
                                results[i] = item
                                if on_result is not None:
                                    on_result(i, item)
                        elif isinstance(exc, BrokenProcessPool):
                            broken = True
                            died.extend(group)
                        elif isinstance(exc, FATAL_ERRORS):
                            raise exc
                        else:  # a single task's own error (a chunk reports its members')
                            for i in group:
                                failed(i, _describe(exc))
            except BaseException:
                self.terminate()
                raise
            if suspects and died:  # a suspect alone in the pool: its own failure
                (i,) = died
                failed(i, "worker process died while running this evaluation alone")
            else:
                for i in died:
                    breaks[i] += 1
                    retry.append(i)
            submitted = {i for group in futures.values() for i in group}
            todo = sorted(retry + [i for i in todo if i not in submitted])
            if broken:
                self._restart()
        return results

    def terminate(self) -> None:
        """Stop the workers now (Ctrl-C, a fatal error): running tasks are abandoned."""
        if self._pool is None:
            return
        procs = list((getattr(self._pool, "_processes", None) or {}).values())
        self._pool.shutdown(wait=False, cancel_futures=True)
        for proc in procs:
            if proc.is_alive():
                proc.terminate()
        for proc in procs:
            proc.join(timeout=5)
        self._pool = None

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None


@dataclass(frozen=True)
class PointError:
    """A member of a chunk that raised (its chunk-mates' outcomes stand)."""

    error: str


def run_chunk(tasks: Sequence[Any]) -> list[dict[str, Any] | PointError]:
    """Evaluate tasks sharing a ``batch_key`` in one ``run_batch`` call (in a worker).

    Returns one item per task: its outcome (as :func:`~tuners.problem.run_task` gives
    it; the wall time is the chunk's divided evenly) or a :class:`PointError`. If the
    batch call raises, each task runs alone, so only the tasks that fail by themselves
    fail. A fatal error (:data:`FATAL_ERRORS`) is raised.
    """
    t0 = time.perf_counter()
    try:
        raw = type(tasks[0]).run_batch(tasks)
    except FATAL_ERRORS:
        raise
    except Exception:  # noqa: BLE001 - which member failed is found by running each alone
        raw = None
    out: list[dict[str, Any] | PointError] = []
    if raw is None:
        for task in tasks:
            try:
                out.append(run_task(task))
            except FATAL_ERRORS:
                raise
            except Exception as exc:  # noqa: BLE001 - the member's own error
                out.append(PointError(_describe(exc)))
        return out
    share = (time.perf_counter() - t0) / len(tasks)
    for item in raw:
        try:
            out.append(finish_outcome(item, share))
        except Exception as exc:  # noqa: BLE001 - a non-finite value of this member
            out.append(PointError(_describe(exc)))
    return out


class LockstepBackend(ProcessBackend):
    """The process pool, each worker evaluating its share of a batch in one call.

    Tasks with the same ``batch_key()`` (env tasks of an env with a lockstep evaluation:
    :func:`train_envs.envs.batch.supports_batch`) are split into one contiguous chunk
    per worker, run by :func:`run_chunk`; other tasks (``batch_key`` None or absent,
    such as pymoo problems) are submitted one by one as with ``"processes"``. Failure
    accounting is the pool's: a member that raises is charged alone and retried in a
    later chunk; a worker death re-submits, uncharged, the members of every chunk in
    flight (finished chunks keep their outcomes); a member in flight at two deaths runs
    alone.
    """

    name = "lockstep"

    def _groups(self, tasks: Sequence[Any], batch: list[int]) -> list[list[int]]:
        keyed: dict[Any, list[int]] = {}
        groups: list[list[int]] = []
        for i in batch:
            key_fn = getattr(tasks[i], "batch_key", None)
            key = key_fn() if key_fn is not None else None
            if key is None:
                groups.append([i])
            else:
                keyed.setdefault(key, []).append(i)
        for members in keyed.values():
            n = min(self.workers, len(members))
            groups.extend(
                [int(i) for i in chunk] for chunk in np.array_split(np.asarray(members), n)
            )
        return sorted(groups)


class DaskBackend(Backend):
    """Dask distributed: ``client.submit`` per task, re-submission on errors.

    Args:
        address: scheduler address; ``None`` with no ``client`` starts a LocalCluster.
        client: an existing ``distributed.Client`` (not closed by :meth:`close`).
        workers: LocalCluster size (default: all cores).
        processes: LocalCluster with worker processes (True) or threads (False).
        max_retries: re-submissions of a task that raised.
    """

    name = "dask"

    def __init__(
        self,
        address: str | None = None,
        client: Any = None,
        workers: int | None = None,
        processes: bool = True,
        max_retries: int = 2,
    ) -> None:
        super().__init__(max_retries)
        from distributed import Client, LocalCluster

        self._own_client = client is None
        self._cluster = None
        if client is None:
            if address is None:
                self._cluster = LocalCluster(
                    n_workers=int(workers or os.cpu_count() or 1),
                    threads_per_worker=1,
                    processes=processes,
                    dashboard_address=None,
                )
                client = Client(self._cluster)
            else:
                client = Client(address)
        self.client = client

    @property
    def workers(self) -> int:
        try:
            info = self.client.scheduler_info()
            return max(1, sum(w.get("nthreads", 1) for w in info["workers"].values()))
        except Exception:  # noqa: BLE001 - informative only
            return 1

    def run(self, tasks, on_result=None, on_error=None):
        from distributed import as_completed

        results: list[Any] = [None] * len(tasks)
        attempts = [0] * len(tasks)
        index: dict[Any, int] = {}
        futs = []
        for i, task in enumerate(tasks):
            f = self.client.submit(run_task, task, pure=False)
            index[f.key] = i
            futs.append(f)
        ac = as_completed(futs)
        for fut in ac:
            i = index.pop(fut.key)
            try:
                out = fut.result()
            except FATAL_ERRORS:
                for f in futs:
                    f.cancel()
                raise
            except Exception as exc:  # noqa: BLE001 - incl. KilledWorker
                err = _describe(exc)
                if self._failed(i, attempts, err, on_error):
                    f = self.client.submit(run_task, tasks[i], pure=False)
                    index[f.key] = i
                    ac.add(f)
                else:
                    results[i] = Failure(err, attempts[i])
                continue
            results[i] = out
            if on_result is not None:
                on_result(i, out)
        return results

    def close(self) -> None:
        if self._own_client and self.client is not None:
            self.client.close()
            if self._cluster is not None:
                self._cluster.close()
            self.client = None
            self._cluster = None


BACKENDS = ("serial", "processes", "lockstep", "dask")


def make_backend(
    kind: str = "processes",
    workers: int | None = None,
    *,
    address: str | None = None,
    client: Any = None,
    max_retries: int = 2,
) -> Backend:
    """The backend for a setting: ``"serial"``, ``"processes"``, ``"lockstep"`` or ``"dask"``."""
    if kind == "serial":
        return SerialBackend(max_retries=max_retries)
    if kind == "processes":
        return ProcessBackend(workers=workers, max_retries=max_retries)
    if kind == "lockstep":
        return LockstepBackend(workers=workers, max_retries=max_retries)
    if kind == "dask":
        return DaskBackend(address=address, client=client, workers=workers, max_retries=max_retries)
    raise ValueError(f"backend must be one of {BACKENDS}, got {kind!r}")


def default_backend(problem: TaskProblem) -> str:
    """``"lockstep"`` for an env problem whose controller has an array law
    (:func:`train_envs.envs.batch.supports_batch` with ``array_law``: PID, Fuzzy-PID,
    DMC), else ``"processes"`` (the other envs, whose members would run one by one in
    lockstep at the same cost; pymoo problems)."""
    env_id = getattr(problem, "env_id", None)
    if isinstance(env_id, str) and hasattr(problem, "config"):
        from train_envs.envs.batch import supports_batch

        if supports_batch(env_id, problem.config, array_law=True):
            return "lockstep"
    return "processes"


@dataclass
class EvalStats:
    """Counters of an :class:`Evaluations` (for progress bars and benchmarks)."""

    requested: int = 0
    cached: int = 0
    run: int = 0
    failed_attempts: int = 0
    failed_final: int = 0
    worker_deaths: int = 0  # pool breaks (in-flight tasks re-submitted, not charged)
    task_time_s: float = 0.0
    batch_time_s: float = 0.0
    store_time_s: float = 0.0
    checkpoint_time_s: float = 0.0
    errors: list[str] = field(default_factory=list)


class Evaluations:
    """Batch evaluator plugged into a :class:`TaskProblem` as its ``runner``.

    Args:
        backend: where tasks run.
        store: a :class:`tuners.storage.StudyStore` (or ``None``: nothing persisted).
        cache: key → outcome of finished evaluations (from the store when resuming).
        on_evaluation: called after each new finished evaluation is recorded, with
            ``(key, outcome, generation)``.
    """

    def __init__(
        self,
        backend: Backend,
        store: Any = None,
        cache: dict[str, dict[str, Any]] | None = None,
        on_evaluation: Callable[[str, dict[str, Any], int | None], None] | None = None,
    ) -> None:
        self.backend = backend
        self.store = store
        self.cache: dict[str, dict[str, Any]] = dict(cache or {})
        self.on_evaluation = on_evaluation
        self.stats = EvalStats()

    def evaluate(
        self, problem: TaskProblem, X: np.ndarray, generation: int | None = None
    ) -> list[dict[str, Any]]:
        t0 = time.perf_counter()
        X = np.asarray(X, dtype=np.float64)
        keys = [problem.key(x) for x in X]
        self.stats.requested += len(keys)
        first: dict[str, int] = {}
        for i, k in enumerate(keys):
            if k not in self.cache and k not in first:
                first[k] = i
        self.stats.cached += len(keys) - len(first)
        todo = list(first.values())
        tasks = [problem.make_task(X[i]) for i in todo]

        def record(j: int, outcome: dict[str, Any]) -> None:
            i = todo[j]
            self.cache[keys[i]] = outcome
            if self.store is not None:
                ts = time.perf_counter()
                self.store.record(problem, keys[i], X[i], outcome, generation, i)
                self.stats.store_time_s += time.perf_counter() - ts
            if self.on_evaluation is not None:
                self.on_evaluation(keys[i], outcome, generation)

        def on_result(j: int, outcome: dict[str, Any]) -> None:
            self.stats.run += 1
            self.stats.task_time_s += float(outcome.get("wall_time_s", 0.0))
            record(j, outcome)

        def on_error(j: int, attempt: int, error: str, final: bool) -> None:
            i = todo[j]
            self.stats.failed_attempts += 1
            self.stats.errors.append(error)
            if self.store is not None and not final:  # a final failure is record()ed
                self.store.record_failure(problem, keys[i], X[i], error, attempt, generation, i)

        if self.store is not None:
            self.store.hold()  # a journal study: the batch's writes go out in one append
        try:
            self._run(problem, tasks, on_result, on_error, record)
        finally:
            if self.store is not None:  # also on Ctrl-C: keep what finished
                ts = time.perf_counter()
                self.store.flush()
                self.stats.store_time_s += time.perf_counter() - ts
        self.stats.batch_time_s += time.perf_counter() - t0
        return [self.cache[k] for k in keys]

    def _run(
        self,
        problem: TaskProblem,
        tasks: list[Any],
        on_result: OnResult,
        on_error: OnError,
        record: Callable[[int, dict[str, Any]], None],
    ) -> None:
        """Run ``tasks`` on the backend; record the ones that failed for good."""
        restarts = getattr(self.backend, "restarts", 0)
        results = self.backend.run(tasks, on_result=on_result, on_error=on_error)
        deaths = getattr(self.backend, "restarts", 0) - restarts
        if deaths:
            self.stats.worker_deaths += deaths
            self.stats.errors.append(f"worker process died {deaths} time(s); pool restarted")
        failures = [r for r in results if isinstance(r, Failure)]
        if failures and len(failures) == len(results) and self.stats.run == 0:
            hint = ""
            if "process died" in failures[0].error or "BrokenProcessPool" in failures[0].error:
                hint = (
                    " (worker processes die: with the spawn start method the calling script "
                    "needs an `if __name__ == '__main__':` guard)"
                )
            raise RuntimeError(
                f"every evaluation of the first batch failed{hint}; first error: "
                f"{failures[0].error}"
            )
        for j, res in enumerate(results):
            if isinstance(res, Failure):
                self.stats.failed_final += 1
                outcome = problem.failure_outcome(res.error)
                outcome["attempts"] = res.attempts
                record(j, outcome)
