"""Optuna's samplers as generation-synchronous pymoo algorithms (``--algo optuna-tpe`` ...).

:class:`OptunaSampler` drives one Optuna sampler by ask-and-tell inside a private
in-memory study: each generation asks ``pop`` trials (one parallel batch), the batch is
evaluated by the tuner's backend like any other algorithm's, and the objective vector
and constraint values are told back. The search space is the problem's own (one
``FloatDistribution`` per variable over ``[xl, xu]``), the defaults (``initial_X``) are
enqueued as the first trials, and feasibility reaches the sampler through
``Trial.set_constraint`` (g ≤ 0 feasible, Optuna's convention and ours).

Because everything goes through :func:`tuners.run.tune`, the samplers share the study
storage (every evaluation one trial of the tuner's study), the checkpoint and exact
resume by replay (:mod:`tuners.checkpoint`: a seeded Optuna sampler asks the same
points given the same told values, so rebuilding the private study from the stored
evaluations reproduces it), and the failure accounting (a failed evaluation is told
its worst-value outcome). The private study is rebuilt on every run; nothing of it is
stored.

================  ======================================================================
``--algo``        sampler
================  ======================================================================
``optuna-tpe``    :class:`optuna.samplers.TPESampler` (multivariate, constant liar)
``optuna-nsga2``  :class:`optuna.samplers.NSGAIISampler` (population = ``pop``)
``optuna-nsga3``  :class:`optuna.samplers.NSGAIIISampler` (population = ``pop``)
``optuna-gp``     :class:`optuna.samplers.GPSampler` (needs torch)
================  ======================================================================
"""

from __future__ import annotations

import importlib.util
import warnings
from collections.abc import Callable
from typing import Any

import numpy as np
import optuna
from optuna.distributions import FloatDistribution
from pymoo.core.algorithm import Algorithm
from pymoo.core.population import Population
from pymoo.util.display.multi import MultiObjectiveOutput
from pymoo.util.display.single import SingleObjectiveOutput
from pymoo.util.optimum import filter_optimum

__all__ = ["OPTUNA_ALGORITHMS", "OptunaSampler", "make_sampler"]


def _tpe(seed: int, pop: int, **kw: Any) -> optuna.samplers.BaseSampler:
    kw.setdefault("multivariate", True)
    kw.setdefault("constant_liar", True)  # a batch of pop asks spreads out
    return optuna.samplers.TPESampler(seed=seed, **kw)


def _nsga2(seed: int, pop: int, **kw: Any) -> optuna.samplers.BaseSampler:
    return optuna.samplers.NSGAIISampler(seed=seed, population_size=pop, **kw)


def _nsga3(seed: int, pop: int, **kw: Any) -> optuna.samplers.BaseSampler:
    return optuna.samplers.NSGAIIISampler(seed=seed, population_size=pop, **kw)


def _gp(seed: int, pop: int, **kw: Any) -> optuna.samplers.BaseSampler:
    return optuna.samplers.GPSampler(seed=seed, **kw)


_FACTORIES: dict[str, Callable[..., optuna.samplers.BaseSampler]] = {
    "optuna-tpe": _tpe,
    "optuna-nsga2": _nsga2,
    "optuna-nsga3": _nsga3,
    "optuna-gp": _gp,
}

#: the ``--algo`` names of the Optuna samplers
OPTUNA_ALGORITHMS: tuple[str, ...] = tuple(_FACTORIES)


def make_sampler(name: str, seed: int, pop: int, **kwargs: Any) -> optuna.samplers.BaseSampler:
    """The seeded Optuna sampler ``name`` (one of :data:`OPTUNA_ALGORITHMS`)."""
    if name not in _FACTORIES:
        raise ValueError(f"Optuna sampler must be one of {OPTUNA_ALGORITHMS}, got {name!r}")
    if name == "optuna-gp" and importlib.util.find_spec("torch") is None:
        raise ValueError("algo 'optuna-gp' needs torch (Optuna's GPSampler); install torch")
    with warnings.catch_warnings():  # GPSampler and constant_liar are "experimental"
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        return _FACTORIES[name](int(seed), int(pop), **kwargs)


class OptunaSampler(Algorithm):
    """A pymoo algorithm asking an Optuna sampler for ``pop_size`` points per generation.

    Args:
        sampler: name in :data:`OPTUNA_ALGORITHMS`.
        pop_size: points per generation (one evaluation batch).
        initial_X: rows enqueued as the first trials (e.g. the defaults).
        **sampler_kwargs: passed to the sampler's constructor.

    ``pop`` is the last batch; ``opt`` the feasible non-dominated points of all batches.
    """

    def __init__(
        self,
        sampler: str,
        pop_size: int = 40,
        initial_X: np.ndarray | None = None,
        output: Any = None,
        **sampler_kwargs: Any,
    ) -> None:
        super().__init__(output=output)
        if sampler not in _FACTORIES:
            raise ValueError(f"sampler must be one of {OPTUNA_ALGORITHMS}, got {sampler!r}")
        self.sampler_name = sampler
        self.pop_size = int(pop_size)
        self.initial_X = None if initial_X is None else np.atleast_2d(np.asarray(initial_X, float))
        self.sampler_kwargs = dict(sampler_kwargs)
        self.study: optuna.Study | None = None
        self._evaluated: Population = Population.empty()
        self._trials: list[optuna.Trial] = []

    def _setup(self, problem: Any, **kwargs: Any) -> None:
        if self.output is None:
            self.output = MultiObjectiveOutput() if problem.n_obj > 1 else SingleObjectiveOutput()
        seed = 0 if self.seed is None else int(self.seed)
        sampler = make_sampler(self.sampler_name, seed, self.pop_size, **self.sampler_kwargs)
        self.study = optuna.create_study(directions=["minimize"] * problem.n_obj, sampler=sampler)
        xl, xu = problem.bounds()
        self._names = [f"x{i}" for i in range(problem.n_var)]
        self._dists = {
            n: FloatDistribution(float(lo), float(hi))
            for n, lo, hi in zip(self._names, xl, xu, strict=True)
        }
        for x in [] if self.initial_X is None else np.clip(self.initial_X, xl, xu):
            self.study.enqueue_trial(dict(zip(self._names, map(float, x), strict=True)))

    def _ask(self) -> Population:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
            self._trials = [self.study.ask(self._dists) for _ in range(self.pop_size)]
        X = np.array([[t.params[n] for n in self._names] for t in self._trials], float)
        return Population.new("X", X)

    def _tell(self, infills: Population) -> None:
        F = np.asarray(infills.get("F"), float)
        G = infills.get("G") if self.problem.n_ieq_constr else None
        for i, trial in enumerate(self._trials):
            for j, g in enumerate([] if G is None else np.asarray(G[i], float)):
                trial.set_constraint(f"g{j}", float(g))
            self.study.tell(trial, [float(f) for f in F[i]])
        self._trials = []
        self._evaluated = Population.merge(self._evaluated, infills)
        self.pop = infills

    def _initialize_infill(self) -> Population:
        return self._ask()

    def _initialize_advance(self, infills: Population | None = None, **kwargs: Any) -> None:
        self._tell(infills)

    def _infill(self) -> Population:
        return self._ask()

    def _advance(self, infills: Population | None = None, **kwargs: Any) -> None:
        self._tell(infills)

    def _set_optimum(self) -> None:
        self.opt = filter_optimum(self._evaluated, least_infeasible=True)
