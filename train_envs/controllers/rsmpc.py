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
1e-10 tolerance, so holds decided on OSQP's costs followed solver noise.  Each
candidate is therefore first evaluated in closed form: the unconstrained optimum with
the held increments pinned is affine in the stage data, and so are its constraint rows
and weighted cost residuals (:meth:`LinearMPC.unconstrained_affine`, composed once per
weight or W change with the stage vector of the trigger: one matrix-vector product per
candidate, ``J^M = ‖r‖²`` as a sum of squares, accurate to its own size rather than to
the constant's).  When no row binds, that optimum is the QP's: the candidate is decided
without the QP core (on the undisturbed run all but a handful of the candidates).
Otherwise its cost is still a lower bound on ``J^M`` -- every constraint and slack
penalty can only raise the optimum -- so a bound above ``J^1`` rejects ``M`` without a
solve (the screen; when the optimum was feasible the bound *is* the cost), and only the
rest goes through the QP core (bounds, the core's own exact shortcut, OSQP).  With
exact costs the undisturbed run holds 1 step at 300 of 372 triggers (β = 3); under paper
001's disturbance the counts are unchanged from the OSQP-only runs (README table).

Info per step: ``triggered`` (bool), ``hold_steps`` (M of the current hold),
``triggers`` (so far in the episode), ``candidates`` (hold lengths examined this step),
``closed_form`` (those decided by their feasible closed-form optimum), ``qp_solves``
(those solved through the QP core; the rest were screened out), and the usual solver
fields (summed over the QP solves of a trigger, zero while holding).
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
                "closed_form": 0,
                "candidates": 0,
                "solve_time_s": 0.0,
                "iterations": 0,
                "fallback": False,
                "slack_max": 0.0,
            }
        data = self._stage_data(obs)
        h = data["h"]  # the stage vector the closed forms read
        relaxed0 = self._relaxed
        sols: dict[int, MPCSolution] = {}  # solved through the QP core
        closed: dict[int, tuple] = {}  # optimum in closed form (no row binds)
        screened = 0

        def accept(M: int, J1: float) -> bool:
            nonlocal screened
            prob = self._problem(M)
            ev = self._closed_form(prob, h)
            if ev is not None:
                if ev[0] > J1:  # J^M >= its unconstrained cost > J^1: rejected
                    screened += 1
                    return False
                if ev[1]:  # the unconstrained optimum is feasible: it is the QP's
                    closed[M] = ev
                    return True
            else:
                lb = self._lower_bound(prob, data)
                if lb is not None and lb > J1:
                    screened += 1
                    return False
            r0 = self._relaxed
            sols[M] = self._solve(prob, data)
            return self._relaxed == r0 and self._accept(sols[M], J1)

        # P^1 feasible: solved, no slack, terminal set kept (ΔU_f^1 ≠ ∅ in eq. 29)
        feasible1 = accept(1, math.inf) and self._relaxed == relaxed0
        J1 = closed[1][0] if 1 in closed else sols[1].cost
        best = 1
        Mx = self.M_max
        if feasible1 and Mx > 1:
            if self.search == "linear":
                for M in range(Mx, 1, -1):
                    if accept(M, J1):
                        best = M
                        break
            elif self.search == "warm":
                # invariant: lo accepted, every M > hi rejected (interval assumption)
                lo, hi = 1, Mx
                g_M = min(max(self._hold_M, 2), Mx)  # last trigger's M first
                if accept(g_M, J1):
                    lo = g_M
                    if g_M < hi:
                        if accept(g_M + 1, J1):
                            lo = g_M + 1
                        else:
                            hi = g_M
                else:
                    hi = g_M - 1
                while lo < hi:
                    mid = (lo + hi + 1) // 2
                    if accept(mid, J1):
                        lo = mid
                    else:
                        hi = mid - 1
                best = lo
            elif accept(Mx, J1):
                best = Mx
            else:
                lo, hi = 1, Mx - 1
                while lo < hi:
                    mid = (lo + hi + 1) // 2
                    if accept(mid, J1):
                        lo = mid
                    else:
                        hi = mid - 1
                best = lo
        self._hold_left = best - 1
        self._hold_M = best
        self._triggers += 1
        n_exam = len(sols) + len(closed) + screened
        solve_time = sum(s.solve_time_s for s in sols.values())
        iters = sum(s.iterations for s in sols.values())
        if best in closed:
            ev = closed[best]
            du0 = self._adopt(self._problems[best], h)
            fallback, slack, status, J = False, 0.0, 1, ev[0]
        else:
            sol = sols[best]
            du0 = float(sol.u0[0])
            fallback, slack, status, J = sol.fallback, sol.slack_max, sol.status_val, sol.cost
        cmd = self._command(obs, data["u_prev"] + du0)
        # what was actually sent
        self._u_hold = (cmd.item() if cmd.size == 1 else float(cmd.sum())) / self._mi
        return cmd, {
            "triggered": True,
            "hold_steps": best,
            "triggers": self._triggers,
            "qp_solves": len(sols),
            "closed_form": len(closed),
            "candidates": n_exam,
            "solve_time_s": solve_time,
            "iterations": iters,
            "fallback": fallback,
            "slack_max": slack,
            "status_val": status,
            "J": J,
            "J1": J1,
            "terminal_relaxed": self._relaxed,
        }
