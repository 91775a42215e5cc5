"""An independent minimum-running-time solve (scipy DOP853), for the profile tests.

Written from the equations alone (no library code): with ``E = v²/2`` the forward run
at full traction obeys ``dE/ds = (F(v) − R(v) − F_g(s)) / M'`` (no singularity at
standstill), integrated by ``solve_ivp(method="DOP853")`` section by section, restarted
at every gradient and limit change and stopped by an event where ``E`` reaches the
section's cap (the train then cruises at the cap: on a section of constant gradient the
net force at the cap keeps its sign).  The braking curve at the constant service
deceleration ``b`` is analytic, ``E_b(s) = min_j (E_cap,j + b (p_j − s))`` over the
section starts ``p_j ≥ s`` and the stop.  The profile is ``min(E_f, E_b, E_cap)`` and
the running time ``∫ ds / v`` is summed piece by piece between the sections and the
crossings of the two curves: ``quad`` on the forward pieces (in ``u = √(s − s₀)``
from standstill, which removes the ``1/√s`` singularity), the exact
``2 Δs / (v₁ + v₂)`` on the braking pieces.  These are the conventions of the
library's minimum-time profile (service braking, forces at the train's speed, gradient
force ``m g sin(atan(i/1000))``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np
from scipy.integrate import quad, solve_ivp
from scipy.optimize import brentq

G = 9.81


def min_running_time(
    *,
    length_m: float,
    limit_sections: Sequence[tuple[float, float]],
    gradient_sections: Sequence[tuple[float, float]],
    traction_N: Callable[[float], float],
    davis: tuple[float, float, float],
    mass_kg: float,
    inertial_mass_kg: float,
    decel_mps2: float,
    table_speeds: Sequence[float] = (),
    rtol: float = 1e-11,
) -> float:
    """Minimum running time [s] from rest at 0 to a stop at ``length_m``.

    ``limit_sections``: ``(start m, limit m/s)``, first start 0 (the limit governing the
    train, length rule applied by the caller); ``gradient_sections``: ``(start m,
    gradient permil)``; ``traction_N(v)``: the traction envelope, with kinks at
    ``table_speeds`` (the forward solve restarts there).
    """
    a, b, c = davis
    starts = sorted({0.0, *(p for p, _ in limit_sections), *(p for p, _ in gradient_sections)})
    starts = [p for p in starts if p < length_m]
    ends = [*starts[1:], length_m]

    def step_value(sections, s):
        val = sections[0][1]
        for p, v in sections:
            if p <= s:
                val = v
        return val

    sec = []
    for s0, s1 in zip(starts, ends, strict=True):
        mid = 0.5 * (s0 + s1)
        cap = step_value(limit_sections, mid)
        grad = step_value(gradient_sections, mid)
        fg = mass_kg * G * math.sin(math.atan(grad * 1e-3))
        sec.append((s0, s1, 0.5 * cap * cap, fg))

    def rhs_value(E, fg):
        v = math.sqrt(max(2.0 * E, 0.0))
        return (traction_N(v) - (a + b * v + c * v * v if v > 0 else 0.0) - fg) / inertial_mass_kg

    # ---------------------------------------------------------------- forward, capped
    pieces = []  # (s0, s1, kind, data): "ode" with a dense solution, "flat" with E
    E = 0.0
    for s0, s1, Ecap, fg in sec:
        E = min(E, Ecap)
        s = s0
        while s < s1:
            if E >= Ecap * (1 - 1e-14) and rhs_value(Ecap, fg) >= 0.0:
                pieces.append((s, s1, "flat", Ecap))
                E, s = Ecap, s1
                break

            def f(_s, y, fg=fg):
                return [rhs_value(y[0], fg)]

            def hit_cap(_s, y, Ecap=Ecap):
                return y[0] - Ecap

            hit_cap.terminal, hit_cap.direction = True, 1.0

            def stall(_s, y):
                return y[0]

            stall.terminal, stall.direction = True, -1.0
            # restarts where the speed crosses a speed of the traction table (kinks)
            kinks = [
                (lambda _s, y, Ek=0.5 * vk * vk: y[0] - Ek)
                for vk in table_speeds
                if abs(0.5 * vk * vk - E) > 1e-9 * (1.0 + E) and 0.5 * vk * vk < Ecap
            ]
            for ev in kinks:
                ev.terminal = True
            sol = solve_ivp(
                f,
                (s, s1),
                [E],
                method="DOP853",
                rtol=rtol,
                atol=1e-12,
                events=[hit_cap, stall, *kinks],
                dense_output=True,
            )
            if sol.t_events[1].size:
                raise ValueError("the train stalls")
            s_end = float(sol.t[-1])
            pieces.append((s, s_end, "ode", sol.sol))
            E = float(sol.y[0, -1])
            if sol.t_events[0].size:
                E = Ecap
            s = s_end

    def E_f(x: float) -> float:
        for s0, s1, kind, data in pieces:
            if s0 <= x <= s1:
                return data if kind == "flat" else float(data(x)[0])
        raise ValueError(x)

    # ---------------------------------------------------------------- braking curve
    cons = [(s0, Ecap) for s0, _, Ecap, _ in sec] + [(length_m, 0.0)]

    def E_b(x: float) -> float:
        return min(Ec + decel_mps2 * (p - x) for p, Ec in cons if p >= x)

    # ---------------------------------------------------------------- running time
    cuts = sorted({0.0, length_m, *(p[0] for p in pieces), *(p[1] for p in pieces)})
    fine = []
    for s0, s1 in zip(cuts[:-1], cuts[1:], strict=True):
        if s1 - s0 <= 1e-9:  # (a piece that short adds < 1e-9 s)
            continue
        xs = np.linspace(s0, s1, 201)
        h = [E_f(float(x)) - E_b(float(x)) for x in xs]
        pts = [s0]
        for k in range(len(xs) - 1):
            if h[k] * h[k + 1] < 0.0:
                pts.append(brentq(lambda x: E_f(x) - E_b(x), xs[k], xs[k + 1], xtol=1e-12))
        pts.append(s1)
        fine += list(zip(pts[:-1], pts[1:], strict=True))
    opts = dict(epsabs=0.0, epsrel=1e-11, limit=200)
    total = 0.0
    for s0, s1 in fine:
        if s1 - s0 <= 1e-9:
            continue
        m = 0.5 * (s0 + s1)
        if E_f(m) <= E_b(m):
            if E_f(s0) > 0.0:
                part = quad(lambda x: 1.0 / math.sqrt(2.0 * E_f(x)), s0, s1, **opts)
            else:  # from standstill: s = s0 + u², smooth in u (E ~ a s near s0)
                part = quad(
                    lambda u, s0=s0: 2.0 * u / math.sqrt(2.0 * E_f(s0 + u * u)),
                    0.0,
                    math.sqrt(s1 - s0),
                    **opts,
                )
            total += part[0]
        else:
            v0, v1 = math.sqrt(2.0 * E_b(s0)), math.sqrt(2.0 * max(E_b(s1), 0.0))
            total += 2.0 * (s1 - s0) / (v0 + v1)
    return total
