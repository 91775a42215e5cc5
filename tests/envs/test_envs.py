"""Gymnasium envs: API conformance, seeding, equivalence with the plain runner, vector envs."""

import gymnasium as gym
import numpy as np
import pandas as pd
import pytest
from gymnasium.utils.env_checker import check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import train_envs  # noqa: F401  (registers the ids)
from train_envs.controllers import make_controller
from train_envs.envs import (
    TrainTuningEnv,
    VectorRewardWrapper,
    evaluate,
    params_to_action,
    registered_ids,
)
from train_envs.simulation import simulate

IDS = registered_ids()
PID_ID = "TrainEnvs/Stopping001PID-v0"


def test_registration_is_idempotent():
    before = registered_ids()
    train_envs.register_envs()
    train_envs.register_envs()
    assert registered_ids() == before and PID_ID in before


@pytest.mark.parametrize("env_id", IDS)
def test_check_env_every_id(env_id):
    env = gym.make(env_id, render_mode="rgb_array")
    check_env(env.unwrapped, skip_render_check=True)
    sb3_check_env(env.unwrapped, warn=True)
    env.close()


@pytest.mark.parametrize("env_id", IDS)
def test_constant_default_action_reproduces_simulate(env_id):
    env = gym.make(env_id, config={"max_episode_steps": 40})
    base = env.unwrapped
    obs, _ = env.reset(seed=7)
    action = params_to_action(env, {})
    done = False
    while not done:
        obs, r, term, trunc, info = env.step(action)
        done = term or trunc
    df_env = base.loop.dataframe()
    # the action maps back onto the defaults to floating-point precision ...
    defaults = make_controller(base.config["controller"], base.scenario).get_params()
    for name, value in info["params"].items():
        assert value == pytest.approx(defaults[name], rel=1e-12, abs=1e-15)
    # ... and with those parameter values the plain runner gives the same run
    ctrl = make_controller(
        base.config["controller"], base.scenario, **base.config["controller_params"]
    )
    ctrl.set_params(**info["params"])
    res = simulate(base.scenario, ctrl, seed=base.loop.seed)
    n = len(df_env) - 1  # the env may stop early (max_episode_steps); compare the common part
    timing = ["solve_time_s"]  # wall-clock, differs between any two runs
    pd.testing.assert_frame_equal(
        df_env.drop(columns=timing, errors="ignore").iloc[:n].reset_index(drop=True),
        res.df.drop(columns=timing, errors="ignore").iloc[:n].reset_index(drop=True),
        check_exact=False,
        # an MPC rebuilt by set_weights (env) and one built with the same weights at
        # reset (plain runner) agree to rounding, which the closed loop may amplify
        rtol=1e-7,
        atol=1e-7,
    )


def test_seeding_same_seed_same_trajectory_and_randomisation():
    cfg = {"disturbance": {"random_bound_mps2": 0.05, "mass_factor_range": [0.9, 1.1]}}
    env = gym.make(PID_ID, config=cfg)

    def run(seed):
        obs, _ = env.reset(seed=seed)
        traj = [obs]
        for _ in range(15):
            obs, *_ = env.step(env.action_space.sample() * 0 + 0.1)
            traj.append(obs)
        return np.array(traj)

    a, b, c = run(3), run(3), run(4)
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)


def test_action_mapping_clipping_and_nan():
    env = gym.make(PID_ID)
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.array([2.0, 0.0, -3.0], dtype=np.float32))
    assert info["action_clipped"] == 2
    kp = env.unwrapped.param_specs[0]
    assert info["params"]["kp"] == pytest.approx(kp.high)
    with pytest.raises(ValueError, match="finite"):
        env.step(np.array([np.nan, 0.0, 0.0], dtype=np.float32))


def test_delta_mode_moves_parameters_gradually():
    env = gym.make(PID_ID, config={"action_mode": "delta", "delta_scale": 0.1})
    _, info0 = env.reset(seed=0)
    _, _, _, _, info = env.step(np.array([1.0, 0.0, 0.0], dtype=np.float32))
    spec = env.unwrapped.param_specs[0]
    assert spec.to_unit(info["params"]["kp"]) == pytest.approx(
        spec.to_unit(info0["params"]["kp"]) + 0.1
    )


