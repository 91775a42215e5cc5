"""Train stable-baselines3 PPO / SAC / TD3 policies that set the inner controller's tuning.

:func:`train` builds the vectorised env (``DummyVecEnv``, ``SubprocVecEnv`` with the
``spawn`` start method -- children get the env id with the ``train_envs:`` module prefix
so that they register the ids themselves -- or the id's native vector env, whose
members step in lockstep in one process, through
:class:`~agents.vec_adapter.GymnasiumVecEnv`), wraps it in ``VecNormalize`` when the
hyperparameters say so, and learns with an ``EvalCallback`` on held-out seeds,
checkpoints, TensorBoard logs (if ``tensorboard`` is installed) and an optional
progress bar. A run folder holds::

    model.zip            final model          vecnormalize.pkl  its normalisation stats
    best/best_model.zip  best evaluation      best/vecnormalize.pkl
    checkpoints/         rl_model_<n>_steps.zip (+ rl_model_vecnormalize_<n>_steps.pkl)
    eval/evaluations.npz EvalCallback log     monitor/          Monitor CSVs (one per env;
                                                                  native: one for all)
    tb/                  TensorBoard logs     config.json       the run's settings

:func:`load_policy` reloads a model (and its VecNormalize statistics) for evaluation.
"""

from __future__ import annotations

import importlib.util
import json
import pickle
import re
import time
import warnings
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from agents.hyperparameters import HyperParams, algo_class, check_algo, resolve_hyperparams

VEC_KINDS = ("dummy", "subproc", "native")
MODULE_PREFIX = "train_envs:"

__all__ = [
    "LoadedPolicy",
    "TrainConfig",
    "TrainResult",
    "check_env_id",
    "load_policy",
    "make_training_env",
    "train",
]


def check_env_id(env_id: str) -> str:
    """``env_id`` without a ``train_envs:`` prefix, if it is registered; else a ValueError."""
    import train_envs  # noqa: F401  (registers the ids)
    from train_envs.envs import ENV_SPECS, registered_ids

    bare = env_id[len(MODULE_PREFIX) :] if env_id.startswith(MODULE_PREFIX) else env_id
    ids = registered_ids()
    if bare not in ids:
        why = " (its controller is not available yet)" if bare in ENV_SPECS else ""
        raise ValueError(f"env {env_id!r} is not registered{why}; registered ids: {', '.join(ids)}")
    return bare


def _jsonable(obj: Any) -> Any:
    return json.loads(json.dumps(obj, default=lambda o: repr(o)))


