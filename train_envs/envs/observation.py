"""The env's observation: tracking state, preview, command and the last action.

Features (``float32``, NaN → 0, clipped to ``[−OBS_CLIP, OBS_CLIP]``), at the plant's
state ``(t, s, v)`` after the env step; ``v_max`` is the line's maximum speed limit
(at least 1 m/s), capped by the train's design speed where that is finite:

=======================  ==================================================================
``v_err``                (v_ref(t, s) − v) / 5 m/s
``s_err``                (s_ref(t) − s) / 50 m
``v``                    v / v_max
``dist_to_stop``         (s_end − s) / 1000 m; s_end: the stop (cruise runs: the profile end)
``slack``                (t_ref(s) − t) / 30 s, schedule slack
``grad_ahead_i``         equivalent gradient at s + i·preview_m/(n−1), / 30 ‰ (i < n)
``limit_ahead_i``        speed limit governing the train with its head at the same
                         points (rear-clearance rule for its length) / v_max
``u``                    total command of the last control step / max traction force
``du``                   its change over the env step / (max traction force · dt ·
                         decision_interval)
``prev_action_<param>``  the last action, clipped (at reset: the base parameters)
``solver_flag``          1 if the controller fell back (solver failure) last step, else 0
=======================  ==================================================================
"""

from __future__ import annotations

import math

import numpy as np
from gymnasium import spaces

from train_envs.envs.action import TuningAction
from train_envs.envs.config import ObservationConfig
from train_envs.lines.limits import effective_limit_fn
from train_envs.plants.lookup import gradient_table
from train_envs.scenarios import Scenario
from train_envs.simulation import ClosedLoop

#: bound of every observation feature
OBS_CLIP = 10.0
_INV_GRAD = 1.0 / 30.0  # gradient feature scale [1/‰]


class TuningObservation:
    """The observation of the env whose action is ``action``.

    Args:
        config: the ``observation`` section.
        action: the env's action part (its ``specs`` name, its ``prev`` fills the
            ``prev_action_*`` features).
        decision_interval: control steps per env step (the ``du`` scale).

    Attributes:
        names: the feature names, in order.
        space: the observation space.
        u_last: the total command at the last observation (``du`` is measured from it).
    """

    def __init__(
        self, config: ObservationConfig, action: TuningAction, decision_interval: int
    ) -> None:
        n = config.preview_points
        names = ["v_err", "s_err", "v", "dist_to_stop", "slack"]
        names += [f"grad_ahead_{i}" for i in range(n)]
        names += [f"limit_ahead_{i}" for i in range(n)]
        names += ["u", "du"]
        names += [f"prev_action_{p.name}" for p in action.specs]
        names += ["solver_flag"]
        self.names = names
        self.space = spaces.Box(-OBS_CLIP, OBS_CLIP, shape=(len(names),), dtype=np.float32)
        self._preview = np.linspace(0.0, config.preview_m, n).tolist()
        self._action = action
        self._decision_interval = decision_interval

    def bind(self, scenario: Scenario, loop: ClosedLoop) -> None:
        """Start an episode on ``loop`` (just reset) running ``scenario``: the episode's
        constants of the hot path."""
        sc = scenario
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
        self._limit_fn = effective_limit_fn(sc.track, sc.train.length_m)
        self._u_scale = sc.train.max_traction_force_N
        self._du_scale = self._u_scale * sc.dt_ctrl_s * self._decision_interval
        self._loop = loop
        self.u_last = self._u_sum()

    def _u_sum(self) -> float:
        """Total command of the last control step (``float(np.sum(loop.u_prev))``)."""
        u = self._loop.u_prev
        if u.size == 1:
            return u.item() + 0.0  # np.sum's value, -0.0 included
        return float(u.sum())

    def observe(self) -> np.ndarray:
        """The observation now (a fresh array)."""
        loop = self._loop
        p = loop.plant
        t, s, v = p.t, p.s, p.v
        u = self._u_sum()
        obs = [
            (self._v_ref_fn(t, s) - v) / 5.0,
            (self._s_ref_fn(t) - s) / 50.0,
            v / self._v_scale,
            (self._end - s) / 1000.0,
            (float(self._t_at_s_fn(s)) - t) / 30.0,
        ]
        # scalar look-ups (the same arithmetic as the vectorised ones)
        grad, lim, inv_v = self._grad_fn, self._limit_fn, self._inv_v_scale
        pts = [s + off for off in self._preview]
        obs += [grad(x) * _INV_GRAD for x in pts]
        obs += [lim(x) * inv_v for x in pts]
        obs.append(u / self._u_scale)
        obs.append((u - self.u_last) / self._du_scale)
        self.u_last = u
        obs += self._action.prev
        obs.append(1.0 if loop.last_info.get("fallback", False) else 0.0)
        # np.clip(np.nan_to_num(x), -OBS_CLIP, OBS_CLIP) on scalars
        return np.array(
            [
                (x if -OBS_CLIP <= x <= OBS_CLIP else OBS_CLIP if x > 0 else -OBS_CLIP)
                if x == x
                else 0.0
                for x in obs
            ],
            dtype=np.float32,
        )
