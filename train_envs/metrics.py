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
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

J_PER_KWH = 3.6e6


def episode_metrics(
    df: pd.DataFrame,
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
    """Compute every metric the papers report for one episode (see module docstring)."""
    if len(df) == 0:
        raise ValueError("cannot compute metrics of an empty run (no control steps)")
    t = df["t_s"].to_numpy()
    v = df["v_mps"].to_numpy()
    s = df["s_m"].to_numpy()
    ev = df["v_ref_mps"].to_numpy() - v
    ex = df["s_ref_m"].to_numpy() - s
    a = df["a_mps2"].to_numpy()
    u = df["u_cmd_N"].to_numpy()
    m: dict[str, float] = {}

    # --- paper 000
    car_cols = [
        c for c in df.columns if c.startswith("u") and c.endswith("_cmd_N") and c[1:-6].isdigit()
    ]
    if car_cols:
        eu = float(sum(np.nansum(df[c].to_numpy() ** 2) for c in car_cols) * dt_s)
    else:
        eu = float(np.nansum(u**2) * dt_s)
    m["E_u_N2s"] = eu
    m["E_v_mps"] = float(np.mean(np.abs(ev)))
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
    m["command_switches"] = float(np.sum(du > switch_tol * rng))

    # --- paper 002
    m["max_speed_error_mps"] = float(np.max(np.abs(ev)))
    if "coupler_force_max_N" in df:
        m["max_coupler_force_N"] = float(df["coupler_force_max_N"].abs().max())
        m["max_coupler_deformation_m"] = float(df["coupler_def_max_m"].abs().max())

    # --- paper 004
    m["ITAE_ms"] = float(np.sum(t * np.abs(ev)) * dt_s)
    t_arr = float(t[-1])
    m["running_time_s"] = t_arr - float(t[0])
    if scheduled_time_s is not None:
        m["time_error_s"] = abs(m["running_time_s"] - scheduled_time_s)
    jerk = np.diff(a) / dt_s if len(a) > 1 else np.zeros(1)
    m["comfort_mean_abs_jerk_mps3"] = float(np.mean(np.abs(jerk)))
    m["max_abs_jerk_mps3"] = float(np.max(np.abs(jerk)))
    w_t = float(df["work_traction_J"].iloc[-1])
    w_b = float(df["work_brake_J"].iloc[-1])
    m["traction_work_kWh"] = w_t / J_PER_KWH
    m["energy_kWh"] = (w_t / traction_efficiency - regen_efficiency * w_b) / J_PER_KWH

    # --- constraint violations
    over = v - df["v_limit_mps"].to_numpy()
    m["max_overspeed_mps"] = float(max(0.0, np.max(over)))
    m["overspeed_time_s"] = float(np.sum(over > 1e-6) * dt_s)
    if "saturated" in df:
        m["saturated_fraction"] = float(df["saturated"].mean())
    # command rate per input (per car when the run has per-car commands: the rate
    # limit of paper 000 is per car)
    series = [df[c].to_numpy() for c in car_cols] if car_cols else [u]
    rate = max((float(np.nanmax(np.abs(np.diff(x)))) / dt_s if len(x) > 1 else 0.0) for x in series)
    m["max_rate_Nps"] = rate
    if math.isfinite(du_max_Nps):
        m["max_rate_excess_Nps"] = max(0.0, rate - du_max_Nps)
    if "fallback" in df:
        m["fallback_fraction"] = float(df["fallback"].mean())
    return m
