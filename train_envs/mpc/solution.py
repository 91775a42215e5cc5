"""Result of one :meth:`~train_envs.mpc.LinearMPC.solve` call.

:class:`MPCSolution` carries the first move, the plan, the solver's status and
timing and the plan's cost; the predicted states and outputs are assembled only
when read (:class:`_Predictions`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from train_envs.mpc.osqp_backend import _SOLVED


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

    def solver_info(self) -> dict[str, Any]:
        """The solver figures a controller reports in its step info: solve and overhead
        time, iterations, fallback, largest slack and the status code."""
        return {
            "solve_time_s": self.solve_time_s,
            "iterations": self.iterations,
            "fallback": self.fallback,
            "slack_max": self.slack_max,
            "status_val": self.status_val,
            "overhead_s": self.overhead_s,
        }

    def __repr__(self) -> str:
        return (
            f"MPCSolution(u0={self.u0!r}, status={self.status!r}, iterations={self.iterations}, "
            f"solve_time_s={self.solve_time_s:.3g}, slack_max={self.slack_max:.3g}, "
            f"fallback={self.fallback}, cost={self.cost:.6g})"
        )


class _Predictions:
    """Deferred ``(X, Y)`` of one solve: copies of the QP solution and data it needs.

    ``mpc`` is the :class:`~train_envs.mpc.linear_mpc.LinearMPC` that solved (typed
    ``Any``: this module sits below it).
    """

    __slots__ = ("mpc", "x", "th")

    def __init__(self, mpc: Any, x: np.ndarray, th: np.ndarray) -> None:
        self.mpc, self.x = mpc, x
        self.th = None if mpc._sparse else th.copy()

    def __call__(self) -> tuple[np.ndarray, np.ndarray]:
        return self.mpc._predictions(self.x, self.th)
