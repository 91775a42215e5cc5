"""Tuner benchmarks: evaluation throughput, persistence overhead, convergence, 004 run.

Run (not a test; numbers go in the closing notes)::

    python benchmarks/bench_tuners.py speed         # evaluations/s, 1 vs N worker processes
    python benchmarks/bench_tuners.py persistence   # Optuna SQLite/journal cost per evaluation
    python benchmarks/bench_tuners.py convergence   # MOWOA/MOPSO vs NSGA-II on ZDT
    python benchmarks/bench_tuners.py tune004       # 20 x 10 tuning run on paper 004
    python benchmarks/bench_tuners.py compare004 --pop004 16 --iters004 8 --seeds 1 2 3
                                                    # MOWOA vs NSGA-II vs MOEA/D on 004 (HV)
    python benchmarks/bench_tuners.py storage       # driver ms per stored trial: SQLite vs journal
    python benchmarks/bench_tuners.py lockstep      # 40 x 100 MOWOA on 004: lockstep vs processes
    python benchmarks/bench_tuners.py lockstep --quick   # the same at 10 x 4
    python benchmarks/bench_tuners.py all

``speed`` evaluates the same points on ``--env`` (default the 004 Fuzzy-PID id, one
scenario seed) with a pool of one worker process and with a pool of ``--workers``,
in turn on the same chunks of points (``--rounds``, order swapped every round), and
reports the speed-up over all rounds and per round (the pool start-up is timed
separately; both pools limit BLAS to one thread per worker). With 2 workers it also
runs a machine-level pair test: one 4-episode task alone in the 1-worker pool against
two copies at once in the 2-worker pool (no scheduling, no tail, nothing in the main
process), as 2 × t_alone / t_pair: what the two cores give each other on this workload
at that moment (it drifts with the machine as much as the speed-up does). ``persistence`` times
what storing costs per finished evaluation (one Optuna trial) and per generation (the
algorithm checkpoint) on a problem whose evaluation is free (ZDT1 with 7 variables,
like 004's DMC; Optuna writes one row per parameter, so the cost grows with their
number), for in-memory Optuna and an SQLite file.
``convergence`` compares hypervolume (reference point 1.1, 1.1) and IGD at equal
evaluations (pop 40 x 100 generations) over seeds, including a shifted ZDT1 whose
Pareto set is not on the lower bound. ``tune004`` tunes ``--env004`` (default the DMC
id of paper 004 if registered, else its Fuzzy-PID id) with MOWOA at a reduced budget
(20 x 10, two disturbed scenario seeds, equal target weights, 004's five objectives
normalised by the tolerance values ``TOLERANCES``, constraints ``CONSTRAINTS``) and
compares the selected solution with the defaults on held-out scenario seeds, by the
Tchebycheff value under the target weights and the run's normalisation.
``storage`` times ``StudyStore.record`` in the driver (CPU and wall time per trial of an
``--env-ls`` outcome) for an SQLite file and a journal file in alternating rounds
(``--rounds``, 40 trials each, held and flushed per round as ``Evaluations`` does per
batch) and reports the median per-round CPU ratio.
``lockstep`` runs the same MOWOA tuning of ``--env-ls`` (default ``Urban004-v0``, its
default objectives, scenario seeds ``--ls-seeds``, algorithm seed 1) once per
``--ls-runs`` entry ``BACKEND:STORAGE`` (``sqlite`` or ``journal`` files in a temporary
folder), the entries in turn and their order reversed every round (``--ls-rounds``),
and prints a markdown table: wall time, evaluations/s, main-process storage time per
stored trial (``EvalStats.store_time_s`` over the trials written) and the selected
point, which must be the same in every run.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np

DISTURBANCE = {"disturbance": {"mass_factor_range": [0.9, 1.15], "random_bound_mps2": 0.03}}
#: 004's "tolerance values" (lower, upper) of ITAE [m], |stop error| [m], time error [s],
#: mean |jerk| [m/s^3], energy [kWh] -- engineering scales, not given by 004: ITAE of the
#: order of the defaults' (~300-600 m), a +-0.5 m stopping window (paper 001), 1 s of
#: punctuality, 0.1 m/s^3 mean jerk, 10 % of a run's ~25 kWh
TOLERANCES = ([0.0, 0.0, 0.0, 0.0, 0.0], [1000.0, 0.5, 1.0, 0.1, 2.5])
#: safety (no overspeed) plus operational acceptability: worst seed within 5 s of the
#: schedule and 2 m of the stopping point (a stalled or overshooting run is no solution)
CONSTRAINTS = {"max_overspeed_mps": 0.0, "time_error_s": 5.0, "E_p_m": 2.0}


def _load() -> str:
    try:
        return " ".join(f"{v:.2f}" for v in os.getloadavg())
    except OSError:
        return "n/a"


# ---------------------------------------------------------------------- speed
def bench_speed(env_id: str, n: int, workers: int, rounds: int = 4) -> dict:
    from tuners.backends import Evaluations, ProcessBackend
    from tuners.problem import EnvTuningProblem

    prob = EnvTuningProblem(env_id, seeds=[0])
    rng = np.random.default_rng(0)
    X = np.vstack([prob.default_x(), rng.uniform(-1, 1, (n - 1, prob.n_var))])
    one, many = ProcessBackend(workers=1), ProcessBackend(workers=workers)
    try:
        t0 = time.perf_counter()
        for be in (one, many):  # every worker imports, builds its env, runs a few
            Evaluations(be).evaluate(prob, rng.uniform(-1, 1, (4 * workers, prob.n_var)))
        t_spawn = time.perf_counter() - t0
        # the two pools in turn on the same chunks, the order swapped every round: this
        # machine's speed drifts within minutes, a ratio per round is what holds
        t1 = tn = 0.0
        ratios = []
        for r, chunk in enumerate(np.array_split(X, rounds)):
            times = {}
            for be in (one, many) if r % 2 == 0 else (many, one):
                t0 = time.perf_counter()
                Evaluations(be).evaluate(prob, chunk)
                times[be is one] = time.perf_counter() - t0
            t1 += times[True]
            tn += times[False]
            ratios.append(times[True] / times[False])
        # machine-level pair test: the same task (4 episodes) alone in the 1-worker pool
        # against two copies at once in the 2-worker pool -- no scheduling, no tail, no
        # main-process work; what the two cores lose to each other running this workload
        pair = []
        if workers == 2:
            task = EnvTuningProblem(env_id, seeds=[0, 1, 2, 3]).make_task(prob.default_x())
            for r in range(rounds):
                times = {}
                for be in (one, many) if r % 2 == 0 else (many, one):
                    t0 = time.perf_counter()
                    be.run([task] if be is one else [task, task])
                    times[be is one] = time.perf_counter() - t0
                pair.append(2.0 * times[True] / times[False])
    finally:
        one.close()
        many.close()
    out = {
        "env": env_id,
        "evaluations": n,
        "workers": workers,
        "cores": os.cpu_count(),
        "one_worker_evals_per_s": n / t1,
        "processes_evals_per_s": n / tn,
        "speedup": t1 / tn,
        "speedup_per_round": ratios,
        "pool_startup_s": t_spawn,
        "pair_test_speedup_per_round": pair,
        "loadavg": _load(),
    }
    print(
        f"[speed] {env_id}: {n} evaluations in {rounds} rounds, 1 worker process "
        f"{out['one_worker_evals_per_s']:.2f}/s, {workers} processes "
        f"{out['processes_evals_per_s']:.2f}/s -> speed-up {out['speedup']:.2f}x (rounds "
        f"{min(ratios):.2f}-{max(ratios):.2f}; pool start-up {t_spawn:.1f} s; "
        f"load {out['loadavg']})"
    )
    print("\n| pool | evaluations/s |\n|---|---:|")
    print(f"| one worker process | {out['one_worker_evals_per_s']:.3f} |")
    print(f"| pool of {workers} processes | {out['processes_evals_per_s']:.3f} |\n")
    if pair:
        print(
            f"[speed] the same 4-episode task twice at once on 2 workers vs once on 1 worker ("
            f"machine level, no scheduling): {float(np.mean(pair)):.2f}x (rounds {min(pair):.2f}-"
            f"{max(pair):.2f})"
        )
    return out


# ---------------------------------------------------------------- persistence
def bench_persistence(pop: int, iters: int, n_var: int = 7) -> dict:
    import optuna
    from pymoo.problems import get_problem

    from tuners.problem import PymooTaskProblem
    from tuners.run import tune

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    out: dict = {"pop": pop, "iters": iters, "n_var": n_var, "loadavg": _load()}
    with tempfile.TemporaryDirectory() as tmp:
        stores = (
            ("memory", None),
            ("sqlite", f"sqlite:///{tmp}/bench.db"),
            ("journal", f"journal:{tmp}/bench.log"),
        )
        for label, storage in stores:
            prob = PymooTaskProblem(get_problem("zdt1", n_var=n_var))
            t0 = time.perf_counter()
            r = tune(prob, "mowoa", pop, iters, backend="serial", storage=storage, study=label)
            wall = time.perf_counter() - t0
            st = r.stats
            out[label] = {
                "evaluations": st.run,
                "store_ms_per_eval": 1e3 * st.store_time_s / max(st.run, 1),
                "checkpoint_ms_per_gen": 1e3 * st.checkpoint_time_s / iters,
                "run_wall_s": wall,
            }
            print(
                f"[persistence] {label:6s}: {n_var} parameters, {st.run} evaluations, "
                f"{out[label]['store_ms_per_eval']:.1f} ms per stored evaluation, "
                f"{out[label]['checkpoint_ms_per_gen']:.1f} ms per checkpoint (generation), "
                f"run {wall:.1f} s"
            )
    return out


# ------------------------------------------------------------------- storage
def bench_storage(env_id: str, rounds: int, n: int = 40) -> dict:
    """Driver time of ``StudyStore.record`` per trial, SQLite and journal in turn."""
    import optuna

    from tuners.problem import EnvTuningProblem
    from tuners.storage import StudyStore

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    prob = EnvTuningProblem(env_id)
    rng = np.random.default_rng(0)
    cols = [*prob.objective_columns, *[c for c, _ in prob.constraints]]
    out: dict = {"env": env_id, "trials_per_round": n, "loadavg_start": _load()}
    with tempfile.TemporaryDirectory() as tmp:
        cfg = {"fingerprint": prob.fingerprint_hash()}
        stores = {
            "sqlite": StudyStore(f"sqlite:///{tmp}/s.db", "s", prob, cfg),
            "journal": StudyStore(f"journal:{tmp}/s.log", "s", prob, cfg),
        }
        times: dict[str, list] = {k: [] for k in stores}
        try:
            for rnd in range(rounds):
                for name in stores if rnd % 2 == 0 else list(stores)[::-1]:
                    st = stores[name]
                    X = rng.uniform(-1, 1, (n, prob.n_var))
                    outs = [
                        {"F": rng.random(prob.n_obj).tolist(), "G": [-0.1],
                         "metrics": {c: [float(rng.random())] for c in cols},
                         "wall_time_s": 0.05, "worker": "bench:0"}
                        for _ in range(n)
                    ]  # fmt: skip
                    c0, w0 = time.process_time(), time.perf_counter()
                    st.hold()  # as Evaluations does per batch
                    for i, x in enumerate(X):
                        st.record(prob, prob.key(x), x, outs[i], rnd, i)
                    st.flush()
                    cpu, wall = time.process_time() - c0, time.perf_counter() - w0
                    times[name].append((1e3 * cpu / n, 1e3 * wall / n))
        finally:
            for st in stores.values():
                st.close()
    out["loadavg_end"] = _load()
    print(f"\nstorage per trial ({env_id} outcome, {n} trials x {rounds} rounds, "
          f"load {out['loadavg_start']} -> {out['loadavg_end']})\n")  # fmt: skip
    print("| storage | CPU ms/trial (median) | wall ms/trial (median) | per round (CPU) |")
    print("|---|---|---|---|")
    for name, t in times.items():
        cpu = [a for a, _ in t]
        wall = [b for _, b in t]
        out[name] = {"cpu_ms": cpu, "wall_ms": wall}
        print(f"| {name} | {np.median(cpu):.2f} | {np.median(wall):.2f} | "
              f"{', '.join(f'{v:.2f}' for v in cpu)} |")  # fmt: skip
    ratio = np.median(np.array(out["sqlite"]["cpu_ms"]) / np.array(out["journal"]["cpu_ms"]))
    out["cpu_ratio_sqlite_over_journal"] = float(ratio)
    print(f"\nmedian CPU ratio sqlite / journal per round: {ratio:.1f}")
    return out


# ------------------------------------------------------------------ lockstep
def bench_lockstep(
    env_id: str, pop: int, iters: int, workers: int, seeds, runs, rounds: int = 1
) -> dict:
    import optuna

    from tuners.run import tune

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    out: dict = {"env": env_id, "pop": pop, "iters": iters, "workers": workers,
                 "seeds": list(seeds), "loadavg_start": _load(), "runs": []}  # fmt: skip
    with tempfile.TemporaryDirectory() as tmp:
        for rnd in range(rounds):
            for k, run in enumerate(runs if rnd % 2 == 0 else runs[::-1]):
                backend, storage = run.split(":")
                stem = f"{tmp}/r{rnd}-{k}"
                url = {"sqlite": f"sqlite:///{stem}.db", "journal": f"journal:{stem}.log"}
                url = url.get(storage)
                t0 = time.perf_counter()
                r = tune(env_id, "mowoa", pop, iters, backend=backend, workers=workers,
                         storage=url, study="ls", seeds=list(seeds), seed=1)  # fmt: skip
                wall = time.perf_counter() - t0
                st = r.stats
                stored = st.run + st.failed_attempts
                out["runs"].append(
                    {
                        "round": rnd,
                        "run": run,
                        "wall_s": wall,
                        "evaluations": st.run,
                        "evals_per_s": st.run / wall,
                        "store_ms_per_trial": 1e3 * st.store_time_s / max(stored, 1),
                        "checkpoint_ms_per_gen": 1e3 * st.checkpoint_time_s / iters,
                        "selected_key": None if r.selected is None else r.selected["key"],
                        "selected": r.selected_params,
                    }
                )
                print(f"[lockstep] round {rnd} {run}: {wall:.1f} s, {st.run} evaluations",
                      flush=True)  # fmt: skip
    out["loadavg_end"] = _load()
    keys = {r["selected_key"] for r in out["runs"]}
    out["same_selected"] = len(keys) == 1
    print(
        f"\n{env_id}: MOWOA {pop} x {iters}, {workers} workers, scenario seeds {list(seeds)}; "
        f"load {out['loadavg_start']} -> {out['loadavg_end']}\n"
    )
    print("| round | backend:storage | wall [s] | evaluations | evals/s | storage [ms/trial] "
          "| checkpoint [ms/gen] | selected point |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|")
    for r in out["runs"]:
        sel = ", ".join(f"{n}={v:.4g}" for n, v in (r["selected"] or {}).items())
        print(
            f"| {r['round']} | {r['run']} | {r['wall_s']:.1f} | {r['evaluations']} | "
            f"{r['evals_per_s']:.1f} | {r['store_ms_per_trial']:.2f} | "
            f"{r['checkpoint_ms_per_gen']:.1f} | {r['selected_key']} ({sel}) |"
        )
    print(f"\nsame selected point in every run: {'yes' if out['same_selected'] else 'NO'}")
    return out


# ---------------------------------------------------------------- convergence
def _shifted_zdt1():
    from pymoo.core.problem import Problem
    from pymoo.problems import get_problem

    class ShiftedZDT1(Problem):
        """ZDT1 with the Pareto set at x_2..30 = 0.35 instead of on the lower bound."""

        def __init__(self) -> None:
            self.base = get_problem("zdt1")
            super().__init__(n_var=30, n_obj=2, xl=0.0, xu=1.0)

        def _evaluate(self, X, out, *args, **kwargs):
            Y = X.copy()
            Y[:, 1:] = np.abs(X[:, 1:] - 0.35) / 0.65
            out["F"] = self.base.evaluate(Y)

        def _calc_pareto_front(self, *args, **kwargs):
            return self.base.pareto_front()

    return ShiftedZDT1()


def bench_convergence(seeds: list[int], pop: int, gens: int) -> dict:
    from pymoo.algorithms.moo.nsga2 import NSGA2
    from pymoo.indicators.hv import HV
    from pymoo.indicators.igd import IGD
    from pymoo.optimize import minimize
    from pymoo.problems import get_problem

    from tuners.mowoa import MOWOA
    from tuners.pso import MOPSO

    problems = {"zdt1": get_problem("zdt1"), "zdt2": get_problem("zdt2")}
    problems["zdt1-shifted"] = _shifted_zdt1()
    algos = {
        "mowoa": lambda: MOWOA(pop_size=pop),
        "mopso": lambda: MOPSO(pop_size=pop),
        "nsga2": lambda: NSGA2(pop_size=pop),
    }
    hv = HV(ref_point=[1.1, 1.1])
    out: dict = {"pop": pop, "generations": gens, "seeds": seeds}
    for pname, p in problems.items():
        igd = IGD(p.pareto_front())
        for aname, make in algos.items():
            vals = [minimize(p, make(), ("n_gen", gens), seed=s).F for s in seeds]
            h = [float(hv(F)) for F in vals]
            d = [float(igd(F)) for F in vals]
            out[f"{pname}/{aname}"] = {"hv": h, "igd": d}
            print(
                f"[convergence] {pname:13s} {aname:6s} HV mean {np.mean(h):.4f} "
                f"(min {np.min(h):.4f})  IGD mean {np.mean(d):.4f}   "
                f"[{pop} x {gens} evaluations, seeds {seeds}]"
            )
    return out


# -------------------------------------------------------------------- tune004
def bench_tune004(env_id: str, pop: int, iters: int, workers: int, seeds, holdout, db) -> dict:
    import optuna

    from tuners.run import tune

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study = f"bench-{env_id.split('/')[-1]}-mowoa-{pop}x{iters}-tol-{{code}}"
    t0 = time.perf_counter()
    r = tune(
        env_id,
        "mowoa",
        pop,
        iters,
        workers=workers,
        backend="processes",
        storage=db,
        study=study,
        resume=True,
        seeds=seeds,
        config=DISTURBANCE,
        constraints=CONSTRAINTS,
        f_bounds=TOLERANCES,
        progress=True,
    )
    wall = time.perf_counter() - t0
    ho = r.compare_on_seeds(holdout)
    d, s = ho.set_index("point").loc["defaults"], ho.set_index("point").loc["selected"]
    change = {o: 100.0 * (s[o] - d[o]) / abs(d[o]) if d[o] else float("nan") for o in r.objectives}
    out = {
        "env": env_id,
        "pop": pop,
        "iters": iters,
        "seeds": list(seeds),
        "holdout_seeds": list(holdout),
        "evaluations_run": r.stats.run,
        "cached": r.stats.cached,
        "wall_s": wall,
        "pareto_size": len(r.pareto),
        "selected_params": r.selected_params,
        "tchebycheff_defaults": float(d["tchebycheff"]),
        "tchebycheff_selected": float(s["tchebycheff"]),
        "objective_change_pct": change,
        "storage": db,
        "study": r.study_name,
        "tolerances": TOLERANCES,
        "constraints": CONSTRAINTS,
    }
    print(f"[tune004] {env_id}: {r.stats.run} evaluations in {wall:.0f} s, Pareto {len(r.pareto)}")
    print(ho.to_string(index=False))
    print(
        f"[tune004] held-out seeds {list(holdout)}: Tchebycheff defaults "
        f"{out['tchebycheff_defaults']:.4f} -> selected {out['tchebycheff_selected']:.4f}; "
        + ", ".join(f"{k} {v:+.1f} %" for k, v in change.items())
    )
    return out


# ----------------------------------------------------------------- compare004
def bench_compare004(env_id: str, pop: int, iters: int, workers: int, seeds, train_seeds, db):
    """MOWOA vs pymoo's NSGA-II and MOEA/D on the 004 env at equal budget (hypervolume).

    Each algorithm runs ``pop x iters`` evaluations per algorithm seed on the same
    disturbed training seeds. Hypervolume of each run's feasible non-dominated set is
    measured in objectives normalised by the ideal and nadir of the union of all runs'
    feasible points, with reference point 1.1 in every objective (larger is better).
    """
    import optuna
    from pymoo.indicators.hv import HV

    from tuners.mowoa import nondominated
    from tuners.run import tune

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    fronts: dict[tuple[str, int], np.ndarray] = {}
    walls: dict[tuple[str, int], float] = {}
    objs = None
    for algo in ("mowoa", "nsga2", "moead"):
        for s in seeds:
            t0 = time.perf_counter()
            r = tune(
                env_id,
                algo,
                pop,
                iters,
                workers=workers,
                storage=db,
                study=f"compare004-{algo}-{pop}x{iters}-s{s}-{{code}}",
                resume=True,
                seeds=train_seeds,
                config=DISTURBANCE,
                constraints=CONSTRAINTS,
                f_bounds=TOLERANCES,
                seed=s,
            )
            walls[(algo, s)] = time.perf_counter() - t0
            objs = r.objectives
            df = r.evaluations
            F = df.loc[df["feasible"], list(objs)].to_numpy(float)
            fronts[(algo, s)] = F[nondominated(F)] if len(F) else F
            print(
                f"[compare004] {algo} seed {s}: {len(df)} evaluations, "
                f"{len(fronts[(algo, s)])} non-dominated, {walls[(algo, s)]:.0f} s"
            )
    allF = np.vstack([F for F in fronts.values() if len(F)])
    lo, hi = allF.min(axis=0), allF.max(axis=0)
    span = np.where(hi > lo, hi - lo, 1.0)
    hv = HV(ref_point=np.full(allF.shape[1], 1.1))
    out: dict = {
        "env": env_id,
        "pop": pop,
        "iters": iters,
        "seeds": list(seeds),
        "objectives": list(objs),
        "runs": {},
    }
    for algo in ("mowoa", "nsga2", "moead"):
        vals = [
            float(hv((fronts[(algo, s)] - lo) / span)) if len(fronts[(algo, s)]) else 0.0
            for s in seeds
        ]
        out["runs"][algo] = {"hv": vals, "wall_s": [walls[(algo, s)] for s in seeds]}
        print(
            f"[compare004] {algo:6s} HV mean {np.mean(vals):.4f} +- {np.std(vals):.4f} "
            f"({', '.join(f'{v:.4f}' for v in vals)})  [{pop} x {iters}, seeds {list(seeds)}]"
        )
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "part",
        choices=[
            "speed",
            "persistence",
            "storage",
            "convergence",
            "tune004",
            "compare004",
            "lockstep",
            "all",
        ],  # fmt: skip
    )
    ap.add_argument("--env", default="TrainEnvs/Urban004FuzzyPID-v0")
    ap.add_argument("--n", type=int, default=12, help="evaluations of the speed benchmark")
    ap.add_argument("--rounds", type=int, default=4, help="alternating rounds of `speed`")
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 2)
    ap.add_argument("--n-var", type=int, default=7, help="variables of the persistence problem")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    ap.add_argument("--env004", default=None)
    ap.add_argument("--pop004", type=int, default=20)
    ap.add_argument("--iters004", type=int, default=10)
    ap.add_argument("--train-seeds", type=int, nargs="+", default=[0, 1])
    ap.add_argument("--holdout", type=int, nargs="+", default=[100, 101, 102, 103, 104])
    ap.add_argument("--db", default="sqlite:///out/bench_tuners.db")
    ap.add_argument("--json", default=None, help="write the results to this JSON file")
    ap.add_argument("--env-ls", default="TrainEnvs/Urban004-v0", help="env of `lockstep`")
    ap.add_argument("--ls-seeds", type=int, nargs="+", default=[0], help="its scenario seeds")
    ap.add_argument(
        "--ls-runs",
        nargs="+",
        default=["processes:sqlite", "lockstep:sqlite", "lockstep:journal"],
        help="BACKEND:STORAGE per run of `lockstep` (storage sqlite, journal or memory)",
    )
    ap.add_argument("--ls-rounds", type=int, default=1, help="rounds of `lockstep`")
    ap.add_argument("--quick", action="store_true", help="`lockstep` at 10 x 4 instead of 40 x 100")
    ap.add_argument(
        "--ls-budget", type=int, nargs=2, default=None, metavar=("POP", "ITERS"),
        help="`lockstep` at this population and number of generations",
    )  # fmt: skip
    args = ap.parse_args()
    res: dict = {}
    if args.part in ("speed", "all"):
        res["speed"] = bench_speed(args.env, args.n, args.workers, args.rounds)
    if args.part in ("persistence", "all"):
        res["persistence"] = bench_persistence(20, 10, args.n_var)
    if args.part in ("storage", "all"):
        res["storage"] = bench_storage(args.env_ls, args.rounds)
    if args.part in ("lockstep", "all"):
        pop, iters = args.ls_budget or ((10, 4) if args.quick else (40, 100))
        res["lockstep"] = bench_lockstep(
            args.env_ls, pop, iters, args.workers, args.ls_seeds, args.ls_runs, args.ls_rounds
        )
    if args.part in ("convergence", "all"):
        res["convergence"] = bench_convergence(args.seeds, 40, 100)
    if args.part in ("tune004", "all"):
        import train_envs  # noqa: F401
        from train_envs.envs import registered_ids

        env004 = args.env004 or (
            "TrainEnvs/Urban004-v0"
            if "TrainEnvs/Urban004-v0" in registered_ids()
            else "TrainEnvs/Urban004FuzzyPID-v0"
        )
        if args.db.startswith("sqlite:///"):
            Path(args.db[len("sqlite:///") :]).parent.mkdir(parents=True, exist_ok=True)
        res["tune004"] = bench_tune004(
            env004,
            args.pop004,
            args.iters004,
            args.workers,
            args.train_seeds,
            args.holdout,
            args.db,
        )
    if args.part == "compare004":
        import train_envs  # noqa: F401

        if args.db.startswith("sqlite:///"):
            Path(args.db[len("sqlite:///") :]).parent.mkdir(parents=True, exist_ok=True)
        res["compare004"] = bench_compare004(
            args.env004 or "TrainEnvs/Urban004-v0",
            args.pop004,
            args.iters004,
            args.workers,
            args.seeds[:3],
            args.train_seeds,
            args.db,
        )
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=2, default=str))


if __name__ == "__main__":
    main()