@dataclass
class TrainConfig:
    """Settings of one training run (None = from the hyperparameter YAML entry).

    Attributes:
        env_id: registered env id (``TrainEnvs/...``).
        algo: ``ppo`` | ``sac`` | ``td3``.
        timesteps: env steps to train (None: the entry's ``n_timesteps``).
        seed: seed of the model and of the training envs (env ``i`` gets ``seed + i``).
        out: run folder (None: ``runs/<env>-<algo>-s<seed>``).
        n_envs: parallel training envs (None: the entry's ``n_envs``).
        vec: ``dummy`` (in-process), ``subproc`` (one process per env, spawn) or
            ``native`` (the id's native vector env: ``gymnasium.make_vec(id,
            num_envs=n_envs, vectorization_mode="vector_entry_point")``, members in
            lockstep in one process; the same episodes as ``dummy`` for the same seeds).
        env_config: env config (``gymnasium.make(id, config=...)``), merged over the
            entry's ``env_kwargs.config``; also used for the evaluation env.
        hyperparams: overrides of the YAML entry's keys.
        hyperparams_file: YAML file to read instead of ``agents/hyperparams/<algo>.yml``.
        eval_freq: env steps between evaluations (None: timesteps // 5; 0: none).
        eval_episodes: episodes per evaluation, on the held-out seeds
            ``eval_seed, eval_seed + 1, ...`` (the same every evaluation).
        checkpoint_freq: env steps between checkpoints (None: timesteps // 4; 0: none).
        progress_bar: show SB3's progress bar (needs ``tqdm`` and ``rich``).
        tensorboard: write TensorBoard logs to ``out/tb`` if tensorboard is installed.
        device: torch device (``cpu``: the policies are small MLPs).
        torch_threads: torch intra-op threads (1 is fastest for small MLPs; None = keep).
        verbose: SB3 verbosity (0, 1, 2).
    """

    env_id: str
    algo: str = "ppo"
    timesteps: int | None = None
    seed: int = 0
    out: str | Path | None = None
    n_envs: int | None = None
    vec: str = "dummy"
    env_config: dict[str, Any] = field(default_factory=dict)
    hyperparams: dict[str, Any] = field(default_factory=dict)
    hyperparams_file: str | Path | None = None
    eval_freq: int | None = None
    eval_episodes: int = 5
    eval_seed: int = 10_000
    checkpoint_freq: int | None = None
    progress_bar: bool = False
    tensorboard: bool = True
    device: str = "cpu"
    torch_threads: int | None = 1
    verbose: int = 0

    def validate(self) -> None:
        """Raise a ValueError naming the first bad field and its allowed values."""
        self.algo = check_algo(self.algo)
        self.env_id = check_env_id(self.env_id)
        if self.vec not in VEC_KINDS:
            raise ValueError(f"vec must be one of {', '.join(VEC_KINDS)}; got {self.vec!r}")
        for name in ("timesteps", "n_envs"):
            val = getattr(self, name)
            if val is not None and int(val) < 1:
                raise ValueError(f"{name} must be an integer >= 1 (or None), got {val}")
        for name in ("eval_freq", "checkpoint_freq"):
            val = getattr(self, name)
            if val is not None and int(val) < 0:
                raise ValueError(f"{name} must be >= 0 (0 = off) or None, got {val}")
        if int(self.eval_episodes) < 1:
            raise ValueError(f"eval_episodes must be >= 1, got {self.eval_episodes}")
        if self.torch_threads is not None and int(self.torch_threads) < 1:
            raise ValueError(f"torch_threads must be >= 1 or None, got {self.torch_threads}")
        if not isinstance(self.env_config, Mapping):
            raise ValueError(f"env_config must be a mapping, got {type(self.env_config).__name__}")

    def run_folder(self) -> Path:
        if self.out is not None:
            return Path(self.out)
        return Path("runs") / f"{self.env_id.split('/')[-1]}-{self.algo}-s{self.seed}"


@dataclass
class TrainResult:
    """What :func:`train` produced (paths are inside ``out``)."""

    out: Path
    model_path: Path
    vecnormalize_path: Path | None
    best_model_path: Path | None
    timesteps: int
    n_envs: int
    wall_time_s: float
    learn_time_s: float
    steps_per_s: float
    best_mean_reward: float | None
    hyperparams: HyperParams


def make_training_env(
    env_id: str,
    n_envs: int = 1,
    *,
    vec: str = "dummy",
    seed: int | None = 0,
    config: Mapping[str, Any] | None = None,
    monitor_dir: str | Path | None = None,
    normalize: Mapping[str, Any] | None = None,
    training: bool = True,
) -> Any:
    """A (VecNormalize-wrapped) SB3 VecEnv of ``env_id``; env ``i`` is seeded ``seed + i``.

    ``vec``: one of :data:`VEC_KINDS` (see :class:`TrainConfig`). ``normalize`` holds
    VecNormalize keyword arguments (None: no normalisation); with ``training=False`` its
    statistics are frozen and rewards are not normalised (for evaluation envs).
    """
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecNormalize

    bare = check_env_id(env_id)
    if vec not in VEC_KINDS:
        raise ValueError(f"vec must be one of {', '.join(VEC_KINDS)}; got {vec!r}")
    if vec == "native":
        venv = _native_vec_env(bare, int(n_envs), seed, config, monitor_dir)
    else:
        kwargs: dict[str, Any] = {
            "n_envs": int(n_envs),
            "seed": seed,
            "env_kwargs": {"config": dict(config or {})},
            "monitor_dir": None if monitor_dir is None else str(monitor_dir),
        }
        if vec == "subproc":
            kwargs.update(vec_env_cls=SubprocVecEnv, vec_env_kwargs={"start_method": "spawn"})
        else:
            kwargs.update(vec_env_cls=DummyVecEnv)
        venv = make_vec_env(MODULE_PREFIX + bare, **kwargs)
    if normalize is not None:
        venv = VecNormalize(venv, **dict(normalize))
        if not training:
            venv.training = False
            venv.norm_reward = False
    return venv


