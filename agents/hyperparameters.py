"""Hyperparameters of the RL agents: rl-zoo3-format YAML files keyed by env id.

``agents/hyperparams/{ppo,sac,td3}.yml`` map an env id (or ``default``) to one entry.
An entry holds the constructor arguments of the stable-baselines3 algorithm plus
rl-zoo3's own keys, which are consumed here:

=================  ===============================================================
``n_timesteps``    training budget (env steps) when none is given
``n_envs``         number of parallel envs when none is given
``policy``         policy name (``MlpPolicy``)
``normalize``      ``false`` | ``true`` | ``{norm_obs: .., norm_reward: ..}`` or
                   rl-zoo3's string ``"dict(norm_obs=True, norm_reward=False)"``:
                   VecNormalize settings (saved with the model)
``env_kwargs``     ``{config: {...}}``: env config merged under the user's config
``noise_type``     ``normal`` | ``ornstein-uhlenbeck`` action noise (SAC/TD3), with
``noise_std``      its standard deviation (in action units, actions are in [-1, 1])
=================  ===============================================================

Values may use rl-zoo3's conventions: ``learning_rate: lin_3e-4`` (linear decay to 0;
also ``clip_range``), ``train_freq: [1, episode]`` and string ``policy_kwargs`` such as
``"dict(net_arch=[64, 64], activation_fn=nn.Tanh)"`` (parsed by a restricted literal
parser, never ``eval``).
"""

from __future__ import annotations

import ast
import copy
import inspect
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

ALGOS: tuple[str, ...] = ("ppo", "sac", "td3")
HYPERPARAMS_DIR = Path(__file__).resolve().parent / "hyperparams"

#: rl-zoo3 keys consumed here (not passed to the algorithm's constructor)
ZOO_KEYS = ("n_timesteps", "n_envs", "policy", "normalize", "env_kwargs", "noise_type", "noise_std")
#: rl-zoo3 keys this package does not implement
UNSUPPORTED_KEYS = (
    "frame_stack",
    "env_wrapper",
    "vec_env_wrapper",
    "callback",
    "monitor_kwargs",
    "replay_buffer_class",
)
SCHEDULE_KEYS = ("learning_rate", "clip_range", "clip_range_vf")
NOISE_TYPES = ("normal", "ornstein-uhlenbeck")

__all__ = [
    "ALGOS",
    "HYPERPARAMS_DIR",
    "HyperParams",
    "LinearSchedule",
    "algo_class",
    "check_algo",
    "hyperparams_path",
    "load_hyperparams_file",
    "parse_value",
    "resolve_hyperparams",
]


def check_algo(algo: str) -> str:
    """Lower-cased ``algo`` if it is one of :data:`ALGOS`, else a ValueError."""
    name = str(algo).lower()
    if name not in ALGOS:
        raise ValueError(f"algo must be one of {', '.join(ALGOS)}; got {algo!r}")
    return name


def algo_class(algo: str) -> type:
    """The stable-baselines3 class of ``algo`` (``ppo`` → ``PPO``, ...)."""
    import stable_baselines3 as sb3

    return {"ppo": sb3.PPO, "sac": sb3.SAC, "td3": sb3.TD3}[check_algo(algo)]


@dataclass(frozen=True)
class LinearSchedule:
    """rl-zoo3's ``lin_<value>``: decays linearly from ``initial`` to 0 over training."""

    initial: float

    def __call__(self, progress_remaining: float) -> float:
        return progress_remaining * self.initial


# ------------------------------------------------------------ safe literal parsing
def _torch_nn(name: str) -> Any:
    import torch.nn as nn

    obj = getattr(nn, name, None)
    if not (inspect.isclass(obj) and issubclass(obj, nn.Module)):
        raise ValueError(f"unknown torch.nn module {name!r} in hyperparameter string")
    return obj


def _literal(node: ast.AST) -> Any:
    if isinstance(node, ast.Constant):
        return node.value
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub | ast.UAdd):
        val = _literal(node.operand)
        if not isinstance(val, int | float):
            raise ValueError("unary sign on a non-number")
        return -val if isinstance(node.op, ast.USub) else val
    if isinstance(node, ast.List):
        return [_literal(e) for e in node.elts]
    if isinstance(node, ast.Tuple):
        return tuple(_literal(e) for e in node.elts)
    if isinstance(node, ast.Dict):
        return {_literal(k): _literal(v) for k, v in zip(node.keys, node.values, strict=True)}
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "dict":
        if node.args:
            raise ValueError("dict(...) takes keyword arguments only")
        return {kw.arg: _literal(kw.value) for kw in node.keywords}
    if (
        isinstance(node, ast.Attribute)
        and isinstance(node.value, ast.Name)
        and node.value.id in ("nn", "th", "torch")
    ):
        return _torch_nn(node.attr)
    if isinstance(node, ast.Name) and node.id in ("True", "False", "None"):
        return {"True": True, "False": False, "None": None}[node.id]
    raise ValueError(f"unsupported expression {ast.dump(node)}")


