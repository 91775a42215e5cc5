r"""Paper 001's robust self-triggered MPC (RSMPC, §3, eq. 21–29) on the tube MPC.

At a trigger time ``t_l`` the controller measures the state, solves for the largest
hold length ``M ∈ [1, N−1]`` whose problem :math:`\mathcal P_N^M` is feasible and not
worse than the one-step problem, applies the increment ``Δū`` and then holds the
command for ``M`` control periods without measuring or solving (eq. 23–24)::

    J^M = (1/β) (‖Δu_0‖²_R + Σ_{i<M} ‖x_i − x_s,i‖²_Q)
          + Σ_{i=M}^{M+N−1} (‖x_i − x_s,i‖²_Q + ‖Δu_i‖²_R) + ‖x_{M+N} − x_s,M+N‖²_P   (25)

subject to the model, ``Δu_1 = … = Δu_{M−1} = 0`` (the held command), the tightened
constraints ``x_i ∈ X ⊖ R_i^M`` with the self-triggered tube ``R_i^M`` (open loop
while held, LQR feedback afterwards; :func:`.model.tube_tightening` with
``hold = M``) and the terminal set ``Σ ⊖ R_{M+N}^M`` (26);

    M* = max{M | P_N^M feasible, P_N^1 feasible, J^{M*} ≤ J^{1*}}                    (29)

``β ≥ 1`` discounts the cost of the held stages (eq. 22, 30–32: the closed-loop cost
is at most β J*(t_0)); it enters as in eq. (25)/(29), inside ``J^M`` and ``J^1``, not
as ``J^M ≤ β J^1``.  The hold is enforced through the shared QP core as equal
per-stage bounds on the increments and the ``1/β`` weights as per-stage weight scales;
one QP per ``M`` (horizon ``M + N``), built once and kept across episodes.

One trigger's decision, step by step (:class:`HoldDecision`):

1. the stage vector of the measured state (:meth:`TubeMPC._stage_data`);
2. ``P^1``: decided (below) with ``J^1 = ∞``; infeasible: hold 1;
3. the search over ``M`` (``search``: ``"linear"`` scans down from ``N − 1``;
   ``"bisect"`` tries ``N − 1`` then bisects; ``"warm"`` tries the last trigger's
   ``M`` and ``M + 1`` then bisects -- the last two assume that the accepted holds
   form an interval ``[1, M*]``), each candidate ``M`` decided by the first step that
   can: (a) the lower-bound screen (the closed-form cost, or the core's unconstrained
   cost, above ``J^1``: rejected), (b) the closed form (no row binds: accepted with
   its exact cost), (c) the QP core (accepted when solved without slack, fallback or
   a dropped terminal set, and ``J^M ≤ J^1``);
4. the command: the chosen candidate's plan (closed form or QP), held ``M`` steps.

Info per step: ``triggered``, ``hold_steps`` (M of the current hold), ``triggers``,
``candidates`` (hold lengths examined this step), ``closed_form`` (decided in closed
form), ``qp_solves`` (solved through the QP core; the rest were screened out), and the
solver fields (summed over the QP solves of a trigger, zero while holding).  Search
measurements and the exact-cost rationale: ``docs/design/tube_mpc.md``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from train_envs.controllers.base import ControlContext, Observation, TunableParam
from train_envs.controllers.tube.problem import TubeProblem
from train_envs.controllers.tube.stage import StageData
from train_envs.controllers.tube.tube_mpc import TubeMPC
from train_envs.mpc import MPCSolution

__all__ = ["HoldDecision", "RobustSelfTriggeredMPC"]


@dataclass
class HoldDecision:
    """The hold lengths examined at one trigger and how each was decided."""

    ctrl: RobustSelfTriggeredMPC
    data: StageData
    sols: dict[int, MPCSolution] = field(default_factory=dict)  # via the QP core
    closed: dict[int, tuple[float, bool]] = field(default_factory=dict)  # closed form
    screened: int = 0  # rejected by the lower bound without a solve

    def accept(self, M: int, J1: float) -> bool:
        """Whether hold ``M`` is accepted against ``J^1`` (step 3 of the module
        docstring): the screen, then the closed form, then the QP core."""
        ctrl = self.ctrl
        prob = ctrl._problem(M)
        ev = ctrl._closed_form(prob, self.data["h"])
        bound = ev[0] if ev is not None else ctrl._lower_bound(prob, self.data)
        if self._screened_out(bound, J1):
            return False
        if ev is not None and ev[1]:  # the unconstrained optimum is feasible: the QP's
            self.closed[M] = ev
            return True
        return self._accepted_by_qp(M, prob, J1)

    def _screened_out(self, bound: float | None, J1: float) -> bool:
        """(a) ``J^M ≥ bound > J^1``: rejected without a solve."""
        if bound is not None and bound > J1:
            self.screened += 1
            return True
        return False

    def _accepted_by_qp(self, M: int, prob: TubeProblem, J1: float) -> bool:
        """(c) Solve through the QP core; accepted when the terminal set was kept and
        the solution is feasible with ``J^M ≤ J^1``."""
        ctrl = self.ctrl
        r0 = ctrl._relaxed
        self.sols[M] = ctrl._solve(prob, self.data)
        return ctrl._relaxed == r0 and ctrl._accept(self.sols[M], J1)

    def cost(self, M: int) -> float:
        """``J^M`` of an accepted or solved candidate."""
        return self.closed[M][0] if M in self.closed else self.sols[M].cost

    @property
    def examined(self) -> int:
        return len(self.sols) + len(self.closed) + self.screened


def _largest_accepted(accept: Callable[[int], bool], lo: int, hi: int) -> int:
    """Bisection for the largest accepted ``M`` in ``[lo, hi]``, ``lo`` accepted and the
    accepted holds an interval (every ``M`` above a rejected one rejected)."""
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if accept(mid):
            lo = mid
        else:
            hi = mid - 1
    return lo


def search_linear(accept: Callable[[int], bool], M_max: int, last_M: int) -> int:
    """The largest accepted ``M`` by a scan down from ``M_max`` (exact)."""
    for M in range(M_max, 1, -1):
        if accept(M):
            return M
    return 1


def search_bisect(accept: Callable[[int], bool], M_max: int, last_M: int) -> int:
    """``M_max`` if accepted, else bisection on ``[1, M_max − 1]``."""
    if accept(M_max):
        return M_max
    return _largest_accepted(accept, 1, M_max - 1)


def search_warm(accept: Callable[[int], bool], M_max: int, last_M: int) -> int:
    """The last trigger's ``M`` first, then ``M + 1`` if it was accepted, then bisection
    in what is left (a steady hold length costs three candidates)."""
    lo, hi = 1, M_max  # invariant: lo accepted, every M > hi rejected
    g_M = min(max(last_M, 2), M_max)
    if accept(g_M):
        lo = g_M
        if g_M < hi:
            if accept(g_M + 1):
                lo = g_M + 1
            else:
                hi = g_M
    else:
        hi = g_M - 1
    return _largest_accepted(accept, lo, hi)


SEARCHES: dict[str, Callable[[Callable[[int], bool], int, int], int]] = {
    "bisect": search_bisect,
    "warm": search_warm,
    "linear": search_linear,
}


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
        if search not in SEARCHES:
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

    def _held(self, M: int) -> tuple[np.ndarray, np.ndarray]:
        """The output stages ``1..M−1`` and the increments ``0..M−1`` (eq. 25)."""
        q = np.zeros(M + self.N, dtype=bool)
        q[: M - 1] = True
        s = np.zeros(M + self.N, dtype=bool)
        s[:M] = True
        return q, s

    def _beta(self) -> float:
        return self._params["beta"]

    def _stage_scales(self, M: int) -> dict[str, np.ndarray] | None:
        """``1/β`` on the held stages (:meth:`_held`; eq. 25)."""
        ib = 1.0 / self._params["beta"]
        q_held, s_held = self._held(M)
        return {"Q": np.where(q_held, ib, 1.0), "S": np.where(s_held, ib, 1.0)}

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

    def _hold(self, obs: Observation) -> tuple[np.ndarray, Mapping[str, Any]]:
        """Between triggers: no measurement, no QP (eq. 23)."""
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

    def _decide(self, dec: HoldDecision) -> tuple[int, float]:
        """Steps 2–3: ``(M*, J^1)``."""
        relaxed0 = self._relaxed
        # P^1 feasible: solved, no slack, terminal set kept (ΔU_f^1 ≠ ∅ in eq. 29)
        feasible1 = dec.accept(1, math.inf) and self._relaxed == relaxed0
        J1 = dec.cost(1)
        if not feasible1 or self.M_max <= 1:
            return 1, J1
        search = SEARCHES[self.search]
        return search(lambda M: dec.accept(M, J1), self.M_max, self._hold_M), J1

    def _apply(
        self, obs: Observation, dec: HoldDecision, best: int, J1: float
    ) -> tuple[np.ndarray, Mapping[str, Any]]:
        """Step 4: send the chosen candidate's first increment and start the hold."""
        self._hold_left = best - 1
        self._hold_M = best
        self._triggers += 1
        sols = dec.sols
        solve_time = sum(s.solve_time_s for s in sols.values())
        iters = sum(s.iterations for s in sols.values())
        if best in dec.closed:
            du0 = self._adopt(self._problems[best], dec.data["h"])
            fallback, slack, status, J = False, 0.0, 1, dec.closed[best][0]
        else:
            sol = sols[best]
            du0 = float(sol.u0[0])
            fallback, slack, status, J = sol.fallback, sol.slack_max, sol.status_val, sol.cost
        cmd = self._command(obs, dec.data["u_prev"] + du0)
        # what was actually sent
        self._u_hold = (cmd.item() if cmd.size == 1 else float(cmd.sum())) / self._mi
        return cmd, {
            "triggered": True,
            "hold_steps": best,
            "triggers": self._triggers,
            "qp_solves": len(sols),
            "closed_form": len(dec.closed),
            "candidates": dec.examined,
            "solve_time_s": solve_time,
            "iterations": iters,
            "fallback": fallback,
            "slack_max": slack,
            "status_val": status,
            "J": J,
            "J1": J1,
            "terminal_relaxed": self._relaxed,
        }

    def compute(self, obs: Observation) -> tuple[np.ndarray, Mapping[str, Any]]:
        self._steps += 1
        if self._hold_left > 0:
            return self._hold(obs)
        dec = HoldDecision(self, self._stage_data(obs))
        best, J1 = self._decide(dec)
        return self._apply(obs, dec, best, J1)
