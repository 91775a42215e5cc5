"""Train parameter sets (SI units inside) and the catalogue of shipped trains.

Every quantity is stored in SI units: kg, N, W, m/s, m/s². Paper tables use t, kN,
N/t, N/kN and km/h; they are converted once here, with the paper's original numbers
kept in the ``source`` text of each set.

Resistance (Davis) is the force ``R(v) = a + b v + c v²`` [N] on the whole train.
The force envelope (:class:`~train_envs.effort.ForceEnvelope`, :attr:`TrainParams.envelope`)
is ``F_max(v) = min(F_t, T(v), P_t / v, M' a_max + R(v))`` with an optional tabulated
tractive-effort curve ``T`` (:class:`~train_envs.effort.EffortCurve`); without a table
it is the usual hyperbola, constant force up to the base speed, then power-limited.
The braking envelope is the same with the regenerative brake (optional table, power)
plus the (not power-limited) friction brake (TTOBench convention).
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from functools import cache, cached_property
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from train_envs.effort import EffortCurve, ForceEnvelope
from train_envs.plants.physics import davis_N
from train_envs.validation import (
    check_choice,
    check_nonnegative,
    check_positive,
    check_range,
    is_json_path,
)

if TYPE_CHECKING:
    from importlib.resources.abc import Traversable

G = 9.81  # m/s², gravitational acceleration used throughout
KMH = 1.0 / 3.6  # m/s per km/h


@dataclass(frozen=True)
class CouplerParams:
    """Linear coupler between neighbouring cars: ``f = k (x_{i-1} - x_i - l) + d (v_{i-1} - v_i)``.

    ``stiffness_N_per_m`` is k, ``damping_Ns_per_m`` is d (0 for the papers' pure
    springs), ``rest_length_m`` is l (000 Table 1: 1.2 m; it only shifts positions).
    ``max_force_N`` and ``max_deformation_m`` are the limits of ``|f|`` and of the
    deformation ``|x_{i-1} - x_i - l|`` (``inf``: none); the runner's supervision flags
    a run beyond them.
    """

    stiffness_N_per_m: float = 1e7
    damping_Ns_per_m: float = 0.0
    rest_length_m: float = 0.0
    max_force_N: float = math.inf
    max_deformation_m: float = math.inf

    def __post_init__(self) -> None:
        check_positive("coupler.stiffness_N_per_m", self.stiffness_N_per_m)
        check_nonnegative("coupler.damping_Ns_per_m", self.damping_Ns_per_m)
        check_nonnegative("coupler.rest_length_m", self.rest_length_m)
        check_positive("coupler.max_force_N", self.max_force_N, allow_inf=True)
        check_positive("coupler.max_deformation_m", self.max_deformation_m, allow_inf=True)


@dataclass(frozen=True)
class TrainParams:
    """Physical parameters of one train (whole-train values, SI units).

    Attributes:
        name: identifier used by the catalogue and the CLI.
        mass_kg: static mass M of the whole train.
        rotating_mass_factor: ρ, so that the inertial mass is ``M (1 + ρ)``.
        davis_a_N, davis_b_Ns_per_m, davis_c_Ns2_per_m2: Davis coefficients of the
            whole train, ``R(v) = a + b v + c v²`` with v in m/s.
        max_traction_force_N, max_traction_power_W: traction envelope (with a
            ``traction_curve``, ``max_traction_force_N`` is a cap on it: give the
            curve's peak for the curve alone).
        max_brake_force_N, max_brake_power_W: electric (regenerative) brake envelope
            (a cap on ``brake_curve`` where one is given).
        max_friction_brake_force_N: pneumatic/friction brake, not power-limited.
        max_accel_mps2, max_decel_mps2: comfort/adhesion limits (``inf`` = none).
        service_decel_mps2: deceleration used by reference profiles when braking.
        max_speed_mps: design speed.
        traction_efficiency, regen_efficiency: in (0, 1]; regen 0 = no regeneration.
        n_cars: number of cars; ``car_masses_kg`` optionally gives each car's mass
            (defaults to ``mass_kg / n_cars`` each).
        coupler: coupler parameters for multi-car models.
        lead_car_aero: if True the ``c v²`` term acts on the lead car only (papers 002,
            003); otherwise resistance is split per car in proportion to mass (000).
        source: where the numbers come from, with the original units.
        traction_curve: optional tabulated tractive effort (speed → force).
        brake_curve: optional tabulated electric braking effort (speed → force); the
            friction brake adds to it.
        length_m: train length [m] (head to rear); 0 = a point train.  Reference
            profiles and the limit preview apply a higher speed limit only once the
            rear has cleared the lower one (:func:`train_envs.lines.limits.effective_limit_table`).
    """

    name: str
    mass_kg: float
    davis_a_N: float
    davis_b_Ns_per_m: float
    davis_c_Ns2_per_m2: float
    max_traction_force_N: float
    max_brake_force_N: float
    max_traction_power_W: float = math.inf
    max_brake_power_W: float = math.inf
    max_friction_brake_force_N: float = 0.0
    rotating_mass_factor: float = 0.0
    max_accel_mps2: float = math.inf
    max_decel_mps2: float = math.inf
    service_decel_mps2: float = 0.8
    max_speed_mps: float = math.inf
    traction_efficiency: float = 1.0
    regen_efficiency: float = 0.0
    n_cars: int = 1
    car_masses_kg: tuple[float, ...] | None = None
    coupler: CouplerParams = field(default_factory=CouplerParams)
    lead_car_aero: bool = False
    source: str = ""
    traction_curve: EffortCurve | None = None
    brake_curve: EffortCurve | None = None
    length_m: float = 0.0

    def __post_init__(self) -> None:
        check_positive("mass_kg", self.mass_kg)
        check_nonnegative("davis_a_N", self.davis_a_N)
        check_nonnegative("davis_b_Ns_per_m", self.davis_b_Ns_per_m)
        check_nonnegative("davis_c_Ns2_per_m2", self.davis_c_Ns2_per_m2)
        check_positive("max_traction_force_N", self.max_traction_force_N)
        check_nonnegative("max_brake_force_N", self.max_brake_force_N)
        check_positive("max_traction_power_W", self.max_traction_power_W, allow_inf=True)
        check_positive("max_brake_power_W", self.max_brake_power_W, allow_inf=True)
        check_nonnegative("max_friction_brake_force_N", self.max_friction_brake_force_N)
        if self.max_brake_force_N + self.max_friction_brake_force_N <= 0:
            raise ValueError("max_brake_force_N + max_friction_brake_force_N must be > 0")
        check_range("rotating_mass_factor", self.rotating_mass_factor, 0.0, 1.0)
        check_positive("max_accel_mps2", self.max_accel_mps2, allow_inf=True)
        check_positive("max_decel_mps2", self.max_decel_mps2, allow_inf=True)
        check_range("service_decel_mps2", self.service_decel_mps2, 0.0, 5.0, low_inclusive=False)
        check_positive("max_speed_mps", self.max_speed_mps, allow_inf=True)
        check_range("traction_efficiency", self.traction_efficiency, 0.0, 1.0, low_inclusive=False)
        check_range("regen_efficiency", self.regen_efficiency, 0.0, 1.0)
        if int(self.n_cars) != self.n_cars or self.n_cars < 1:
            raise ValueError(f"n_cars must be an integer >= 1, got {self.n_cars}")
        if self.car_masses_kg is not None:
            if len(self.car_masses_kg) != self.n_cars:
                raise ValueError(
                    f"car_masses_kg must have n_cars={self.n_cars} entries, "
                    f"got {len(self.car_masses_kg)}"
                )
            for i, m in enumerate(self.car_masses_kg):
                check_positive(f"car_masses_kg[{i}]", m)
            if not math.isclose(sum(self.car_masses_kg), self.mass_kg, rel_tol=1e-9):
                raise ValueError("car_masses_kg must sum to mass_kg")
        for name in ("traction_curve", "brake_curve"):
            curve = getattr(self, name)
            if curve is not None and not isinstance(curve, EffortCurve):
                raise ValueError(
                    f"{name} must be an EffortCurve or None, got {type(curve).__name__}"
                )
        if self.traction_curve is not None and max(self.traction_curve.forces_N) <= 0.0:
            raise ValueError("traction_curve must have a positive force somewhere")
        check_nonnegative("length_m", self.length_m)

    # ------------------------------------------------------------------ derived
    @property
    def inertial_mass_kg(self) -> float:
        """``M (1 + ρ)``: the mass that multiplies the acceleration."""
        return self.mass_kg * (1.0 + self.rotating_mass_factor)

    @property
    def car_masses(self) -> tuple[float, ...]:
        """Mass of each car [kg]."""
        if self.car_masses_kg is not None:
            return tuple(self.car_masses_kg)
        return (self.mass_kg / self.n_cars,) * self.n_cars

    @cached_property
    def envelope(self) -> ForceEnvelope:
        """The force envelope of this (frozen) parameter set, built once: every force-bound
        query of the library goes through it."""
        fin = math.isfinite
        m = self.inertial_mass_kg
        return ForceEnvelope(
            traction_force_N=self.max_traction_force_N,
            brake_force_N=self.max_brake_force_N,
            traction_curve=self.traction_curve,
            traction_power_W=self.max_traction_power_W,
            accel_force_N=m * self.max_accel_mps2 if fin(self.max_accel_mps2) else math.inf,
            davis=(self.davis_a_N, self.davis_b_Ns_per_m, self.davis_c_Ns2_per_m2),
            brake_curve=self.brake_curve,
            brake_power_W=self.max_brake_power_W,
            friction_brake_N=self.max_friction_brake_force_N,
            decel_force_N=m * self.max_decel_mps2 if fin(self.max_decel_mps2) else math.inf,
        )

    def resistance_N(self, v: float) -> float:
        """Davis resistance of the whole train at speed ``v`` [m/s] (opposes motion)."""
        av = abs(v)
        r = davis_N(self.davis_a_N, self.davis_b_Ns_per_m, self.davis_c_Ns2_per_m2, av)
        return math.copysign(r, v) if v != 0 else 0.0

    def max_traction_N(self, v: float) -> float:
        """Traction envelope ``min(F_t, T(|v|), P_t / |v|, M a_max + R(|v|))`` [N]
        (:meth:`ForceEnvelope.traction_N`)."""
        return self.envelope.traction_N(v)

    def max_brake_N(self, v: float) -> float:
        """Braking envelope (positive number) = power-limited electric + friction [N]
        (:meth:`ForceEnvelope.brake_N`)."""
        return self.envelope.brake_N(v)

    def envelope_N(self, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Vectorised force bounds ``(−max_brake_N(v), max_traction_N(v))`` for speeds ``v``
        (:meth:`ForceEnvelope.bounds`)."""
        return self.envelope.bounds(v)

    def envelope_lists(self, speeds: Sequence[float]) -> tuple[list[float], list[float]]:
        """:meth:`envelope_N` for a short sequence of finite speeds, as Python lists, equal
        to it bit for bit (:meth:`ForceEnvelope.bounds_lists`)."""
        return self.envelope.bounds_lists(speeds)

    def envelope_box(self, v_lo: float, v_hi: float) -> tuple[float, float]:
        """A box inside the force envelope for every speed in ``[v_lo, v_hi]`` (``0 ≤ v_lo
        ≤ v_hi``): ``(lo, hi)`` with ``−max_brake_N(v) ≤ lo`` and ``hi ≤ max_traction_N(v)``
        (:meth:`ForceEnvelope.box`).  A controller can test a plan against this box
        with two evaluations and fall back to :meth:`envelope_lists` only when the box
        is too tight."""
        return self.envelope.box(v_lo, v_hi)

    def with_traction_fraction(self, fraction: float) -> TrainParams:
        """Copy with the traction envelope scaled by ``fraction``: force cap, power,
        tractive-effort table and acceleration limit (a train planned with a margin)."""
        check_range("traction_fraction", fraction, 0.1, 1.0)
        curve = self.traction_curve
        return replace(
            self,
            max_traction_force_N=self.max_traction_force_N * fraction,
            max_traction_power_W=self.max_traction_power_W * fraction,
            max_accel_mps2=self.max_accel_mps2 * fraction,
            traction_curve=None if curve is None else curve.scaled(fraction),
        )

    def with_mass_factor(self, factor: float) -> TrainParams:
        """Copy with the mass (load) scaled by ``factor``; Davis a, b scale with mass."""
        check_range("mass factor", factor, 0.5, 2.0)
        masses = (
            None if self.car_masses_kg is None else tuple(m * factor for m in self.car_masses_kg)
        )
        return replace(
            self,
            mass_kg=self.mass_kg * factor,
            car_masses_kg=masses,
            davis_a_N=self.davis_a_N * factor,
            davis_b_Ns_per_m=self.davis_b_Ns_per_m * factor,
        )


# ---------------------------------------------------------------- paper trains
def _paper000() -> TrainParams:
    n, m = 6, 64.8e3
    return TrainParams(
        name="paper000_dtype_metro",
        mass_kg=n * m,
        n_cars=n,
        davis_a_N=9.888 * 64.8 * n,  # 9.888 N/t
        davis_b_Ns_per_m=0.005 * 64.8 * n,  # 0.005 N s/(m t)
        davis_c_Ns2_per_m2=0.00195 * 64.8 * n,  # 0.00195 N s²/(m² t)
        max_traction_force_N=7e4 * n,
        max_brake_force_N=6.5e4 * n,
        max_speed_mps=45.8,
        service_decel_mps2=0.8,
        # l_safe 0.2 m: the bound of paper 000's spacing constraint |x_{i-1} - x_i - l|
        coupler=CouplerParams(
            stiffness_N_per_m=1e7, damping_Ns_per_m=0.0, rest_length_m=1.2, max_deformation_m=0.2
        ),
        regen_efficiency=0.0,
        source=(
            "Paper 000 (Wang, Xing, Wang, IEEE Access 2024) Table 1: 6 cars of 64.8 t, "
            "c0 9.888 N/t, c1 0.005 Ns/(m t), c2 0.00195 Ns^2/(m^2 t), k_s 1e7 N/m, l 1.2 m, "
            "u_max 7e4 N, u_min -6.5e4 N per car, du 6e4 N/s."
        ),
    )


def _paper001() -> TrainParams:
    m = 490e3
    w = m * G / 1000.0  # N per (N/kN)
    return TrainParams(
        name="paper001_hst",
        mass_kg=m,
        davis_a_N=5.4 * w,
        davis_b_Ns_per_m=0.0098 * w,
        davis_c_Ns2_per_m2=0.00163 * w,
        max_traction_force_N=1.07 * m,
        max_brake_force_N=1.07 * m,
        max_decel_mps2=1.07,
        service_decel_mps2=0.5,
        max_speed_mps=20.0,
        source=(
            "Paper 001 (Liu, Xun, Gao, Yin, Acta Automatica Sinica 2022) Table 1: 490 t, "
            "basic resistance 5.4 + 0.0098 v + 0.00163 v^2 read as N/kN (per unit weight) "
            "with v in m/s, max braking 1.07 m/s^2, tau 0.4 s, T_d 1.0 s."
        ),
    )


def _paper002() -> TrainParams:
    n, m = 4, 47.5e3
    return TrainParams(
        name="paper002_crh3",
        mass_kg=n * m,
        n_cars=n,
        davis_a_N=7.75e-3 * n * m,
        davis_b_Ns_per_m=2.28e-4 * n * m,
        davis_c_Ns2_per_m2=1.66e-5 * n * m,
        max_traction_force_N=30e3 * n,
        max_brake_force_N=30e3 * n,
        max_speed_mps=85.0,
        coupler=CouplerParams(stiffness_N_per_m=1e7, max_deformation_m=0.02),  # 002 §5: 20 mm
        lead_car_aero=True,
        source=(
            "Paper 002 (Xu et al. 2019) Table 1, CRH-3 with 4 cars of 47.5 t: c0* 7.75e-3 "
            "N/kg, c1* 2.28e-4 Ns/(m kg), c2* 1.66e-5 Ns^2/(m^2 kg) (aerodynamic term on the "
            "lead car with the total mass), k 1e4 kN/m, -30 kN <= u_i <= 30 kN."
        ),
    )


def _paper003() -> TrainParams:
    # Paper 003's Table 1 numbers were lost in extraction; the paper says they derive from
    # Shinkansen experiments (its ref. [17]). We could not recover them, so this is an
    # ASSUMED Shinkansen-like 8-car set of plausible magnitude (8 x 40 t, per-kg Davis
    # coefficients of the order used for 250-300 km/h EMUs, coupler k = 8e5 N/m).
    n, m = 8, 40e3
    return TrainParams(
        name="paper003_shinkansen",
        mass_kg=n * m,
        n_cars=n,
        davis_a_N=0.01176 * n * m,
        davis_b_Ns_per_m=7.7e-4 * n * m,
        davis_c_Ns2_per_m2=1.6e-5 * n * m,
        max_traction_force_N=60e3 * n,
        max_brake_force_N=60e3 * n,
        max_speed_mps=300 * KMH,
        coupler=CouplerParams(stiffness_N_per_m=8e5, max_deformation_m=0.07),  # as 003's bound
        lead_car_aero=True,
        source=(
            "Paper 003 (fuzzy constrained predictive control) uses Shinkansen parameters whose "
            "table was lost in extraction; ASSUMED Shinkansen-like set: 8 x 40 t, c0 0.01176 "
            "N/kg, c1 7.7e-4 Ns/(m kg), c2 1.6e-5 Ns^2/(m^2 kg) (aero on lead car), k 8e5 N/m, "
            "force limit 60 kN per car."
        ),
    )


def _paper004() -> TrainParams:
    # Paper 004 (Dalian Metro Line 12) publishes no vehicle data. We use a 6-car B-type
    # metro of the kind that runs there: 6 x 35 t (AW2 load), 0-36 km/h at 1.0 m/s^2,
    # B-type Davis 2.755 + 0.014 v + 0.00075 v^2 N/kN (v in km/h), regenerative braking.
    m = 6 * 35e3
    return TrainParams(
        name="paper004_btype_metro",
        mass_kg=m,
        n_cars=6,
        rotating_mass_factor=0.08,
        davis_a_N=2.755e-3 * m * G,  # 2.755 N/kN
        davis_b_Ns_per_m=0.014e-3 * m * G * 3.6,  # 0.014 N/kN per km/h
        davis_c_Ns2_per_m2=0.00075e-3 * m * G * 3.6**2,  # 0.00075 N/kN per (km/h)^2
        max_traction_force_N=1.0 * m * 1.08 + 5e3,
        max_traction_power_W=2.4e6,
        max_brake_force_N=1.0 * m * 1.08,
        max_brake_power_W=3.0e6,
        max_friction_brake_force_N=0.3 * m,
        max_accel_mps2=1.0,
        max_decel_mps2=1.0,
        service_decel_mps2=0.8,
        max_speed_mps=100 * KMH,
        traction_efficiency=0.85,
        regen_efficiency=0.7,
        source=(
            "Paper 004 publishes no vehicle data (Dalian Metro Line 12). Assumed 6-car B-type "
            "metro, 6 x 35 t, rho 0.08, Davis 2.755 + 0.014 v + 0.00075 v^2 N/kN (v in km/h), "
            "1.0 m/s^2 acceleration/deceleration limits, 2.4 MW traction, 3.0 MW regen."
        ),
    )


# --------------------------------------------------------------- TTOBench trains
#: plausibility bounds of a TTOBench train (SI): anything outside is a unit or data error
TTOBENCH_TRAIN_BOUNDS: dict[str, tuple[float, float]] = {
    "mass": (1e3, 2e7),  # 1 t .. 20,000 t (the heaviest freight trains)
    "max speed": (1.0, 600 * KMH),
    "max acceleration": (0.01, 5.0),
    "max deceleration": (0.01, 5.0),
    "rho": (0.0, 1.0),
    "num coaches": (1.0, 100.0),
    "efficiency traction": (0.2, 1.0),
    "efficiency reg brake": (0.0, 1.0),
}


def _unit_value(entry: dict[str, Any], name: str) -> tuple[float, str]:
    try:
        value, unit = float(entry["value"]), str(entry["unit"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(
            f"TTOBench train field {name!r} must be {{'value': <number>, 'unit': <text>}}, "
            f"got {entry!r}"
        ) from exc
    if not math.isfinite(value):
        raise ValueError(f"TTOBench train field {name!r} must be finite, got {value}")
    return value, unit


def _to_si(value: float, unit: str, field_name: str) -> float:
    """``value`` in ``unit`` converted to SI; ``"%"`` is a percentage (``10 %`` is 0.1)."""
    factors = {
        "kg": 1.0,
        "t": 1e3,
        "kN": 1e3,
        "N": 1.0,
        "kW": 1e3,
        "W": 1.0,
        "km/h": KMH,
        "m/s": 1.0,
        "m/s^2": 1.0,
        "kN/(km/h)": 1e3 / KMH,
        "kN/(km/h)^2": 1e3 / KMH**2,
        "-": 1.0,
    }
    if unit == "%":
        return value / 100.0
    if unit not in factors:
        raise ValueError(
            f"TTOBench train field {field_name!r}: unsupported unit {unit!r}; "
            f"expected one of {sorted([*factors, '%'])}"
        )
    return value * factors[unit]


def _loss_map_efficiency(entry: dict[str, Any], name: str, p_max_W: float) -> float:
    """Mean efficiency ``1 − losses / P_max`` of a loss map ``[[load %, speed, losses],
    ...]`` at its highest load (100 % in TTOBench's maps)."""
    rows = entry.get("values")
    if not isinstance(rows, list) or not rows:
        raise ValueError(f"TTOBench train field {name!r}: the loss map has no rows")
    unit = entry.get("units", {}).get("losses", "kW")
    try:
        table = [(float(r[0]), _to_si(float(r[2]), unit, name)) for r in rows]
    except (TypeError, ValueError, IndexError) as exc:
        raise ValueError(
            f"TTOBench train field {name!r}: rows must be [load %, speed, losses] numbers ({exc})"
        ) from None
    if not math.isfinite(p_max_W) or p_max_W <= 0:
        raise ValueError(f"TTOBench train field {name!r}: a loss map needs a finite max power")
    top = max(load for load, _ in table)
    losses = [loss for load, loss in table if load == top]
    return max(0.05, 1.0 - sum(losses) / len(losses) / p_max_W)


def train_from_ttobench(data: dict[str, Any]) -> TrainParams:
    """Build :class:`TrainParams` from a parsed TTOBench train JSON document.

    Units are converted to SI (``"%"`` is a percentage); values outside
    :data:`TTOBENCH_TRAIN_BOUNDS` and traction or braking forces above twice the
    train's weight (a unit error: adhesion stays below 0.4) are refused.
    """
    if not isinstance(data, dict):
        raise ValueError(f"a TTOBench train must be a JSON object, got {type(data).__name__}")

    def efficiency(name: str, power_field: str) -> float:
        entry = data.get(name)
        if isinstance(entry, dict) and "values" in entry:
            return checked(name, _loss_map_efficiency(entry, name, get(power_field, math.inf)))
        return get(name, 1.0 if "traction" in name else 0.0)

    def checked(name: str, x: float) -> float:
        if name in TTOBENCH_TRAIN_BOUNDS:
            lo, hi = TTOBENCH_TRAIN_BOUNDS[name]
            if not lo <= x <= hi:
                raise ValueError(
                    f"TTOBench train field {name!r} = {x:g} (SI) is implausible; allowed "
                    f"[{lo:g}, {hi:g}] (check the value and its unit)"
                )
        return x

    def get(name: str, default: float | None = None) -> float:
        if name not in data:
            if default is None:
                raise ValueError(f"TTOBench train is missing required field {name!r}")
            return default
        v, u = _unit_value(data[name], name)
        return checked(name, _to_si(v, u, name))

    name = str(data.get("metadata", {}).get("id", "ttobench_train"))
    mass = get("mass")
    max_acc = get("max acceleration", math.inf)
    max_dec = get("max deceleration", math.inf)
    n_cars = get("num coaches", 1.0)
    if not float(n_cars).is_integer():
        raise ValueError(f"TTOBench train field 'num coaches' must be an integer, got {n_cars}")
    for force in ("max traction force", "max reg braking force", "max pn braking force"):
        f = get(force, 0.0)
        if not 0.0 <= f <= 2.0 * mass * G:
            raise ValueError(
                f"TTOBench train field {force!r} = {f:g} N is implausible for a "
                f"{mass / 1e3:g} t train; allowed [0, {2.0 * mass * G:g}] N (twice its weight)"
            )
    return TrainParams(
        name=name,
        mass_kg=mass,
        rotating_mass_factor=get("rho", 0.0),
        davis_a_N=get("rolling resistance r0"),
        davis_b_Ns_per_m=get("rolling resistance r1", 0.0),
        davis_c_Ns2_per_m2=get("rolling resistance r2", 0.0),
        max_traction_force_N=get("max traction force"),
        max_traction_power_W=get("max traction power", math.inf),
        max_brake_force_N=get("max reg braking force", 0.0),
        max_brake_power_W=get("max reg braking power", math.inf),
        max_friction_brake_force_N=get("max pn braking force", 0.0),
        max_accel_mps2=max_acc,
        max_decel_mps2=max_dec,
        service_decel_mps2=min(0.8, max_dec) if math.isfinite(max_dec) else 0.8,
        max_speed_mps=get("max speed", math.inf),
        traction_efficiency=efficiency("efficiency traction", "max traction power"),
        regen_efficiency=efficiency("efficiency reg brake", "max reg braking power"),
        n_cars=int(n_cars),
        source=f"TTOBench v1.3 train {name} (BSD-2-Clause, Kouzoupis, Pendharkar, Corman 2023)",
        **rolling_stock_from_ttobench(data),
    )


#: optional fields of a TTOBench-style train document read by :func:`rolling_stock_from_ttobench`
TTOBENCH_CURVE_FIELDS = {
    "traction effort curve": "traction_curve",
    "reg braking effort curve": "brake_curve",
}


def rolling_stock_from_ttobench(data: dict[str, Any]) -> dict[str, Any]:
    """The :class:`TrainParams` fields of the optional rolling-stock entries of a
    TTOBench-style train document (TTOBench v1.3/v1.4 files have none of them):

    * ``"traction effort curve"``, ``"reg braking effort curve"``: tables in the style of
      TTOBench's loss maps, ``{"units": {"velocity": "km/h", "force": "kN"}, "values":
      [[v, F], ...]}`` (any speed and force unit of the loader);
    * ``"length"``: ``{"unit": "m", "value": L}``, the train length.
    """
    out: dict[str, Any] = {}
    for key, attr in TTOBENCH_CURVE_FIELDS.items():
        entry = data.get(key)
        if entry is None:
            continue
        try:
            units, rows = entry["units"], entry["values"]
            vu, fu = str(units["velocity"]), str(units["force"])
        except (KeyError, TypeError) as exc:
            raise ValueError(
                f"TTOBench train field {key!r} must have 'units' (velocity, force) and 'values'"
            ) from exc
        pairs = []
        for row in rows:
            if len(row) != 2:
                raise ValueError(f"TTOBench train field {key!r}: rows must be [speed, force]")
            pairs.append((_to_si(float(row[0]), vu, key), _to_si(float(row[1]), fu, key)))
        out[attr] = EffortCurve.from_pairs(
            pairs, "m/s", "N", source=f"TTOBench field {key!r} ({vu}, {fu})"
        )
    if "length" in data:
        value, unit = _unit_value(data["length"], "length")
        if unit != "m":
            raise ValueError(f"TTOBench train field 'length': unit must be 'm', got {unit!r}")
        out["length_m"] = value
    return out


def train_from_ttobench_file(path: str | os.PathLike[str] | Traversable) -> TrainParams:
    """:func:`train_from_ttobench` of a JSON file; every error names the file."""
    try:
        text = path.read_text() if hasattr(path, "read_text") else Path(path).read_text()
        data = json.loads(text)
        return train_from_ttobench(data)
    except (OSError, ValueError) as exc:  # JSONDecodeError is a ValueError
        raise ValueError(f"TTOBench train file {str(path)!r}: {exc}") from None


TTOBENCH_TRAIN_FILES = {
    "CN_Beijing_Subway": "CN_Beijing_Subway.json",
    "CH_Stadler_FLIRT_TPF": "CH_Stadler_FLIRT_TPF.json",
    "CH_Stadler_KISS": "CH_Stadler_KISS.json",
    "NL_Intercity_VIRM6": "NL_Intercity_VIRM6.json",
    "00_Loco_Dyn": "00_Loco_Dyn.json",
}

PAPER_TRAINS = {
    "paper000_dtype_metro": _paper000,
    "paper001_hst": _paper001,
    "paper002_crh3": _paper002,
    "paper003_shinkansen": _paper003,
    "paper004_btype_metro": _paper004,
}


def list_trains() -> list[str]:
    """Names of every train in the catalogue (paper sets and TTOBench trains)."""
    return sorted(PAPER_TRAINS) + sorted(TTOBENCH_TRAIN_FILES)


@cache
def get_train(name: str | os.PathLike[str]) -> TrainParams:
    """Return a catalogue train by name (see :func:`list_trains`), or the train of a
    user's TTOBench-format JSON file when ``name`` is a path (ends in ``.json`` or
    holds a directory separator)."""
    if is_json_path(name):
        return train_from_ttobench_file(os.fspath(name))
    check_choice("train", name, list_trains(), sort=False)
    if name in PAPER_TRAINS:
        return PAPER_TRAINS[name]()
    folder = resources.files("train_envs") / "data" / "TTOBench" / "trains"
    return train_from_ttobench_file(folder / TTOBENCH_TRAIN_FILES[name])
