r"""The OSQP adapter of :class:`~train_envs.mpc.LinearMPC`: the only module touching OSQP.

Default settings: ``eps_abs = eps_rel = 1e-6``, ``max_iter = 100`` (an iteration cap:
a solve that reaches it is finished exactly, ``mpc/recovery.py``),
``polishing = False``, ``check_dualgap = False``, ``check_termination = 10``,
``verbose = False``, ``warm_starting = True``; the OSQP 0.6 names ``polish`` and
``warm_start`` are accepted.  Status values are OSQP's (1 solved, 2 solved inaccurate,
3 primal infeasible, 7 maximum iterations, 8 time limit, ...) plus -1 (invalid,
non-finite input) and -2 (solver exception); ``"solved (unconstrained)"`` names a step
solved by the unconstrained optimum.  ``_BIG = 1e30`` is OSQP's infinity.

:class:`_Backend` calls OSQP's compiled solver object (``OSQP._solver``) directly when
it has the needed methods -- the Python wrapper's ``update`` and ``solve`` cost more
than a small solve -- and the public API otherwise (``fast_osqp=False``).
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from typing import Any

import numpy as np
import osqp
import scipy.sparse as sp

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
    "max_iter": 100,
    "polishing": False,
    "check_dualgap": False,
    "check_termination": 10,
    "verbose": False,
    "warm_starting": True,
}
_RENAMED_SETTINGS = {"polish": "polishing", "warm_start": "warm_starting"}

_Stats = tuple[int, str, int, float, float, int]


def osqp_settings_with(overrides: Mapping[str, Any] | None) -> dict[str, Any]:
    """The default OSQP settings updated by ``overrides`` (OSQP 0.6 names accepted)."""
    settings = dict(_DEFAULT_OSQP)
    for k, v in dict(overrides or {}).items():
        settings[_RENAMED_SETTINGS.get(k, k)] = v
    return settings


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

    def update_mat(self, Px: np.ndarray, Ax: np.ndarray | None) -> None:
        """New values of ``P`` and ``A`` (``Ax=None``: ``A`` unchanged)."""
        if self.raw is not None:
            rc = self.raw.update_data_mat(Px, None, Ax, None)
            if rc:
                raise RuntimeError(f"OSQP rejected the matrix update (error {rc})")
        elif Ax is None:
            self.prob.update(Px=Px)
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

    def step(
        self,
        q: np.ndarray,
        l: np.ndarray,  # noqa: E741
        u: np.ndarray,
        ws_x: np.ndarray | None,
        ws_y: np.ndarray | None,
    ) -> tuple[np.ndarray, np.ndarray, _Stats] | None:
        """One per-step solve: new ``q, l, u``, warm start ``(ws_x, ws_y)`` unless None,
        OSQP; returns ``x, y, stats`` as :meth:`solve`, None if OSQP rejected the vectors.
        """
        raw = self.raw
        if raw is not None and not self.polishing:
            # compiled solver object, inlined: the wrapper costs more than small solves
            if raw.update_data_vec(q, l, u):
                return None
            if ws_x is not None:
                raw.warm_start(ws_x, ws_y)
            raw.solve()
            sol = raw.solution
            info = raw.info
            val = info.status_val
            status = self._status_names.get(val) or self.status_name(val, info)
            return sol.x, sol.y, (val, status, info.iter, info.solve_time, info.obj_val, 0)
        if self.update_vec(q, l, u):
            return None
        if ws_x is not None:
            self.warm_start(ws_x, ws_y)
        return self.solve()

    def reset(self, n_var: int, n_row: int) -> None:
        """OSQP's initial ``rho`` and a zero primal/dual iterate."""
        self.prob.update_settings(rho=self.rho0)
        self.warm_start(np.zeros(n_var), np.zeros(n_row))

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
