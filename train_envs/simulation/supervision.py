"""ATP-like supervision of the closed loop, and the safety quantities of a run.

Automatic train protection (ATP) watches the train's speed against the permitted speed
and brakes when the train exceeds it by a margin; the driving controller (ATO, the
controllers of this package) runs under it. The rules, per control period, on the state
at its start (head position ``s``, speed ``v``), after ERA/ERTMS SUBSET-026 §3.13.9
(emergency brake intervention at ``V_permitted + dV_ebi``, ``dV_ebi = 7.5 km/h`` up to
110 km/h; release at the permitted speed, national option ``Q_NVEMRRLS``)::

    trip:     v > v_lim(s) + margin           -> brake (one intervention counted)
    hold:     while braking and v > v_lim(s)
    command:  u = −B_max(v)                   (the train's full braking envelope,
                                               electric + friction, split per car by mass)

``v_lim(s)`` is :func:`permitted_speed_mps` (the one limit query). Safety quantities
recorded per control step (columns of the run's DataFrame) and their sources:

* ``atp_brake``: 1 while the ATP brake is commanded, else 0;
* ``overspeed_mps = max(v − v_lim(s), 0)``;
* ``overrun_m = max(s − (s_stop + w), 0)``, ``w`` the scenario's stopping window
  (:meth:`train_envs.scenarios.Scenario.stop_window`), 0 on runs without a stop;
* multi-car runs: ``coupler_excess = max(|F|/F_max − 1, 0) + max(|q|/q_max − 1, 0)``
  of the coupler of largest force ``F`` and deformation ``q``, limits from
  :class:`train_envs.trains.CouplerParams` (fraction beyond the limits; 0 if unlimited).

The per-step safety cost (the env's ``info["cost"]``, Safety-Gymnasium's convention of
a float ≥ 0 per step) and the episode's ``safety_cost`` metric are built from them, see
:func:`train_envs.metrics.episode_metrics`. Design notes: ``docs/design/supervision.md``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from train_envs.lines.limits import effective_limit_fn, effective_limit_table
from train_envs.scenarios import Scenario
from train_envs.trains import KMH

#: ETCS ``dV_ebi_min`` (SUBSET-026 §3.13.9.3): EB intervention 7.5 km/h over the limit
DEFAULT_MARGIN_MPS = 7.5 * KMH


@dataclass(frozen=True)
class Supervision:
    """Settings of the runner's supervision.

    Attributes:
        atp: whether the ATP brakes above ``v_lim + margin_mps`` (on by default).
        margin_mps: the intervention margin over the permitted speed [m/s], in [0, 20].
        end_on_violation: end the episode (terminated) at the first safety violation:
            an ATP intervention, a coupler beyond its limits or an overrun beyond the
            stopping window.
    """

    atp: bool = True
    margin_mps: float = DEFAULT_MARGIN_MPS
    end_on_violation: bool = False

    def __post_init__(self) -> None:
        for name in ("atp", "end_on_violation"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(
                    f"supervision.{name} must be true or false, got {getattr(self, name)!r}"
                )
        m = self.margin_mps
        ok = isinstance(m, (int, float)) and not isinstance(m, bool)
        if not (ok and math.isfinite(m) and 0.0 <= m <= 20.0):
            raise ValueError(f"supervision.margin_mps must be a number in [0, 20] m/s, got {m!r}")


def permitted_speed_mps(scenario: Scenario, s_m: float) -> float:
    """The permitted speed [m/s] for the train whose head is at ``s_m``: the track's
    speed limit there (the one limit query of the runner, its record and the ATP)."""
    return float(permitted_speed_fn(scenario)(s_m))


def permitted_speed_table(scenario: Scenario) -> tuple[np.ndarray, np.ndarray]:
    """The step function of :func:`permitted_speed_fn` as ``(positions, limits)``: the
    limit at ``s`` is ``limits[max(i, 0)]`` with ``i`` the last position ``≤ s``."""
    return effective_limit_table(scenario.track, scenario.train.length_m)


def permitted_speed_fn(scenario: Scenario) -> Callable[[float], float]:
    """:func:`permitted_speed_mps` of ``scenario`` as a function of the head position
    (the same look-up, bound once: the runner calls it every control step)."""
    return effective_limit_fn(scenario.track, scenario.train.length_m)


def overrun_m(s_m: float, s_stop_m: float | None, window_m: float) -> float:
    """Distance [m] beyond the stopping window ``s_stop + window`` (0 before it or
    without a stop)."""
    if s_stop_m is None:
        return 0.0
    d = s_m - (s_stop_m + window_m)
    return d if d > 0.0 else 0.0


def coupler_excess(force_N: float, def_m: float, force_max_N: float, def_max_m: float) -> float:
    """``max(|F|/F_max − 1, 0) + max(|q|/q_max − 1, 0)`` (infinite limits add 0)."""
    e = 0.0
    rf = abs(force_N) / force_max_N
    if rf > 1.0:
        e += rf - 1.0
    rq = abs(def_m) / def_max_m
    if rq > 1.0:
        e += rq - 1.0
    return e


def coupler_excess_arrays(
    force_N: np.ndarray, def_m: np.ndarray, force_max_N: float, def_max_m: float
) -> np.ndarray:
    """:func:`coupler_excess` elementwise (the same operations: ``0 + x`` is ``x`` for the
    positive excesses, so the sum of the two terms is the scalar's)."""
    rf = np.abs(force_N) / force_max_N
    rq = np.abs(def_m) / def_max_m
    return np.where(rf > 1.0, rf - 1.0, 0.0) + np.where(rq > 1.0, rq - 1.0, 0.0)


class ATP:
    """The supervision state of one episode (see the module docstring for the rules)."""

    def __init__(self, settings: Supervision, scenario: Scenario) -> None:
        self.settings = settings
        self._margin = settings.margin_mps
        self._on = settings.atp
        self._train = scenario.train
        self.braking = False
        self.interventions = 0

    def command(self, v: float, limit: float) -> float | None:
        """The ATP's total brake force [N] for the period starting at speed ``v`` under
        the permitted speed ``limit``, or ``None`` when it leaves the command alone."""
        if not self._on:
            return None
        if self.braking:
            if not v > limit:
                self.braking = False
        elif v > limit + self._margin:
            self.braking = True
            self.interventions += 1
        return -self._train.max_brake_N(v) if self.braking else None
