"""The speed limit that governs a train of length L: the rear-clearance rule.

A train whose head is at ``s`` occupies ``[s − L, s]``; every part of it must respect
the limit of the section it is in, so the governing limit is

    ``V_L(s) = min { V(x) : s − L ≤ x ≤ s }``

with ``V`` the track's piecewise-constant limit (a section starts at its position).
A lower limit therefore applies as soon as the head enters it, a higher one only once
the rear has cleared the lower one (railway practice and every running-time
calculator; e.g. Brünger & Dahlhaus, "Running time estimation", ch. 4 of Hansen &
Pachl (eds.), *Railway Timetable & Traffic*, Eurailpress 2008).  ``V_L`` is again
piecewise constant, right-continuous, with steps at the section starts ``p_i`` and at
``p_i + L``; before the start of the line the first section's limit is assumed.  ``L = 0`` gives the
track's own table.

:func:`effective_limit_table` builds that table once per (track, length); reference
profiles (:mod:`train_envs.lines.profiles`), the env's limit preview and speed
supervision read the limit through it (:func:`effective_limit_fn`).
"""

from __future__ import annotations

from bisect import bisect_right
from collections.abc import Callable
from typing import Protocol

import numpy as np

from train_envs.lines.track import section_index
from train_envs.validation import check_nonnegative


class _HasLimits(Protocol):
    speed_limit_positions_m: np.ndarray
    speed_limits_mps: np.ndarray

    def speed_limit_at(self, s): ...


def effective_limit_sections(
    positions_m: np.ndarray, limits_mps: np.ndarray, length_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """``(section starts, limits)`` of ``V_L`` for the limit table ``(positions_m,
    limits_mps)`` (first position 0) and a train of ``length_m`` (module docstring)."""
    length_m = check_nonnegative("length_m", length_m)
    p = np.asarray(positions_m, dtype=float)
    lim = np.asarray(limits_mps, dtype=float)
    if length_m == 0.0:
        return p.copy(), lim.copy()
    cand = np.union1d(p, p + length_m)
    head = np.searchsorted(p, cand, side="right") - 1
    rear = np.maximum(np.searchsorted(p, cand - length_m, side="right") - 1, 0)
    vals = np.array(
        [lim[r : h + 1].min() for r, h in zip(rear.tolist(), head.tolist(), strict=True)]
    )
    keep = np.ones(cand.size, dtype=bool)
    keep[1:] = vals[1:] != vals[:-1]
    return cand[keep], vals[keep]


_TABLES: dict[tuple[int, float], tuple[object, tuple[np.ndarray, np.ndarray], Callable]] = {}


def _entry(track: _HasLimits, length_m: float):
    key = (id(track), float(length_m))
    hit = _TABLES.get(key)
    if hit is None or hit[0] is not track:
        if len(_TABLES) > 256:
            _TABLES.clear()
        pos, val = effective_limit_sections(
            track.speed_limit_positions_m, track.speed_limits_mps, length_m
        )
        pos.setflags(write=False)
        val.setflags(write=False)
        _TABLES[key] = hit = (track, (pos, val), _step_function(pos, val))
    return hit


def _step_function(pos: np.ndarray, val: np.ndarray) -> Callable:
    """``s ↦ val[i]`` on ``[pos[i], pos[i+1])`` (the first value before ``pos[0]``)."""
    pl, vl = pos.tolist(), val.tolist()

    def limit_at(s):
        if isinstance(s, (float, int)):
            i = bisect_right(pl, s) - 1
            return vl[i if i > 0 else 0]
        return val[section_index(pos, s)]

    return limit_at


def effective_limit_table(track: _HasLimits, length_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Cached :func:`effective_limit_sections` of a track's limits (read-only arrays)."""
    return _entry(track, length_m)[1]


def effective_limit_at(track: _HasLimits, length_m: float, s):
    """``V_L(s)`` [m/s] for a head position ``s`` [m] (float or array)."""
    return effective_limit_fn(track, length_m)(s)


def effective_limit_fn(track: _HasLimits, length_m: float) -> Callable:
    """The function ``s ↦ V_L(s)`` (floats and arrays; cached per track and length);
    for a point train the same values as the track's own ``speed_limit_at``."""
    return _entry(track, length_m)[2]


__all__ = [
    "effective_limit_at",
    "effective_limit_fn",
    "effective_limit_sections",
    "effective_limit_table",
]