def test_bad_config_names_key_and_allowed():
    with pytest.raises(ValueError, match="unknown config key 'nope'.*decision_interval"):
        gym.make(PID_ID, config={"nope": 1})
    with pytest.raises(ValueError, match="action_params"):
        gym.make(PID_ID, config={"action_params": ["kp", "zz"]})
    with pytest.raises(ValueError, match="action_mode"):
        gym.make(PID_ID, config={"action_mode": "relative"})
    with pytest.raises(ValueError, match="disturbance"):
        gym.make(PID_ID, config={"disturbance": {"windy": 1}})


def _first_steps(env, n=8):
    obs, _ = env.reset(seed=2)
    out = [obs]
    for _ in range(n):
        obs, r, *_ = env.step(np.full(env.action_space.shape, 0.3))
        out.append(obs)
        out.append(np.array([r]))
    return np.concatenate(out)


def test_sectioned_and_flat_config_give_the_same_env():
    flat = {
        "action_mode": "delta",
        "delta_scale": 0.2,
        "decision_interval": 3,
        "preview_m": 400.0,
        "preview_points": 2,
        "reward_weights": {"energy": 1.0},
        "disturbance": {"random_bound_mps2": 0.02},
        "max_episode_steps": 30,
    }
    sectioned = {
        "action": {"mode": "delta", "delta_scale": 0.2},
        "observation": {"preview_m": 400.0, "preview_points": 2},
        "reward": {"weights": {"energy": 1.0}},
        "scenario": {"disturbance": {"random_bound_mps2": 0.02}},
        "episode": {"decision_interval": 3, "max_steps": 30},
    }
    mixed = {
        "action": {"mode": "delta"},
        "delta_scale": 0.2,
        **{k: v for k, v in flat.items() if k not in ("action_mode", "delta_scale")},
    }
    envs = [gym.make(PID_ID, config=c).unwrapped for c in (flat, sectioned, mixed)]
    assert envs[0].config == envs[1].config == envs[2].config
    assert envs[0].settings == envs[1].settings == envs[2].settings
    # reward weights merge key by key over the defaults
    assert envs[0].config["reward_weights"] == dict(
        TrainTuningEnv.default_config()["reward_weights"], energy=1.0
    )
    runs = [_first_steps(e) for e in envs]
    np.testing.assert_array_equal(runs[0], runs[1])
    np.testing.assert_array_equal(runs[0], runs[2])
    # a scenario / controller section names them by ``name``
    env = gym.make(
        PID_ID, config={"scenario": {"name": "paper004_urban"}, "controller": {"name": "fuzzy_pid"}}
    ).unwrapped
    assert env.config["scenario"] == "paper004_urban" and env.config["controller"] == "fuzzy_pid"


def test_default_config_and_registered_base_configs():
    from train_envs.envs import ENV_SPECS, EnvConfig

    cfg = TrainTuningEnv.default_config()
    assert list(cfg) == [
        "scenario",
        "scenario_overrides",
        "real_line",
        "controller",
        "controller_params",
        "action_params",
        "action_bounds",
        "action_mode",
        "delta_scale",
        "decision_interval",
        "preview_m",
        "preview_points",
        "reward_weights",
        "disturbance",
        "max_episode_steps",
        "supervision",
    ]
    assert EnvConfig.resolve(cfg) == EnvConfig()
    for base, _doc in ENV_SPECS.values():
        flat = EnvConfig.resolve(base).flat()
        assert all(flat[k] == v for k, v in base.items())
    # the Urban004 id fixes a controller argument; a user's controller_params merge over it
    env = gym.make("TrainEnvs/Urban004-v0", config={"controller_params": {}}).unwrapped
    assert env.config["controller_params"] == {"alpha_order": "clip"}


@pytest.mark.parametrize(
    "config, match",
    [
        ({"action": {"mod": "delta"}}, r"unknown config key action\.mod; .*delta_scale"),
        ({"action": "delta"}, r"config action must be a mapping"),
        ({"reward_weights": {"speed": 1.0}}, r"reward\.weights.*speed.*tracking"),
        ({"reward": {"weights": {"jerk": -1.0}}}, r"reward\.weights \(reward_weights\).*>= 0"),
        ({"delta_scale": 0.0}, r"action\.delta_scale \(delta_scale\) .*> 0"),
        ({"decision_interval": 0}, r"decision_interval.* integer >= 1"),
        ({"decision_interval": 2.5}, r"decision_interval.* integer >= 1"),
        ({"preview_points": -1}, r"preview_points.* integer >= 0"),
        ({"preview_m": float("nan")}, r"preview_m.*finite"),
        ({"max_episode_steps": 0}, r"max_steps \(max_episode_steps\).* integer >= 1"),
        ({"action_params": []}, r"action_params.*non-empty"),
        ({"controller": 3}, r"controller\.name \(controller\).*string"),
        ({"real_line": {"track": "x"}}, r"real_line.*'train'"),
        ({"real_line": {"track": "x", "train": "y", "stops": 1}}, r"real_line.*stops"),
        ({"action_mode": "delta", "action": {"mode": "delta"}}, r"action\.mode twice"),
    ],
)
def test_bad_config_values_name_the_key(config, match):
    with pytest.raises(ValueError, match=match) as err:
        gym.make(PID_ID, config=config)
    assert "\n" not in str(err.value)


