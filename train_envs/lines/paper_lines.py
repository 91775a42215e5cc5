"""The papers' test lines as :class:`~train_envs.lines.track.Track` objects.

Each constructor states its source and what is assumed where the paper is silent.
"""

from __future__ import annotations

import math

import numpy as np

from train_envs.lines.track import PAPER_LINES, Track
from train_envs.trains import KMH

__all__ = list(PAPER_LINES)


def paper001_track() -> Track:
    """Paper 001's test line: 400 m, stops at 0 and 400 m, limit 20 m/s.

    Source: paper 001 (Liu, Xun, Gao, Yin, Acta Automatica Sinica 2022) simulation set-up:
    gradient 12 permil on [0, 150] m, 28 permil on (150, 300) m and -6 permil on
    [300, 400] m; the train cruises at 20 m/s and brakes to the stop at 400 m. Nothing is
    assumed except that the 20 m/s cruise speed is also the line's speed limit and that
    the line is straight.
    """
    return Track(
        name="paper001",
        stops_m=np.array([0.0, 400.0]),
        speed_limit_positions_m=np.array([0.0]),
        speed_limits_mps=np.array([20.0]),
        gradient_positions_m=np.array([0.0, 150.0, 300.0]),
        gradients_permil=np.array([12.0, 28.0, -6.0]),
        source=(
            "Paper 001 (Liu et al. 2022): 400 m, gradients 12 / 28 / -6 permil on "
            "[0,150] / (150,300) / [300,400] m; limit = the 20 m/s cruise speed (assumed); "
            "straight (assumed)."
        ),
    )


def paper000_section_track() -> Track:
    """ASSUMED urban section for paper 000's single-section experiments (3000 m).

    Source: paper 000 (Wang, Xing, Wang, IEEE Access 2024) publishes its 6-car metro train
    but not the single section's infrastructure; 45.8 m/s in the paper is the over-speed
    protection speed, not a line limit. We assume a 3 km metro interstation: limit
    100 km/h (27.8 m/s) with an 80 km/h (22.2 m/s) curve on [1200, 1800] m (R = 800 m with
    50 m clothoids), and a varying slope profile within ±20 permil (3, 15, -2, -20, 5, -3
    permil). The paper's 6-car train (about 1.08 m/s² at low speed) reaches a 100 km/h
    cruise in about 30 s / 450 m, so the run has accelerate-cruise-brake phases.
    """
    kmh = KMH
    return Track(
        name="paper000_section",
        stops_m=np.array([0.0, 3000.0]),
        speed_limit_positions_m=np.array([0.0, 1200.0, 1800.0]),
        speed_limits_mps=np.array([100.0, 80.0, 100.0]) * kmh,
        gradient_positions_m=np.array([0.0, 400.0, 900.0, 1500.0, 2100.0, 2700.0]),
        gradients_permil=np.array([3.0, 15.0, -2.0, -20.0, 5.0, -3.0]),
        curve_positions_m=np.array([0.0, 1250.0, 1300.0, 1700.0, 1750.0]),
        curve_radius_start_m=np.array([math.inf, math.inf, 800.0, 800.0, math.inf]),
        curve_radius_end_m=np.array([math.inf, 800.0, 800.0, math.inf, math.inf]),
        source=(
            "ASSUMED urban section for paper 000 (Wang et al., IEEE Access 2024), which does "
            "not publish one: 3000 m, 100 km/h with 80 km/h on [1200,1800] m around an "
            "R = 800 m curve, gradients 3/15/-2/-20/5/-3 permil."
        ),
    )


