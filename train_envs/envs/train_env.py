"""Gymnasium env whose action is the inner controller's tuning parameters.

:class:`TrainTuningEnv` holds a scenario (plant + line + reference) and a controller and
runs the one closed-loop runner, :class:`train_envs.simulation.ClosedLoop`: every env
step applies the action to the controller's tunable parameters, then runs
``decision_interval`` control steps, the controller (an MPC, a PID, ...) computing the
command at each. It adds no physics and no control of its own.

Its parts, one module each: :mod:`~train_envs.envs.config` (the sections and their flat
aliases), :mod:`~train_envs.envs.action` (unit box ↔ parameters),
:mod:`~train_envs.envs.observation` (the features) and :mod:`~train_envs.envs.reward`
(the objectives). Design notes: ``docs/design/envs.md``.
"""

from __future__ import annotations

import weakref
from collections.abc import Mapping
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.error import ResetNeeded

from train_envs.controllers import make_controller
from train_envs.controllers.base import Controller, TunableParam
from train_envs.envs.action import TuningAction
from train_envs.envs.config import EnvConfig
from train_envs.envs.observation import OBS_CLIP, TuningObservation
from train_envs.envs.reward import OBJECTIVES, TuningReward
from train_envs.mpc.blas import single_thread_blas
from train_envs.scenarios import DisturbanceSpec, Scenario, get_scenario, real_line_scenario
from train_envs.simulation import ClosedLoop

__all__ = ["OBJECTIVES", "OBS_CLIP", "TrainTuningEnv"]

#: the controller info entries an env step passes on in its ``info``
INFO_KEYS = ("fallback", "slack_max", "iterations")


