r"""Closed-form unconstrained optimum of one QP of the tube MPC family.

The unconstrained optimum of a problem (held increments pinned at zero) is affine in the
QP core's data vector θ, and θ is linear in the step's stage vector ``h``
(:mod:`.stage`).  Composed once per weight or W change, one matrix-vector product per
candidate gives::

    out = T h[cols],   rows: out[:nchk] <= b,   J = ‖out[nchk:]‖²

the constraint rows of the QP (increment box, tightened ``s``, ``v`` and command rows
of every stage, the terminal set) and the weighted cost residuals.  When no row binds
(``feasible``) the optimum is the QP's and ``J`` its exact cost (a sum of squares,
accurate to its own size); otherwise ``J`` is a lower bound on the QP's cost: every
constraint and slack penalty can only raise the optimum.

The cost is linear in the weights: with the core's residual maps ``e = E_z z + E_θ θ``
(:meth:`LinearMPC.residual_maps`) and the free decisions ``z_F``, ``H = Σ_k c_k H_k``
and ``F = Σ_k c_k F_k`` over nine pieces ``H_k = E_kᵀ W_k E_k``, ``F_k = E_kᵀ W_k E_θ,k``
(the ``q_s``, ``q_v`` and increment rows of the held and the free stages, and the three
pieces of the terminal weight, :func:`.model.core_terminal_basis`), made once per
problem, layout and pinned pattern (:class:`Frame`); a change is two weighted sums, one
inverse and three products: ``z_F = −H⁻¹ F h``.

:func:`closed_form_cost` (the reference implementation) and its compiled twin
(:func:`.kernels.closed_form_source`) are registered as ``"tube.closed_form"``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from train_envs._jit import register
from train_envs.controllers.tube.kernels import closed_form_source
from train_envs.controllers.tube.problem import ClosedForm, TubeProblem
from train_envs.controllers.tube.stage import StageLayout
from train_envs.mpc.assembly import ResidualMaps, _psd_sqrt

__all__ = ["ClosedForm", "Frame", "adopt", "closed_form_cost", "make_closed_form"]

_min_reduce = np.minimum.reduce
#: pieces of the weights: Q rows s, v and increments (held stages, then free ones), P
N_PIECES = 9
_FRAMES_MAX = 32  # frames kept per problem (one per pinned pattern: W moves the pins)


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


def weight_coefficients(q_s: float, q_v: float, r_du: float, beta: float) -> np.ndarray:
    """The coefficients ``c`` of the nine pieces (module docstring): ``(q_s, q_v, r)/β``
    on the held stages, ``(q_s, q_v, r)`` on the others and on the terminal weight."""
    ib = 1.0 / beta
    return np.array([q_s * ib, q_v * ib, r_du * ib, q_s, q_v, r_du, q_s, q_v, r_du])


@dataclass(frozen=True)
class Frame:
    """The weight-independent part of one problem's closed form (per layout, pinned
    pattern and terminal basis): the pieces ``H_k`` and ``F_k`` on the free decisions
    and the used stage-vector columns ``cols`` (flattened to ``(9, nf·nf)``, ``(9,
    nf·nc)``), the constraint rows ``Acon z_F + Ccon``, the residual rows ``Er z_F +
    Ethr`` (the weighted ones, each scaled by the square root of its piece's
    coefficient ``row_piece``, then the terminal ones), and the plan map (None: the
    plan is ``z``).
    """

    cols: np.ndarray
    free: np.ndarray
    Hk: np.ndarray
    Fk: np.ndarray
    Acon: np.ndarray
    Ccon: np.ndarray
    Er: np.ndarray
    Ethr: np.ndarray
    row_piece: np.ndarray
    Umap: tuple[np.ndarray, np.ndarray] | None
    eye: np.ndarray


def _theta_fold(prob: TubeProblem, layout: StageLayout, aff: ResidualMaps) -> tuple:
    """Where each entry of the core's data vector θ comes from in the stage vector
    (before folding): ``(order, coef[order], gcols, starts, ngv)``, the gather of θ's
    columns sorted by their target and summed per target."""
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
    return order, coef[order], gcols, starts, 6 + 6 * ng


def _theta_to_h(prob: TubeProblem, layout: StageLayout, maps: ResidualMaps) -> np.ndarray:
    """The map ``(ntheta, nh)`` of row vectors on θ to row vectors on the stage vector
    ``h``: θ gathered onto the derived layout ``g``, then folded (:meth:`StageLayout.fold`)."""
    order, coef_o, gcols, starts, ngv = _theta_fold(prob, layout, maps)
    tgt = np.repeat(gcols, np.diff(np.append(starts, order.size)))
    Gg = np.zeros((maps.ntheta, ngv))
    Gg[order, tgt] = coef_o
    return layout.fold(Gg)


def _frame(prob: TubeProblem, layout: StageLayout) -> Frame | None:
    """The problem's :class:`Frame` for its current pinned pattern (kept on the problem
    per pattern: the tightening of a larger W pins more increments); None when the core
    has no closed form (sparse form, not one decision per stage)."""
    pin = prob.du == 0.0
    basis = prob.basis
    frames = prob.frames
    if frames is None or frames[0] is not layout or frames[1] is not basis:
        frames = prob.frames = (layout, basis, {})
    key = pin.tobytes()
    hit = frames[2].get(key)
    if hit is not None:
        return hit
    mpc = prob.mpc
    if mpc.form != "condensed" or not mpc._unc_first or mpc.Nc * mpc.m != prob.Np:
        return None
    maps = mpc.residual_maps()
    Np = prob.Np
    GF = _theta_to_h(prob, layout, maps)
    free = np.flatnonzero(~pin)
    l, ng = layout.l, layout.n_grid  # noqa: E741
    XS, VL = 6, 6 + 5 * ng
    ngv = 6 + 6 * ng
    stage = l + 1 + np.arange(Np)  # grid index of stage i = 1..Np
    nb = prob.H_N.shape[0]
    nt = layout.term_idx.size
    # constraint rows as affine maps of z: z, then s, v, command of every stage, the
    # terminal rows (on θ), then the speed rows once more (their limit row)
    Sy, Yth = maps.Sy.reshape(Np, 3, -1), maps.Yth.reshape(Np, 3, -1)
    Bz = [np.eye(Np), Sy[:, 0], Sy[:, 1], Sy[:, 2]]
    Bc = [np.zeros((Np, maps.ntheta)), Yth[:, 0], Yth[:, 1], Yth[:, 2]]
    if nb:
        Bz.append(prob.H_N @ maps.Sx[-4:])
        Bc.append(prob.H_N @ maps.Xth[-4:])
    Bz += [Sy[:, 1]]
    Bc += [Yth[:, 1]]
    Bz, Bc = np.vstack(Bz), np.vstack(Bc)
    adj = np.zeros((Bz.shape[0], ngv))  # the unit terms of the data-dependent bounds
    adj[Np : 2 * Np, 5] += 1.0  # s + s_o <= s_max − τ_s
    vl = 4 * Np + nb  # the speed-limit rows: v − v_lim <= −τ_v
    adj[vl + np.arange(Np), VL + stage] -= 1.0
    if nb:
        steps = layout.term_idx + (l + Np)
        tr = np.arange(4 * Np, 4 * Np + nb)
        adj[tr, XS + 4 * (l + Np) : XS + 4 * (l + Np) + 4] -= prob.H_N
        adj[tr[:nt], 5] += 1.0
        adj[tr[:nt], XS + 4 * steps] += 1.0
        if nb > nt:
            adj[tr[nt:], XS + 4 * steps + 1] += 1.0
            adj[tr[nt:], VL + steps] -= 1.0
    C_h = Bc @ GF + layout.fold(adj)
    z_, s_, v_, u_ = (np.arange(k * Np, (k + 1) * Np) for k in range(4))
    t_ = np.arange(4 * Np, 4 * Np + nb)
    vl_ = vl + np.arange(Np)
    # rows "row <= b": z (upper), −z, s, −v, v − v_lim, −u, u, terminal
    idx = np.concatenate([z_, z_, s_, v_, vl_, u_, u_, t_])
    sign = np.concatenate([np.ones(Np), -np.ones(Np), np.ones(Np), -np.ones(Np)])
    sign = np.concatenate([sign, np.ones(Np), -np.ones(Np), np.ones(Np), np.ones(nb)])
    Acon = sign[:, None] * Bz[idx][:, free]
    Ccon = sign[:, None] * C_h[idx]
    # weighted residual rows: the s and v rows of every stage, the increments, terminal
    held_q, held_s = prob.held
    bq, bs, bp = maps.blocks["Q"], maps.blocks["S"], maps.blocks["P"]
    rows, piece = [], []
    for i in range(Np):
        for j in (0, 1):
            rows.append(bq.start + 3 * i + j)
            piece.append(j + (0 if held_q[i] else 3))
    for i in range(Np):
        rows.append(bs.start + i)
        piece.append(2 if held_s[i] else 5)
    rows += list(range(bp.start, bp.stop))
    Eth_h = maps.Eth @ GF
    Er_all = maps.Ez[rows][:, free]
    Eth_all = Eth_h[rows]
    Tz, Uth_h = maps.Tz, maps.Uth @ GF
    plan_is_z = np.array_equal(Tz, np.eye(Np)) and not Uth_h.any()
    used = np.any(Ccon != 0.0, axis=0) | np.any(Eth_all != 0.0, axis=0)
    if not plan_is_z:
        used |= np.any(Uth_h != 0.0, axis=0)
    cols = np.flatnonzero(used)
    Ccon, Eth_all = Ccon[:, cols], Eth_all[:, cols]
    nq = len(piece)
    piece_a = np.asarray(piece)
    nf = free.size
    Hk = np.zeros((N_PIECES, nf, nf))
    Fk = np.zeros((N_PIECES, nf, cols.size))
    for k in range(6):
        sel = np.flatnonzero(piece_a == k)
        E, Et = Er_all[sel], Eth_all[sel]
        Hk[k] = E.T @ E
        Fk[k] = E.T @ Et
    EN, EtN = Er_all[nq:], Eth_all[nq:]
    for j in range(3):
        Hk[6 + j] = EN.T @ basis[j] @ EN
        Fk[6 + j] = EN.T @ basis[j] @ EtN
    fr = Frame(
        cols=cols,
        free=free,
        Hk=Hk.reshape(N_PIECES, -1),
        Fk=Fk.reshape(N_PIECES, -1),
        Acon=np.ascontiguousarray(Acon),
        Ccon=np.ascontiguousarray(Ccon),
        Er=np.ascontiguousarray(Er_all),
        Ethr=np.ascontiguousarray(Eth_all),
        row_piece=piece_a,
        Umap=None if plan_is_z else (Tz[:, free], Uth_h[:, cols]),
        eye=np.eye(nf),
    )
    if len(frames[2]) >= _FRAMES_MAX:
        frames[2].clear()
    frames[2][key] = fr
    return fr


def _terminal_factor(P: np.ndarray) -> np.ndarray:
    """``L`` with ``‖L e‖² = eᵀ P e``: the transposed Cholesky factor, the symmetric
    square root's rows where ``P`` is only semidefinite."""
    try:
        return np.linalg.cholesky(P).T
    except np.linalg.LinAlgError:
        return _psd_sqrt(P)


