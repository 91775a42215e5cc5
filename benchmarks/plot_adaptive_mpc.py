"""Figure and per-step cost: paper 002's adaptive MPC against the non-adaptive MPC.

Runs ``adaptive_mpc`` and ``mpc002`` on ``paper002_cruise`` with the same disturbance
seed (the time-varying Davis coefficients are drawn from it), saves the 002 Fig. 7/9/10
style figure (estimation error, resistance estimate, speed error, coupler force) and
prints, for each controller, the run's metrics and the per-step cost: median wall time
of one control step (controller + plant), of the controller alone, and OSQP's own
median solve time.

Usage::

    python benchmarks/plot_adaptive_mpc.py [--seed 0] [--t-max 1200] \
        [--out out/paper002_adaptive.png]

Not a test.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd

from train_envs.plots_papers import paper002_figure
from train_envs.reproduce.paper002 import CONTROLLERS, run_paper002, summarise_run


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--t-max", type=float, default=None, help="episode length [s] (1200)")
    ap.add_argument("--out", default="out/paper002_adaptive.png")
    args = ap.parse_args(argv)
    runs = {c: run_paper002(c, args.seed, t_max_s=args.t_max) for c in CONTROLLERS}
    rows = [{"controller": c, **summarise_run(df)} for c, df in runs.items()]
    pd.set_option("display.width", 200)
    table = pd.DataFrame(rows).set_index("controller").T
    print(table.round(4).to_string())
    fig = paper002_figure(runs, title=f"paper 002, seed {args.seed}: adaptive vs non-adaptive")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=120)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
