"""Breakpoint-exact sub-steps of the general plant path (any number of cars).

The gradient table (:class:`~train_envs.plants.lookup.PiecewiseLinear`) jumps at its
segment starts: gradient steps, curve starts, curve-resistance cut-offs.  An ETD2 step
across such a jump treats the nonlinear term as if it varied linearly over the whole
step, an error of ``½ Δa h`` in speed per jump (first order).  When the predictor of a
sub-step puts a car on another segment than the one it starts on,
:func:`jump_corrections` gives, per car, the constant and linear corrections of its
nonlinear term that carry the jump at the crossing time (taken from the car's own
kinematics) into the step: :func:`train_envs.plants.single_car._jumps`, the rule of
the single-car loop as well.  :func:`held_state` applies the standstill rule at the end
of a sub-step.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from train_envs.plants.integrator import ETD2Integrator
from train_envs.plants.single_car import _jumps

if TYPE_CHECKING:
    from train_envs.plants.multi_car import TrainPlant


def jump_corrections(
    plant: TrainPlant,
    z: np.ndarray,
    w: np.ndarray,
    pred: np.ndarray,
    segs0: list[int],
    segs1: list[int],
    n0: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """``(c, l)`` per car for a sub-step from ``z`` under input ``w`` whose predictor
    ``pred`` puts car i on table segment ``segs1[i]`` instead of ``segs0[i]``; ``n0`` is
    the nonlinear term at ``z``.  The step becomes ``Φ z + Γ w + h φ1 (n0 + c) + h φ2
    (n1 − n0 + l)``."""
    n, h = plant.n, plant.h
    tab = plant._grad_table()
    assert tab is not None
    xl, y0l, sl = tab
    rows = slice(n, 2 * n)
    acc = (plant.A[rows].dot(z) + plant.B[rows].dot(w) + n0).tolist()
    zl, al = z.tolist(), pred.tolist()
    off = plant._offsets.tolist()
    kg = (plant._mg / plant.m_inertial).tolist()
    c = np.zeros(n)
    lin = np.zeros(n)
    for i in range(n):
        if segs1[i] != segs0[i]:
            c[i], lin[i] = _jumps(
                zl[i] - off[i], zl[n + i], acc[i], al[i] - zl[i], segs0[i], segs1[i], h,
                xl, y0l, sl, kg[i],
            )  # fmt: skip
    return c, lin


def held_state(
    plant: TrainPlant,
    z: np.ndarray,
    z_new: np.ndarray,
    w: np.ndarray,
    v_old: float,
    v_new: float,
) -> np.ndarray | None:
    """The state in which the brakes hold the train during the sub-step from ``z`` to
    ``z_new`` (lead-car speeds ``v_old``, ``v_new``), or None when it moves on.

    Held: crawling below the hold speed under braking, or the lead car's speed reaching
    zero.  One car: held where the sub-step ends, or at the zero crossing interpolated
    at constant deceleration; several cars: the state at the instant the lead car
    reaches the hold speed (under braking) or zero (:func:`stop_inside`), so that the
    couplers keep the deformation of that instant.  A train that has just left rest
    and would roll back stays where it is.
    """
    n, h = plant.n, plant.h
    hold = plant.HOLD_SPEED_MPS
    if v_old > 0.0 and 0.0 < v_new < hold and v_new < v_old and plant._braking():
        if n > 1:
            z_new = stop_inside(plant, z, w, h * max(v_old - hold, 0.0) / (v_old - v_new))
    elif v_new <= 0.0:
        if v_old <= 0.0:
            z_new[:n] = z[:n]
        elif n > 1:
            target = hold if v_old > hold and plant._braking() else 0.0
            z_new = stop_inside(plant, z, w, h * (v_old - target) / (v_old - v_new))
        else:
            frac = v_old / (v_old - v_new)
            z_new[:n] = z[:n] + 0.5 * z[n : 2 * n] * frac * h
    else:
        return None
    z_new[n : 2 * n] = 0.0
    return z_new


def stop_inside(plant: TrainPlant, z: np.ndarray, w: np.ndarray, tau: float) -> np.ndarray:
    """The state ``tau`` into the sub-step from ``z`` (one ETD2 step of that length): where
    the lead car of a train of several cars is held, the couplers keep the deformation
    of that instant."""
    n = plant.n
    ig = ETD2Integrator(plant.A, plant.B, tau, nonlinear_rows=slice(n, 2 * n))
    n0 = plant._nonlinear(z, plant.t)
    a = ig.Phi.dot(z) + ig.Gamma.dot(w) + ig.P1.dot(n0)
    return a + ig.P2.dot(plant._nonlinear(a, plant.t + tau) - n0)
