"""The env contract pages in docs/envs/ are what the code generates, and say what it does."""

from __future__ import annotations

import re

import gymnasium as gym
import numpy as np

import train_envs  # noqa: F401  (registers the ids)
from train_envs.envs.contract import DEFAULT_OUT, generated_pages, page_name, write_pages
from train_envs.envs.registration import registered_ids


def test_committed_pages_equal_the_generated_ones():
    stale = write_pages(DEFAULT_OUT, check=True)
    assert stale == [], f"run `python -m train_envs.envs.contract` to refresh: {stale}"


def _table(text: str, heading: str) -> list[list[str]]:
    section = text.split(f"## {heading}\n", 1)[1].split("\n## ", 1)[0]
    rows = [ln for ln in section.splitlines() if ln.startswith("| ") and not ln.startswith("| i ")]
    return [[c.strip() for c in re.split(r"(?<!\\)\|", r)[1:-1]] for r in rows]


def test_pages_define_every_feature_and_the_default_action_sets_the_defaults():
    pages = generated_pages()
    assert set(pages) == {page_name(i) for i in registered_ids()} | {"README.md"}
    for env_id in ("TrainEnvs/Urban004-v0", "TrainEnvs/Cruise003-v0"):
        text = pages[page_name(env_id)]
        env = gym.make(env_id)
        base = env.unwrapped
        features = _table(text, "Observation")
        assert [r[1].strip("`") for r in features] == base.observation_names
        assert all(r[2] for r in features), "a feature without a definition"
        action = _table(text, "Action")
        assert [r[1].strip("`") for r in action] == [p.name for p in base.param_specs]
        a0 = np.array([float(r[-1]) for r in action])
        env.reset(seed=0)
        _, _, _, _, info = env.step(a0)
        defaults = base.default_params()
        for name, value in info["params"].items():
            assert np.isclose(value, defaults[name], rtol=1e-5), name
        objectives = _table(text, "Reward")
        assert all(r[1].strip("`") for r in objectives if r[0].startswith("`"))
        env.close()
