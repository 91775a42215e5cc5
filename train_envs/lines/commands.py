"""Reference speed commands of the papers: a braking curve and time-indexed commands.

* :func:`constant_decel_profile`: paper 001's braking curve ``v(s) = min(v0,
  sqrt(2 b (s_stop − s)))``;
* :func:`piecewise_speed_command`: a command linear in time between breakpoints, and
  the commands of paper 002 (Table 2) and paper 003 built with it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from train_envs.lines.speed_profile import SpeedProfile
from train_envs.trains import KMH
from train_envs.validation import check_increasing, check_range


def constant_decel_profile(
    v0: float, s0: float, s_stop: float, decel: float, ds: float | None = None
) -> SpeedProfile:
    """Paper 001's reference braking curve ``v(s) = min(v0, sqrt(2 b (s_stop - s)))``.

    The train cruises at ``v0`` until the braking point ``s_b = s_stop - v0² / (2 b)``
    and then brakes at the constant deceleration ``b = decel`` to ``v = 0`` at ``s_stop``
    (paper 001: ``v0 = 20 m/s``, ``b = 0.5 m/s²``, stop at 400 m, so ``s_b = 0``: it
    brakes over the whole 400 m). If ``s_b < s0`` the curve starts below ``v0``. The
    nodes are ``s0``, ``s_b`` (if inside) and ``s_stop`` (plus every ``ds`` if given);
    the representation is exact because ``v²`` is linear in ``s`` on each piece.
    """
    v0 = check_range("v0", v0, 0.0, math.inf, low_inclusive=False)
    s0 = check_range("s0", s0)
    s_stop = check_range("s_stop", s_stop)
    if s_stop <= s0:
        raise ValueError(f"s_stop ({s_stop}) must be greater than s0 ({s0})")
    decel = check_range("decel", decel, 0.0, 10.0, low_inclusive=False)
    s_brake = s_stop - v0 * v0 / (2.0 * decel)
    nodes = [s0, s_stop] if s_brake <= s0 else [s0, s_brake, s_stop]
    if ds is not None:
        ds = check_range("ds", ds, 0.0, math.inf, low_inclusive=False)
        nodes = np.union1d(nodes, np.arange(s0, s_stop, ds)).tolist()
    s = np.array(nodes, float)
    v = np.minimum(v0, np.sqrt(np.maximum(2.0 * decel * (s_stop - s), 0.0)))
    v[-1] = 0.0
    return SpeedProfile(
        s,
        v,
        label=(
            f"constant deceleration {decel:g} m/s^2 from {v0:g} m/s to a stop at {s_stop:g} m "
            f"(braking point {s_brake:g} m)"
        ),
    )


def piecewise_speed_command(
    breakpoints: Sequence[tuple[float, float]], s0: float = 0.0, label: str = ""
) -> SpeedProfile:
    """Time-indexed speed command, linear in time between ``(t_s, v_mps)`` breakpoints.

    Between breakpoints the acceleration is constant, so positions follow exactly from
    ``s_{i+1} = s_i + (v_i + v_{i+1}) (t_{i+1} - t_i) / 2`` and the returned
    :class:`SpeedProfile` reproduces the command (use ``v_at_t`` / ``s_at_t``). Times
    must be strictly increasing (a step needs a ramp); no segment may be a standstill.
    """
    pts = [tuple(p) for p in breakpoints]
    if len(pts) < 2 or any(len(p) != 2 for p in pts):
        raise ValueError("breakpoints must be a sequence of at least 2 (t_s, v_mps) pairs")
    t = check_increasing("breakpoints times", [p[0] for p in pts])
    v = np.array([check_range(f"breakpoints[{i}] speed", p[1], 0.0) for i, p in enumerate(pts)])
    s = s0 + np.concatenate(([0.0], np.cumsum(0.5 * (v[:-1] + v[1:]) * np.diff(t))))
    if np.any(np.diff(s) <= 0):
        i = int(np.nonzero(np.diff(s) <= 0)[0][0])
        raise ValueError(
            f"breakpoints {i} and {i + 1} are a standstill (v = 0 at both); a distance-"
            "indexed profile cannot represent it"
        )
    return SpeedProfile(s, v, t0_s=float(t[0]), label=label or "piecewise-linear speed command")


def paper002_speed_command(ramp_end_s: float = 450.0) -> SpeedProfile:
    """Paper 002 (Xu et al. 2019) Table 2 speed command, time-indexed.

    0 -> 40 m/s over 0-100 s, cruise 40 m/s to 400 s, 40 -> 70 m/s over 400-450 s,
    cruise 70 m/s to 850 s, 70 -> 50 m/s over 850-900 s, cruise 50 m/s to 1200 s
    (62.75 km in total).

    ``ramp_end_s`` moves the end of the 40 -> 70 m/s ramp. Table 2's 450 s asks for
    0.6 m/s², more than 002's own train can give near 70 m/s (4 × 30 kN over 190 t is
    0.63 m/s² minus ≈ 0.1 m/s² of resistance); 470 s (0.43 m/s², 83 % of what is
    available at 70 m/s) is the traction-feasible variant.
    """
    end = check_range("ramp_end_s", ramp_end_s, 400.0, 850.0, low_inclusive=False)
    label = "paper 002 Table 2 speed command"
    if end != 450.0:
        label += f" (40 -> 70 m/s ramp ending at {end:g} s)"
    return piecewise_speed_command(
        [
            (0.0, 0.0),
            (100.0, 40.0),
            (400.0, 40.0),
            (end, 70.0),
            (850.0, 70.0),
            (900.0, 50.0),
            (1200.0, 50.0),
        ],
        label=label,
    )


def paper003_speed_command(accel_mps2: float = 0.15) -> SpeedProfile:
    """Paper 003's speed command, time-indexed (2000 s, about 101 km).

    From the paper's text: the train cruises, the desired speed rises to 200 km/h at
    ``t = 100 s`` and later drops to 170 km/h. The paper's reference is a step and gives no
    initial cruise speed or drop time; we ASSUME a 150 km/h start, the drop at 1000 s and
    the end at 2000 s, and replace each step by a ramp at ``accel_mps2`` (ours, default
    0.15 m/s²) starting at the step time.
    """
    a = check_range("accel_mps2", accel_mps2, 0.0, 2.0, low_inclusive=False)
    v1, v2, v3 = 150.0 * KMH, 200.0 * KMH, 170.0 * KMH
    return piecewise_speed_command(
        [
            (0.0, v1),
            (100.0, v1),
            (100.0 + (v2 - v1) / a, v2),
            (1000.0, v2),
            (1000.0 + (v2 - v3) / a, v3),
            (2000.0, v3),
        ],
        label=f"paper 003 speed command (150 -> 200 -> 170 km/h, ramps {a:g} m/s^2 assumed)",
    )


__all__ = [
    "constant_decel_profile",
    "paper002_speed_command",
    "paper003_speed_command",
    "piecewise_speed_command",
]