def paper000_multi_section_track() -> Track:
    """Paper 000's multi-section line: stops at 0, 14687, 25279 and 33086 m.

    Source: paper 000 (Wang, Xing, Wang, IEEE Access 2024) gives the station positions.
    ASSUMED (not published): speed limits 140 km/h between stations, 120 km/h on the last
    interstation, 80 km/h over the 600 m leaving the first station and approaching the last,
    100 km/h through the intermediate station areas (±500 m); gradients within ±15 permil.
    All limits stay below the paper's 45.8 m/s (165 km/h) over-speed protection.
    """
    kmh = KMH
    sl = [
        (0.0, 80.0),
        (600.0, 140.0),
        (14187.0, 100.0),
        (15187.0, 140.0),
        (24779.0, 100.0),
        (25779.0, 120.0),
        (32486.0, 80.0),
    ]
    gr = [
        (0.0, 2.0),
        (800.0, 8.0),
        (3000.0, -4.0),
        (5200.0, 12.0),
        (6800.0, 0.0),
        (9000.0, -10.0),
        (11000.0, -3.0),
        (13900.0, 1.5),
        (15500.0, -6.0),
        (18000.0, 6.0),
        (21000.0, -15.0),
        (22500.0, 4.0),
        (24900.0, -1.5),
        (25700.0, 10.0),
        (28000.0, -8.0),
        (30500.0, 3.0),
        (32600.0, 0.0),
    ]
    return Track(
        name="paper000_multi_section",
        stops_m=np.array([0.0, 14687.0, 25279.0, 33086.0]),
        speed_limit_positions_m=np.array([p for p, _ in sl]),
        speed_limits_mps=np.array([v for _, v in sl]) * kmh,
        gradient_positions_m=np.array([p for p, _ in gr]),
        gradients_permil=np.array([g for _, g in gr]),
        source=(
            "Paper 000 (Wang et al., IEEE Access 2024): stops 0/14687/25279/33086 m. Speed "
            "limits (80-140 km/h) and gradients (within ±15 permil) ASSUMED; straight."
        ),
    )


def paper002_track() -> Track:
    """Long level high-speed line for paper 002's speed-command tracking (70 km).

    Source: paper 002 (Xu et al. 2019) tracks a time-indexed speed command (Table 2,
    up to 70 m/s for 1200 s, about 62.75 km) and publishes no line. ASSUMED: 70 km,
    level, straight, limit 80 m/s, stops only at both ends.
    """
    return Track(
        name="paper002",
        stops_m=np.array([0.0, 70_000.0]),
        speed_limit_positions_m=np.array([0.0]),
        speed_limits_mps=np.array([80.0]),
        source=(
            "ASSUMED line for paper 002 (Xu et al. 2019): 70 km level straight, limit 80 m/s "
            "(the Table 2 command covers about 62.75 km in 1200 s)."
        ),
    )


def paper003_track() -> Track:
    """Long level high-speed line for paper 003's speed-command tracking (110 km).

    Source: paper 003 (fuzzy constrained predictive control, Shinkansen data) tracks a
    time-indexed command of 150-200 km/h for 2000 s (about 101 km, see
    ``paper003_speed_command``) and publishes no line. ASSUMED: 110 km, level, straight,
    limit 250 km/h (69.4 m/s), stops only at both ends.
    """
    return Track(
        name="paper003",
        stops_m=np.array([0.0, 110_000.0]),
        speed_limit_positions_m=np.array([0.0]),
        speed_limits_mps=np.array([250.0 * KMH]),
        source=(
            "ASSUMED line for paper 003: 110 km level straight, limit 250 km/h (the command, "
            "150 -> 200 -> 170 km/h over 2000 s, covers about 101 km)."
        ),
    )


def paper004_track() -> Track:
    """Dalian Metro Line 12, Lüshun New Port -> Tieshan Town (2940 m), ASSUMED profile.

    Source: paper 004 names the interstation and its length (2940 m) but publishes no
    speed limits or gradients. ASSUMED: an 80 km/h line section with 60 km/h over the
    first 250 m (turnouts at the terminus), 65 km/h through an R = 600 m curve on
    [1350, 1850] m (50 m clothoids at both ends), 70 km/h over the last 300 m; gradients
    2 / -12 / 8 / 24 / -6 / 2 permil (station platforms at 2 permil, all within ±30).
    """
    kmh = KMH
    return Track(
        name="paper004",
        stops_m=np.array([0.0, 2940.0]),
        speed_limit_positions_m=np.array([0.0, 250.0, 1350.0, 1850.0, 2640.0]),
        speed_limits_mps=np.array([60.0, 80.0, 65.0, 80.0, 70.0]) * kmh,
        gradient_positions_m=np.array([0.0, 300.0, 900.0, 1500.0, 2100.0, 2600.0]),
        gradients_permil=np.array([2.0, -12.0, 8.0, 24.0, -6.0, 2.0]),
        curve_positions_m=np.array([0.0, 1350.0, 1400.0, 1800.0, 1850.0]),
        curve_radius_start_m=np.array([math.inf, math.inf, 600.0, 600.0, math.inf]),
        curve_radius_end_m=np.array([math.inf, 600.0, 600.0, math.inf, math.inf]),
        source=(
            "Paper 004: Dalian Metro Line 12, Lushun New Port -> Tieshan Town, 2940 m. "
            "Speed limits (60-80 km/h), gradients (within ±30 permil) and the R = 600 m "
            "curve are ASSUMED (not published)."
        ),
    )
