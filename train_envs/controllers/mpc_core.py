r"""Linear MPC quadratic-programming core (OSQP; condensed or sparse QP).

This module knows nothing about trains.  It turns a discrete linear model, a
quadratic tracking cost and box / polyhedral constraints into one quadratic
program (QP) per sampling instant and solves it with OSQP.  Every model-predictive
controller of the library is built on :class:`LinearMPC`.

Model
-----
.. math::

    x_{k+1} = A x_k + B u_k + d_k, \qquad y_k = C x_k,

with an optional affine term :math:`d_k` that may vary over the horizon
(linearised running resistance, gradient force, ...).  ``delta_u=True`` (the
default) uses the :math:`\Delta u`-augmented form of Maciejowski (2002, sec. 2.4)

.. math::

    \xi_k = \begin{bmatrix} x_k \\ u_{k-1} \end{bmatrix},\qquad
    \xi_{k+1} = \begin{bmatrix} A & B \\ 0 & I \end{bmatrix} \xi_k
              + \begin{bmatrix} B \\ I \end{bmatrix} \Delta u_k
              + \begin{bmatrix} d_k \\ 0 \end{bmatrix},

whose condensed decision variables are the increments
:math:`z = (\Delta u_0, \dots, \Delta u_{N_c-1})`; with ``delta_u=False`` they are
the absolute inputs :math:`z = (u_0, \dots, u_{N_c-1})`.  After the control
horizon the input is held (:math:`\Delta u_i = 0`, i.e. :math:`u_i = u_{N_c-1}`
for :math:`N_c \le i < N_p`).  The augmented prediction is written out as affine
maps of :math:`z`, the previous input :math:`u_{-1}` and the data:

.. math::

    U = T_z z + T_u u_{-1},\quad \Delta U = D_z z + D_u u_{-1},\quad
    X = \Phi x_0 + \Gamma U + \Gamma_d D,\quad Y = (I \otimes C) X,

with :math:`X = (x_1,\dots,x_{N_p})`, :math:`U = (u_0,\dots,u_{N_p-1})`.

QP
--
.. math::

    \min\ \sum_{i=1}^{N_p} \lVert y_i - r_i\rVert_Q^2
      + \sum_{i=0}^{N_c-1} \lVert \Delta u_i\rVert_R^2
      + \sum_{i=0}^{N_p-1} \lVert u_i - u^{\mathrm{ref}}_i\rVert_S^2
      + \lVert x_{N_p} - x^{\mathrm{ref}}_{N}\rVert_P^2
      + \sum_k \bigl(\rho_k \varepsilon_k + \gamma_k \varepsilon_k^2\bigr)

subject to

* hard input box   :math:`u_{\min} \le u_i \le u_{\max}` (:math:`i < N_c`; the held
  inputs equal :math:`u_{N_c-1}`) and hard rate box
  :math:`\Delta u_{\min} \le \Delta u_i \le \Delta u_{\max}`;
* soft output box  :math:`y_{\min,i} - \varepsilon \le y_i \le y_{\max,i} + \varepsilon`
  (:math:`i = 1..N_p`, bounds may vary per stage), soft polyhedra
  :math:`H_y y_i \le h_{y,i} + \varepsilon`, :math:`H_x x_i \le h_{x,i} + \varepsilon`,
  optional soft terminal box / polyhedron on :math:`x_{N_p}`;
* :math:`\varepsilon \ge 0`: one slack per constraint row and stage.

The linear slack cost is an *exact* (L1) penalty (Kerrigan & Maciejowski 2000):
when the hard-constrained problem is feasible and :math:`\rho_k` exceeds the
corresponding Lagrange multiplier, the soft QP returns the hard solution with
:math:`\varepsilon = 0`; otherwise the QP stays feasible and the violation is
minimised.  The quadratic :math:`\gamma_k \varepsilon_k^2` (default
:math:`\gamma_k = 0.01 \rho_k`) makes the QP strictly convex in
:math:`\varepsilon` and never changes the exactness threshold; for physically
small violations it is negligible next to :math:`\rho_k \varepsilon_k`, but it
matters for ADMM: in the closed loop of benchmark system (a) with
:math:`\rho = 10^5`, :math:`\gamma = 1` left about half of the steps with a
violated soft constraint unsolved after 4000 iterations (the QP then behaves like
a degenerate LP whose multipliers sit at :math:`\rho`); with
:math:`\gamma = 0.01\rho` all were solved.  A penalty of ``np.inf``
makes a row hard (no slack).  If the previous input lies outside
``[u_min, u_max]`` while rates are limited, the input bounds of the first stages
are relaxed to what the rate limits can reach, so the QP stays feasible.

Every vector that changes between sampling instants (``q``, the constraint
offsets, the predicted free response, the constant part of the cost) is linear in
the parameter vector
:math:`\theta = (1, x_0, u_{-1}, r, x^{\mathrm{ref}}_N, d, u^{\mathrm{ref}}, D)` and
is obtained from one pre-computed matrix-vector product per step.

Two QP forms
------------
* **condensed** -- decision :math:`w = (z, \varepsilon)`; dense Hessian
  :math:`2 E_z^\top W E_z` (``E_z``: sensitivities of all weighted residuals to
  ``z``) and dense constraint rows;
* **sparse** -- decision :math:`w = (X, U, \varepsilon)` with the dynamics as
  equality rows; it always uses absolute inputs (the :math:`\Delta u` cost and
  limits become banded rows), which is the same QP.  (Variables relative to the
  free response were tried: OSQP's relative tolerances then become tighter when
  states are large, and the mean solve time grew 1.7-6x on the benchmarks without
  a more accurate first move, so absolute states are kept.)

Both are shipped; they were measured with ``benchmarks/bench_mpc_core.py
--crossover`` (OSQP 1.1.3, default settings, closed loops of 600 steps with
reference changes and soft constraints that become active; one core of a shared
2-core VM, so absolute times are +-20 %; median / mean wall time of ``solve()``):

=====================================  ======================  ======================
system, horizon                        condensed (med / mean)  sparse (med / mean)
=====================================  ======================  ======================
4 states, 1 input, N = 10                  60 /    610 us          170 /  1095 us
4 states, 1 input, N = 20                 104 /   3349 us          341 /  3303 us
4 states, 1 input, N = 30                 155 /   6457 us          459 /  4836 us
2 states, 1 input, N = 30                 136 /   5207 us          341 /  4230 us
12 states, 6 inputs, N = 3                662 /    937 us          350 /   346 us
12 states, 6 inputs, N = 10              1830 /  17692 us         1834 /  2809 us
12 states, 6 inputs, N = 20              8885 / 101276 us         5399 /  8938 us
=====================================  ======================  ======================

The condensed QP has the fewest variables and the cheapest iterations and wins
the typical (median) step on single-input systems.  But its dense rows
(long-horizon sensitivities, cumulative sums in the :math:`\Delta u` form) are
badly conditioned for ADMM: during transients it needs hundreds to thousands of
iterations, each refactorisation of its dense KKT system is expensive, and the
mean time explodes with many inputs or long horizons (101 ms at N = 20 for the
12-state system).  The sparse QP keeps local, well-conditioned rows.  At the
default tolerance the condensed solution is the more accurate one (its dynamics
are exact; the sparse residuals include the dynamics rows): on a 12-state,
6-input train MPC with N = 3 the closed-loop metrics of the condensed form equal
those of a 1e-9-tolerance solve while the sparse ones differ by up to 5 %.
``form="auto"`` therefore picks condensed while it has few decision variables
(``Nc*m <= 20``; its size does not depend on ``n``, the sparse one grows with
``Np*n``) and sparse otherwise; ``form=`` overrides the choice.

Accuracy at the default tolerances (first move against a 1e-10-tolerance solve
along the benchmark closed loops, inputs in [-1, 1]): 4-state system median 1e-6,
worst 1e-2; 12-state system median 2e-3 (condensed) to 2e-2 (sparse, N = 10),
worst 5e-2.  OSQP's tolerances are relative to the largest entries of the problem
(here the exact penalty :math:`\rho = 10^5` in ``q``, large positions); tighten
``eps_rel``/``eps_abs``, set ``polishing=True`` or use a smaller ``soft_penalty``
where the plan itself must be exact.  Rescaling the slacks (penalty entry of
``q`` capped at 1e3) improved the worst case 30-100x but made ADMM fail on
violated problems, so it was not kept.

Solver
------
OSQP (Stellato, Banjac, Goulart, Bemporad & Boyd 2020) is set up once per
controller.  Each :meth:`LinearMPC.solve` only updates ``q``, ``l``, ``u`` and
warm-starts from the previous primal/dual solution shifted by one stage.
:meth:`LinearMPC.set_weights` / :meth:`LinearMPC.set_model` update the matrix
values (``Px``, ``Ax``) of a sparsity pattern fixed at construction: every block
a model or weight can touch is stored as a dense block (zeros included), so new
values never change the pattern.

Default OSQP settings: ``eps_abs = eps_rel = 1e-6``, ``max_iter = 4000``,
``polishing = False``, ``check_dualgap = False``, ``check_termination = 10``,
``verbose = False``.  OSQP 1.x also stops only on a small duality gap by default;
in the prototype closed loops that multiplied the iterations by 2-20 (e.g. median
25 -> 275 for the condensed 12-state system at N = 20) without changing the
residual guarantees, so it is off.  Checking termination every 10 instead of 25
iterations cut the median wall time by 22-29 % on the benchmark systems.

When OSQP does not converge (maximum iterations, inaccurate, spurious
infeasibility) :meth:`LinearMPC._rescue` continues from the last iterate with a
relaxed tolerance and OSQP's polishing and, failing that, runs an exact
active-set refinement whose KKT conditions are verified; only if everything fails
does the controller fall back to the shifted previous plan (``fallback=True``).

Speed notes
-----------
The python wrapper of OSQP 1.x costs ~15 us per ``update`` and ~25 us per
``solve`` call on top of the C solver (it clips the bounds and packs the ``info``
structure into a namespace).  For small problems that is more than the solve
itself, so this module calls the compiled solver object (``OSQP._solver``)
directly when it is available and falls back to the public API otherwise
(``LinearMPC(..., fast_osqp=False)`` forces the public API).

References
----------
* J. M. Maciejowski, *Predictive Control with Constraints*, Prentice Hall, 2002
  (condensed prediction, Delta-u augmented form, sec. 2.4 and 3.1).
* E. C. Kerrigan and J. M. Maciejowski, "Soft constraints and exact penalty
  functions in model predictive control", UKACC Int. Conf. Control, 2000.
* B. Stellato, G. Banjac, P. Goulart, A. Bemporad and S. Boyd, "OSQP: an
  operator splitting solver for quadratic programs", Math. Prog. Comp. 12,
  637-672, 2020.
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any

import numpy as np
import osqp
import scipy.linalg as sla
import scipy.sparse as sp
from numpy.typing import ArrayLike

_min_reduce = np.minimum.reduce

__all__ = [
    "LinearMPC",
    "MPCSolution",
    "UnconstrainedAffine",
    "UnconstrainedGain",
    "terminal_cost_dare",
    "terminal_cost_lyapunov",
]

_BIG = 1e30  # OSQP_INFTY: bounds beyond this are treated as infinite by OSQP
_SOLVED = 1
_SOLVED_INACCURATE = 2
# statuses worth a second, relaxed-and-polished attempt (time-limit hits are final)
_RESCUE = (2, 3, 4, 7)  # solved inaccurate, primal infeasible (+inaccurate), max iter
_UNCONSTRAINED = "solved (unconstrained)"
_STATUS_INVALID_INPUT = -1
_STATUS_EXCEPTION = -2

_DEFAULT_OSQP: dict[str, Any] = {
    "eps_abs": 1e-6,
    "eps_rel": 1e-6,
    "max_iter": 4000,
    "polishing": False,
    "check_dualgap": False,
    "check_termination": 10,
    "verbose": False,
    "warm_starting": True,
}
_RENAMED_SETTINGS = {"polish": "polishing", "warm_start": "warm_starting"}
_SOFT_GROUPS = ("y", "H_y", "H_x", "xN", "H_N")


# ---------------------------------------------------------------------------
# results
# ---------------------------------------------------------------------------
class MPCSolution:
    """Result of one :meth:`LinearMPC.solve` call.

    Attributes:
        u0: first input to apply (absolute), shape ``(m,)``; always finite and
            inside the input and rate bounds.
        du0: ``u0 - u_prev``, shape ``(m,)``.
        U: planned absolute inputs ``u_0 .. u_{Nc-1}``, shape ``(Nc, m)``.
        X: predicted states ``x_1 .. x_{Np}``, shape ``(Np, n)`` (NaN only if the
            inputs of :meth:`LinearMPC.solve` were not finite).
        Y: predicted outputs ``y_1 .. y_{Np}``, shape ``(Np, p)``.
        status: OSQP status string (``"solved"``, ``"solved inaccurate"``,
            ``"maximum iterations reached"``, ``"primal infeasible"``, ...),
            ``"solved (polished)"`` after a successful rescue (see
            :meth:`LinearMPC._rescue`), or ``"invalid input"`` / ``"solver error"``
            when OSQP was not (successfully) called.
        status_val: OSQP status value (1 solved or polished, 2 solved inaccurate,
            3 primal infeasible, 7 maximum iterations, 8 time limit, ...); -1 invalid
            (non-finite) input, -2 solver exception.
        iterations: ADMM iterations (all attempts).
        solve_time_s: OSQP's own solve time ``info.solve_time`` (plus its polish
            time when polishing is on, plus the rescue when one ran), seconds.
        overhead_s: wall time of :meth:`LinearMPC.solve` minus ``solve_time_s``
            (vector updates, warm start, result assembly), seconds.
        slack_max: largest soft-constraint violation (0 when all soft
            constraints hold), in the units of the constrained quantity.
        fallback: True when the QP solution was not used and ``u0`` comes from
            the shifted previous plan or from holding the previous input.
        cost: value of the MPC cost (including slack penalties) of the plan.
    """

    __slots__ = (
        "u0",
        "du0",
        "U",
        "_X",
        "_Y",
        "status",
        "status_val",
        "iterations",
        "solve_time_s",
        "overhead_s",
        "slack_max",
        "fallback",
        "cost",
        "_traj",
    )

    def __init__(
        self,
        u0: np.ndarray,
        du0: np.ndarray,
        U: np.ndarray,
        X: np.ndarray | None,
        Y: np.ndarray | None,
        status: str,
        status_val: int,
        iterations: int,
        solve_time_s: float,
        overhead_s: float,
        slack_max: float,
        fallback: bool,
        cost: float,
        traj: Any = None,
    ) -> None:
        self.u0, self.du0, self.U, self._X, self._Y = u0, du0, U, X, Y
        self.status, self.status_val, self.iterations = status, status_val, iterations
        self.solve_time_s, self.overhead_s = solve_time_s, overhead_s
        self.slack_max, self.fallback, self.cost = slack_max, fallback, cost
        # (callable returning (X, Y)): the predictions are assembled only when read
        self._traj = traj

    def _expand(self) -> None:
        self._X, self._Y = self._traj()
        self._traj = None

    @property
    def X(self) -> np.ndarray:
        if self._X is None and self._traj is not None:
            self._expand()
        return self._X

    @property
    def Y(self) -> np.ndarray:
        if self._Y is None and self._traj is not None:
            self._expand()
        return self._Y

    @property
    def ok(self) -> bool:
        """True when the QP was solved to the requested accuracy."""
        return self.status_val == _SOLVED and not self.fallback

    def __repr__(self) -> str:
        return (
            f"MPCSolution(u0={self.u0!r}, status={self.status!r}, iterations={self.iterations}, "
            f"solve_time_s={self.solve_time_s:.3g}, slack_max={self.slack_max:.3g}, "
            f"fallback={self.fallback}, cost={self.cost:.6g})"
        )


class _Predictions:
    """Deferred ``(X, Y)`` of one solve: copies of the QP solution and data it needs."""

    __slots__ = ("mpc", "x", "th")

    def __init__(self, mpc: LinearMPC, x: np.ndarray, th: np.ndarray) -> None:
        self.mpc, self.x = mpc, x
        self.th = None if mpc._sparse else th.copy()

    def __call__(self) -> tuple[np.ndarray, np.ndarray]:
        return self.mpc._predictions(self.x, self.th)


@dataclass(frozen=True)
class UnconstrainedGain:
    r"""Analytic first move of the unconstrained MPC (condensed normal equations).

    ``u0 = Kx x0 + Ku u_prev + Kr vec(y_ref) + Kd d + KD vec(D) + Kur vec(u_ref)
    + KxN x_ref_N``, where ``vec`` stacks the rows of the ``(Np, .)`` arrays, ``d`` is
    a constant affine term and ``D`` an ``(Np, n)`` sequence.  ``Kur`` / ``KxN`` are
    ``None`` when the controller has no ``S`` / state terminal weight.
    """

    Kx: np.ndarray
    Ku: np.ndarray
    Kr: np.ndarray
    Kd: np.ndarray
    KD: np.ndarray
    Kur: np.ndarray | None
    KxN: np.ndarray | None
    Np: int
    p: int
    Cpinv: np.ndarray  # default terminal reference x_ref_N = Cpinv @ y_ref[-1]

    def apply(
        self,
        x0: ArrayLike,
        u_prev: ArrayLike,
        y_ref: ArrayLike,
        d: ArrayLike | None = None,
        u_ref: ArrayLike | None = None,
        x_ref_N: ArrayLike | None = None,
    ) -> np.ndarray:
        """Evaluate the unconstrained first move for the given data."""
        m = self.Kx.shape[0]
        r = np.broadcast_to(np.asarray(y_ref, float), (self.Np, self.p))
        u = self.Kx @ np.asarray(x0, float) + self.Ku @ np.asarray(u_prev, float)
        u = u + self.Kr @ r.ravel()
        if d is not None:
            d_ = np.asarray(d, float)
            u = u + (self.Kd @ d_ if d_.ndim == 1 else self.KD @ d_.ravel())
        if self.Kur is not None and u_ref is not None:
            ur = np.broadcast_to(np.asarray(u_ref, float), (self.Np, m))
            u = u + self.Kur @ ur.ravel()
        if self.KxN is not None:
            xN = self.Cpinv @ r[-1] if x_ref_N is None else np.asarray(x_ref_N, float)
            u = u + self.KxN @ xN
        return u


@dataclass(frozen=True)
class UnconstrainedAffine:
    r"""The unconstrained optimum of a :class:`LinearMPC` as explicit functions of its data.

    With no active row the QP's optimum is affine in the data vector ``θ`` (the critical
    region of the empty active set of the multiparametric QP; Bemporad, Morari, Dua,
    Pistikopoulos, Automatica 38(1), 2002): ``z = Z θ`` (condensed decision, inputs pinned
    by the base bounds held at zero), the predicted states ``vec(X) = X θ`` (stages
    ``1..Np``, rows stacked), outputs ``vec(Y) = Y θ``, input plan ``vec(U) = U θ`` and
    the weighted residuals ``e = R θ`` of the cost, ``J = ‖R θ‖²`` (``MPCSolution.cost``:
    objective plus its data constant, here as a sum of squares: the solve forms it as
    the objective plus a constant, which cancel to its size, so for costs far below the
    constant this one is the more accurate).
    ``θ``'s layout is the controller's: ``θ[0] = 1`` and the named ``slots`` (index
    slices of ``x0``, ``up``, ``r``, ``xN``, ``d``, ``D``, ``ur``; ``r`` and ``D`` row
    major ``(Np, p)`` / ``(Np, n)``).  Valid while the weights and the pinned pattern
    are those it was made with (:meth:`LinearMPC.unconstrained_affine`); whether the
    optimum is feasible for given data is the caller's check.
    """

    Z: np.ndarray
    X: np.ndarray
    Y: np.ndarray
    U: np.ndarray
    R: np.ndarray
    slots: dict
    ntheta: int


# ---------------------------------------------------------------------------
# terminal-cost helpers
# ---------------------------------------------------------------------------
def terminal_cost_dare(
    A: ArrayLike, B: ArrayLike, Qx: ArrayLike, R: ArrayLike
) -> tuple[np.ndarray, np.ndarray]:
    r"""Infinite-horizon LQR terminal weight.

    Solves :math:`P = A^\top P A - A^\top P B (R + B^\top P B)^{-1} B^\top P A + Q_x`
    and returns ``(P, K)`` with :math:`K = (R + B^\top P B)^{-1} B^\top P A`
    (control law :math:`u = -K x`).
    """
    A_ = _matrix("A", A)
    n = A_.shape[0]
    if A_.shape != (n, n):
        raise ValueError(f"A must be square, got shape {A_.shape}")
    B_ = _matrix("B", B, column=True)
    if B_.shape[0] != n:
        raise ValueError(f"B must have {n} rows to match A, got shape {B_.shape}")
    m = B_.shape[1]
    Q_ = _weight("Qx", Qx, n)
    R_ = _weight("R", R, m)
    try:
        P = sla.solve_discrete_are(A_, B_, Q_, R_)
    except (np.linalg.LinAlgError, ValueError) as exc:
        raise ValueError(f"terminal_cost_dare: no stabilising solution ({exc})") from exc
    P = 0.5 * (P + P.T)
    K = np.linalg.solve(R_ + B_.T @ P @ B_, B_.T @ P @ A_)
    return P, K


def terminal_cost_lyapunov(A_cl: ArrayLike, Qx: ArrayLike) -> np.ndarray:
    r"""Terminal weight of a fixed stabilising closed loop :math:`x^+ = A_{cl} x`.

    Returns ``P`` with :math:`A_{cl}^\top P A_{cl} - P + Q_x = 0` (the cost-to-go
    :math:`\sum_k x_k^\top Q_x x_k`).  For a local law ``u = -K x`` pass
    ``A_cl = A - B K`` and ``Qx + K.T @ R @ K``.  Raises ``ValueError`` if
    ``A_cl`` is not Schur stable.
    """
    Acl = _matrix("A_cl", A_cl)
    n = Acl.shape[0]
    if Acl.shape != (n, n):
        raise ValueError(f"A_cl must be square, got shape {Acl.shape}")
    Q_ = _weight("Qx", Qx, n)
    rad = float(np.max(np.abs(np.linalg.eigvals(Acl)))) if n else 0.0
    if rad >= 1.0:
        raise ValueError(f"A_cl must be Schur stable (spectral radius {rad:.6g} >= 1)")
    P = sla.solve_discrete_lyapunov(Acl.T, Q_)
    return 0.5 * (P + P.T)


# ---------------------------------------------------------------------------
# validation helpers
# ---------------------------------------------------------------------------
def _matrix(name: str, value: ArrayLike, *, column: bool = False) -> np.ndarray:
    try:
        a = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a real matrix, got {value!r}") from exc
    if a.ndim == 0:
        a = a.reshape(1, 1)
    elif a.ndim == 1:
        a = a.reshape(-1, 1) if column else a.reshape(1, -1)
    if a.ndim != 2:
        raise ValueError(f"{name} must be a 2-D matrix, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must contain only finite values")
    return a


def _weight(name: str, value: ArrayLike, dim: int) -> np.ndarray:
    """Scalar, diagonal (vector) or full symmetric PSD weight -> (dim, dim) matrix."""
    try:
        w = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a real matrix, got {value!r}") from exc
    if w.ndim == 0:
        w = w * np.eye(dim)
    elif w.ndim == 1:
        if w.shape[0] != dim:
            raise ValueError(f"{name} must have shape ({dim},) or ({dim}, {dim}), got {w.shape}")
        w = np.diag(w)
    if w.shape != (dim, dim):
        raise ValueError(f"{name} must have shape ({dim}, {dim}), got {w.shape}")
    if not np.all(np.isfinite(w)):
        raise ValueError(f"{name} must contain only finite values")
    scale = max(1.0, float(np.max(np.abs(w)))) if dim else 1.0
    if np.max(np.abs(w - w.T), initial=0.0) > 1e-9 * scale:
        raise ValueError(f"{name} must be symmetric")
    w = 0.5 * (w + w.T)
    if dim and float(np.min(np.linalg.eigvalsh(w))) < -1e-10 * scale:
        raise ValueError(f"{name} must be positive semidefinite")
    return w


def _vector(name: str, value: ArrayLike, dim: int, *, allow_inf: bool = False) -> np.ndarray:
    try:
        v = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be real numbers, got {value!r}") from exc
    if v.ndim == 0:
        v = np.full(dim, float(v))
    if v.shape != (dim,):
        raise ValueError(f"{name} must have shape ({dim},), got {v.shape}")
    if np.any(np.isnan(v)) or (not allow_inf and not np.all(np.isfinite(v))):
        raise ValueError(f"{name} must contain only {'non-NaN' if allow_inf else 'finite'} values")
    return v


def _check_order(lo_name: str, lo: np.ndarray, hi_name: str, hi: np.ndarray) -> None:
    bad = np.flatnonzero(lo > hi)
    if bad.size:
        i = int(bad[0])
        raise ValueError(f"{lo_name}[{i}] ({lo[i]}) > {hi_name}[{i}] ({hi[i]})")


def _psd_sqrt(W: np.ndarray) -> np.ndarray:
    """Return L with L.T @ L == W for a symmetric PSD W (rows of zero weight dropped)."""
    lam, V = np.linalg.eigh(W)
    keep = lam > 1e-14 * max(1.0, float(np.max(np.abs(lam), initial=0.0)))
    return np.sqrt(lam[keep])[:, None] * V[:, keep].T


def _scaled_blocks(D: np.ndarray, X: np.ndarray) -> np.ndarray:
    """``np.kron(D, X)`` for a diagonal ``D``: the blocks ``D_ii X`` on the diagonal (the
    same products, without kron's general machinery; called at every weight change)."""
    k = D.shape[0]
    r, c = X.shape
    out = np.zeros((k, r, k, c))
    i = np.arange(k)
    out[i, :, i, :] = np.diag(D)[:, None, None] * X
    return out.reshape(k * r, k * c)


def _block_diag(parts: list[np.ndarray]) -> np.ndarray:
    """``scipy.linalg.block_diag`` of 2-D arrays (without its argument handling)."""
    rows = sum(a.shape[0] for a in parts)
    cols = sum(a.shape[1] for a in parts)
    out = np.zeros((rows, cols))
    r = c = 0
    for a in parts:
        out[r : r + a.shape[0], c : c + a.shape[1]] = a
        r += a.shape[0]
        c += a.shape[1]
    return out


def _csc_pattern(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Column-major (CSC) structure of a boolean mask: (rows, cols, indptr, indices)."""
    cols, rows = np.nonzero(mask.T)
    indptr = np.zeros(mask.shape[1] + 1, dtype=np.int64)
    np.cumsum(np.bincount(cols, minlength=mask.shape[1]), out=indptr[1:])
    return rows, cols, indptr, rows.astype(np.int64)


def _as_slice(idx: np.ndarray) -> slice | np.ndarray | None:
    """``idx`` (sorted, unique) as a slice when contiguous (basic indexing gives views)."""
    if idx.size == 0:
        return None
    if idx[-1] - idx[0] + 1 == idx.size:
        return slice(int(idx[0]), int(idx[-1]) + 1)
    return idx


def _bound_label(name: str, side: int) -> str:
    """User-facing name of a per-call bound (``y_min``, ``y_max``, ``h_y``, ``h_x``)."""
    if name == "y":
        return "y_max" if side else "y_min"
    return "h" + name[1:]


class _Group:
    """One family of output/state constraints (before the soft/hard split)."""

    def __init__(
        self,
        name: str,
        on: str,
        stages: np.ndarray,
        G: np.ndarray,
        lo: np.ndarray,
        hi: np.ndarray,
        rho: np.ndarray,
        two_sided: bool,
        cols: np.ndarray,
        dim_full: int,
    ) -> None:
        self.name = name
        self.on = on  # "x" or "y"
        self.stages = stages  # 1-based prediction stages
        self.G = G  # (r, n or p)
        self.lo = lo
        self.hi = hi
        self.rho = rho  # per row; inf -> hard
        self.two_sided = two_sided
        self.cols = cols  # original rows kept (indices into the construction-time rows)
        self.dim_full = dim_full  # number of construction-time rows (before dropping)
        self.lb_pos = np.empty((0, 0), dtype=np.int64)  # (stages, r) index into bound prefix
        self.ub_pos = np.empty((0, 0), dtype=np.int64)


# ---------------------------------------------------------------------------
# OSQP access
# ---------------------------------------------------------------------------
_Stats = tuple[int, str, int, float, float, int]


class _Backend:
    """Thin OSQP adapter: compiled solver object when available, public API otherwise."""

    def __init__(
        self,
        P: sp.csc_matrix,
        q: np.ndarray,
        A: sp.csc_matrix,
        l: np.ndarray,  # noqa: E741
        u: np.ndarray,
        settings: dict[str, Any],
        fast: bool,
    ) -> None:
        self.prob = osqp.OSQP()
        try:
            self.prob.setup(P, q, A, l, u, **settings)
        except ValueError as exc:
            raise ValueError(f"osqp_settings rejected by OSQP: {exc}") from exc
        self.polishing = bool(settings.get("polishing", False))
        self.rho0 = float(settings.get("rho", 0.1))  # OSQP's default initial rho
        self._status_names: dict[int, str] = {}
        raw = getattr(self.prob, "_solver", None)
        needed = ("update_data_vec", "update_data_mat", "warm_start", "solve", "solution", "info")
        self.raw = (
            raw if fast and raw is not None and all(hasattr(raw, a) for a in needed) else None
        )

    def update_vec(self, q: np.ndarray, l: np.ndarray, u: np.ndarray) -> int:  # noqa: E741
        if self.raw is not None:
            return int(self.raw.update_data_vec(q, l, u))
        self.prob.update(q=q, l=l, u=u)
        return 0

    def update_mat(self, Px: np.ndarray, Ax: np.ndarray) -> None:
        if self.raw is not None:
            rc = self.raw.update_data_mat(Px, None, Ax, None)
            if rc:
                raise RuntimeError(f"OSQP rejected the matrix update (error {rc})")
        else:
            self.prob.update(Px=Px, Ax=Ax)

    def warm_start(self, x: np.ndarray, y: np.ndarray) -> None:
        if self.raw is not None:
            self.raw.warm_start(x, y)
        else:
            self.prob.warm_start(x=x, y=y)

    def solve(self) -> tuple[np.ndarray, np.ndarray, _Stats]:
        """Run OSQP; return ``x, y`` and ``(status_val, status, iter, time, obj, polish)``."""
        if self.raw is not None:
            raw = self.raw
            raw.solve()
            sol = raw.solution
            info = raw.info
            x, y = sol.x, sol.y
        else:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", PendingDeprecationWarning)
                res = self.prob.solve(raise_error=False)
            info = res.info
            x, y = res.x, res.y
        val = int(info.status_val)
        status = self.status_name(val, info)
        if self.polishing:
            t = info.solve_time + info.polish_time
            polished = int(info.status_polish)
        else:
            t = info.solve_time
            polished = 0
        return x, y, (val, status, int(info.iter), t, info.obj_val, polished)

    def status_name(self, val: int, info: Any) -> str:
        """OSQP status string of ``val`` (cached: reading it from ``info`` is slow)."""
        name = self._status_names.get(val)
        if name is None:
            name = self._status_names[val] = str(info.status)
        return name

    def rescue(
        self, x: np.ndarray, y: np.ndarray, eps: float, polishing: bool, restore: dict[str, Any]
    ) -> tuple[np.ndarray, np.ndarray, _Stats]:
        """Continue from ``(x, y)`` with tolerance ``eps`` and polishing, then restore settings."""
        self.prob.update_settings(eps_abs=eps, eps_rel=eps, polishing=polishing)
        self.polishing = polishing
        try:
            self.warm_start(x, y)
            return self.solve()
        finally:
            self.prob.update_settings(**restore)
            self.polishing = bool(restore.get("polishing", False))


# ---------------------------------------------------------------------------
# controller
# ---------------------------------------------------------------------------
class LinearMPC:
    r"""Linear MPC solved with OSQP (see the module docstring for the QP).

    Typical loop::

        mpc = LinearMPC(A, B, C, Np=20, Q=Q, R=R, u_min=-1, u_max=1, du_min=-0.1,
                        du_max=0.1, y_max=[v_max], soft_penalty=1e5)
        sol = mpc.solve(x, u_prev, y_ref, d=d)   # never raises on solver failure
        u_prev = sol.u0                          # finite, inside box and rate window

    Args:
        A, B, C: model matrices, shapes ``(n, n)``, ``(n, m)``, ``(p, n)``;
            ``C=None`` means ``C = I`` (state tracking).
        Np: prediction horizon (>= 1).  Nc: control horizon, ``1 <= Nc <= Np``
            (default ``Np``); inputs are held after ``Nc``.
        Q: output weight ``(p, p)`` (scalar or diagonal vector accepted).
        R: weight on input increments ``Delta u`` ``(m, m)``.
        S: optional weight on input levels ``u_i - u_ref_i`` ``(m, m)``.
        P: optional terminal weight: ``(n, n)`` on ``x_Np - x_ref_N``
            (``terminal="state"``, default) or ``(p, p)`` on ``y_Np - r_Np``
            (``terminal="output"``).
        u_min, u_max: hard input bounds ``(m,)`` (scalars broadcast; +-inf allowed).
        du_min, du_max: hard increment bounds ``(m,)``; ``None`` = unbounded.
        y_min, y_max: output box ``(p,)`` at stages ``1..Np``; rows with both
            bounds infinite are dropped (they cannot be given per-stage values
            later).
        H_y, h_y: output polyhedron ``H_y y_i <= h_y`` (``(r, p)``, ``(r,)``).
        H_x, h_x: state polyhedron ``H_x x_i <= h_x`` (``(r, n)``, ``(r,)``).
        xN_min, xN_max, H_N, h_N: terminal state box / polyhedron at ``x_Np``.
        soft_penalty: exact-penalty weight rho: a scalar for all output/state
            constraints, or a mapping with keys ``"y"``, ``"H_y"``, ``"H_x"``,
            ``"xN"``, ``"H_N"`` whose values are scalars or per-row vectors
            (missing keys use 1e5).  ``np.inf`` makes a row hard.
        soft_quadratic: gamma of the strictly convex term ``gamma_k * eps_k^2``; ``None``
            (default) uses ``gamma_k = 0.01 * rho_k`` per row.  For physically small
            violations this term is negligible next to ``rho_k * eps_k`` (it never
            changes the exact-penalty threshold), but its curvature makes violated
            problems far easier for ADMM (see the module docstring).
        delta_u: condensed decision variables are the increments (default) or the
            absolute inputs; both give the same optimum.  The sparse form always
            uses absolute inputs as variables.
        terminal: ``"state"`` or ``"output"`` (what ``P`` weights).
        osqp_settings: overrides of the default OSQP settings (``eps_abs``,
            ``eps_rel``, ``max_iter``, ``polishing``, ``time_limit``, ...).
        fast_osqp: call OSQP's compiled solver object directly (default True).
        unconstrained_first: (condensed form) before calling OSQP, take the
            unconstrained minimiser ``z = −H⁻¹ q`` and keep it when it satisfies every
            constraint row -- then it *is* the QP's optimum (strictly convex cost, zero
            slacks), reported with status ``"solved (unconstrained)"``, zero iterations
            and zero solve time.  Otherwise OSQP runs as usual, warm-started as always.
            Off by default; worth it where constraints are rarely active.
        warm_start: ``"shift"`` (default): start OSQP from the previous primal/dual
            solution shifted by one stage; ``"previous"``: from the previous
            solution as is; ``"none"``: let OSQP start from its last iterate.
        rescue: on a non-converged solve, try the relaxed/polished second attempt
            and the exact active-set refinement before falling back (default True;
            see :meth:`_rescue`).
        form: ``"condensed"``, ``"sparse"`` or ``"auto"`` (default; condensed for
            ``Nc*m <= 20``, see the module docstring).
        stage_scales: optional per-stage weight multipliers ``{"Q": (Np,), "R": (Nc,),
            "S": (Np,)}`` (entries >= 0; missing keys = 1): the cost terms of stage
            ``i`` are multiplied by ``c_i`` -- time-varying weights, e.g. the ``1/beta``
            weighting of the held stages of self-triggered MPC.
    """

    def __init__(
        self,
        A: ArrayLike,
        B: ArrayLike,
        C: ArrayLike | None = None,
        *,
        Np: int,
        Nc: int | None = None,
        Q: ArrayLike,
        R: ArrayLike,
        S: ArrayLike | None = None,
        P: ArrayLike | None = None,
        u_min: ArrayLike,
        u_max: ArrayLike,
        du_min: ArrayLike | None = None,
        du_max: ArrayLike | None = None,
        y_min: ArrayLike | None = None,
        y_max: ArrayLike | None = None,
        H_y: ArrayLike | None = None,
        h_y: ArrayLike | None = None,
        H_x: ArrayLike | None = None,
        h_x: ArrayLike | None = None,
        xN_min: ArrayLike | None = None,
        xN_max: ArrayLike | None = None,
        H_N: ArrayLike | None = None,
        h_N: ArrayLike | None = None,
        soft_penalty: float | Mapping[str, float | ArrayLike] = 1e5,
        soft_quadratic: float | None = None,
        delta_u: bool = True,
        terminal: str = "state",
        osqp_settings: Mapping[str, Any] | None = None,
        fast_osqp: bool = True,
        unconstrained_first: bool = False,
        warm_start: str = "shift",
        rescue: bool = True,
        form: str = "auto",
        stage_scales: Mapping[str, ArrayLike] | None = None,
    ) -> None:
        # ---- model ---------------------------------------------------------
        A_, B_, C_ = self._check_model(A, B, C, None)
        n, m, p = A_.shape[0], B_.shape[1], C_.shape[0]
        self.n, self.m, self.p = n, m, p
        self._A, self._B, self._C = A_, B_, C_

        if isinstance(Np, bool) or not isinstance(Np, int | np.integer) or Np < 1:
            raise ValueError(f"Np must be an integer >= 1, got {Np!r}")
        Nc = Np if Nc is None else Nc
        if isinstance(Nc, bool) or not isinstance(Nc, int | np.integer) or not 1 <= Nc <= Np:
            raise ValueError(f"Nc must be an integer with 1 <= Nc <= Np ({Np}), got {Nc!r}")
        self.Np, self.Nc = int(Np), int(Nc)
        self.delta_u = bool(delta_u)
        if terminal not in ("state", "output"):
            raise ValueError(f"terminal must be 'state' or 'output', got {terminal!r}")
        self.terminal = terminal

        # ---- weights -------------------------------------------------------
        self._Q = _weight("Q", Q, p)
        self._R = _weight("R", R, m)
        self._S = None if S is None else _weight("S", S, m)
        self._P = None if P is None else _weight("P", P, n if terminal == "state" else p)
        self._gamma = None if soft_quadratic is None else self._check_gamma(soft_quadratic)

        # ---- input constraints ---------------------------------------------
        self._umin = _vector("u_min", u_min, m, allow_inf=True)
        self._umax = _vector("u_max", u_max, m, allow_inf=True)
        _check_order("u_min", self._umin, "u_max", self._umax)
        self._dumin = (
            np.full(m, -np.inf) if du_min is None else _vector("du_min", du_min, m, allow_inf=True)
        )
        self._dumax = (
            np.full(m, np.inf) if du_max is None else _vector("du_max", du_max, m, allow_inf=True)
        )
        _check_order("du_min", self._dumin, "du_max", self._dumax)
        self._has_du = bool(np.any(np.isfinite(self._dumin)) or np.any(np.isfinite(self._dumax)))
        self._umin_l, self._umax_l = self._umin.tolist(), self._umax.tolist()
        self._dumin_l, self._dumax_l = self._dumin.tolist(), self._dumax.tolist()
        self._ncm, self._npn = self.Nc * m, self.Np * n
        if warm_start not in ("shift", "previous", "none"):
            raise ValueError(
                f"warm_start must be 'shift', 'previous' or 'none', got {warm_start!r}"
            )
        self._ws_mode = warm_start
        self._rescue_on = bool(rescue)
        if form not in ("auto", "condensed", "sparse"):
            raise ValueError(f"form must be 'auto', 'condensed' or 'sparse', got {form!r}")
        if form == "auto":
            form = self._auto_form(self.Np, self.Nc, n, m)
        self.form = form
        self._sparse = form == "sparse"
        self._zdu = self.delta_u and not self._sparse

        # ---- output / state constraints --------------------------------------
        self._groups = self._make_groups(
            y_min, y_max, H_y, h_y, H_x, h_x, xN_min, xN_max, H_N, h_N, soft_penalty
        )

        # ---- OSQP settings ---------------------------------------------------
        settings = dict(_DEFAULT_OSQP)
        for k, v in dict(osqp_settings or {}).items():
            settings[_RENAMED_SETTINGS.get(k, k)] = v
        self.osqp_settings = settings

        self._stage_scales = self._check_stage_scales(stage_scales)
        self._layout()
        self._build()
        P0 = sp.csc_matrix(
            (self._P_dense[self._P_rows, self._P_cols], self._P_ind, self._P_ptr),
            shape=(self._nv, self._nv),
        )
        A0 = sp.csc_matrix(
            (self._A_dense[self._A_rows, self._A_cols], self._A_ind, self._A_ptr),
            shape=(self._nA, self._nv),
        )
        self._backend = _Backend(P0, self._q_init(), A0, self._l, self._u, settings, fast_osqp)
        self._unc_first = bool(unconstrained_first) and not self._sparse
        self.reset()

    @staticmethod
    def _auto_form(Np: int, Nc: int, n: int, m: int) -> str:
        """QP form chosen by ``form="auto"`` (measured crossover, see the module docstring).

        Condensed for few decision variables (``Nc*m <= 20``), sparse otherwise.  The
        state dimension does not enter: the condensed QP does not grow with ``n``
        (e.g. a DMC FIR register), while the sparse one does.
        """
        del Np, n
        return "condensed" if Nc * m <= 20 else "sparse"

    # ------------------------------------------------------------------ checks
    def _check_model(
        self, A: ArrayLike, B: ArrayLike, C: ArrayLike | None, dims: tuple[int, int, int] | None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        A_ = _matrix("A", A)
        n = A_.shape[0]
        if A_.shape != (n, n):
            raise ValueError(f"A must be square, got shape {A_.shape}")
        if dims is not None and n != dims[0]:
            raise ValueError(
                f"set_model must keep the dimensions (n, m, p) = {dims}, got A {A_.shape}"
            )
        B_ = _matrix("B", B, column=True)
        if B_.shape[0] != n:
            raise ValueError(f"B must have shape ({n}, m) to match A, got {B_.shape}")
        C_ = np.eye(n) if C is None else _matrix("C", C)
        if C_.shape[1] != n:
            raise ValueError(f"C must have shape (p, {n}) to match A, got {C_.shape}")
        if dims is not None and (n, B_.shape[1], C_.shape[0]) != dims:
            raise ValueError(
                f"set_model must keep the dimensions (n, m, p) = {dims}, "
                f"got {(n, B_.shape[1], C_.shape[0])}"
            )
        return A_, B_, C_

    @staticmethod
    def _check_gamma(value: float) -> float:
        g = float(value)
        if not math.isfinite(g) or g < 0:
            raise ValueError(f"soft_quadratic must be finite and >= 0, got {value!r}")
        return g

    @staticmethod
    def _penalty(name: str, soft_penalty: Any, rows: int) -> np.ndarray:
        if isinstance(soft_penalty, Mapping):
            unknown = set(soft_penalty) - set(_SOFT_GROUPS)
            if unknown:
                raise ValueError(
                    f"soft_penalty keys must be among {_SOFT_GROUPS}, got {sorted(unknown)}"
                )
            val = soft_penalty.get(name, 1e5)
        else:
            val = soft_penalty
        rho = _vector(f"soft_penalty[{name!r}]", val, rows, allow_inf=True)
        if np.any(rho <= 0):
            raise ValueError(f"soft_penalty[{name!r}] must be > 0 (np.inf for hard), got {rho}")
        return rho

    def _make_groups(
        self,
        y_min: ArrayLike | None,
        y_max: ArrayLike | None,
        H_y: ArrayLike | None,
        h_y: ArrayLike | None,
        H_x: ArrayLike | None,
        h_x: ArrayLike | None,
        xN_min: ArrayLike | None,
        xN_max: ArrayLike | None,
        H_N: ArrayLike | None,
        h_N: ArrayLike | None,
        soft_penalty: Any,
    ) -> list[_Group]:
        n, p, Np = self.n, self.p, self.Np
        _check_penalty_arg(soft_penalty)
        groups: list[_Group] = []
        all_stages = np.arange(1, Np + 1)

        def box(name: str, lo_v: Any, hi_v: Any, dim: int, on: str, stages: np.ndarray) -> None:
            if lo_v is None and hi_v is None:
                return
            lo_name, hi_name = {"y": ("y_min", "y_max"), "xN": ("xN_min", "xN_max")}[name]
            lo = (
                np.full(dim, -np.inf)
                if lo_v is None
                else _vector(lo_name, lo_v, dim, allow_inf=True)
            )
            hi = (
                np.full(dim, np.inf)
                if hi_v is None
                else _vector(hi_name, hi_v, dim, allow_inf=True)
            )
            _check_order(lo_name, lo, hi_name, hi)
            rho = self._penalty(name, soft_penalty, dim)
            keep = np.flatnonzero(np.isfinite(lo) | np.isfinite(hi))
            if keep.size:
                G = np.eye(dim)[keep]
                groups.append(
                    _Group(name, on, stages, G, lo[keep], hi[keep], rho[keep], True, keep, dim)
                )

        def poly(name: str, H: Any, h: Any, dim: int, on: str, stages: np.ndarray) -> None:
            if H is None and h is None:
                return
            hn = "h" + name[1:]
            if H is None or h is None:
                raise ValueError(f"{name} and {hn} must be given together")
            H_ = _matrix(name, H)
            if H_.shape[1] != dim:
                raise ValueError(f"{name} must have shape (r, {dim}), got {H_.shape}")
            r = H_.shape[0]
            h_ = _vector(hn, h, r, allow_inf=True)
            if np.any(h_ == -np.inf):
                raise ValueError(f"{hn} must not contain -inf (the constraint could never hold)")
            rho = self._penalty(name, soft_penalty, r)
            keep = np.flatnonzero(np.isfinite(h_))
            if keep.size:
                groups.append(
                    _Group(
                        name,
                        on,
                        stages,
                        H_[keep],
                        np.full(keep.size, -np.inf),
                        h_[keep],
                        rho[keep],
                        False,
                        keep,
                        r,
                    )
                )

        box("y", y_min, y_max, p, "y", all_stages)
        poly("H_y", H_y, h_y, p, "y", all_stages)
        poly("H_x", H_x, h_x, n, "x", all_stages)
        box("xN", xN_min, xN_max, n, "x", np.array([Np]))
        poly("H_N", H_N, h_N, n, "x", np.array([Np]))
        return groups

    # ------------------------------------------------------------------ layout
    def _layout(self) -> None:
        """Fix the variable/row layout, sparsity patterns and parameter slots."""
        n, m, Np, Nc = self.n, self.m, self.Np, self.Nc
        nz = Nc * m
        self._nz = nz
        sparse = self._sparse
        nxv = Np * n if sparse else 0  # state variables (sparse form only)
        self._nxv = nxv

        # parameter vector theta = [1, x0, u_prev, r, (xN), d, (u_ref), D]
        slots: dict[str, slice] = {}
        pos = 0
        for name, size, present in (
            ("one", 1, True),
            ("x0", n, True),
            ("up", m, True),
            ("r", Np * self.p, True),
            ("xN", n, self._P is not None and self.terminal == "state"),
            ("d", n, True),
            ("ur", Np * m, self._S is not None),
            ("D", Np * n, True),
        ):
            if present:
                slots[name] = slice(pos, pos + size)
                pos += size
        self._slots = slots
        self._ntheta = pos
        self._nb = slots["D"].start  # parameters without the D sequence

        # output/state constraint rows: (group, stage, row-in-group) ----------------
        con_g, con_s, con_r, con_lo, con_hi, con_rho, con_two = [], [], [], [], [], [], []
        for gi, g in enumerate(self._groups):
            R_ = g.G.shape[0]
            K = g.stages.size
            con_g.append(np.full(K * R_, gi))
            con_s.append(np.repeat(g.stages, R_))
            con_r.append(np.tile(np.arange(R_), K))
            con_lo.append(np.tile(g.lo, K))
            con_hi.append(np.tile(g.hi, K))
            con_rho.append(np.tile(g.rho, K))
            con_two.append(np.full(K * R_, g.two_sided))

        def cat(parts: list[np.ndarray], dtype: Any) -> np.ndarray:
            return np.concatenate(parts).astype(dtype) if parts else np.zeros(0, dtype)

        cg, cs, cr = cat(con_g, np.int64), cat(con_s, np.int64), cat(con_r, np.int64)
        clo, chi, crho = cat(con_lo, float), cat(con_hi, float), cat(con_rho, float)
        ctwo = cat(con_two, bool)
        soft = np.isfinite(crho)
        hard_c = np.flatnonzero(~soft)
        soft_c = np.flatnonzero(soft)
        soft2_c = soft_c[ctwo[soft_c]]  # soft rows that also get a lower-side row
        self._con = {"g": cg, "s": cs, "r": cr, "lo": clo, "hi": chi, "rho": crho}
        self._hard_c, self._soft_c, self._soft2_c = hard_c, soft_c, soft2_c
        self._soft2_slack = np.searchsorted(soft_c, soft2_c)
        ns = soft_c.size
        self._ns = ns
        self._oz = nxv  # first input variable
        self._oe = nxv + nz  # first slack variable
        self._nv = nxv + nz + ns

        # row layout: [dynamics (sparse) | hard | soft upper | soft lower | eps >= 0] ----
        r0 = nxv
        n_u = nz
        n_du = nz if self._has_du else 0
        o = r0 + n_u + n_du  # first hard output/state row
        nh = o + hard_c.size
        self._r0, self._nh = r0, nh
        self._nlu = nh + ns + soft2_c.size  # rows whose bounds may change per step
        self._nA = self._nlu + ns
        # rows whose offsets depend on theta (condensed: all; sparse: dynamics, input and
        # rate rows -- the state/output rows act on the variables and have fixed bounds)
        self._off = slice(0, self._nlu if not sparse else o)

        Lb = np.zeros(self._nlu)
        Ub = np.zeros(self._nlu)
        Lb[r0 : r0 + n_u] = np.tile(self._umin, Nc)
        Ub[r0 : r0 + n_u] = np.tile(self._umax, Nc)
        if n_du:
            Lb[r0 + n_u : o] = np.tile(self._dumin, Nc)
            Ub[r0 + n_u : o] = np.tile(self._dumax, Nc)
        Lb[o:nh] = clo[hard_c]
        Ub[o:nh] = chi[hard_c]
        Lb[nh : nh + ns] = -np.inf
        Ub[nh : nh + ns] = chi[soft_c]
        Lb[nh + ns :] = clo[soft2_c]
        Ub[nh + ns :] = np.inf
        # lower/upper bounds are rows of 2-D arrays so one ufunc call updates both
        self._LUb0 = np.clip(np.vstack([Lb, Ub]), -_BIG, _BIG)
        self._LUb = self._LUb0.copy()
        self._Lb0, self._Ub0 = self._LUb0[0], self._LUb0[1]
        self._Lb, self._Ub = self._LUb[0], self._LUb[1]
        self._bounds_dirty = False
        self._LU = np.empty((2, self._nA))
        self._l, self._u = self._LU[0], self._LU[1]
        self._LU[:, : self._nlu] = self._LUb0
        self._l[self._nlu :] = 0.0
        self._u[self._nlu :] = _BIG
        kk = np.arange(1, Nc + 1, dtype=float)[:, None]
        off = self._off  # views used by solve()
        self._Lb_off, self._Ub_off = self._Lb[off], self._Ub[off]
        self._l_off, self._u_off = self._l[off], self._u[off]
        self._k_dumax = kk * self._dumax[None, :]  # (Nc, m): reach of k rate-limited steps
        self._k_dumin = kk * self._dumin[None, :]
        self._umin_t = np.tile(self._umin, (Nc, 1))
        self._umax_t = np.tile(self._umax, (Nc, 1))

        # positions of each group's (stage, row) in the bound prefix (for overrides)
        hard_pos = np.full(cg.size, -1)
        hard_pos[hard_c] = o + np.arange(hard_c.size)
        up_pos = np.full(cg.size, -1)
        up_pos[soft_c] = nh + np.arange(ns)
        lo_pos = np.full(cg.size, -1)
        lo_pos[soft2_c] = nh + ns + np.arange(soft2_c.size)
        ub_all = np.where(hard_pos >= 0, hard_pos, up_pos)
        lb_all = np.where(hard_pos >= 0, hard_pos, lo_pos)
        for gi, g in enumerate(self._groups):
            idx = np.flatnonzero(cg == gi)
            shape = (g.stages.size, g.G.shape[0])
            g.ub_pos = ub_all[idx].reshape(shape)
            g.lb_pos = lb_all[idx].reshape(shape)

        # input parametrisation (decision z: increments in the condensed Delta-u form,
        # absolute inputs otherwise; the sparse form always uses absolute inputs)
        if self._zdu:
            Tz_c = np.kron(np.tril(np.ones((Nc, Nc))), np.eye(m))
            Dz = np.eye(nz)
        else:
            Tz_c = np.eye(nz)
            Dz = np.eye(nz) - np.eye(nz, k=-m)
        self._Tz_c, self._Dz = Tz_c, Dz

        # sparsity patterns: every entry a model/weight change could touch --------------
        oz, oe = self._oz, self._oe
        Amask = np.zeros((self._nA, self._nv), dtype=bool)
        Amask[r0 : r0 + n_u, oz : oz + nz] = Tz_c != 0
        if n_du:
            Amask[r0 + n_u : o, oz : oz + nz] = Dz != 0
        con_rows = np.concatenate([hard_c, soft_c, soft2_c])
        con_at = np.concatenate([np.arange(o, nh), np.arange(nh, self._nlu)])
        if sparse:
            hold = np.minimum(np.arange(Np), Nc - 1)
            for t in range(Np):  # -x_{t+1} + A x_t + B u_t + offset = 0
                rows = slice(t * n, (t + 1) * n)
                Amask[rows, t * n : (t + 1) * n] |= np.eye(n, dtype=bool)
                if t:
                    Amask[rows, (t - 1) * n : t * n] = True
                Amask[rows, oz + hold[t] * m : oz + (hold[t] + 1) * m] = True
            for k, rr in zip(con_rows, con_at, strict=True):  # dense block on x_stage
                st = cs[k] - 1
                Amask[rr, st * n : (st + 1) * n] = True
        else:
            # z-block j influences stage i iff j <= i - 1
            blk = np.arange(nz) // m
            Amask[con_at, :nz] = blk[None, :] <= (cs[con_rows, None] - 1)
        sl = np.arange(ns)
        Amask[nh + sl, oe + sl] = True
        if soft2_c.size:
            Amask[nh + ns + np.arange(soft2_c.size), oe + self._soft2_slack] = True
        Amask[self._nlu + sl, oe + sl] = True
        Pmask = np.zeros((self._nv, self._nv), dtype=bool)
        Pmask[oz : oz + nz, oz : oz + nz] = np.triu(np.ones((nz, nz), dtype=bool))
        if sparse:
            blk_n = np.triu(np.ones((n, n), dtype=bool))
            for t in range(Np):
                Pmask[t * n : (t + 1) * n, t * n : (t + 1) * n] = blk_n
        Pmask[oe + sl, oe + sl] = True
        self._Amask, self._Pmask = Amask, Pmask
        self._A_rows, self._A_cols, self._A_ptr, self._A_ind = _csc_pattern(Amask)
        self._P_rows, self._P_cols, self._P_ptr, self._P_ind = _csc_pattern(Pmask)

        # warm-start shift maps --------------------------------------------------------
        key_to_con = {
            (g_, s_, r_): k for k, (g_, s_, r_) in enumerate(zip(cg, cs, cr, strict=True))
        }

        def next_con(k: int) -> int:
            return key_to_con.get((cg[k], cs[k] + 1, cr[k]), k)

        soft_index = {int(c): i for i, c in enumerate(soft_c)}
        soft2_index = {int(c): i for i, c in enumerate(soft2_c)}
        hard_index = {int(c): i for i, c in enumerate(hard_c)}
        esrc = np.array([soft_index[next_con(int(c))] for c in soft_c], dtype=np.int64)
        stage_next = np.minimum(np.arange(Np) + 1, Np - 1)
        xsrc = (stage_next[:, None] * n + np.arange(n)[None, :]).ravel() if sparse else []
        zsrc = np.arange(nz) + m
        zsrc[-m:] = self._nv if self._zdu else np.arange(nz - m, nz)  # nv -> appended 0
        zsrc[: nz - m] += oz
        if not self._zdu:
            zsrc[-m:] += oz
        self._xshift = np.concatenate([np.asarray(xsrc, dtype=np.int64), zsrc, oe + esrc]).astype(
            np.int64
        )
        ysrc = np.arange(self._nA)
        if sparse:
            ysrc[:r0] = xsrc
        ublk = np.arange(n_u) + m
        ublk[-m:] -= m
        ysrc[r0 : r0 + n_u] = r0 + ublk
        if n_du:
            ysrc[r0 + n_u : o] = r0 + n_u + ublk
        ysrc[o:nh] = [o + hard_index[next_con(int(c))] for c in hard_c]
        ysrc[nh : nh + ns] = nh + esrc
        ysrc[nh + ns : self._nlu] = [nh + ns + soft2_index[next_con(int(c))] for c in soft2_c]
        ysrc[self._nlu :] = self._nlu + esrc
        self._yshift = ysrc.astype(np.int64)

    # ------------------------------------------------------------------ build
    def _sel(self, name: str, ntheta: int) -> np.ndarray:
        s = self._slots[name]
        M = np.zeros((s.stop - s.start, ntheta))
        M[:, s] = np.eye(s.stop - s.start)
        return M

    def _structure(self) -> SimpleNamespace:
        """The weight-independent part of :meth:`_build`: condensed prediction matrices and
        the constraint rows on ``z`` (made once per model; weight changes reuse it)."""
        st = self.__dict__.get("_struct")
        if st is not None:
            return st
        n, m, p, Np, Nc, nz = self.n, self.m, self.p, self.Np, self.Nc, self._nz
        A, B, C = self._A, self._B, self._C
        nt = self._ntheta
        sel = self._sel
        # condensed prediction -------------------------------------------------------
        powers = [np.eye(n)]
        for _ in range(Np):
            powers.append(A @ powers[-1])
        Phi = np.vstack(powers[1:])
        Gam = np.zeros((Np * n, Np * m))
        GamD = np.zeros((Np * n, Np * n))
        for i in range(Np):  # x_{i+1}
            for t in range(i + 1):
                Gam[i * n : (i + 1) * n, t * m : (t + 1) * m] = powers[i - t] @ B
                GamD[i * n : (i + 1) * n, t * n : (t + 1) * n] = powers[i - t]
        hold = np.minimum(np.arange(Np), Nc - 1)  # stage t uses block hold[t]
        if self._zdu:
            blocks = (np.arange(Nc)[None, :] <= hold[:, None]).astype(float)
            Tu = np.kron(np.ones((Np, 1)), np.eye(m))
            Du = np.zeros((nz, m))
        else:
            blocks = (np.arange(Nc)[None, :] == hold[:, None]).astype(float)
            Tu = np.zeros((Np * m, m))
            Du = np.zeros((nz, m))
            Du[:m] = -np.eye(m)
        Tz = np.kron(blocks, np.eye(m))
        Cb = np.kron(np.eye(Np), C)
        Sx = Gam @ Tz
        Sy = Cb @ Sx
        ones_n = np.kron(np.ones((Np, 1)), np.eye(n))
        Dth = ones_n @ sel("d", nt) + sel("D", nt)  # affine term of every stage
        Xth = Phi @ sel("x0", nt) + Gam @ Tu @ sel("up", nt) + GamD @ Dth
        Yth = Cb @ Xth
        Uth = Tu @ sel("up", nt)
        dUth = Du @ sel("up", nt)

        # output/state constraint rows on z (condensed)
        con = self._con
        ncon = con["g"].size
        Gz = np.zeros((ncon, nz))
        Gth = np.zeros((ncon, nt))
        Gx = np.zeros((ncon, n))  # coefficient on the state of the row's stage
        for gi, g in enumerate(self._groups):
            idx = np.flatnonzero(con["g"] == gi)
            K = g.stages.size
            dim = p if g.on == "y" else n
            rows = (g.stages[:, None] - 1) * dim + np.arange(dim)[None, :]
            Sz = (Sy if g.on == "y" else Sx)[rows.ravel()]
            St = (Yth if g.on == "y" else Xth)[rows.ravel()]
            GK = np.kron(np.eye(K), g.G)
            Gz[idx] = GK @ Sz
            Gth[idx] = GK @ St
            Gx[idx] = np.tile(g.G @ C if g.on == "y" else g.G, (K, 1))
        st = self._struct = SimpleNamespace(
            Tu=Tu,
            Tz=Tz,
            Cb=Cb,
            Sx=Sx,
            Sy=Sy,
            Dth=Dth,
            Xth=Xth,
            Yth=Yth,
            Uth=Uth,
            dUth=dUth,
            Gz=Gz,
            Gth=Gth,
            Gx=Gx,
            Cpinv=np.linalg.pinv(C),
        )
        return st

    def _build(self) -> None:
        """Compute every model/weight-dependent matrix (dense) and the OSQP values.

        The condensed quantities (prediction matrices, Hessian ``H``, the maps of the
        constraint rows onto ``z``) are built for both forms: they give
        :meth:`gain_unconstrained`, the exact refinement and the fallback prediction.
        """
        self._unc = None  # the unconstrained shortcut's data follow the matrices
        self._pin_key: bytes | None | bool = False  # pinned inputs: not looked at yet
        n, m, p, Np, Nc, nz = self.n, self.m, self.p, self.Np, self.Nc, self._nz
        A, B, C = self._A, self._B, self._C
        nt = self._ntheta
        sel = self._sel
        sparse = self._sparse

        S_ = self._structure()
        Tu, Tz, Cb, Sx, Sy = S_.Tu, S_.Tz, S_.Cb, S_.Sx, S_.Sy
        Dth, Xth, Yth, Uth, dUth = S_.Dth, S_.Xth, S_.Yth, S_.Uth, S_.dUth
        Gz, Gth, Gx = S_.Gz, S_.Gth, S_.Gx

        # weighted residuals e = Ez z + Eth theta (condensed), weights W ------------------
        Ez_parts = [Sy, self._Dz]
        Eth_parts = [Yth - sel("r", nt), dUth]
        # per-stage weight scales (``stage_scales``; identity by default)
        sQ, sR, sS = self._stage_scales
        DQ = np.eye(Np) if sQ is None else np.diag(sQ)
        DR = np.eye(Nc) if sR is None else np.diag(sR)
        DS = np.eye(Np) if sS is None else np.diag(sS)
        W_parts = [_scaled_blocks(DQ, self._Q), _scaled_blocks(DR, self._R)]
        L_parts = [
            _scaled_blocks(np.sqrt(DQ), _psd_sqrt(self._Q)),
            _scaled_blocks(np.sqrt(DR), _psd_sqrt(self._R)),
        ]
        if self._S is not None:
            Ez_parts.append(Tz)
            Eth_parts.append(Uth - sel("ur", nt))
            W_parts.append(_scaled_blocks(DS, self._S))
            L_parts.append(_scaled_blocks(np.sqrt(DS), _psd_sqrt(self._S)))
        if self._P is not None:
            if self.terminal == "state":
                Ez_parts.append(Sx[-n:])
                Eth_parts.append(Xth[-n:] - sel("xN", nt))
            else:
                Ez_parts.append(Sy[-p:])
                Eth_parts.append(Yth[-p:] - sel("r", nt)[-p:])
            W_parts.append(self._P)
            L_parts.append(_psd_sqrt(self._P))
        Ez = np.vstack(Ez_parts)
        Eth = np.vstack(Eth_parts)
        W = _block_diag(W_parts)
        Lw = _block_diag(L_parts)
        EzW = Ez.T @ W
        H = EzW @ Ez
        H = 0.5 * (H + H.T)
        Fq = 2.0 * EzW @ Eth  # condensed q_z = Fq theta
        Lth_c = Lw @ Eth  # condensed cost constant = ||Lth_c theta||^2

        con = self._con
        rho_s = con["rho"][self._soft_c]  # exact-penalty weights of the soft rows
        self._rho_s = rho_s
        self._gamma_s = 0.01 * rho_s if self._gamma is None else np.full(rho_s.size, self._gamma)
        ns, nh, nlu, r0 = self._ns, self._nh, self._nlu, self._r0
        n_u = nz
        n_du = nz if self._has_du else 0
        o = r0 + n_u + n_du
        hard_c, soft_c, soft2_c = self._hard_c, self._soft_c, self._soft2_c
        # semantic rows (everything except the dynamics) in condensed coordinates
        self._Gsem = np.vstack(
            [self._Tz_c] + ([self._Dz] if n_du else []) + [Gz[hard_c], Gz[soft_c], Gz[soft2_c]]
        )
        self._Csem = np.vstack(
            [Uth[:nz]] + ([dUth] if n_du else []) + [Gth[hard_c], Gth[soft_c], Gth[soft2_c]]
        )

        # OSQP matrices ------------------------------------------------------------------
        oz, oe, nv = self._oz, self._oe, self._nv
        sl = np.arange(ns)
        Ad = np.zeros((self._nA, nv))
        Pd = np.zeros((nv, nv))
        if not sparse:
            Ad[:nlu, :nz] = self._Gsem
            Pd[:nz, :nz] = 2.0 * np.triu(H)
            Hw_q = Fq  # q of the non-slack variables
            Lth = Lth_c
            Cth = self._Csem
        else:
            nxv = self._nxv
            # dynamics: -x_{t+1} + A x_t + B u_t + (A x0 [t = 0] + d_t) = 0
            Cth_dyn = np.zeros((nxv, nt))
            for t in range(Np):
                rows = slice(t * n, (t + 1) * n)
                Ad[rows, t * n : (t + 1) * n] = -np.eye(n)
                if t:
                    Ad[rows, (t - 1) * n : t * n] = A
                Ad[rows, oz : oz + nz] = B @ Tz[t * m : (t + 1) * m]
                Cth_dyn[rows] = B @ Tu[t * m : (t + 1) * m] @ sel("up", nt) + Dth[rows]
            Cth_dyn[:n] += A @ sel("x0", nt)
            Ad[r0 : r0 + n_u, oz : oz + nz] = self._Tz_c
            if n_du:
                Ad[r0 + n_u : o, oz : oz + nz] = self._Dz
            for rows_c, at in (
                (hard_c, np.arange(o, nh)),
                (soft_c, np.arange(nh, nh + ns)),
                (soft2_c, np.arange(nh + ns, nlu)),
            ):
                for k, rr in zip(rows_c, at, strict=True):
                    st = con["s"][k] - 1
                    Ad[rr, st * n : (st + 1) * n] = Gx[k]
            # cost: residuals Ew w + Eth_s theta in the variables w = (X, z)
            Ew_parts = [np.hstack([Cb, np.zeros((Np * p, nz))])]
            Ew_parts.append(np.hstack([np.zeros((nz, nxv)), self._Dz]))
            Eth_s = [-sel("r", nt), dUth]
            if self._S is not None:
                Ew_parts.append(np.hstack([np.zeros((Np * m, nxv)), Tz]))
                Eth_s.append(Uth - sel("ur", nt))
            if self._P is not None:
                last = np.zeros((n, nxv + nz))
                last[:, nxv - n : nxv] = np.eye(n)
                if self.terminal == "state":
                    Ew_parts.append(last)
                    Eth_s.append(-sel("xN", nt))
                else:
                    Ew_parts.append(C @ last)
                    Eth_s.append(-sel("r", nt)[-p:])
            Ew = np.vstack(Ew_parts)
            EwW = Ew.T @ W
            Hw = EwW @ Ew
            Pd[:oe, :oe] = 2.0 * np.triu(0.5 * (Hw + Hw.T))
            Hw_q = 2.0 * EwW @ np.vstack(Eth_s)
            Lth = Lw @ np.vstack(Eth_s)
            # theta-dependent offsets: dynamics, input and rate rows (the state and
            # output rows act on the variables directly and have constant bounds)
            Cth = np.vstack([Cth_dyn, Uth[:nz]] + ([dUth] if n_du else []))
        Ad[nh + sl, oe + sl] = -1.0
        if soft2_c.size:
            Ad[nh + ns + np.arange(soft2_c.size), oe + self._soft2_slack] = 1.0
        Ad[nlu + sl, oe + sl] = 1.0
        Pd[oe + sl, oe + sl] = 2.0 * self._gamma_s
        if np.any(Ad[~self._Amask] != 0) or np.any(Pd[~self._Pmask] != 0):
            raise RuntimeError("internal error: QP entries outside the fixed sparsity pattern")
        self._A_dense, self._P_dense = Ad, Pd

        # the per-step affine map v = M theta ---------------------------------------------
        # v = [q (nv) | offsets of the rows self._off | trajectory offsets | cost factor]
        qth = np.zeros((nv, nt))
        qth[:oe] = Hw_q
        qth[oe:, 0] = rho_s  # column 0 of theta is the constant 1
        self._y_is_x = p == n and np.array_equal(C, np.eye(n))
        # (condensed: the planned inputs' offsets are part of v; the predicted states and
        # outputs, rarely read, have their own map evaluated on demand -- MPCSolution.X/Y)
        if sparse:  # the states are variables
            traj_th: list[np.ndarray] = []
            self._M_xy = self._Wz_xy = None
        else:
            traj_th = [Uth[:nz]]
            self._M_xy = np.ascontiguousarray(np.vstack([Xth] + ([] if self._y_is_x else [Yth])))
            self._Wz_xy = np.ascontiguousarray(np.vstack([Sx] + ([] if self._y_is_x else [Sy])))
        Lth = Lth[np.any(Lth != 0, axis=1)]
        M = np.vstack([qth, Cth] + traj_th + [Lth])
        self._M_full = np.ascontiguousarray(M)
        self._M_nd = np.ascontiguousarray(M[:, : self._nb])
        self._v = np.empty(M.shape[0])
        self._sl_q = slice(0, nv)
        n_off = self._off.stop - self._off.start
        self._sl_c = slice(nv, nv + n_off)
        t0 = nv + n_off
        n_tu = 0 if sparse else self._ncm
        self._sl_traj_u = slice(t0, t0 + n_tu)
        self._sl_L = slice(t0 + n_tu, M.shape[0])
        self._Wz_u = None if sparse else np.ascontiguousarray(self._Tz_c)
        self._Cpinv = S_.Cpinv
        # condensed data for gain_unconstrained(), the refinement and the fallback
        self._H, self._Fq, self._Lth_c = H, Fq, Lth_c
        # weighted residuals e = LwEz z + Lth_c theta (unconstrained_affine's cost)
        self._LwEz = None if sparse else Lw @ Ez
        self._Xth, self._Sx = Xth, Sx

    def _q_init(self) -> np.ndarray:
        q = np.zeros(self._nv)
        q[self._oe :] = self._rho_s
        return q

    def _push_matrices(self) -> None:
        Px = self._P_dense[self._P_rows, self._P_cols]
        Ax = self._A_dense[self._A_rows, self._A_cols]
        self._backend.update_mat(Px, Ax)

    # ------------------------------------------------------------------ public
    def reset(self) -> None:
        """Forget the warm start, the last plan and the last applied input."""
        self._theta = np.zeros(self._ntheta)
        self._theta[0] = 1.0
        self._has_xN = "xN" in self._slots
        self._has_ur = "ur" in self._slots
        self._th_nb = self._theta[: self._nb]
        self._th_up = self._theta[self._slots["up"]]
        self._th_x0 = self._theta[self._slots["x0"]]
        self._th_r = self._theta[self._slots["r"]].reshape(self.Np, self.p)
        self._th_D = self._theta[self._slots["D"]].reshape(self.Np, self.n)
        self._shape_D = (self.Np, self.n)
        if self._has_xN:
            self._th_xN = self._theta[self._slots["xN"]]
        self._d_dirty = 0  # 0: no d, 1: constant d written, 2: sequence D written
        self._ur_dirty = False
        self._ws_x: np.ndarray | None = None
        self._ws_y: np.ndarray | None = None
        #: the last solution (primal, dual; dual None: condensed z with zero slacks and
        #: duals), turned into the next warm start only when OSQP runs (_warm_start)
        self._ws_src: tuple[np.ndarray, np.ndarray | None] | None = None
        self._xbuf = np.zeros(self._nv + 1)
        self._plan: np.ndarray | None = None
        self._plan_age = 0
        self._u_last: np.ndarray | None = None

    def reset_solver(self) -> None:
        """:meth:`reset` plus OSQP's own state: initial ``rho`` and a zero iterate.

        OSQP keeps its adapted ``rho`` (and, without a warm start, its last iterate)
        between solves; after this call identical data give identical solutions, so a
        controller can keep one QP across episodes and stay reproducible per seed
        (costs one KKT refactorisation).
        """
        self.reset()
        be = self._backend
        be.prob.update_settings(rho=be.rho0)
        be.warm_start(np.zeros(self._nv), np.zeros(self._nA))

    def set_weights(
        self,
        *,
        Q: ArrayLike | None = None,
        R: ArrayLike | None = None,
        S: ArrayLike | None = None,
        P: ArrayLike | None = None,
        soft_penalty: float | Mapping[str, float | ArrayLike] | None = None,
        soft_quadratic: float | None = None,
        stage_scales: Mapping[str, ArrayLike] | None = None,
    ) -> None:
        """Change cost weights (``None`` keeps a weight); matrix values are updated in OSQP.

        ``stage_scales`` replaces the per-stage multipliers (see the constructor).

        ``S`` / ``P`` can only be changed if they were given at construction (pass zeros
        to reserve them).  ``soft_penalty`` may change finite values but cannot turn a
        soft row hard or vice versa (that would change the QP structure).
        """
        Q_ = self._Q if Q is None else _weight("Q", Q, self.p)
        R_ = self._R if R is None else _weight("R", R, self.m)
        if S is not None and self._S is None:
            raise ValueError("S was not given at construction; pass S=0 there to reserve it")
        if P is not None and self._P is None:
            raise ValueError("P was not given at construction; pass P=0 there to reserve it")
        S_ = self._S if S is None else _weight("S", S, self.m)
        dimP = self.n if self.terminal == "state" else self.p
        P_ = self._P if P is None else _weight("P", P, dimP)
        g_ = self._gamma if soft_quadratic is None else self._check_gamma(soft_quadratic)
        scales = None if stage_scales is None else self._check_stage_scales(stage_scales)
        new_rho = None
        if soft_penalty is not None:
            _check_penalty_arg(soft_penalty)
            parts = []
            for g in self._groups:
                full = self._penalty(g.name, soft_penalty, g.dim_full)
                rho_g = full[g.cols]
                if np.any(np.isfinite(rho_g) != np.isfinite(g.rho)):
                    raise ValueError(
                        f"soft_penalty[{g.name!r}] cannot switch rows between soft and hard "
                        "after construction"
                    )
                parts.append(rho_g)
            new_rho = parts
        self._Q, self._R, self._S, self._P, self._gamma = Q_, R_, S_, P_, g_
        if scales is not None:
            self._stage_scales = scales
        if new_rho is not None:
            for g, rho_g in zip(self._groups, new_rho, strict=True):
                g.rho = rho_g
            self._con["rho"] = (
                np.concatenate([np.tile(g.rho, g.stages.size) for g in self._groups])
                if self._groups
                else np.zeros(0)
            )
        self._build()
        self._push_matrices()

    def set_model(self, A: ArrayLike, B: ArrayLike, C: ArrayLike | None = None) -> None:
        """Replace the model (same dimensions; ``C=None`` keeps the current ``C``)."""
        A_, B_, C_ = self._check_model(A, B, self._C if C is None else C, (self.n, self.m, self.p))
        self._A, self._B, self._C = A_, B_, C_
        self._struct = None
        self._build()
        self._push_matrices()

    def _check_stage_scales(
        self, stage_scales: Mapping[str, ArrayLike] | None
    ) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None]:
        """Validate ``stage_scales`` -> (Q (Np,), R (Nc,), S (Np,)) multipliers or None."""
        if stage_scales is None:
            return (None, None, None)
        if not isinstance(stage_scales, Mapping) or set(stage_scales) - {"Q", "R", "S"}:
            raise ValueError(
                "stage_scales must be a mapping with keys among 'Q', 'R', 'S', "
                f"got {stage_scales!r}"
            )
        out = []
        for name, dim in (("Q", self.Np), ("R", self.Nc), ("S", self.Np)):
            val = stage_scales.get(name)
            if val is None:
                out.append(None)
                continue
            v = _vector(f"stage_scales[{name!r}]", val, dim)
            if np.any(v < 0):
                raise ValueError(f"stage_scales[{name!r}] must be >= 0, got {v}")
            out.append(v)
        return out[0], out[1], out[2]

    def set_base_bounds(
        self,
        *,
        u_min: ArrayLike | None = None,
        u_max: ArrayLike | None = None,
        y_min: ArrayLike | None = None,
        y_max: ArrayLike | None = None,
        h_N: ArrayLike | None = None,
    ) -> None:
        """Replace construction-time bounds until the next call (cheap: no matrix update).

        ``u_min`` / ``u_max``: per-stage input box ``(Nc, m)`` (or ``(m,)``, held), e.g.
        equal bounds to fix inputs (move blocking); ``y_min`` / ``y_max``: per-stage
        output box ``(Np, p)`` (values of rows dropped at construction are ignored); ``h_N``:
        offsets ``(r,)`` of the terminal polyhedron ``H_N x_Np <= h_N`` given at
        construction (rows that were infinite there stay dropped).  ``None`` leaves a
        bound as it is; per-call bounds of :meth:`solve` still override these for one
        call.  Setting all per-step bounds here and calling :meth:`solve` without
        overrides is the cheapest way to move them every step.  The first
        input is still clipped to the construction-time box and rate window after the
        solve, so stage-0 input bounds should stay inside them; when the previous input
        lies outside the box with rate limits, the reachable-box relaxation of
        :meth:`solve` replaces the stage input bounds for that call.
        """
        Nc, m = self.Nc, self.m
        lo0, hi0 = self._Lb0, self._Ub0
        r0, nu = self._r0, self._nz
        groups = self.__dict__.get("_base_groups")
        if groups is None:
            groups = self._base_groups = {g.name: g for g in self._groups}
        if u_min is not None or u_max is not None:
            new = [lo0[r0 : r0 + nu].copy(), hi0[r0 : r0 + nu].copy()]
            for name, val, side in (("u_min", u_min, 0), ("u_max", u_max, 1)):
                if val is None:
                    continue
                try:
                    arr = np.broadcast_to(np.asarray(val, dtype=float), (Nc, m))
                except ValueError:
                    raise ValueError(
                        f"set_base_bounds(): {name} must have shape ({Nc}, {m}) or ({m},), "
                        f"got {np.shape(val)}"
                    ) from None
                if np.isnan(arr).any():
                    raise ValueError(f"set_base_bounds(): {name} must not contain NaN")
                new[side] = np.clip(arr, -_BIG, _BIG).ravel()
            if np.any(new[0] > new[1]):
                raise ValueError("set_base_bounds(): u_min must not exceed u_max at any stage")
            lo0[r0 : r0 + nu], hi0[r0 : r0 + nu] = new
            self._pin_key = False
        if y_min is not None or y_max is not None:  # called every step: keep it lean
            g, _, cols, lb, ub_pos, _ = self._bounds_entry("y")
            if g is None:
                raise ValueError("set_base_bounds(): y bounds given but no y box at construction")
            for name, val in (("y_min", y_min), ("y_max", y_max)):
                if val is None:
                    continue
                arr = val if type(val) is np.ndarray else np.asarray(val, dtype=float)
                if arr.shape != (self.Np, self.p):
                    try:
                        arr = np.broadcast_to(arr, (self.Np, self.p))
                    except ValueError:
                        raise ValueError(
                            f"set_base_bounds(): {name} must have shape ({self.Np}, {self.p}) "
                            f"or ({self.p},), got {np.shape(val)}"
                        ) from None
                vals = arr if cols is None else arr[:, cols]
                tot = float(vals.sum())
                if tot != tot and np.isnan(vals).any():  # (+inf + -inf is NaN too)
                    raise ValueError(f"set_base_bounds(): {name} must not contain NaN")
                vals = np.minimum(np.maximum(vals, -_BIG), _BIG)
                if name == "y_min":
                    pos, ok = lb
                    lo0[pos] = vals if ok is None else vals[ok]
                else:
                    hi0[ub_pos] = vals
        if h_N is not None:  # called every step by terminal sets that move: keep it lean
            g = groups.get("H_N")
            if g is None:
                raise ValueError("set_base_bounds(): h_N given but H_N was not set at construction")
            h = h_N if type(h_N) is np.ndarray else np.asarray(h_N, dtype=float)
            if h.shape != (g.dim_full,):
                raise ValueError(f"set_base_bounds(): h_N must have shape ({g.dim_full},)")
            cols = self._bounds_entry("H_N")[2]
            if cols is not None:
                h = h[cols]
            lo_h = float(h.min()) if h.size else 0.0
            if lo_h != lo_h or lo_h == -np.inf:
                raise ValueError("set_base_bounds(): h_N must not contain NaN or -inf")
            hi0[g.ub_pos[0]] = np.minimum(h, _BIG)
        self._bounds_dirty = True

    def adopt_unconstrained(self, z: np.ndarray, U: np.ndarray) -> None:
        """Leave the state :meth:`solve` leaves after the unconstrained optimum ``z``.

        For a caller that evaluates the unconstrained law itself and checks the
        constraints on its own (the DMC's classic gain): the warm start of the next OSQP
        call and the plan kept for a fallback become those of the condensed decision
        ``z`` (``(nz,)``, zero slacks and duals) with input plan ``U`` (``(Nc, m)``), as
        if :meth:`solve` had returned them with ``unconstrained_first``.
        """
        if self._sparse:
            raise ValueError("adopt_unconstrained() needs the condensed form")
        self._ws_src = (z, None)
        self._plan = U
        self._plan_age = 0
        self._u_last = U[0]

    def _warm_start(self) -> tuple[np.ndarray | None, np.ndarray | None]:
        """The warm start of the next OSQP call, formed from the last solution on demand
        (shifted by one stage or as it is, per ``warm_start``): most solves of the MPCs
        that try the unconstrained optimum first never reach OSQP."""
        src = self._ws_src
        if src is not None:
            self._ws_src = None
            x, y = src
            mode = self._ws_mode
            if y is None:  # condensed decision z, zero slacks and duals
                xb = self._xbuf
                xb[: self._nz] = x
                xb[self._nz : self._nv] = 0.0
                if mode == "shift":
                    self._ws_x, self._ws_y = xb[self._xshift], self._zero_duals()
                elif mode == "previous":
                    self._ws_x, self._ws_y = xb[: self._nv].copy(), self._zero_duals()
            elif mode == "shift":
                xb = self._xbuf
                xb[: self._nv] = x
                self._ws_x = xb[self._xshift]
                self._ws_y = y[self._yshift]
            elif mode == "previous":
                self._ws_x, self._ws_y = x, y
        return self._ws_x, self._ws_y

    def _zero_duals(self) -> np.ndarray:
        y = self.__dict__.get("_y_zero")
        if y is None or y.size != self._nA:
            y = self._y_zero = np.zeros(self._nA)  # shared: nothing writes into duals
        return y

    def gain_unconstrained(self) -> UnconstrainedGain:
        """First-move gain of the unconstrained problem from the condensed normal equations.

        Without active constraints the minimiser is ``z* = -H^-1 F theta`` with
        ``H = Ez' W Ez`` and ``F = Ez' W Eth``; the first move is
        ``u0 = [Tz z* + Tu u_prev]_0``.  Requires ``H`` to be nonsingular.
        """
        m = self.m
        try:
            Z = -np.linalg.solve(self._H, 0.5 * self._Fq)  # (nz, ntheta)
        except np.linalg.LinAlgError as exc:
            raise ValueError("the condensed Hessian is singular (increase R or S)") from exc
        K = self._Tz_c[:m] @ Z
        if self._zdu:  # u0 = u_prev + du0
            K[:, self._slots["up"]] += np.eye(m)
        s = self._slots
        g = UnconstrainedGain(
            Kx=K[:, s["x0"]],
            Ku=K[:, s["up"]],
            Kr=K[:, s["r"]],
            Kd=K[:, s["d"]],
            KD=K[:, s["D"]],
            Kur=K[:, s["ur"]] if "ur" in s else None,
            KxN=K[:, s["xN"]] if "xN" in s else None,
            Np=self.Np,
            p=self.p,
            Cpinv=self._Cpinv.copy(),
        )
        return g

    # ------------------------------------------------------------------ solve
    def solve(
        self,
        x0: ArrayLike,
        u_prev: ArrayLike,
        y_ref: ArrayLike,
        *,
        d: ArrayLike | None = None,
        u_ref: ArrayLike | None = None,
        x_ref_N: ArrayLike | None = None,
        y_min: ArrayLike | None = None,
        y_max: ArrayLike | None = None,
        h_y: ArrayLike | None = None,
        h_x: ArrayLike | None = None,
    ) -> MPCSolution:
        """Solve the MPC problem at the current sampling instant.

        Args:
            x0: current state ``(n,)``.
            u_prev: input applied at the previous instant ``(m,)``.
            y_ref: output references ``r_1 .. r_Np`` as ``(Np, p)`` (or ``(p,)``, held).
            d: affine model term: ``(n,)`` constant or ``(Np, n)`` for ``d_0 .. d_{Np-1}``.
            u_ref: input-level references ``(Np, m)`` or ``(m,)`` (used with ``S``; default 0).
            x_ref_N: terminal state reference (state terminal weight only); default
                ``pinv(C) @ y_ref[-1]`` (exactly ``y_ref[-1]`` when ``C = I``).
            y_min, y_max, h_y, h_x: per-stage bounds ``(Np, .)`` (or one row, held)
                replacing the construction-time values for this call only; where some
                rows were unconstrained at construction, ``(Np, k)`` with only the ``k``
                constrained ones is accepted too (the cheapest form).

        Never raises for non-finite data or solver failures: the result then has
        ``fallback=True`` and a safe ``u0``.  Wrong shapes raise ``ValueError``.
        """
        t_start = time.perf_counter()
        th = self._theta
        M = self._load(x0, u_prev, y_ref, d, u_ref, x_ref_N)
        v = self._v
        tv = self._th_nb if M is self._M_nd else th
        up = self._th_up
        if not math.isfinite(np.dot(tv, tv)):  # NaN/inf anywhere in the data
            v.fill(np.nan)
            return self._fallback(t_start, "invalid input", _STATUS_INVALID_INPUT, up)
        np.dot(M, tv, out=v)
        upl = up.tolist()

        # bounds -------------------------------------------------------------------
        override = y_min is not None or y_max is not None or h_y is not None or h_x is not None
        relax = self._has_du and self._outside_box(upl)
        changed = False
        if override or relax:
            ok = self._set_bounds(up, relax, y_min, y_max, h_y, h_x)
            if not ok:
                return self._fallback(t_start, "invalid input", _STATUS_INVALID_INPUT, up)
            changed = True
        elif self._bounds_dirty:
            self._LUb[...] = self._LUb0
            self._bounds_dirty = False
            changed = True
        if changed and self._off.stop < self._nlu:  # rows with constant offsets (sparse)
            k = self._off.stop
            self._LU[:, k : self._nlu] = self._LUb[:, k:]
        c = v[self._sl_c]
        np.subtract(self._Lb_off, c, out=self._l_off)  # l = lower bounds - offsets
        np.subtract(self._Ub_off, c, out=self._u_off)

        # unconstrained optimum when it is feasible (exact; see unconstrained_first) ---
        if self._unc_first:
            hit = self._unconstrained(v[self._sl_q], relax)
            if hit is not None:
                x, y, obj_val = hit
                status_val, status, iters, solve_time = _SOLVED, _UNCONSTRAINED, 0, 0.0
                return self._finish(
                    t_start,
                    x,
                    y,
                    v,
                    th,
                    upl,
                    up,
                    status,
                    status_val,
                    iters,
                    solve_time,
                    obj_val,
                    0.0,
                )

        # OSQP -----------------------------------------------------------------------
        be = self._backend
        raw = be.raw
        try:
            ws_x, ws_y = self._warm_start()
            if raw is not None and not be.polishing:
                # compiled solver object, inlined: the wrapper costs more than small solves
                rc = raw.update_data_vec(v[self._sl_q], self._l, self._u)
                if rc:
                    return self._fallback(t_start, "solver error", _STATUS_EXCEPTION, up)
                if ws_x is not None:
                    raw.warm_start(ws_x, ws_y)
                raw.solve()
                sol = raw.solution
                x = sol.x
                y = sol.y
                info = raw.info
                status_val = info.status_val
                iters = info.iter
                solve_time = info.solve_time
                obj_val = info.obj_val
                status = be._status_names.get(status_val) or be.status_name(status_val, info)
                stats = (status_val, status, iters, solve_time, obj_val, 0)
            else:
                rc = be.update_vec(v[self._sl_q], self._l, self._u)
                if rc:
                    return self._fallback(t_start, "solver error", _STATUS_EXCEPTION, up)
                if ws_x is not None:
                    be.warm_start(ws_x, ws_y)
                x, y, stats = be.solve()
                status_val, status, iters, solve_time, obj_val, _ = stats
            if status_val != _SOLVED and self._rescue_on:
                x, y, stats = self._rescue(x, y, stats)
                status_val, status, iters, solve_time, obj_val, _ = stats
        except Exception:  # noqa: BLE001 - the control loop must never raise here
            return self._fallback(t_start, "solver error", _STATUS_EXCEPTION, up)
        if status_val != _SOLVED and status_val != _SOLVED_INACCURATE:
            return self._fallback(t_start, status, status_val, up, iters, solve_time)
        return self._finish(
            t_start, x, y, v, th, upl, up, status, status_val, iters, solve_time, obj_val
        )

    def unconstrained_cost(
        self,
        x0: ArrayLike,
        u_prev: ArrayLike,
        y_ref: ArrayLike,
        *,
        d: ArrayLike | None = None,
        u_ref: ArrayLike | None = None,
        x_ref_N: ArrayLike | None = None,
    ) -> float | None:
        """A lower bound on the cost :meth:`solve` would return for the same data, exact
        when the problem's unconstrained optimum is feasible.

        It is the cost (``MPCSolution.cost``: objective plus its data constant) of the
        minimiser of the objective with the inputs pinned by the base bounds (equal
        ``u_min``/``u_max`` of :meth:`set_base_bounds`) at their values and every other row
        ignored.  Every constraint and the non-negative slack penalties can only raise the
        optimum, so the QP's optimal cost is at least this; when the minimiser satisfies
        every row it *is* the optimum and the value equals the cost that :meth:`solve`
        returns, bit for bit (same data map, same arithmetic).  It costs one
        matrix-vector product of the data map and one of the cached reduced inverse: no
        bounds, no feasibility check, no solver.  Use it to discard candidate problems
        whose cost cannot beat a known value (self-triggered MPC's hold lengths).  It
        loads the call's data as :meth:`solve` does and leaves the warm start, the kept
        plan and the last input untouched.

        Returns None when the bound is not available: ``unconstrained_first`` off, the
        sparse form, ``H`` (or its reduced block) not invertible to 1e-9, a previous input
        outside the input box (the solve would relax the input rows), non-finite data.
        Per-call bounds of :meth:`solve` do not enter (they do not change the minimiser).
        """
        if not self._unc_first:
            return None
        th = self._theta
        M = self._load(x0, u_prev, y_ref, d, u_ref, x_ref_N)
        tv = self._th_nb if M is self._M_nd else th
        if not math.isfinite(np.dot(tv, tv)):
            return None
        if self._has_du and self._outside_box(self._th_up.tolist()):
            return None
        v = self._v
        np.dot(M, tv, out=v)  # the full map, as solve() applies it: the same numbers
        hit = self._unc_minimiser(v[: self._nz], False, self._Lb0)
        if hit is None:
            return None
        Lv = v[self._sl_L]
        return hit[1] + float(np.dot(Lv, Lv))

    def unconstrained_affine(self) -> UnconstrainedAffine | None:
        """The unconstrained optimum as explicit affine maps of the data vector ``θ``.

        The same minimiser as :meth:`unconstrained_cost` and the unconstrained shortcut of
        :meth:`solve` (inputs pinned by equal base bounds held at their value), composed
        with the data map: see :class:`UnconstrainedAffine`.  A caller that evaluates
        many problems of a family for the same stage data (self-triggered MPC's hold
        lengths) composes these maps with its own data layout once and then needs one
        matrix-vector product per problem and step.  Its check that the optimum meets
        every row replaces the solve's; :meth:`adopt_unconstrained` then leaves the state
        a solve would.  Returns None where the shortcut is not available (see
        :meth:`unconstrained_cost`) or a pinned input is held at a non-zero value.  Costs
        a few small matrix products: make it once per weight or pin change.
        """
        if not self._unc_first or self._sparse:
            return None
        nz = self._nz
        if self._unc_minimiser(np.zeros(nz), False, self._Lb0) is None:
            return None
        mHinv, _, _, reduced = self._unc
        key = None if self._zdu else self._pin_key
        if key is None:
            K = mHinv
        else:
            rows_p, K, _ = reduced[key]
            if np.any(self._Lb0[rows_p] != 0.0):
                return None
        Mf = self._M_full
        Z = K @ Mf[:nz]
        R = self._LwEz @ Z + self._Lth_c
        npn = self.Np * self.n
        traj = self._Wz_xy @ Z + self._M_xy
        X = traj[:npn]
        Y = X if self._y_is_x else traj[npn:]
        U = self._Wz_u @ Z + Mf[self._sl_traj_u]
        return UnconstrainedAffine(
            Z=Z, X=X, Y=Y, U=U, R=R, slots=dict(self._slots), ntheta=Mf.shape[1]
        )

    def _outside_box(self, upl: list[float]) -> bool:
        """Whether the previous input lies outside the input box (with rate limits the
        solve then relaxes the stage input bounds to the reachable box)."""
        umin_l, umax_l = self._umin_l, self._umax_l
        for i in range(self.m):
            if upl[i] < umin_l[i] or upl[i] > umax_l[i]:
                return True
        return False

    def _load(
        self,
        x0: ArrayLike,
        u_prev: ArrayLike,
        y_ref: ArrayLike,
        d: ArrayLike | None,
        u_ref: ArrayLike | None,
        x_ref_N: ArrayLike | None,
    ) -> np.ndarray:
        """Write one call's data into ``θ``; the data map to apply to it (ValueError on
        wrong shapes)."""
        th = self._theta
        s = self._slots
        if (x0.ndim if type(x0) is np.ndarray else np.ndim(x0)) != 1 or (
            u_prev.ndim if type(u_prev) is np.ndarray else np.ndim(u_prev)
        ) != 1:
            raise ValueError(
                f"solve(): x0 must have shape ({self.n},) and u_prev ({self.m},), got "
                f"{np.shape(x0)} and {np.shape(u_prev)}"
            )
        try:
            self._th_x0[...] = x0
            self._th_up[...] = u_prev
        except ValueError:
            raise ValueError(
                f"solve(): x0 must have shape ({self.n},) and u_prev ({self.m},), got "
                f"{np.shape(x0)} and {np.shape(u_prev)}"
            ) from None
        try:
            self._th_r[...] = y_ref
        except ValueError:
            if self.p == 1 and np.shape(y_ref) == (self.Np,):
                th[s["r"]] = y_ref
            else:
                raise ValueError(
                    f"solve(): y_ref must have shape ({self.Np}, {self.p}) or ({self.p},), "
                    f"got {np.shape(y_ref)}"
                ) from None
        if self._has_xN:
            if x_ref_N is None:
                np.dot(self._Cpinv, self._th_r[-1], out=self._th_xN)
            else:
                self._th_xN[...] = x_ref_N
        M = self._M_nd
        if d is not None:
            d_arr = d if type(d) is np.ndarray else np.asarray(d, dtype=float)
            shape = d_arr.shape
            if shape == self._shape_D:
                self._th_D[...] = d_arr
                if self._d_dirty == 1:
                    th[s["d"]] = 0.0
                self._d_dirty = 2
                M = self._M_full
            elif shape == (self.n,):
                th[s["d"]] = d_arr
                if self._d_dirty == 2:
                    th[s["D"]] = 0.0
                self._d_dirty = 1
            else:
                raise ValueError(
                    f"solve(): d must have shape ({self.n},) or ({self.Np}, {self.n}), "
                    f"got {d_arr.shape}"
                )
        elif self._d_dirty:
            th[s["d"]] = 0.0
            th[s["D"]] = 0.0
            self._d_dirty = 0
        if self._has_ur:
            if u_ref is not None:
                try:
                    th[s["ur"]].reshape(self.Np, self.m)[...] = u_ref
                except ValueError as exc:
                    raise ValueError(
                        f"solve(): u_ref must have shape ({self.Np}, {self.m}) or ({self.m},)"
                    ) from exc
                self._ur_dirty = True
            elif self._ur_dirty:
                th[s["ur"]] = 0.0
                self._ur_dirty = False

        return M

    def _finish(
        self,
        t_start: float,
        x: np.ndarray,
        y: np.ndarray,
        v: np.ndarray,
        th: np.ndarray,
        upl: list[float],
        up: np.ndarray,
        status: str,
        status_val: int,
        iters: int,
        solve_time: float,
        obj_val: float,
        slack_max: float | None = None,
    ) -> MPCSolution:
        """Plan, safe first move, cost and warm start from a solution ``(x, y)``
        (``slack_max`` when the caller knows it)."""
        # result ---------------------------------------------------------------------
        if self._sparse:  # states and (absolute) inputs are variables
            U = x[self._oz : self._oe].reshape(self.Nc, self.m)
        else:  # inputs now, predicted states and outputs when read (MPCSolution.X/Y)
            U = np.dot(self._Wz_u, x[: self._nz])
            U += v[self._sl_traj_u]
            U = U.reshape(self.Nc, self.m)
        u0 = U[0]
        # remove the solver's O(eps) constraint violation: u0 exactly inside both boxes
        if self.m == 1:  # the common single-input case without the helper call
            a = upl[0]
            v0 = float(u0[0])
            rlo = a + self._dumin_l[0]
            rhi = a + self._dumax_l[0]
            lo = min(max(self._umin_l[0], rlo), rhi)
            hi = max(min(self._umax_l[0], rhi), rlo)
            if v0 < lo:
                u0[0] = lo
            elif v0 > hi:
                u0[0] = hi
            elif v0 != v0:  # NaN
                return self._fallback(t_start, status, status_val, up, iters, solve_time)
        elif not self._clip_to_window(u0, upl):
            return self._fallback(t_start, status, status_val, up, iters, solve_time)
        Lv = v[self._sl_L]
        cost = obj_val + float(np.dot(Lv, Lv))
        if slack_max is None:
            ns = self._ns
            if ns == 0:
                slack_max = 0.0
            elif ns <= 64:  # python max beats a ufunc call for short vectors
                slack_max = max(0.0, max(x[self._oe :].tolist()))
            else:
                slack_max = max(0.0, float(x[self._oe :].max()))
        self._ws_src = (x, y)  # the next warm start, formed when OSQP runs next
        self._plan = U
        self._plan_age = 0
        self._u_last = u0
        return MPCSolution(
            u0,
            u0 - up,
            U,
            None,
            None,
            status,
            status_val,
            iters,
            solve_time,
            time.perf_counter() - t_start - solve_time,
            slack_max,
            False,
            cost,
            _Predictions(self, x, th),
        )

    def _unconstrained(
        self, q: np.ndarray, relax: bool
    ) -> tuple[np.ndarray, np.ndarray, float] | None:
        """``(x, y, objective)`` of the unconstrained minimiser if it is feasible, else None.

        Condensed QP ``min ½ wᵀPw + qᵀw``, ``w = [z; ε]``: ``z = −H_zz⁻¹ q_z`` with zero
        slacks.  If ``l ≤ A w ≤ u`` holds row by row, no constraint is active and ``w`` is
        the unique optimum (zero duals; at ε = 0 the slack rows' multipliers are the
        penalties themselves).  The inverse is formed once per matrix update and only
        used when it inverts ``H_zz`` to 1e-9.

        *Pinned inputs.*  With absolute inputs as variables (``delta_u=False``) an input
        row whose lower and upper bound coincide fixes its variable (e.g. the held
        increments of self-triggered MPC).  Then ``z`` is the minimiser over the free
        variables with the pinned ones at their values, ``z_F = −H_FF⁻¹ (q_F + H_FP z_P)``
        -- the optimum of the problem with only those equalities, hence of the QP when
        every other row holds.  The reduced inverse is cached per pinned pattern.  The
        returned duals are zero (a warm start only; the pinned rows' multipliers are
        not computed).
        """
        hit = self._unc_minimiser(q[: self._nz], relax, self._l)
        if hit is None:
            return None
        z, obj = hit
        Az = self._unc[1]
        g = np.dot(Az, z)
        # l <= g <= u row by row (bounds are clipped to ±_BIG, so finite; NaN fails)
        if not (_min_reduce(g - self._l) >= 0.0 and _min_reduce(self._u - g) >= 0.0):
            return None
        x = np.zeros(self._nv)
        x[: self._nz] = z
        return x, self._zero_duals(), obj

    def _unc_minimiser(
        self, qz: np.ndarray, relax: bool, lower: np.ndarray
    ) -> tuple[np.ndarray, float] | None:
        """``(z, ½zᵀHz + qᵀz)`` of the minimiser with the pinned inputs at their values
        (read from the row bounds ``lower``) and no other row; None when the shortcut is
        not available (see :meth:`_unconstrained`)."""
        unc = self._unc
        nz = self._nz
        if unc is None:
            Pu = self._P_dense[:nz, :nz]
            H = Pu + Pu.T - np.diag(np.diag(Pu))
            try:
                Hinv = np.linalg.inv(H)
                ok = np.abs(H @ Hinv - np.eye(nz)).max() < 1e-9
            except np.linalg.LinAlgError:
                ok = False
            unc = self._unc = (
                (
                    np.ascontiguousarray(-Hinv),
                    np.ascontiguousarray(self._A_dense[:, :nz]),
                    H,
                    {},
                )
                if ok
                else False
            )
        if unc is False:
            return None
        mHinv, Az, H, reduced = unc
        r0 = self._r0
        if self._zdu:
            key = None
        elif relax:  # this call's input rows are the reachable box: look at them
            pin = self._l[r0 : r0 + nz] == self._u[r0 : r0 + nz]
            key = pin.tobytes() if pin.any() else None
        else:  # the base input rows, which change only in set_base_bounds
            key = self._pin_key
            if key is False:
                pin = self._Lb0[r0 : r0 + nz] == self._Ub0[r0 : r0 + nz]
                key = self._pin_key = pin.tobytes() if pin.any() else None
        if key is not None:
            red = reduced.get(key)
            if red is None:
                pin = np.frombuffer(key, dtype=bool)
                free = np.flatnonzero(~pin)
                fixed = np.flatnonzero(pin)
                HFF = H[np.ix_(free, free)]
                try:
                    Mi = np.linalg.inv(HFF) if free.size else np.zeros((0, 0))
                    good = not free.size or np.abs(HFF @ Mi - np.eye(free.size)).max() < 1e-9
                except np.linalg.LinAlgError:
                    good = False
                if good:
                    # −H_FF⁻¹ embedded in the full space (zero rows/columns at the pinned
                    # variables): z = K (q + H z_P) + z_P without any gather or scatter
                    K = np.zeros((nz, nz))
                    K[np.ix_(free, free)] = -Mi
                    Hp = np.zeros((nz, nz))
                    Hp[:, fixed] = H[:, fixed]
                    red = (r0 + fixed, np.ascontiguousarray(K), Hp)
                else:
                    red = False
                reduced[key] = red
            if red is False:
                return None
            rows_p, K, Hp = red
            zp = lower[rows_p]
            if zp.any():
                zP = np.zeros(nz)
                zP[rows_p - r0] = zp
                z = np.dot(K, qz + np.dot(Hp, zP))
                z += zP
                obj = 0.5 * float(np.dot(z, np.dot(H, z))) + float(np.dot(qz, z))
            else:  # pinned at zero (a hold): the free part only
                z = np.dot(K, qz)
                obj = 0.5 * float(np.dot(qz, z))
        else:
            z = np.dot(mHinv, qz)
            obj = 0.5 * float(np.dot(qz, z))
        return z, obj

    def _predictions(self, x: np.ndarray, th: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Predicted states and outputs ``(X, Y)`` of the QP solution ``x`` (data ``th``)."""
        npn = self._npn
        if self._sparse:
            X = x[:npn].reshape(self.Np, self.n)
            return X, X if self._y_is_x else X @ self._C.T
        traj = np.dot(self._Wz_xy, x[: self._nz])
        traj += np.dot(self._M_xy, th)
        X = traj[:npn].reshape(self.Np, self.n)
        return X, X if self._y_is_x else traj[npn:].reshape(self.Np, self.p)

    # ------------------------------------------------------------------ helpers
    def _bounds_entry(self, name: str) -> tuple:
        """Per-group constants of :meth:`_set_bounds` (cached: it runs every step)."""
        cache = self.__dict__.setdefault("_bounds_cache", {})
        hit = cache.get(name)
        if hit is None:
            g = next((g for g in self._groups if g.name == name), None)
            if g is None:
                hit = (None, None, None, None, None, False)
            else:
                dropped = _as_slice(np.setdiff1d(np.arange(g.dim_full), g.cols))
                cols = None if np.array_equal(g.cols, np.arange(g.dim_full)) else g.cols
                cols = None if cols is None else _as_slice(cols)
                lb_ok = g.lb_pos >= 0
                lb_all = bool(lb_ok.all())
                lb = (g.lb_pos if lb_all else g.lb_pos[lb_ok], None if lb_all else lb_ok)
                # rows of a hard group bound OSQP rows that need l <= u
                hard = bool(np.any(g.ub_pos < self._nh)) or bool(np.any(g.lb_pos[lb_ok] < self._nh))
                hit = (g, dropped, cols, lb, g.ub_pos, hard)
            cache[name] = hit
        return hit

    def _set_bounds(
        self,
        up: np.ndarray,
        relax: bool,
        y_min: ArrayLike | None,
        y_max: ArrayLike | None,
        h_y: ArrayLike | None,
        h_x: ArrayLike | None,
    ) -> bool:
        """Write per-call bounds into the working bound vectors; False if they contain NaN."""
        Lb, Ub = self._Lb, self._Ub
        self._LUb[...] = self._LUb0
        self._bounds_dirty = True
        check = relax
        if relax:
            # reachable input bounds when u_prev lies outside [u_min, u_max]
            nu = self._nz
            with np.errstate(invalid="ignore"):
                lo = np.minimum(self._umin_t, up[None, :] + self._k_dumax)
                hi = np.maximum(self._umax_t, up[None, :] + self._k_dumin)
            r0 = self._r0
            Lb[r0 : r0 + nu] = np.clip(np.nan_to_num(lo, nan=-_BIG), -_BIG, _BIG).ravel()
            Ub[r0 : r0 + nu] = np.clip(np.nan_to_num(hi, nan=_BIG), -_BIG, _BIG).ravel()
        for name, val, side in (
            ("y", y_min, 0),
            ("y", y_max, 1),
            ("H_y", h_y, 1),
            ("H_x", h_x, 1),
        ):
            if val is None:
                continue
            g, dropped, cols, lb, ub_pos, hard = self._bounds_entry(name)
            arr = val if type(val) is np.ndarray else np.asarray(val, dtype=float)
            if g is not None and arr.shape == g.lb_pos.shape and dropped is not None:
                # only the rows constrained at construction, (Np, kept): nothing to drop;
                # min/max propagate NaN
                vals = arr
                lo_v, hi_v = vals.min(), vals.max()
                if lo_v != lo_v or hi_v != hi_v:
                    return False
            else:
                if g is not None:
                    dim = g.dim_full
                elif name == "y":
                    dim = self.p
                else:
                    dim = arr.shape[-1] if arr.ndim else 1
                if arr.shape != (self.Np, dim):
                    try:
                        arr = np.broadcast_to(arr, (self.Np, dim))
                    except ValueError:
                        raise ValueError(
                            f"solve(): {_bound_label(name, side)} must have shape "
                            f"({self.Np}, {dim}) or ({dim},), got {arr.shape}"
                        ) from None
                total = arr.sum()
                if total != total and np.isnan(arr).any():  # +inf plus -inf is NaN too
                    return False
                if g is None:
                    if np.isfinite(arr).any():
                        raise ValueError(
                            f"solve(): {_bound_label(name, side)} given but no {name} "
                            "constraint was set at construction"
                        )
                    continue
                if dropped is not None and np.isfinite(arr[:, dropped]).any():
                    rows = np.arange(dim)[dropped].tolist()
                    raise ValueError(
                        f"solve(): {_bound_label(name, side)} has finite values in rows "
                        f"{rows} that were unconstrained at construction"
                    )
                vals = arr if cols is None else arr[:, cols]
                lo_v, hi_v = vals.min(), vals.max()
            if lo_v < -_BIG or hi_v > _BIG:
                vals = np.minimum(np.maximum(vals, -_BIG), _BIG)
            if side == 0:
                pos, ok = lb
                Lb[pos] = vals if ok is None else vals[ok]
            else:
                Ub[ub_pos] = vals
            check = check or hard
        if not check:
            return True
        # hard rows must have l <= u for OSQP
        nh = self._nh
        return bool((Lb[:nh] <= Ub[:nh]).all())

    def _fallback(
        self,
        t_start: float,
        status: str,
        status_val: int,
        up: np.ndarray,
        iters: int = 0,
        solve_time: float = 0.0,
    ) -> MPCSolution:
        """Safe command: shifted previous plan (or held input), clipped to all input bounds."""
        m, Nc = self.m, self.Nc
        up = np.array(up, dtype=float)
        if not np.all(np.isfinite(up)):
            up = (
                self._u_last.copy()
                if self._u_last is not None and np.all(np.isfinite(self._u_last))
                else np.where(np.isfinite(up), up, 0.0)
            )
            rate_ok = False
        else:
            rate_ok = True
        self._plan_age += 1
        if self._plan is not None:
            idx = np.minimum(np.arange(Nc) + self._plan_age, Nc - 1)
            cand = self._plan[idx]
        else:
            cand = np.tile(up, (Nc, 1))
        U = np.empty((Nc, m))
        prev = up
        for i in range(Nc):
            lo, hi = self._umin, self._umax
            if rate_ok or i > 0:
                lo, hi = self._input_window(prev)
            ui = np.clip(cand[i], lo, hi)
            ui = np.where(np.isfinite(ui), ui, np.clip(0.0, lo, hi))
            U[i] = ui
            prev = ui
        u0 = U[0].copy()
        # prediction with the fallback plan (NaN if the data were not finite)
        if self._zdu:
            z = np.diff(np.vstack([up[None, :], U]), axis=0).ravel()
        else:
            z = U.ravel()
        self._theta[self._slots["up"]] = up
        X, Y, slack_max, cost = self._evaluate_plan(z)
        # next warm start: shift the previous one again (never reuse a failed iterate)
        ws_x, ws_y = self._warm_start()
        if ws_x is not None:
            xb = self._xbuf
            xb[: self._nv] = ws_x
            self._ws_x = xb[self._xshift]
            self._ws_y = ws_y[self._yshift]
        self._u_last = u0
        return MPCSolution(
            u0=u0,
            du0=u0 - up,
            U=U,
            X=X,
            Y=Y,
            status=status,
            status_val=status_val,
            iterations=iters,
            solve_time_s=solve_time,
            overhead_s=time.perf_counter() - t_start - solve_time,
            slack_max=slack_max,
            fallback=True,
            cost=cost,
        )

    def _clip_to_window(self, u0: np.ndarray, upl: list[float]) -> bool:
        """In-place clip of ``u0`` to :meth:`_input_window`; False if ``u0`` is not finite.

        Python floats: ``m`` is small and numpy calls cost more than the arithmetic.
        """
        umin, umax, dmin, dmax = self._umin_l, self._umax_l, self._dumin_l, self._dumax_l
        u0l = u0.tolist()
        for i in range(self.m):
            a = upl[i]
            rlo = a + dmin[i]
            rhi = a + dmax[i]
            lo = umin[i] if umin[i] > rlo else rlo
            if lo > rhi:
                lo = rhi
            hi = umax[i] if umax[i] < rhi else rhi
            if hi < rlo:
                hi = rlo
            val = u0l[i]
            if val < lo:
                u0[i] = lo
            elif val > hi:
                u0[i] = hi
            elif val != val:  # NaN
                return False
        return True

    def _rescue(self, x: np.ndarray, y: np.ndarray, stats: _Stats) -> tuple[Any, Any, _Stats]:
        """Recover from a solve that did not meet the tolerances.

        ADMM usually identifies the active set long before it meets tight
        tolerances; this is typical when soft constraints are violated, because
        their multipliers then sit at the large penalty ``rho`` and the QP behaves
        like a degenerate LP.  Cascade:

        1. OSQP continued from the last iterate with a relaxed tolerance
           (``max(1e-4, 10 eps)``) and OSQP's own solution polishing;
        2. if polishing failed: an exact active-set iteration (:meth:`_refine`).

        A verified KKT point is reported as ``"solved (polished)"`` (status 1); an
        unpolished relaxed-tolerance solution as ``"solved inaccurate"`` (status 2).
        """
        status_val, status, iters, solve_time = stats[0], stats[1], stats[2], stats[3]
        if status_val not in _RESCUE or x is None or not math.isfinite(np.dot(x, x)):
            return x, y, stats
        t0 = time.perf_counter()
        st = self.osqp_settings
        eps = max(1e-4, 10.0 * float(st["eps_abs"]), 10.0 * float(st["eps_rel"]))
        restore = {k: st[k] for k in ("eps_abs", "eps_rel", "polishing")}
        x2, y2, s2 = self._backend.rescue(x, y, eps, True, restore)
        it = iters + s2[2]
        if s2[0] == _SOLVED and s2[5] == 1:
            t = solve_time + time.perf_counter() - t0
            return x2, y2, (_SOLVED, "solved (polished)", it, t, s2[4], 1)
        ok2 = x2 is not None and math.isfinite(np.dot(x2, x2))
        ref = self._refine(x2, y2) if ok2 else self._refine(x, y)
        t = solve_time + time.perf_counter() - t0
        if ref is not None:
            return ref[0], ref[1], (_SOLVED, "solved (polished)", it, t, ref[2], 1)
        if ok2 and s2[0] == _SOLVED:
            return x2, y2, (_SOLVED_INACCURATE, "solved inaccurate", it, t, s2[4], s2[5])
        return x, y, (status_val, status, it, t, stats[4], stats[5])

    def _refine(
        self, x: np.ndarray, y: np.ndarray, max_iter: int = 20
    ) -> tuple[np.ndarray, np.ndarray, float] | None:
        """Exact solution by a primal-dual active-set iteration started from ``(x, y)``.

        Slacks are eliminated: each soft constraint ``k`` (row ``g_k``, bounds
        ``L_k <= g_k z <= U_k``) is *free* (``eps_k = 0``, bounds inactive), *bound*
        (``eps_k = 0``, ``g_k z`` on a bound, multiplier in ``[0, rho_k]``) or
        *violated* (``eps_k = g_k z - U_k > 0`` or ``L_k - g_k z > 0``, whose penalty
        ``rho_k eps_k + gamma eps_k^2`` enters the cost).  Each iteration solves the
        equality-constrained QP in ``z`` of the current active set (dense KKT
        system) and updates the set with the complementarity rules of the
        primal-dual active-set method (semismooth Newton); the result is accepted
        only if every KKT condition of the full QP holds.  Returns ``(w, y, obj)``
        in OSQP's variables or ``None``.
        """
        nz, ns, r0 = self._nz, self._ns, self._r0
        nh, nlu = self._nh - r0, self._nlu - r0  # semantic row counts (no dynamics rows)
        th = self._theta
        c_sem = self._Csem @ th  # condensed offsets of the semantic rows
        lb = np.clip(self._Lb[r0:] - c_sem, -_BIG, _BIG)
        ub = np.clip(self._Ub[r0:] - c_sem, -_BIG, _BIG)
        ys = y[r0:]  # duals of the semantic rows (and of the eps >= 0 rows)
        Gsem = self._Gsem
        Gh = Gsem[:nh]
        lo_h, hi_h = lb[:nh], ub[:nh]
        Gs = Gsem[nh : nh + ns]
        jl = self._soft2_slack
        U_s = ub[nh : nh + ns]
        L_s = np.full(ns, -_BIG)
        L_s[jl] = lb[nh + ns : nlu]
        rho = self._rho_s
        g2 = 2.0 * self._gamma_s
        H2 = 2.0 * self._H
        q = self._Fq @ th
        eq_h = (hi_h - lo_h) <= 1e-12 * (1.0 + np.abs(hi_h))

        # initial active set from the ADMM iterate (OSQP's polishing rule)
        z = x[self._oz : self._oe]
        ah = Gh @ z
        yh = ys[:nh]
        st_h = np.where((hi_h - ah) < yh, 1, np.where((ah - lo_h) < -yh, -1, 0))
        st_h[eq_h] = 1
        st_s = np.zeros(ns, dtype=np.int64)
        if ns:
            eps = x[self._oe :]
            ysu = ys[nh : nh + ns]
            ysl = np.zeros(ns)
            ysl[jl] = ys[nh + ns : nlu]
            gs = Gs @ z
            zero = eps < -ys[nlu:]
            st_s = np.where(ysu >= -ysl, 1, -1)
            st_s = np.where(
                zero, np.where(ysu >= -ysl, (U_s - gs) < ysu, (gs - L_s) < -ysl) * st_s, 2 * st_s
            )
        for _ in range(max_iter):
            # ---- KKT system of the current active set -----------------------------
            Hr = H2
            f = q
            vu, vl = st_s == 2, st_s == -2
            if vu.any() or vl.any():
                Gv = Gs[vu | vl]
                Hr = H2 + (Gv.T * g2[vu | vl]) @ Gv
                coef = np.where(st_s == 2, rho - g2 * U_s, -rho - g2 * L_s)[vu | vl]
                f = q + Gv.T @ coef
            ah_idx = np.flatnonzero(st_h != 0)
            bs_idx = np.flatnonzero(np.abs(st_s) == 1)
            E = np.vstack([Gh[ah_idx], Gs[bs_idx]])
            e = np.concatenate(
                [
                    np.where(st_h[ah_idx] > 0, hi_h[ah_idx], lo_h[ah_idx]),
                    np.where(st_s[bs_idx] > 0, U_s[bs_idx], L_s[bs_idx]),
                ]
            )
            ne = e.size
            K = np.zeros((nz + ne, nz + ne))
            K[:nz, :nz] = Hr
            K[:nz, nz:] = E.T
            K[nz:, :nz] = E
            rhs = np.concatenate([-f, e])
            try:
                sol = np.linalg.solve(K, rhs)
            except np.linalg.LinAlgError:
                sol = np.linalg.lstsq(K, rhs, rcond=None)[0]
            if not np.all(np.isfinite(sol)):
                return None
            z = sol[:nz]
            lam_h = np.zeros(nh)
            lam_h[ah_idx] = sol[nz : nz + ah_idx.size]
            ah = Gh @ z
            gs = Gs @ z
            v_u = gs - U_s
            v_l = L_s - gs
            mu = np.zeros(ns)  # signed multiplier of soft constraint k (upper > 0)
            mu[bs_idx] = sol[nz + ah_idx.size :]
            mu = np.where(st_s == 2, rho + g2 * v_u, np.where(st_s == -2, -(rho + g2 * v_l), mu))
            # ---- complementarity update (c = 1) -----------------------------------
            new_h = np.where(lam_h + (ah - hi_h) > 0, 1, np.where(lam_h + (ah - lo_h) < 0, -1, 0))
            new_h[eq_h] = 1
            t_u = np.maximum(mu, 0.0) + v_u
            t_l = np.maximum(-mu, 0.0) + v_l
            new_s = np.where(
                t_u >= t_l,
                np.where(t_u > rho, 2, np.where(t_u > 0, 1, 0)),
                np.where(t_l > rho, -2, np.where(t_l > 0, -1, 0)),
            )
            if np.array_equal(new_h, st_h) and np.array_equal(new_s, st_s):
                break
            st_h, st_s = new_h, new_s
        else:
            return None

        # ---- verify the KKT conditions of the full QP ---------------------------------
        scale = 1.0 + float(np.max(np.abs(rhs), initial=0.0))
        if np.max(np.abs(K @ sol - rhs), initial=0.0) > 1e-8 * scale:
            return None  # inconsistent (singular) active set
        tol_p = 1e-9 * (
            1.0 + float(np.max(np.abs(e), initial=0.0)) + float(np.abs(ah).max(initial=0))
        )
        tol_d = 1e-9 * (
            1.0 + float(np.max(np.abs(sol[nz:]), initial=0.0)) + float(rho.max(initial=0))
        )
        if np.any(ah > hi_h + tol_p) or np.any(ah < lo_h - tol_p):
            return None
        act = (st_h != 0) & ~eq_h
        if np.any(lam_h[act] * st_h[act] < -tol_d):
            return None
        if ns:
            free = st_s == 0
            if np.any(v_u[free] > tol_p) or np.any(v_l[free] > tol_p):
                return None
            bound = np.abs(st_s) == 1
            if np.any(mu[bound] * st_s[bound] < -tol_d) or np.any(
                np.abs(mu[bound]) > rho[bound] + tol_d
            ):
                return None
            if np.any(v_u[st_s == 2] < -tol_p) or np.any(v_l[st_s == -2] < -tol_p):
                return None
        eps_r = np.where(st_s == 2, v_u, np.where(st_s == -2, v_l, 0.0)).clip(min=0.0)
        parts = [z, eps_r]
        if self._sparse:
            parts.insert(0, self._Xth @ th + self._Sx @ z)
        w = np.concatenate(parts)
        # OSQP-convention duals, useful as the next warm start
        yw = np.array(y, dtype=float)
        yw[r0 : r0 + nh] = lam_h
        if ns:
            yw[r0 + nh : r0 + nh + ns] = np.maximum(mu, 0.0)
            yw[r0 + nh + ns : r0 + nlu] = np.minimum(mu, 0.0)[jl]
            yw[r0 + nlu :] = -rho - g2 * eps_r + np.maximum(mu, 0.0) - np.minimum(mu, 0.0)
        # OSQP objective 1/2 w'Pw + q'w (P stored as its upper triangle)
        Pd = self._P_dense
        qv = self._v[self._sl_q]
        obj = float(w @ (Pd @ w) - 0.5 * (np.diagonal(Pd) * w) @ w + qv @ w)
        return w, yw, obj

    def _input_window(self, up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Inputs reachable from ``up`` in one step: box intersected with the rate window.

        If the box cannot be reached in one step (``up`` far outside it) the rate
        limit wins and the window is the rate-limited point closest to the box.
        """
        r_lo = up + self._dumin
        r_hi = up + self._dumax
        lo = np.minimum(np.maximum(self._umin, r_lo), r_hi)
        hi = np.maximum(np.minimum(self._umax, r_hi), r_lo)
        return lo, hi

    def _evaluate_plan(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, float]:
        """Prediction, soft violation and cost of a plan ``z`` from the condensed model.

        Used for fallback plans; NaN where the data of this call were not finite.
        """
        th = self._theta
        ns, r0 = self._ns, self._r0
        nh, nlu = self._nh - r0, self._nlu - r0
        with np.errstate(invalid="ignore", over="ignore"):
            X = (self._Xth @ th + self._Sx @ z).reshape(self.Np, self.n)
            Y = X if self._y_is_x else X @ self._C.T
            g = self._Gsem @ z + self._Csem @ th
            eps = np.zeros(ns)
            if ns:
                eps = np.maximum(eps, g[nh : nh + ns] - self._Ub[r0 + nh : r0 + nh + ns])
                np.maximum.at(eps, self._soft2_slack, self._Lb[r0 + nh + ns :] - g[nh + ns : nlu])
            Lc = self._Lth_c @ th
            cost = float(
                z @ self._H @ z
                + (self._Fq @ th) @ z
                + Lc @ Lc
                + self._rho_s @ eps
                + self._gamma_s @ eps**2
            )
            slack_max = float(eps.max()) if ns else 0.0
        if not math.isfinite(cost):
            cost = float("nan")
        return X, Y, slack_max, cost

    # ------------------------------------------------------------------ info
    @property
    def n_variables(self) -> int:
        """Number of QP decision variables (states in the sparse form, inputs, slacks)."""
        return self._nv

    @property
    def n_constraints(self) -> int:
        """Number of QP constraint rows."""
        return self._nA


def _check_penalty_arg(soft_penalty: Any) -> None:
    if isinstance(soft_penalty, Mapping):
        unknown = set(soft_penalty) - set(_SOFT_GROUPS)
        if unknown:
            raise ValueError(
                f"soft_penalty keys must be among {_SOFT_GROUPS}, got {sorted(unknown)}"
            )
        return
    if np.ndim(soft_penalty) != 0:
        raise ValueError(
            "soft_penalty must be a scalar or a mapping {group: scalar or per-row vector}"
        )
    _vector("soft_penalty", soft_penalty, 1, allow_inf=True)
