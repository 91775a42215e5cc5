"""Per-step cost of paper 003's fuzzy LMI controller, and the re-solve trade-off.

Run: ``python benchmarks/bench_fuzzy_mpc.py [--full]``.

On ``paper003_cruise`` (8 cars, per-car forces, second-order actuators) with 003's step
reference, shortened to 300 s (150 → 200 km/h at 100 s), each control step's
``compute`` is timed. Reported per configuration: median wall time of a step, of a step
without an LMI solve, of a step with one (cvxpy parameter update + Clarabel + gain
extraction), Clarabel's own median solve time, the number of solves, and the closed-loop
quality (mean |speed error|, max coupler displacement, traction energy) so that the
caching trade-off can be judged:

* ``lmi_period=1``: Kothare's original scheme, the LMI re-solved every step;
* ``lmi_period=10``: every 5 s plus the event triggers;
* ``lmi_period=0`` (default): event triggers only (state leaves / shrinks inside the
  cached invariant ellipsoid, v_r moved, weights changed).

The plain MPC on the same problem is paper 000's SEMPC (``MultiCarMPC``, OSQP, N = 3,
full 16-state 8-car model, no actuator model), run on the same scenario and, for a
quality reference, on the scenario without actuator dynamics (its own assumption: with
the 2 rad/s actuators its aggressive coupler weights destabilise the couplers); the last
column is the ratio of each median step to its median step. ``--full`` also times one
LMI solve of the full-order design model (all 7 coupler modes: 15 states, 8 inputs),
which is why the controller uses the modal reduction (tens of seconds per solve).
"""

from __future__ import annotations

import sys
import time
import warnings

import numpy as np

from train_envs.controllers.fuzzy_mpc import FuzzyMPCController
from train_envs.controllers.train_mpc import MultiCarMPC
from train_envs.plants.multi_car import ActuatorParams
from train_envs.reproduce.paper003 import paper003_step_scenario
from train_envs.simulation import ClosedLoop

T_BENCH_S = 300.0


def bench(ctrl, sc) -> dict[str, float]:
    loop = ClosedLoop(sc, ctrl)
    loop.reset(seed=0)
    walls, solve_walls, idle_walls, solver = [], [], [], []
    while not loop.done:
        obs = loop.observe()
        t0 = time.perf_counter()
        u, info = ctrl.compute(obs)
        w = time.perf_counter() - t0
        walls.append(w)
        if info.get("triggered", 0.0):
            solve_walls.append(w)
            solver.append(info["solve_time_s"])
        else:
            idle_walls.append(w)
            if "iterations" in info and "triggered" not in info:  # OSQP controllers
                solver.append(info["solve_time_s"])
        loop.step(u)
    m = loop.metrics()

    def med(x: list[float]) -> float:
        return 1e3 * float(np.median(x)) if x else float("nan")

    return {
        "steps": len(walls),
        "wall_ms": med(walls),
        "idle_ms": med(idle_walls),
        "solve_wall_ms": med(solve_walls),
        "solver_ms": med(solver),
        "solves": len(solve_walls),
        "total_s": float(np.sum(walls)),
        "E_v": m["E_v_mps"],
        "cpl_cm": 100 * m["max_coupler_deformation_m"],
        "energy_kWh": m["energy_kWh"],
    }


def full_order_solve_s() -> float:
    sc = paper003_step_scenario()
    c = FuzzyMPCController(sc, n_modes=None)
    c.reset(sc.control_context())
    x = np.zeros(c._model.nx)
    x[c._model.nx // 2 :] = -1.0
    c.solve_lmi(x, 50.0, np.full(8, 30.0))  # first call compiles
    sol = c.solve_lmi(x, 50.0, np.full(8, 30.0))
    return sol.wall_s


def main() -> None:
    warnings.filterwarnings("ignore")
    sc = paper003_step_scenario().with_overrides(t_max_s=T_BENCH_S)
    kw = {"feedforward": "resistance"}
    cases = [
        ("sempc (OSQP, N=3)", MultiCarMPC(sc, Np=3)),
        ("sempc, no actuator dynamics", MultiCarMPC(sc, Np=3)),
        ("fuzzy LMI, lmi_period=1", FuzzyMPCController(sc, lmi_period=1, **kw)),
        ("fuzzy LMI, lmi_period=10", FuzzyMPCController(sc, lmi_period=10, **kw)),
        ("fuzzy LMI, events only", FuzzyMPCController(sc, **kw)),
    ]
    # warm the shared cvxpy problem (its one-off compilation is not a step cost)
    FuzzyMPCController(sc).reset(sc.control_context())
    warm = FuzzyMPCController(sc, **kw)
    warm.reset(sc.control_context())
    warm.solve_lmi(np.ones(warm._model.nx), 50.0, np.full(8, 30.0))
    no_act = sc.with_overrides(actuator=ActuatorParams(order=0))
    res = [(label, bench(c, no_act if "no actuator" in label else sc)) for label, c in cases]
    base = res[0][1]["wall_ms"]
    print(
        "| controller | steps | LMI solves | median step [ms] | step w/o solve [ms] | "
        "step with solve [ms] | solver [ms] | total [s] | mean abs(e_v) [m/s] | "
        "max coupler [cm] | energy [kWh] | step / sempc step |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for label, r in res:
        print(
            f"| {label} | {r['steps']} | {r['solves']} | {r['wall_ms']:.2f} | "
            f"{r['idle_ms']:.2f} | {r['solve_wall_ms']:.1f} | {r['solver_ms']:.2f} | "
            f"{r['total_s']:.1f} | {r['E_v']:.3f} | {r['cpl_cm']:.2f} | "
            f"{r['energy_kWh']:.1f} | {r['wall_ms'] / base:.3g} |"
        )
    if "--full" in sys.argv:
        print(
            f"\nfull-order LMI (15 states, 8 inputs, 2 rules): {full_order_solve_s():.1f} s/solve"
        )


if __name__ == "__main__":
    main()
