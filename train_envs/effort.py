"""The force envelope of a train: tractive and braking effort limits against speed.

One object, :class:`ForceEnvelope`, answers every "how much force is available at
speed v" query of the library (plant saturation, reference profiles, controller bounds).
With ``|v|`` the speed, the traction limit is

    ``F_max(v) = min(F_t, T(|v|), P_t / |v|, M' a_max + R(|v|))``

and the braking limit (a positive number)

    ``B_max(v) = min(min(F_b, E(|v|), P_b / |v|) + F_fric, M' d_max)``

with ``T``, ``E`` optional tabulated tractive/electric-brake effort curves
(:class:`EffortCurve`: piecewise linear in speed, held at the end values outside the
table), ``P_t``, ``P_b`` optional power limits (moving speeds only), ``F_fric`` the
friction brake (not power-limited, TTOBench convention), ``M' = M (1 + ρ)`` the inertial
mass and ``R`` the Davis resistance (the acceleration limit is on the net force).
A term that is absent is ``+inf``; the classic "constant force, then constant power"
train is the case without tables.  Published effort curves of diesel-hydraulic and
many electric units (e.g. UIC/EN 15528-style tractive-effort diagrams) are tables of
this kind, far from the hyperbola.

Floating point: without tables the arithmetic is exactly that of the hyperbolic
envelope (the same operations in the same order); a table adds one ``min``.  The
scalar, list and array forms give equal values bit for bit.  See
``docs/design/plants.md`` (section "The force envelope") and ``docs/rolling_stock.md``.
"""

from __future__ import annotations

import csv
import functools
import math
from bisect import bisect_left, bisect_right
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from train_envs import _jit
from train_envs.plants.lookup import PiecewiseLinear
from train_envs.plants.physics import davis_sq_N
from train_envs.validation import check_nonnegative, check_positive

#: speed units of the table readers, in m/s per unit
SPEED_UNITS = {"m/s": 1.0, "km/h": 1.0 / 3.6}
#: force units of the table readers, in N per unit
FORCE_UNITS = {"N": 1.0, "kN": 1e3}


