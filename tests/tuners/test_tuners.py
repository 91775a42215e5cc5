"""Tests of the tuners: algorithms, problem, backends, persistence/resume, CLI, plots.

Budgets are tiny (cheap PID env, one scenario seed, a few generations); the standard
test problems run at 004's 40 × 100 evaluations against pymoo's NSGA-II.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import signal
import subprocess
import sys
import textwrap
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from pymoo.core.problem import Problem
from pymoo.problems import get_problem

# kept light: worker processes of the crash test import this module to unpickle
# FlakyTask; everything heavier is imported inside the tests
from tuners.problem import EnvTuningProblem, PymooTask, PymooTaskProblem

REPO = Path(__file__).resolve().parents[2]
PID = "TrainEnvs/Stopping001PID-v0"


def tune(*args, **kwargs):
    from tuners.run import tune as _tune

    return _tune(*args, **kwargs)


# ------------------------------------------------------------------ helpers
class Sphere(Problem):
    """Sphere centred at 0.3 (not the origin, where WOA is biased) in [−1, 1]^n."""

    def __init__(self, n: int = 10, c: float = 0.3) -> None:
        self.c = c
        super().__init__(n_var=n, n_obj=1, xl=-1.0, xu=1.0)

    def _evaluate(self, X, out, *args, **kwargs):
        out["F"] = np.sum((X - self.c) ** 2, axis=1)[:, None]


@dataclass(frozen=True)
class FlakyTask(PymooTask):
    """Fails on its first attempt if ``fail``: raises, or kills the worker process."""

    marker_dir: str = ""
    mode: str = "raise"
    fail: bool = False

    def run(self):
        if self.fail:
            tag = hashlib.sha1(np.asarray(self.x).tobytes()).hexdigest()
            marker = Path(self.marker_dir) / tag
            if not marker.exists():
                marker.touch()
                if self.mode == "exit":
                    os._exit(3)
                raise RuntimeError("injected failure")
        return super().run()


class FlakyProblem(PymooTaskProblem):
    """ZDT1 (n_var 4) whose every ``every``-th point fails once."""

    def __init__(self, marker_dir: Path, mode: str = "raise", every: int = 3) -> None:
        super().__init__(get_problem("zdt1", n_var=4), name="flaky-zdt1")
        Path(marker_dir).mkdir(parents=True, exist_ok=True)
        self.marker_dir, self.mode, self.every = str(marker_dir), mode, every

    def make_task(self, x):
        h = int(hashlib.sha1(np.asarray(x, np.float64).tobytes()).hexdigest(), 16)
        return FlakyTask(
            self.inner, tuple(map(float, x)), 0.0, self.marker_dir, self.mode, h % self.every == 0
        )


def _clean_problem() -> PymooTaskProblem:
    return PymooTaskProblem(get_problem("zdt1", n_var=4), name="flaky-zdt1")


def _clean_run(pop: int, iters: int, seed: int):
    """The undisturbed serial MOWOA run that a disturbed run must reproduce."""
    return tune(
        _clean_problem(),
        "mowoa",
        pop=pop,
        iters=iters,
        backend="serial",
        storage=None,
        study="clean",
        seed=seed,
    )


def _trials(db: str, study: str):
    from tuners.storage import load_study

    return load_study(study, db).get_trials(deepcopy=False)


def _n_final(trials) -> int:
    return sum(
        1 for t in trials if t.state.name == "COMPLETE" or t.user_attrs["tuner"].get("final")
    )


# ------------------------------------------------------------ decomposition
def test_weight_vectors_tchebycheff_and_selection():
    from tuners.mowoa import (
        convergence_factor,
        nondominated,
        select_by_cosine,
        tchebycheff,
        weight_vectors,
    )

    for m, n in [(1, 5), (2, 40), (3, 10), (5, 40)]:
        w = weight_vectors(m, n)
        assert w.shape == (n, m)
        assert np.allclose(w.sum(axis=1), 1.0) and w.min() > 0
    # Tchebycheff: max_i w_i (f_i - z_i) / (nad_i - z_i)
    F = np.array([[1.0, 3.0], [2.0, 2.0], [3.0, 1.0]])
    g = tchebycheff(F, np.array([0.5, 0.5]), np.array([1.0, 1.0]), np.array([3.0, 3.0]))
    assert np.allclose(g, [0.5, 0.25, 0.5])
    # 004 pick: the subproblem closest to the target, then its best point
    idx = select_by_cosine(F, [0.5, 0.5], F.min(0), F.max(0), weight_vectors(2, 11))
    assert idx == 1
    assert select_by_cosine(F, [0.95, 0.05], F.min(0), F.max(0), weight_vectors(2, 11)) == 0
    assert list(nondominated(np.vstack([F, [[3, 3]]]))) == [0, 1, 2]
    # convergence factor: 2 -> 0, rate 1.72 keeps exploration (a > 1) longer than linear
    assert convergence_factor(0.0) == pytest.approx(2.0)
    assert convergence_factor(1.0) == pytest.approx(0.0)
    assert convergence_factor(0.6) > convergence_factor(0.6, "linear") > 0.5


@pytest.mark.parametrize("name", ["zdt1", "zdt2"])
def test_mowoa_matches_nsga2_on_zdt(name):
    """Stated tolerance: mean HV ≥ NSGA-II's − 0.02 and mean IGD ≤ NSGA-II's + 0.05
    (seeds 1–3, pop 40 × 100 generations = 4000 evaluations each)."""
    from pymoo.algorithms.moo.nsga2 import NSGA2
    from pymoo.indicators.hv import HV
    from pymoo.indicators.igd import IGD
    from pymoo.optimize import minimize

    from tuners.mowoa import MOWOA

    p = get_problem(name)
    hv, igd = HV(ref_point=[1.1, 1.1]), IGD(p.pareto_front())
    res = {"mowoa": [], "nsga2": []}
    for seed in (1, 2, 3):
        for algo, alg in (("mowoa", MOWOA(pop_size=40)), ("nsga2", NSGA2(pop_size=40))):
            r = minimize(p, alg, ("n_gen", 100), seed=seed)
            assert r.algorithm.evaluator.n_eval == 4000
            res[algo].append((hv(r.F), igd(r.F)))
    m, n = np.mean(res["mowoa"], axis=0), np.mean(res["nsga2"], axis=0)
    assert m[0] >= n[0] - 0.02, (name, m, n)
    assert m[1] <= n[1] + 0.05, (name, m, n)


def test_energy_weight_vectors_are_kept_on_disk_and_a_bad_file_is_recomputed(tmp_path, monkeypatch):
    from pymoo.util.ref_dirs import get_reference_directions

    from tuners import mowoa

    monkeypatch.setenv("TRAIN_ENVS_CACHE_DIR", str(tmp_path))
    n_obj, n, seed = 3, 7, 4  # not a simplex-lattice size: Riesz s-energy directions
    expected = mowoa._weight_vectors_cached.__wrapped__(n_obj, n, seed)
    path = mowoa._energy_cache_path(n_obj, n, seed)
    assert path.is_relative_to(tmp_path) and path.exists()
    stored = np.load(path, allow_pickle=False)
    assert np.array_equal(stored, get_reference_directions("energy", n_obj, n, seed=seed))
    # a second process reads the file: the same vectors, bit for bit
    assert mowoa._weight_vectors_cached.__wrapped__(n_obj, n, seed) == expected
    # a file of the wrong shape, an empty or foreign file, an .npz archive: computed again
    for bad in (np.zeros((2, 3)), b"", b"not an npy file", "npz"):
        if isinstance(bad, bytes):
            path.write_bytes(bad)
        elif isinstance(bad, str):
            with open(path, "wb") as fh:
                np.savez(fh, w=stored)
        else:
            np.save(path, bad)
        assert mowoa._weight_vectors_cached.__wrapped__(n_obj, n, seed) == expected
        assert np.array_equal(np.load(path, allow_pickle=False), stored)


def test_pso_and_mowoa_converge_on_sphere():
    """10-D sphere centred at 0.3, 40 × 100: PSO ≤ 1e-4 and ≤ NSGA-II; MOWOA (one
    objective = plain WOA) within 1e-3 of NSGA-II."""
    from pymoo.algorithms.moo.nsga2 import NSGA2
    from pymoo.optimize import minimize

    from tuners.mowoa import MOWOA
    from tuners.pso import PSO

    f = {}
    for algo, alg in (
        ("pso", PSO(pop_size=40)),
        ("mowoa", MOWOA(pop_size=40)),
        ("nsga2", NSGA2(pop_size=40)),
    ):
        f[algo] = float(minimize(Sphere(), alg, ("n_gen", 100), seed=1).F[0])
    assert f["pso"] <= 1e-4 and f["pso"] <= f["nsga2"], f
    assert f["mowoa"] <= f["nsga2"] + 1e-3, f


def test_mopso_runs_on_zdt1():
    from pymoo.algorithms.moo.nsga2 import NSGA2
    from pymoo.indicators.hv import HV
    from pymoo.optimize import minimize

    from tuners.pso import MOPSO

    p = get_problem("zdt1")
    r = minimize(p, MOPSO(pop_size=40), ("n_gen", 100), seed=1)
    n = minimize(p, NSGA2(pop_size=40), ("n_gen", 100), seed=1)
    hv = HV(ref_point=[1.1, 1.1])
    assert hv(r.F) >= hv(n.F) - 0.02


# ------------------------------------------------------------------ problem
def test_env_problem_mapping_objectives_and_penalty():
    p = EnvTuningProblem(PID)
    assert p.var_names == ["kp", "ki", "kd"]
    assert "time_error_s" not in p.objective_columns  # no schedule in 001's stopping run
    assert p.objective_columns[:2] == ("ITAE_m_s", "E_p_m") and p.n_ieq_constr == 1
    x0 = p.default_x()
    assert p.x_to_params(x0) == pytest.approx(p.defaults)
    assert np.all(p.xl == -1) and np.all(p.xu == 1)
    native = EnvTuningProblem(PID, space="native")
    assert native.xl[0] == pytest.approx(-2.0) and native.xu[0] == pytest.approx(1.0)  # log10
    assert native.x_to_params(native.params_to_x({"kp": 2.0}))["kp"] == pytest.approx(2.0)
    urban = EnvTuningProblem("TrainEnvs/Urban004FuzzyPID-v0", seeds=[0])
    assert urban.objective_columns == (
        "ITAE_m_s",
        "E_p_m",
        "time_error_s",
        "comfort_mean_abs_jerk_mps3",
        "energy_kWh",
    )
    pen = EnvTuningProblem(PID, constraint_mode="penalty", objectives=["itae"])
    F, G = pen.outcome_arrays({"F": [1.0], "G": [0.5]})
    assert pen.n_ieq_constr == 0 and F[0] == pytest.approx(1.0 + 1e3 * 0.5) and G.size == 0
    with pytest.raises(ValueError, match="not tunable"):
        EnvTuningProblem(PID, params=["nope"])
    # evaluate the defaults directly (no runner): pymoo sees F and G
    out = p.evaluate(x0[None, :], return_as_dictionary=True)
    assert out["F"].shape == (1, p.n_obj) and out["G"][0, 0] <= 0


# ---------------------------------------------------- tune, storage, results
def test_tune_env_records_every_evaluation_once(tmp_path):
    from tuners.storage import checkpoint_info

    db = f"sqlite:///{tmp_path / 'runs.db'}"
    cfg = {"disturbance": {"mass_factor_range": [0.9, 1.15], "random_bound_mps2": 0.03}}
    r = tune(
        PID,
        "mowoa",
        pop=5,
        iters=2,
        backend="serial",
        storage=db,
        study="s",
        seeds=[0],
        objectives=["itae", "stop", "comfort"],
        config=cfg,
    )
    trials = _trials(db, "s")
    keys = [t.user_attrs["tuner"]["key"] for t in trials]
    assert len(keys) == len(set(keys)) == r.stats.run == len(r.evaluations)
    assert r.stats.requested == 10 and r.stats.cached == 10 - r.stats.run
    df = r.evaluations
    assert df["is_default"].sum() == 1 and df.loc[df["is_default"], "generation"].item() == 1
    assert set(df["generation"]) == {1, 2}
    assert df["pareto"].any() and df["selected"].sum() == 1 and r.selected["pareto"]
    # each trial: params (native), values = objectives, constraint, attrs
    t = trials[0]
    assert set(t.params) == {"kp", "ki", "kd"} and len(t.values) == 3
    # feasibility under Optuna's own constraints key (a list in constraint_names order)
    assert t.system_attrs["constraints"] == t.user_attrs["tuner"]["G"]
    assert t.constraints == {"0": pytest.approx(t.user_attrs["tuner"]["G"][0])}
    assert t.user_attrs["tuner"]["seeds"] == [0] and t.user_attrs["generation"] == 1
    assert checkpoint_info("s", db)["n_gen"] == 2
    # held-out seeds: defaults and selected, scored with the run's normalisation
    ho = r.compare_on_seeds([7])
    assert list(ho["point"]) == ["defaults", "selected"] and ho["tchebycheff"].notna().all()
    # the runs of a figure: a selection equal to the defaults is named so
    r.selected = {**r.selected, "x": r.problem.default_x()}
    runs = r.trajectories(7)
    assert list(runs) == ["defaults", "selected (= defaults)"]
    assert runs["defaults"].equals(runs["selected (= defaults)"])
    # a second run on the same study without resume is refused
    with pytest.raises(ValueError, match="resume"):
        tune(
            PID,
            "mowoa",
            pop=5,
            iters=2,
            backend="serial",
            storage=db,
            study="s",
            objectives=["itae", "stop", "comfort"],
            config=cfg,
        )


@pytest.mark.parametrize("space", ["unit", "native"])
def test_stored_params_are_what_the_controller_ran(monkeypatch, space):
    """Every value the study stores is exactly the value the controller ran with."""
    from train_envs.envs.evaluation import EnvEpisodes

    ran = []
    start = EnvEpisodes.start

    def spy(self, seed, params):
        loop = start(self, seed, params)
        ran.append(tuple(sorted(loop.controller.get_params().items())))
        return loop

    monkeypatch.setattr(EnvEpisodes, "start", spy)
    r = tune(
        PID,
        "mowoa",
        pop=4,
        iters=2,
        backend="serial",
        storage=None,
        seeds=[0],
        objectives=["itae", "stop"],
        space=space,
        config={"max_episode_steps": 40},
    )
    df = r.evaluations
    stored = [
        tuple(sorted((n, float(row[n])) for n in ("kd", "ki", "kp"))) for _, row in df.iterrows()
    ]
    probe, ran = ran[0], ran[1:]  # the first: the one-step metric check of the defaults
    assert probe == next(s for s, d in zip(stored, df["is_default"], strict=True) if d)
    assert len(ran) == len(stored) == r.stats.run
    assert sorted(ran) == sorted(stored)
    assert r.selected_params == {n: float(r.selected[n]) for n in ("kp", "ki", "kd")}


#: a run that SIGKILLs itself right after its 7th stored evaluation: generation 1 has at
#: most 5 evaluations, so the kill falls inside generation 2, whatever the machine's speed
KILL_SCRIPT = textwrap.dedent(
    """
    import os, signal, sys
    from tuners import storage
    from tuners.run import tune
    _record, _stored = storage.StudyStore.record, []
    def record(self, *args, **kwargs):
        _record(self, *args, **kwargs)
        _stored.append(1)
        if len(_stored) == 7:
            os.kill(os.getpid(), signal.SIGKILL)
    storage.StudyStore.record = record
    if __name__ == "__main__":
        tune("{env}", "mowoa", pop=5, iters=3, backend="serial", storage=sys.argv[1],
             study=sys.argv[2], seeds=[0], seed=5, objectives=["itae", "stop", "comfort"])
    """
)


@pytest.mark.parametrize("storage", ["sqlite", "journal"])
def test_resume_after_kill_is_identical(tmp_path, storage):
    """SIGKILL a run mid-generation, resume it: same Pareto set and result as an
    uninterrupted seeded run, and no finished evaluation is run twice (the journal
    appends each trial at once and syncs once per generation: nothing is lost either)."""
    from tuners.storage import checkpoint_info

    db = f"sqlite:///{tmp_path / 'runs.db'}"
    if storage == "journal":
        db = f"journal:{tmp_path / 'runs.log'}"
    kw = dict(
        pop=5,
        iters=3,
        backend="serial",
        storage=db,
        seeds=[0],
        seed=5,
        objectives=["itae", "stop", "comfort"],
    )
    script = tmp_path / "run.py"
    script.write_text(KILL_SCRIPT.format(env=PID))
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.run([sys.executable, str(script), db, "killed"], env=env, cwd=REPO)
    assert proc.returncode == -signal.SIGKILL  # killed by itself after 7 stored trials
    done_gen = checkpoint_info("killed", db)["n_gen"]
    before = {t.user_attrs["tuner"]["key"] for t in _trials(db, "killed")}
    gens_before = [t.user_attrs["generation"] for t in _trials(db, "killed")]
    assert done_gen < 3 and max(gens_before) == done_gen + 1  # killed inside a generation

    resumed = tune(PID, "mowoa", study="killed", resume=True, **kw)
    reference = tune(PID, "mowoa", study="reference", **kw)

    assert np.array_equal(resumed.pymoo_result.X, reference.pymoo_result.X)
    assert np.array_equal(resumed.pymoo_result.F, reference.pymoo_result.F)
    cols = ["kp", "ki", "kd", *reference.objectives]
    a = resumed.pareto[cols].sort_values(cols).to_numpy()
    b = reference.pareto[cols].sort_values(cols).to_numpy()
    assert np.array_equal(a, b)
    assert resumed.selected[cols].equals(reference.selected[cols])
    assert set(resumed.evaluations["key"]) == set(reference.evaluations["key"])
    # nothing finished before the kill was run again, and every evaluation is there once
    assert resumed.stats.run == len(set(resumed.evaluations["key"]) - before)
    trials = _trials(db, "killed")
    keys = [t.user_attrs["tuner"]["key"] for t in trials]
    assert len(keys) == len(set(keys)) == len(reference.evaluations)


def test_worker_exception_is_retried_and_recorded(tmp_path):
    db = f"sqlite:///{tmp_path / 'runs.db'}"
    flaky = tune(
        FlakyProblem(tmp_path / "m"),
        "mowoa",
        pop=8,
        iters=3,
        backend="serial",
        storage=db,
        study="flaky",
        seed=2,
    )
    clean = _clean_run(pop=8, iters=3, seed=2)
    assert flaky.stats.failed_attempts > 0 and flaky.stats.failed_final == 0
    assert np.array_equal(flaky.pymoo_result.F, clean.pymoo_result.F)
    trials = _trials(db, "flaky")
    retried = [t for t in trials if t.user_attrs["tuner"].get("retried")]
    assert len(retried) == flaky.stats.failed_attempts
    assert all("injected failure" in t.user_attrs["error"] for t in retried)
    assert all(t.state.name == "FAIL" for t in retried)
    assert _n_final(trials) == len(flaky.evaluations) == flaky.stats.run


def test_failed_for_good_is_infeasible_not_fatal(tmp_path):
    """An evaluation failing on every retry gets worst values; the run goes on."""
    p = FlakyProblem(tmp_path / "m", every=4)
    r = tune(
        p, "nsga2", pop=8, iters=2, backend="serial", storage=None, study="x", max_retries=0, seed=3
    )
    assert r.stats.failed_final > 0
    failed = r.evaluations[r.evaluations["failed"]]
    assert len(failed) == r.stats.failed_final and (failed["f1"] == p.fail_value).all()


def test_process_worker_crash_is_resubmitted(tmp_path):
    """A worker dying (os._exit) breaks the pool: it restarts and the run completes
    with the result of a clean run."""
    p = FlakyProblem(tmp_path / "m", mode="exit", every=5)
    r = tune(
        p,
        "mowoa",
        pop=6,
        iters=2,
        backend="processes",
        workers=2,
        storage=None,
        study="crash",
        seed=4,
    )
    clean = _clean_run(pop=6, iters=2, seed=4)
    # worker deaths are not charged to the tasks in flight: no failed attempt
    assert r.stats.worker_deaths > 0 and r.stats.failed_attempts == r.stats.failed_final == 0
    assert any("process died" in e for e in r.stats.errors)
    assert np.array_equal(r.pymoo_result.F, clean.pymoo_result.F)


def test_dask_backend_local_cluster(tmp_path):
    distributed = pytest.importorskip("distributed", reason="dask.distributed not installed")
    try:
        cluster = distributed.LocalCluster(
            n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None
        )
    except Exception as exc:  # noqa: BLE001 - e.g. no network interface in a sandbox
        pytest.skip(f"Dask LocalCluster cannot start here: {exc}")
    with cluster, distributed.Client(cluster) as client:
        r = tune(
            FlakyProblem(tmp_path / "m"),
            "mowoa",
            pop=6,
            iters=2,
            backend="dask",
            dask_client=client,
            storage=None,
            study="dask",
            seed=6,
        )
    clean = _clean_run(pop=6, iters=2, seed=6)
    assert r.stats.failed_attempts > 0 and r.stats.failed_final == 0
    assert np.array_equal(r.pymoo_result.F, clean.pymoo_result.F)


@pytest.mark.parametrize("algo", ["pso", "mopso", "nsga2", "moead"])
def test_other_algorithms_through_tune(algo):
    r = tune(
        _clean_problem(), algo, pop=6, iters=3, backend="serial", storage=None, study=algo, seed=1
    )
    assert len(r.evaluations) >= 6 and r.selected is not None and r.pareto["pareto"].all()


# ----------------------------------------------------------------- CLI, plots
def test_cli_tune_show_and_outputs(tmp_path, capsys):
    from matplotlib.figure import Figure

    from tuners import plots
    from tuners.cli import add_tune_parser
    from tuners.run import load_result
    from tuners.storage import evaluations_frame, load_study

    parser = argparse.ArgumentParser(prog="train-envs")
    add_tune_parser(parser.add_subparsers(dest="command", required=True))
    db = f"sqlite:///{tmp_path / 'cli.db'}"
    args = parser.parse_args(
        [
            "tune",
            "--env",
            PID,
            "--algo",
            "pso",
            "--pop",
            "4",
            "--iters",
            "2",
            "--backend",
            "serial",
            "--storage",
            db,
            "--study",
            "cli",
            "--objectives",
            "itae",
            "stop",
            "--constraint",
            "max_overspeed_mps=0",
            "--constraint",
            "E_p_m=50",
            "--no-progress",
            "--out",
            str(tmp_path / "out"),
            "--holdout-seeds",
            "7",
        ]
    )
    assert args.func(args) == 0
    out = capsys.readouterr().out
    assert "Pareto set" in out and "Selected" in out and "Defaults" in out
    assert "Held-out seeds [7]" in out  # the main job's comparison (make demo)
    assert load_result("cli", db).evaluations.filter(like="g:").shape[1] == 2
    for suffix in (".csv", ".parquet", "_pareto.png", "_parallel.png", "_hypervolume.png"):
        assert (tmp_path / "out" / f"cli{suffix}").exists(), suffix
    args = parser.parse_args(["tune", "show", "cli", "--storage", db])
    assert args.func(args) == 0
    assert "Selected" in capsys.readouterr().out
    args = parser.parse_args(["tune", "show", "nope", "--storage", db])
    with pytest.raises(KeyError, match="no study 'nope'"):  # train_envs.cli.main: one line
        args.func(args)
    # plots on the stored frame
    df = evaluations_frame(load_study("cli", db))
    res = load_result("cli", db)
    # a loaded result has no problem object; the parameters come from the stored settings
    assert res.problem is None and set(res.selected_params) == {"kp", "ki", "kd"}
    for fig in (
        plots.pareto_front_figure(res.evaluations),
        plots.parallel_coordinates_figure(res.evaluations),
        plots.hypervolume_figure(res.evaluations),
    ):
        assert isinstance(fig, Figure)
    h = plots.hypervolume_history(res.evaluations)
    assert list(h["generation"]) == [1, 2] and h["hypervolume"].is_monotonic_increasing
    assert len(df) == len(res.evaluations)


def test_optuna_dashboard_reads_the_study(tmp_path):
    dashboard = pytest.importorskip("optuna_dashboard", reason="optuna-dashboard not installed")
    import json
    from wsgiref.util import setup_testing_defaults

    db = f"sqlite:///{tmp_path / 'dash.db'}"
    r = tune(
        _clean_problem(),
        "mowoa",
        pop=4,
        iters=2,
        backend="serial",
        storage=db,
        study="dash",
        seed=1,
    )
    app = dashboard.wsgi(db)

    def get(path: str):
        environ: dict = {}
        setup_testing_defaults(environ)
        environ.update(PATH_INFO=path, REQUEST_METHOD="GET")
        status: dict = {}
        body = b"".join(app(environ, lambda s, h, *a: status.setdefault("s", s)))
        return status["s"], json.loads(body)

    status, summaries = get("/api/studies")
    assert status.startswith("200")
    study_id = summaries["study_summaries"][0]["study_id"]
    status, detail = get(f"/api/studies/{study_id}")
    assert status.startswith("200") and len(detail["trials"]) == len(r.evaluations)
    assert {p["name"] for p in detail["trials"][0]["params"]} == {"x0", "x1", "x2", "x3"}


def test_summarize_normalizations_and_target_subproblem():
    import pandas as pd

    from tuners.run import run_weight_vectors, summarize

    W = run_weight_vectors(3, 10, [0.2, 0.3, 0.5])
    assert np.allclose(W.sum(axis=1), 1) and any(np.allclose(w, [0.2, 0.3, 0.5]) for w in W)
    # defaults (key "d") and three trade-offs; "b" beats the defaults in both objectives
    df = pd.DataFrame(
        {
            "key": ["d", "a", "b", "c"],
            "f1": [1.0, 0.2, 0.8, 3.0],
            "f2": [1.0, 5.0, 0.9, 0.1],
            "feasible": [True, True, True, True],
        }
    )
    _, sel, ideal, nadir = summarize(df.copy(), ["f1", "f2"], None, 10, default_key="d")
    assert sel["key"] == "b" and np.allclose(nadir - ideal, [0.8, 0.9])  # defaults scale
    d2 = df.copy()
    _, sel, _, _ = summarize(d2, ["f1", "f2"], None, 10, normalization="pareto")
    assert d2.attrs["normalization"] == "pareto" and sel["key"] in {"a", "b", "c"}
    _, sel, ideal, nadir = summarize(df.copy(), ["f1", "f2"], None, 10, f_bounds=([0, 0], [10, 1]))
    assert np.allclose(nadir - ideal, [10, 1])
    with pytest.raises(ValueError, match="defaults"):
        summarize(df.copy(), ["f1", "f2"], normalization="defaults")


# ------------------------------------------------------- env reuse per worker
@dataclass(frozen=True)
class CacheProbeTask:
    """Runs env tasks one after the other in one worker; F = hits of its env cache."""

    tasks: tuple

    def run(self):
        from train_envs.envs.evaluation import ENV_CACHE

        hits = ENV_CACHE.hits
        outs = [t.run() for t in self.tasks]
        return {"F": [float(ENV_CACHE.hits - hits)], "G": [], "metrics": {"outs": outs}}


def test_env_tasks_reuse_one_env_per_worker_with_fresh_env_results():
    from train_envs.envs.evaluation import clear_env_cache
    from tuners.backends import ProcessBackend
    from tuners.problem import run_task

    p = EnvTuningProblem(PID, seeds=[0, 1])
    xs = [np.full(3, 0.4), p.default_x(), np.array([-0.5, 0.2, 0.9])]
    tasks = tuple(p.make_task(x) for x in xs)
    fresh = []
    for t in tasks:  # each on a newly made env
        clear_env_cache()
        fresh.append(t.run())
    clear_env_cache()
    serial = run_task(CacheProbeTask(tasks))
    assert serial["F"] == [2.0] and serial["metrics"]["outs"] == fresh
    with ProcessBackend(workers=1) as backend:  # spawned worker: its own cache
        (out,) = backend.run([CacheProbeTask(tasks)])
    assert out["F"] == [2.0] and out["metrics"]["outs"] == fresh


def test_resume_by_other_code_is_refused_unless_allowed(tmp_path, monkeypatch):
    """A study records the code fingerprint; resuming it with other code is refused (its
    cache would answer for the new code), allowed on request (and recorded), and
    '{code}' in a study name gives one study per code version."""
    import optuna

    import tuners.run as run
    from tuners.storage import CODE_HISTORY_ATTR, CONFIG_ATTR, code_fingerprint

    db = f"sqlite:///{tmp_path / 'runs.db'}"
    problem = PymooTaskProblem(get_problem("zdt1", n_var=4))
    kw = dict(pop=4, iters=1, backend="serial", storage=db, seed=1)
    first = run.tune(problem, "mowoa", study="z", **kw)
    st = optuna.load_study(study_name="z", storage=db)
    assert st.user_attrs[CONFIG_ATTR]["code"] == code_fingerprint()
    monkeypatch.setattr(run, "code_fingerprint", lambda: "feedfacecafebeef")
    with pytest.raises(ValueError, match="other code.*allow_code_change"):
        run.tune(problem, "mowoa", study="z", resume=True, **kw)
    again = run.tune(problem, "mowoa", study="z", resume=True, allow_code_change=True, **kw)
    assert again.stats.run == 0 and len(again.evaluations) == len(first.evaluations)
    st = optuna.load_study(study_name="z", storage=db)
    assert st.user_attrs[CODE_HISTORY_ATTR] == [code_fingerprint(), "feedfacecafebeef"]
    per_code = run.tune(problem, "mowoa", study="z-{code}", resume="auto", **kw)
    assert per_code.study_name == "z-feedface" and per_code.stats.run > 0
