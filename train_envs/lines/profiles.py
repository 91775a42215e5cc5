"""Reference speed profiles: minimum-time runs, time-supplemented runs and paper commands.

A :class:`SpeedProfile` is a piecewise *constant-acceleration* trajectory given at nodes
``(s_i, v_i)``: on each segment ``v²`` is linear in ``s`` (``v² = v_i² + 2 a_i (s - s_i)``),
so the time follows exactly from

    ``t_{i+1} - t_i = 2 (s_{i+1} - s_i) / (v_i + v_{i+1})``

(the trapezoid rule on ``1/v`` is replaced by this exact constant-acceleration formula,
which stays finite when one end of a segment is at standstill). The same model is used
by every interpolation method, so ``s_at_t``, ``t_at_s``, ``v_at_s`` and ``v_at_t`` are
mutually consistent. Outside its range a profile is held at its end values.

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
limit anywhere. The train is a point mass (train length ignored for limit changes).
"""

from __future__ import annotations

import math
from bisect import bisect_right
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from train_envs.lines.track import Track
from train_envs.trains import KMH, TrainParams, get_train
from train_envs.validation import check_choice, check_increasing, check_range

if TYPE_CHECKING:
    import pandas as pd

FloatOrArray = float | np.ndarray
_SCALAR = (float, int)  # fast path for scalar arguments (np.float64 is a float)

#: Minimum node spacing [m] when merging the regular grid with section starts.
_MERGE_TOL_M = 1e-6


