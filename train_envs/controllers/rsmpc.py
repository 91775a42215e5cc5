r"""Paper 001's robust self-triggered MPC (RSMPC, §3, eq. 21–29) on the tube MPC.

At a trigger time ``t_l`` the controller measures the state, solves for the largest
hold length ``M ∈ [1, N−1]`` whose problem :math:`\mathcal P_N^M` is feasible and not
worse than the one-step problem, applies the increment ``Δū`` and then holds the
command for ``M`` control periods without measuring or solving (eq. 23–24)::

    J^M = (1/β) (‖Δu_0‖²_R + Σ_{i<M} ‖x_i − x_s,i‖²_Q)
          + Σ_{i=M}^{M+N−1} (‖x_i − x_s,i‖²_Q + ‖Δu_i‖²_R) + ‖x_{M+N} − x_s,M+N‖²_P   (25)

subject to the model, ``Δu_1 = … = Δu_{M−1} = 0`` (the held command), the tightened
constraints ``x_i ∈ X ⊖ R_i^M`` with the self-triggered tube ``R_i^M`` (open loop
while held, LQR feedback afterwards; :func:`~train_envs.controllers.tube_mpc.
tube_tightening` with ``hold = M``) and the terminal set ``Σ ⊖ R_{M+N}^M`` (26);

    M* = max{M | P_N^M feasible, P_N^1 feasible, J^{M*} ≤ J^{1*}}                    (29)

``β ≥ 1`` discounts the cost of the held stages and so trades optimality
(eq. 22, 30–32: the closed-loop cost is at most β J*(t_0)) against switching.  β
enters as in eq. (25)/(29) -- inside ``J^M`` and ``J^1`` as the ``1/β`` weight of the
first stages, compared by ``J^M ≤ J^1`` -- not as ``J^M ≤ β J^1`` on undiscounted
costs.  With ``β = 1`` the controller is the tube MPC with horizon ``N + 1`` except
where holding is free.  The hold is enforced through the shared QP core as equal
per-stage bounds on the increments (:meth:`LinearMPC.set_base_bounds`) and the
``1/β`` weights as per-stage weight scales (``stage_scales`` of :class:`LinearMPC`);
one QP per ``M`` (horizon ``M + N``), built once and kept across episodes.

Search (our choice; the paper does not say how ``M*`` is found).  All searches solve
``P^1`` first and assume that the accepted hold lengths form an interval ``[1, M*]``
(true when ``J^M − J^1`` grows with ``M``, the typical case), except the exact
``search="linear"``, which scans down from ``N − 1`` and stops at the first accepted
``M``.  ``"bisect"``: ``M = N − 1`` (accepted: done), else bisection on ``[1, N−2]``;
``"warm"`` (default): the previous trigger's ``M`` first, then ``M + 1`` if it was
accepted (so a steady hold length costs three QPs), then bisection in what is left.
On paper 001's scenario (4 seeds) the QPs per trigger were, for N = 5, 10, 15:
warm 2.3, 3.7, 4.4; bisect 2.3, 4.4, 5.1; linear 2.5, 5.6, 9.8, with the same
stopping errors within 1.5 cm and switch counts within 4 %.  The ``M − 1`` steps after a
trigger cost nothing.

Exact costs.  ``J^M ≤ J^1`` compares numbers that are small when the train tracks well
(of order 1e-7 … 1e-5 on the undisturbed paper 001 run, each the difference of a QP
objective and a constant of order 1e3).  OSQP's objective is not accurate at that
level: its L1 slack penalty on slacks at solver precision alone adds ~1e-7, even at a
1e-10 tolerance, so holds decided on OSQP's costs followed solver noise.  The
candidates are therefore first solved exactly (the unconstrained optimum with the held
increments pinned, kept when no row binds, see :class:`LinearMPC`); on that run 98 % of
the candidate solves are decided this way.  With exact costs the undisturbed run holds
1 step at 300 of 372 triggers (β = 3); under paper 001's disturbance the counts are
unchanged from the OSQP-only runs (README table).

Screening.  A candidate ``M`` is first bounded from below by the cost of its
unconstrained minimiser (held increments pinned; :meth:`LinearMPC.unconstrained_cost`):
every constraint and slack penalty can only raise ``J^M``, so a bound above ``J^1``
rejects ``M`` without setting bounds or solving -- the decision exact costs give (when
the minimiser is feasible the bound is the solve's cost, bit for bit; otherwise only
OSQP's tolerance could have put its cost at or below ``J^1``).  On
paper 001's undisturbed run this discards 40 % of the candidates (618 of 1518 over six
episodes), most of the rejected holds; accepted candidates are solved in full (their
feasibility and plan are needed).

Info per step: ``triggered`` (bool), ``hold_steps`` (M of the current hold),
``triggers`` (so far in the episode), ``candidates`` (hold lengths examined this step),
``qp_solves`` (those solved in full, the others were screened out), and the usual
solver fields (summed over the QPs of a trigger, zero while holding).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from train_envs.controllers.base import ControlContext, Observation, TunableParam
from train_envs.controllers.mpc_core import MPCSolution
from train_envs.controllers.tube_mpc import TubeMPC

__all__ = ["RobustSelfTriggeredMPC"]


class RobustSelfTriggeredMPC(TubeMPC):
    """Robust self-triggered MPC ("rsmpc") of paper 001; see the module docstring.

    Tunable: ``q_s``, ``q_v``, ``r_du``, ``w_scale`` (as :class:`TubeMPC`) and ``beta``
    (β ≥ 1, eq. 22/25).  Needs ``N >= 2`` (holds ``M ∈ [1, N−1]``).
    """

    name = "rsmpc"
    PARAMS: tuple[TunableParam, ...] = TubeMPC.PARAMS + (
        TunableParam("beta", 1.0, 20.0, 3.0, log=True, description="suboptimality factor β"),
    )

    def __init__(self, scenario: Any = None, *, N: int = 10, search: str = "warm", **kw: Any):
        if isinstance(N, bool) or not isinstance(N, int | np.integer) or N < 2:
            raise ValueError(f"N must be an integer >= 2 for rsmpc (holds 1..N-1), got {N!r}")
        if search not in ("bisect", "warm", "linear"):
            raise ValueError(f"search must be 'bisect', 'warm' or 'linear', got {search!r}")
        self.search = search
        super().__init__(scenario, N=int(N), **kw)

    # ------------------------------------------------------------------ design
    @property
    def M_max(self) -> int:
        """Longest hold ``N − 1`` (001 eq. 25)."""
        return self.N - 1

    def _holds(self) -> list[int]:
        return list(range(1, self.M_max + 1))

    def _horizon(self, M: int) -> int:
        return M + self.N

    def _stage_scales(self, M: int) -> dict[str, np.ndarray] | None:
        """``1/β`` on the output stages ``1..M−1`` and the increments ``0..M−1`` (eq. 25)."""
        ib = 1.0 / self._params["beta"]
        q = np.ones(M + self.N)
        q[: M - 1] = ib
        s = np.ones(M + self.N)
        s[:M] = ib
        return {"Q": q, "S": s}

    def reset(self, ctx: ControlContext) -> None:
        super().reset(ctx)
        self._hold_left = 0
        self._u_hold = 0.0
        self._hold_M = 0
        self._triggers = 0

    # ------------------------------------------------------------------ control
    def _accept(self, sol: MPCSolution, J1: float) -> bool:
        return (
            not sol.fallback
            and sol.status_val in (1, 2)
            and sol.slack_max <= self.settings.feas_tol
            and sol.cost <= J1
        )

    def compute(self, obs: Observation) -> tuple[np.ndarray, Mapping[str, Any]]:
        self._steps += 1
        if self._hold_left > 0:  # between triggers: no measurement, no QP (eq. 23)
            self._hold_left -= 1
            return self._command(obs, self._u_hold), {
                "triggered": False,
                "hold_steps": self._hold_M,
                "triggers": self._triggers,
                "qp_solves": 0,
                "candidates": 0,
                "solve_time_s": 0.0,
                "iterations": 0,
                "fallback": False,
                "slack_max": 0.0,
            }
        data = self._stage_data(obs)
        relaxed0 = self._relaxed
        sols: dict[int, MPCSolution] = {1: self._solve(self._problem(1), data)}
        sol1 = sols[1]
        best = 1
        screened = 0
        Mx = self.M_max
        # P^1 feasible: solved, no slack, terminal set kept (ΔU_f^1 ≠ ∅ in eq. 29)
        feasible1 = self._accept(sol1, math.inf) and self._relaxed == relaxed0
        if feasible1 and Mx > 1:
            J1 = sol1.cost

            def accept(M: int) -> bool:
                nonlocal screened
                prob = self._problem(M)
                lb = self._lower_bound(prob, data)
                if lb is not None and lb > J1:  # J^M >= lb > J^1: rejected, no solve
                    screened += 1
                    return False
                r0 = self._relaxed
                sols[M] = self._solve(prob, data)
                return self._relaxed == r0 and self._accept(sols[M], J1)

            if self.search == "linear":
                for M in range(Mx, 1, -1):
                    if accept(M):
                        best = M
                        break
            elif self.search == "warm":
                # invariant: lo accepted, every M > hi rejected (interval assumption)
                lo, hi = 1, Mx
                g = min(max(self._hold_M, 2), Mx)  # last trigger's M first
                if accept(g):
                    lo = g
                    if g < hi:
                        if accept(g + 1):
                            lo = g + 1
                        else:
                            hi = g
                else:
                    hi = g - 1
                while lo < hi:
                    mid = (lo + hi + 1) // 2
                    if accept(mid):
                        lo = mid
                    else:
                        hi = mid - 1
                best = lo
            elif accept(Mx):
                best = Mx
            else:
                lo, hi = 1, Mx - 1
                while lo < hi:
                    mid = (lo + hi + 1) // 2
                    if accept(mid):
                        lo = mid
                    else:
                        hi = mid - 1
                best = lo
        sol = sols[best]
        u = data["u_prev"] + float(sol.u0[0])
        cmd = self._command(obs, u)
        self._u_hold = float(cmd.sum()) / self._mi  # what was actually sent
        self._hold_left = best - 1
        self._hold_M = best
        self._triggers += 1
        return cmd, {
            "triggered": True,
            "hold_steps": best,
            "triggers": self._triggers,
            "qp_solves": len(sols),
            "candidates": len(sols) + screened,
            "solve_time_s": sum(s.solve_time_s for s in sols.values()),
            "iterations": sum(s.iterations for s in sols.values()),
            "fallback": sol.fallback,
            "slack_max": sol.slack_max,
            "status_val": sol.status_val,
            "J": sol.cost,
            "J1": sol1.cost,
            "terminal_relaxed": self._relaxed,
        }
