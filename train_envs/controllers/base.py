"""The controller protocol shared by the closed-loop runner, the envs and the tuners.

A controller never knows about the env. It is reset with a :class:`ControlContext`
(what the controller may know about the run: nominal train, track, reference, control
period, command bounds) and, every control period, turns an :class:`Observation`
(the measured state) into a command in newtons. Its tuning parameters are declared
by :meth:`Controller.tunable_params` as :class:`TunableParam` specs and can be changed
between steps with :meth:`Controller.set_params` — that is what the env's action does.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from train_envs.trains import TrainParams
from train_envs.validation import check_finite


@dataclass(frozen=True)
class TunableParam:
    """One tuning parameter: name, bounds, scale and default.

    ``log=True`` means the parameter is searched on a logarithmic scale (weights);
    :meth:`from_unit` / :meth:`to_unit` map between the parameter and [−1, 1]. The
    ordered parameters of an env or a tuning problem, with these maps and the tuner's
    native scale, are a :class:`train_envs.controllers.params.ParamSpace`.
    """

    name: str
    low: float
    high: float
    default: float
    log: bool = False
    description: str = ""

    def __post_init__(self) -> None:
        if not (math.isfinite(self.low) and math.isfinite(self.high)) or self.low >= self.high:
            raise ValueError(
                f"param {self.name}: need finite low < high, got [{self.low}, {self.high}]"
            )
        if self.log and self.low <= 0:
            raise ValueError(f"param {self.name}: log scale needs low > 0, got {self.low}")
        if not (self.low <= self.default <= self.high):
            raise ValueError(
                f"param {self.name}: default {self.default} outside [{self.low}, {self.high}]"
            )

    def from_unit(self, a: float) -> float:
        """Map a ∈ [−1, 1] to the parameter range (log-uniform if ``log``)."""
        a = min(1.0, max(-1.0, float(a)))
        f = 0.5 * (a + 1.0)
        if self.log:
            x = math.exp(math.log(self.low) + f * (math.log(self.high) - math.log(self.low)))
        else:
            x = self.low + f * (self.high - self.low)
        return min(self.high, max(self.low, x))  # exact bounds despite rounding

    def to_unit(self, x: float) -> float:
        """Inverse of :meth:`from_unit`."""
        if self.log:
            f = (math.log(x) - math.log(self.low)) / (math.log(self.high) - math.log(self.low))
        else:
            f = (x - self.low) / (self.high - self.low)
        return 2.0 * f - 1.0

    def check(self, value: float) -> float:
        x = check_finite(f"param {self.name}", value)
        if not (self.low <= x <= self.high):
            raise ValueError(f"param {self.name} must lie in [{self.low}, {self.high}], got {x}")
        return x


@dataclass
class ControlContext:
    """What a controller may know about the run it is reset for.

    Attributes:
        train: nominal train parameters (the plant may differ: mass, drift).
        track: the line (gradient/curve/limit look-up), or ``None``.
        reference: the reference profile (``train_envs.reference.Reference``).
        dt_s: control period.
        n_inputs: 1 (whole-train force) or n_cars (per-car forces).
        u_min_N, u_max_N: command bounds per input at standstill (the controller may
            query ``train.max_traction_N(v)`` for the speed-dependent envelope).
        du_max_Nps: command rate limit (per input, N/s), ``inf`` if none.
        actuator_tau_s, dead_time_s: the actuator model the controller may assume.
        s_stop_m: target stopping position, or ``None`` for cruise scenarios.
        extra: scenario-specific data (e.g. the paper's weights).
    """

    train: TrainParams
    track: Any
    reference: Any
    dt_s: float
    n_inputs: int = 1
    u_min_N: np.ndarray = field(default_factory=lambda: np.array([-np.inf]))
    u_max_N: np.ndarray = field(default_factory=lambda: np.array([np.inf]))
    du_max_Nps: float = math.inf
    actuator_order: int = 0
    actuator_tau_s: float = 0.0
    dead_time_s: float = 0.0
    n_cars: int = 1
    s_stop_m: float | None = None
    extra: dict[str, Any] = field(default_factory=dict)


@dataclass
class Observation:
    """Measured state handed to the controller each control period."""

    t_s: float
    s_m: float
    v_mps: float
    a_mps2: float
    u_prev_N: np.ndarray
    positions_m: np.ndarray
    speeds_mps: np.ndarray
    forces_N: np.ndarray


class Controller:
    """Base class. Subclasses implement :meth:`compute` and declare tunable parameters."""

    name: str = "controller"
    #: tunable parameters; subclasses override
    PARAMS: tuple[TunableParam, ...] = ()
    #: when a parameter change acts, where not at the next control step (the env contract
    #: pages print it; None: at the next control step)
    PARAMS_TAKE_EFFECT: str | None = None
    #: whether data the controller keeps across :meth:`reset` (e.g. a QP built once)
    #: was formed with the parameters of an earlier episode, so that only a new
    #: controller equals a fresh one bit for bit; a reused env then rebuilds it
    #: (:meth:`~train_envs.envs.train_env.TrainTuningEnv.renew_controller`).  True unless
    #: a subclass knows better: a controller whose ``reset`` re-derives everything the
    #: parameters touch declares False.
    keeps_parameter_state: bool = True

    def __init__(self, **params: float) -> None:
        self._params: dict[str, float] = {p.name: p.default for p in self.PARAMS}
        self.set_params(**params)
        self.ctx: ControlContext | None = None

    # -------------------------------------------------------------- params
    @classmethod
    def tunable_params(cls) -> tuple[TunableParam, ...]:
        return cls.PARAMS

    def set_params(self, **params: float) -> None:
        """Set tuning parameters (cheap; may be called between any two steps)."""
        specs = {p.name: p for p in self.PARAMS}
        for k, v in params.items():
            if k not in specs:
                raise ValueError(
                    f"{self.name} has no tunable parameter {k!r}; choose from: "
                    f"{', '.join(specs) or '(none)'}"
                )
            self._params[k] = specs[k].check(v)
        if params:
            self._on_params_changed()

    def get_params(self) -> dict[str, float]:
        return dict(self._params)

    def _on_params_changed(self) -> None:  # noqa: B027 - optional hook
        """Hook: recompute whatever depends on the parameters."""

    # ------------------------------------------------------------- control
    def reset(self, ctx: ControlContext) -> None:
        self.ctx = ctx

    def compute(self, obs: Observation) -> tuple[np.ndarray, Mapping[str, Any]]:
        """Return the command [N] (array of ``ctx.n_inputs``) and an info mapping."""
        raise NotImplementedError