# ====================================================================== SpeedProfile
@dataclass(frozen=True, eq=False, repr=False)
class SpeedProfile:
    """Reference trajectory with nodes ``s_m`` [m], ``v_mps`` [m/s] and derived ``t_s`` [s].

    Attributes:
        s_m: positions, strictly increasing (at least 2 nodes).
        v_mps: speeds at the nodes, finite and ``>= 0``; no segment may have zero speed at
            both ends (a standstill cannot be indexed by distance).
        v_limit_mps: optional speed limit at the nodes (NaN where unknown).
        t0_s: time at the first node.
        label: free description (how the profile was made).
        t_s: node times, computed in ``__post_init__`` with the exact constant-acceleration
            formula ``Δt = 2 Δs / (v_i + v_{i+1})``.
    """

    s_m: np.ndarray
    v_mps: np.ndarray
    v_limit_mps: np.ndarray | None = None
    t0_s: float = 0.0
    label: str = ""
    t_s: np.ndarray = field(init=False)
    _a: np.ndarray = field(init=False)
    _a_nodes: np.ndarray = field(init=False)
    _s: list[float] = field(init=False)
    _v: list[float] = field(init=False)
    _t: list[float] = field(init=False)
    _al: list[float] = field(init=False)
    _seg_tbl: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        s = check_increasing("SpeedProfile.s_m", self.s_m)
        v = np.array(self.v_mps, dtype=float)
        if v.shape != s.shape:
            raise ValueError(
                f"SpeedProfile.v_mps must have the shape of s_m {s.shape}, got {v.shape}"
            )
        if s.size < 2:
            raise ValueError(f"SpeedProfile.s_m needs at least 2 nodes, got {s.size}")
        if not np.all(np.isfinite(v)) or np.any(v < 0):
            i = int(np.nonzero(~np.isfinite(v) | (v < 0))[0][0])
            raise ValueError(f"SpeedProfile.v_mps must be finite and >= 0: element {i} is {v[i]}")
        vsum = v[:-1] + v[1:]
        if np.any(vsum <= 0):
            i = int(np.nonzero(vsum <= 0)[0][0])
            raise ValueError(
                f"SpeedProfile.v_mps is 0 at both ends of segment {i} "
                f"([{s[i]}, {s[i + 1]}] m): a standstill cannot be indexed by distance"
            )
        t0 = check_range("SpeedProfile.t0_s", self.t0_s)
        dsg = np.diff(s)
        t = t0 + np.concatenate(([0.0], np.cumsum(2.0 * dsg / vsum)))
        a = (v[1:] ** 2 - v[:-1] ** 2) / (2.0 * dsg)
        if self.v_limit_mps is None:
            lim = np.full(s.shape, np.nan)
        else:
            lim = np.array(self.v_limit_mps, dtype=float)
            if lim.shape != s.shape:
                raise ValueError(
                    f"SpeedProfile.v_limit_mps must have the shape of s_m {s.shape}, "
                    f"got {lim.shape}"
                )
        for name, arr in (("s_m", s), ("v_mps", v), ("v_limit_mps", lim), ("t_s", t), ("_a", a)):
            arr = np.array(arr, dtype=float)
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        a_nodes = np.append(self._a, self._a[-1])
        a_nodes.setflags(write=False)
        object.__setattr__(self, "_a_nodes", a_nodes)
        object.__setattr__(self, "t0_s", t0)
        object.__setattr__(self, "_s", s.tolist())
        object.__setattr__(self, "_v", v.tolist())
        object.__setattr__(self, "_t", t.tolist())
        object.__setattr__(self, "_al", a.tolist())
        # per segment, for sv_at_t's single gather: t_i, t_i+1 − t_i, v_i, a_i / 2, a_i, s_i,
        # s_i+1 (a_i / 2 is exact: (a/2)·τ is the bit pattern of 0.5 * a * τ)
        tbl = np.column_stack([t[:-1], t[1:] - t[:-1], v[:-1], 0.5 * a, a, s[:-1], s[1:]])
        tbl.setflags(write=False)
        object.__setattr__(self, "_seg_tbl", tbl)

    def __repr__(self) -> str:
        return (
            f"SpeedProfile(label={self.label!r}, nodes={len(self._s)}, "
            f"s=[{self._s[0]:g}, {self._s[-1]:g}] m, t=[{self._t[0]:g}, {self._t[-1]:.2f}] s, "
            f"v_max={max(self._v):.2f} m/s)"
        )

    # ------------------------------------------------------------------ summary
    @property
    def length_m(self) -> float:
        """Distance covered [m]."""
        return self._s[-1] - self._s[0]

    @property
    def running_time_s(self) -> float:
        """Time from the first to the last node [s]."""
        return self._t[-1] - self._t[0]

    @property
    def a_mps2(self) -> np.ndarray:
        """Acceleration at each node [m/s²]: that of the segment starting there (the last
        node repeats the last segment's value; read-only, built once)."""
        return self._a_nodes

    # ------------------------------------------------------------------ interpolation
    def _seg(self, x: np.ndarray, nodes: np.ndarray) -> np.ndarray:
        # np.minimum/np.maximum: np.clip's Python-level overhead is ~10x theirs here
        i = nodes.searchsorted(x, side="right") - 1
        return np.minimum(np.maximum(i, 0), len(nodes) - 2)

    def v_at_s(self, s: FloatOrArray) -> FloatOrArray:
        """Speed [m/s] at position ``s`` [m] (``v²`` linear in ``s`` within a segment)."""
        if isinstance(s, _SCALAR):
            sl = self._s
            i = min(max(bisect_right(sl, s) - 1, 0), len(sl) - 2)
            d = min(max(s - sl[i], 0.0), sl[i + 1] - sl[i])
            v2 = self._v[i] ** 2 + 2.0 * self._al[i] * d
            return math.sqrt(v2) if v2 > 0.0 else 0.0
        x = np.asarray(s, float)
        i = self._seg(x, self.s_m)
        d = np.minimum(np.maximum(x - self.s_m[i], 0.0), self.s_m[i + 1] - self.s_m[i])
        return np.sqrt(np.maximum(self.v_mps[i] ** 2 + 2.0 * self._a[i] * d, 0.0))

    def t_at_s(self, s: FloatOrArray) -> FloatOrArray:
        """Time [s] at which the profile reaches position ``s`` [m]."""
        if isinstance(s, _SCALAR):
            sl = self._s
            i = min(max(bisect_right(sl, s) - 1, 0), len(sl) - 2)
            d = min(max(s - sl[i], 0.0), sl[i + 1] - sl[i])
            if d == 0.0:
                return self._t[i]
            v2 = self._v[i] ** 2 + 2.0 * self._al[i] * d
            return self._t[i] + 2.0 * d / (self._v[i] + math.sqrt(max(v2, 0.0)))
        x = np.asarray(s, float)
        i = self._seg(x, self.s_m)
        d = np.minimum(np.maximum(x - self.s_m[i], 0.0), self.s_m[i + 1] - self.s_m[i])
        vs = self.v_mps[i] + np.sqrt(np.maximum(self.v_mps[i] ** 2 + 2.0 * self._a[i] * d, 0.0))
        with np.errstate(divide="ignore", invalid="ignore"):
            dt = np.where(d > 0.0, 2.0 * d / vs, 0.0)
        return self.t_s[i] + dt

    def s_at_t(self, t: FloatOrArray) -> FloatOrArray:
        """Position [m] at time ``t`` [s]: ``s_i + v_i τ + a_i τ² / 2``."""
        if isinstance(t, _SCALAR):
            tl = self._t
            i = min(max(bisect_right(tl, t) - 1, 0), len(tl) - 2)
            tau = min(max(t - tl[i], 0.0), tl[i + 1] - tl[i])
            s = self._s[i] + self._v[i] * tau + 0.5 * self._al[i] * tau * tau
            return min(s, self._s[i + 1])
        x = np.asarray(t, float)
        i = self._seg(x, self.t_s)
        tau = np.minimum(np.maximum(x - self.t_s[i], 0.0), self.t_s[i + 1] - self.t_s[i])
        s = self.s_m[i] + self.v_mps[i] * tau + 0.5 * self._a[i] * tau * tau
        return np.minimum(s, self.s_m[i + 1])

    def sv_at_t(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(s_at_t(t), v_at_t(t))`` for an array of times with one segment search (and
        one gather of the segments' constants: the same arithmetic, fewer numpy calls)."""
        x = np.asarray(t, float)
        i = self.t_s.searchsorted(x, side="right")
        i -= 1
        np.maximum(i, 0, out=i)
        np.minimum(i, len(self._t) - 2, out=i)
        seg = self._seg_tbl[i].T
        t0, span, v0, ha, a, s0, s1 = seg
        tau = x - t0
        np.maximum(tau, 0.0, out=tau)
        np.minimum(tau, span, out=tau)
        s = ha * tau
        s += v0
        s *= tau
        s += s0
        np.minimum(s, s1, out=s)
        v = a * tau
        v += v0
        np.maximum(v, 0.0, out=v)
        return s, v

    def sample_sv(self, t0: float, dt: float, n: int) -> tuple[list[float], list[float]]:
        """``(s, v)`` at the ``n`` times ``t0 + k dt``, ``k = 1..n``, as Python lists.

        The scalar twin of :meth:`sv_at_t` for a predictive controller's short,
        uniform preview: the same arithmetic per point (results equal bit for bit), one
        segment search per crossed node interval (bisection from the current segment: a
        reference built on a fine grid has many nodes per dt) instead of a dozen numpy
        calls on tiny arrays.
        """
        tl, sl, vl, al = self._t, self._s, self._v, self._al
        last = len(tl) - 2
        i = min(max(bisect_right(tl, t0 + dt) - 1, 0), last)
        s_out: list[float] = []
        v_out: list[float] = []
        t_next = tl[i + 1]
        for k in range(1, n + 1):
            x = t0 + dt * k
            if x >= t_next and i < last:
                # the last node at or before x (nodes may be far denser than dt)
                i = bisect_right(tl, x, i + 1) - 1
                if i > last:
                    i = last
                t_next = tl[i + 1]
            # min/max written as comparisons (same values, NaN included)
            ti = tl[i]
            tau = x - ti
            if tau < 0.0:
                tau = 0.0
            span = t_next - ti
            if tau > span:
                tau = span
            v0 = vl[i]
            a = al[i]
            s = sl[i] + (v0 + 0.5 * a * tau) * tau
            s_end = sl[i + 1]
            s_out.append(s if s < s_end else s_end)
            v = v0 + a * tau
            v_out.append(v if v > 0.0 else 0.0)
        return s_out, v_out

    def v_at_t(self, t: FloatOrArray) -> FloatOrArray:
        """Speed [m/s] at time ``t`` [s]: ``v_i + a_i τ`` (linear in time per segment)."""
        if isinstance(t, _SCALAR):
            tl = self._t
            i = min(max(bisect_right(tl, t) - 1, 0), len(tl) - 2)
            tau = min(max(t - tl[i], 0.0), tl[i + 1] - tl[i])
            return max(self._v[i] + self._al[i] * tau, 0.0)
        x = np.asarray(t, float)
        i = self._seg(x, self.t_s)
        tau = np.minimum(np.maximum(x - self.t_s[i], 0.0), self.t_s[i + 1] - self.t_s[i])
        return np.maximum(self.v_mps[i] + self._a[i] * tau, 0.0)

    def to_dataframe(self) -> pd.DataFrame:
        """Nodes as a table: ``s_m``, ``v_mps``, ``t_s``, ``a_mps2``, ``v_limit_mps``."""
        import pandas as pd

        return pd.DataFrame(
            {
                "s_m": self.s_m,
                "v_mps": self.v_mps,
                "t_s": self.t_s,
                "a_mps2": self.a_mps2,
                "v_limit_mps": self.v_limit_mps,
            }
        )


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
    grid = np.union1d(grid, bp[(bp > s_start) & (bp < s_stop)])
    keep = np.ones(grid.size, dtype=bool)
    keep[1:] = np.diff(grid) > _MERGE_TOL_M
    grid = grid[keep]
    grid[0], grid[-1] = s_start, s_stop

    mid = 0.5 * (grid[:-1] + grid[1:])
    seg_limit = np.asarray(track.speed_limit_at(mid), float)
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
    "SpeedProfile",
    "constant_decel_profile",
    "minimum_time_profile",
    "paper002_speed_command",
    "paper003_speed_command",
    "piecewise_speed_command",
    "time_supplemented_profile",
]
