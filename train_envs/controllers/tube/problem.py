r"""One QP of the tube MPC family and its per-step data (001 eq. 11–16; 25–26).

A problem is the condensed QP of :class:`LinearMPC` for one hold length ``M``
(``M = 1``: the plain tube MPC) with horizon ``Np``, its tube tightening per unit
``w̄`` and its terminal rows ``h A_cl^t``.  With ``w̄`` set (:meth:`TubeProblem.
set_disturbance_bound`) the bounds are the tightened constraint set::

    |Δu_i| ≤ rate − w̄ τ_Δu,i   (i ≥ 1; Δu_0 exact; held stages 1..M−1 pinned at 0)
    s_i ≤ s_max − w̄ τ_s,i,   v_i ≤ v_lim,i − w̄ τ_v,i,
    u_lo + w̄ τ_u,i ≤ u_i ≤ u_hi − w̄ τ_u,i

and the terminal set ``h A_cl^t ξ_N ≤ b_{N+t} − w̄ τ_{N+t}(h) − h (ξ_s,N+t − A_cl^t
ξ_s,N)`` for ``t`` in the terminal steps, whose offsets move with the reference and
are set per step (:meth:`TubeProblem.solve`).  Positions are relative to the
dead-time predicted position ``s_o`` (eq. 9 is translation invariant in ``s``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from train_envs.controllers.tube.model import ROW_DU, ROW_S, ROW_U, ROW_V
from train_envs.controllers.tube.settings import TubeSettings
from train_envs.controllers.tube.stage import StageLayout
from train_envs.mpc import LinearMPC, MPCSolution

__all__ = ["BIG", "ClosedForm", "Limits", "TubeProblem"]

BIG = 1e6  # "no bound" for rows whose offsets change per call
_ZERO1 = np.zeros(1)


@dataclass
class ClosedForm:
    """One problem's unconstrained optimum as affine maps of the trigger's stage vector.

    ``out = T @ h[cols]`` (``h`` of :mod:`.stage`) stacks the constraint
    rows written as ``row <= b`` (``nchk`` rows: first the decision ``z`` itself, ``nz``
    rows, as the upper side of the increment box, then its lower side, the tightened
    ``s``, ``v``, command rows of every stage and the terminal set) and the weighted cost
    residuals (``J = ‖r‖²``); ``Umap @ h[cols]`` is the input plan (None: it is ``z``).
    """

    cols: np.ndarray
    T: np.ndarray
    nz: int
    nchk: int
    b: np.ndarray
    Umap: np.ndarray | None


@dataclass(frozen=True)
class Limits:
    """One episode's untightened limits per unit inertial mass.

    Attributes:
        rate: increment bound ``|Δu| ≤ rate`` [m/s² per step];
        u_lo, u_hi: command box [m/s²] (brake/traction envelope at standstill);
        v_min: the speed row's lower bound (``-BIG``: none); s_max: the position row.
    """

    rate: float
    u_lo: float
    u_hi: float
    v_min: float
    s_max: float


@dataclass
class TubeProblem:
    """One QP of the family: hold ``M`` (1 = plain tube MPC) with horizon ``Np``."""

    M: int
    Np: int
    mpc: LinearMPC
    tight: np.ndarray  # (Np + t_max + 1, 4), per unit w̄
    H_N: np.ndarray  # terminal rows h A_cl^t
    weights_key: tuple | None = None
    w_bar: float = -1.0
    y_min: np.ndarray | None = None
    y_max: np.ndarray | None = None
    tau_v: np.ndarray | None = None
    tau_term: np.ndarray | None = None
    buffers: tuple | None = None  # per-step index constants and work arrays of solve
    du: np.ndarray | None = None  # per-stage increment bound (0: pinned, a held stage)
    explicit: ClosedForm | bool | None = None  # closed form (None: not made, False: n/a)
    held: tuple[np.ndarray, np.ndarray] | None = None  # stages weighted 1/β: Q, increments
    basis: np.ndarray | None = None  # (3, 4, 4) pieces of the core's terminal weight
    coef: np.ndarray | None = None  # the weights' coefficients of the closed form's pieces
    P_core: np.ndarray | None = None  # the core's terminal weight for these coefficients
    frames: Any = None  # (layout, basis, {pinned pattern: closed_form.Frame})
    qp_stale: bool = False  # the core's weights lag behind coef (set before it solves)
    cf_bounds: np.ndarray | None = None  # the closed form's row bounds for this w̄
    bounds_stale: bool = False  # the core's base bounds lag behind du, y_min (sync_bounds)

    def set_disturbance_bound(self, wb: float, lim: Limits, st: TubeSettings) -> None:
        """Tighten the bounds for the disturbance bound ``w̄ = wb`` (module docstring)."""
        Np, M = self.Np, self.M
        tight = self.tight
        rate = lim.rate
        # input (Δu) box per stage: rate tightened by |K A_cl^j Ẽ|, held stages fixed
        du = np.maximum(rate - wb * tight[:Np, ROW_DU], 0.0)
        du[0] = rate
        du[1:M] = 0.0
        self.du = du
        ts = tight[1 : Np + 1]
        y_min = np.empty((Np, 3))
        y_max = np.empty((Np, 3))
        y_min[:, 0] = -BIG
        y_min[:, 1] = lim.v_min
        y_min[:, 2] = lim.u_lo + wb * ts[:, ROW_U]
        y_max[:, 0] = lim.s_max - wb * ts[:, ROW_S]
        y_max[:, 2] = lim.u_hi - wb * ts[:, ROW_U]
        if st.command_box == "off":
            y_min[:, 2], y_max[:, 2] = -BIG, BIG
        # an empty command box (W too large) keeps its midpoint
        bad = y_min[:, 2] > y_max[:, 2]
        if bad.any():
            mid = 0.5 * (y_min[bad, 2] + y_max[bad, 2])
            y_min[bad, 2] = y_max[bad, 2] = mid
        self.y_min, self.y_max = y_min, y_max
        self.bounds_stale = True  # the core gets them before it solves (sync_bounds)
        self.tau_v = wb * ts[:, ROW_V]
        steps = np.asarray(st.terminal_steps, dtype=int)
        rows = (ROW_S, ROW_V) if st.terminal_speed_rows else (ROW_S,)
        self.tau_term = np.concatenate([wb * tight[Np + steps, r] for r in rows])
        # the closed form's bounds (its rows "row <= b", .closed_form.make_closed_form)
        nt = steps.size
        b = [du, du, y_max[:, 0], -y_min[:, 1], -self.tau_v, -y_min[:, 2], y_max[:, 2]]
        if self.H_N.shape[0]:
            s_t = np.concatenate([np.full(nt, lim.s_max), np.zeros(self.H_N.shape[0] - nt)])
            b.append(s_t - self.tau_term)
        self.cf_bounds = np.concatenate(b)
        self.w_bar = wb
        self.explicit = None

    def sync_bounds(self) -> None:
        """Give the QP core the tightened base bounds of :meth:`set_disturbance_bound`
        (deferred to its next use: most steps are decided in closed form)."""
        if self.bounds_stale:
            du = self.du.reshape(self.Np, 1)
            self.mpc.set_base_bounds(u_min=-du, u_max=du)
            self.mpc.set_base_bounds(y_min=self.y_min)
            self.bounds_stale = False

    def work(self, layout: StageLayout) -> tuple:
        """Per-step index constants and work arrays (made on first use)."""
        Np, l = self.Np, layout.l  # noqa: E741
        bufs = self.buffers
        if bufs is None or bufs[0] != l:
            bufs = self.buffers = (
                l,
                slice(l + 1, l + Np + 1),  # stages 1..Np on the grid
                np.zeros((Np, 3)),  # y_ref (command column stays 0)
                np.empty((Np, 3)),  # y_max
                layout.term_idx + (l + Np),  # grid indices of the terminal checks
                np.empty(self.H_N.shape[0]),
                slice(l, l + Np),  # d_0 .. d_{Np-1}
            )
        return bufs

    def lower_bound(self, layout: StageLayout, data: Mapping[str, Any]) -> float | None:
        """A lower bound on :meth:`solve`'s cost for the same data, exact when the
        problem's unconstrained optimum (held increments pinned) is feasible; None when
        not available (:meth:`LinearMPC.unconstrained_cost`).  No per-step bounds are set."""
        self.sync_bounds()
        _, idx, y_ref, _, _, _, d_idx = self.work(layout)
        xs = data["xs"]
        y_ref[:, :2] = xs[idx, :2]
        return self.mpc.unconstrained_cost(
            data["xi0"], _ZERO1, y_ref, d=data["D"][d_idx], x_ref_N=xs[layout.l + self.Np]
        )

    def solve(
        self, layout: StageLayout, data: Mapping[str, Any], s_max: float
    ) -> tuple[MPCSolution, bool]:
        """Solve the problem from the stage data (001 eq. 11, 14 / 25–26); also whether
        the terminal set had to be dropped (unreachable: the QP failed with it)."""
        Np, l = self.Np, layout.l  # noqa: E741
        self.sync_bounds()
        _, idx, y_ref, y_max, steps, b, d_idx = self.work(layout)
        xs, v_lim, s_o = data["xs"], data["v_lim"], data["s_o"]
        y_ref[:, :2] = xs[idx, :2]
        y_max[...] = self.y_max
        y_max[:, 0] -= s_o
        np.subtract(v_lim[idx], self.tau_v, out=y_max[:, 1])
        xs_N = xs[l + Np]
        # terminal set: rows h A_cl^t ξ_N <= b_{N+t} − τ_{N+t} − h (ξ_s,N+t − A_cl^t ξ_s,N)
        nt = steps.size
        if nt:
            xt = xs[steps]
            np.subtract(s_max - s_o, xt[:, 0], out=b[:nt])
            if b.size > nt:
                np.subtract(v_lim[steps], xt[:, 1], out=b[nt:])
            b -= self.tau_term
            b += self.H_N @ xs_N
            self.mpc.set_base_bounds(y_max=y_max, h_N=b)
        else:
            self.mpc.set_base_bounds(y_max=y_max)
        args = (data["xi0"], _ZERO1, y_ref)
        kw = {"d": data["D"][d_idx], "x_ref_N": xs_N}
        sol = self.mpc.solve(*args, **kw)
        if nt and (sol.fallback or sol.status_val not in (1, 2)):
            # terminal set unreachable (the train is already headed beyond it): drop it
            # for this step rather than fall back to the previous plan
            self.mpc.set_base_bounds(h_N=np.full(self.H_N.shape[0], BIG))
            return self.mpc.solve(*args, **kw), True
        return sol, False