@dataclass(frozen=True)
class EffortCurve:
    """A tractive or braking effort curve: force [N] against speed [m/s], piecewise linear.

    Attributes:
        speeds_mps: table speeds, strictly increasing, the first ``>= 0``.
        forces_N: force at each table speed, finite and ``>= 0``.
        source: where the numbers come from (with the original units).

    Between table speeds the force is interpolated linearly; below the first and above
    the last speed it is held at the end value (give the table up to the train's
    maximum speed).
    """

    speeds_mps: tuple[float, ...]
    forces_N: tuple[float, ...]
    source: str = field(default="", compare=False)

    def __post_init__(self) -> None:
        v = tuple(float(x) for x in self.speeds_mps)
        f = tuple(float(x) for x in self.forces_N)
        if len(v) < 1 or len(v) != len(f):
            raise ValueError(
                f"EffortCurve needs as many forces_N as speeds_mps (at least 1), "
                f"got {len(f)} and {len(v)}"
            )
        for i, x in enumerate(v):
            if not math.isfinite(x) or x < 0.0 or (i and x <= v[i - 1]):
                raise ValueError(
                    f"EffortCurve.speeds_mps must be finite, >= 0 and strictly increasing: "
                    f"element {i} is {x}"
                )
        for i, x in enumerate(f):
            if not math.isfinite(x) or x < 0.0:
                raise ValueError(
                    f"EffortCurve.forces_N must be finite and >= 0: element {i} is {x}"
                )
        object.__setattr__(self, "speeds_mps", v)
        object.__setattr__(self, "forces_N", f)

    @classmethod
    def from_pairs(
        cls,
        pairs: Sequence[Sequence[float]],
        speed_unit: str = "km/h",
        force_unit: str = "kN",
        source: str = "",
    ) -> EffortCurve:
        """A curve from ``(speed, force)`` pairs in the given units (see
        :data:`SPEED_UNITS`, :data:`FORCE_UNITS`)."""
        if speed_unit not in SPEED_UNITS:
            raise ValueError(f"speed_unit must be one of {sorted(SPEED_UNITS)}, got {speed_unit!r}")
        if force_unit not in FORCE_UNITS:
            raise ValueError(f"force_unit must be one of {sorted(FORCE_UNITS)}, got {force_unit!r}")
        ks, kf = SPEED_UNITS[speed_unit], FORCE_UNITS[force_unit]
        rows = [tuple(r) for r in pairs]
        if any(len(r) != 2 for r in rows):
            raise ValueError("effort curve rows must be (speed, force) pairs")
        return cls(
            tuple(float(r[0]) * ks for r in rows), tuple(float(r[1]) * kf for r in rows), source
        )

    @classmethod
    def from_csv(
        cls, path: str | Path, speed_unit: str = "km/h", force_unit: str = "kN"
    ) -> EffortCurve:
        """Read a plain CSV of ``speed, force`` rows (comma-separated; a first row that
        is not numeric is a header; blank lines and ``#`` comments are skipped)."""
        path = Path(path)
        rows: list[tuple[float, float]] = []
        header_seen = False
        with path.open(newline="") as fh:
            for k, row in enumerate(csv.reader(fh)):
                cells = [c.strip() for c in row]
                if not cells or not cells[0] or cells[0].startswith("#"):
                    continue
                try:
                    rows.append((float(cells[0]), float(cells[1])))
                except (ValueError, IndexError):
                    if rows or header_seen:
                        raise ValueError(
                            f"{path}: row {k + 1} is not a (speed, force) pair: {row}"
                        ) from None
                    header_seen = True  # the first non-blank row may be a header
        if not rows:
            raise ValueError(f"{path}: no (speed, force) rows")
        return cls.from_pairs(
            rows, speed_unit, force_unit, source=f"{path.name} ({speed_unit}, {force_unit})"
        )

    # ------------------------------------------------------------------ evaluation
    @cached_property
    def table(self) -> PiecewiseLinear:
        """The curve as a :class:`~train_envs.plants.lookup.PiecewiseLinear` look-up
        (the last segment has slope 0: the end value is held)."""
        v = np.array(self.speeds_mps)
        f = np.array(self.forces_N)
        slope = np.zeros(v.size)
        if v.size > 1:
            slope[:-1] = np.diff(f) / np.diff(v)
        return PiecewiseLinear(v, f, slope)

    @cached_property
    def constant(self) -> bool:
        """True for a one-point table (a constant force)."""
        return len(self.speeds_mps) == 1

    def __call__(self, v):
        """Force [N] at speed(s) ``v >= 0`` [m/s] (a float, or an array of the same shape)."""
        if self.constant:
            return (
                self.forces_N[0] if isinstance(v, float) else np.full(np.shape(v), self.forces_N[0])
            )
        return self.table(v)

    def min_over(self, v_lo: float, v_hi: float) -> float:
        """A lower bound of the curve on ``[v_lo, v_hi]``: the smallest of the values at
        both ends and at the table speeds inside, less 8 ulps of the peak force (the
        rounding of the interpolation between table speeds)."""
        if self.constant:
            return self.forces_N[0]
        xs, fs = self.speeds_mps, self.forces_N
        m = min(self(float(v_lo)), self(float(v_hi)))
        i0, i1 = bisect_right(xs, v_lo), bisect_left(xs, v_hi)
        if i1 > i0:
            m = min(m, min(fs[i0:i1]))
        return max(m - 8.0 * math.ulp(max(fs)), 0.0)

    def scaled(self, factor: float) -> EffortCurve:
        """The curve with every force multiplied by ``factor``."""
        return EffortCurve(self.speeds_mps, tuple(f * factor for f in self.forces_N), self.source)


