r"""The DMC's rolling optimisation on the shared QP core (004 §4.2).

QP at every step (acceleration units, m/s²)::

    min_ΔU  ‖w − ŷ_P0 − A ΔU‖²_Q + ‖ΔU‖²_R ,   Q = q I_P,  R = r I_L
    s.t.    |Δu(k+j)| ≤ Δu_max                                      (hard)
            u_lo(k+j) ≤ u(k−1) + Σ_{l≤j} Δu(k+l) ≤ u_hi(k+j)        (soft, exact L1 penalty)

*Realisation on the core* (:class:`~train_envs.mpc.LinearMPC`, Δu
form): the model is an FIR shift register of the input level, ``z_1(k+1) = u(k)``,
``z_{j+1}(k+1) = z_j(k)`` (j < P), with two outputs ``y₁ = Σ_j g_j z_j`` (pulse-response
taps ``g_j = a_j − a_{j−1}``) and ``y₂ = z_1`` (the input level). From ``x0 = 0`` and the
previous level u(k−1) the core predicts ``y₁(k+i) = u(k−1) a_i + Σ_j a_{i−j+1} Δu(k+j)``
— since ``Σ g_j u_{i−j} = Σ a_j Δu_{i−j}`` its condensed sensitivity *is* the dynamic
matrix A. Passing ``r_i = w_i − ŷ_P0,i + u(k−1) a_i`` on y₁ (weight q; y₂ has weight 0)
makes the core's cost the DMC cost. y₂ carries the per-stage soft bounds [u_lo, u_hi]
(the envelope at the speeds the current plan predicts, minus the feedforward); the
core's hard Δu box is the rate bound. The exact-penalty weight ``soft_penalty`` is
large against the cost gradients in these units and moderate enough to keep the QP
well conditioned; OSQP's tolerance ``osqp_eps`` applies to eps_abs and eps_rel.

*Classic law first*: each step first forms the whole unconstrained move plan
``ΔU = K (w − ŷ_P0)``, ``K = (AᵀQA + R)⁻¹AᵀQ`` (:func:`~.step_response.dmc_gain`), and
keeps it when every ``|Δu| ≤ Δu_max`` and every level lies inside the envelope at its
stage: then no row is active and the plan *is* the QP's optimum (zero slacks). The
envelope is first checked against the box :meth:`~train_envs.trains.TrainParams.envelope_box`
over the plan's speed range, per stage only when that box is too tight. The other
steps go through the core and OSQP; the core is told the plan of a classic step
(:meth:`LinearMPC.adopt_unconstrained`), so its warm start is what its own
unconstrained shortcut would have left. Measurements: ``docs/design/dmc.md``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from train_envs.mpc import LinearMPC, MPCSolution
from train_envs.trains import TrainParams

#: solver fields (solve time, iterations, fallback, slack, status) of a step decided by
#: the unconstrained law (solved, no OSQP)
UNCONSTRAINED_INFO = (0.0, 0, 0.0, 0.0, 1)


def _max_abs(x: np.ndarray) -> float:
    """max |x_i| of a short vector (two reductions instead of abs + max)."""
    return max(float(x.max()), -float(x.min()))


class DMCProblem:
    """The DMC QP on :class:`LinearMPC` with the classic law first.

    Args:
        a: step coefficients a_1 … a_N; ``K``: the (L, P) plan gain of :func:`dmc_gain`.
        q, r: weights; ``du_max``: the rate bound Δu_max (inf: none).
        level_bound: a level bound far outside reach (construction-time bounds of y₂;
            the per-call bounds replace them).
        soft_penalty, osqp_eps: exact-penalty weight and OSQP tolerance.
    """

    def __init__(
        self,
        a: np.ndarray,
        K: np.ndarray,
        *,
        q: float,
        r: float,
        du_max: float,
        level_bound: float,
        soft_penalty: float,
        osqp_eps: float,
    ) -> None:
        P = K.shape[1]
        self.P = P
        self.L = K.shape[0]
        self.a_P = a[:P]
        self.K = K
        big = level_bound
        # no rate bound at all: a bound far outside reach keeps the core's Δu rows
        # (LinearMPC needs du_min/du_max to build this problem)
        #: the Δu box of the core rows (what the classic plan is checked against)
        self.du_rows = du_max if math.isfinite(du_max) else 100.0 * big
        g = np.diff(np.concatenate([[0.0], a[:P]]))  # pulse-response taps
        A = np.eye(P, k=-1)
        B = np.zeros((P, 1))
        B[0, 0] = 1.0
        C = np.zeros((2, P))
        C[0] = g
        C[1, 0] = 1.0
        du = self.du_rows
        self.core = LinearMPC(
            A, B, C,
            Np=P,
            Nc=self.L,
            Q=np.diag([q, 0.0]),
            R=r,
            u_min=-np.inf,
            u_max=np.inf,
            du_min=-du,
            du_max=du,
            y_min=[-np.inf, -big],
            y_max=[np.inf, big],
            soft_penalty=soft_penalty,
            # the DMC's bounds are active on a few % of the steps: the exact
            # unconstrained optimum spares OSQP the rest (see LinearMPC)
            unconstrained_first=True,
            osqp_settings={"eps_abs": osqp_eps, "eps_rel": osqp_eps},
        )
        # QP data: the reference of both outputs, the level bounds, x0 = 0
        self._r = np.zeros((P, 2))
        self._y_min = np.zeros((P, 1))
        self._y_max = np.zeros((P, 1))
        self._x0 = np.zeros(P)

    def optimise(
        self,
        w: Sequence[float] | np.ndarray,
        y_free: Sequence[float] | np.ndarray,
        u_prev: float,
        u_lo: Sequence[float] | np.ndarray | float = -np.inf,
        u_hi: Sequence[float] | np.ndarray | float = np.inf,
    ) -> MPCSolution:
        """Solve ``min ‖w − ŷ_P0 − AΔU‖²_Q + ‖ΔU‖²_R`` s.t. the rate box and the level
        bounds ``u_lo``/``u_hi`` of stages k … k+P−1 (scalars or (P,))."""
        r = self._r
        np.subtract(w, y_free, out=r[:, 0])
        r[:, 0] += u_prev * self.a_P
        self._y_min[:, 0] = u_lo
        self._y_max[:, 0] = u_hi
        return self.core.solve(
            self._x0, np.array([u_prev]), r, y_min=self._y_min, y_max=self._y_max
        )

    def classic_plan(
        self,
        e_w: list[float],
        u_prev: float,
        v_plan: list[float],
        train: TrainParams,
        ff_N: float,
        M: float,
    ) -> tuple[np.ndarray, np.ndarray, tuple[list[float], list[float]] | None]:
        """``(ΔU, levels, envelope)`` of the classic law ``ΔU = K e_w`` (e_w = w − ŷ_P0);
        ΔU is None when the plan leaves the rate box or the envelope
        ``[(lo − ff)/M, (hi − ff)/M]`` at the speeds ``v_plan``. ``envelope``: the
        per-stage force bounds (lo, hi) when they were evaluated, else None."""
        dU = np.dot(self.K, e_w)
        lev = np.cumsum(dU)
        lev += u_prev
        if not _max_abs(dU) <= self.du_rows:
            return None, lev, None
        lev_l = lev.tolist()
        lo_b, hi_b = train.envelope_box(min(v_plan), max(v_plan))
        if min(lev_l) >= (lo_b - ff_N) / M and max(lev_l) <= (hi_b - ff_N) / M:
            return dU, lev, None
        lo, hi = train.envelope_lists(v_plan)
        levels = lev_l + [lev_l[-1]] * (self.P - self.L)  # held after the last move
        inside = all(
            (lo_i - ff_N) / M <= x <= (hi_i - ff_N) / M
            for lo_i, hi_i, x in zip(lo, hi, levels, strict=True)
        )
        return (dU if inside else None), lev, (lo, hi)