def test_final_info_has_episode_metrics_and_objectives():
    env = gym.make(PID_ID)
    env.reset(seed=0)
    done = False
    while not done:
        _, _, term, trunc, info = env.step(params_to_action(env, {}))
        assert set(info["objectives"]) == set(train_envs.envs.OBJECTIVES)
        done = term or trunc
    assert term and "stop_error_m" in info["episode_metrics"]


def test_vector_reward_wrapper():
    env = VectorRewardWrapper(gym.make(PID_ID), objectives=("tracking", "jerk", "stop"))
    env.reset(seed=0)
    _, r, _, _, info = env.step(env.action_space.sample())
    assert r.shape == (3,) and env.reward_space.shape == (3,)
    assert np.all(r <= 0) and "scalar_reward" in info


def test_rgb_render():
    env = gym.make(PID_ID, render_mode="rgb_array")
    env.reset(seed=0)
    env.step(env.action_space.sample())
    img = env.render()
    assert img.ndim == 3 and img.shape[2] == 3 and img.dtype == np.uint8


def test_real_line_env_samples_sections():
    env = TrainTuningEnv(
        {
            "real_line": {"track": "CN_Songjiazhuang_Yizhuang", "train": "CN_Beijing_Subway"},
            "controller": "pid",
        }
    )
    names = set()
    for seed in range(6):
        env.reset(seed=seed)
        names.add(env.scenario.name)
    assert len(names) > 1


@pytest.mark.parametrize("mode", ["sync", "async"])
def test_make_vec(mode):
    venv = gym.make_vec(PID_ID, num_envs=2, vectorization_mode=mode)
    venv.reset(seed=0)
    for _ in range(3):
        obs, r, term, trunc, info = venv.step(venv.action_space.sample())
    assert obs.shape[0] == 2
    venv.close()


def test_sb3_subproc_spawn():
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import SubprocVecEnv

    venv = make_vec_env(
        "train_envs:" + PID_ID,
        n_envs=2,
        vec_env_cls=SubprocVecEnv,
        vec_env_kwargs={"start_method": "spawn"},
        seed=0,
    )
    venv.reset()
    for _ in range(3):
        venv.step(np.stack([venv.action_space.sample() for _ in range(2)]))
    venv.close()


def test_evaluate_same_seeds_same_table():
    a = evaluate(PID_ID, {"kp": 0.5}, seeds=[0, 1])
    b = evaluate(PID_ID, {"kp": 0.5}, seeds=[0, 1])
    pd.testing.assert_frame_equal(a, b)
    assert {"stop_error_m", "E_v_mps", "return", "seed"} <= set(a.columns)


@pytest.mark.parametrize("env_id", [PID_ID, "TrainEnvs/Urban004-v0"])
def test_ppo_smoke(env_id):
    from stable_baselines3 import PPO

    env = gym.make(env_id)
    model = PPO("MlpPolicy", env, n_steps=64, batch_size=32, n_epochs=1, seed=0, device="cpu")
    model.learn(total_timesteps=256)
    obs, _ = env.reset(seed=0)
    action, _ = model.predict(obs, deterministic=True)
    assert env.action_space.contains(action)


