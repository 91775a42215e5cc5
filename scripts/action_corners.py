"""Whole episodes of registered env ids at the corners of their action boxes.

Prints one line per corner with its safety metrics (``docs/design/supervision.md``)
and whether the corner was flagged; corners as in
``tests/faults/test_env_action_corners.py`` (all ``2^n``, 64 sampled where n > 6)::

    python scripts/action_corners.py TrainEnvs/Stopping001PID-v0 TrainEnvs/Urban004-v0
"""

from __future__ import annotations

import argparse
import json

import gymnasium as gym
import numpy as np

import train_envs  # noqa: F401  (registers the ids)
from train_envs.envs import registered_ids
from train_envs.envs.action import action_corners

KEYS = (
    "max_overspeed_mps",
    "atp_interventions",
    "overrun_m",
    "max_coupler_excess",
    "max_coupler_deformation_m",
    "safety_cost",
    "stop_error_m",
    "max_speed_error_mps",
)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("ids", nargs="*", help="env ids (default: every registered id)")
    ap.add_argument("--limit", type=int, default=64, help="corners per id at most")
    args = ap.parse_args()
    for env_id in args.ids or registered_ids():
        env = gym.make(env_id)
        n = env.action_space.shape[0]
        for a in action_corners(n, np.random.default_rng(0), args.limit):
            env.reset(seed=0)
            cost, done = 0.0, False
            while not done:
                _, _, term, trunc, info = env.step(a)
                cost += info["cost"]
                done = term or trunc
            m = info["episode_metrics"]
            row = {k: round(float(m[k]), 4) for k in KEYS if k in m}
            print(
                json.dumps(
                    {"id": env_id, "corner": a.astype(int).tolist(), "cost": round(cost, 4), **row}
                ),
                flush=True,
            )
        env.close()


if __name__ == "__main__":
    main()
