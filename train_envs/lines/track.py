"""Track (line) description: stops, speed limits, gradients and curves, in SI units.

A :class:`Track` is the static infrastructure seen by a point-mass train at position
``s`` [m] along the line:

* **stops** ``stops_m``: strictly increasing, first 0; the last stop is the track length.
* **speed-limit sections**: start positions [m] and limits [m/s]; a limit holds from its
  start position (inclusive) to the next start position (exclusive).
* **gradient sections**: start positions [m] and gradients [permil = m per km], uphill
  positive.
* **curve sections**: start positions [m], radius at start and radius at end [m]
  (signed: positive = right-hand, negative = left-hand, ``inf`` = straight). Equal radii
  mean a circular arc; different radii mean a clothoid (transition curve) whose
  *curvature* ``1/R`` varies linearly with distance between the two values.

The section conventions are those of TTOBench (Kouzoupis, Pendharkar, Corman 2023, see
``train_envs/data/TTOBench/tracks/README.md``); km/h is only used at the JSON boundary.

The position lookups (``speed_limit_at`` etc.) are called every simulation sub-step, so
they use binary search on arrays precomputed in ``__post_init__``: ``bisect`` on Python
lists for scalar arguments, ``np.searchsorted`` for arrays. Positions outside
``[0, length_m]`` are clamped to the first / last section.

Curve resistance is converted into an equivalent gradient with the standard empirical
formula ``w_c = 600 / R`` [N/kN, i.e. permil], ``R`` in m, see
:meth:`Track.curve_resistance_permil_at`.
"""

from __future__ import annotations

import functools
import json
import math
import os
from bisect import bisect_right
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from train_envs import _jit
from train_envs._lazy import lazy_exports
from train_envs.trains import KMH, G
from train_envs.validation import check_increasing, check_range

if TYPE_CHECKING:
    from importlib.resources.abc import Traversable

    import pandas as pd

FloatOrArray = float | np.ndarray
#: constructors of the papers' lines (in :mod:`train_envs.lines.paper_lines`)
PAPER_LINES = (
    "paper001_track",
    "paper000_section_track",
    "paper000_multi_section_track",
    "paper002_track",
    "paper003_track",
    "paper004_track",
)
_SCALAR = (float, int)  # fast path for scalar arguments (np.float64 is a float)

#: Curve-resistance coefficient of the empirical formula ``w_c = A / R`` [N/kN * m].
CURVE_RESISTANCE_COEFF = 600.0
#: Radii above this [m] are treated as straight track for curve resistance.
CURVE_RESISTANCE_MAX_RADIUS_M = 10_000.0
#: Largest gradient magnitude accepted by the validation [permil] (adhesion railways).
MAX_ABS_GRADIENT_PERMIL = 100.0


def _step_lookup(
    pos_list: str, val_list: str, pos_array: str, val_array: str, doc: str
) -> Callable[[Track, FloatOrArray], FloatOrArray]:
    """A piecewise-constant look-up method: the value of the section holding ``s``.

    Sections start at their positions (right-continuous steps); before the first position
    the first value holds. Scalars take a bisection over the section lists (the plants'
    per-step path), arrays :func:`numpy.searchsorted` over the frozen arrays.
    """

    def lookup(self: Track, s: FloatOrArray) -> FloatOrArray:
        if isinstance(s, _SCALAR):
            i = bisect_right(getattr(self, pos_list), s) - 1
            return getattr(self, val_list)[i if i > 0 else 0]
        return getattr(self, val_array)[section_index(getattr(self, pos_array), s)]

    lookup.__doc__ = doc
    return lookup


def _section_values(
    label: str, values: Any, n: int, unit: str, lo: float, hi: float, low_inclusive: bool = True
) -> np.ndarray:
    """The values of ``n`` sections of ``track.<label>``, one each, within ``[lo, hi]``."""
    arr = _as_array(values, f"track.{label} values")
    if arr.size != n:
        raise ValueError(
            f"track.{label} values must have one entry per position ({n}), got {arr.size}"
        )
    for i, v in enumerate(arr):
        check_range(f"track.{label} values[{i}] ({unit})", v, lo, hi, low_inclusive=low_inclusive)
    return arr


def _as_array(value: Any, name: str) -> np.ndarray:
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a sequence of numbers, got {value!r}") from exc
    if arr.ndim != 1:
        raise ValueError(f"{name} must be a 1-D sequence, got shape {arr.shape}")
    return arr


def _frozen(arr: np.ndarray) -> np.ndarray:
    arr = np.array(arr, dtype=float)
    arr.setflags(write=False)
    return arr


