"""Inner controllers: the protocol, PID baselines and the MPC family."""

from __future__ import annotations

import inspect
from collections.abc import Callable
from typing import Any

from train_envs.controllers.afsmc import AFSMCController
from train_envs.controllers.base import ControlContext, Controller, Observation, TunableParam
from train_envs.controllers.fuzzy_pid import FuzzyPIDController
from train_envs.controllers.pid import PIDController


def _tracking(**kw: Any) -> Controller:
    c = PIDController(**kw)
    c.name = "tracking"
    c.set_params(ki=0.0, kd=0.0)
    return c


#: controller factories by name; each takes keyword tuning parameters
CONTROLLERS: dict[str, Callable[..., Controller]] = {
    "pid": PIDController,
    "tracking": _tracking,
    "fuzzy_pid": FuzzyPIDController,
    "afsmc": AFSMCController,
}


def list_controllers() -> list[str]:
    return sorted(CONTROLLERS)


def make_controller(name: str, scenario: Any = None, **params: float) -> Controller:
    """Build a controller by name (``scenario`` lets paper controllers pick its settings)."""
    if name not in CONTROLLERS:
        raise ValueError(
            f"unknown controller {name!r}; choose one of: {', '.join(list_controllers())}"
        )
    factory = CONTROLLERS[name]
    if "scenario" in inspect.signature(factory).parameters:
        return factory(scenario=scenario, **params)
    return factory(**params)


__all__ = [
    "AFSMCController",
    "CONTROLLERS",
    "ControlContext",
    "Controller",
    "FuzzyPIDController",
    "Observation",
    "PIDController",
    "TunableParam",
    "list_controllers",
    "make_controller",
]