# ------------------------------------------------- hot path and env reuse (evaluate)
def _reference_observation(env, u_before: float | None = None) -> np.ndarray:
    """The documented observation, computed the straightforward (vectorised) way;
    ``u_before``: the total command at the previous observation (None: at reset)."""
    from train_envs.plants.lookup import gradient_table

    b = env.unwrapped
    sc, loop = b.scenario, b.loop
    p, ref = loop.plant, sc.reference
    t, s, v = p.t, p.s, p.v
    v_max = max(float(np.max(sc.track.speed_limits_mps)), 1.0)
    if np.isfinite(sc.train.max_speed_mps):
        v_max = min(v_max, sc.train.max_speed_mps) or v_max
    end = sc.s_stop_m if sc.s_stop_m is not None else ref.end_m
    pts = s + np.linspace(0.0, float(b.config["preview_m"]), int(b.config["preview_points"]))
    u = float(np.sum(loop.u_prev))
    u_scale = sc.train.max_traction_force_N
    u0 = u if u_before is None else u_before
    du = (u - u0) / (u_scale * sc.dt_ctrl_s * b.config["decision_interval"])
    obs = np.concatenate(
        [
            [
                (ref.v_ref(t, s) - v) / 5.0,
                (ref.s_ref(t) - s) / 50.0,
                v / v_max,
                (end - s) / 1000.0,
                (float(ref.profile.t_at_s(s)) - t) / 30.0,
            ],
            gradient_table(sc.track)(pts) * (1.0 / 30.0),
            sc.track.speed_limit_at(pts) * (1.0 / v_max),
            [u / u_scale, du],
            np.asarray(b.action_type.prev, dtype=float),
            [float(bool(loop.last_info.get("fallback", False)))],
        ]
    )
    return np.clip(np.nan_to_num(obs), -10.0, 10.0).astype(np.float32)


@pytest.mark.parametrize("env_id", [PID_ID, "TrainEnvs/Section000-v0"])
def test_observation_and_costs_follow_their_definitions(env_id):
    env = gym.make(env_id, config={"max_episode_steps": 12})
    b = env.unwrapped
    obs, _ = env.reset(seed=1)
    np.testing.assert_array_equal(obs, _reference_observation(env))
    assert obs.dtype == np.float32 and len(obs) == len(b.observation_names)
    action = np.clip(params_to_action(env, {}) + 0.3, -1, 1)
    action[0] = 1.7  # clipped, counted
    k_rows, a_prev, returned, done = [0], b.loop.plant.accel, [], False
    while not done:
        u_before = b.observation_type.u_last
        obs, r, term, trunc, info = env.step(action)
        returned.append(obs)
        np.testing.assert_array_equal(obs, _reference_observation(env, u_before))
        assert obs is not b.observation_type.observe()  # a fresh array every call
        k_rows.append(b.loop.k)
        assert info["action_clipped"] == 1 and info["action_clipped_total"] == len(k_rows) - 1
        # the per-step costs from the runner's rows, as documented
        df = b.loop.dataframe()
        rows = df.iloc[k_rows[-2] : k_rows[-1]]
        dt = b.scenario.dt_ctrl_s
        e_v = rows["v_ref_mps"].to_numpy() - rows["v_mps"].to_numpy()
        a = rows["a_mps2"].to_numpy()
        jerk = np.diff(a, prepend=a_prev) / dt
        a_prev = a[-1]
        over = np.maximum(rows["v_mps"].to_numpy() - rows["v_limit_mps"].to_numpy(), 0.0)
        c = info["objectives"]
        assert list(c) == list(train_envs.envs.OBJECTIVES)
        assert c["tracking"] == pytest.approx(float(e_v @ e_v) * dt, rel=1e-12, abs=1e-300)
        assert c["jerk"] == pytest.approx(float(jerk @ jerk) * dt, rel=1e-12, abs=1e-300)
        sat = rows["saturated"].sum()
        assert c["violation"] == pytest.approx((over.sum() + sat) * dt, rel=1e-12, abs=1e-300)
        w = b.reward_type.weights
        assert r == pytest.approx(-sum(w[k] * c[k] for k in c), rel=1e-12, abs=1e-300)
        done = term or trunc
    # the arrays handed out earlier were not overwritten by later steps
    assert not all(np.array_equal(returned[0], o) for o in returned[1:])
    with pytest.raises(ValueError, match="finite"):
        env.reset(seed=0)
        env.step(np.full(action.shape, np.inf))
    with pytest.raises(ValueError, match="shape"):
        env.step(action[:-1])


def test_episode_metrics_from_dataframe_or_columns_agree_bitwise():
    from train_envs.metrics import episode_metrics

    env = gym.make("TrainEnvs/Section000-v0", config={"max_episode_steps": 20})
    env.reset(seed=0)
    done = False
    while not done:
        *_, term, trunc, info = env.step(params_to_action(env, {}))
        done = term or trunc
    loop = env.unwrapped.loop
    df = loop.dataframe()
    df.loc[2, "saturated"] = np.nan  # pandas skips missing values: so must the columns path
    kw = {"dt_s": loop.dt, "s_stop_m": 100.0, "scheduled_time_s": 5.0, "du_max_Nps": 1e5}
    a = episode_metrics(df, **kw)
    b = episode_metrics({c: df[c].to_numpy() for c in df.columns}, **kw)
    assert a == b and a["max_coupler_force_N"] > 0
    assert info["episode_metrics"] == loop.metrics()