def make_closed_form(prob: TubeProblem, layout: StageLayout) -> ClosedForm | bool:
    """Compose the problem's unconstrained optimum for its current weights (``prob.coef``,
    ``prob.P_core``) with the stage vector of :mod:`.stage` and the rows the QP sets.

    Row for row the same constraints as the QP: the increment box ``|Δu_i| <= du_i``
    (held stages pinned at 0), per stage ``s + s_o <= s_max − τ_s``, ``v >= v_min``,
    ``v − v_lim <= −τ_v``, ``u_lo + τ_u <= u <= u_hi − τ_u``, and the terminal rows
    ``h A_cl^t ξ_N − h ξ_s,N + (s_o + s_r,N+t | v_r,N+t − v_lim,N+t) <= (s_max | 0) −
    τ_N+t`` (their bounds: ``prob.cf_bounds``, made with the tightening).  False when the
    core has no closed form for this problem (or ``H`` does not invert to 1e-9).
    """
    if prob.du is None:
        return False
    fr = _frame(prob, layout)
    if fr is None:
        return False
    c = prob.coef
    nf, nc = fr.free.size, fr.cols.size
    H = np.dot(c, fr.Hk).reshape(nf, nf)
    try:
        Hinv = np.linalg.inv(H)
    except np.linalg.LinAlgError:
        return False
    if not np.abs(np.dot(H, Hinv) - fr.eye).max() < 1e-9:
        return False
    Z = np.dot(Hinv, np.dot(c, fr.Fk).reshape(nf, nc))
    np.negative(Z, out=Z)
    L = _terminal_factor(prob.P_core)
    nchk, nq = fr.Acon.shape[0], fr.row_piece.size
    T = np.empty((nchk + nq + L.shape[0], nc))
    con, res = T[:nchk], T[nchk : nchk + nq]
    np.dot(fr.Acon, Z, out=con)
    con += fr.Ccon
    np.dot(fr.Er[:nq], Z, out=res)
    res += fr.Ethr[:nq]
    res *= np.sqrt(c)[fr.row_piece][:, None]
    EN = np.dot(fr.Er[nq:], Z)
    EN += fr.Ethr[nq:]
    np.dot(L, EN, out=T[nchk + nq :])
    Um = None
    if fr.Umap is not None:
        Um = fr.Umap[0] @ Z
        Um += fr.Umap[1]
    bb = prob.cf_bounds
    return ClosedForm(cols=fr.cols, T=T, nz=prob.Np, nchk=nchk, b=bb, Umap=Um)
