"""The physics laws of the train models, each written once.

Davis running resistance (Davis 1926; 000 eq. 2, 001 eq. 7, 002 eq. 3), opposing motion::

    R(v) = sign(v) (a + b |v| + c v²)                                  [N]

and its linearisation at a speed v₀ (the controllers' linear models)::

    R(v) ≈ R(v₀) + R'(v₀) (v − v₀),   R'(v₀) = b + 2 c v₀

The n-car coupler (spring-damper) forces ``f_j = k (x_j − x_{j+1} − L) + d (v_j −
v_{j+1})`` enter the car accelerations through the graph Laplacian of the chain
(:func:`coupler_matrix`): ``m' v̇ = … + k K q + d K v`` on the shifted positions
``q_i = x_i + (i − 1) L`` (000 eq. 1, 002 eq. 1, 003 eq. 1).

The gradient force ``F_g = m g θ(s) / 1000`` (000 eq. 3, 001 eq. 6) reads θ from the
piecewise-linear table of :mod:`train_envs.plants.lookup` (:func:`gradient_at`).  The
traction/braking envelope lives with the parameters that define it,
:meth:`train_envs.trains.TrainParams.max_traction_N` and its siblings, which use
:func:`davis_N` for the ``M a_max + R(v)`` limit.

Floating point: each function fixes one order of operations: :func:`davis_N`
``(a + b v) + (c v) v``, :func:`davis_sq_N` ``(a + b v) + c (v v)`` and
:func:`davis_horner_N` ``a + (b + c v) v``; a caller uses the one of its order.
All functions take Python floats or numpy arrays alike (element-wise arithmetic is
IEEE-exact in both) and are compiled unchanged as helpers of the numba twins.
"""

from __future__ import annotations

from bisect import bisect_right

import numpy as np


def davis_N(a, b, c, av):
    """Davis resistance magnitude ``a + b av + c av av`` at a speed ``av ≥ 0``, evaluated
    as ``(a + b av) + (c av) av``."""
    return a + b * av + c * av * av


def davis_sq_N(a, b, c, av):
    """:func:`davis_N` bracketed as ``(a + b av) + c (av av)`` (the envelope's form)."""
    return a + b * av + c * (av * av)


def davis_horner_N(a, b, c, v):
    """:func:`davis_N` in Horner form ``a + (b + c v) v`` (the controllers' predictions,
    with ``a`` replaced by ``a (v > 0)`` where the constant term acts only in motion)."""
    return a + (b + c * v) * v


def davis_signed_N(a: float, b: float, c: float, v: float) -> float:
    """Davis resistance of a moving car at a signed speed ``v`` (scalar): ``sign(v)
    R(|v|)``, with ``v = 0`` counted as forward motion (``+a``: the speed of a train
    leaving rest, the only moving state at exactly zero speed)."""
    av = v if v >= 0.0 else -v
    f = a + b * av + c * av * av
    return f if v >= 0 else -f


def davis_slope(b, c, v0):
    """Slope ``R'(v₀) = b + 2 c v₀`` of the Davis law at ``v₀ ≥ 0`` (its linearisation;
    the offset is ``R(v₀) − R'(v₀) v₀``)."""
    return b + 2.0 * c * v0


def car_davis(
    a: float, b: float, c: float, share: np.ndarray, lead_car_aero: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-car Davis coefficients of a train with whole-train ``(a, b, c)``: ``a`` and
    ``b`` split by the mass shares ``share``; ``c`` too, or all of it on the lead car
    when ``lead_car_aero`` (the aerodynamic term of papers 002 and 003)."""
    ca = a * share
    cb = b * share
    if lead_car_aero:
        cc = np.zeros(share.size)
        cc[0] = c
    else:
        cc = c * share
    return ca, cb, cc


def coupler_matrix(n: int) -> np.ndarray:
    """The ``n × n`` Laplacian ``K`` of a chain of ``n`` cars: ``(K q)_i = f_{i−1} − f_i``
    for unit coupler forces ``f_j = q_j − q_{j+1}`` (entries −1, 0, 1, −2: exact)."""
    K = np.zeros((n, n))
    for j in range(n - 1):
        K[j, j] -= 1.0
        K[j, j + 1] += 1.0
        K[j + 1, j] += 1.0
        K[j + 1, j + 1] -= 1.0
    return K


def gradient_at(xs, y0, slope, s: float) -> float:
    """The piecewise-linear table ``(xs, y0, slope)`` at one position ``s``:
    ``y0[i] + slope[i] (s − xs[i])`` with ``i`` the last ``xs[i] ≤ s`` (``xs[0]`` is a
    sentinel below every position, see :class:`~train_envs.plants.lookup.PiecewiseLinear`)."""
    i = bisect_right(xs, s) - 1
    return y0[i] + slope[i] * (s - xs[i])