def _curvature(radius: np.ndarray) -> np.ndarray:
    """Signed curvature ``1/R`` [1/m]; ``R = ±inf`` gives 0."""
    with np.errstate(divide="ignore"):
        return np.where(np.isinf(radius), 0.0, 1.0 / radius)


def _radius(curvature: float) -> float:
    return math.inf if curvature == 0.0 else 1.0 / curvature


def _radii(curvature: np.ndarray) -> np.ndarray:
    """Signed radius [m] of each curvature; 0 gives ``inf``."""
    out = np.full(curvature.shape, math.inf)
    nz = curvature != 0.0
    out[nz] = 1.0 / curvature[nz]
    return out


@dataclass(frozen=True, eq=False, repr=False)
class Track:
    """Static description of a line, SI units (see the module docstring for conventions).

    Attributes:
        name: identifier (catalogue name or TTOBench id).
        stops_m: stop positions [m], strictly increasing, first 0; ``stops_m[-1]`` is the
            track length.
        speed_limit_positions_m, speed_limits_mps: section starts [m] (first 0) and the
            speed limit of each section [m/s] (> 0).
        gradient_positions_m, gradients_permil: section starts [m] (first 0) and the
            gradient of each section [permil], uphill positive. Empty = level track.
        curve_positions_m, curve_radius_start_m, curve_radius_end_m: section starts [m]
            (first 0), signed radii at the start and end of each section [m]; ``inf`` for
            straight track; different radii = clothoid with linearly varying curvature.
            Empty = straight track.
        source: where the data come from and what was assumed.

    All section positions must be strictly increasing, start at 0 and lie before the
    last stop. Arrays are stored as read-only copies, so a ``Track`` is immutable and can
    be shared (the catalogue caches them).
    """

    name: str
    stops_m: np.ndarray
    speed_limit_positions_m: np.ndarray
    speed_limits_mps: np.ndarray
    gradient_positions_m: np.ndarray = field(default_factory=lambda: np.zeros(0))
    gradients_permil: np.ndarray = field(default_factory=lambda: np.zeros(0))
    curve_positions_m: np.ndarray = field(default_factory=lambda: np.zeros(0))
    curve_radius_start_m: np.ndarray = field(default_factory=lambda: np.zeros(0))
    curve_radius_end_m: np.ndarray = field(default_factory=lambda: np.zeros(0))
    source: str = ""

    # precomputed lookup tables (not part of the constructor)
    _sl_pos: list[float] = field(init=False, repr=False, compare=False)
    _sl_val: list[float] = field(init=False, repr=False, compare=False)
    _gr_pos: list[float] = field(init=False, repr=False, compare=False)
    _gr_val: list[float] = field(init=False, repr=False, compare=False)
    _gr_sin: list[float] = field(init=False, repr=False, compare=False)
    _straight: bool = field(init=False, repr=False, compare=False)
    _cv_pos: list[float] = field(init=False, repr=False, compare=False)
    _cv_end: list[float] = field(init=False, repr=False, compare=False)
    _cv_k0: list[float] = field(init=False, repr=False, compare=False)
    _cv_k1: list[float] = field(init=False, repr=False, compare=False)
    _cv_end_arr: np.ndarray = field(init=False, repr=False, compare=False)
    _cv_k0_arr: np.ndarray = field(init=False, repr=False, compare=False)
    _cv_k1_arr: np.ndarray = field(init=False, repr=False, compare=False)
    _stops: list[float] = field(init=False, repr=False, compare=False)

    # ------------------------------------------------------------------ validation
    def __post_init__(self) -> None:
        try:
            self._validate_and_freeze()
        except ValueError as exc:
            raise ValueError(f"{exc} [track {self.name!r}]") from None

    def _set(self, name: str, value: Any) -> None:
        object.__setattr__(self, name, value)

    def _check_sections(self, label: str, positions: np.ndarray, length: float) -> np.ndarray:
        pos = check_increasing(f"track.{label} positions", positions)
        if pos.size == 0:
            raise ValueError(f"track.{label} must have at least one section")
        if pos[0] != 0.0:
            raise ValueError(f"track.{label} positions must start at 0, got {pos[0]}")
        if pos[-1] >= length:
            raise ValueError(
                f"track.{label} positions must lie in [0, length_m={length}), "
                f"got last position {pos[-1]}"
            )
        return pos

    def _validate_and_freeze(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"track.name must be a non-empty string, got {self.name!r}")
        stops = check_increasing("track.stops_m", _as_array(self.stops_m, "track.stops_m"))
        if stops.size < 2:
            raise ValueError(f"track.stops_m needs at least 2 stops, got {stops.size}")
        if stops[0] != 0.0:
            raise ValueError(f"track.stops_m must start at 0, got {stops[0]}")
        length = float(stops[-1])  # > 0 because strictly increasing from 0

        # speed limits
        sl_pos = self._check_sections(
            "speed_limits", _as_array(self.speed_limit_positions_m, "track.speed_limits"), length
        )
        sl_val = _section_values(
            "speed_limits", self.speed_limits_mps, sl_pos.size, "m/s", 0.0, math.inf, False
        )

        # gradients (empty = level)
        gr_pos_in = _as_array(self.gradient_positions_m, "track.gradients positions")
        gr_val = _as_array(self.gradients_permil, "track.gradients values")
        if gr_pos_in.size == 0 and gr_val.size == 0:
            gr_pos_in, gr_val = np.zeros(1), np.zeros(1)
        gr_pos = self._check_sections("gradients", gr_pos_in, length)
        gr_val = _section_values(
            "gradients",
            gr_val,
            gr_pos.size,
            "permil",
            -MAX_ABS_GRADIENT_PERMIL,
            MAX_ABS_GRADIENT_PERMIL,
        )

        # curves (empty = straight)
        cv_pos_in = _as_array(self.curve_positions_m, "track.curvatures positions")
        r0 = _as_array(self.curve_radius_start_m, "track.curvatures radius_start")
        r1 = _as_array(self.curve_radius_end_m, "track.curvatures radius_end")
        if cv_pos_in.size == 0 and r0.size == 0 and r1.size == 0:
            cv_pos_in, r0, r1 = np.zeros(1), np.full(1, math.inf), np.full(1, math.inf)
        cv_pos = self._check_sections("curvatures", cv_pos_in, length)
        for label, r in (("radius_start", r0), ("radius_end", r1)):
            if r.size != cv_pos.size:
                raise ValueError(
                    f"track.curvatures {label} must have one entry per position "
                    f"({cv_pos.size}), got {r.size}"
                )
            bad = np.nonzero(np.isnan(r) | (r == 0.0))[0]
            if bad.size:
                i = int(bad[0])
                raise ValueError(
                    f"track.curvatures {label}[{i}] must be a non-zero radius in m "
                    f"(inf for straight track), got {r[i]}"
                )

        for name, arr in (
            ("stops_m", stops),
            ("speed_limit_positions_m", sl_pos),
            ("speed_limits_mps", sl_val),
            ("gradient_positions_m", gr_pos),
            ("gradients_permil", gr_val),
            ("curve_positions_m", cv_pos),
            ("curve_radius_start_m", r0),
            ("curve_radius_end_m", r1),
        ):
            self._set(name, _frozen(arr))

        cv_end = np.append(cv_pos[1:], length)
        self._set("_stops", stops.tolist())
        self._set("_sl_pos", sl_pos.tolist())
        self._set("_sl_val", sl_val.tolist())
        self._set("_gr_pos", gr_pos.tolist())
        self._set("_gr_val", gr_val.tolist())
        self._set("_gr_sin", np.sin(np.arctan(gr_val * 1e-3)).tolist())
        self._set("_cv_pos", cv_pos.tolist())
        self._set("_cv_end", cv_end.tolist())
        k0, k1 = _curvature(r0), _curvature(r1)
        self._set("_cv_k0", k0.tolist())
        self._set("_cv_k1", k1.tolist())
        self._set("_cv_end_arr", _frozen(cv_end))
        self._set("_cv_k0_arr", _frozen(k0))
        self._set("_cv_k1_arr", _frozen(k1))
        self._set("_straight", bool(np.all(k0 == 0.0) and np.all(k1 == 0.0)))

    def __repr__(self) -> str:
        return (
            f"Track(name={self.name!r}, length_m={self.length_m:g}, stops={len(self._stops)}, "
            f"speed_limit_sections={len(self._sl_pos)}, gradient_sections={len(self._gr_pos)}, "
            f"curve_sections={len(self._cv_pos)})"
        )

    # ------------------------------------------------------------------ basics
    @property
    def length_m(self) -> float:
        """Track length [m] = position of the last stop."""
        return self._stops[-1]

    @property
    def station_pairs(self) -> list[tuple[float, float]]:
        """Consecutive stop pairs ``(from_m, to_m)``: the station-to-station runs."""
        return list(zip(self._stops[:-1], self._stops[1:], strict=True))

    def breakpoints_m(self) -> np.ndarray:
        """Sorted union of all section starts and stops [m] (where any property changes)."""
        return np.unique(
            np.concatenate(
                (
                    self.stops_m,
                    self.speed_limit_positions_m,
                    self.gradient_positions_m,
                    self.curve_positions_m,
                )
            )
        )

    def resistance_breakpoints_m(self) -> np.ndarray:
        """Sorted positions [m] where the equivalent gradient changes its formula: the
        gradient and curve section starts, and inside each clothoid the points where the
        radius crosses the curve-resistance cut-off (:data:`CURVE_RESISTANCE_MAX_RADIUS_M`)
        or the curvature changes sign.  Between two of them the equivalent gradient is
        constant or linear in ``s`` (a plant integrates across none of them)."""
        pts = [self.gradient_positions_m, self.curve_positions_m]
        cut = 1.0 / CURVE_RESISTANCE_MAX_RADIUS_M
        for p0, p1, k0, k1 in zip(
            self._cv_pos, self._cv_end, self._cv_k0, self._cv_k1, strict=True
        ):
            if k0 == k1:
                continue
            for target in (-cut, 0.0, cut):
                frac = (target - k0) / (k1 - k0)
                if 0.0 < frac < 1.0:
                    pts.append(np.array([p0 + frac * (p1 - p0)]))
        return np.unique(np.concatenate(pts))

    # ------------------------------------------------------------------ lookups
    speed_limit_at = _step_lookup(
        "_sl_pos",
        "_sl_val",
        "speed_limit_positions_m",
        "speed_limits_mps",
        "Speed limit [m/s] at position ``s`` [m] (a section starts at its position).",
    )
    gradient_permil_at = _step_lookup(
        "_gr_pos",
        "_gr_val",
        "gradient_positions_m",
        "gradients_permil",
        "Gradient [permil] at position ``s`` [m], uphill positive.",
    )

    def curvature_at(self, s: FloatOrArray) -> FloatOrArray:
        """Signed curvature ``1/R`` [1/m] at ``s`` [m] (positive = right-hand curve).

        Within a section the curvature varies linearly from ``1/R_start`` at the section
        start to ``1/R_end`` at the next section start (or the track end): constant on an
        arc, a clothoid when the radii differ.
        """
        if isinstance(s, _SCALAR):
            i = bisect_right(self._cv_pos, s) - 1
            if i < 0:
                i = 0
            k0 = self._cv_k0[i]
            k1 = self._cv_k1[i]
            if k0 == k1:
                return k0
            p = self._cv_pos[i]
            frac = (s - p) / (self._cv_end[i] - p)
            frac = 0.0 if frac < 0.0 else (1.0 if frac > 1.0 else frac)
            return k0 + (k1 - k0) * frac
        x = np.asarray(s, float)
        cv = self.section_arrays()[2:]
        return curvature_in_section(section_index(cv[0], x), x, *cv)

    def curve_resistance_permil_at(self, s: FloatOrArray) -> FloatOrArray:
        """Curve resistance per unit weight [N/kN = permil] at ``s`` [m].

        Standard empirical formula ``w_c = 600 / R`` with ``R`` the curve radius in m
        (``|R|``: left- and right-hand curves resist alike), as used in the Chinese train
        traction calculation regulations (TB/T 1407) and of the same form as the widely
        used Röckl-type ``k / R`` curve-resistance formulas. Radii above 10 km (including
        straight track) give 0. The train is treated as a point mass (the whole train is
        on the curve at ``s``).
        """
        k = self.curvature_at(s)
        if isinstance(k, float):
            ak = abs(k)
            return CURVE_RESISTANCE_COEFF * ak if ak * CURVE_RESISTANCE_MAX_RADIUS_M >= 1.0 else 0.0
        return curve_resistance_of(k)

    def equivalent_gradient_permil_at(self, s: FloatOrArray) -> FloatOrArray:
        """Gradient plus curve resistance as an equivalent gradient [permil].

        ``i_eq = i + 600 / |R|`` (``R`` in m, ignored above 10 km), see
        :meth:`curve_resistance_permil_at`. An array of positions goes through
        :data:`EQUIVALENT_GRADIENT` (the same values).
        """
        if isinstance(s, _SCALAR) or np.ndim(s) == 0:
            return self.gradient_permil_at(s) + self.curve_resistance_permil_at(s)
        x = np.asarray(s, float)
        return _equivalent_gradient_impl()(x.reshape(-1), *self.section_arrays()).reshape(x.shape)

    def section_arrays(self) -> tuple[np.ndarray, ...]:
        """The section arrays of the equivalent gradient: gradient positions and values,
        curve section starts and ends, curvatures at the start and at the end (the
        arguments after the positions of :func:`equivalent_gradient_arrays`)."""
        return (
            self.gradient_positions_m, self.gradients_permil, self.curve_positions_m,
            self._cv_end_arr, self._cv_k0_arr, self._cv_k1_arr,
        )  # fmt: skip

    def gradient_force_N(
        self, s: FloatOrArray, mass_kg: float, *, include_curves: bool = True
    ) -> FloatOrArray:
        """Track force opposing the motion [N] on a train of (static) mass ``mass_kg``.

        ``F = m g sin(atan(i / 1000)) + m g w_c / 1000`` with ``i`` the gradient [permil]
        (exact slope angle, not the small-angle ``m g i / 1000``; the difference is below
        0.1 % for |i| < 40 permil) and ``w_c`` the curve resistance [N/kN] of
        :meth:`curve_resistance_permil_at`. Positive uphill / in curves, negative
        downhill. Pass ``include_curves=False`` for the gradient term alone. ``g = 9.81``.
        """
        if isinstance(s, _SCALAR):
            i = bisect_right(self._gr_pos, s) - 1
            f = mass_kg * G * self._gr_sin[i if i > 0 else 0]
            if include_curves and not self._straight:
                f += mass_kg * G * 1e-3 * self.curve_resistance_permil_at(s)
            return f
        x = np.asarray(s, float)
        f = mass_kg * G * np.sin(np.arctan(self.gradient_permil_at(x) * 1e-3))
        if include_curves:
            f = f + mass_kg * G * 1e-3 * self.curve_resistance_permil_at(x)
        return f

    def next_stop_after(self, s: float, tol_m: float = 1e-6) -> float | None:
        """First stop strictly beyond ``s + tol_m`` [m], or ``None`` past the last stop.

        ``tol_m`` lets a train that halted a hair short of a stop look past it.
        """
        i = bisect_right(self._stops, s + tol_m)
        return self._stops[i] if i < len(self._stops) else None

    # ------------------------------------------------------------------ sections
    def section(self, s_from: float, s_to: float, name: str | None = None) -> Track:
        """Sub-track ``[s_from, s_to]`` re-based so that ``s_from`` becomes position 0.

        Stops strictly inside the interval are kept; ``0`` and ``s_to - s_from`` become the
        first and last stops. The sections active at ``s_from`` start at 0; a clothoid cut
        by either end keeps its curvature (the cut ends get the radius at the cut).
        """
        s_from = check_range("section s_from", s_from, 0.0, self.length_m)
        s_to = check_range("section s_to", s_to, 0.0, self.length_m)
        if s_to <= s_from:
            raise ValueError(f"section s_to ({s_to}) must be greater than s_from ({s_from})")
        length = s_to - s_from

        def cut(positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            """Indices of the kept sections and their re-based start positions."""
            i0 = max(int(np.searchsorted(positions, s_from, side="right")) - 1, 0)
            rebased = positions - s_from
            inside = np.nonzero((rebased > 0.0) & (rebased < length))[0]
            idx = np.concatenate(([i0], inside)).astype(int)
            return idx, np.concatenate(([0.0], rebased[inside]))

        stops_rel = self.stops_m - s_from
        stops = np.concatenate(
            ([0.0], stops_rel[(stops_rel > 0.0) & (stops_rel < length)], [length])
        )
        sl_idx, sl_pos = cut(self.speed_limit_positions_m)
        gr_idx, gr_pos = cut(self.gradient_positions_m)
        cv_idx, cv_pos = cut(self.curve_positions_m)

        r_start, r_end = [], []
        for j in cv_idx:
            p, e = self._cv_pos[j], self._cv_end[j]
            k0, k1 = self._cv_k0[j], self._cv_k1[j]
            a, b = max(p, s_from), min(e, s_to)
            if k0 == k1:
                ka, kb = k0, k1
            else:
                ka = k0 + (k1 - k0) * (a - p) / (e - p)
                kb = k0 + (k1 - k0) * (b - p) / (e - p)
            r_start.append(self.curve_radius_start_m[j] if a == p else _radius(ka))
            r_end.append(self.curve_radius_end_m[j] if b == e else _radius(kb))

        return Track(
            name=name or f"{self.name}[{s_from:g}-{s_to:g}]",
            stops_m=stops,
            speed_limit_positions_m=sl_pos,
            speed_limits_mps=self.speed_limits_mps[sl_idx],
            gradient_positions_m=gr_pos,
            gradients_permil=self.gradients_permil[gr_idx],
            curve_positions_m=cv_pos,
            curve_radius_start_m=np.array(r_start, float),
            curve_radius_end_m=np.array(r_end, float),
            source=f"section [{s_from:g} m, {s_to:g} m] of track {self.name!r}; {self.source}",
        )

    # ------------------------------------------------------------------ I/O
    @classmethod
    def from_ttobench(
        cls, path_or_dict: str | os.PathLike[str] | Traversable | Mapping[str, Any]
    ) -> Track:
        """Build a track from a TTOBench track JSON file (path) or its parsed dictionary.

        Speed limits are converted from km/h to m/s; ``"infinity"`` radii become ``inf``.
        Values outside :data:`TTOBENCH_TRACK_BOUNDS` are refused as unit or data errors;
        every error from a file names the file.
        """
        if isinstance(path_or_dict, Mapping):
            return _track_from_ttobench_dict(path_or_dict)
        try:
            if hasattr(path_or_dict, "read_text") and not isinstance(path_or_dict, str | bytes):
                data = json.loads(path_or_dict.read_text())  # type: ignore[union-attr]
            else:
                with open(path_or_dict, encoding="utf-8") as fh:
                    data = json.load(fh)
            return _track_from_ttobench_dict(data)
        except (OSError, ValueError) as exc:  # JSONDecodeError is a ValueError
            raise ValueError(f"TTOBench track file {str(path_or_dict)!r}: {exc}") from None

    def to_dataframe(self) -> pd.DataFrame:
        """Summary table: one row per homogeneous piece between consecutive breakpoints.

        Columns: ``start_m``, ``end_m``, ``length_m``, ``v_limit_mps``, ``v_limit_kmh``,
        ``gradient_permil``, ``radius_start_m``, ``radius_end_m`` (signed; ``inf`` =
        straight; the radius at the piece ends), ``curve_resistance_permil`` (at the piece
        midpoint), ``stop_at_start`` (a stop lies at ``start_m``).
        """
        import pandas as pd

        bp = self.breakpoints_m()
        start, end = bp[:-1], bp[1:]
        mid = 0.5 * (start + end)
        k_start = self.curvature_at(start)
        cv = self.section_arrays()[2:]
        k_end = curvature_in_section(section_index(cv[0], start), end, *cv)  # its own section
        v = self.speed_limit_at(start)
        return pd.DataFrame(
            {
                "start_m": start,
                "end_m": end,
                "length_m": end - start,
                "v_limit_mps": v,
                "v_limit_kmh": v / KMH,
                "gradient_permil": self.gradient_permil_at(start),
                "radius_start_m": _radii(k_start),
                "radius_end_m": _radii(k_end),
                "curve_resistance_permil": self.curve_resistance_permil_at(mid),
                "stop_at_start": np.isin(start, self.stops_m),
            }
        )


# ---------------------------------------------------------------------- TTOBench
_POSITION_UNITS = {"m": 1.0, "km": 1000.0}
_VELOCITY_UNITS = {"km/h": KMH, "m/s": 1.0}

#: plausibility bounds of a TTOBench track (SI): line length [m] (the longest railway
#: line is 9,300 km), speed limit [m/s] (600 km/h) and the smallest curve radius [m]
TTOBENCH_TRACK_BOUNDS = {"length_m": 1e7, "speed_limit_mps": 600 * KMH, "radius_m": 10.0}


def _unit_factor(
    units: Mapping[str, Any], key: str, table: Mapping[str, float], what: str
) -> float:
    """Conversion factor to SI of ``units[key]`` (positions default to m)."""
    unit = units.get(key, "m" if table is _POSITION_UNITS else None)
    if unit not in table:
        raise ValueError(
            f"TTOBench track field {what!r}: unsupported {key} unit {unit!r}; "
            f"expected one of {sorted(table)}"
        )
    return table[unit]


def _rows(data: Mapping[str, Any], what: str, width: int) -> list[Sequence[Any]]:
    entry = data.get(what)
    if not isinstance(entry, Mapping) or "values" not in entry:
        raise ValueError(f"TTOBench track field {what!r} must be an object with 'values'")
    rows = entry["values"]
    if not isinstance(rows, Sequence) or isinstance(rows, str):
        raise ValueError(f"TTOBench track field {what!r}: 'values' must be a list of rows")
    for i, row in enumerate(rows):
        if not isinstance(row, Sequence) or len(row) != width:
            raise ValueError(
                f"TTOBench track field {what!r}: row {i} must have {width} entries, got {row!r}"
            )
    return list(rows)


def _num(x: Any, what: str) -> float:
    try:
        return float(x)  # also parses "infinity" / "-infinity"
    except (TypeError, ValueError) as exc:
        raise ValueError(f"TTOBench track field {what!r}: {x!r} is not a number") from exc


def _units(data: Mapping[str, Any], what: str) -> Mapping[str, Any]:
    """The ``units`` mapping of section ``what`` (empty if it gives none)."""
    entry = data.get(what, {})
    units = entry.get("units", {}) if isinstance(entry, Mapping) else None
    if not isinstance(units, Mapping):
        raise ValueError(f"TTOBench track field {what!r} must be an object with 'units'")
    return units


def _track_from_ttobench_dict(data: Mapping[str, Any]) -> Track:
    if not isinstance(data, Mapping):
        raise ValueError(f"a TTOBench track must be a JSON object, got {type(data).__name__}")
    meta = data.get("metadata", {})
    name = str(meta.get("id", "ttobench_track")) if isinstance(meta, Mapping) else "ttobench"

    stops_entry = data.get("stops")
    if not isinstance(stops_entry, Mapping) or "values" not in stops_entry:
        raise ValueError("TTOBench track field 'stops' must be an object with 'values'")
    stop_factor = _unit_factor(
        {"position": stops_entry.get("unit", "m")}, "position", _POSITION_UNITS, "stops"
    )
    if not isinstance(stops_entry["values"], Sequence) or isinstance(stops_entry["values"], str):
        raise ValueError("TTOBench track field 'stops': 'values' must be a list of positions")
    stops = [_num(x, "stops") * stop_factor for x in stops_entry["values"]]
    if stops and not abs(stops[-1]) <= TTOBENCH_TRACK_BOUNDS["length_m"]:
        raise ValueError(
            f"TTOBench track field 'stops': a line of {stops[-1] / 1e3:g} km is implausible; "
            f"allowed up to {TTOBENCH_TRACK_BOUNDS['length_m'] / 1e3:g} km (check the unit)"
        )

    sl_units = _units(data, "speed limits")
    sl_pf = _unit_factor(sl_units, "position", _POSITION_UNITS, "speed limits")
    sl_vf = _unit_factor(sl_units, "velocity", _VELOCITY_UNITS, "speed limits")
    sl = _rows(data, "speed limits", 2)

    gr_pos: list[float] = []
    gr_val: list[float] = []
    if "gradients" in data:
        g_units = _units(data, "gradients")
        g_pf = _unit_factor(g_units, "position", _POSITION_UNITS, "gradients")
        slope = g_units.get("slope", "permil")
        if slope != "permil":
            raise ValueError(
                f"TTOBench track field 'gradients': unsupported slope unit {slope!r}; "
                "expected 'permil'"
            )
        for row in _rows(data, "gradients", 2):
            gr_pos.append(_num(row[0], "gradients") * g_pf)
            gr_val.append(_num(row[1], "gradients"))

    cv_pos: list[float] = []
    r0: list[float] = []
    r1: list[float] = []
    if "curvatures" in data:
        c_units = _units(data, "curvatures")
        c_pf = _unit_factor(c_units, "position", _POSITION_UNITS, "curvatures")
        rf0 = _unit_factor(c_units, "radius at start", _POSITION_UNITS, "curvatures")
        rf1 = _unit_factor(c_units, "radius at end", _POSITION_UNITS, "curvatures")
        r_min = TTOBENCH_TRACK_BOUNDS["radius_m"]
        for i, row in enumerate(_rows(data, "curvatures", 3)):
            cv_pos.append(_num(row[0], "curvatures") * c_pf)
            r0.append(_num(row[1], "curvatures") * rf0)
            r1.append(_num(row[2], "curvatures") * rf1)
            if not (abs(r0[-1]) >= r_min and abs(r1[-1]) >= r_min):
                raise ValueError(
                    f"TTOBench track field 'curvatures': row {i} has a radius of "
                    f"{min(abs(r0[-1]), abs(r1[-1])):g} m; allowed |R| >= {r_min:g} m "
                    "(check the unit)"
                )

    meta = meta if isinstance(meta, Mapping) else {}
    source = (
        f"TTOBench track {name} ({meta.get('library version', 'TTOBench')}, "
        f"{meta.get('license', 'BSD 2-Clause License')}, created by "
        f"{meta.get('created by', 'unknown')}); Kouzoupis, Pendharkar, Corman, "
        "Operations Research Forum 4:67 (2023)"
    )
    limits = np.array([_num(r[1], "speed limits") * sl_vf for r in sl])
    v_max = TTOBENCH_TRACK_BOUNDS["speed_limit_mps"]
    if limits.size and not np.all(np.abs(limits) <= v_max):
        i = int(np.argmax(~(np.abs(limits) <= v_max)))
        raise ValueError(
            f"TTOBench track field 'speed limits': row {i} limits {limits[i] / KMH:g} km/h; "
            f"allowed up to {v_max / KMH:g} km/h (check the unit)"
        )
    return Track(
        name=name,
        stops_m=np.array(stops, float),
        speed_limit_positions_m=np.array([_num(r[0], "speed limits") * sl_pf for r in sl]),
        speed_limits_mps=limits,
        gradient_positions_m=np.array(gr_pos, float),
        gradients_permil=np.array(gr_val, float),
        curve_positions_m=np.array(cv_pos, float),
        curve_radius_start_m=np.array(r0, float),
        curve_radius_end_m=np.array(r1, float),
        source=source,
    )


# the papers' lines live in train_envs.lines.paper_lines (importable from here as well)
__getattr__, __dir__ = lazy_exports(
    __name__, {name: "train_envs.lines.paper_lines" for name in PAPER_LINES}
)


def section_index(pos: np.ndarray, x: FloatOrArray) -> np.ndarray:
    """The section of each position ``x`` among section starts ``pos`` (the last start
    ``<= x``; the first section before ``pos[0]``): the array look-up of every
    piecewise table of a track."""
    return np.maximum(np.searchsorted(pos, np.asarray(x, float), side="right") - 1, 0)


def curvature_in_section(
    i: np.ndarray, x: np.ndarray, cv_pos: np.ndarray, cv_end: np.ndarray,
    cv_k0: np.ndarray, cv_k1: np.ndarray,
) -> np.ndarray:  # fmt: skip
    """Curvature [1/m] of curve sections ``i`` at ``x`` (clamped to the section): linear
    from ``cv_k0`` at the section start to ``cv_k1`` at its end."""
    p = cv_pos[i]
    frac = np.clip((x - p) / (cv_end[i] - p), 0.0, 1.0)
    k0 = cv_k0[i]
    return k0 + (cv_k1[i] - k0) * frac


def curve_resistance_of(k: np.ndarray) -> np.ndarray:
    """Curve resistance [‰] of curvatures ``k`` (:meth:`Track.curve_resistance_permil_at`)."""
    ak = np.abs(k)
    return np.where(ak * CURVE_RESISTANCE_MAX_RADIUS_M >= 1.0, CURVE_RESISTANCE_COEFF * ak, 0.0)


def equivalent_gradient_arrays(
    x, gr_pos, gr_val, cv_pos, cv_end, cv_k0, cv_k1,
) -> np.ndarray:  # fmt: skip
    """:meth:`Track.equivalent_gradient_permil_at` at the positions ``x`` (1-D) from the
    track's section arrays, numpy form: the reference of :data:`EQUIVALENT_GRADIENT`."""
    k = curvature_in_section(section_index(cv_pos, x), x, cv_pos, cv_end, cv_k0, cv_k1)
    return gr_val[section_index(gr_pos, x)] + curve_resistance_of(k)


def equivalent_gradient_1(s, gr_pos, gr_val, cv_pos, cv_end, cv_k0, cv_k1) -> float:  # fmt: skip
    """:func:`equivalent_gradient_arrays` at one position ``s`` (the same IEEE
    operations; a helper of compiled loops)."""
    ig = bisect_right(gr_pos, s) - 1
    g = gr_val[ig if ig > 0 else 0]
    i = bisect_right(cv_pos, s) - 1
    if i < 0:
        i = 0
    p = cv_pos[i]
    num = s - p
    den = cv_end[i] - p
    if den != 0.0:
        frac = num / den
    elif num != num or num == 0.0:
        frac = np.nan
    else:
        frac = np.inf if num > 0.0 else -np.inf
    if frac < 0.0:  # np.clip (NaN stays NaN)
        frac = 0.0
    elif frac > 1.0:
        frac = 1.0
    k0 = cv_k0[i]
    k = k0 + (cv_k1[i] - k0) * frac
    ak = k if (k >= 0.0 or k != k) else -k
    if ak * CURVE_RESISTANCE_MAX_RADIUS_M >= 1.0:
        return g + CURVE_RESISTANCE_COEFF * ak
    return g + 0.0


def equivalent_gradient_loop(
    x, gr_pos, gr_val, cv_pos, cv_end, cv_k0, cv_k1,
) -> np.ndarray:  # fmt: skip
    """:func:`equivalent_gradient_arrays` position by position (:func:`equivalent_gradient_1`):
    the source of the compiled twin of :data:`EQUIVALENT_GRADIENT`."""
    out = np.empty(x.shape[0])
    for j in range(x.shape[0]):
        out[j] = equivalent_gradient_1(x[j], gr_pos, gr_val, cv_pos, cv_end, cv_k0, cv_k1)
    return out


#: the name of the array form of the equivalent gradient in :data:`train_envs._jit.TWINS`
EQUIVALENT_GRADIENT = "lines.equivalent_gradient"
_jit.register(
    EQUIVALENT_GRADIENT,
    equivalent_gradient_arrays,
    source=equivalent_gradient_loop,
    helpers={"bisect_right": _jit.bisect_right, "equivalent_gradient_1": equivalent_gradient_1},
)


@functools.cache
def _equivalent_gradient_impl() -> Callable[..., np.ndarray]:
    return _jit.implementation(EQUIVALENT_GRADIENT)
