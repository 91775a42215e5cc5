"""Gymnasium env whose action is the inner controller's tuning parameters.

The env holds a scenario (plant + line + reference) and a controller, and runs the one
closed-loop runner (:class:`train_envs.simulation.ClosedLoop`): every env step applies
the action to the controller's tunable parameters, then runs ``decision_interval``
control steps, the controller (an MPC, a PID, ...) computing the command at each. It
adds no physics and no control of its own.

Configuration follows HighwayEnv's convention: ``gymnasium.make(id, config={...})``
merges ``config`` over :meth:`TrainTuningEnv.default_config`; unknown keys raise a
``ValueError`` naming the key and listing the allowed ones.

Action: ``Box(-1, 1, (n,))`` over the ``n`` exposed parameters. ``action_mode =
"absolute"``: each component maps to the parameter's range (log-uniform where the spec
says ``log``); ``"delta"``: it moves the parameter by ``delta_scale`` of its (unit)
range per step. Out-of-range actions are clipped and counted in ``info``; NaN/inf
raise ``ValueError``.

Observation (all features scaled to roughly [−1, 1] and clipped to [−10, 10]; the
feature names are in ``env.observation_names``):

======================  =====================================================
``v_err``               (v_ref − v) / 5 m/s
``s_err``               (s_ref − s) / 50 m
``v``                   v / v_max (train design speed or line maximum)
``dist_to_stop``        distance to the stop / 1000 m (cruise runs: to the end)
``slack``               schedule slack: t_ref(s) − t, / 30 s
``grad_ahead_k``        equivalent gradient at s + k·preview/(n−1), / 30 ‰
``limit_ahead_k``       speed limit at the same points, / v_max
``u``                   current command / max traction force
``du``                  command rate / (max traction force per second)
``prev_action_i``       previous action components
``solver_flag``         1 if the controller fell back (solver failure) last step
======================  =====================================================

Reward: ``−Σ_k w · c_k`` over the control steps of the env step, with per-step costs
(state at the start of each control period, as the runner records it)
``tracking = (v_err / 1 m/s)² dt``, ``jerk = (Δa/dt)² dt``, ``energy`` = traction
energy increment [kWh] net of regeneration, ``violation`` = overspeed [m/s]·dt +
saturation·dt; at the end ``stop`` = |stop error| [m] and ``punctuality`` =
|t − t_scheduled| / 10 s. ``info["objectives"]`` carries every component each step;
the final step's ``info["episode_metrics"]`` carries :func:`train_envs.metrics.
episode_metrics`.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from train_envs.controllers import make_controller
from train_envs.controllers.base import Controller, TunableParam
from train_envs.plants.lookup import gradient_table
from train_envs.scenarios import DisturbanceSpec, Scenario, get_scenario, real_line_scenario
from train_envs.simulation import ClosedLoop

OBJECTIVES = ("tracking", "jerk", "energy", "violation", "stop", "punctuality")
OBS_CLIP = 10.0


def _merge(base: dict[str, Any], update: Mapping[str, Any], path: str = "config") -> dict[str, Any]:
    """Recursively merge ``update`` into a copy of ``base``; unknown keys are errors."""
    out = copy.deepcopy(base)
    for key, value in update.items():
        if key not in base:
            raise ValueError(f"unknown {path} key {key!r}; allowed keys: {', '.join(sorted(base))}")
        if isinstance(base[key], dict) and isinstance(value, Mapping) and key not in _FREE_DICTS:
            out[key] = _merge(base[key], value, f"{path}.{key}")
        else:
            out[key] = copy.deepcopy(value)
    return out


#: config dictionaries whose keys are free-form (validated elsewhere)
_FREE_DICTS = {"scenario_overrides", "controller_params", "disturbance", "real_line"}


class TrainTuningEnv(gym.Env):
    """Train + line + inner controller; the action sets the controller's tuning parameters."""

    metadata = {"render_modes": ["rgb_array", "human"], "render_fps": 4}

    @classmethod
    def default_config(cls) -> dict[str, Any]:
        """The documented defaults (every key, with its meaning)."""
        return {
            # scenario name (``train-envs list scenarios``) and Scenario field overrides
            "scenario": "paper001_stopping",
            "scenario_overrides": {},
            # real-line mode: {"track": ..., "train": ..., "sections": [(i, j), ...] or
            # None for every consecutive pair, "time_supplement": 0.08}; reset samples a
            # station-to-station run. None = use ``scenario``.
            "real_line": None,
            # inner controller name and fixed values of its non-exposed parameters
            "controller": "pid",
            "controller_params": {},
            # which tunable parameters form the action (None = all of the controller's)
            "action_params": None,
            "action_mode": "absolute",  # or "delta"
            "delta_scale": 0.1,  # delta mode: unit-range change per step at |a| = 1
            "decision_interval": 5,  # control steps per env step
            "preview_m": 600.0,  # gradient / limit preview distance
            "preview_points": 3,
            "reward_weights": {
                "tracking": 1.0,
                "jerk": 0.05,
                "energy": 0.0,
                "violation": 10.0,
                "stop": 5.0,
                "punctuality": 1.0,
            },
            # disturbances / domain randomisation (DisturbanceSpec fields), merged over
            # the scenario's own
            "disturbance": {},
            # cap on env steps (None = from the scenario's t_max)
            "max_episode_steps": None,
        }

    def __init__(
        self,
        config: Mapping[str, Any] | None = None,
        render_mode: str | None = None,
        base_config: Mapping[str, Any] | None = None,
    ):
        super().__init__()
        # registered ids pass their settings as ``base_config``; the user's ``config``
        # is merged over them
        self.config = _merge(_merge(self.default_config(), base_config or {}), config or {})
        cfg = self.config
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode must be one of {self.metadata['render_modes']}, got {render_mode!r}"
            )
        self.render_mode = render_mode
        if cfg["action_mode"] not in ("absolute", "delta"):
            raise ValueError(
                f"config action_mode must be 'absolute' or 'delta', got {cfg['action_mode']!r}"
            )
        if int(cfg["decision_interval"]) < 1:
            raise ValueError(
                f"config decision_interval must be an integer >= 1, got {cfg['decision_interval']}"
            )
        for key in cfg["reward_weights"]:
            if key not in OBJECTIVES:
                raise ValueError(f"unknown reward_weights key {key!r}; allowed: {OBJECTIVES}")
        self._dist_overrides = dict(cfg["disturbance"])
        bad = set(self._dist_overrides) - set(DisturbanceSpec.__dataclass_fields__)
        if bad:
            raise ValueError(
                f"unknown disturbance key(s) {sorted(bad)}; allowed: "
                f"{sorted(DisturbanceSpec.__dataclass_fields__)}"
            )

        self._sections: list[tuple[int, int]] | None = None
        self._section_cache: dict[tuple[int, int], Scenario] = {}
        self.scenario = self._initial_scenario()
        self.controller: Controller = make_controller(
            cfg["controller"], self.scenario, **cfg["controller_params"]
        )
        specs = {p.name: p for p in self.controller.tunable_params()}
        names = list(specs) if cfg["action_params"] is None else list(cfg["action_params"])
        for n in names:
            if n not in specs:
                raise ValueError(
                    f"config action_params: {cfg['controller']} has no tunable parameter {n!r}; "
                    f"allowed: {', '.join(specs)}"
                )
        if not names:
            raise ValueError(f"controller {cfg['controller']} exposes no tunable parameters")
        self.param_specs: tuple[TunableParam, ...] = tuple(specs[n] for n in names)
        self._base_params = self.controller.get_params()
        n = len(self.param_specs)
        self.action_space = spaces.Box(-1.0, 1.0, shape=(n,), dtype=np.float32)

        self.observation_names = self._observation_names()
        self._n_preview = int(cfg["preview_points"])
        self._preview_offsets = np.linspace(0.0, float(cfg["preview_m"]), self._n_preview)
        self._obs_buf = np.zeros(len(self.observation_names))
        self.observation_space = spaces.Box(
            -OBS_CLIP, OBS_CLIP, shape=(len(self.observation_names),), dtype=np.float32
        )
        self.loop = ClosedLoop(self.scenario, self.controller)
        self._weights = {k: float(cfg["reward_weights"].get(k, 0.0)) for k in OBJECTIVES}
        self._fig = None

    # ----------------------------------------------------------------- scenarios
    def _with_disturbance(self, sc: Scenario) -> Scenario:
        over = dict(self.config["scenario_overrides"])
        if self._dist_overrides:
            base = sc.disturbance.__dict__ | self._dist_overrides
            over["disturbance"] = DisturbanceSpec(
                **{k: tuple(v) if isinstance(v, list) else v for k, v in base.items()}
            )
        return sc.with_overrides(**over) if over else sc

    def _initial_scenario(self) -> Scenario:
        rl = self.config["real_line"]
        if rl is None:
            return self._with_disturbance(get_scenario(self.config["scenario"]))
        allowed = {"track", "train", "sections", "time_supplement"}
        bad = set(rl) - allowed
        if bad:
            raise ValueError(f"unknown real_line key(s) {sorted(bad)}; allowed: {sorted(allowed)}")
        from train_envs.lines import get_track

        track = get_track(rl["track"])
        n_stops = len(track.stops_m)
        sections = rl.get("sections") or [(i, i + 1) for i in range(n_stops - 1)]
        self._sections = [tuple(s) for s in sections]
        return self._section_scenario(self._sections[0])

    def _section_scenario(self, sec: tuple[int, int]) -> Scenario:
        if sec not in self._section_cache:
            rl = self.config["real_line"]
            sc = real_line_scenario(
                rl["track"],
                rl["train"],
                sec[0],
                sec[1],
                time_supplement=float(rl.get("time_supplement", 0.08)),
            )
            self._section_cache[sec] = self._with_disturbance(sc)
        return self._section_cache[sec]

    # ------------------------------------------------------------ observation
    def _observation_names(self) -> list[str]:
        k = int(self.config["preview_points"])
        names = ["v_err", "s_err", "v", "dist_to_stop", "slack"]
        names += [f"grad_ahead_{i}" for i in range(k)]
        names += [f"limit_ahead_{i}" for i in range(k)]
        names += ["u", "du"]
        names += [f"prev_action_{p.name}" for p in self.param_specs]
        names += ["solver_flag"]
        return names

    def _observe(self) -> np.ndarray:
        sc, loop = self.scenario, self.loop
        p = loop.plant
        t, s, v = p.t, p.s, p.v
        ref = sc.reference
        v_max = self._v_scale
        end = sc.s_stop_m if sc.s_stop_m is not None else ref.end_m
        t_ref = float(ref.profile.t_at_s(s))
        pts = s + self._preview_offsets
        grads = gradient_table(sc.track)(pts) * (1.0 / 30.0)
        lims = sc.track.speed_limit_at(pts) * (1.0 / v_max)
        u = float(loop.u_prev.sum())
        u_scale = sc.train.max_traction_force_N
        du = (u - self._u_before) / (u_scale * sc.dt_ctrl_s * self.config["decision_interval"])
        obs = self._obs_buf
        obs[:5] = (
            (ref.v_ref(t, s) - v) / 5.0,
            (ref.s_ref(t) - s) / 50.0,
            v / v_max,
            (end - s) / 1000.0,
            (t_ref - t) / 30.0,
        )
        k = self._n_preview
        obs[5 : 5 + k] = grads
        obs[5 + k : 5 + 2 * k] = lims
        j = 5 + 2 * k
        obs[j : j + 2] = (u / u_scale, du)
        na = self._prev_action.size
        obs[j + 2 : j + 2 + na] = self._prev_action
        obs[-1] = float(bool(loop.last_info.get("fallback", False)))
        return np.clip(np.nan_to_num(obs), -OBS_CLIP, OBS_CLIP).astype(np.float32)  # copy

    # ------------------------------------------------------------- gym API
    def reset(self, *, seed: int | None = None, options: Mapping[str, Any] | None = None):
        super().reset(seed=seed)
        if self._sections is not None:
            sec = self._sections[int(self.np_random.integers(len(self._sections)))]
            if options and "section" in options:
                sec = tuple(options["section"])
            self.scenario = self._section_scenario(sec)
        episode_seed = int(self.np_random.integers(2**31 - 1))
        self.controller.set_params(**self._base_params)
        self.loop.reset(seed=episode_seed, scenario=self.scenario)
        sc = self.scenario
        self._v_scale = max(float(np.max(sc.track.speed_limits_mps)), 1.0)
        if math.isfinite(sc.train.max_speed_mps):
            self._v_scale = min(self._v_scale, sc.train.max_speed_mps) or self._v_scale
        self._base_unit = [p.to_unit(self._base_params[p.name]) for p in self.param_specs]
        self._unit = np.array(self._base_unit, dtype=float)
        self._prev_action = self._unit.copy()
        self._u_before = float(np.sum(self.loop.u_prev))
        self._a_prev = self.loop.plant.accel
        self._energy_prev = 0.0
        self._steps = 0
        self._clipped_total = 0
        cap = self.config["max_episode_steps"]
        self._max_steps = int(cap) if cap else None
        obs = self._observe()
        return obs, {"scenario": sc.name, "params": self.controller.get_params()}

    def _apply_action(self, action: np.ndarray) -> int:
        a = np.asarray(action, dtype=float).reshape(-1)
        if a.shape != (len(self.param_specs),):
            raise ValueError(f"action must have shape ({len(self.param_specs)},), got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"action must be finite, got {a}")
        clipped = int(np.sum(np.abs(a) > 1.0))
        a = np.clip(a, -1.0, 1.0)
        if self.config["action_mode"] == "absolute":
            unit = a
        else:
            unit = np.clip(self._unit + float(self.config["delta_scale"]) * a, -1.0, 1.0)
        self._unit = unit
        self._prev_action = a
        # the unit value of a base parameter maps back onto it exactly (from_unit and
        # to_unit are inverse only up to rounding)
        base = self._base_unit
        self.controller.set_params(
            **{
                p.name: self._base_params[p.name] if u == base[i] else p.from_unit(u)
                for i, (p, u) in enumerate(zip(self.param_specs, unit, strict=True))
            }
        )
        return clipped

    def step(self, action):
        clipped = self._apply_action(action)
        self._clipped_total += clipped
        loop, sc = self.loop, self.scenario
        dt = sc.dt_ctrl_s
        self._u_before = float(np.sum(loop.u_prev))
        costs = dict.fromkeys(OBJECTIVES, 0.0)
        tr = sc.train
        k0 = loop.k
        for _ in range(int(self.config["decision_interval"])):
            loop.step()
            if loop.done:
                break
        # per-control-step costs from the rows the runner recorded (state at the start
        # of each control period)
        rows = loop.columns(k0, loop.k)
        v = rows["v_mps"]
        e_v = rows["v_ref_mps"] - v
        costs["tracking"] = float(e_v @ e_v) * dt
        a = rows["a_mps2"]
        jerk = np.diff(a, prepend=self._a_prev) / dt
        costs["jerk"] = float(jerk @ jerk) * dt
        self._a_prev = float(a[-1])
        over = np.maximum(v - rows["v_limit_mps"], 0.0)
        costs["violation"] = float(over.sum() + rows["saturated"].sum()) * dt
        p = loop.plant
        energy = (
            p.work_traction_J / tr.traction_efficiency - tr.regen_efficiency * p.work_brake_J
        ) / 3.6e6
        costs["energy"] = energy - self._energy_prev
        self._energy_prev = energy
        self._steps += 1
        terminated = loop.terminated
        truncated = loop.truncated or (
            self._max_steps is not None and self._steps >= self._max_steps
        )
        info: dict[str, Any] = {
            "action_clipped": clipped,
            "action_clipped_total": self._clipped_total,
            "params": self.controller.get_params(),
        }
        if terminated or truncated:
            if sc.s_stop_m is not None:
                costs["stop"] = abs(loop.plant.s - sc.s_stop_m)
            if sc.scheduled_time_s is not None:
                costs["punctuality"] = abs(loop.plant.t - sc.scheduled_time_s) / 10.0
            info["episode_metrics"] = loop.metrics()
        reward = -sum(self._weights[k] * costs[k] for k in OBJECTIVES)
        info["objectives"] = costs
        # (no wall-clock timings in info: identical seeds must give identical infos)
        for key in ("fallback", "slack_max", "iterations"):
            if key in loop.last_info:
                info[key] = loop.last_info[key]
        obs = self._observe()
        if self.render_mode == "human":
            self.render()
        return obs, float(reward), bool(terminated), bool(truncated), info

    # --------------------------------------------------------------- render
    def render(self):
        if self.render_mode is None:
            return None
        import matplotlib.pyplot as plt

        from train_envs.plotting import speed_distance_figure

        df = self.loop.dataframe()
        if len(df) == 0:
            return None
        fig = speed_distance_figure(df, title=self.scenario.name, s_stop_m=self.scenario.s_stop_m)
        if self.render_mode == "rgb_array":
            fig.canvas.draw()
            img = np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()
            plt.close(fig)
            return img
        plt.show(block=False)
        plt.pause(0.001)
        if self._fig is not None:
            plt.close(self._fig)
        self._fig = fig
        return None

    def close(self):
        if self._fig is not None:
            import matplotlib.pyplot as plt

            plt.close(self._fig)
            self._fig = None
