"""Reference trajectories a controller tracks: a speed profile indexed by distance or time."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from train_envs.lines.profiles import SpeedProfile


@dataclass(frozen=True)
class Reference:
    """A speed profile plus how it is tracked.

    ``mode="distance"``: the reference speed is v_ref(s) at the train's position
    (station stopping, paper 001; speed–distance curves of ATO); the reference position
    is s_ref(t) from the profile's own timing.
    ``mode="time"``: v_ref(t) and s_ref(t) are functions of time (speed commands of
    papers 000, 002, 003, 004 and timetabled runs).
    """

    profile: SpeedProfile
    mode: str = "time"
    _at: dict[float, tuple[float, float]] = field(
        default_factory=dict, init=False, repr=False, compare=False
    )

    def __post_init__(self) -> None:
        if self.mode not in ("distance", "time"):
            raise ValueError(f"reference mode must be 'distance' or 'time', got {self.mode!r}")

    def v_ref(self, t: float, s: float) -> float:
        if self.mode == "distance":
            return float(self.profile.v_at_s(s))
        return float(self.profile.v_at_t(t))

    def s_ref(self, t: float) -> float:
        return float(self.profile.s_at_t(t))

    def at_time(self, t: float) -> tuple[float, float]:
        """``(v_ref(t, ·), s_ref(t))`` of a time-indexed reference, remembered per time
        (the profile is read-only: a population in lockstep and the next one on the same
        grid of times read it once per time)."""
        hit = self._at.get(t)
        if hit is None:
            if len(self._at) >= 16384:
                self._at.clear()
            hit = self._at[t] = (float(self.profile.v_at_t(t)), float(self.profile.s_at_t(t)))
        return hit

    def preview_time(self, t0: float, dt: float, n: int) -> tuple[np.ndarray, np.ndarray]:
        """Reference (s, v) at times t0 + dt, ..., t0 + n dt (for predictive controllers)."""
        ts = t0 + dt * np.arange(1, n + 1)
        return np.asarray(self.profile.s_at_t(ts), float), np.asarray(
            self.profile.v_at_t(ts), float
        )

    @property
    def duration_s(self) -> float:
        return float(self.profile.t_s[-1])

    @property
    def end_m(self) -> float:
        return float(self.profile.s_m[-1])
