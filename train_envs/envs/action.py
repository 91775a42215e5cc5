"""The env's action: the inner controller's tuning parameters on the unit box.

The action is ``Box(−1, 1, (n,))`` over the ``n`` exposed :class:`~train_envs.controllers.
base.TunableParam`. Component ``i`` is the parameter's unit value ``u_i``: ``−1`` its
``low``, ``+1`` its ``high``, linear in between (log-linear where the parameter says
``log``); :class:`~train_envs.controllers.params.ParamSpace` holds the two maps (the
same one the tuners use).

``mode = "absolute"``: ``u = clip(a, −1, 1)``. ``mode = "delta"``: ``u ← clip(u +
delta_scale · clip(a, −1, 1), −1, 1)``, starting from the parameters' base values at
reset. Components outside ``[−1, 1]`` are clipped and counted; NaN/inf raise
``ValueError``. ``config action.bounds`` narrows a parameter's range (the registered
ids use it where a corner of the controller's own range makes the run diverge).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping
from dataclasses import replace

import numpy as np
from gymnasium import spaces

from train_envs.controllers.base import Controller, TunableParam
from train_envs.controllers.params import ParamSpace
from train_envs.envs.config import ActionConfig


def _narrowed(
    spec: TunableParam | None, name: str, lo: float, hi: float, base: Mapping[str, float], ctrl: str
) -> TunableParam:
    """``spec`` with the range ``[lo, hi]`` (config ``action.bounds``), checked."""
    where = "config action.bounds (action_bounds)"
    if spec is None:
        raise ValueError(f"{where}: {ctrl} has no tunable parameter {name!r}")
    if not spec.low <= lo < hi <= spec.high:
        raise ValueError(
            f"{where} {name!r}: ({lo:g}, {hi:g}) must lie inside the controller's range "
            f"[{spec.low:g}, {spec.high:g}]"
        )
    if not lo <= base[name] <= hi:
        raise ValueError(
            f"{where} {name!r}: ({lo:g}, {hi:g}) must contain the base value {base[name]:g}"
        )
    return replace(spec, low=lo, high=hi, default=min(max(spec.default, lo), hi))


class TuningAction:
    """Decode env actions into the parameters of ``controller`` and apply them.

    Args:
        controller: the inner controller (its current parameters are the base values).
        config: the ``action`` section.
        controller_name: for error messages.

    Attributes:
        specs: the exposed parameters, in action order; param_space: their encodings.
        base_params: the controller's parameters at construction (every episode starts
            from them).
        base_unit: their unit values.
        space: the action space.
        prev: the last action, clipped (at reset: ``base_unit``).
        params_changed: whether actions have set non-base parameters since the
            controller was (re)bound.
    """

    def __init__(self, controller: Controller, config: ActionConfig, controller_name: str) -> None:
        specs = {p.name: p for p in controller.tunable_params()}
        names = list(specs) if config.params is None else list(config.params)
        for n in names:
            if n not in specs:
                raise ValueError(
                    f"config action.params (action_params): {controller_name} has no tunable "
                    f"parameter {n!r}; allowed: {', '.join(specs)}"
                )
        if not names:
            raise ValueError(f"controller {controller_name} exposes no tunable parameters")
        self.base_params = controller.get_params()
        for n, (lo, hi) in config.bounds.items():
            specs[n] = _narrowed(specs.get(n), n, lo, hi, self.base_params, controller_name)
        self.specs: tuple[TunableParam, ...] = tuple(specs[n] for n in names)
        self.param_space = ParamSpace(self.specs)
        self.base_unit = self.param_space.unit_of(self.base_params)
        self.space = spaces.Box(-1.0, 1.0, shape=(len(self.specs),), dtype=np.float32)
        self._absolute = config.mode == "absolute"
        self._delta_scale = float(config.delta_scale)
        self.bind(controller)

    def set_native(self, values: Mapping[str, float]) -> None:
        """Set native parameter values on the controller directly (no action decode);
        the controller counts as changed, so a reused env rebuilds it."""
        self.controller.set_params(**values)
        self.params_changed = True

    def bind(self, controller: Controller) -> None:
        """Apply later actions to ``controller`` (holding the base parameters)."""
        self.controller = controller
        self.params_changed = False

    def reset(self) -> dict[str, float]:
        """Start an episode (the controller holds the base parameters); returns them."""
        self._unit = list(self.base_unit)
        self.prev = list(self.base_unit)
        # what the controller holds now: a constant action skips set_params (see apply)
        self._applied_unit = list(self.base_unit)
        self._applied_params = self.controller.get_params()
        return dict(self._applied_params)

    def apply(self, action: np.ndarray) -> tuple[int, dict[str, float]]:
        """Clip ``action`` and set the controller's parameters from it.

        Returns the number of clipped components and the parameters now in force (a
        fresh dict, for ``info``).
        """
        a = np.asarray(action, dtype=float).reshape(-1)
        n = len(self.specs)
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
        self.prev = act
        # set_params only when the parameters change (setting the values the controller
        # holds is a no-op)
        ctrl = self.controller
        params = ctrl.get_params()
        if unit != self._applied_unit or params != self._applied_params:
            space = self.param_space
            ctrl.set_params(**space.decode_action(unit, self.base_unit, self.base_params))
            self._applied_unit = unit
            self._applied_params = ctrl.get_params()
            if unit != self.base_unit:
                self.params_changed = True
            params = dict(self._applied_params)
        return clipped, params


def action_corners(n: int, rng: np.random.Generator, limit: int = 64) -> list[np.ndarray]:
    """All ``2^n`` corners of the action box ``[−1, 1]^n`` if there are at most
    ``limit``; else all −1, all +1 and ``limit − 2`` distinct others drawn with ``rng``."""
    if 2**n <= limit:
        return [np.array(c, float) for c in itertools.product((-1.0, 1.0), repeat=n)]
    picks = [0, 2**n - 1, *(1 + rng.choice(2**n - 2, size=limit - 2, replace=False))]
    return [np.array([1.0 if (int(k) >> i) & 1 else -1.0 for i in range(n)]) for k in picks]
