"""Tests of the agents package: SB3 training, reloading, the evaluation harness, CLI, rl-zoo3.

Budgets are tiny (a few hundred env steps): these tests check plumbing and
reproducibility, not learning.
"""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import train_envs  # noqa: F401  (registers the ids)
from agents.evaluation import (
    ControllerDriver,
    EnvCase,
    ParamsDriver,
    PolicyDriver,
    compare,
    format_summary,
    load_params,
    overlay_figure,
    significance,
    summary,
)
from agents.hyperparameters import ALGOS, LinearSchedule, parse_value, resolve_hyperparams
from agents.training import TrainConfig, load_policy, train
from train_envs.cli import main as cli_main
from train_envs.envs import registered_ids

REPO = Path(__file__).resolve().parents[2]
# the paper-001 stopping env: the RSMPC one once its controller has landed
STOP_ID = (
    "TrainEnvs/Stopping001-v0"
    if "TrainEnvs/Stopping001-v0" in registered_ids()
    else "TrainEnvs/Stopping001PID-v0"
)
PID_ID = "TrainEnvs/Stopping001PID-v0"
TINY = {
    "ppo": {"n_steps": 64, "batch_size": 32, "n_epochs": 1},
    "sac": {"learning_starts": 32, "batch_size": 32},
}


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """PPO (through the CLI) and SAC (through the library) on the 001 stopping env, and
    a PPO policy of the PID env for the harness tests (policies need their env's
    observation/action spaces; the PID env is the fastest)."""
    root = tmp_path_factory.mktemp("agents")
    ppo_dir = root / "ppo"
    rc = cli_main(
        [
            "train",
            "--env",
            STOP_ID,
            "--algo",
            "ppo",
            "--timesteps",
            "128",
            "--seed",
            "3",
            "--out",
            str(ppo_dir),
            "--n-envs",
            "1",
            "--hyperparams",
            "n_steps=64",
            "batch_size=32",
            "n_epochs=1",
            "--eval-freq",
            "128",
            "--eval-episodes",
            "1",
            "--no-progress",
        ]
    )
    assert rc == 0
    res = train(
        TrainConfig(
            env_id=STOP_ID,
            algo="sac",
            timesteps=64,
            seed=1,
            out=root / "sac",
            hyperparams=TINY["sac"],
            eval_freq=0,
            checkpoint_freq=0,
            tensorboard=False,
        )
    )
    assert res.timesteps >= 64 and res.vecnormalize_path is None
    res = train(
        env_id=PID_ID,
        timesteps=64,
        out=root / "pid_ppo",
        n_envs=1,
        hyperparams=TINY["ppo"],
        eval_freq=0,
        checkpoint_freq=0,
        tensorboard=False,
    )
    return {"ppo": ppo_dir, "sac": root / "sac", "pid_ppo": root / "pid_ppo"}


# ------------------------------------------------------------------ hyperparams
@pytest.mark.parametrize("algo", ALGOS)
def test_yaml_hyperparams_load_for_every_registered_id(algo):
    for env_id in registered_ids():
        hp = resolve_hyperparams(algo, env_id)
        assert hp.n_timesteps > 0 and hp.n_envs >= 1 and hp.policy == "MlpPolicy"
        assert hp.source in (env_id, "default")
    hp = resolve_hyperparams(algo, "TrainEnvs/NotInTheFile-v0")  # falls back to default
    assert hp.source == "default"


def test_hyperparam_conventions_and_errors():
    hp = resolve_hyperparams(
        "ppo",
        PID_ID,
        overrides={
            "learning_rate": "lin_3e-4",
            "policy_kwargs": "dict(net_arch=[32, 32], activation_fn=nn.Tanh)",
            "normalize": "dict(norm_obs=False, norm_reward=True)",
        },
    )
    assert isinstance(hp.model_kwargs["learning_rate"], LinearSchedule)
    assert hp.model_kwargs["learning_rate"](0.5) == pytest.approx(1.5e-4)
    assert hp.model_kwargs["policy_kwargs"]["net_arch"] == [32, 32]
    assert hp.normalize["norm_obs"] is False and hp.normalize["gamma"] == hp.model_kwargs["gamma"]
    td3 = resolve_hyperparams("td3", PID_ID)
    assert td3.noise_type == "normal" and "action_noise" in td3.constructor_kwargs(3)
    with pytest.raises(ValueError, match="cannot parse"):
        parse_value("__import__('os').system('true')")
    with pytest.raises(ValueError, match=r"unknown ppo hyperparameter\(s\) \['n_step'\]"):
        resolve_hyperparams("ppo", PID_ID, overrides={"n_step": 64})
    with pytest.raises(ValueError, match="lin_<number>"):
        resolve_hyperparams("ppo", PID_ID, overrides={"learning_rate": "exp_1e-3"})
    with pytest.raises(ValueError, match="noise_type"):
        resolve_hyperparams("ppo", PID_ID, overrides={"noise_type": "normal"})


