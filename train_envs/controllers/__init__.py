"""Inner controllers: the protocol, PID baselines and the MPC family."""

from __future__ import annotations

import inspect
from collections.abc import Callable
from typing import Any

from train_envs.controllers.adaptive_mpc import AdaptiveCruiseMPC, NominalCruiseMPC
from train_envs.controllers.afsmc import AFSMCController
from train_envs.controllers.base import ControlContext, Controller, Observation, TunableParam
from train_envs.controllers.dmc import DMCController
from train_envs.controllers.fuzzy_pid import FuzzyPIDController
from train_envs.controllers.pid import PIDController
from train_envs.controllers.requirements import (
    Requirements,
    UnsupportedScenarioError,
    requirements,
    scenario_defaults,
    unsupported_reason,
)
from train_envs.controllers.train_mpc import MultiCarMPC, PointMassMPC
from train_envs.controllers.tube import RobustSelfTriggeredMPC, TubeMPC
from train_envs.validation import check_choice


def _tracking(**kw: Any) -> Controller:
    c = PIDController(**kw)
    c.name = "tracking"
    c.set_params(ki=0.0, kd=0.0)
    return c


def _mpc000(scenario: Any = None, **kw: Any) -> Controller:
    """Paper 000's plain MPC comparator: SEMPC's model without the terminal cost."""
    return MultiCarMPC(scenario, terminal=False, **kw)


def _afsmc000(**kw: Any) -> Controller:
    """Paper 000's AFSMC comparator as we reconstruct it: speed sliding surface σ = e_v."""
    c = AFSMCController(surface="speed", **kw)
    c.name = "afsmc000"
    return c


def _fuzzy_mpc(scenario: Any = None, **kw: Any) -> Controller:
    """Paper 003's fuzzy constrained predictive controller (imports cvxpy on first use)."""
    from train_envs.controllers.fuzzy_mpc import FuzzyMPCController

    return FuzzyMPCController(scenario, **kw)


#: controller factories by name; each takes keyword tuning parameters
CONTROLLERS: dict[str, Callable[..., Controller]] = {
    "pid": PIDController,
    "tracking": _tracking,
    "fuzzy_pid": FuzzyPIDController,
    "afsmc": AFSMCController,
    "afsmc000": _afsmc000,
    "dmc": DMCController,
    "mpc": PointMassMPC,
    "sempc": MultiCarMPC,
    "mpc000": _mpc000,
    "fuzzy_mpc": _fuzzy_mpc,
    "rmpc": TubeMPC,
    "rsmpc": RobustSelfTriggeredMPC,
    "adaptive_mpc": AdaptiveCruiseMPC,
    "mpc002": NominalCruiseMPC,
}


def list_controllers() -> list[str]:
    return sorted(CONTROLLERS)


def make_controller(name: str, scenario: Any = None, **params: float) -> Controller:
    """Build a controller by name (``scenario`` lets paper controllers pick its settings).

    A scenario the controller does not support (:func:`unsupported_reason`) raises
    :class:`UnsupportedScenarioError` naming the requirement it breaks; options derived
    from the scenario (:func:`scenario_defaults`) apply under the caller's ``params``.
    """
    check_choice("controller", name, list_controllers())
    if scenario is not None:
        reason = unsupported_reason(name, scenario)
        if reason is not None:
            raise UnsupportedScenarioError(reason)
    factory = CONTROLLERS[name]
    if scenario is not None:
        params = {**scenario_defaults(name, scenario), **params}
    if "scenario" in inspect.signature(factory).parameters:
        return factory(scenario=scenario, **params)
    return factory(**params)


__all__ = [
    "AFSMCController",
    "AdaptiveCruiseMPC",
    "CONTROLLERS",
    "ControlContext",
    "Controller",
    "DMCController",
    "FuzzyPIDController",
    "Observation",
    "MultiCarMPC",
    "NominalCruiseMPC",
    "PIDController",
    "PointMassMPC",
    "Requirements",
    "RobustSelfTriggeredMPC",
    "TubeMPC",
    "TunableParam",
    "UnsupportedScenarioError",
    "list_controllers",
    "make_controller",
    "requirements",
    "scenario_defaults",
    "unsupported_reason",
]
