"""Every registered id at the corners of its action box: whatever a corner does, no
safety violation goes unflagged.

With ``TRAIN_ENVS_ALL_CORNERS=1``: all ``2^n`` corners (64 sampled where ``n > 6``);
by default ``SAMPLED`` corners per id (all −1, all +1 and seeded draws), since the
fuzzy MPC's corners cost seconds each. Each corner runs a short episode (the first
``STEPS`` env steps); with ``TRAIN_ENVS_CORNER_EPISODES=1`` every corner runs its whole
episode (the acceptance run: about an hour on 2 cores with every corner of every id;
``scripts/action_corners.py`` prints the same runs' safety metrics). A violation is
detected here from the run's own columns, independently of the runner's safety
columns: a speed beyond the limit plus the ATP margin, a coupler beyond the train's
limits, a position beyond the stopping window.
"""

from __future__ import annotations

import os

import gymnasium as gym
import numpy as np
import pytest

import train_envs  # noqa: F401  (registers the ids)
from train_envs.envs import registered_ids
from train_envs.envs.action import action_corners

STEPS = 3
MAX_CORNERS = 64
SAMPLED = 8
ALL = os.environ.get("TRAIN_ENVS_ALL_CORNERS") == "1"
EPISODES = os.environ.get("TRAIN_ENVS_CORNER_EPISODES") == "1"


def unsafe(env) -> dict[str, bool]:
    """The run's violations, read from its plain columns (not the safety columns)."""
    base = env.unwrapped
    df = base.loop.dataframe()
    sc, sup = base.scenario, base.loop.supervision
    rows = df.iloc[:-1]  # the control periods (the last row is the final state)
    out = {"overspeed": bool((rows.v_mps > rows.v_limit_mps + sup.margin_mps).any())}
    cp = sc.train.coupler
    if "coupler_def_max_m" in df:
        out["coupler"] = bool(
            (rows.coupler_def_max_m.abs() > cp.max_deformation_m).any()
            or (rows.coupler_force_max_N.abs() > cp.max_force_N).any()
        )
    if sc.s_stop_m is not None:
        out["overrun"] = bool((df.s_m > sc.s_stop_m + sc.stop_window()).any())
    return out


def test_corners_are_all_or_a_sample_with_both_extremes():
    rng = np.random.default_rng(0)
    assert len({tuple(c) for c in action_corners(3, rng)}) == 8
    sample = action_corners(7, rng, 64)
    assert len({tuple(c) for c in sample}) == 64
    assert np.all(sample[0] == -1.0) and np.all(sample[1] == 1.0)
    assert all(set(np.abs(c)) == {1.0} for c in sample)


@pytest.mark.parametrize("env_id", registered_ids())
def test_corner_violations_are_flagged(env_id):
    env = gym.make(env_id, config={} if EPISODES else {"max_episode_steps": STEPS})
    n = env.action_space.shape[0]
    for action in action_corners(n, np.random.default_rng(0), MAX_CORNERS if ALL else SAMPLED):
        env.reset(seed=0)
        total, violation, done = 0.0, 0.0, False
        while not done:
            obs, r, term, trunc, info = env.step(action)
            assert np.all(np.isfinite(obs)) and np.isfinite(r)
            assert info["cost"] >= 0.0
            total += info["cost"]
            violation += info["objectives"]["violation"]
            done = term or trunc
        m = info["episode_metrics"]
        assert total == pytest.approx(m["safety_cost"], rel=1e-9, abs=1e-12)
        found = unsafe(env)
        if any(found.values()):
            assert total > 0 and violation > 0, (env_id, action, found)
        if found["overspeed"]:
            assert m["atp_interventions"] >= 1, (env_id, action)
    env.close()