def test_bad_algo_and_env_names_raise_clear_errors(tmp_path):
    with pytest.raises(ValueError, match="algo must be one of ppo, sac, td3; got 'a2c'"):
        resolve_hyperparams("a2c", PID_ID)
    with pytest.raises(ValueError, match="algo must be one of"):
        train(env_id=PID_ID, algo="dqn", timesteps=8, out=tmp_path)
    with pytest.raises(ValueError, match=r"env 'TrainEnvs/Nope-v0' is not registered.*Urban004"):
        train(env_id="TrainEnvs/Nope-v0", timesteps=8, out=tmp_path)
    with pytest.raises(ValueError, match="vec must be one of dummy, subproc, native"):
        TrainConfig(env_id=PID_ID, vec="forkserver").validate()
    with pytest.raises(ValueError, match="timesteps must be"):
        TrainConfig(env_id=PID_ID, timesteps=0).validate()
    with pytest.raises(ValueError, match="ControllerDriver controller must be"):
        ControllerDriver("no_such_controller")
    with pytest.raises(ValueError, match="not registered"):
        compare(["TrainEnvs/Nope-v0"], [ControllerDriver()], [0])
    # the CLI turns them into exit code 2 with the message
    assert cli_main(["train", "--env", "TrainEnvs/Nope-v0", "--timesteps", "8"]) == 2
    with pytest.raises(SystemExit):
        cli_main(["train", "--env", PID_ID, "--algo", "a2c"])


# --------------------------------------------------------------- train / reload
@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_native_vector_env_trains_the_same_policy_as_the_dummy_one(tmp_path, algo):
    """``vec="native"`` (the id's vector env through the SB3 adapter) gives the agent
    the episodes of ``DummyVecEnv`` of single envs for the same seeds: the trained
    policies are equal bit for bit, and the monitor files hold the same episodes (their
    returns summed from the float32 rewards SB3 sees: to 1e-6 relative of Monitor's)."""
    import torch

    from agents.hyperparameters import algo_class

    hyper = {
        "ppo": {"n_steps": 64, "batch_size": 64, "n_epochs": 2},
        "sac": {"learning_starts": 32, "batch_size": 32},
    }[algo]
    params, episodes = {}, {}
    for vec in ("dummy", "native"):
        res = train(
            env_id=PID_ID,
            algo=algo,
            timesteps=256 if algo == "ppo" else 128,
            seed=3,
            out=tmp_path / vec,
            n_envs=2,
            vec=vec,
            hyperparams=hyper,
            eval_freq=0,
            checkpoint_freq=0,
            tensorboard=False,
        )
        assert res.n_envs == 2
        model = algo_class(algo).load(res.model_path, device="cpu")
        params[vec] = model.policy.state_dict()
        frames = [
            pd.read_csv(f, skiprows=1) for f in sorted((tmp_path / vec / "monitor").iterdir())
        ]
        episodes[vec] = pd.concat(frames).sort_values(["r", "l"]).reset_index(drop=True)
    assert params["dummy"].keys() == params["native"].keys()
    for key, val in params["dummy"].items():
        assert torch.equal(val, params["native"][key]), key
    native_monitor = tmp_path / "native" / "monitor" / "native.monitor.csv"
    assert PID_ID in native_monitor.read_text().splitlines()[0]
    dummy, native = episodes["dummy"], episodes["native"]
    assert len(dummy) == len(native) >= 2
    assert (dummy["l"] == native["l"]).all()
    np.testing.assert_allclose(native["r"], dummy["r"], rtol=1e-6)