@dataclass(frozen=True)
class ForceEnvelope:
    """Traction and braking limits against speed (equations in the module docstring).

    Attributes:
        traction_force_N: ``F_t``, the constant traction cap (adhesion / converter).
        traction_curve: ``T``, optional tabulated tractive effort.
        traction_power_W: ``P_t`` (``inf`` = none).
        accel_force_N: ``M' a_max`` (``inf`` = none); the cap is ``M' a_max + R(|v|)``
            with ``R(0) = 0``.
        davis: ``(a, b, c)`` of the whole train, for that cap.
        brake_force_N: ``F_b``, electric brake cap.
        brake_curve: ``E``, optional tabulated electric braking effort.
        brake_power_W: ``P_b`` (``inf`` = none).
        friction_brake_N: ``F_fric``.
        decel_force_N: ``M' d_max`` (``inf`` = none).
    """

    traction_force_N: float
    brake_force_N: float
    traction_curve: EffortCurve | None = None
    traction_power_W: float = math.inf
    accel_force_N: float = math.inf
    davis: tuple[float, float, float] = (0.0, 0.0, 0.0)
    brake_curve: EffortCurve | None = None
    brake_power_W: float = math.inf
    friction_brake_N: float = 0.0
    decel_force_N: float = math.inf
    # (F_t, T, P_t | None, M'a_max | None, a, b, c) and (F_b, E, P_b | None, F_fric, M'd_max | None)
    _t: tuple = field(init=False, repr=False, compare=False)
    _b: tuple = field(init=False, repr=False, compare=False)

    # (F_t, P_t, M'a_max, a, b, c, F_b, P_b, F_fric, M'd_max), NaN where absent: BOUNDS
    _k: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        for name in ("traction_force_N", "brake_force_N", "friction_brake_N"):
            check_nonnegative(name, getattr(self, name))
        for name in ("traction_power_W", "accel_force_N", "brake_power_W", "decel_force_N"):
            check_positive(name, getattr(self, name), allow_inf=True)
        fin = math.isfinite
        a, b, c = self.davis
        object.__setattr__(
            self,
            "_t",
            (
                self.traction_force_N,
                self.traction_curve,
                self.traction_power_W if fin(self.traction_power_W) else None,
                self.accel_force_N if fin(self.accel_force_N) else None,
                a,
                b,
                c,
            ),
        )
        object.__setattr__(
            self,
            "_b",
            (
                self.brake_force_N,
                self.brake_curve,
                self.brake_power_W if fin(self.brake_power_W) else None,
                self.friction_brake_N,
                self.decel_force_N if fin(self.decel_force_N) else None,
            ),
        )

        t, b = self._t, self._b
        nan = math.nan
        object.__setattr__(
            self,
            "_k",
            np.array(
                [t[0], nan if t[2] is None else t[2], nan if t[3] is None else t[3], t[4],
                 t[5], t[6], b[0], nan if b[2] is None else b[2], b[3],
                 nan if b[4] is None else b[4]],
                dtype=float,
            ),
        )  # fmt: skip

    @property
    def tabulated(self) -> bool:
        """True when a tractive or braking effort table is part of the envelope."""
        return self.traction_curve is not None or self.brake_curve is not None

    # ------------------------------------------------------------------ scalar
    def traction_N(self, v: float) -> float:
        """``F_max(v)`` [N] at one speed."""
        f, T, P, MA, a, b, c = self._t
        av = abs(v)
        if T is not None:
            f = min(f, T(float(av)))
        if av > 0 and P is not None:
            f = min(f, P / av)
        if MA is not None:
            # M (1 + ρ) a_max + R(|v|), R(0) = 0 (the envelope's bracketing, as bounds())
            f = min(f, MA + (davis_sq_N(a, b, c, av) if av != 0 else 0.0))
        return f

    def brake_N(self, v: float) -> float:
        """``B_max(v)`` [N] (a positive number) at one speed."""
        f, E, P, Ffr, MD = self._b
        av = abs(v)
        if E is not None:
            f = min(f, E(float(av)))
        if av > 0 and P is not None:
            f = min(f, P / av)
        f += Ffr
        if MD is not None:
            f = min(f, MD)
        return f

    # ------------------------------------------------------------------ vectorised
    def bounds(self, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(−B_max(v), F_max(v))`` for an array (or numpy scalar) of speeds
        (:data:`BOUNDS`: :func:`bounds_arrays` or its compiled twin)."""
        av = np.abs(np.asarray(v, dtype=float))
        if av.ndim == 0:  # a scalar speed: numpy scalars, the same values as the arrays
            lo, hi = self.bounds(av.reshape(1))
            return lo[0], hi[0] if self._t[3] is not None else hi.reshape(())
        flat = av.reshape(-1)
        lo, hi = _bounds_impl()(flat, *self.table_forces(flat), self._k)
        return lo.reshape(av.shape), hi.reshape(av.shape)

    def table_forces(self, av: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The effort tables' forces ``(T(av), E(av))`` at the speeds ``av ≥ 0`` (1-D), an
        empty array for a term without a table: what :func:`bounds_arrays` and its
        compiled twin take with :attr:`constants`."""
        T, E = self._t[1], self._b[1]
        tv = _NONE if T is None else np.asarray(T(av), dtype=float)
        ev = _NONE if E is None else np.asarray(E(av), dtype=float)
        return tv, ev

    @property
    def constants(self) -> np.ndarray:
        """The envelope's ``(F_t, P_t, M'a_max, a, b, c, F_b, P_b, F_fric, M'd_max)`` as
        :func:`bounds_arrays` takes them (NaN where a term is absent)."""
        return self._k

    def bounds_lists(self, speeds: Sequence[float]) -> tuple[list[float], list[float]]:
        """:meth:`bounds` for a short sequence of finite speeds, as Python lists (the
        same arithmetic per speed, results equal bit for bit)."""
        F, T, P, MA, a, b, c = self._t
        Fb, E, Pb, Ffr, MD = self._b
        lo_out: list[float] = []
        hi_out: list[float] = []
        for v in speeds:
            av = abs(v)
            hi = F if T is None else min(F, T(float(av)))
            lo = Fb if E is None else min(Fb, E(float(av)))
            if av > 0.0:
                if P is not None:
                    hi = min(hi, P / av)
                if MA is not None:
                    hi = min(hi, MA + davis_sq_N(a, b, c, av))
                if Pb is not None:
                    lo = min(lo, Pb / av)
            elif MA is not None:
                hi = min(hi, MA + 0.0)
            lo += Ffr
            if MD is not None:
                lo = min(lo, MD)
            lo_out.append(-lo)
            hi_out.append(hi)
        return lo_out, hi_out

    def box(self, v_lo: float, v_hi: float) -> tuple[float, float]:
        """A box ``(lo, hi)`` inside the envelope for every speed in ``[v_lo, v_hi]``
        (``0 <= v_lo <= v_hi``): ``−B_max(v) <= lo`` and ``hi <= F_max(v)`` there.

        ``P/v`` falls and the Davis resistance rises with speed (non-negative
        coefficients), so ``min(F, min T, P/v_hi, M' a_max + R(v_lo))`` bounds the
        traction and ``min(min(F_b, min E, P_b/v_hi) + F_fric, M' d_max)`` the braking
        from below (``min T``: :meth:`EffortCurve.min_over`).  Rounding is monotone, so
        the bounds hold in floating point too.
        """
        F, T, P, MA, a, b, c = self._t
        Fb, E, Pb, Ffr, MD = self._b
        hi = F if T is None else min(F, T.min_over(v_lo, v_hi))
        if v_hi > 0.0 and P is not None:
            hi = min(hi, P / v_hi)
        if MA is not None:
            hi = min(hi, MA + (davis_sq_N(a, b, c, v_lo) if v_lo > 0.0 else 0.0))
        if E is None:
            return -self.brake_N(v_hi), hi
        lo = min(Fb, E.min_over(v_lo, v_hi))
        if v_hi > 0.0 and Pb is not None:
            lo = min(lo, Pb / v_hi)
        lo += Ffr
        if MD is not None:
            lo = min(lo, MD)
        return -lo, hi

    def peak_traction_N(self) -> float:
        """The largest traction force of the envelope over all speeds (an upper bound:
        ``min(F_t, max T)``)."""
        F, T = self._t[0], self._t[1]
        return F if T is None else min(F, max(T.forces_N))


_NONE = np.zeros(0)


def bounds_arrays(
    av: np.ndarray, tv: np.ndarray, ev: np.ndarray, K: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``(−B_max, F_max)`` at the speeds ``av ≥ 0`` (1-D), numpy form: the reference of
    :data:`BOUNDS`. ``tv``, ``ev``: ``T(av)``, ``E(av)`` (empty: no table); ``K``: the
    envelope's ``(F_t, P_t, M'a_max, a, b, c, F_b, P_b, F_fric, M'd_max)``, NaN where a
    term is absent (the module docstring's equations)."""
    F, P, MA, a, b, c, Fb, Pb, Ffr, MD = K.tolist()
    pos = av > 0
    hi = np.full(av.shape, F) if tv.size == 0 else np.minimum(F, tv)
    # the power limits apply to moving speeds only: P/|v| there, +inf at standstill
    if P == P:
        hi = np.minimum(hi, np.divide(P, av, out=np.full(av.shape, np.inf), where=pos))
    if MA == MA:
        davis = davis_sq_N(a, b, c, av)  # (numpy's av**2 is av * av)
        hi = np.minimum(hi, MA + np.where(pos, davis, 0.0))
    lo = np.full(av.shape, Fb) if ev.size == 0 else np.minimum(Fb, ev)
    if Pb == Pb:
        lo = np.minimum(lo, np.divide(Pb, av, out=np.full(av.shape, np.inf), where=pos))
    lo += Ffr
    if MD == MD:
        lo = np.minimum(lo, MD)
    return -lo, hi


def _np_min(x: float, y: float) -> float:
    """numpy's ``minimum`` of two floats (NaN if either is NaN)."""
    return x if (x < y or x != x) else y


def bounds_loop(
    av: np.ndarray, tv: np.ndarray, ev: np.ndarray, K: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`bounds_arrays` speed by speed (the same IEEE operations): the source of
    the compiled twin of :data:`BOUNDS`."""
    F, P, MA, a, b, c, Fb, Pb, Ffr, MD = K[0], K[1], K[2], K[3], K[4], K[5], K[6], K[7], K[8], K[9]
    n = av.shape[0]
    lo_out = np.empty(n)
    hi_out = np.empty(n)
    for i in range(n):
        x = av[i]
        pos = x > 0
        hi = F if tv.size == 0 else _np_min(F, tv[i])
        if P == P:
            hi = _np_min(hi, P / x if pos else np.inf)
        if MA == MA:
            hi = _np_min(hi, MA + (davis_sq_N(a, b, c, x) if pos else 0.0))
        lo = Fb if ev.size == 0 else _np_min(Fb, ev[i])
        if Pb == Pb:
            lo = _np_min(lo, Pb / x if pos else np.inf)
        lo += Ffr
        if MD == MD:
            lo = _np_min(lo, MD)
        lo_out[i] = -lo
        hi_out[i] = hi
    return lo_out, hi_out


#: the name of the envelope's array form in :data:`train_envs._jit.TWINS`
BOUNDS = "effort.bounds"
#: the functions :func:`bounds_loop` calls, by name (for the compiled loops that call it)
BOUNDS_HELPERS = {"_np_min": _np_min, "davis_sq_N": davis_sq_N}
_jit.register(
    BOUNDS, bounds_arrays, source=bounds_loop,
    helpers=BOUNDS_HELPERS,
)  # fmt: skip


@functools.cache
def _bounds_impl() -> Any:
    return _jit.implementation(BOUNDS)


__all__ = [
    "BOUNDS",
    "BOUNDS_HELPERS",
    "FORCE_UNITS",
    "SPEED_UNITS",
    "EffortCurve",
    "ForceEnvelope",
    "bounds_arrays",
    "bounds_loop",
]
