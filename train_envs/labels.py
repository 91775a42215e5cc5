"""Readable labels with units for metric columns, and numbers for printed tables.

:data:`METRIC_LABELS` is the one table from a metric column of
:func:`train_envs.metrics.episode_metrics` (SI suffixes: ``_m``, ``_mps``, ``_kWh``,
...) to an axis label with its unit (``ITAE_m_s`` → ``ITAE [m·s]``, the integral of
|position error| × time, not milliseconds). :func:`metric_label` falls back to the
suffix for other columns. :func:`format_number` and :func:`format_table` print values
with a fixed number of significant digits and round-off noise (``1.009e-11`` for an
exact 0) as ``0``; constraint columns ``g:<metric>`` print as the metric with its bound.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import pandas as pd

__all__ = ["METRIC_LABELS", "format_number", "format_table", "metric_label"]

#: metric column -> label with unit
METRIC_LABELS: dict[str, str] = {
    "ITAE_m_s": "ITAE [m·s]",
    "E_p_m": "stop error E_p [m]",
    "stop_error_m": "stop error [m]",
    "E_x_m": "position error E_x [m]",
    "E_v_mps": "speed error E_v [m/s]",
    "E_u_N2s": "control effort E_u [N²·s]",
    "time_error_s": "time error [s]",
    "running_time_s": "running time [s]",
    "comfort_mean_abs_jerk_mps3": "mean |jerk| [m/s³]",
    "max_abs_jerk_mps3": "max |jerk| [m/s³]",
    "energy_kWh": "energy [kWh]",
    "traction_work_kWh": "traction work [kWh]",
    "max_speed_error_mps": "max speed error [m/s]",
    "max_overspeed_mps": "max overspeed [m/s]",
    "overspeed_time_s": "time over the limit [s]",
    "command_switches": "command switches [-]",
    "saturated_fraction": "saturated fraction [-]",
    "max_rate_Nps": "max command rate [N/s]",
    "atp_interventions": "ATP interventions [-]",
    "atp_brake_time_s": "time under ATP brake [s]",
    "overrun_m": "overrun [m]",
    "safety_cost": "safety cost",
    "max_coupler_deformation_m": "max coupler deformation [m]",
    "tchebycheff": "Tchebycheff value [-]",
}

#: unit suffix of a column name -> unit (longest suffix first)
_SUFFIX_UNITS: tuple[tuple[str, str], ...] = (
    ("_mps3", "m/s³"),
    ("_mps2", "m/s²"),
    ("_mps", "m/s"),
    ("_kWh", "kWh"),
    ("_N2s", "N²·s"),
    ("_Nps", "N/s"),
    ("_kN", "kN"),
    ("_ms", "m·s"),
    ("_cm", "cm"),
    ("_m", "m"),
    ("_s", "s"),
    ("_N", "N"),
)


def metric_label(column: str) -> str:
    """Axis label with unit of a metric column (``energy_kWh`` → ``energy [kWh]``)."""
    if column in METRIC_LABELS:
        return METRIC_LABELS[column]
    for suffix, unit in _SUFFIX_UNITS:
        if column.endswith(suffix) and len(column) > len(suffix):
            return f"{column[: -len(suffix)].replace('_', ' ')} [{unit}]"
    return column


def format_number(x: object, digits: int = 4, zero: float = 1e-9) -> str:
    """``x`` with ``digits`` significant digits; ``|x| < zero`` prints as ``0``."""
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        return str(x)
    v = float(x)
    if math.isnan(v):
        return "NaN"
    if abs(v) < zero:
        return "0"
    return f"{v:.{digits}g}"


def format_table(
    df: pd.DataFrame,
    digits: int = 4,
    bounds: Mapping[str, float] | None = None,
    index: bool = False,
) -> str:
    """``df.to_string`` with :func:`format_number` for every float. A constraint column
    ``g:<name>`` (g = value − bound, g ≤ 0 feasible) prints as the value itself, headed
    ``<name> (≤ bound)``, when ``bounds`` gives the bound, else as ``<name> margin``."""
    out = df.copy()
    renames = {}
    for col in out.columns:
        if isinstance(col, str) and col.startswith("g:"):
            name = col[2:]
            b = (bounds or {}).get(name)
            if b is None:
                renames[col] = f"{name} margin"
            else:
                out[col] = out[col] + float(b)
                renames[col] = f"{name} (≤ {format_number(b, digits)})"
    out = out.rename(columns=renames)
    formatters = {
        c: (lambda v, d=digits: format_number(v, d))
        for c in out.columns
        if pd.api.types.is_float_dtype(out[c])
    }
    return out.to_string(index=index, formatters=formatters)
