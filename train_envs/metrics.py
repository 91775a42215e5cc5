"""Episode metrics of the five papers, computed from a closed-loop run's DataFrame.

The DataFrame has one row per control step with (at least) ``t_s``, ``s_m``,
``v_mps``, ``a_mps2``, ``v_ref_mps``, ``s_ref_m``, ``v_limit_mps``, ``u_cmd_N``,
``u_N`` (actual total force) and the cumulative mechanical works
``work_traction_J`` / ``work_brake_J``; multi-car runs add ``u{i}_cmd_N`` per car and
``coupler_force_max_N`` / ``coupler_def_max_m``.

Definitions (all integrals by the rectangle rule over the control period ``dt``):

* Paper 000 §IV: ``E_u = Σ_i ∫ u_i² dt`` [N² s], ``E_v = mean |v_r − v_1|``,
  ``E_x = mean |x_r − x_1|``, ``E_p = |x_desired − x_end|``.
* Paper 001 §4: stopping error ``s_end − s_stop`` (signed, + = overshoot) and the
  number of command switches (steps where the command changes by more than
  ``switch_tol`` of its range).
* Paper 002 §5: max |v − v_r| and max |coupler force|.
* Paper 004 §4: ``ITAE = ∫ t |v_r − v| dt``; stopping distance error
  ``|s_end − s_stop|``; time (punctuality) error ``|t_arrival − t_scheduled|``;
  comfort = mean |jerk| (jerk = Δa/Δt of the lead car); traction energy
  ``E = W_traction / η_t − η_r W_brake`` (regeneration credited only where the train
  has it), reported in kWh.
* Constraint violations: max overspeed above the limit and the time spent over it,
  the fraction of steps whose command saturated the force envelope, and the largest
  command rate (per car where commands are per car) beyond the limit.
* Safety (the runner's supervision columns, :mod:`train_envs.simulation.supervision`):
  ``atp_interventions`` (ATP brake applications), ``atp_brake_time_s``, ``overrun_m``
  (largest distance beyond the stopping window), ``max_coupler_excess`` (fraction
  beyond the coupler limits) and ``safety_cost = Σ_k (overspeed_k + atp_k +
  coupler_excess_k) dt + overrun_m`` over the control periods ``k`` (every row but the
  final state): the sum of the env's per-step ``info["cost"]`` over the episode.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping

import numpy as np
import pandas as pd

J_PER_KWH = 3.6e6


def _nanmean(x: np.ndarray) -> float:
    """``pd.Series.mean`` (NaN skipped) of a float array, bit for bit."""
    mask = np.isnan(x)
    if mask.any():
        x = x.copy()
        x[mask] = 0.0
    count = np.float64(mask.size - mask.sum())
    return float(x.sum() / count) if count > 0 else math.nan


def _nanmax_abs(x: np.ndarray) -> float:
    """``pd.Series.abs().max()`` (NaN skipped; NaN if every value is) of a float array."""
    a = np.abs(x)
    mask = np.isnan(a)
    if mask.all():
        return math.nan
    if mask.any():
        a = a[~mask]
    return float(a.max())


def episode_metrics(
    df: pd.DataFrame | Mapping[str, np.ndarray],
    *,
    dt_s: float,
    s_stop_m: float | None = None,
    scheduled_time_s: float | None = None,
    traction_efficiency: float = 1.0,
    regen_efficiency: float = 0.0,
    du_max_Nps: float = math.inf,
    u_range_N: float | None = None,
    switch_tol: float = 1e-3,
) -> dict[str, float]:
    """Compute every metric the papers report for one episode (see module docstring).

    ``df`` is the run's DataFrame or a mapping of its columns (name -> 1-D float
    array, in the DataFrame's column order); both give the same values, bit for bit
    (missing values of the optional columns are skipped as pandas skips them).
    """
    if isinstance(df, pd.DataFrame):
        names = list(df.columns)
        n_rows = len(df)
        values = df.to_numpy()  # one float block: a view (``df[name]`` costs ~30 us each)
        if values.dtype == np.float64 and len(set(names)) == len(names):
            index = {c: j for j, c in enumerate(names)}

            def col(name: str) -> np.ndarray:
                return np.ascontiguousarray(values[:, index[name]])

        else:

            def col(name: str) -> np.ndarray:
                return df[name].to_numpy(dtype=float)

    else:
        names = list(df)

        def col(name: str) -> np.ndarray:
            return np.asarray(df[name], dtype=float)

        n_rows = len(col("t_s")) if "t_s" in names else 0
    if n_rows == 0:
        raise ValueError("cannot compute metrics of an empty run (no control steps)")
    t = col("t_s")
    v = col("v_mps")
    s = col("s_m")
    ev = col("v_ref_mps") - v
    ex = col("s_ref_m") - s
    a = col("a_mps2")
    u = col("u_cmd_N")
    m: dict[str, float] = {}
    abs_ev = np.abs(ev)

    # --- paper 000
    car_cols = [
        c for c in names if c.startswith("u") and c.endswith("_cmd_N") and c[1:-6].isdigit()
    ]
    car_series = [col(c) for c in car_cols]
    if car_cols:
        eu = float(sum(np.nansum(x**2) for x in car_series) * dt_s)
    else:
        eu = float(np.nansum(u**2) * dt_s)
    m["E_u_N2s"] = eu
    m["E_v_mps"] = float(np.mean(abs_ev))
    m["E_x_m"] = float(np.mean(np.abs(ex)))

    # --- stopping (000 E_p, 001, 004)
    s_end = float(s[-1])
    if s_stop_m is not None:
        m["stop_error_m"] = s_end - s_stop_m
        m["E_p_m"] = abs(s_end - s_stop_m)
        m["stopped"] = float(abs(v[-1]) < 1e-6)
    # --- command switches (001)
    rng = u_range_N if u_range_N else max(float(np.ptp(u)), 1.0)
    du = np.abs(np.diff(u))
    m["command_switches"] = float(np.count_nonzero(du > switch_tol * rng))

    # --- paper 002
    m["max_speed_error_mps"] = float(np.max(abs_ev))
    if "coupler_force_max_N" in names:
        m["max_coupler_force_N"] = _nanmax_abs(col("coupler_force_max_N"))
        m["max_coupler_deformation_m"] = _nanmax_abs(col("coupler_def_max_m"))

    # --- paper 004
    m["ITAE_m_s"] = float(np.sum(t * abs_ev) * dt_s)
    t_arr = float(t[-1])
    m["running_time_s"] = t_arr - float(t[0])
    if scheduled_time_s is not None:
        m["time_error_s"] = abs(m["running_time_s"] - scheduled_time_s)
    jerk = np.diff(a) / dt_s if len(a) > 1 else np.zeros(1)
    abs_jerk = np.abs(jerk)
    m["comfort_mean_abs_jerk_mps3"] = float(np.mean(abs_jerk))
    m["max_abs_jerk_mps3"] = float(np.max(abs_jerk))
    w_t = float(col("work_traction_J")[-1])
    w_b = float(col("work_brake_J")[-1])
    m["traction_work_kWh"] = w_t / J_PER_KWH
    m["energy_kWh"] = (w_t / traction_efficiency - regen_efficiency * w_b) / J_PER_KWH

    # --- constraint violations
    over = v - col("v_limit_mps")
    m["max_overspeed_mps"] = float(max(0.0, np.max(over)))
    m["overspeed_time_s"] = float(np.count_nonzero(over > 1e-6) * dt_s)
    if "saturated" in names:
        m["saturated_fraction"] = _nanmean(col("saturated"))
    # command rate per input (per car when the run has per-car commands: the rate
    # limit of paper 000 is per car)
    series = car_series if car_cols else [u]
    rate = max((float(np.nanmax(np.abs(np.diff(x)))) / dt_s if len(x) > 1 else 0.0) for x in series)
    m["max_rate_Nps"] = rate
    if math.isfinite(du_max_Nps):
        m["max_rate_excess_Nps"] = max(0.0, rate - du_max_Nps)
    if "fallback" in names:
        m["fallback_fraction"] = _nanmean(col("fallback"))
    if "atp_brake" in names:
        m.update(_safety(col, "coupler_excess" in names, dt_s))
    return m


def _safety(col: Callable[[str], np.ndarray], coupled: bool, dt_s: float) -> dict[str, float]:
    """The safety metrics of the supervision columns (see the module docstring)."""
    atp = col("atp_brake")
    periods = slice(0, max(len(atp) - 1, 1))  # the last row is the final state
    rises = np.count_nonzero(np.diff(atp, prepend=0.0) > 0.0)
    out = {
        "atp_interventions": float(rises),
        "atp_brake_time_s": float(np.sum(atp[periods]) * dt_s),
        "overrun_m": float(np.max(col("overrun_m"))),
    }
    integral = np.sum(col("overspeed_mps")[periods]) + np.sum(atp[periods])
    if coupled:
        exc = col("coupler_excess")
        out["max_coupler_excess"] = float(np.max(exc))
        integral = integral + np.sum(exc[periods])
    out["safety_cost"] = float(integral * dt_s + out["overrun_m"])
    return out
