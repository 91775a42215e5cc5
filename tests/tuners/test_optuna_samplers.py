"""Optuna's samplers as ``tune`` algorithms: faithful ask-and-tell, storage, resume.

Tiny budgets on pymoo's constrained two-objective BNH problem (GP: a 3-d sphere with
three random start-up trials, a GP ask costs seconds).
"""

from __future__ import annotations

import numpy as np
import optuna
import pytest
from pymoo.core.callback import Callback
from pymoo.problems import get_problem

from tuners.optuna_samplers import OPTUNA_ALGORITHMS, make_sampler
from tuners.problem import PymooTaskProblem, run_task
from tuners.run import ALGORITHMS, TuneInterrupted, tune
from tuners.storage import load_study

SEED = 3


class Keep(Callback):
    """Keeps the algorithm seen after each generation."""

    def __init__(self, seen: list) -> None:
        super().__init__()
        self.seen = seen

    def notify(self, algorithm) -> None:
        self.seen.append(algorithm)


class WithDefaults(PymooTaskProblem):
    """A pymoo problem with a 'default' point, enqueued by ``tune`` as the first trial."""

    def default_x(self) -> np.ndarray:
        xl, xu = self.bounds()
        return xl + 0.25 * (xu - xl)


def _case(algo: str) -> tuple[PymooTaskProblem, int, int, dict]:
    if algo == "optuna-gp":
        return (
            WithDefaults(get_problem("sphere", n_var=3), name="sphere"),
            3,
            2,
            {"n_startup_trials": 3},
        )
    return WithDefaults(get_problem("bnh"), name="bnh"), 6, 3, {}


def _ask_tell_reference(algo: str, problem, pop: int, iters: int, kw: dict) -> np.ndarray:
    """The points a plain Optuna study with the same seeded sampler asks."""
    study = optuna.create_study(
        directions=["minimize"] * problem.n_obj, sampler=make_sampler(algo, SEED, pop, **kw)
    )
    dists = {
        f"x{i}": optuna.distributions.FloatDistribution(float(lo), float(hi))
        for i, (lo, hi) in enumerate(zip(problem.xl, problem.xu, strict=True))
    }
    study.enqueue_trial({f"x{i}": float(v) for i, v in enumerate(problem.default_x())})
    X = []
    for _ in range(iters):
        trials = [study.ask(dists) for _ in range(pop)]
        for t in trials:
            x = np.array([t.params[f"x{i}"] for i in range(problem.n_var)])
            out = run_task(problem.make_task(x))
            for j, g in enumerate(out["G"]):
                t.set_constraint(f"g{j}", g)
            study.tell(t, out["F"])
            X.append(x)
    return np.array(X)


def test_optuna_samplers_are_offered():
    assert {"optuna-tpe", "optuna-nsga2", "optuna-nsga3"} <= set(OPTUNA_ALGORITHMS)
    assert set(OPTUNA_ALGORITHMS) <= set(ALGORITHMS)
    with pytest.raises(ValueError, match="Optuna sampler must be one of"):
        make_sampler("optuna-cmaes", 0, 4)


@pytest.mark.parametrize("algo", OPTUNA_ALGORITHMS)
def test_sampler_through_tune_is_plain_ask_and_tell(algo, tmp_path):
    """``tune`` with an Optuna sampler evaluates exactly the points that the same seeded
    sampler asks in a plain ask-and-tell loop (defaults first), stores each evaluation
    once in the tuner's study, and hands the constraint values to the sampler."""
    problem, pop, iters, kw = _case(algo)
    db = f"sqlite:///{tmp_path / 'runs.db'}"
    seen = []
    r = tune(
        problem,
        algo,
        pop=pop,
        iters=iters,
        backend="serial",
        storage=db,
        study=algo,
        seed=SEED,
        algo_kwargs=kw,
        callback=Keep(seen),
    )
    X = np.array(r.evaluations.sort_values("trial")["x"].tolist())
    ref = _ask_tell_reference(algo, problem, pop, iters, kw)
    assert np.array_equal(X, ref)
    assert np.array_equal(X[0], problem.default_x()) and bool(r.evaluations["is_default"].iloc[0])
    trials = load_study(algo, db).get_trials()
    assert len(trials) == len(r.evaluations) == pop * iters
    assert (X >= problem.xl).all() and (X <= problem.xu).all()
    private = seen[-1].study.get_trials()  # the sampler's view: values and constraints
    assert [t.values for t in private] == r.evaluations.sort_values("trial")[
        r.objectives
    ].to_numpy().tolist()
    if problem.n_ieq_constr:
        G = r.evaluations.sort_values("trial")[[f"g:{n}" for n in problem.constr_names]].to_numpy()
        assert np.array_equal(
            [[t.system_attrs[f"constraints:g{j}"] for j in (0, 1)] for t in private], G
        )
    # the Pareto rows are feasible and non-dominated among the feasible evaluations
    F = r.evaluations.loc[r.evaluations["feasible"], r.objectives].to_numpy()
    for f in r.pareto[r.objectives].to_numpy():
        assert not np.any(np.all(F <= f, axis=1) & np.any(F < f, axis=1))


def test_optuna_sampler_resume_after_interrupt_is_identical(tmp_path):
    """Ctrl-C inside generation 2, resume: the result of an uninterrupted run, and no
    finished evaluation is run again."""
    problem = WithDefaults(get_problem("bnh"), name="bnh")
    db = f"sqlite:///{tmp_path / 'runs.db'}"
    kw = dict(pop=5, iters=3, backend="serial", storage=db, seed=SEED)
    count = {"n": 0}

    def stop_at_8(key, outcome, generation):
        count["n"] += 1
        if count["n"] == 8:
            raise KeyboardInterrupt

    with pytest.raises(TuneInterrupted):
        tune(problem, "optuna-tpe", study="cut", on_evaluation=stop_at_8, **kw)
    before = {t.user_attrs["tuner"]["key"] for t in load_study("cut", db).get_trials()}
    assert len(before) == 8
    resumed = tune(problem, "optuna-tpe", study="cut", resume=True, **kw)
    reference = tune(problem, "optuna-tpe", study="reference", **kw)
    assert np.array_equal(resumed.pymoo_result.X, reference.pymoo_result.X)
    assert np.array_equal(resumed.pymoo_result.F, reference.pymoo_result.F)
    assert set(resumed.evaluations["key"]) == set(reference.evaluations["key"])
    assert resumed.stats.run == len(reference.evaluations) - len(before)


def test_cli_offers_every_algorithm_and_runs_an_optuna_sampler(tmp_path, capsys):
    import argparse

    from tuners.cli import ALGO_CHOICES, add_tune_parser

    assert ALGO_CHOICES == ALGORITHMS
    parser = argparse.ArgumentParser(prog="train-envs")
    add_tune_parser(parser.add_subparsers(dest="command", required=True))
    db = f"sqlite:///{tmp_path / 'cli.db'}"
    argv = ["tune", "--env", "TrainEnvs/Stopping001PID-v0", "--algo", "optuna-nsga2"]
    argv += ["--pop", "3", "--iters", "2", "--backend", "serial", "--storage", db]
    argv += ["--study", "cli", "--objectives", "itae", "stop", "--no-progress"]
    args = parser.parse_args(argv)
    assert args.func(args) == 0
    assert "Pareto set" in capsys.readouterr().out
    assert len(load_study("cli", db).get_trials()) == 6