def parse_value(text: str) -> Any:
    """Parse rl-zoo3's Python-literal strings (``"dict(net_arch=[64, 64])"``) safely.

    Numbers, strings, lists, tuples, dicts, ``dict(...)`` calls and ``nn.<Module>``
    names are allowed; anything else is a ValueError.
    """
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except SyntaxError as exc:
        raise ValueError(f"cannot parse hyperparameter string {text!r}: {exc}") from exc
    try:
        return _literal(tree.body)
    except ValueError as exc:
        raise ValueError(f"cannot parse hyperparameter string {text!r}: {exc}") from exc


# ------------------------------------------------------------------- loading
def hyperparams_path(algo: str) -> Path:
    """The packaged YAML file of ``algo``."""
    return HYPERPARAMS_DIR / f"{check_algo(algo)}.yml"


def load_hyperparams_file(algo: str, path: str | Path | None = None) -> dict[str, dict[str, Any]]:
    """All entries of a hyperparameter YAML file (default: the packaged one of ``algo``)."""
    p = Path(path) if path is not None else hyperparams_path(algo)
    if not p.is_file():
        raise ValueError(f"hyperparameter file {str(p)!r} does not exist")
    with open(p, encoding="utf-8") as fh:
        data = yaml.safe_load(fh)
    if not isinstance(data, dict) or not all(isinstance(v, dict) for v in data.values()):
        raise ValueError(
            f"hyperparameter file {str(p)!r} must map env ids (and 'default') to mappings"
        )
    return data


@dataclass
class HyperParams:
    """One resolved hyperparameter entry.

    Attributes:
        algo, env_id: what it is for; source: the YAML key used (the id or ``default``).
        n_timesteps, n_envs, policy: rl-zoo3's budget, env count and policy name.
        normalize: VecNormalize keyword arguments, or None for no normalisation.
        env_config: env config from ``env_kwargs: {config: ...}``.
        noise_type, noise_std: action noise of SAC/TD3 (None = none).
        model_kwargs: the remaining constructor arguments (schedules resolved).
        raw: the entry as read (after overrides), JSON-able, for the run record.
    """

    algo: str
    env_id: str
    source: str
    n_timesteps: int
    n_envs: int
    policy: str
    normalize: dict[str, Any] | None
    env_config: dict[str, Any] = field(default_factory=dict)
    noise_type: str | None = None
    noise_std: float = 0.1
    model_kwargs: dict[str, Any] = field(default_factory=dict)
    raw: dict[str, Any] = field(default_factory=dict)

    def constructor_kwargs(self, n_actions: int) -> dict[str, Any]:
        """Keyword arguments of the SB3 constructor, action noise built for ``n_actions``."""
        kw = dict(self.model_kwargs)
        if self.noise_type is not None:
            import numpy as np
            from stable_baselines3.common.noise import (
                NormalActionNoise,
                OrnsteinUhlenbeckActionNoise,
            )

            cls = NormalActionNoise if self.noise_type == "normal" else OrnsteinUhlenbeckActionNoise
            kw["action_noise"] = cls(
                mean=np.zeros(n_actions), sigma=float(self.noise_std) * np.ones(n_actions)
            )
        return kw


def _normalize(value: Any) -> dict[str, Any] | None:
    if isinstance(value, str):
        value = parse_value(value)
    if value is None or value is False:
        return None
    if value is True:
        return {}
    if isinstance(value, Mapping):
        allowed = {"norm_obs", "norm_reward", "clip_obs", "clip_reward", "gamma", "epsilon"}
        bad = set(value) - allowed
        if bad:
            raise ValueError(
                f"hyperparameter normalize: unknown key(s) {sorted(bad)}; "
                f"allowed: {sorted(allowed)}"
            )
        return dict(value)
    raise ValueError(
        f"hyperparameter normalize must be true, false, a mapping or a dict(...) string; "
        f"got {value!r}"
    )


