"""Tuners: search an env's inner-controller parameters over closed-loop episodes.

Algorithms (pymoo ``Algorithm`` subclasses): :class:`~tuners.mowoa.MOWOA` (paper 004's
multi-objective whale optimisation), :class:`~tuners.pso.PSO` (scalarised PSO, 004's
comparator) and :class:`~tuners.pso.MOPSO`; pymoo's NSGA-II and MOEA/D as baselines.
:func:`~tuners.run.tune` runs them on an env id with parallel evaluation
(:mod:`tuners.backends`), an Optuna study per run and resumable checkpoints
(:mod:`tuners.storage`); :mod:`tuners.plots` draws the results,
:func:`~tuners.cli.add_tune_parser` adds ``train-envs tune`` and
:func:`~tuners.paper004.reproduce_paper004` is ``train-envs reproduce paper004``.

Names are imported lazily (``import tuners`` stays cheap).
"""

from __future__ import annotations

from train_envs._lazy import lazy_exports

_EXPORTS = {
    "MOWOA": "tuners.mowoa",
    "PSO": "tuners.pso",
    "MOPSO": "tuners.pso",
    "select_by_cosine": "tuners.mowoa",
    "tchebycheff": "tuners.mowoa",
    "weight_vectors": "tuners.mowoa",
    "EnvTuningProblem": "tuners.problem",
    "PymooTaskProblem": "tuners.problem",
    "TaskProblem": "tuners.problem",
    "Evaluations": "tuners.backends",
    "make_backend": "tuners.backends",
    "StudyStore": "tuners.storage",
    "evaluations_frame": "tuners.storage",
    "TuneResult": "tuners.run",
    "load_result": "tuners.run",
    "show": "tuners.run",
    "summarize": "tuners.run",
    "run_weight_vectors": "tuners.run",
    "tune": "tuners.run",
    "add_tune_parser": "tuners.cli",
    "reproduce_paper004": "tuners.paper004",
}

__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
