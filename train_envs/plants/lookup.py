"""Fast piecewise-linear look-up of a track property for the integrator's hot path."""

from __future__ import annotations

from collections.abc import Callable
from functools import partial

import numpy as np

from train_envs.plants.physics import gradient_at


class PiecewiseLinear:
    """``f(s) = y0[i] + slope[i] (s − x[i])`` on ``[x[i], x[i+1])``, right-continuous.

    Built by sampling a function that is constant or linear between ``breakpoints``
    (a track's gradient is piecewise constant, a clothoid's curve resistance 600|κ|
    piecewise linear, cut off above a 10 km radius: see
    :meth:`train_envs.lines.track.Track.resistance_breakpoints_m`), at two points inside
    each segment, so the table reproduces it exactly, also where it jumps, at a fraction
    of the cost.  A plant splits its integration steps at the segment starts ``x``.
    """

    def __init__(self, x: np.ndarray, y0: np.ndarray, slope: np.ndarray) -> None:
        # a sentinel segment before the first breakpoint holds the first value, so the
        # segment index is never negative and needs no clipping on the hot path
        self.x = np.concatenate(([-1e30], np.asarray(x, dtype=float)))
        self.y0 = np.concatenate(([float(y0[0])], np.asarray(y0, dtype=float)))
        self.slope = np.concatenate(([0.0], np.asarray(slope, dtype=float)))
        # Python-list copies for the scalar path (see docs/design/plants.md)
        self._xl, self._y0l, self._sl = self.x.tolist(), self.y0.tolist(), self.slope.tolist()
        #: the table at one float position (``self(s)`` for a float ``s``, bound once)
        self.at: Callable[[float], float] = partial(gradient_at, self._xl, self._y0l, self._sl)

    @classmethod
    def from_function(
        cls, f: Callable[[np.ndarray], np.ndarray], breakpoints: np.ndarray, end: float
    ) -> PiecewiseLinear:
        x = np.unique(np.asarray(breakpoints, dtype=float))
        x = x[x < end]
        width = np.append(x[1:], end) - x
        # two samples inside each segment: the value at a jump (the segment start) is the
        # segment's own, whichever side a function evaluates exactly at the jump
        xa, xb = x + 0.25 * width, x + 0.75 * width
        fa = np.asarray(f(xa), dtype=float)
        slope = (np.asarray(f(xb), dtype=float) - fa) / (xb - xa)
        y0 = fa - slope * (xa - x)
        return cls(x, y0, slope)

    def __call__(self, s):
        if isinstance(s, float):
            return gradient_at(self._xl, self._y0l, self._sl, s)
        s = np.asarray(s, dtype=float)
        i = self.x.searchsorted(s, side="right") - 1
        return self.y0[i] + self.slope[i] * (s - self.x[i])


_TABLES: dict[int, tuple[object, PiecewiseLinear]] = {}


def gradient_table(track) -> PiecewiseLinear:
    """Cached look-up table of a track's equivalent gradient [‰] (gradient + curves)."""
    key = id(track)
    hit = _TABLES.get(key)
    if hit is None or hit[0] is not track:
        table = PiecewiseLinear.from_function(
            track.equivalent_gradient_permil_at,
            track.resistance_breakpoints_m(),
            track.length_m + 1e6,
        )
        _TABLES[key] = hit = (track, table)
    return hit[1]
