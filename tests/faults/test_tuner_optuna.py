"""Fault cases of the study as an Optuna citizen, and of populations below the number of
objectives."""

from __future__ import annotations

import numpy as np
import optuna
import pytest
from pymoo.core.problem import Problem

from tuners.problem import PymooTaskProblem

optuna.logging.set_verbosity(optuna.logging.WARNING)


class Constrained(Problem):
    """Two objectives, one constraint (x0 >= 0.3) that cuts the front."""

    def __init__(self) -> None:
        super().__init__(n_var=2, n_obj=2, n_ieq_constr=1, xl=0.0, xu=1.0)

    def _evaluate(self, X, out, *args, **kwargs):
        out["F"] = np.column_stack([X[:, 0], 1.0 - np.sqrt(X[:, 0]) + X[:, 1]])
        out["G"] = 0.3 - X[:, :1]


class Three(Problem):
    """Three objectives: the squared distances to three corners."""

    def __init__(self) -> None:
        super().__init__(n_var=2, n_obj=3, xl=0.0, xu=1.0)

    def _evaluate(self, X, out, *args, **kwargs):
        c = np.array([[0, 0], [1, 0], [0, 1]], float)
        out["F"] = np.stack([np.sum((X - ci) ** 2, axis=1) for ci in c], axis=1)


def test_best_trials_and_dashboard_honour_feasibility(tmp_path):
    from tuners.run import tune

    db = f"sqlite:///{tmp_path / 'c.db'}"
    r = tune(PymooTaskProblem(Constrained(), name="c"), "nsga2", pop=8, iters=3,
             backend="serial", storage=db, study="c", seed=2)  # fmt: skip
    study = optuna.load_study(study_name="c", storage=db)
    feasible = {t.number for t in study.trials if t.constraints and t.constraints["0"] <= 0}
    infeasible = {t.number for t in study.trials} - feasible
    assert infeasible and feasible  # the case is meaningful
    best = {t.number for t in study.best_trials}
    assert best and best <= feasible
    assert best == set(r.pareto["trial"])  # Optuna's Pareto set is the tuner's
    dashboard = pytest.importorskip("optuna_dashboard._serializer")
    trial = study.trials[0]
    attrs = study._storage.get_study_system_attrs(study._study_id)
    ser = dashboard.serialize_frozen_trial(study._study_id, trial, attrs)
    assert ser["constraints"] == trial.user_attrs["tuner"]["G"]


@pytest.mark.parametrize("algo", ["mowoa", "mopso", "moead"])
def test_pop_below_the_objectives_is_a_clear_error_before_work(algo, tmp_path):
    from tuners.run import tune

    db = f"sqlite:///{tmp_path / 'p.db'}"
    with pytest.raises(ValueError, match=rf"pop 2 is below the 3 objectives: {algo}"):
        tune(PymooTaskProblem(Three(), name="t"), algo, pop=2, iters=2, backend="serial",
             storage=db, study="p")  # fmt: skip
    assert not (tmp_path / "p.db").exists()


@pytest.mark.parametrize("algo", ["pso", "nsga2"])
def test_pop_below_the_objectives_runs_and_shows(algo, tmp_path):
    """Algorithms without one weight vector per individual run with pop < n_obj; the
    final pick uses at least one weight vector per objective."""
    from tuners.run import show, tune

    db = f"sqlite:///{tmp_path / 'p.db'}"
    r = tune(PymooTaskProblem(Three(), name="t"), algo, pop=2, iters=2, backend="serial",
             storage=db, study="p")  # fmt: skip
    assert r.selected is not None and r.selected["pareto"]
    assert "Selected" in show("p", db)
