"""A reference speed profile: a piecewise constant-acceleration trajectory.

A :class:`SpeedProfile` is given at nodes ``(s_i, v_i)``: on each segment ``v²`` is
linear in ``s`` (``v² = v_i² + 2 a_i (s - s_i)``), so the time follows exactly from

    ``t_{i+1} - t_i = 2 (s_{i+1} - s_i) / (v_i + v_{i+1})``

(the trapezoid rule on ``1/v`` is replaced by this exact constant-acceleration formula,
which stays finite when one end of a segment is at standstill). The same model is used
by every interpolation method, so ``s_at_t``, ``t_at_s``, ``v_at_s`` and ``v_at_t`` are
mutually consistent. Outside its range a profile is held at its end values.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from train_envs.validation import check_increasing, check_range

if TYPE_CHECKING:
    import pandas as pd

FloatOrArray = float | np.ndarray
_SCALAR = (float, int)  # fast path for scalar arguments (np.float64 is a float)


def sv_on_table(p_t: np.ndarray, p_tbl: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Reference position and speed at the times ``x`` of a speed profile given by its
    node times ``p_t`` and segment table ``p_tbl`` (per segment ``t_i, t_i+1 − t_i, v_i,
    a_i/2, a_i, s_i, s_i+1``), with one segment search and one gather of the segments'
    constants: ``s = min(s_i + (v_i + a_i/2 τ) τ, s_i+1)``, ``v = max(v_i + a_i τ, 0)``,
    ``τ = clip(x − t_i, 0, t_i+1 − t_i)`` (:meth:`SpeedProfile.sv_at_t` on arrays)."""
    i = p_t.searchsorted(x, side="right")
    i -= 1
    np.maximum(i, 0, out=i)
    np.minimum(i, p_t.size - 2, out=i)
    seg = p_tbl[i].T
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
        # np.minimum/np.maximum rather than np.clip (see docs/design/plants.md)
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
        """``(s_at_t(t), v_at_t(t))`` for an array of times (:func:`sv_on_table` on the
        profile's segment table: the same arithmetic, fewer numpy calls)."""
        return sv_on_table(self.t_s, self._seg_tbl, np.asarray(t, float))

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


__all__ = ["SpeedProfile", "sv_on_table"]
