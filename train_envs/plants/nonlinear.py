"""The nonlinear part of the n-car model: running resistance, gradient, disturbances.

Per car i (rows of the speeds in ż = A z + B w + N(z, t))::

    N_i(z, t) = −(R_i(v_i) + m_i g θ(x_i)/1000 + m_i w(t)) / m'_i

with R_i the car's Davis law (:func:`train_envs.plants.physics.davis_signed_N`), θ the
equivalent gradient under the car (:func:`train_envs.plants.physics.gradient_at` on a
:class:`~train_envs.plants.lookup.PiecewiseLinear`, or any vectorised callable), w the
sum of the disturbances and, with a :class:`~train_envs.plants.resistance.DavisVariation`,
the coefficients ``a_i + δa m_i``, ``b_i + δb m_i``, ``c_i + δc m_i`` (``c_1 + δc M`` on
the lead car alone when the aerodynamic term sits there).

:meth:`NonlinearTerm.array` is the numpy formulation; :meth:`NonlinearTerm.floats`
computes the same on Python floats, element by element in the same order (numpy's
element-wise arithmetic is IEEE-exact like Python's), so both give the same bits.
"""

from __future__ import annotations

from bisect import bisect_right
from collections.abc import Callable, Sequence

import numpy as np

from train_envs.plants.physics import davis_N, davis_signed_N
from train_envs.plants.resistance import DavisVariation, Disturbance

Table = tuple[list[float], list[float], list[float]]