@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_train_save_reload_evaluate_deterministic(runs, algo):
    run = runs[algo]
    assert (run / "model.zip").is_file() and (run / "config.json").is_file()
    record = json.loads((run / "config.json").read_text())
    assert record["algo"] == algo and record["env_id"] == STOP_ID
    if algo == "ppo":  # VecNormalize, EvalCallback's best model, checkpoints
        assert (run / "vecnormalize.pkl").is_file()
        assert (run / "best" / "best_model.zip").is_file()
        assert (run / "best" / "vecnormalize.pkl").is_file()
        assert any((run / "checkpoints").glob("*.zip"))
    pol = load_policy(run)
    assert type(pol.model).__name__ == algo.upper()
    assert (pol.vecnormalize is not None) == (algo == "ppo")
    # same metrics twice (fresh drivers: reloaded from disk each time)
    a = compare([STOP_ID], [PolicyDriver(run)], [0])
    b = compare([STOP_ID], [PolicyDriver(run / "model.zip", name=a["driver"][0])], [0])
    pd.testing.assert_frame_equal(a, b)
    assert np.isfinite(a["return"]).all() and "stop_error_m" in a.columns


def test_policy_algo_inferred_without_run_record(runs, tmp_path):
    # a bare .zip (no config.json beside it): the algorithm comes from the policy class
    for algo in ("ppo", "sac"):
        dst = tmp_path / algo
        dst.mkdir()
        (dst / "m.zip").write_bytes((runs[algo] / "model.zip").read_bytes())
        if algo == "ppo":
            (dst / "vecnormalize.pkl").write_bytes((runs[algo] / "vecnormalize.pkl").read_bytes())
        assert type(load_policy(dst / "m.zip").model).__name__ == algo.upper()


# --------------------------------------------------------------------- harness
def test_harness_identical_seeds_identical_tables(runs, tmp_path):
    drivers = [
        PolicyDriver(runs["pid_ppo"], name="ppo"),
        ParamsDriver("kp05", {"kp": 0.5}),
        ControllerDriver("pid"),
        ControllerDriver("tracking"),  # another controller, through simulate
    ]
    a = compare([PID_ID], drivers, [0, 1])
    b = compare([PID_ID], drivers, [0, 1])
    pd.testing.assert_frame_equal(a, b)
    assert list(a.columns[:7]) == [
        "env",
        "env_id",
        "driver",
        "seed",
        "scenario",
        "return",
        "env_steps",
    ]
    assert len(a) == 8 and set(a["driver"]) == {"ppo", "kp05", "pid", "tracking"}
    assert {"stop_error_m", "E_v_mps", "energy_kWh", "ITAE_m_s"} <= set(a.columns)
    assert a.loc[a["driver"] == "tracking", "return"].isna().all()
    s = summary(a, ["return", "stop_error_m"])
    assert s.shape == (4, 4) and ("stop_error_m", "std") in s.columns
    assert "±" in format_summary(s).iloc[0, 1]
    sig = significance(a, "pid", ["return", "stop_error_m"])
    assert set(sig["driver"]) == {"ppo", "kp05", "tracking"}
    assert {"p_value", "n_pairs", "median_diff", "note"} <= set(sig.columns)
    with pytest.raises(ValueError, match="baseline driver 'nope'"):
        significance(a, "nope")
    fig = overlay_figure(PID_ID, drivers, 0)
    assert len(fig.axes[0].lines) >= len(drivers)


def test_controller_driver_simulate_path_matches_env_path():
    case = EnvCase(PID_ID)
    drv = ControllerDriver("pid")
    env_row = drv.evaluate(case, [0]).iloc[0]
    res, _ = drv._simulate(case, 0)
    for key, val in res.metrics.items():
        assert env_row[key] == pytest.approx(val, rel=1e-9, abs=1e-12), key


def test_significance_on_random_seeds():
    rng = np.random.default_rng(0)
    seeds = list(range(8))
    base = rng.normal(size=8)
    df = pd.DataFrame(
        {
            "env": "e",
            "driver": ["a"] * 8 + ["b"] * 8 + ["c"] * 8,
            "seed": seeds * 3,
            "m_s": np.concatenate([base, base + 1.0 + 0.01 * rng.normal(size=8), base]),
        }
    )
    sig = significance(df, "a").set_index("driver")
    assert sig.loc["b", "p_value"] == pytest.approx(2 / 2**8)  # every pair worse: exact test
    assert np.isnan(sig.loc["c", "p_value"]) and "identical" in sig.loc["c", "note"]


