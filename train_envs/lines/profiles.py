"""Reference speed profiles: minimum-time and time-supplemented runs.

The profiles are :class:`~train_envs.lines.speed_profile.SpeedProfile` objects; the
papers' own commands are in :mod:`train_envs.lines.commands` (both re-exported here).

Minimum-time profile (the classic forward/backward speed-profile construction):

* forward pass at full traction, per segment of length ``Δs``
  ``a_i = min((F_max(v_i) - R(v_i) - F_track(s)) / (M (1 + ρ)), a_max)`` and
  ``v_{i+1}² = v_i² + 2 a_i Δs``, capped by ``min(limit - margin, v_max train)``;
  ``F_track`` is gravity plus curve resistance (:meth:`Track.gradient_force_N`) on the
  static mass, taken at the segment midpoint (the segment's own gradient, since every
  section start is a grid node); the train forces are taken at the segment-start speed;
* backward pass braking at the constant service deceleration ``b = train.service_decel_mps2``
  (the usual ATO reference choice: a constant comfort deceleration, assumed achievable by
  the brakes on any gradient) from the stop (``v = 0`` exactly at ``s_stop``) and from
  every lower limit downstream: ``v_b(s)² = min_{s_j ≥ s} (cap_j² + 2 b (s_j - s))``;
* the profile is the pointwise minimum of both.

Every section start of the track is a grid node and the cap of a node is the lower of the
limits of its two adjacent segments, so a limit drop is reached by braking *before* the
section start and, since ``v`` is monotone within a segment, the profile never exceeds the
limit anywhere.

The limit is the one governing the whole train (:mod:`train_envs.lines.limits`): for a
train of ``length_m = L > 0`` a higher limit applies only once the rear has cleared the
lower one, ``V_L(s) = min V`` over ``[s − L, s]``, whose steps ``p_i + L`` are grid nodes
too; the stored ``v_limit_mps`` is that governing limit.  Forces act on a point mass.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from train_envs.lines.commands import (
    constant_decel_profile,
    paper002_speed_command,
    paper003_speed_command,
    piecewise_speed_command,
)
from train_envs.lines.limits import effective_limit_fn, effective_limit_table
from train_envs.lines.speed_profile import SpeedProfile
from train_envs.lines.track import Track
from train_envs.trains import TrainParams, get_train
from train_envs.validation import check_choice, check_range

#: Minimum node spacing [m] when merging the regular grid with section starts.
_MERGE_TOL_M = 1e-6


# ====================================================================== run set-up
class _StallError(Exception):
    """Raised by the forward integration when the speed reaches 0 before the stop."""

    def __init__(self, node: int) -> None:
        super().__init__(node)
        self.node = node


@dataclass(frozen=True)
class _Run:
    """Grid and per-node/per-segment data of one station-to-station run."""

    track: Track
    train: TrainParams
    s: np.ndarray  # nodes [m], s[0] = s_start, s[-1] = s_stop
    ds: np.ndarray  # segment lengths [m]
    seg_cap: np.ndarray  # per segment: min(limit - margin, train v_max) [m/s]
    cap: np.ndarray  # per node: min of adjacent segment caps; 0 at the stop
    limit: np.ndarray  # per node: min of adjacent segment track limits
    grade_N: np.ndarray  # per segment: track force (gravity + curves) [N]
    v0: float


def _resolve(track: Track | str, train: TrainParams | str) -> tuple[Track, TrainParams]:
    if isinstance(track, str):
        from train_envs.lines.catalog import get_track

        track = get_track(track)
    if isinstance(train, str):
        train = get_train(train)
    return track, train


def _prepare(
    track: Track,
    train: TrainParams,
    s_start: float,
    s_stop: float | None,
    ds: float,
    v0: float,
    margin_mps: float,
) -> _Run:
    s_start = check_range("s_start", s_start, 0.0, track.length_m, high_inclusive=False)
    if s_stop is None:
        nxt = track.next_stop_after(s_start)
        if nxt is None:  # pragma: no cover - s_start < length guarantees a next stop
            raise ValueError(f"s_start={s_start} has no stop after it on {track.name!r}")
        s_stop = nxt
    s_stop = check_range("s_stop", s_stop, 0.0, track.length_m)
    if s_stop <= s_start:
        raise ValueError(f"s_stop ({s_stop}) must be greater than s_start ({s_start})")
    ds = check_range("ds", ds, 0.0, 1000.0, low_inclusive=False)
    margin_mps = check_range("margin_mps", margin_mps, 0.0)

    length = s_stop - s_start
    n = max(math.ceil(length / ds - 1e-9), 4)
    grid = s_start + length * (np.arange(n + 1) / n)
    bp = track.breakpoints_m()
    limit_at = track.speed_limit_at
    if train.length_m > 0.0:  # the rear-clearance rule: steps also at p_i + L
        bp = np.union1d(bp, effective_limit_table(track, train.length_m)[0])
        limit_at = effective_limit_fn(track, train.length_m)
    grid = np.union1d(grid, bp[(bp > s_start) & (bp < s_stop)])
    keep = np.ones(grid.size, dtype=bool)
    keep[1:] = np.diff(grid) > _MERGE_TOL_M
    grid = grid[keep]
    grid[0], grid[-1] = s_start, s_stop

    mid = 0.5 * (grid[:-1] + grid[1:])
    seg_limit = np.asarray(limit_at(mid), float)
    if margin_mps >= seg_limit.min():
        raise ValueError(
            f"margin_mps must be below the lowest speed limit on the run "
            f"({seg_limit.min():.3f} m/s), got {margin_mps}"
        )
    seg_cap = np.minimum(seg_limit - margin_mps, train.max_speed_mps)
    cap = np.empty(grid.size)
    cap[0] = seg_cap[0]
    cap[1:-1] = np.minimum(seg_cap[:-1], seg_cap[1:])
    cap[-1] = 0.0
    limit = np.empty(grid.size)
    limit[0], limit[-1] = seg_limit[0], seg_limit[-1]
    limit[1:-1] = np.minimum(seg_limit[:-1], seg_limit[1:])
    v0 = check_range("v0", v0, 0.0, float(cap[0]))
    grade = np.asarray(track.gradient_force_N(mid, train.mass_kg), float)
    return _Run(track, train, grid, np.diff(grid), seg_cap, cap, limit, grade, v0)


def _forward(
    train: TrainParams,
    ds: np.ndarray,
    grade_N: np.ndarray,
    cap: np.ndarray,
    v_start: float,
    *,
    coast: bool = False,
) -> np.ndarray:
    """Integrate ``v_{i+1}² = v_i² + 2 a_i Δs_i`` at full traction (or coasting).

    ``cap`` has one entry per node (``len(ds) + 1``); ``cap[0]`` is ignored. Raises
    :class:`_StallError` if the speed reaches 0 at a node before the last one.
    """
    n = len(ds)
    out = np.empty(n + 1)
    out[0] = v = v_start
    m = train.inertial_mass_kg
    amax = train.max_accel_mps2
    trac = train.max_traction_N
    res = train.resistance_N
    ds_l, gr_l, cap_l = ds.tolist(), grade_N.tolist(), cap.tolist()
    for i in range(n):
        if coast:
            a = (-res(v) - gr_l[i]) / m
        else:
            a = (trac(v) - res(v) - gr_l[i]) / m
            if a > amax:
                a = amax
        v2 = v * v + 2.0 * a * ds_l[i]
        c = cap_l[i + 1]
        if v2 > 0.0:
            v = math.sqrt(v2)
            if v > c:
                v = c
        elif i == n - 1:
            v = 0.0
        else:
            raise _StallError(i + 1)
        out[i + 1] = v
    return out


def _backward(s: np.ndarray, cap: np.ndarray, decel: float) -> np.ndarray:
    """Service-braking envelope ``v_b(s_i)² = min_{j >= i} (cap_j² + 2 b (s_j - s_i))``."""
    key = cap * cap + 2.0 * decel * s
    env = np.minimum.accumulate(key[::-1])[::-1] - 2.0 * decel * s
    env[-1] = cap[-1] ** 2
    return np.sqrt(np.maximum(env, 0.0))


def _running_time(s: np.ndarray, v: np.ndarray) -> float:
    vs = v[:-1] + v[1:]
    if np.any(vs <= 0.0):
        return math.inf
    return float(np.sum(2.0 * np.diff(s) / vs))


def _min_time_speeds(run: _Run) -> np.ndarray:
    try:
        fwd = _forward(run.train, run.ds, run.grade_N, run.cap, run.v0)
    except _StallError as exc:
        s = run.s[exc.node]
        raise ValueError(
            f"train {run.train.name!r} cannot climb track {run.track.name!r} at full traction: "
            f"speed reaches 0 at s = {s:.1f} m (gradient "
            f"{run.track.gradient_permil_at(float(s)):.1f} permil)"
        ) from None
    return np.minimum(fwd, _backward(run.s, run.cap, run.train.service_decel_mps2))


# ====================================================================== public API
def minimum_time_profile(
    track: Track | str,
    train: TrainParams | str,
    s_start: float = 0.0,
    s_stop: float | None = None,
    ds: float = 1.0,
    v0: float = 0.0,
    margin_mps: float = 0.0,
) -> SpeedProfile:
    """Fastest run from ``s_start`` (speed ``v0``) to a stop at ``s_stop`` [m].

    Forward pass at full traction, backward pass at the constant service deceleration,
    pointwise minimum (see the module docstring for the equations). The speed is capped by
    ``speed limit - margin_mps`` and ``train.max_speed_mps``; the profile ends with
    ``v = 0`` exactly at ``s_stop`` and never exceeds the limit between nodes.

    Args:
        track, train: objects or catalogue names.
        s_start: start position [m]. ``s_stop``: stop position [m]; default the next stop
            after ``s_start``.
        ds: nominal grid step [m] (the grid is uniform with step ``<= ds`` plus every
            section start of the track).
        v0: initial speed [m/s] (must not exceed the cap at ``s_start``).
        margin_mps: speed margin kept below the limits [m/s].

    Raises:
        ValueError: bad arguments, or a gradient the train cannot climb.
    """
    track, train = _resolve(track, train)
    run = _prepare(track, train, s_start, s_stop, ds, v0, margin_mps)
    v = _min_time_speeds(run)
    return SpeedProfile(
        run.s,
        v,
        v_limit_mps=run.limit,
        label=(
            f"minimum time, {train.name} on {track.name} "
            f"[{run.s[0]:g}, {run.s[-1]:g}] m, margin {margin_mps:g} m/s"
        ),
    )


def time_supplemented_profile(
    track: Track | str,
    train: TrainParams | str,
    scheduled_time_s: float,
    s_start: float = 0.0,
    s_stop: float | None = None,
    ds: float = 1.0,
    method: str = "cruise_cap",
    *,
    margin_mps: float = 0.0,
    tol_s: float = 0.05,
    min_coast_speed_mps: float = 1.0,
) -> SpeedProfile:
    """Run from ``s_start`` to a stop at ``s_stop`` taking ``scheduled_time_s`` seconds.

    The running time supplement (schedule minus minimum time) is absorbed by one of:

    * ``"cruise_cap"``: a global cruise-speed cap ``v_c`` is added to the caps of the
      minimum-time construction (forward at full traction up to ``min(limit, v_c)``,
      service braking); the running time falls monotonically with ``v_c``, which is found
      by a bracketing search (bisection accelerated by Illinois false-position steps).
    * ``"coast"``: the minimum-time profile is followed up to a coasting point ``s_c``;
      from there the train coasts (traction off: ``a = -(R(v) + F_track(s)) / M(1+ρ)``,
      still held below the caps, i.e. braking to hold a limit downhill) until the service
      braking curve to the stop; ``s_c`` is found by the same bracketing search (earlier
      coasting = slower).
      A coasting run that stalls, or whose falling speed drops below
      ``min_coast_speed_mps`` (default 1 m/s, the point where an ATO would re-apply
      traction) before the braking curve takes over, is infeasible; the method fails if the
      schedule needs such a run.

    The result is never faster than the minimum-time profile and its running time is
    within ``tol_s`` (default 0.05 s) of the schedule.

    Raises:
        ValueError: ``scheduled_time_s`` below the minimum achievable time (the message
            gives it), an unknown ``method``, or a supplement that coasting cannot absorb.
    """
    track, train = _resolve(track, train)
    check_choice("method", method, ["cruise_cap", "coast"])
    tol_s = check_range("tol_s", tol_s, 0.0, 0.5, low_inclusive=False)
    min_coast = check_range("min_coast_speed_mps", min_coast_speed_mps, 0.0)
    run = _prepare(track, train, s_start, s_stop, ds, 0.0, margin_mps)
    v_min = _min_time_speeds(run)
    t_min = _running_time(run.s, v_min)
    check_range("scheduled_time_s", scheduled_time_s, 0.0, low_inclusive=False)
    if scheduled_time_s < t_min - 1e-9:
        raise ValueError(
            f"scheduled_time_s ({scheduled_time_s:.2f} s) is below the minimum achievable "
            f"running time {t_min:.2f} s of {train.name!r} on {track.name!r} "
            f"[{run.s[0]:g}, {run.s[-1]:g}] m"
        )
    where = f"{train.name} on {track.name} [{run.s[0]:g}, {run.s[-1]:g}] m"
    if scheduled_time_s - t_min <= tol_s:
        s, v, lim, label = run.s, v_min, run.limit, f"minimum time (schedule met), {where}"
    elif method == "cruise_cap":
        s, v, lim, label = _cruise_cap(run, v_min, scheduled_time_s, tol_s, where)
    else:
        s, v, lim, label = _coast(run, v_min, scheduled_time_s, tol_s, where, min_coast)
    return SpeedProfile(s, v, v_limit_mps=lim, label=label)


_Payload = tuple[np.ndarray, np.ndarray, np.ndarray]  # (s, v, v_limit) of a candidate


def _solve_decreasing(
    evaluate: Callable[[float], tuple[float, _Payload | None]],
    lo: float,
    hi: float,
    t_lo: float,
    t_hi: float,
    hi_payload: _Payload | None,
    target: float,
    tol: float,
    xtol: float,
) -> tuple[float, float, _Payload | None]:
    """Find ``x`` in ``[lo, hi]`` with ``|T(x) - target| <= tol`` for a decreasing ``T``.

    Requires ``T(lo) > target >= T(hi)``; ``T(lo)`` may be ``inf`` (infeasible). Bisection
    on the bracket, accelerated by Illinois false-position steps while both ends are
    finite. Returns the best point found on the fast side (``T <= target``), or the first
    point within ``tol``.
    """
    g_lo, g_hi = t_lo - target, t_hi - target
    best = (hi, t_hi, hi_payload)
    side = 0
    for _ in range(200):
        x = 0.5 * (lo + hi)
        if math.isfinite(g_lo) and g_lo != g_hi:
            xf = (lo * g_hi - hi * g_lo) / (g_hi - g_lo)
            if lo < xf < hi:
                x = xf
        t, payload = evaluate(x)
        g = t - target
        if abs(g) <= tol and payload is not None:
            return x, t, payload
        if g > 0.0:
            lo, g_lo = x, g
            if side == 1:
                g_hi *= 0.5
            side = 1
        else:
            hi, g_hi = x, g
            best = (x, t, payload)
            if side == -1 and math.isfinite(g_lo):
                g_lo *= 0.5
            side = -1
        if hi - lo <= xtol:
            break
    return best


def _cruise_cap(
    run: _Run, v_min: np.ndarray, target: float, tol: float, where: str
) -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
    decel = run.train.service_decel_mps2

    def evaluate(vc: float) -> tuple[float, _Payload | None]:
        cap = np.minimum(run.cap, vc)
        try:
            fwd = _forward(run.train, run.ds, run.grade_N, cap, run.v0)
        except _StallError:
            return math.inf, None
        v = np.minimum(fwd, _backward(run.s, cap, decel))
        return _running_time(run.s, v), (run.s, v, run.limit)

    hi = float(v_min.max())
    t_hi = _running_time(run.s, v_min)
    hi_payload: _Payload | None = (run.s, v_min, run.limit)
    lo = 0.5 * hi * t_hi / target  # T roughly scales as 1 / v_c
    t_lo, lo_payload = evaluate(lo)
    while t_lo <= target:
        hi, t_hi, hi_payload = lo, t_lo, lo_payload
        if abs(t_hi - target) <= tol:
            break
        if lo < 1e-3:
            raise ValueError(
                f"scheduled_time_s ({target:.2f} s) cannot be reached with a cruise cap "
                f">= {lo:.4f} m/s on {where}"
            )
        lo *= 0.25
        t_lo, lo_payload = evaluate(lo)
    if abs(t_hi - target) <= tol:
        vc, t, payload = hi, t_hi, hi_payload
    else:
        vc, t, payload = _solve_decreasing(
            evaluate, lo, hi, t_lo, t_hi, hi_payload, target, tol, xtol=1e-12
        )
    if payload is None or abs(t - target) > tol:  # pragma: no cover - T(v_c) is continuous
        raise RuntimeError(f"cruise-cap search did not converge ({t - target:.3f} s off)")
    s, v, lim = payload
    return s, v, lim, f"time-supplemented (cruise cap {vc:.3f} m/s), {where}"


def _coast(
    run: _Run,
    v_min: np.ndarray,
    target: float,
    tol: float,
    where: str,
    min_coast_speed_mps: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
    decel = run.train.service_decel_mps2
    s_nodes = run.s

    def evaluate(sc: float) -> tuple[float, _Payload | None]:
        """Running time and profile when coasting from ``sc`` (inf if coasting stalls)."""
        k = min(int(np.searchsorted(s_nodes, sc, side="right")) - 1, len(s_nodes) - 2)
        frac = (sc - s_nodes[k]) / (s_nodes[k + 1] - s_nodes[k])
        v_sc = math.sqrt(max(v_min[k] ** 2 + frac * (v_min[k + 1] ** 2 - v_min[k] ** 2), 0.0))
        if sc - s_nodes[k] > _MERGE_TOL_M and s_nodes[k + 1] - sc > _MERGE_TOL_M:
            s = np.concatenate((s_nodes[: k + 1], [sc], s_nodes[k + 1 :]))
            v_head = np.append(v_min[: k + 1], v_sc)
            cap = np.concatenate((run.cap[: k + 1], [run.seg_cap[k]], run.cap[k + 1 :]))
            lim = np.concatenate((run.limit[: k + 1], [run.limit[k]], run.limit[k + 1 :]))
            grade = np.concatenate((run.grade_N[: k + 1], run.grade_N[k:]))
            j = k + 1  # index of the coasting point in the new grid
        else:
            s, cap, lim, grade = s_nodes, run.cap, run.limit, run.grade_N
            j = k if sc - s_nodes[k] <= _MERGE_TOL_M else k + 1
            if j >= len(s_nodes) - 1:  # coasting from the stop itself: minimum-time run
                return _running_time(s_nodes, v_min), (s_nodes, v_min, run.limit)
            v_head = v_min[: j + 1]
        try:
            tail = _forward(run.train, np.diff(s[j:]), grade[j:], cap[j:], v_head[-1], coast=True)
        except _StallError:
            return math.inf, None
        bwd = _backward(s, cap, decel)
        if min_coast_speed_mps > 0.0:
            # interior nodes where the coasting curve governs, falls and is below the floor
            inner, bwd_inner = tail[1:-1], bwd[j + 1 : -1]
            falling = np.diff(tail)[:-1] < 0.0
            if np.any((inner < min_coast_speed_mps) & falling & (inner < bwd_inner)):
                return math.inf, None
        v = np.minimum(np.concatenate((v_head[:-1], tail)), bwd)
        return _running_time(s, v), (s, v, lim)

    lo, hi = float(s_nodes[0]), float(s_nodes[-1])
    t_lo, _ = evaluate(lo)
    if t_lo < target:
        raise ValueError(
            f"scheduled_time_s ({target:.2f} s) cannot be reached by coasting: coasting from "
            f"the start takes only {t_lo:.2f} s on {where}; use method='cruise_cap'"
        )
    t_hi = _running_time(s_nodes, v_min)
    sc, t, payload = _solve_decreasing(
        evaluate, lo, hi, t_lo, t_hi, (s_nodes, v_min, run.limit), target, tol, xtol=1e-9
    )
    if payload is None or abs(t - target) > tol:
        raise ValueError(
            f"scheduled_time_s ({target:.2f} s) cannot be reached by coasting on {where}: the "
            f"longest feasible coasting run takes {t:.2f} s (coasting earlier stalls or falls "
            f"below min_coast_speed_mps={min_coast_speed_mps:g}); use method='cruise_cap'"
        )
    s, v, lim = payload
    return s, v, lim, f"time-supplemented (coast from {sc:.2f} m), {where}"


__all__ = [
    "SpeedProfile",
    "constant_decel_profile",
    "minimum_time_profile",
    "paper002_speed_command",
    "paper003_speed_command",
    "piecewise_speed_command",
    "time_supplemented_profile",
]
