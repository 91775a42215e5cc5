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
#: the recorded columns a step's reward reads
_STEP_COLUMNS = ("v_mps", "a_mps2", "v_ref_mps", "v_limit_mps", "saturated")
OBS_CLIP = 10.0
_INV_GRAD = 1.0 / 30.0  # gradient feature scale [1/‰]


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
        self._scenario0 = self.scenario  # the controller is built for this one
        self.controller: Controller = make_controller(
            cfg["controller"], self.scenario, **cfg["controller_params"]
        )
        #: whether actions have set non-default parameters since the controller was built
        self._params_changed = False
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

        self._base_unit = [p.to_unit(self._base_params[p.name]) for p in self.param_specs]

        self.observation_names = self._observation_names()
        self._n_preview = int(cfg["preview_points"])
        self._preview_offsets = np.linspace(0.0, float(cfg["preview_m"]), self._n_preview)
        self._preview_list = self._preview_offsets.tolist()
        self.observation_space = spaces.Box(
            -OBS_CLIP, OBS_CLIP, shape=(len(self.observation_names),), dtype=np.float32
        )
        self.loop = ClosedLoop(self.scenario, self.controller)
        self._weights = {k: float(cfg["reward_weights"].get(k, 0.0)) for k in OBJECTIVES}
        # hot-path copies of the (validated) config
        self._w = tuple(self._weights[k] for k in OBJECTIVES)
        self._n_ctrl = int(cfg["decision_interval"])
        self._absolute = cfg["action_mode"] == "absolute"
        self._delta_scale = float(cfg["delta_scale"])
        self._fig = None

    def default_params(self) -> dict[str, float]:
        """The controller parameters every episode starts from (defaults + config's
        ``controller_params``), whatever the last episode's actions set."""
        return dict(self._base_params)

    def renew_controller(self) -> bool:
        """Rebuild the controller (and runner) if actions have changed its parameters.

        ``reset`` re-initialises what an episode depends on, except data a controller
        deliberately keeps across episodes that depend on the parameters it ran with:
        the RSMPC / tube MPC keep their QPs, built with the weights of the episode that
        first needed them and updated in place afterwards, which agrees with a fresh
        build only to rounding. Controllers that declare ``keeps_parameter_state =
        False`` (the DMC: what it keeps does not depend on its tunables) are kept as they
        are. After this call the env is as good as newly made: an
        evaluation on it equals one on a fresh env bit for bit (what
        :func:`~train_envs.envs.evaluate` relies on when it reuses envs). Returns whether
        it rebuilt anything; takes effect at the next ``reset``.
        """
        if not self._params_changed or not self.controller.keeps_parameter_state:
            return False
        cfg = self.config
        self.controller = make_controller(
            cfg["controller"], self._scenario0, **cfg["controller_params"]
        )
        self.loop = ClosedLoop(self._scenario0, self.controller)
        self._params_changed = False
        return True

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

    def _prepare_episode(self) -> None:
        """Per-episode constants of the hot path (the scenario may change at reset)."""
        sc = self.scenario
        ref = sc.reference
        v_scale = max(float(np.max(sc.track.speed_limits_mps)), 1.0)
        if math.isfinite(sc.train.max_speed_mps):
            v_scale = min(v_scale, sc.train.max_speed_mps) or v_scale
        self._v_scale = v_scale
        self._inv_v_scale = 1.0 / v_scale
        self._end = sc.s_stop_m if sc.s_stop_m is not None else ref.end_m
        self._v_ref_fn = ref.v_ref
        self._s_ref_fn = ref.s_ref
        self._t_at_s_fn = ref.profile.t_at_s
        self._grad_fn = gradient_table(sc.track)
        self._limit_fn = sc.track.speed_limit_at
        self._u_scale = sc.train.max_traction_force_N
        self._du_scale = self._u_scale * sc.dt_ctrl_s * self.config["decision_interval"]
        self._dt = sc.dt_ctrl_s
        self._s_stop = sc.s_stop_m
        self._t_sched = sc.scheduled_time_s
        tr = sc.train
        self._eta_t, self._eta_r = tr.traction_efficiency, tr.regen_efficiency

    def _u_sum(self) -> float:
        """Total command of the last control step (``float(np.sum(loop.u_prev))``)."""
        u = self.loop.u_prev
        if u.size == 1:
            return u.item() + 0.0  # np.sum's value, -0.0 included
        return float(u.sum())

    def _observe(self) -> np.ndarray:
        p = self.loop.plant
        t, s, v = p.t, p.s, p.v
        u = self._u_obs = self._u_sum()
        obs = [
            (self._v_ref_fn(t, s) - v) / 5.0,
            (self._s_ref_fn(t) - s) / 50.0,
            v / self._v_scale,
            (self._end - s) / 1000.0,
            (float(self._t_at_s_fn(s)) - t) / 30.0,
        ]
        # scalar look-ups (the same arithmetic as the vectorised ones)
        grad, lim, inv_v = self._grad_fn, self._limit_fn, self._inv_v_scale
        pts = [s + off for off in self._preview_list]
        obs += [grad(x) * _INV_GRAD for x in pts]
        obs += [lim(x) * inv_v for x in pts]
        obs.append(u / self._u_scale)
        obs.append((u - self._u_before) / self._du_scale)
        obs += self._prev_action
        obs.append(1.0 if self.loop.last_info.get("fallback", False) else 0.0)
        # np.clip(np.nan_to_num(x), -OBS_CLIP, OBS_CLIP) on scalars; a fresh float32 array
        return np.array(
            [
                (x if -OBS_CLIP <= x <= OBS_CLIP else OBS_CLIP if x > 0 else -OBS_CLIP)
                if x == x
                else 0.0
                for x in obs
            ],
            dtype=np.float32,
        )

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
        self._prepare_episode()
        self._unit = list(self._base_unit)
        self._prev_action = list(self._base_unit)
        # what the controller holds now: a constant action skips set_params (see step)
        self._applied_unit = list(self._base_unit)
        self._applied_params = self.controller.get_params()
        self._u_before = self._u_sum()
        self._a_prev = self.loop.plant.accel
        self._energy_prev = 0.0
        self._steps = 0
        self._clipped_total = 0
        cap = self.config["max_episode_steps"]
        self._max_steps = int(cap) if cap else None
        obs = self._observe()
        return obs, {"scenario": self.scenario.name, "params": dict(self._applied_params)}

    def _apply_action(self, action: np.ndarray) -> tuple[int, dict[str, float]]:
        """Clip ``action`` and set the controller's parameters from it.

        Returns the number of clipped components and the parameters now in force (a
        fresh dict, for ``info``).
        """
        a = np.asarray(action, dtype=float).reshape(-1)
        n = len(self.param_specs)
        if a.shape != (n,):
            raise ValueError(f"action must have shape ({n},), got {a.shape}")
        clipped = 0
        act = a.tolist()
        for i, x in enumerate(act):
            if -1.0 <= x <= 1.0:
                continue
            if 1.0 < x < math.inf:
                act[i] = 1.0
            elif -math.inf < x < -1.0:
                act[i] = -1.0
            else:  # NaN or inf
                raise ValueError(f"action must be finite, got {a}")
            clipped += 1
        if self._absolute:
            unit = act
        else:
            ds = self._delta_scale
            unit = [min(1.0, max(-1.0, u + ds * x)) for u, x in zip(self._unit, act, strict=True)]
        self._unit = unit
        self._prev_action = act
        # set_params only when the parameters change (a constant action, as the tuners
        # apply, sets them once; setting the values the controller holds is a no-op)
        params = self.controller.get_params()
        if unit != self._applied_unit or params != self._applied_params:
            # the unit value of a base parameter maps back onto it exactly (from_unit and
            # to_unit are inverse only up to rounding)
            base, base_params = self._base_unit, self._base_params
            self.controller.set_params(
                **{
                    p.name: base_params[p.name] if u == base[i] else p.from_unit(u)
                    for i, (p, u) in enumerate(zip(self.param_specs, unit, strict=True))
                }
            )
            self._applied_unit = unit
            self._applied_params = self.controller.get_params()
            if unit != self._base_unit:
                self._params_changed = True
            params = dict(self._applied_params)
        return clipped, params

    def step(self, action):
        clipped, params = self._apply_action(action)
        self._clipped_total += clipped
        loop = self.loop
        dt = self._dt
        self._u_before = self._u_obs  # the command of the last observation (loop.u_prev)
        k0 = loop.k
        for _ in range(self._n_ctrl):
            loop.step()
            if loop.done:
                break
        # per-control-step costs from the rows the runner recorded (state at the start
        # of each control period)
        k1 = loop.k
        j0 = k0 - 1 if k0 > 0 else 0  # one row more: the previous step's last row
        rows = loop.columns(j0, k1, _STEP_COLUMNS)
        i0 = k0 - j0
        # a handful of rows: Python floats beat numpy's per-call overhead here
        v = rows["v_mps"].tolist()[i0:]
        a_all = rows["a_mps2"].tolist()
        tracking = 0.0
        for x, y in zip(rows["v_ref_mps"].tolist()[i0:], v, strict=True):
            e = x - y
            tracking += e * e
        tracking *= dt
        prev = a_all[0] if i0 else self._a_prev  # the previous row holds a_prev
        jerk_cost = 0.0
        for x in a_all[i0:]:
            jk = (x - prev) / dt
            jerk_cost += jk * jk
            prev = x
        jerk_cost *= dt
        self._a_prev = prev
        lim, sat = rows["v_limit_mps"].tolist()[i0:], rows["saturated"].tolist()[i0:]
        if any(sat) or not all(x - y <= 0.0 for x, y in zip(v, lim, strict=True)):
            # overspeed (NaN counts) plus saturated steps
            d = [x - y for x, y in zip(v, lim, strict=True)]
            over = sum(e if not e <= 0.0 else 0.0 for e in d)
            violation = (over + sum(sat)) * dt
        else:  # the usual case, no overspeed, no saturation (NaN takes the branch above)
            violation = 0.0
        p = loop.plant
        energy = (p.work_traction_J / self._eta_t - self._eta_r * p.work_brake_J) / 3.6e6
        energy_cost = energy - self._energy_prev
        self._energy_prev = energy
        self._steps += 1
        terminated = loop.terminated
        truncated = loop.truncated or (
            self._max_steps is not None and self._steps >= self._max_steps
        )
        info: dict[str, Any] = {
            "action_clipped": clipped,
            "action_clipped_total": self._clipped_total,
            "params": params,
        }
        stop = punctuality = 0.0
        if terminated or truncated:
            if self._s_stop is not None:
                stop = abs(p.s - self._s_stop)
            if self._t_sched is not None:
                punctuality = abs(p.t - self._t_sched) / 10.0
            info["episode_metrics"] = loop.metrics()
        costs = {
            "tracking": tracking,
            "jerk": jerk_cost,
            "energy": energy_cost,
            "violation": violation,
            "stop": stop,
            "punctuality": punctuality,
        }
        w = self._w
        # = -sum(w_k c_k for k in OBJECTIVES), the same additions in the same order
        reward = -(
            0.0
            + w[0] * tracking
            + w[1] * jerk_cost
            + w[2] * energy_cost
            + w[3] * violation
            + w[4] * stop
            + w[5] * punctuality
        )
        info["objectives"] = costs
        # (no wall-clock timings in info: identical seeds must give identical infos)
        last = loop.last_info
        for key in ("fallback", "slack_max", "iterations"):
            if key in last:
                info[key] = last[key]
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
