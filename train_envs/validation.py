"""Input validation helpers: every error names the offending field and its allowed range."""

from __future__ import annotations

import math
import os
from collections.abc import Sequence

import numpy as np


def check_finite(name: str, value: float) -> float:
    """Return ``value`` as float, or raise ``ValueError`` naming ``name`` if it is NaN/inf."""
    try:
        x = float(value)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a real number, got {value!r}") from exc
    if not math.isfinite(x):
        raise ValueError(f"{name} must be finite, got {x}")
    return x


def check_range(
    name: str,
    value: float,
    low: float = -math.inf,
    high: float = math.inf,
    *,
    low_inclusive: bool = True,
    high_inclusive: bool = True,
    allow_inf: bool = False,
) -> float:
    """Check ``low <= value <= high`` (bounds inclusive unless told otherwise).

    Raises ``ValueError`` whose message names the field and states the allowed range.
    """
    try:
        x = float(value)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a real number, got {value!r}") from exc
    if math.isnan(x) or (math.isinf(x) and not allow_inf):
        raise ValueError(f"{name} must be finite, got {x}")
    lo_ok = x >= low if low_inclusive else x > low
    hi_ok = x <= high if high_inclusive else x < high
    if not (lo_ok and hi_ok):
        lb = "[" if low_inclusive else "("
        hb = "]" if high_inclusive else ")"
        raise ValueError(f"{name} must lie in {lb}{low}, {high}{hb}, got {x}")
    return x


def check_positive(name: str, value: float, *, allow_inf: bool = False) -> float:
    """Check ``value > 0``."""
    return check_range(name, value, 0.0, math.inf, low_inclusive=False, allow_inf=allow_inf)


def check_nonnegative(name: str, value: float, *, allow_inf: bool = False) -> float:
    """Check ``value >= 0``."""
    return check_range(name, value, 0.0, math.inf, allow_inf=allow_inf)


def check_increasing(name: str, values: Sequence[float], *, strict: bool = True) -> np.ndarray:
    """Check that a sequence of positions is (strictly) increasing and finite."""
    arr = np.asarray(values, dtype=float)
    if arr.ndim != 1:
        raise ValueError(f"{name} must be a 1-D sequence, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must contain only finite values")
    d = np.diff(arr)
    bad = np.nonzero(d <= 0 if strict else d < 0)[0]
    if bad.size:
        i = int(bad[0])
        word = "strictly increasing" if strict else "non-decreasing"
        raise ValueError(f"{name} must be {word}: element {i + 1} ({arr[i + 1]}) follows {arr[i]}")
    return arr


def check_choice(name: str, value: str, choices: Sequence[str], *, sort: bool = True) -> str:
    """Check that ``value`` is one of ``choices``: a registry look-up's error names them all
    (sorted, or in the registry's own order with ``sort=False``)."""
    if value not in choices:
        listed = sorted(choices) if sort else choices
        raise ValueError(f"unknown {name} {value!r}; choose one of: {', '.join(listed)}")
    return value


def is_json_path(name: object) -> bool:
    """Whether ``name`` names a JSON file (a path-like, or a string ending in ``.json``
    or holding a directory separator) rather than a catalogue entry."""
    return isinstance(name, os.PathLike) or (
        isinstance(name, str) and (name.endswith(".json") or os.sep in name)
    )