def test_load_params_file_and_study(tmp_path):
    (tmp_path / "p.json").write_text(json.dumps({"kp": 0.6, "ki": 0.04}))
    (tmp_path / "p.yml").write_text("params:\n  kp: 0.7\n")
    assert load_params(tmp_path / "p.json") == ("p", {"kp": 0.6, "ki": 0.04})
    assert load_params(tmp_path / "p.yml") == ("p", {"kp": 0.7})
    with pytest.raises(ValueError, match="no such file"):
        load_params(tmp_path / "missing.json")
    with pytest.raises(ValueError, match="storage URL"):
        load_params("sqlite:///x.db")


# ------------------------------------------------------------------------- CLI
def test_cli_evaluate_accepts_each_driver_kind(runs, tmp_path, capsys):
    import optuna

    from tuners.run import tune

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    db = tmp_path / "t.db"
    tune(PID_ID, "pso", pop=4, iters=1, backend="serial", storage=f"sqlite:///{db}", study="s")
    (tmp_path / "p.json").write_text(json.dumps({"kp": 0.5}))
    out = tmp_path / "eval"
    rc = cli_main(
        [
            "evaluate",
            "--env",
            PID_ID,
            "--policy",
            str(runs["pid_ppo"]),
            "--params",
            str(tmp_path / "p.json"),
            "--params",
            f"sqlite:///{db}:s",
            "--controller",
            "pid",
            "--seeds",
            "0-1",
            "--baseline",
            "pid",
            "--out",
            str(out),
        ]
    )
    text = capsys.readouterr().out
    assert rc == 0, text
    assert "stop_error_m" in text and "params:s" in text and "Wilcoxon" in text
    df = pd.read_csv(out / "episodes.csv")
    assert set(df["driver"]) == {"policy:pid_ppo", "params:p", "params:s", "pid"}
    assert (out / "summary.csv").is_file() and (out / "significance.csv").is_file()
    assert list(out.glob("speed_distance_*.png"))
    # where the study selected the defaults, it reproduces the controller defaults
    import gymnasium as gym

    g = df.set_index(["driver", "seed"])["return"]
    defaults = gym.make(PID_ID).unwrapped.controller.get_params()
    selected = load_params(f"sqlite:///{db}:s")[1]
    assert set(selected) == set(defaults)
    if all(selected[k] == pytest.approx(v, abs=1e-12) for k, v in defaults.items()):
        assert g["params:s"].to_numpy() == pytest.approx(g["pid"].to_numpy(), rel=1e-6)
    # bad input: clear errors, exit code 2
    assert cli_main(["evaluate", "--env", PID_ID, "--episodes", "1"]) == 2
    assert "needs at least one" in capsys.readouterr().err
    missing = f"sqlite:///{db.parent / 'nope.db'}:x"
    assert cli_main(["evaluate", "--env", PID_ID, "--params", missing]) == 2


# ---------------------------------------------------------------------- rl-zoo3
def test_rl_zoo3_finds_envs_with_gym_packages(tmp_path):
    if importlib.util.find_spec("rl_zoo3") is None:
        pytest.skip("rl_zoo3 is not installed (pip install rl_zoo3)")
    try:
        import rl_zoo3.exp_manager  # noqa: F401
    except ImportError as exc:  # e.g. its Hugging Face helpers missing
        pytest.skip(f"rl_zoo3 is installed but cannot be imported: {exc}")
    cmd = [
        sys.executable,
        "-m",
        "rl_zoo3.train",
        "--algo",
        "ppo",
        "--env",
        PID_ID,
        "--gym-packages",
        "train_envs",
        "-conf",
        str(REPO / "agents" / "hyperparams" / "ppo.yml"),
        "-n",
        "64",
        "-f",
        str(tmp_path),
        "--seed",
        "0",
        "-params",
        "n_envs:1",
        "n_steps:64",
        "batch_size:32",
        "n_epochs:1",
    ]
    env = dict(os.environ, OMP_NUM_THREADS="1")
    proc = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300, env=env)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
    models = list(tmp_path.glob("ppo/*/*.zip"))
    assert models, proc.stdout[-2000:]
    # our loader reads rl-zoo3's layout (model + <env>/vecnormalize.pkl)
    pol = load_policy(models[0])
    assert pol.vecnormalize is not None
