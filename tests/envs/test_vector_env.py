"""The native vector env: Gymnasium's vector-env contract and B single envs' trajectories.

Gymnasium 1.4 ships no vector-env checker (``gymnasium.utils.env_checker`` checks single
envs), so the documented contract is tested here: spaces, reset/step shapes and dtypes,
next-step autoreset, seeding (``seed + i``), ``reset_mask``, the ``_key`` info masks.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode, VectorEnv

import train_envs  # noqa: F401 - registers the ids
from train_envs.envs.registration import VECTOR_ENTRY_POINT
from train_envs.envs.vector_env import TrainTuningVectorEnv

CFG = {"max_episode_steps": 6}
IDS = [
    "TrainEnvs/Urban004-v0",
    "TrainEnvs/Stopping001PID-v0",
    "TrainEnvs/Urban004FuzzyPID-v0",
    "TrainEnvs/Stopping001-v0",  # (no array law: each member on its own RSMPC)
    "TrainEnvs/Yizhuang-v0",  # (a section per episode: one runner per section drawn)
    # multi-car trains (each member on its own controller, the batched multi-car plant):
    "TrainEnvs/Section000-v0",  # (6 cars, one input per car, SEMPC)
    "TrainEnvs/Cruise002-v0",  # (4 cars, one whole-train input, adaptive MPC)
    "TrainEnvs/Cruise003-v0",  # (8 cars, actuator dynamics, fuzzy MPC; coupler costs)
]


def _make(env_id: str, n: int) -> VectorEnv:
    return gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point", config=CFG)


def _same_info(a, b) -> None:
    assert set(a) == set(b)
    for k, v in a.items():
        if isinstance(v, dict):
            _same_info(v, b[k])
        else:
            assert v == b[k] or (v != v and b[k] != b[k]), k


def _member_info(infos, i):
    out = {}
    for k, v in infos.items():
        if not k.startswith("_") and infos["_" + k][i]:
            out[k] = _member_info(v, i) if isinstance(v, dict) else v[i]
    return out


@pytest.mark.parametrize("env_id", IDS)
def test_vector_env_steps_as_single_envs_with_next_step_autoreset(env_id):
    _steps_as_single_envs(env_id, CFG, 3)


def test_vector_env_members_share_and_change_the_runners_of_their_sections():
    """Four members on two sections of a real line: members share a section's runner,
    move to the other one when a reset draws it, and step as single envs."""
    cfg = dict(CFG, real_line={"sections": [[3, 4], [4, 5]]})
    runners = _steps_as_single_envs("TrainEnvs/Yizhuang-v0", cfg, 4)
    assert max(runners) == 2 and min(runners) >= 1


@pytest.mark.parametrize(
    ("env_id", "episode", "steps", "what"),
    [
        # to the stop and past it (terminated, not truncated), the overrun cost
        ("TrainEnvs/Section000-v0", 200, 172, "terminated"),
        # coupler forces and deformations beyond the limits (the coupler cost)
        ("TrainEnvs/Cruise003-v0", 20, 25, "coupler"),
    ],
)
def test_multi_car_members_step_as_single_envs_through_their_episodes(env_id, episode, steps, what):
    """Multi-car members over longer episodes than the contract test's: the reward's
    coupler terms, the end of episode at the stop and the episode metrics, bit for bit."""
    stats: dict = {}
    _steps_as_single_envs(env_id, {"max_episode_steps": episode}, 3, steps, stats)
    assert stats["resets"] == 3
    if what == "terminated":
        assert stats["terminated"] == 3 and stats["truncated"] == 0
        assert stats["cost"]["overrun"] > 0.0
    else:
        assert stats["truncated"] == 3 and stats["cost"]["coupler"] > 0.0


def _steps_as_single_envs(
    env_id: str, cfg: dict, B: int, steps: int = 15, stats: dict | None = None
) -> list[int]:
    """Run the vector env against B single envs (same seeds, actions) for ``steps``
    steps; returns the number of batched runners after each step. Without ``stats``,
    episodes of 6 env steps (CFG) and two autoresets per member are checked; with it,
    ``stats`` receives the counts of resets, terminations and truncations and the
    members' summed cost components."""
    venv = gym.make_vec(env_id, num_envs=B, vectorization_mode="vector_entry_point", config=cfg)
    assert isinstance(venv, TrainTuningVectorEnv)
    assert venv.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    singles = [gym.make(env_id, config=cfg) for _ in range(B)]
    runners = []
    obs, infos = venv.reset(seed=7)
    for i, env in enumerate(singles):
        o, info = env.reset(seed=7 + i)
        assert np.array_equal(obs[i], o)
        _same_info(_member_info(infos, i), info)
    rng = np.random.default_rng(0)
    pending = [False] * B
    resets = ends_term = ends_trunc = 0
    cost: dict[str, float] = {}
    for _ in range(steps):  # (CFG's episodes of 6 env steps: two autoresets per member)
        actions = rng.uniform(-1, 1, venv.action_space.shape).astype(np.float32)
        obs, rew, term, trunc, infos = venv.step(actions)
        assert obs.shape == venv.observation_space.shape and obs.dtype == np.float32
        assert rew.shape == (B,) and term.dtype == bool and trunc.dtype == bool
        for i, env in enumerate(singles):
            if pending[i]:
                o, info = env.reset()
                r, te, tr = 0.0, False, False
                resets += 1
            else:
                o, r, te, tr, info = env.step(actions[i])
                for k, c in info["cost_components"].items():
                    cost[k] = cost.get(k, 0.0) + c
                ends_term, ends_trunc = ends_term + te, ends_trunc + tr
            pending[i] = te or tr
            assert np.array_equal(obs[i], o) and rew[i] == r
            assert (term[i], trunc[i]) == (te, tr)
            _same_info(_member_info(infos, i), info)
        runners.append(len(venv._loops))
    if stats is None:
        assert resets == 2 * B
    else:
        stats.update(resets=resets, terminated=ends_term, truncated=ends_trunc, cost=cost)
    venv.close()
    return runners