def _native_vec_env(
    bare: str,
    n_envs: int,
    seed: int | None,
    config: Mapping[str, Any] | None,
    monitor_dir: str | Path | None,
) -> Any:
    """The id's native vector env (every registered id has one) as an SB3 VecEnv: member
    ``i`` seeded ``seed + i`` at the first reset, episode statistics by ``VecMonitor``
    in ``monitor_dir``."""
    import gymnasium as gym
    from stable_baselines3.common.vec_env import VecMonitor

    from agents.vec_adapter import GymnasiumVecEnv

    venv = GymnasiumVecEnv(
        gym.make_vec(
            bare,
            num_envs=n_envs,
            vectorization_mode="vector_entry_point",
            config=dict(config or {}),
        )
    )
    venv.seed(seed)
    filename = None
    if monitor_dir is not None:
        Path(monitor_dir).mkdir(parents=True, exist_ok=True)
        filename = str(Path(monitor_dir) / "native")
    return VecMonitor(venv, filename=filename)


def _freq_calls(steps: int, n_envs: int) -> int:
    """SB3 callbacks count vectorised steps: env steps → calls."""
    return max(int(steps) // max(n_envs, 1), 1)


def _callbacks(
    cfg: TrainConfig, hp: HyperParams, out: Path, n_envs: int, timesteps: int, env_config: dict
) -> tuple[list[Any], Any]:
    from stable_baselines3.common.callbacks import BaseCallback, CheckpointCallback, EvalCallback

    callbacks: list[Any] = []
    eval_cb = None
    ck_freq = cfg.checkpoint_freq if cfg.checkpoint_freq is not None else timesteps // 4
    if ck_freq:
        callbacks.append(
            CheckpointCallback(
                save_freq=_freq_calls(ck_freq, n_envs),
                save_path=str(out / "checkpoints"),
                save_vecnormalize=hp.normalize is not None,
            )
        )
    ev_freq = cfg.eval_freq if cfg.eval_freq is not None else timesteps // 5
    if ev_freq:

        class _SaveBestStats(BaseCallback):
            """Saves the training env's VecNormalize stats beside the new best model."""

            def _on_step(self) -> bool:
                vn = self.model.get_vec_normalize_env()
                if vn is not None:
                    vn.save(str(out / "best" / "vecnormalize.pkl"))
                return True

        class _HeldOutEval(EvalCallback):
            """EvalCallback that re-seeds the eval envs before each evaluation, so every
            evaluation runs the same held-out episodes (env i: ``eval_seed + i``)."""

            def _on_step(self) -> bool:
                if self.eval_freq > 0 and self.n_calls % self.eval_freq == 0:
                    self.eval_env.seed(cfg.eval_seed)
                return super()._on_step()

        eval_env = make_training_env(
            cfg.env_id,
            cfg.eval_episodes,
            vec="dummy",
            seed=cfg.eval_seed,
            config=env_config,
            normalize=hp.normalize,
            training=False,
        )
        eval_cb = _HeldOutEval(
            eval_env,
            callback_on_new_best=_SaveBestStats(),
            n_eval_episodes=cfg.eval_episodes,
            eval_freq=_freq_calls(ev_freq, n_envs),
            log_path=str(out / "eval"),
            best_model_save_path=str(out / "best"),
            deterministic=True,
            verbose=cfg.verbose,
        )
        callbacks.append(eval_cb)
    return callbacks, eval_cb


def train(config: TrainConfig | None = None, **kwargs: Any) -> TrainResult:
    """Train a policy; ``train(TrainConfig(...))`` or ``train(env_id=..., algo=..., ...)``."""
    if config is not None and kwargs:
        raise ValueError("pass either a TrainConfig or keyword arguments, not both")
    cfg = config if config is not None else TrainConfig(**kwargs)
    cfg.validate()
    t0 = time.perf_counter()
    hp = resolve_hyperparams(
        cfg.algo, cfg.env_id, path=cfg.hyperparams_file, overrides=cfg.hyperparams
    )
    timesteps = int(cfg.timesteps if cfg.timesteps is not None else hp.n_timesteps)
    n_envs = int(cfg.n_envs if cfg.n_envs is not None else hp.n_envs)
    env_config = {**hp.env_config, **dict(cfg.env_config)}
    out = cfg.run_folder()
    out.mkdir(parents=True, exist_ok=True)

    import torch

    if cfg.torch_threads is not None:
        torch.set_num_threads(int(cfg.torch_threads))

    venv = make_training_env(
        cfg.env_id,
        n_envs,
        vec=cfg.vec,
        seed=cfg.seed,
        config=env_config,
        monitor_dir=out / "monitor",
        normalize=hp.normalize,
    )
    eval_cb = None
    try:
        n_actions = int(np.prod(venv.action_space.shape))
        tb = None
        if cfg.tensorboard and importlib.util.find_spec("tensorboard") is not None:
            tb = str(out / "tb")
        model = algo_class(cfg.algo)(
            hp.policy,
            venv,
            seed=cfg.seed,
            device=cfg.device,
            verbose=cfg.verbose,
            tensorboard_log=tb,
            **hp.constructor_kwargs(n_actions),
        )
        callbacks, eval_cb = _callbacks(cfg, hp, out, n_envs, timesteps, env_config)
        progress = bool(cfg.progress_bar)
        if progress and not (importlib.util.find_spec("tqdm") and importlib.util.find_spec("rich")):
            print("note: no progress bar (needs tqdm and rich: pip install rich)")
            progress = False
        _write_config(out, cfg, hp, timesteps, n_envs, env_config)
        t_learn = time.perf_counter()
        with warnings.catch_warnings():
            # subproc training env + in-process eval env is intended
            warnings.filterwarnings("ignore", message="Training and eval env are not of the same")
            model.learn(
                total_timesteps=timesteps,
                callback=callbacks or None,
                progress_bar=progress,
                tb_log_name=cfg.algo.upper(),
            )
        learn_time = time.perf_counter() - t_learn
        model_path = out / "model.zip"
        model.save(str(model_path))
        vn_path = None
        if hp.normalize is not None:
            vn_path = out / "vecnormalize.pkl"
            model.get_vec_normalize_env().save(str(vn_path))
        done = int(model.num_timesteps)
    finally:
        venv.close()
        if eval_cb is not None:
            eval_cb.eval_env.close()
    best = out / "best" / "best_model.zip"
    best_reward = None
    if eval_cb is not None and np.isfinite(eval_cb.best_mean_reward):
        best_reward = float(eval_cb.best_mean_reward)
    return TrainResult(
        out=out,
        model_path=model_path,
        vecnormalize_path=vn_path,
        best_model_path=best if best.is_file() else None,
        timesteps=done,
        n_envs=n_envs,
        wall_time_s=time.perf_counter() - t0,
        learn_time_s=learn_time,
        steps_per_s=done / max(learn_time, 1e-9),
        best_mean_reward=best_reward,
        hyperparams=hp,
    )


def _write_config(
    out: Path, cfg: TrainConfig, hp: HyperParams, timesteps: int, n_envs: int, env_config: dict
) -> None:
    import stable_baselines3
    import torch

    import train_envs

    record = {
        "env_id": cfg.env_id,
        "algo": cfg.algo,
        "seed": cfg.seed,
        "timesteps": timesteps,
        "n_envs": n_envs,
        "vec": cfg.vec,
        "env_config": env_config,
        "normalize": hp.normalize,
        "hyperparams_source": hp.source,
        "hyperparams": hp.raw,
        "eval_seeds": list(range(cfg.eval_seed, cfg.eval_seed + cfg.eval_episodes)),
        "train_config": {k: v for k, v in asdict(cfg).items() if k != "out"},
        "versions": {
            "train_envs": train_envs.__version__,
            "stable_baselines3": stable_baselines3.__version__,
            "torch": torch.__version__,
        },
    }
    (out / "config.json").write_text(json.dumps(_jsonable(record), indent=2) + "\n")


# ------------------------------------------------------------------- loading
@dataclass
class LoadedPolicy:
    """A reloaded model, its VecNormalize statistics (or None) and its run record."""

    model: Any
    vecnormalize: Any
    config: dict[str, Any]
    model_path: Path

    def predict(self, obs: np.ndarray) -> np.ndarray:
        """Deterministic action for one (unbatched) observation."""
        if self.vecnormalize is not None:
            obs = self.vecnormalize.normalize_obs(np.asarray(obs))
        return self.model.predict(obs, deterministic=True)[0]


def _find_model(path: Path) -> Path:
    if path.is_dir():
        for name in ("model.zip", "best_model.zip"):
            if (path / name).is_file():
                return path / name
        raise ValueError(f"policy folder {str(path)!r} holds no model.zip or best_model.zip")
    if path.is_file():
        return path
    if path.with_suffix(".zip").is_file():
        return path.with_suffix(".zip")
    raise ValueError(f"policy {str(path)!r} does not exist (a run folder or a .zip model)")


def _find_stats(model_path: Path) -> Path | None:
    folder = model_path.parent
    # ours, then rl-zoo3's layout (<run>/<env>.zip + <run>/<env>/vecnormalize.pkl)
    cands = [folder / "vecnormalize.pkl", folder / model_path.stem / "vecnormalize.pkl"]
    m = re.fullmatch(r"(.*)_(\d+)_steps", model_path.stem)
    if m:  # CheckpointCallback naming
        cands.insert(0, folder / f"{m.group(1)}_vecnormalize_{m.group(2)}_steps.pkl")
    return next((c for c in cands if c.is_file()), None)


def _find_record(model_path: Path) -> dict[str, Any]:
    for folder in (model_path.parent, model_path.parent.parent):
        f = folder / "config.json"
        if f.is_file():
            return json.loads(f.read_text())
    return {}


def _algo_from_zip(model_path: Path) -> str:
    from stable_baselines3.common.save_util import load_from_zip_file

    data, _, _ = load_from_zip_file(str(model_path), load_data=True, device="cpu")
    module = getattr((data or {}).get("policy_class"), "__module__", "")
    for algo in ("sac", "td3"):
        if f".{algo}." in module:
            return algo
    if "common.policies" in module or ".ppo." in module:
        return "ppo"
    raise ValueError(f"cannot tell the algorithm of {str(model_path)!r}; pass algo=ppo|sac|td3")


def load_policy(path: str | Path, algo: str | None = None, device: str = "cpu") -> LoadedPolicy:
    """Reload a model saved by :func:`train` (a run folder, ``best/`` or a ``.zip``).

    The VecNormalize statistics next to the model are loaded too (frozen); the
    algorithm comes from ``algo``, the run's ``config.json`` or the saved policy class.
    """
    model_path = _find_model(Path(path))
    record = _find_record(model_path)
    name = check_algo(algo or record.get("algo") or _algo_from_zip(model_path))
    model = algo_class(name).load(str(model_path), device=device)
    stats_path = _find_stats(model_path)
    vn = None
    if stats_path is not None:
        with open(stats_path, "rb") as fh:
            vn = pickle.load(fh)  # VecNormalize without its venv (SB3's own format)
        vn.training = False
        vn.norm_reward = False
    elif record.get("normalize") is not None:
        raise ValueError(
            f"{str(model_path)!r} was trained with VecNormalize but no statistics file "
            "(vecnormalize.pkl) lies beside it"
        )
    return LoadedPolicy(model=model, vecnormalize=vn, config=record, model_path=model_path)
