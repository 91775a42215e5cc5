r"""The DMC's setpoint y_r(k) and its preview y_r(k+1 … k+P) (004 §4.2).

The setpoint is the profile speed ``v_ref(t + iΔt)`` for a time-indexed reference; for
a distance-indexed one the profile followed at its own timing from the current
position, ``v(t_p(s) + iΔt)``. Two choices where 004 is silent (it tracks speed, but is
judged on the stopping position and time of a time-indexed run):

* *position catch-up* (time-indexed references only):
  ``y_r = v_ref + sat(λ_x (s_ref(t) − s), ±c_max) · min(1, v_ref / v_fade)``
  (:func:`~.laws.position_catchup`, :func:`~.laws.with_catchup`). A pure speed tracker
  keeps the position deficit of the start to the stop; the fade switches the catch-up
  off as the reference comes to rest, so that the train stops instead of creeping up
  to the stop point;
* *stop hold*: once the preview reaches the end of a profile that ends at the stop,
  the setpoint there is ``−stop_hold`` (a little below zero), so that the train really
  comes to rest and is held; an exact regulator to 0 m/s hovers just above it.

A time-indexed :class:`~train_envs.lines.profiles.SpeedProfile` is read through its
scalar methods (``v_at_t``/``s_at_t`` on a float, :meth:`SpeedProfile.sample_sv` for
the preview), which equal its array methods bit for bit; other references go through
the array methods.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from train_envs.controllers.dmc.laws import position_catchup, with_catchup
from train_envs.lines.profiles import SpeedProfile


class SetpointPreview:
    """``(v_ref(k), y_r(k), [y_r(k+1) … y_r(k+P)])`` of a reference, with catch-up and hold.

    Args:
        reference: the control context's reference (``profile``, ``mode``).
        dt_s: control period Δt; ``horizon``: P.
        gain_1ps, c_max_mps, fade_mps: λ_x, c_max and v_fade of the catch-up (λ_x = 0: off).
        hold_mps: the setpoint after the end of the profile (0: off).
    """

    def __init__(
        self,
        reference: Any,
        dt_s: float,
        horizon: int,
        *,
        gain_1ps: float,
        c_max_mps: float,
        fade_mps: float,
        hold_mps: float,
    ) -> None:
        self.profile = reference.profile
        self.mode = reference.mode
        self.dt_s = dt_s
        self.horizon = horizon
        self.gain = gain_1ps
        self.c_max = c_max_mps
        self.fade = fade_mps
        self.hold = hold_mps
        tp = getattr(self.profile, "t_s", None)
        #: time at which the profile ends (the stop hold starts there)
        self.t_end = float(tp[-1]) if tp is not None else math.inf
        self._steps = np.arange(1, horizon + 1)
        self._dtk = (dt_s * self._steps).tolist()  # the preview's time offsets i Δt
        #: the position catch-up applies (time-indexed references, λ_x > 0)
        self.catchup = self.mode == "time" and gain_1ps > 0.0
        #: a time-indexed SpeedProfile is read through its scalar methods
        self.scalar = self.mode == "time" and isinstance(self.profile, SpeedProfile)
        self.reference = reference
        self._rows: dict[float, tuple[np.ndarray, float, np.ndarray, np.ndarray | None]] = {}

    def same_as(self, other: SetpointPreview) -> bool:
        """Whether ``other`` gives the same preview at every time (the same reference
        object, period, horizon, catch-up and hold)."""
        return other.reference is self.reference and (
            self.mode, self.dt_s, self.horizon, self.gain, self.c_max, self.fade, self.hold
        ) == (other.mode, other.dt_s, other.horizon, other.gain, other.c_max, other.fade,
              other.hold)  # fmt: skip

    #: the most times :meth:`time_row` remembers (then it starts afresh)
    MEMO_SIZE = 16384

    def time_row(self, t: float) -> tuple[np.ndarray, float, np.ndarray, np.ndarray | None]:
        """The part of the preview that depends on the time only, for a time-indexed
        profile read through its scalar methods (:attr:`scalar`), at time ``t``:
        ``(v, s_ref, fade, held)`` with ``v = [v_ref(t), v_ref(t + Δt) … v_ref(t + PΔt)]``
        (as :meth:`__call__` reads it), ``s_ref = s_ref(t)`` (0 without catch-up),
        ``fade = min(v / v_fade, 1)`` elementwise (``None`` without catch-up) and
        ``held`` the mask of the entries the stop hold replaces. The setpoint row of a
        member at position ``s`` is then ``v + sat(λ_x (s_ref − s), ±c_max) · fade`` with
        the held entries set to ``−stop_hold``: :meth:`__call__`'s values.

        Remembered per time (the values do not change: the profile is read-only), so
        that a population in lockstep and the next generation on the same grid of
        times read the profile once per time.
        """
        row = self._rows.get(t)
        if row is None:
            if len(self._rows) >= self.MEMO_SIZE:
                self._rows.clear()
            prof = self.profile
            v = np.array([prof.v_at_t(t), *prof.sample_sv(t, self.dt_s, self.horizon)[1]])
            held = np.zeros(self.horizon + 1, dtype=bool)
            if self.hold > 0.0 and t + self._dtk[-1] >= self.t_end:
                held[:] = [t >= self.t_end] + [t + d >= self.t_end for d in self._dtk]
            if self.catchup:
                q = v / self.fade
                fade = np.where(q < 1.0, q, 1.0)
                row = (v, prof.s_at_t(t), fade, held)
            else:
                row = (v, 0.0, None, held)
            self._rows[t] = row
        return row

    def __call__(self, t_s: float, s_m: float) -> tuple[float, float, list[float]]:
        """(v_ref(k), y_r(k), y_r(k+1 … k+P)) at time ``t_s`` and position ``s_m``."""
        prof = self.profile
        catchup = self.catchup
        if self.scalar and type(t_s) is float and t_s - t_s == 0.0:
            t0 = t_s
            v0 = prof.v_at_t(t0)
            v_prev = prof.sample_sv(t0, self.dt_s, self.horizon)[1]
            if catchup:
                c = position_catchup(prof.s_at_t(t0), s_m, self.gain, self.c_max)
        else:
            if self.mode == "distance":
                t0 = float(prof.t_at_s(s_m))
                v0 = float(prof.v_at_s(s_m))
            else:
                t0 = t_s
                v0 = float(prof.v_at_t(t0))
            v_prev = np.asarray(prof.v_at_t(t0 + self.dt_s * self._steps), dtype=float).tolist()
            if catchup:
                c = position_catchup(float(prof.s_at_t(t0)), s_m, self.gain, self.c_max)
        if catchup:
            y_all = with_catchup([v0, *v_prev], c, self.fade)
            y0 = y_all[0]
            y_r = y_all[1:]
        else:
            y0 = v0
            y_r = v_prev
        if self.hold > 0.0:
            t_end = self.t_end
            if t0 + self._dtk[-1] >= t_end:
                # the profile has ended at the stop: aim a little below zero so that the
                # train really comes to rest (and is held) instead of creeping towards 0
                hold = -self.hold
                y_r = [hold if t0 + d >= t_end else v for d, v in zip(self._dtk, y_r, strict=True)]
                if t0 >= t_end:
                    y0 = hold
        return v0, y0, y_r