class TrainTuningEnv(gym.Env):
    """Train + line + inner controller; the action sets the controller's tuning parameters.

    ## Description

    An episode is one run of the scenario (a stopping run, a cruise, an urban run, or a
    station-to-station run sampled from a real line) under the inner controller. At
    every env step the agent chooses the controller's tuning parameters (cost weights,
    gains, softening factors, ...); the controller then drives the train for
    ``decision_interval`` control periods with them.

    ## Action Space

    ``Box(-1, 1, (n,), float32)`` over the ``n`` exposed tunable parameters
    (``param_specs``, ``config action.params``): ``−1`` is a parameter's lower bound,
    ``+1`` its upper bound (log-linear for weights). ``action.mode = "absolute"`` sets
    the parameters; ``"delta"`` moves their unit values by ``delta_scale · a`` per step.
    Components outside ``[−1, 1]`` are clipped and counted; NaN/inf raise
    ``ValueError``. See :mod:`train_envs.envs.action`.

    ## Observation Space

    ``Box(-10, 10, (5 + 2·preview_points + 2 + n + 1,), float32)``, features named in
    ``observation_names``: ``v_err, s_err, v, dist_to_stop, slack, grad_ahead_i,
    limit_ahead_i, u, du, prev_action_<param>, solver_flag``, each scaled to about
    ``[−1, 1]``. Definitions in :mod:`train_envs.envs.observation`.

    ## Rewards

    ``−Σ_i w_i c_i`` over :data:`OBJECTIVES` = ``tracking, jerk, energy, violation``
    (per env step) and ``stop, punctuality`` (last env step), weights ``reward.weights``
    (default 1, 0.05, 0, 10, 5, 1). Definitions in :mod:`train_envs.envs.reward`.

    ## Starting State

    ``reset(seed=...)`` draws the episode seed (plant disturbances and domain
    randomisation, see ``scenario.disturbance``) and, on a real line, the station pair
    (or ``options={"section": (i, j)}``); the controller restarts from its base
    parameters (defaults + ``controller.params``).

    ## Episode End

    Terminated: the runner's termination (the train stopped after moving, or overran
    the stop by the scenario's ``overrun_m``; cruise runs: ``t ≥ t_max``; with
    ``supervision.end_on_violation``: the first safety violation). Truncated: the
    runner's truncation (``t_max`` or its step budget) or ``episode.max_steps`` env
    steps. ``step()`` before ``reset()`` or after the end raises ``ResetNeeded``.

    ## Supervision and cost

    The runner's ATP brakes whenever the speed exceeds the limit by
    ``supervision.margin_mps`` (:mod:`train_envs.simulation.supervision`). Every step
    reports ``info["cost"]`` (Safety-Gymnasium convention: a float ≥ 0, 0 on a safe
    step) and its components ``info["cost_components"]`` (``overspeed``, ``atp``,
    ``coupler``, ``overrun``; definitions in :mod:`train_envs.envs.reward`); the
    ``violation`` objective contains them.

    ## Information

    ``reset``: ``scenario`` (name), ``params`` (the parameters in force). ``step``:
    ``action_clipped`` (components clipped this step), ``action_clipped_total``,
    ``params``, ``objectives`` (every cost ``c_i`` of the step), ``cost`` and
    ``cost_components`` (the safety cost), the controller's ``fallback`` /
    ``slack_max`` / ``iterations`` where it reports them, and on the last step
    ``episode_metrics`` (:func:`train_envs.metrics.episode_metrics`) and, when a safety
    violation ended it, ``safety_violation`` (what it was). No wall-clock timings: the
    same seed gives the same infos.

    ## Threads

    From its construction to ``close()`` (or its garbage collection) the env holds the
    process's BLAS libraries at one thread (:func:`train_envs.mpc.blas.single_thread_blas`):
    its matrices are small, so threads only cost, and the results do not depend on the
    machine's core count. Close the env to give numpy its threads back.

    ## Arguments

    ``gymnasium.make(id, config={...}, render_mode=None)``: ``config`` in sections
    (``scenario``, ``controller``, ``action``, ``observation``, ``reward``,
    ``episode``) or flat keys, merged over the id's ``base_config`` and
    :meth:`default_config`; see :mod:`train_envs.envs.config`. ``render_mode``:
    ``"rgb_array"`` (speed-distance figure as an image) or ``"human"``.

    Attributes:
        config: the resolved configuration under its flat keys (a dict).
        settings: the same in sections (:class:`~train_envs.envs.config.EnvConfig`).
        scenario, controller, loop: the episode's scenario, the inner controller and
            the runner.
        param_specs: the exposed parameters, in action order.
        observation_names: the observation features, in order.
        action_type, observation_type, reward_type: the parts
            (:class:`~train_envs.envs.action.TuningAction`,
            :class:`~train_envs.envs.observation.TuningObservation`,
            :class:`~train_envs.envs.reward.TuningReward`); ``step`` calls the hooks
            of the parts present at ``reset``.
    """

    metadata = {"render_modes": ["rgb_array", "human"], "render_fps": 4}

    @classmethod
    def default_config(cls) -> dict[str, Any]:
        """The defaults under their flat keys (meanings: :mod:`train_envs.envs.config`)."""
        return EnvConfig().flat()

    def __init__(
        self,
        config: Mapping[str, Any] | None = None,
        render_mode: str | None = None,
        base_config: Mapping[str, Any] | None = None,
    ):
        super().__init__()
        # one BLAS thread from construction to close (small matrices: threads only cost,
        # and results do not depend on the machine's core count; see train_envs.mpc.blas)
        blas = single_thread_blas()
        blas.acquire()
        self._blas_release = weakref.finalize(self, blas.release)
        # registered ids pass their settings as ``base_config``; ``config`` goes over them
        self.settings = EnvConfig.resolve(self.default_config(), base_config, config)
        self.config = self.settings.flat()
        st = self.settings
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode must be one of {self.metadata['render_modes']}, got {render_mode!r}"
            )
        self.render_mode = render_mode

        self._sections: list[tuple[int, int]] | None = None
        self._section_cache: dict[tuple[int, int], Scenario] = {}
        self.scenario = self._initial_scenario()
        self._scenario0 = self.scenario  # the controller is built for this one
        self.controller: Controller = self._make_controller()
        self.loop = ClosedLoop(self.scenario, self.controller, st.episode.supervisor())

        self.action_type = TuningAction(self.controller, st.action, st.controller.name)
        self.observation_type = TuningObservation(
            st.observation, self.action_type, st.episode.decision_interval
        )
        self.reward_type = TuningReward(st.reward.weights)
        self.action_space = self.action_type.space
        self.observation_space = self.observation_type.space
        self.param_specs: tuple[TunableParam, ...] = self.action_type.specs
        self.observation_names = self.observation_type.names
        self._n_ctrl = st.episode.decision_interval
        self._max_steps = st.episode.max_steps
        self._fig = None
        self._over: str | None = "step() called before reset()"

    def _make_controller(self) -> Controller:
        c = self.settings.controller
        try:
            return make_controller(c.name, self._scenario0, **c.params)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"config controller ({c.name}, params {c.params}): {exc}") from None

    def default_params(self) -> dict[str, float]:
        """The controller parameters every episode starts from (defaults + config's
        ``controller.params``), whatever the last episode's actions set."""
        return dict(self.action_type.base_params)

    def set_native_params(self, values: Mapping[str, float]) -> None:
        """Set the controller's parameters to native ``values`` for the coming episode,
        bypassing the action (what fixed-parameter evaluations use); marks the
        controller as changed for :meth:`renew_controller`."""
        self.action_type.set_native(values)

    def renew_controller(self) -> bool:
        """Rebuild the controller (and runner) if actions have changed its parameters
        and it keeps state that depends on them (``keeps_parameter_state``).

        After this call the env is as good as newly made: an evaluation on it equals
        one on a fresh env bit for bit (what :func:`~train_envs.envs.evaluate` relies on
        when it reuses envs; see ``docs/design/envs.md``). Returns whether it rebuilt
        anything; takes effect at the next ``reset``.
        """
        if not self.action_type.params_changed or not self.controller.keeps_parameter_state:
            return False
        self.controller = self._make_controller()
        self.loop = ClosedLoop(self._scenario0, self.controller, self.settings.episode.supervisor())
        self.action_type.bind(self.controller)
        return True

    # ----------------------------------------------------------------- scenarios
    def _with_disturbance(self, sc: Scenario) -> Scenario:
        cfg = self.settings.scenario
        over = dict(cfg.overrides)
        if cfg.disturbance:
            base = sc.disturbance.__dict__ | cfg.disturbance
            try:
                over["disturbance"] = DisturbanceSpec(
                    **{k: tuple(v) if isinstance(v, list) else v for k, v in base.items()}
                )
            except (TypeError, ValueError) as exc:
                raise ValueError(f"config scenario.disturbance (disturbance): {exc}") from None
        try:
            return sc.with_overrides(**over) if over else sc
        except (TypeError, ValueError) as exc:
            raise ValueError(f"config scenario.overrides (scenario_overrides): {exc}") from None

    def _initial_scenario(self) -> Scenario:
        cfg = self.settings.scenario
        rl = cfg.real_line
        if rl is None:
            return self._with_disturbance(get_scenario(cfg.name))
        from train_envs.lines import get_track

        track = get_track(rl["track"])
        n_stops = len(track.stops_m)
        sections = rl.get("sections") or [(i, i + 1) for i in range(n_stops - 1)]
        self._sections = [tuple(s) for s in sections]
        bad = [s for s in self._sections if s[1] >= n_stops]
        if bad:
            raise ValueError(
                f"config scenario.real_line (real_line) sections {bad} name stops beyond the "
                f"last one ({n_stops - 1}) of track {track.name!r}"
            )
        return self._section_scenario(self._sections[0])

    def _section_scenario(self, sec: tuple[int, int]) -> Scenario:
        if sec not in self._section_cache:
            rl = self.settings.scenario.real_line
            sc = real_line_scenario(
                rl["track"],
                rl["train"],
                sec[0],
                sec[1],
                time_supplement=float(rl.get("time_supplement", 0.08)),
            )
            self._section_cache[sec] = self._with_disturbance(sc)
        return self._section_cache[sec]

    # ------------------------------------------------------------- gym API
    def reset(self, *, seed: int | None = None, options: Mapping[str, Any] | None = None):
        super().reset(seed=seed)
        if self._sections is not None:
            sec = self._sections[int(self.np_random.integers(len(self._sections)))]
            if options and "section" in options:
                sec = tuple(options["section"])
            self.scenario = self._section_scenario(sec)
        episode_seed = int(self.np_random.integers(2**31 - 1))
        self.controller.set_params(**self.action_type.base_params)
        self.loop.reset(seed=episode_seed, scenario=self.scenario)
        params = self.action_type.reset()
        self.observation_type.bind(self.scenario, self.loop)
        self.reward_type.bind(self.scenario, self.loop)
        # the hooks of the hot path, bound once per episode
        self._act = self.action_type.apply
        self._observe = self.observation_type.observe
        self._costs = self.reward_type.costs
        self._reward = self.reward_type.reward
        self._steps = 0
        self._clipped_total = 0
        self._over = None
        return self._observe(), {"scenario": self.scenario.name, "params": params}

    def step(self, action):
        if self._over is not None:
            raise ResetNeeded(f"{type(self).__name__}: {self._over}; call reset()")
        with single_thread_blas():  # (held since construction; restored on close)
            clipped, params = self._act(action)
            k0 = self._simulate()
        self._clipped_total += clipped
        terminated, truncated = self._episode_end()
        final = terminated or truncated
        if final:
            self._over = "the episode is over (terminated or truncated)"
        costs = self._costs(k0, final)
        reward = self._reward(costs)
        info = self._info(clipped, params, costs, final)
        obs = self._observe()
        if self.render_mode == "human":
            self.render()
        return obs, float(reward), terminated, truncated, info

    def _simulate(self) -> int:
        """Run up to ``decision_interval`` control steps; returns the first one's index."""
        loop = self.loop
        k0 = loop.k
        for _ in range(self._n_ctrl):
            loop.step()
            if loop.done:
                break
        self._steps += 1
        return k0

    def _episode_end(self) -> tuple[bool, bool]:
        loop = self.loop
        truncated = loop.truncated or (
            self._max_steps is not None and self._steps >= self._max_steps
        )
        return bool(loop.terminated), bool(truncated)

    def _info(
        self, clipped: int, params: dict[str, float], costs: dict[str, float], final: bool
    ) -> dict[str, Any]:
        info: dict[str, Any] = {
            "action_clipped": clipped,
            "action_clipped_total": self._clipped_total,
            "params": params,
        }
        if final:
            info["episode_metrics"] = self.loop.metrics()
            if self.loop.safety_end is not None:
                info["safety_violation"] = self.loop.safety_end
        info["objectives"] = costs
        rw = self.reward_type
        info["cost"] = rw.cost()
        info["cost_components"] = dict(rw.safety)
        last = self.loop.last_info
        for key in INFO_KEYS:
            if key in last:
                info[key] = last[key]
        return info

    # --------------------------------------------------------------- render
    def render(self):
        if self.render_mode is None:
            return None
        from train_envs.plotting import speed_distance_figure

        df = self.loop.dataframe()
        if len(df) == 0:
            return None
        fig = speed_distance_figure(df, title=self.scenario.name, s_stop_m=self.scenario.s_stop_m)
        if self.render_mode == "rgb_array":
            from matplotlib.backends.backend_agg import FigureCanvasAgg

            canvas = FigureCanvasAgg(fig)  # drawn off-screen, whatever the backend
            canvas.draw()
            return np.asarray(canvas.buffer_rgba())[..., :3].copy()
        import matplotlib.pyplot as plt

        plt.figure(fig)  # shown by pyplot's backend (a window, or inline in Jupyter)
        plt.show(block=False)
        plt.pause(0.001)
        if self._fig is not None:
            plt.close(self._fig)
        self._fig = fig
        return None

    def close(self):
        self._blas_release()  # BLAS threads restored (once; also when garbage-collected)
        if self._fig is not None:
            import matplotlib.pyplot as plt

            plt.close(self._fig)
            self._fig = None
