r"""The tube MPC's stage vector: one step's data as one flat array.

``h = [1, s, v, a, u_prev, u_pend (l), s_r, v_r, res, v_lim]``: the measured state,
the ``l`` commands still in the dead time (oldest first), and along the grid of
``n_grid`` times ``t_0 + j T`` (``t_0``: now, or the profile time at the train's
position for distance-indexed references) the reference position and speed, the
nominal resistance per unit inertial mass at the reference and the speed limit::

    res_j = c_a [v_r,j > 0] + (c_b + c_c v_r,j) v_r,j + c_g θ(s_r,j)

(Davis law ``R(v) = a + b v + c v²`` divided by the inertial mass, the gradient
``θ`` in ‰ times ``m g / 1000`` likewise; ``w_ff = −res`` is the feed-forward term
of 001 eq. 10).  Everything the QP core needs -- the dead-time prediction ``ξ_0``, the
reference states ``ξ_s`` and the affine terms -- is linear in ``h``
(:meth:`StageLayout.derive`), so maps on the derived data fold into maps on ``h``
(:meth:`StageLayout.fold`); the closed forms (:mod:`.closed_form`) read ``h`` only.

:func:`fill_reference` (the reference implementation) and its compiled twin
(:func:`.kernels.fill_reference_source`) are registered as ``"tube.fill_reference"``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from train_envs._jit import bisect_right, register
from train_envs.controllers.tube.kernels import fill_reference_source
from train_envs.controllers.tube.model import StoppingModel
from train_envs.lines.speed_profile import sv_on_table
from train_envs.plants.physics import davis_horner_N

__all__ = ["StageData", "StageLayout", "fill_reference", "sv_on_table"]


def fill_reference(
    h: np.ndarray,
    o: int,
    tgrid: np.ndarray,
    t0: float,
    p_t: np.ndarray,
    p_tbl: np.ndarray,
    g_x: np.ndarray,
    g_tbl: np.ndarray,
    has_grad: bool,
    ca: float,
    cb: float,
    cc: float,
    cg: float,
) -> None:
    """Write ``s_r``, ``v_r`` and ``res`` at the grid times ``tgrid + t0`` into
    ``h[o:o+ng]``, ``h[o+ng:o+2ng]``, ``h[o+2ng:o+3ng]`` (``ng = tgrid.size``).

    ``p_t``, ``p_tbl``: the profile (:func:`sv_on_table`); ``g_x``, ``g_tbl``: the
    gradient table's breakpoints and per-segment ``(y0, slope)``, used when
    ``has_grad``; ``ca, cb, cc``: the Davis coefficients and ``cg = m g / 1000`` per
    unit inertial mass.
    """
    ng = tgrid.size
    s_r, v_r = sv_on_table(p_t, p_tbl, tgrid + t0)
    h[o : o + ng] = s_r
    h[o + ng : o + 2 * ng] = v_r
    res = h[o + 2 * ng : o + 3 * ng]
    res[:] = davis_horner_N(ca * (v_r > 0), cb, cc, v_r)
    if has_grad:
        k = g_x.searchsorted(s_r, side="right") - 1
        res += cg * (g_tbl[k, 0] + g_tbl[k, 1] * (s_r - g_x[k]))


register(
    "tube.fill_reference",
    fill_reference,
    source=fill_reference_source,
    helpers={"bisect_right": bisect_right, "davis_horner_N": davis_horner_N},
)


class StageData(dict):
    """One step's data: the stage vector ``h`` and ``u_prev``; the QP core's arrays
    (``xs``, ``D``, ``v_lim``, ``xi0``, ``s_o``) are derived on first access."""

    __slots__ = ("derive",)

    def __missing__(self, key: str) -> Any:
        if "xs" in self:
            raise KeyError(key)
        self.update(self.derive(self))
        return dict.__getitem__(self, key)


@dataclass(frozen=True)
class StageLayout:
    """The stage vector's layout for one episode's problem structure.

    Attributes:
        n_grid: grid points ``l + N_max + t_max + 2``; l: dead-time steps;
        model: the stopping model; inv_dt: ``1/T``; minus_E4: ``−E`` (4,);
        term_idx: the terminal set's LQR-law steps.
    """

    n_grid: int
    l: int  # noqa: E741 - the paper's symbol
    model: StoppingModel
    inv_dt: float
    minus_E4: np.ndarray
    term_idx: np.ndarray

    def derive(self, data: Mapping[str, Any]) -> dict[str, Any]:
        """The QP core's data from the stage vector: the dead-time prediction ξ_0 (eq. 10),
        the reference states ξ_s and the affine terms along the grid (stage ``i`` of a QP
        is grid index ``l + i``).  Positions are relative to the dead-time predicted one,
        ``s_o`` (eq. 9 is translation invariant in ``s``): the QP data stay O(1) for
        OSQP's relative tolerances."""
        h = data["h"]
        ng, l = self.n_grid, self.l  # noqa: E741
        o = 5 + l
        s_r, v_r = h[o : o + ng], h[o + ng : o + 2 * ng]
        res, v_lim = h[o + 2 * ng : o + 3 * ng], h[o + 3 * ng :]
        x = h[1:4]
        if l:
            m = self.model
            x = m.Phi_l @ x + m.Gam_u @ h[5:o] - m.Gam_w @ res[:l]  # w_ff = −res
        s_o = float(x[0])
        # reference state ξ_s = [s_r, v_r, a_s, u_s]: a_s = mean reference acceleration of
        # the next interval minus w_ff, u_s = a_s of the previous interval
        xs = np.empty((ng, 4))
        np.subtract(s_r, s_o, out=xs[:, 0])
        xs[:, 1] = v_r
        a_s = xs[:-1, 2]
        np.subtract(v_r[1:], v_r[:-1], out=a_s)
        a_s *= self.inv_dt
        a_s += res[:-1]
        xs[-1, 2] = xs[-2, 2]
        xs[1:, 3] = a_s
        xs[0, 3] = xs[0, 2]
        return {
            "xs": xs,
            "D": np.multiply(res[:, None], self.minus_E4),  # d_j = E w_ff,j
            "v_lim": v_lim,
            "xi0": np.array([0.0, x[1], x[2], h[4]]),
            "s_o": s_o,
        }

    def fold(self, G: np.ndarray) -> np.ndarray:
        """Maps on the derived layout ``g = [1, ξ_0, s_o, ξ_s (ng × 4), res, v_lim]`` as
        maps on the stage vector ``h`` of the module docstring (every relation of
        :meth:`derive` is linear: substitute it column by column)."""
        ng, l = self.n_grid, self.l  # noqa: E741
        rows = G.shape[0]
        XS, RES, VL = 6, 6 + 4 * ng, 6 + 5 * ng
        o = 5 + l
        xsc = G[:, XS:RES].reshape(rows, ng, 4)
        A2 = xsc[:, :-1, 2].copy()  # on a_s,j = (v_r,j+1 − v_r,j)/T + res_j, j < ng − 1
        A2 += xsc[:, 1:, 3]  # u_s,j+1 = a_s,j
        A2[:, 0] += xsc[:, 0, 3]  # u_s,0 = a_s,0
        A2[:, -1] += xsc[:, -1, 2]  # a_s,ng−1 = a_s,ng−2
        Vr = xsc[:, :, 1].copy()
        Vr[:, 1:] += A2 * self.inv_dt
        Vr[:, :-1] -= A2 * self.inv_dt
        Res = G[:, RES:VL].copy()
        Res[:, :-1] += A2
        Sr = xsc[:, :, 0]
        # on the dead-time predicted (s_o, v, a): s_o also enters every ξ_s,j = s_r,j − s_o
        cx = np.column_stack([G[:, 5] - Sr.sum(axis=1), G[:, 2], G[:, 3]])
        H = np.zeros((rows, o + 4 * ng))
        H[:, 0] = G[:, 0]
        H[:, 4] = G[:, 4]
        if l:
            m = self.model
            H[:, 1:4] = cx @ m.Phi_l
            H[:, 5:o] = cx @ m.Gam_u
            Res[:, :l] -= cx @ m.Gam_w
        else:
            H[:, 1:4] = cx
        H[:, o : o + ng] = Sr
        H[:, o + ng : o + 2 * ng] = Vr
        H[:, o + 2 * ng : o + 3 * ng] = Res
        H[:, o + 3 * ng :] = G[:, VL:]
        return H
