"""The env's configuration: six sections, with flat keys as aliases.

``gymnasium.make(id, config={...})`` merges ``config`` over the id's base config, itself
merged over the defaults (HighwayEnv's convention). A config names a section and its
fields, ``{"action": {"mode": "delta"}}``, or a field by its flat key,
``{"action_mode": "delta"}``; both give the same env. ``"scenario"`` and
``"controller"`` given a string name the scenario / controller (the flat form), given a
mapping set the section.

==========================  ======================  ========================================
section.field               flat key                meaning
==========================  ======================  ========================================
scenario.name               ``scenario``            scenario (``train-envs list scenarios``)
scenario.overrides          ``scenario_overrides``  ``Scenario`` field overrides
scenario.real_line          ``real_line``           real-line mode (:class:`ScenarioConfig`)
scenario.disturbance        ``disturbance``         ``DisturbanceSpec`` fields
controller.name             ``controller``          the inner controller
controller.params           ``controller_params``   its fixed constructor arguments
action.params               ``action_params``       exposed tunable parameters (None: all)
action.bounds               ``action_bounds``       name -> (low, high) narrowing its range
action.mode                 ``action_mode``         ``"absolute"`` or ``"delta"``
action.delta_scale          ``delta_scale``         delta mode: unit change at ``|a| = 1``
observation.preview_m       ``preview_m``           preview distance [m]
observation.preview_points  ``preview_points``      preview points (0: none)
reward.weights              ``reward_weights``      objective -> weight
episode.decision_interval   ``decision_interval``   control steps per env step
episode.max_steps           ``max_episode_steps``   cap on env steps (None: no cap)
episode.supervision         ``supervision``         ATP settings (``Supervision`` fields)
==========================  ======================  ========================================

Merge rule: a later layer's mapping merges into the earlier one key by key, nested
mappings recursively (``{"real_line": {"sections": [(0, 1)]}}`` keeps the id's track
and train, ``{"controller_params": {"Np": 20}}`` keeps its other arguments); any other
value (``None`` included) replaces. To undo what an id sets, give the value wanted
(e.g. the constructor's default). Unknown keys and bad values raise a one-line
``ValueError`` naming the key and what it allows.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import numbers
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from train_envs.envs.reward import DEFAULT_WEIGHTS, OBJECTIVES
from train_envs.scenarios import DisturbanceSpec
from train_envs.simulation import Supervision

#: flat key -> (section, field), in the order of :meth:`EnvConfig.flat`
FLAT_KEYS: dict[str, tuple[str, str]] = {
    "scenario": ("scenario", "name"),
    "scenario_overrides": ("scenario", "overrides"),
    "real_line": ("scenario", "real_line"),
    "controller": ("controller", "name"),
    "controller_params": ("controller", "params"),
    "action_params": ("action", "params"),
    "action_bounds": ("action", "bounds"),
    "action_mode": ("action", "mode"),
    "delta_scale": ("action", "delta_scale"),
    "decision_interval": ("episode", "decision_interval"),
    "preview_m": ("observation", "preview_m"),
    "preview_points": ("observation", "preview_points"),
    "reward_weights": ("reward", "weights"),
    "disturbance": ("scenario", "disturbance"),
    "max_episode_steps": ("episode", "max_steps"),
    "supervision": ("episode", "supervision"),
}
_FLAT_OF = {target: flat for flat, target in FLAT_KEYS.items()}
REAL_LINE_KEYS = ("track", "train", "sections", "time_supplement")
ACTION_MODES = ("absolute", "delta")


def _name(section: str, name: str) -> str:
    return f"config {section}.{name} ({_FLAT_OF[section, name]})"


def _integer(section: str, name: str, value: Any, low: int) -> int:
    ok = isinstance(value, numbers.Real) and not isinstance(value, bool)
    if not (ok and math.isfinite(value) and float(value).is_integer() and value >= low):
        raise ValueError(f"{_name(section, name)} must be an integer >= {low}, got {value!r}")
    return int(value)


def _real(section: str, name: str, value: Any, low: float, strict: bool) -> float:
    ok = isinstance(value, numbers.Real) and not isinstance(value, bool)
    x = float(value) if ok else math.nan
    if not (math.isfinite(x) and (x > low if strict else x >= low)):
        bound = f"> {low}" if strict else f">= {low}"
        raise ValueError(f"{_name(section, name)} must be a finite number {bound}, got {value!r}")
    return x


def _mapping(section: str, name: str, value: Any, allowed: Sequence[str] | None = None) -> dict:
    if not isinstance(value, Mapping):
        raise ValueError(f"{_name(section, name)} must be a mapping, got {value!r}")
    if allowed is not None:
        bad = sorted(set(value) - set(allowed))
        if bad:
            raise ValueError(
                f"unknown {_name(section, name)} key(s) {bad}; allowed: {sorted(allowed)}"
            )
    return copy.deepcopy(dict(value))


def _text(section: str, name: str, value: Any) -> str:
    if not isinstance(value, str) or not value:
        raise ValueError(f"{_name(section, name)} must be a non-empty string, got {value!r}")
    return value


@dataclass
class ScenarioConfig:
    """Which run the env simulates.

    Attributes:
        name: scenario name; not used when ``real_line`` is set.
        overrides: :class:`~train_envs.scenarios.Scenario` field overrides.
        real_line: ``None``, or real-line mode ``{"track": ..., "train": ...`` (catalogue
            names or paths of the user's TTOBench-format JSON files) ``, "sections":
            [(i, j), ...] or None for every consecutive pair of stops,
            "time_supplement": 0.08}``: reset samples a station-to-station run.
        disturbance: :class:`~train_envs.scenarios.DisturbanceSpec` fields merged over
            the scenario's own (disturbances, domain randomisation).
    """

    name: str = "paper001_stopping"
    overrides: dict[str, Any] = field(default_factory=dict)
    real_line: dict[str, Any] | None = None
    disturbance: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.name = _text("scenario", "name", self.name)
        self.overrides = _mapping("scenario", "overrides", self.overrides)
        if self.real_line is not None:
            self.real_line = _mapping("scenario", "real_line", self.real_line, REAL_LINE_KEYS)
            rl = self.real_line
            for key in ("track", "train"):
                if key not in rl:
                    raise ValueError(f"{_name('scenario', 'real_line')} needs the key {key!r}")
                if not isinstance(rl[key], (str, os.PathLike)) or not rl[key]:
                    raise ValueError(
                        f"{_name('scenario', 'real_line')} {key} must be a catalogue name or "
                        f"a JSON path, got {rl[key]!r}"
                    )
            if "time_supplement" in rl:
                ts = rl["time_supplement"]
                ok = isinstance(ts, numbers.Real) and not isinstance(ts, bool)
                if not (ok and 0.0 <= ts <= 1.0):
                    raise ValueError(
                        f"{_name('scenario', 'real_line')} time_supplement must be a number "
                        f"in [0, 1], got {ts!r}"
                    )
            sections = rl.get("sections")
            if sections is not None:
                ok = isinstance(sections, Sequence) and len(sections) > 0
                ok = ok and all(
                    isinstance(p, Sequence)
                    and len(p) == 2
                    and all(isinstance(i, int) and not isinstance(i, bool) for i in p)
                    and 0 <= p[0] < p[1]
                    for p in sections
                )
                if not ok:
                    raise ValueError(
                        f"{_name('scenario', 'real_line')} sections must be None or a non-empty "
                        f"list of stop pairs (i, j) with 0 <= i < j, got {sections!r}"
                    )
        fields = tuple(DisturbanceSpec.__dataclass_fields__)
        self.disturbance = _mapping("scenario", "disturbance", self.disturbance, fields)


@dataclass
class ControllerConfig:
    """The inner controller.

    Attributes:
        name: controller name (:data:`train_envs.controllers.CONTROLLERS`).
        params: fixed values of its constructor arguments (the exposed tunable
            parameters start from them every episode).
    """

    name: str = "pid"
    params: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.name = _text("controller", "name", self.name)
        self.params = _mapping("controller", "params", self.params)


@dataclass
class ActionConfig:
    """The action (see :mod:`train_envs.envs.action`).

    Attributes:
        params: names of the exposed tunable parameters, in action order (``None``: all
            of the controller's).
        bounds: parameter name -> ``(low, high)`` replacing its range (inside the
            controller's own range; the action's ``±1`` map to them).
        mode: ``"absolute"`` or ``"delta"``.
        delta_scale: delta mode: unit-range change per env step at ``|a| = 1``.
    """

    params: list[str] | None = None
    mode: str = "absolute"
    delta_scale: float = 0.1
    bounds: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        p = self.params
        if p is not None:
            if isinstance(p, str) or not isinstance(p, Sequence) or not p:
                raise ValueError(
                    f"{_name('action', 'params')} must be None or a non-empty list of "
                    f"parameter names, got {p!r}"
                )
            self.params = [_text("action", "params", n) for n in p]
        if self.mode not in ACTION_MODES:
            raise ValueError(
                f"{_name('action', 'mode')} must be 'absolute' or 'delta', got {self.mode!r}"
            )
        self.delta_scale = _real("action", "delta_scale", self.delta_scale, 0.0, strict=True)
        self.bounds = _mapping("action", "bounds", self.bounds)
        for n, b in self.bounds.items():
            ok = isinstance(b, Sequence) and not isinstance(b, str) and len(b) == 2
            ok = ok and all(isinstance(x, numbers.Real) and math.isfinite(x) for x in b)
            if not (ok and b[0] < b[1]):
                raise ValueError(
                    f"{_name('action', 'bounds')} {n!r} must be a pair (low, high) of finite "
                    f"numbers with low < high, got {b!r}"
                )
            self.bounds[n] = (float(b[0]), float(b[1]))


@dataclass
class ObservationConfig:
    """The preview part of the observation (see :mod:`train_envs.envs.observation`).

    Attributes:
        preview_m: preview distance of the gradient / speed-limit features [m].
        preview_points: points from the train's position to ``preview_m``, evenly spaced.
    """

    preview_m: float = 600.0
    preview_points: int = 3

    def __post_init__(self) -> None:
        self.preview_m = _real("observation", "preview_m", self.preview_m, 0.0, strict=False)
        self.preview_points = _integer("observation", "preview_points", self.preview_points, 0)


@dataclass
class RewardConfig:
    """The reward (see :mod:`train_envs.envs.reward`).

    Attributes:
        weights: objective (:data:`~train_envs.envs.reward.OBJECTIVES`) -> weight >= 0.
    """

    weights: dict[str, float] = field(default_factory=lambda: dict(DEFAULT_WEIGHTS))

    def __post_init__(self) -> None:
        w = _mapping("reward", "weights", self.weights, OBJECTIVES)
        self.weights = {k: _real("reward", "weights", v, 0.0, strict=False) for k, v in w.items()}


@dataclass
class EpisodeConfig:
    """Env step and episode length.

    Attributes:
        decision_interval: control steps per env step.
        max_steps: cap on env steps (``None``: the scenario's ``t_max`` alone ends it).
        supervision: :class:`~train_envs.simulation.Supervision` fields (ATP on/off,
            its margin, ending the episode at a safety violation) over its defaults.
    """

    decision_interval: int = 5
    max_steps: int | None = None
    supervision: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        di = self.decision_interval
        self.decision_interval = _integer("episode", "decision_interval", di, 1)
        if self.max_steps is not None:
            self.max_steps = _integer("episode", "max_steps", self.max_steps, 1)
        fields = tuple(Supervision.__dataclass_fields__)
        self.supervision = _mapping("episode", "supervision", self.supervision, fields)
        try:
            Supervision(**self.supervision)
        except ValueError as exc:
            raise ValueError(f"{_name('episode', 'supervision')}: {exc}") from None

    def supervisor(self) -> Supervision:
        """The runner's :class:`~train_envs.simulation.Supervision` of these settings."""
        return Supervision(**self.supervision)


SECTIONS: dict[str, type] = {
    "scenario": ScenarioConfig,
    "controller": ControllerConfig,
    "action": ActionConfig,
    "observation": ObservationConfig,
    "reward": RewardConfig,
    "episode": EpisodeConfig,
}


@dataclass
class EnvConfig:
    """The env's configuration, one dataclass per section."""

    scenario: ScenarioConfig = field(default_factory=ScenarioConfig)
    controller: ControllerConfig = field(default_factory=ControllerConfig)
    action: ActionConfig = field(default_factory=ActionConfig)
    observation: ObservationConfig = field(default_factory=ObservationConfig)
    reward: RewardConfig = field(default_factory=RewardConfig)
    episode: EpisodeConfig = field(default_factory=EpisodeConfig)

    @classmethod
    def resolve(cls, *layers: Mapping[str, Any] | None) -> EnvConfig:
        """The defaults with ``layers`` (sectioned, flat or mixed) merged over them in
        order."""
        state = cls().to_dict()
        for layer in layers:
            for (section, name), value in _targets(layer or {}).items():
                state[section][name] = merge(state[section][name], value)
        return cls(**{s: SECTIONS[s](**fields) for s, fields in state.items()})

    def to_dict(self) -> dict[str, dict[str, Any]]:
        """The sections as nested dicts (deep copies)."""
        return dataclasses.asdict(self)

    def flat(self) -> dict[str, Any]:
        """Every field under its flat key (deep copies)."""
        d = self.to_dict()
        return {flat: d[section][name] for flat, (section, name) in FLAT_KEYS.items()}


def merge(base: Any, over: Any) -> Any:
    """``over`` merged over ``base`` (the module's merge rule): mappings key by key,
    recursively; anything else replaces."""
    if not (isinstance(base, Mapping) and isinstance(over, Mapping)):
        return copy.deepcopy(over)
    out = dict(base)
    for key, value in over.items():
        out[key] = merge(out.get(key), value)
    return out


def _targets(layer: Mapping[str, Any]) -> dict[tuple[str, str], Any]:
    """``(section, field) -> value`` of one config layer; unknown keys and fields set
    twice are errors."""
    out: dict[tuple[str, str], Any] = {}
    given: dict[tuple[str, str], str] = {}

    def put(target: tuple[str, str], key: str, value: Any) -> None:
        if target in out:
            raise ValueError(
                f"config sets {target[0]}.{target[1]} twice ({given[target]!r} and {key!r})"
            )
        out[target], given[target] = value, key

    for key, value in layer.items():
        if key in SECTIONS and (isinstance(value, Mapping) or key not in FLAT_KEYS):
            if not isinstance(value, Mapping):
                raise ValueError(f"config {key} must be a mapping of its fields, got {value!r}")
            allowed = [f.name for f in dataclasses.fields(SECTIONS[key])]
            for name, v in value.items():
                if name not in allowed:
                    raise ValueError(
                        f"unknown config key {key}.{name!s}; allowed keys of section {key}: "
                        f"{', '.join(allowed)}"
                    )
                put((key, name), f"{key}.{name}", v)
        elif key in FLAT_KEYS:
            put(FLAT_KEYS[key], key, value)
        else:
            raise ValueError(
                f"unknown config key {key!r}; allowed keys: sections "
                f"{', '.join(SECTIONS)} or flat keys {', '.join(sorted(FLAT_KEYS))}"
            )
    return out