def _non_default_params(env_id, phase):
    env = gym.make(env_id)
    specs = env.unwrapped.param_specs
    env.close()
    return {p.name: p.from_unit(0.6 * np.cos(i + phase)) for i, p in enumerate(specs)}


@pytest.mark.parametrize(
    "env_id, config",
    [
        (PID_ID, {}),
        # a real line: reset samples the station pair from the seed
        ("TrainEnvs/Yizhuang-v0", {"max_episode_steps": 25}),
        # RSMPC keeps its QPs across episodes: a reused env gets a fresh controller
        ("TrainEnvs/Stopping001-v0", {}),
        # the DMC keeps its QP too, built without the tunable parameters: kept as it is
        ("TrainEnvs/Urban004-v0", {"max_episode_steps": 30}),
    ],
)
def test_reused_env_evaluates_like_a_fresh_env_bitwise(env_id, config):
    from train_envs.envs.evaluation import ENV_CACHE, clear_env_cache

    A, B = _non_default_params(env_id, 0.3), _non_default_params(env_id, 2.0)
    B1 = dict(list(B.items())[:1])  # the others: the env's defaults, not A's values
    fresh = evaluate(env_id, B, seeds=[0, 1], config=config)
    fresh1 = evaluate(env_id, B1, seeds=[2], config=config)
    clear_env_cache()
    hits = ENV_CACHE.hits
    evaluate(env_id, A, seeds=[5], config=config, reuse_env=True)
    reused = evaluate(env_id, B, seeds=[0, 1], config=config, reuse_env=True)
    evaluate(env_id, A, seeds=[0], config=config, reuse_env=True)
    reused1 = evaluate(env_id, B1, seeds=[2], config=config, reuse_env=True)
    assert ENV_CACHE.hits - hits == 3 and len(ENV_CACHE) == 1
    pd.testing.assert_frame_equal(fresh, reused, check_exact=True)
    pd.testing.assert_frame_equal(fresh1, reused1, check_exact=True)
    clear_env_cache()
    assert len(ENV_CACHE) == 0


@pytest.mark.parametrize(
    "env_id, kept", [("TrainEnvs/Urban004-v0", True), ("TrainEnvs/Stopping001-v0", False)]
)
def test_reused_env_keeps_a_controller_only_if_its_state_is_parameter_free(env_id, kept):
    """After an episode with other parameters, a reused env keeps its DMC (what the DMC
    keeps does not depend on its tunables) but rebuilds the RSMPC (its QPs do)."""
    from train_envs.envs.evaluation import EnvCache

    cache = EnvCache(maxsize=1)
    cfg = {"max_episode_steps": 3}
    env = cache.acquire(env_id, cfg)
    ctrl = env.unwrapped.controller
    evaluate_params = _non_default_params(env_id, 0.3)
    env.reset(seed=0)
    env.step(params_to_action(env, evaluate_params))
    cache.release(env_id, cfg, env)
    again = cache.acquire(env_id, cfg)
    assert again is env and (again.unwrapped.controller is ctrl) is kept
    cache.clear()


def test_env_cache_is_bounded_and_lends_each_env_once():
    from train_envs.envs.evaluation import EnvCache

    cache = EnvCache(maxsize=2)
    e1 = cache.acquire(PID_ID, {})
    e2 = cache.acquire(PID_ID, {})  # e1 is lent out: a second env
    assert e1 is not e2 and cache.misses == 2
    cache.release(PID_ID, {}, e1)
    cache.release(PID_ID, {}, e2)
    assert cache.acquire(PID_ID, {}) is e2 and cache.hits == 1  # most recent first
    cache.release(PID_ID, {}, e2)
    cfg = {"decision_interval": 3}
    e3 = cache.acquire(PID_ID, cfg)  # another config: another env
    assert e3.unwrapped.config["decision_interval"] == 3
    cache.release(PID_ID, cfg, e3)
    assert len(cache) == 2  # bounded: the least recently used (e1) was closed
    assert cache.acquire(PID_ID, {"decision_interval": 3}) is e3
    assert EnvCache.key(PID_ID, {"x": object()}) is None  # not JSON-able: no reuse
    cache.clear()
    assert len(cache) == 0