def _schedule(key: str, value: Any) -> Any:
    if isinstance(value, str):
        kind, _, num = value.partition("_")
        if kind != "lin" or not num:
            raise ValueError(
                f"hyperparameter {key}: string values must be 'lin_<number>', got {value!r}"
            )
        try:
            return LinearSchedule(float(num))
        except ValueError as exc:
            raise ValueError(f"hyperparameter {key}: bad number in {value!r}") from exc
    if isinstance(value, int | float) and not isinstance(value, bool):
        return float(value)
    raise ValueError(f"hyperparameter {key} must be a number or 'lin_<number>', got {value!r}")


def _constructor_args(algo: str) -> set[str]:
    cls = algo_class(algo)
    names = set(inspect.signature(cls.__init__).parameters) - {"self", "policy", "env"}
    return names - {"action_noise"}


def resolve_hyperparams(
    algo: str,
    env_id: str,
    *,
    path: str | Path | None = None,
    overrides: Mapping[str, Any] | None = None,
) -> HyperParams:
    """The entry of ``env_id`` (else ``default``) of ``algo``'s YAML file, validated.

    ``overrides`` replace keys of the entry (e.g. ``{"n_steps": 64}``); string values
    follow the YAML conventions. Unknown keys raise a ValueError listing the allowed ones.
    """
    algo = check_algo(algo)
    table = load_hyperparams_file(algo, path)
    if env_id in table:
        source = env_id
    elif "default" in table:
        source = "default"
    else:
        raise ValueError(
            f"no hyperparameters for {env_id!r} and no 'default' entry in "
            f"{str(path or hyperparams_path(algo))!r}"
        )
    entry = copy.deepcopy(table[source])
    entry.update(copy.deepcopy(dict(overrides or {})))
    raw = copy.deepcopy(entry)

    unsupported = [k for k in UNSUPPORTED_KEYS if k in entry]
    if unsupported:
        raise ValueError(f"hyperparameter(s) {unsupported} are rl-zoo3 features not supported here")
    allowed = _constructor_args(algo)
    unknown = sorted(set(entry) - allowed - set(ZOO_KEYS))
    if unknown:
        raise ValueError(
            f"unknown {algo} hyperparameter(s) {unknown}; allowed: "
            f"{', '.join(sorted(allowed | set(ZOO_KEYS)))}"
        )
    if "n_timesteps" not in entry:
        raise ValueError(f"hyperparameter entry {source!r} of {algo} lacks n_timesteps")
    n_timesteps = int(float(entry.pop("n_timesteps")))
    n_envs = int(entry.pop("n_envs", 1))
    if n_timesteps < 1 or n_envs < 1:
        raise ValueError(f"n_timesteps and n_envs must be >= 1, got {n_timesteps}, {n_envs}")
    policy = str(entry.pop("policy", "MlpPolicy"))
    if policy not in ("MlpPolicy",):
        raise ValueError(
            f"hyperparameter policy must be 'MlpPolicy' (flat Box observations), got {policy!r}"
        )
    normalize = _normalize(entry.pop("normalize", False))
    env_kwargs = entry.pop("env_kwargs", None) or {}
    if not isinstance(env_kwargs, Mapping) or set(env_kwargs) - {"config"}:
        raise ValueError(
            f"hyperparameter env_kwargs must be {{config: {{...}}}}, got {env_kwargs!r}"
        )
    env_config = dict(env_kwargs.get("config") or {})
    noise_type = entry.pop("noise_type", None)
    noise_std = float(entry.pop("noise_std", 0.1))
    if noise_type is not None:
        noise_type = str(noise_type).strip()
        if noise_type not in NOISE_TYPES:
            raise ValueError(f"noise_type must be one of {NOISE_TYPES}, got {noise_type!r}")
        if algo == "ppo":
            raise ValueError("noise_type (action noise) applies to sac and td3 only, not ppo")
    for key in SCHEDULE_KEYS:
        if key in entry and not (key == "clip_range_vf" and entry[key] is None):
            entry[key] = _schedule(key, entry[key])
    if isinstance(entry.get("train_freq"), list):
        entry["train_freq"] = tuple(entry["train_freq"])
    for key in ("policy_kwargs", "replay_buffer_kwargs"):
        if isinstance(entry.get(key), str):
            entry[key] = parse_value(entry[key])
    if normalize is not None and "gamma" in entry:
        normalize.setdefault("gamma", float(entry["gamma"]))
    return HyperParams(
        algo=algo,
        env_id=env_id,
        source=source,
        n_timesteps=n_timesteps,
        n_envs=n_envs,
        policy=policy,
        normalize=normalize,
        env_config=env_config,
        noise_type=noise_type,
        noise_std=noise_std,
        model_kwargs=entry,
        raw=raw,
    )
