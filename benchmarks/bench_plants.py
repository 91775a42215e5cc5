"""Plant throughput: simulation sub-steps and control steps per second.

Run: ``python benchmarks/bench_plants.py`` (not a test; numbers go in the README and
the closing notes). Measures the single-point train of paper 001 (lag + dead time,
0.01 s sub-steps, 0.2 s control period) and the 6-car train of paper 000 (couplers
k = 1e7 N/m, 0.02 s sub-steps, 0.2 s control period) on their scenario tracks.
"""

from __future__ import annotations

import statistics
import time

import numpy as np

from train_envs.scenarios import build_plant, get_scenario


def bench(name: str, n_ctrl: int = 100, repeats: int = 7) -> dict[str, float]:
    sc = get_scenario(name)
    rng = np.random.default_rng(0)
    plant = build_plant(sc, rng)
    n_in = sc.n_cars if sc.input_mode == "per_car" else 1
    # a command that roughly holds the speed, so the train keeps moving
    hold = sc.train.resistance_N(20.0) + sc.train.mass_kg * 9.81e-3 * 15.0
    u = np.full(n_in, hold / n_in) if n_in > 1 else hold
    sub = int(round(sc.dt_ctrl_s / sc.dt_sim_s))
    times = []
    for _ in range(repeats):
        plant.reset(sc.s0_m, 20.0, u0=u, rng=rng)
        t0 = time.perf_counter()
        for _ in range(n_ctrl):
            plant.step(u, sc.dt_ctrl_s)
        times.append(time.perf_counter() - t0)
    med = statistics.median(times)
    return {
        "scenario": name,
        "cars": plant.n,
        "substeps_per_ctrl": sub,
        "ctrl_steps_per_s": n_ctrl / med,
        "substeps_per_s": n_ctrl * sub / med,
        "us_per_substep": 1e6 * med / (n_ctrl * sub),
    }


def main() -> None:
    rows = [bench("paper001_stopping"), bench("paper000_single_section")]
    print("| scenario | cars | sub-steps/ctrl | control steps/s | sub-steps/s | µs/sub-step |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['scenario']} | {r['cars']} | {r['substeps_per_ctrl']} | "
            f"{r['ctrl_steps_per_s']:.0f} | {r['substeps_per_s']:.0f} | {r['us_per_substep']:.1f} |"
        )


if __name__ == "__main__":
    main()