class NonlinearTerm:
    """N(z, t) of an ``n``-car train (constants per car, as arrays and as floats)."""

    def __init__(
        self,
        m: np.ndarray,
        m_inertial: np.ndarray,
        davis: tuple[np.ndarray, np.ndarray, np.ndarray],
        lead_aero: bool,
        offsets: np.ndarray,
        mg: np.ndarray,
        disturbances: Sequence[Disturbance],
        davis_variation: DavisVariation | None,
    ) -> None:
        self.n = n = m.size
        self.m, self.m_inertial, self.offsets, self.mg = m, m_inertial, offsets, mg
        self.ca, self.cb, self.cc = davis
        self.lead_aero = lead_aero
        self.disturbances = tuple(disturbances)
        self.davis_variation = davis_variation
        self.ca_l, self.cb_l, self.cc_l = self.ca.tolist(), self.cb.tolist(), self.cc.tolist()
        self.m_l, self.mi_l = m.tolist(), m_inertial.tolist()
        self.mg_l, self.off_l = mg.tolist(), offsets.tolist()
        self.m_sum = float(m.sum())
        self.zeros_l = [0.0] * n
        # per car: (index of its speed in z, a_i, b_i, c_i, offset_i, m_i g/1000, m_i, m'_i)
        self.car_consts = [
            (n + i, *c)
            for i, c in enumerate(
                zip(
                    self.ca_l,
                    self.cb_l,
                    self.cc_l,
                    self.off_l,
                    self.mg_l,
                    self.m_l,
                    self.mi_l,
                    strict=True,
                )
            )
        ]
        self.a0, self.b0, self.c0 = self.ca_l[0], self.cb_l[0], self.cc_l[0]
        self.mg0, self.m0 = self.mg_l[0], self.m_l[0]
        self.minv0 = 1.0 / self.mi_l[0]

    def disturbance_sum(self, t: float) -> float:
        """Sum of the disturbance accelerations at ``t``, in their order."""
        w = 0.0
        for dist in self.disturbances:
            w += dist.accel(t)
        return w

    def array(
        self, z: np.ndarray, t: float, gradient: Callable[[np.ndarray], np.ndarray] | None
    ) -> np.ndarray:
        """N(z, t) with numpy arrays (any gradient callable)."""
        n = self.n
        v = z[n : 2 * n]
        av = np.abs(v)
        ca, cb, cc = self.ca, self.cb, self.cc
        if self.davis_variation is not None:
            d0, d1, d2 = self.davis_variation.deltas(t)
            ca = ca + d0 * self.m
            cb = cb + d1 * self.m
            if self.lead_aero:
                cc = cc.copy()
                cc[0] += d2 * self.m.sum()
            else:
                cc = cc + d2 * self.m
        force = np.where(v >= 0.0, 1.0, -1.0) * davis_N(ca, cb, cc, av)  # v = 0: leaving rest
        if gradient is not None:
            x = z[:n] - self.offsets
            force = force + self.mg * gradient(x)
        if self.disturbances:
            force = force + self.m * self.disturbance_sum(t)
        return -force / self.m_inertial

    def floats(
        self,
        z: list[float],
        t: float,
        cars: int,
        tab: Table | None,
        minus: list[float] | None = None,
        segs: list[int] | None = None,
    ) -> list[float]:
        """:meth:`array` on Python floats for the first ``cars`` cars, with the gradient
        as the table lists ``tab`` (or None for a level track).  ``minus`` (n values) is
        subtracted from the results: the ETD2 step's ``N(a) − N(z)`` in one pass
        (subtracting 0.0 changes nothing).  ``segs``, a list, receives the table segment
        under each car (the plant's breakpoint check)."""
        if minus is None:
            minus = self.zeros_l
        dv = self.davis_variation
        wd = self.disturbance_sum(t) if self.disturbances else None
        out = []
        if dv is None and tab is not None:  # the usual case, one tuple of constants per car
            xl, y0l, sl = tab
            consts = self.car_consts if cars == self.n else self.car_consts[:cars]
            for (vi, ca, cb, cc, off, mg, m, mi), x, s0 in zip(consts, z, minus, strict=False):
                f = davis_signed_N(ca, cb, cc, z[vi])
                xi = x - off
                j = bisect_right(xl, xi) - 1  # (gradient_at, inlined for the index)
                if segs is not None:
                    segs.append(j)
                f = f + mg * (y0l[j] + sl[j] * (xi - xl[j]))
                if wd is not None:
                    f = f + m * wd
                out.append(-f / mi - s0)
            return out
        n = self.n
        ca, cb, cc = self.ca_l, self.cb_l, self.cc_l
        m, mg, mi, off = self.m_l, self.mg_l, self.mi_l, self.off_l
        d0 = d1 = d2 = 0.0
        if dv is not None:
            d0, d1, d2 = dv.deltas(t)
        for i in range(cars):
            v = z[n + i]
            if dv is None:
                f = davis_signed_N(ca[i], cb[i], cc[i], v)
            else:
                if self.lead_aero:
                    c2 = cc[i] + d2 * self.m_sum if i == 0 else cc[i]
                else:
                    c2 = cc[i] + d2 * m[i]
                f = davis_signed_N(ca[i] + d0 * m[i], cb[i] + d1 * m[i], c2, v)
            if tab is not None:
                xi = z[i] - off[i]
                j = bisect_right(tab[0], xi) - 1
                if segs is not None:
                    segs.append(j)
                f = f + mg[i] * (tab[1][j] + tab[2][j] * (xi - tab[0][j]))
            if wd is not None:
                f = f + m[i] * wd
            out.append(-f / mi[i] - minus[i])
        return out

    def at_segments(
        self, z: list[float], t: float, wd: float, tab: Table, segs: list[int]
    ) -> list[float]:
        """N of every car with the gradient under car i read on the table segment
        ``segs[i]`` (a side of a breakpoint, for a split sub-step) and the disturbance
        sum ``wd`` (the plant interpolates it inside the sub-step)."""
        n = self.n
        xl, y0l, sl = tab
        d0 = d1 = d2 = 0.0
        if self.davis_variation is not None:
            d0, d1, d2 = self.davis_variation.deltas(t)
        out = []
        for i in range(n):
            m = self.m_l[i]
            if self.lead_aero:
                c2 = self.cc_l[i] + d2 * self.m_sum if i == 0 else self.cc_l[i]
            else:
                c2 = self.cc_l[i] + d2 * m
            f = davis_signed_N(self.ca_l[i] + d0 * m, self.cb_l[i] + d1 * m, c2, z[n + i])
            j = segs[i]
            f = f + self.mg_l[i] * (y0l[j] + sl[j] * (z[i] - self.off_l[i] - xl[j]))
            if self.disturbances:
                f = f + m * wd
            out.append(-f / self.mi_l[i])
        return out

    def single(
        self, s: float, v: float, t: float, gradient: Callable[[float], float] | None
    ) -> float:
        """N of the single-point train on floats (no Davis variation): −(R + F_g + m w)/m'."""
        f = davis_signed_N(self.a0, self.b0, self.c0, v)
        if gradient is not None:
            f += self.mg0 * float(gradient(s))
        if self.disturbances:
            f += self.m0 * self.disturbance_sum(t)
        return -f * self.minv0