def test_vector_env_spaces_seeding_and_reset_mask():
    venv = _make(IDS[0], 2)
    single = gym.make(IDS[0], config=CFG)
    assert venv.single_observation_space == single.observation_space
    assert venv.single_action_space == single.action_space
    assert venv.observation_space.shape == (2, *single.observation_space.shape)
    assert venv.action_space.shape == (2, *single.action_space.shape)
    a, _ = venv.reset(seed=[3, 4])
    b, _ = venv.reset(seed=3)
    assert np.array_equal(a, b)
    act = np.zeros(venv.action_space.shape, np.float32)
    stepped, *_ = venv.step(act)
    again, infos = venv.reset(seed=[None, 4], options={"reset_mask": np.array([False, True])})
    assert np.array_equal(again[0], stepped[0]) and np.array_equal(again[1], a[1])
    assert infos["_scenario"].tolist() == [False, True]
    with pytest.raises(ValueError, match="seed"):
        venv.reset(seed=[1, 2, 3])


def test_the_ids_of_a_lockstep_scenario_have_the_vector_entry_point():
    """Every registered id (single-car and multi-car, one input or one per car) has the
    native vector env, and its plant is one the lockstep runner batches."""
    from train_envs.envs.registration import ENV_SPECS
    from train_envs.simulation.batch import batchable_member

    for env_id in ENV_SPECS:
        assert gym.spec(env_id).vector_entry_point == VECTOR_ENTRY_POINT, env_id
        env = gym.make(env_id, config=CFG).unwrapped
        env.reset(seed=0)
        assert batchable_member(env.loop.plant), env_id
        env.close()
    with pytest.raises(ValueError, match="num_envs"):
        TrainTuningVectorEnv(0, config=CFG, base_config={"scenario": "paper004_urban"})


def test_the_vector_env_refuses_what_the_lockstep_runner_cannot_batch(monkeypatch):
    base = {"scenario": "paper000_single_section", "controller": "sempc"}
    cfg = dict(CFG, supervision={"end_on_violation": True})
    with pytest.raises(ValueError, match="end_on_violation"):
        TrainTuningVectorEnv(2, config=cfg, base_config=base)
    import train_envs.envs.vector_env as vector_env

    monkeypatch.setattr(vector_env, "batchable_member", lambda plant: False)
    with pytest.raises(ValueError, match="not one the lockstep runner batches"):
        TrainTuningVectorEnv(2, config=CFG, base_config=base)


def test_ppo_trains_on_the_vector_env_through_the_sb3_adapter():
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecEnv

    from agents.vec_adapter import GymnasiumVecEnv

    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # (small networks: threads only contend)
    try:
        venv = GymnasiumVecEnv(_make("TrainEnvs/Stopping001PID-v0", 4))
        assert isinstance(venv, VecEnv)
        venv.seed(0)
        model = PPO("MlpPolicy", venv, n_steps=64, batch_size=64, n_epochs=1, seed=0, device="cpu")
        model.learn(total_timesteps=256)
        assert model.num_timesteps == 256
        obs = venv.reset()
        act, _ = model.predict(obs, deterministic=True)
        dones = np.zeros(4, dtype=bool)
        for _ in range(7):  # past the end of the first episodes (6 env steps)
            _, rew, dones, infos = venv.step(act)
            assert rew.shape == (4,) and np.isfinite(rew).all()
            if dones.any():
                break
        assert dones.all()  # the same episode length for every member
        for info in infos:  # the last observation kept aside, the next episode's returned
            assert info["terminal_observation"].shape == venv.observation_space.shape
            assert info["TimeLimit.truncated"]
        venv.close()
    finally:
        torch.set_num_threads(threads)
