r"""Closed-form unconstrained optimum of one QP of the tube MPC family.

The unconstrained optimum of a problem (held increments pinned) is affine in the QP
core's data vector θ (:meth:`LinearMPC.unconstrained_affine`), and θ is linear in the
step's stage vector ``h`` (:mod:`.stage`).  Composed once per weight or W change, one
matrix-vector product per candidate gives::

    out = T h[cols],   rows: out[:nchk] <= b,   J = ‖out[nchk:]‖²

the constraint rows of the QP (increment box, tightened ``s``, ``v`` and command rows
of every stage, the terminal set) and the weighted cost residuals.  When no row binds
(``feasible``) the optimum is the QP's and ``J`` its exact cost (a sum of squares,
accurate to its own size); otherwise ``J`` is a lower bound on the QP's cost: every
constraint and slack penalty can only raise the optimum.

:func:`closed_form_cost` (the reference implementation) and its compiled twin
(:func:`.kernels.closed_form_source`) are registered as ``"tube.closed_form"``.
"""

from __future__ import annotations

import numpy as np

from train_envs._jit import register
from train_envs.controllers.tube.kernels import closed_form_source
from train_envs.controllers.tube.problem import ClosedForm, TubeProblem
from train_envs.controllers.tube.stage import StageLayout
from train_envs.mpc import UnconstrainedAffine

__all__ = ["ClosedForm", "adopt", "closed_form_cost", "make_closed_form"]

_min_reduce = np.minimum.reduce


def closed_form_cost(
    T: np.ndarray, cols: np.ndarray, h: np.ndarray, b: np.ndarray, nchk: int
) -> tuple[float, bool]:
    """``(J, feasible)`` of one candidate: ``out = T @ h[cols]``, feasible when every
    margin ``b − out[:nchk]`` is ``>= 0`` (NaN is not), ``J = ‖out[nchk:]‖²``."""
    out = np.dot(T, h[cols])
    r = out[nchk:]
    return float(np.dot(r, r)), bool(_min_reduce(b - out[:nchk]) >= 0.0)


register("tube.closed_form", closed_form_cost, source=closed_form_source)


def adopt(prob: TubeProblem, h: np.ndarray, rate: float) -> float:
    """Take the feasible closed-form optimum for ``h`` as the problem's solution: leave
    the core the state its solve would, return the first increment (within ``±rate``)."""
    e = prob.explicit
    nz = e.nz
    hv = h[e.cols]
    z = np.dot(e.T[:nz], hv)
    U = z if e.Umap is None else np.dot(e.Umap, hv)
    prob.mpc.adopt_unconstrained(z, U.reshape(nz, 1))
    return min(max(float(z[0]), -rate), rate)


def _theta_fold(prob: TubeProblem, layout: StageLayout, aff: UnconstrainedAffine) -> tuple:
    """Where each entry of the core's data vector θ comes from in the stage vector
    (before folding): ``(order, coef[order], gcols, starts, ngv)``, the gather of θ's
    columns sorted by their target and summed per target (weight independent: made once
    per problem and layout, kept on the problem)."""
    hit = prob.theta_fold
    if hit is not None and hit[0] is layout and hit[1] == aff.ntheta:
        return hit[2]
    Np, l, ng = prob.Np, layout.l, layout.n_grid  # noqa: E741
    nth = aff.ntheta
    XS = 6
    RES = 6 + 4 * ng
    tgt = np.full(nth, -1)
    coef = np.ones(nth)
    ith = np.arange(nth)
    sl = aff.slots
    tgt[0] = 0
    tgt[ith[sl["x0"]]] = 1 + np.arange(4)
    stage = l + 1 + np.arange(Np)  # grid index of stage i = 1..Np
    r = ith[sl["r"]].reshape(Np, 3)  # the command column's reference stays 0
    tgt[r[:, 0]] = XS + 4 * stage
    tgt[r[:, 1]] = XS + 4 * stage + 1
    if "xN" in sl:
        tgt[ith[sl["xN"]]] = XS + 4 * (l + Np) + np.arange(4)
    Dk = ith[sl["D"]].reshape(Np, 4)  # d_i = −E res_{l+i}
    tgt[Dk] = RES + (l + np.arange(Np))[:, None]
    coef[Dk] = layout.minus_E4[None, :]
    used = np.flatnonzero(tgt >= 0)
    order = used[np.argsort(tgt[used], kind="stable")]
    gcols, starts = np.unique(tgt[order], return_index=True)
    out = (order, coef[order], gcols, starts, 6 + 6 * ng)
    prob.theta_fold = (layout, nth, out)
    return out


