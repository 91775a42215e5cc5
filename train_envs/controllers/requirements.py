"""What each controller needs of a scenario, and the check that refuses the rest.

Every name in :data:`train_envs.controllers.CONTROLLERS` declares here, in one table,
the scenarios its method is made for: the train model (single point or multi-car), the
inputs (one whole-train force or per-car forces), the task (stopping at a mark or
cruising on a speed command), how a stopping run's reference must be indexed (by
distance or time), the actuator its prediction model accounts for (order of the lag,
dead time) and what it reads of the line. :func:`unsupported_reason` compares a
scenario with these and returns the first requirement it breaks, in words;
:func:`train_envs.controllers.make_controller` raises :class:`UnsupportedScenarioError`
with that reason, so a run is refused at construction rather than failing (or running
badly) part-way. The measured matrix behind each declaration:
``docs/design/compatibility.md``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

from train_envs.validation import check_choice

__all__ = [
    "CAR_MODELS",
    "INPUT_MODES",
    "REFERENCE_MODES",
    "TASKS",
    "Requirements",
    "UnsupportedScenarioError",
    "requirements",
    "scenario_defaults",
    "unsupported_reason",
]

#: train models a controller may ask for: one point mass, n ≥ 2 coupled cars, or either
CAR_MODELS = ("single", "multi", "any")
#: the scenario's ``input_mode`` values
INPUT_MODES = ("total", "per_car")
#: stopping at ``s_stop_m``, or cruising on a speed command (``s_stop_m is None``)
TASKS = ("stopping", "cruise")
#: a reference indexed by position, v_ref(s), or by time, v_ref(t) and s_ref(t)
REFERENCE_MODES = ("distance", "time")


class UnsupportedScenarioError(ValueError):
    """A controller was asked to run a scenario its method does not support."""


@dataclass(frozen=True)
class Requirements:
    """The scenarios a controller's method is made for.

    Attributes:
        description: one line saying what the controller is.
        cars: ``"single"`` (single-point train), ``"multi"`` (n_cars ≥ 2) or ``"any"``.
        inputs: the input modes it accepts (``"total"``, ``"per_car"``).
        tasks: the tasks it accepts (``"stopping"``, ``"cruise"``).
        stop_references: the reference modes it stops on (``"distance"``, ``"time"``);
            its own paper's scenarios are exempt (they run as the paper ran them).
        max_actuator_order: highest actuator order its model accounts for (0: forces
            act at once, 1: first-order lag, 2: second-order actuator).
        dead_time: whether it accepts an actuator dead time.
        persistent_disturbance: whether it accepts a scenario with a persistent force
            (``disturbance.wind``): ``False`` for a method without integral action or
            disturbance estimate, whose steady speed error under a constant force
            integrates into a position lag growing with the run.
        line: what it reads of the line (informative: every scenario carries a track).
        why: the reason behind the narrowest requirement, quoted in refusals.
        own_scenarios: the scenarios of the controller's own paper, whose reproduction
            fixes its defaults (:func:`scenario_defaults` derives nothing there).
    """

    description: str
    cars: str = "any"
    inputs: tuple[str, ...] = INPUT_MODES
    tasks: tuple[str, ...] = TASKS
    stop_references: tuple[str, ...] = REFERENCE_MODES
    max_actuator_order: int = 2
    dead_time: bool = True
    persistent_disturbance: bool = True
    line: str = "gradient and speed limits"
    why: str = ""
    own_scenarios: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        check_choice("cars", self.cars, CAR_MODELS, sort=False)
        for name, allowed in (
            ("inputs", INPUT_MODES),
            ("tasks", TASKS),
            ("stop_references", REFERENCE_MODES),
        ):
            vals = getattr(self, name)
            if not vals or any(v not in allowed for v in vals):
                raise ValueError(f"{name} must be a non-empty subset of {allowed}, got {vals!r}")
        if self.max_actuator_order not in (0, 1, 2):
            raise ValueError(
                f"max_actuator_order must be 0, 1 or 2, got {self.max_actuator_order!r}"
            )

    def summary(self) -> str:
        """The requirements in one line (``train-envs list controllers``)."""
        cars = {"single": "single-point", "multi": "multi-car", "any": "any train"}[self.cars]
        inputs = "/".join("per-car" if i == "per_car" else "lumped" for i in self.inputs)
        act = ("no lag", "lag <= 1st order", "lag <= 2nd order")[self.max_actuator_order]
        dead = "dead time ok" if self.dead_time else "no dead time"
        if not self.persistent_disturbance:
            dead += ", no persistent disturbance"
        tasks = "/".join(self.tasks)
        if "stopping" in self.tasks and self.stop_references != REFERENCE_MODES:
            tasks += f" (stops on {'/'.join(self.stop_references)}-indexed references)"
        return f"{cars}, {inputs} inputs, {tasks}, {act}, {dead}; line: {self.line}"

    def unsupported_reason(self, scenario: Any) -> str | None:
        """The first requirement ``scenario`` breaks, in words, or ``None``."""
        n = int(scenario.n_cars)
        why = f" ({self.why})" if self.why else ""
        if self.cars == "multi" and n < 2:
            return f"needs a multi-car train (n_cars >= 2), got a single-point train{why}"
        if self.cars == "single" and n > 1:
            return f"needs a single-point train, got {n} cars{why}"
        if scenario.input_mode not in self.inputs:
            kind = "per-car" if scenario.input_mode == "per_car" else "lumped (whole-train)"
            return (
                f"needs input_mode in {self.inputs}, got {kind} inputs "
                f"({scenario.input_mode!r}){why}"
            )
        task = "cruise" if scenario.s_stop_m is None else "stopping"
        if task not in self.tasks:
            return f"needs a {'/'.join(self.tasks)} task, got a {task} run{why}"
        mode = scenario.reference.mode
        if (
            task == "stopping"
            and mode not in self.stop_references
            and scenario.name not in self.own_scenarios
        ):
            return (
                f"stops on a {'/'.join(self.stop_references)}-indexed reference, "
                f"got a {mode}-indexed stopping run{why}"
            )
        order = int(scenario.actuator.order)
        if order > self.max_actuator_order:
            kinds = ("no actuator dynamics", "a first-order actuator lag at most")
            return (
                f"its model has {kinds[self.max_actuator_order]}, "
                f"got an order-{order} actuator{why}"
            )
        if not self.dead_time and float(scenario.actuator.dead_time_s) > 0.0:
            return (
                f"needs an actuator without dead time, got "
                f"{float(scenario.actuator.dead_time_s):g} s{why}"
            )
        wind = scenario.disturbance.wind
        if not self.persistent_disturbance and wind is not None:
            return (
                f"needs a scenario without a persistent disturbance, got {wind} wind "
                "(no integral action or disturbance estimate: a constant force leaves a "
                "steady speed error, and the position lag grows with the run)"
            )
        return None


_SINGLE_POINT = "gradient and speed limits (feedforward)"
_NO_POSITION_LOOP = (
    "speed tracking without position feedback: on v_ref(s) the train slows to the mark "
    "because the reference does, but on a timetable v_ref(t) the stop error is the "
    "integral of the speed error (start lag, lag and dead time in the final braking), "
    "which nothing corrects; station stops need a position loop (pid, afsmc)"
)
_COUPLED_CARS = (
    "paper 000's model: per-car forces acting at once on coupled cars; "
    "for a single-point train use mpc, which predicts the lag and dead time"
)
_CRUISE_MODEL = (
    "paper 002's cruise model holds coupler deformations and speeds, no position, "
    "and no actuator dynamics"
)

P000 = (
    "paper000_single_section",
    "paper000_multi_section",
    "paper000_disturbance_constant",
    "paper000_disturbance_harmonic",
)
P001 = ("paper001_stopping",)
P002 = ("paper002_cruise", "paper002_cruise_feasible")
P003 = ("paper003_cruise",)
P004 = ("paper004_urban",)

#: the declarations, one per controller in CONTROLLERS (tests check the two agree)
REQUIREMENTS: dict[str, Requirements] = {
    "pid": Requirements(
        "speed PID with resistance and gradient feedforward (paper 001's comparator)",
        line=_SINGLE_POINT,
        own_scenarios=P001,
    ),
    "tracking": Requirements(
        "reference tracking: feedforward plus proportional speed feedback",
        stop_references=("distance",),
        line=_SINGLE_POINT,
        why=_NO_POSITION_LOOP,
        own_scenarios=P001,
    ),
    "fuzzy_pid": Requirements(
        "PID with fuzzy online correction of its gains (paper 004's comparator)",
        line=_SINGLE_POINT,
    ),
    "afsmc": Requirements(
        "adaptive fuzzy sliding-mode control on speed and position error",
        line=_SINGLE_POINT,
        own_scenarios=P001,
    ),
    "afsmc000": Requirements(
        "adaptive fuzzy sliding-mode control on speed error (paper 000's comparator)",
        stop_references=("distance",),
        line=_SINGLE_POINT,
        why=_NO_POSITION_LOOP,
        own_scenarios=P000,
    ),
    "dmc": Requirements(
        "dynamic matrix control with fuzzy softening and correction (paper 004)",
        line=_SINGLE_POINT,
        own_scenarios=P004,
    ),
    "mpc": Requirements(
        "linear MPC of a point mass with actuator lag and dead-time prediction (paper 001)",
        line="gradient, speed limits and stop (constraints along the horizon)",
        own_scenarios=P001,
    ),
    "sempc": Requirements(
        "stable economic MPC of the coupled cars, Riccati terminal cost (paper 000)",
        cars="multi",
        inputs=("per_car",),
        max_actuator_order=0,
        dead_time=False,
        line="gradient, speed limits and stop (constraints along the horizon)",
        why=_COUPLED_CARS,
        own_scenarios=P000,
    ),
    "fuzzy_mpc": Requirements(
        "fuzzy constrained predictive cruise control with actuator compensator (paper 003)",
        cars="multi",
        inputs=("per_car",),
        dead_time=False,
        line="gradient and speed limits",
        why="its T-S fuzzy model has one force and one speed per car",
        persistent_disturbance=False,
        own_scenarios=P003,
    ),
    "rmpc": Requirements(
        "tube robust MPC of a point mass with lag and dead time (paper 001)",
        line="gradient, speed limits and stop (tightened constraints)",
        own_scenarios=P001,
    ),
    "rsmpc": Requirements(
        "robust self-triggered tube MPC (paper 001)",
        line="gradient, speed limits and stop (tightened constraints)",
        own_scenarios=P001,
    ),
    "adaptive_mpc": Requirements(
        "adaptive MPC of the coupled cars on an estimated model (paper 002)",
        cars="multi",
        inputs=("per_car",),
        tasks=("cruise",),
        max_actuator_order=0,
        dead_time=False,
        line="gradient and speed limits",
        why=_CRUISE_MODEL,
        own_scenarios=P002,
    ),
}


# the comparators of papers 000 and 002 share their method's model, hence its needs
REQUIREMENTS["mpc000"] = replace(
    REQUIREMENTS["sempc"],
    description="plain MPC of the coupled cars, no terminal cost (paper 000's comparator)",
)
REQUIREMENTS["mpc002"] = replace(
    REQUIREMENTS["adaptive_mpc"],
    description="the adaptive MPC's nominal twin, estimate frozen (paper 002's comparator)",
)


def requirements(controller: str) -> Requirements:
    """The declared requirements of ``controller`` (a name of ``CONTROLLERS``)."""
    check_choice("controller", controller, sorted(REQUIREMENTS))
    return REQUIREMENTS[controller]


def unsupported_reason(controller: str, scenario: Any) -> str | None:
    """Why ``controller`` cannot run ``scenario`` (one line naming the requirement), or
    ``None`` when the pair is supported.  ``scenario``: a
    :class:`train_envs.scenarios.Scenario`."""
    reason = requirements(controller).unsupported_reason(scenario)
    if reason is None:
        return None
    return f"{controller} does not support scenario {scenario.name!r}: {reason}"


def _integrate_on_timetable(scenario: Any) -> dict[str, Any]:
    """PID family: integrate the speed error in every step on a time-indexed stopping
    run, where ∫e dt is the position lag the stop must make up (see ``pid``)."""
    if scenario.s_stop_m is not None and scenario.reference.mode == "time":
        return {"integrate_saturated": True}
    return {}


def _pid_on_timetable(scenario: Any) -> dict[str, Any]:
    """``pid`` on a time-indexed stop: integrate in every step, and the critically
    damped position loop ``k_i = k_p² / 4`` (see ``pid``)."""
    out = _integrate_on_timetable(scenario)
    if out:
        from train_envs.controllers.pid import PIDController

        kp = next(p.default for p in PIDController.PARAMS if p.name == "kp")
        out["ki"] = kp * kp / 4.0
    return out


#: controller -> the options it derives from a scenario
_DERIVED: dict[str, Callable[[Any], dict[str, Any]]] = {
    "pid": _pid_on_timetable,
    "fuzzy_pid": _integrate_on_timetable,
}


def scenario_defaults(controller: str, scenario: Any) -> dict[str, Any]:
    """Constructor options of ``controller`` derived from ``scenario`` (empty on the
    controller's own paper scenarios, whose reproductions fix the defaults);
    :func:`train_envs.controllers.make_controller` applies them under the caller's."""
    req = requirements(controller)
    if scenario.name in req.own_scenarios or controller not in _DERIVED:
        return {}
    return _DERIVED[controller](scenario)
