"""Paper 004 (MPC-MOWOA): Fuzzy-PID, conventional DMC, MPC-PSO and MPC-MOWOA side by side.

This module holds the setting (env ids, disturbance, objectives with 004's published
changes, constraints, tolerance scale) and :func:`compare_paper004`, the held-out
table of four drivers:

* ``fuzzy_pid``: the Fuzzy-PID reference (``TrainEnvs/Urban004FuzzyPID-v0``, defaults);
* ``dmc_default``: DMC with its default parameters (004's "conventional MPC");
* ``mpc_pso``, ``mpc_mowoa``: DMC with each tuner's selected parameters.

The tuning lives with the tuners: :func:`tuners.paper004.reproduce_paper004` (registered
as the ``paper004`` entry point of ``train_envs.reproduce``, so ``train-envs reproduce
paper004`` runs it) tunes the seven DMC parameters of 004 §3.4 with PSO and MOWOA on the
same budget and passes their picks here. ``reproduce_paper004`` is still importable from
this module: it is looked up through that entry point. Write-up: ``docs/papers/paper004.md``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd

ENV_DMC = "TrainEnvs/Urban004-v0"
ENV_FUZZY_PID = "TrainEnvs/Urban004FuzzyPID-v0"
#: disturbed runs: load ±, bounded random resistance disturbance (as in the main job)
CONFIG = {"disturbance": {"mass_factor_range": [0.9, 1.15], "random_bound_mps2": 0.03}}
#: 004's five objectives (our metric columns) and the paper's change vs Fuzzy-PID [%]
OBJECTIVES = {
    "energy_kWh": ("energy", -5.9),
    "ITAE_m_s": ("ITAE", -39.6),
    "time_error_s": ("time error", -33.2),
    "E_p_m": ("distance error", -12.4),
    "comfort_mean_abs_jerk_mps3": ("comfort (mean |jerk|)", 7.1),
}
#: tolerance scale of the Tchebycheff pick (ITAE, |stop|, time, jerk, energy; as the demo)
F_BOUNDS = ([0.0, 0.0, 0.0, 0.0, 0.0], [1000.0, 0.5, 1.0, 0.1, 2.5])
CONSTRAINTS = {"max_overspeed_mps": 0.0, "time_error_s": 5.0, "E_p_m": 2.0}
#: seeds of the held-out evaluation
HOLDOUT_SEEDS = (100, 101, 102, 103, 104)


def compare_paper004(
    tuned: Mapping[str, Mapping[str, float]],
    holdout_seeds: Sequence[int] = HOLDOUT_SEEDS,
) -> pd.DataFrame:
    """Held-out means of 004's objectives per driver and their change vs Fuzzy-PID [%].

    ``tuned`` maps a driver name (``"mpc_pso"``, ``"mpc_mowoa"``) to DMC parameter
    values; ``fuzzy_pid`` and ``dmc_default`` are added in front. One row per objective
    with the paper's change of MPC-MOWOA beside ours; ``attrs`` holds the held-out seeds
    and the tuned parameters.
    """
    from train_envs.envs import evaluate

    drivers = {
        "fuzzy_pid": (ENV_FUZZY_PID, {}),
        "dmc_default": (ENV_DMC, {}),
        **{name: (ENV_DMC, params) for name, params in tuned.items()},
    }
    means = {}
    for name, (env_id, params) in drivers.items():
        df = evaluate(env_id, params, seeds=list(holdout_seeds), config=CONFIG, label=name)
        means[name] = {c: float(np.mean(df[c])) for c in OBJECTIVES}
    rows = []
    base = means["fuzzy_pid"]
    for col, (label, paper) in OBJECTIVES.items():
        row: dict[str, Any] = {"objective": label, "column": col}
        for name in drivers:
            row[name] = means[name][col]
        for name in drivers:
            if name != "fuzzy_pid":
                # a change relative to a zero reference (Fuzzy-PID on time) is not defined
                ref = base[col]
                rel = 100.0 * (means[name][col] - ref) / ref if abs(ref) > 1e-9 else np.nan
                row[f"{name}_vs_fpid_pct"] = rel
        row["paper_mowoa_vs_fpid_pct"] = paper
        rows.append(row)
    out = pd.DataFrame(rows)
    out.attrs["holdout_seeds"] = list(holdout_seeds)
    out.attrs["tuned_params"] = dict(tuned)
    return out


def __getattr__(name: str) -> Any:
    # the tuning half lives above train_envs; reach it through its entry point
    if name == "reproduce_paper004":
        from train_envs.reproduce import get_reproduction

        return get_reproduction("paper004")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