def make_closed_form(prob: TubeProblem, layout: StageLayout, s_max: float) -> ClosedForm | bool:
    """Compose the core's unconstrained optimum (:meth:`LinearMPC.unconstrained_affine`)
    with the stage vector of :mod:`.stage` and the rows the QP sets.

    Row for row the same constraints as the QP: the increment box ``|Δu_i| <= du_i``
    (held stages pinned at 0), per stage ``s + s_o <= s_max − τ_s``, ``v >= v_min``,
    ``v − v_lim <= −τ_v``, ``u_lo + τ_u <= u <= u_hi − τ_u``, and the terminal rows
    ``h A_cl^t ξ_N − h ξ_s,N + (s_o + s_r,N+t | v_r,N+t − v_lim,N+t) <= (s_max | 0) −
    τ_N+t``.  False when the core has no closed form for this problem.
    """
    aff = prob.mpc.unconstrained_affine()
    if aff is None or prob.du is None or aff.Z.shape[0] != prob.Np:
        return False
    Np, nth = prob.Np, aff.ntheta
    order, coef_o, gcols, starts, ngv = _theta_fold(prob, layout, aff)

    def on_g(A: np.ndarray) -> np.ndarray:
        out = np.zeros((A.shape[0], ngv))
        out[:, gcols] = np.add.reduceat(A[:, order] * coef_o, starts, axis=1)
        return out

    l, ng = layout.l, layout.n_grid  # noqa: E741
    XS, VL = 6, 6 + 5 * ng
    stage = l + 1 + np.arange(Np)  # grid index of stage i = 1..Np
    Y = aff.Y.reshape(Np, 3, nth)
    Z = aff.Z
    ymin, ymax = prob.y_min, prob.y_max
    nb = prob.H_N.shape[0]
    nt = layout.term_idx.size
    # every distinct row once on g (the stage vector before folding), then the unit
    # terms of the data-dependent bounds, then the fold onto h
    base = [Z, Y[:, 0], Y[:, 1], Y[:, 2]]
    if nb:
        base.append(prob.H_N @ aff.X[-4:])
    base.append(aff.R)
    Gb = on_g(np.vstack(base))
    s_rows = slice(Np, 2 * Np)
    Gb[s_rows, 5] += 1.0  # s + s_o <= s_max − τ_s
    Gv = Gb[2 * Np : 3 * Np].copy()
    Gv[np.arange(Np), VL + stage] -= 1.0  # v − v_lim <= −τ_v
    if nb:
        steps = layout.term_idx + (l + Np)
        tr = np.arange(4 * Np, 4 * Np + nb)
        Gb[tr, XS + 4 * (l + Np) : XS + 4 * (l + Np) + 4] -= prob.H_N
        Gb[tr[:nt], 5] += 1.0
        Gb[tr[:nt], XS + 4 * steps] += 1.0
        if nb > nt:
            Gb[tr[nt:], XS + 4 * steps + 1] += 1.0
            Gb[tr[nt:], VL + steps] -= 1.0
    H = layout.fold(np.vstack([Gb, Gv]))
    Hz, Hs, Hv, Hu = H[:Np], H[Np : 2 * Np], H[2 * Np : 3 * Np], H[3 * Np : 4 * Np]
    Ht, Hr, Hvl = H[4 * Np : 4 * Np + nb], H[4 * Np + nb : -Np], H[-Np:]
    rows = [Hz, -Hz, Hs, -Hv, Hvl, -Hu, Hu, Ht, Hr]  # (z's rows are its upper bounds)
    b = [prob.du, prob.du, ymax[:, 0], -ymin[:, 1], -prob.tau_v, -ymin[:, 2], ymax[:, 2]]
    if nb:
        b.append(np.concatenate([np.full(nt, s_max), np.zeros(nb - nt)]) - prob.tau_term)
    G = np.vstack(rows)
    # the plan is the decision itself in the absolute-input form
    Um = None if np.array_equal(aff.U, Z) else layout.fold(on_g(aff.U))
    used = np.any(G != 0.0, axis=0)
    if Um is not None:
        used |= np.any(Um != 0.0, axis=0)
    cols = np.flatnonzero(used)
    bb = np.concatenate(b)
    return ClosedForm(
        cols=cols,
        T=np.ascontiguousarray(G[:, cols]),
        nz=Np,
        nchk=bb.size,
        b=bb,
        Umap=None if Um is None else np.ascontiguousarray(Um[:, cols]),
    )
