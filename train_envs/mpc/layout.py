r"""Variable, row and data layout of the QP of :class:`~train_envs.mpc.LinearMPC`.

Fixed at construction by :meth:`_LayoutMixin._layout`; the per-step code reads these
attributes (plain instance attributes: no lookups beyond one ``self.`` each).

Variables ``w`` (OSQP's ``x``), ``_n_var`` in all::

    [ X: states x_1..x_Np (sparse form only, _nxv) | z (_nz) | eps: slacks (_ns) ]
      0                                     _col_input    _col_slack       _n_var

``z`` holds the increments (condensed Δu form, ``_z_is_du``) or the absolute inputs.

Rows (``_n_row`` in all)::

    [ dynamics (sparse, _nxv) | input box (_nz) | rate box (_nz, with rate limits)
      | hard output/state rows | soft upper (_ns) | soft lower (two-sided soft rows)
      | eps >= 0 (_ns) ]

``_row_input``: first input-box row; ``_row_soft``: first soft-upper row (the hard
rows end there); ``_n_bound_row``: the rows before ``eps >= 0``, whose bounds may
change per call; ``_offset_rows``: the rows whose offsets depend on the data.

Bounds: ``_bounds_base`` (2, ``_n_bound_row``) = construction-time / base bounds
(rows ``_lower_base``, ``_upper_base``); ``_bounds_call`` the bounds of this call
(``_lower_call``, ``_upper_call``, per-call overrides written here); OSQP's ``l, u``
(``_lu``, rows ``_l``, ``_u``) = call bounds minus the data offsets; ``*_off`` are
views of the ``_offset_rows`` part.

Data vector ``θ = [1, x0, u_prev, r, (x_ref_N), d, (u_ref), D]`` (``_theta``, named
index slices ``_slots``, views ``_theta_x0``, ``_theta_up``, ``_theta_r``,
``_theta_D``, ``_theta_xN``; ``_theta_no_D`` the part before ``D``).  One product
``v = M θ`` per step (``_M_full``, or ``_M_no_D`` when no ``D`` sequence is loaded)
gives every vector of the call; ``v``'s slices: ``_v_q`` (OSQP's ``q``),
``_v_offsets`` (offsets of ``_offset_rows``), ``_v_plan`` (condensed: offsets of the
input plan), ``_v_cost`` (factor ``L`` of the cost constant ``‖L θ‖²``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from train_envs.mpc.osqp_backend import _BIG


def _csc_pattern(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Column-major (CSC) structure of a boolean mask: (rows, cols, indptr, indices)."""
    cols, rows = np.nonzero(mask.T)
    indptr = np.zeros(mask.shape[1] + 1, dtype=np.int64)
    np.cumsum(np.bincount(cols, minlength=mask.shape[1]), out=indptr[1:])
    return rows, cols, indptr, rows.astype(np.int64)


class _LayoutMixin:
    """The variable/row layout, the sparsity patterns, the parameter slots and the
    warm-start shift maps (:meth:`_layout`)."""

    def _layout(self) -> None:
        """Fix the variable/row layout, sparsity patterns and parameter slots (the
        attributes of the module docstring) and the warm-start shift maps."""
        n, m, Np, Nc = self.n, self.m, self.Np, self.Nc
        nz = Nc * m
        self._nz = nz
        sparse = self._sparse
        nxv = Np * n if sparse else 0  # state variables (sparse form only)
        self._nxv = nxv

        # parameter vector theta = [1, x0, u_prev, r, (xN), d, (u_ref), D]
        slots: dict[str, slice] = {}
        pos = 0
        for name, size, present in (
            ("one", 1, True),
            ("x0", n, True),
            ("up", m, True),
            ("r", Np * self.p, True),
            ("xN", n, self._P is not None and self.terminal == "state"),
            ("d", n, True),
            ("ur", Np * m, self._S is not None),
            ("D", Np * n, True),
        ):
            if present:
                slots[name] = slice(pos, pos + size)
                pos += size
        self._slots = slots
        self._ntheta = pos
        self._n_theta_no_D = slots["D"].start  # parameters without the D sequence

        # output/state constraint rows: (group, stage, row-in-group) ----------------
        con_g, con_s, con_r, con_lo, con_hi, con_rho, con_two = [], [], [], [], [], [], []
        for gi, g in enumerate(self._groups):
            R_ = g.G.shape[0]
            K = g.stages.size
            con_g.append(np.full(K * R_, gi))
            con_s.append(np.repeat(g.stages, R_))
            con_r.append(np.tile(np.arange(R_), K))
            con_lo.append(np.tile(g.lo, K))
            con_hi.append(np.tile(g.hi, K))
            con_rho.append(np.tile(g.rho, K))
            con_two.append(np.full(K * R_, g.two_sided))

        def cat(parts: list[np.ndarray], dtype: Any) -> np.ndarray:
            return np.concatenate(parts).astype(dtype) if parts else np.zeros(0, dtype)

        cg, cs, cr = cat(con_g, np.int64), cat(con_s, np.int64), cat(con_r, np.int64)
        clo, chi, crho = cat(con_lo, float), cat(con_hi, float), cat(con_rho, float)
        ctwo = cat(con_two, bool)
        soft = np.isfinite(crho)
        hard_c = np.flatnonzero(~soft)
        soft_c = np.flatnonzero(soft)
        soft2_c = soft_c[ctwo[soft_c]]  # soft rows that also get a lower-side row
        self._con = {"g": cg, "s": cs, "r": cr, "lo": clo, "hi": chi, "rho": crho}
        self._hard_c, self._soft_c, self._soft2_c = hard_c, soft_c, soft2_c
        self._soft2_slack = np.searchsorted(soft_c, soft2_c)
        ns = soft_c.size
        self._ns = ns
        self._col_input = nxv  # first input variable
        self._col_slack = nxv + nz  # first slack variable
        self._n_var = nxv + nz + ns

        # row layout: [dynamics (sparse) | hard | soft upper | soft lower | eps >= 0] ----
        r0 = nxv
        n_u = nz
        n_du = nz if self._has_du else 0
        o = r0 + n_u + n_du  # first hard output/state row
        nh = o + hard_c.size
        self._row_input, self._row_soft = r0, nh
        self._n_bound_row = nh + ns + soft2_c.size  # rows whose bounds may change per step
        self._n_row = self._n_bound_row + ns
        # rows whose offsets depend on theta (condensed: all; sparse: dynamics, input and
        # rate rows -- the state/output rows act on the variables and have fixed bounds)
        self._offset_rows = slice(0, self._n_bound_row if not sparse else o)

        Lb = np.zeros(self._n_bound_row)
        Ub = np.zeros(self._n_bound_row)
        Lb[r0 : r0 + n_u] = np.tile(self._umin, Nc)
        Ub[r0 : r0 + n_u] = np.tile(self._umax, Nc)
        if n_du:
            Lb[r0 + n_u : o] = np.tile(self._dumin, Nc)
            Ub[r0 + n_u : o] = np.tile(self._dumax, Nc)
        Lb[o:nh] = clo[hard_c]
        Ub[o:nh] = chi[hard_c]
        Lb[nh : nh + ns] = -np.inf
        Ub[nh : nh + ns] = chi[soft_c]
        Lb[nh + ns :] = clo[soft2_c]
        Ub[nh + ns :] = np.inf
        # lower/upper bounds are rows of 2-D arrays so one ufunc call updates both
        self._bounds_base = np.clip(np.vstack([Lb, Ub]), -_BIG, _BIG)
        self._bounds_call = self._bounds_base.copy()
        self._lower_base, self._upper_base = self._bounds_base[0], self._bounds_base[1]
        self._lower_call, self._upper_call = self._bounds_call[0], self._bounds_call[1]
        self._bounds_dirty = False
        self._lu = np.empty((2, self._n_row))
        self._l, self._u = self._lu[0], self._lu[1]
        self._lu[:, : self._n_bound_row] = self._bounds_base
        self._l[self._n_bound_row :] = 0.0
        self._u[self._n_bound_row :] = _BIG
        kk = np.arange(1, Nc + 1, dtype=float)[:, None]
        off = self._offset_rows  # views used by solve()
        self._lower_call_off, self._upper_call_off = self._lower_call[off], self._upper_call[off]
        self._l_off, self._u_off = self._l[off], self._u[off]
        self._k_dumax = kk * self._dumax[None, :]  # (Nc, m): reach of k rate-limited steps
        self._k_dumin = kk * self._dumin[None, :]
        self._umin_t = np.tile(self._umin, (Nc, 1))
        self._umax_t = np.tile(self._umax, (Nc, 1))

        # positions of each group's (stage, row) in the bound prefix (for overrides)
        hard_pos = np.full(cg.size, -1)
        hard_pos[hard_c] = o + np.arange(hard_c.size)
        up_pos = np.full(cg.size, -1)
        up_pos[soft_c] = nh + np.arange(ns)
        lo_pos = np.full(cg.size, -1)
        lo_pos[soft2_c] = nh + ns + np.arange(soft2_c.size)
        ub_all = np.where(hard_pos >= 0, hard_pos, up_pos)
        lb_all = np.where(hard_pos >= 0, hard_pos, lo_pos)
        for gi, g in enumerate(self._groups):
            idx = np.flatnonzero(cg == gi)
            shape = (g.stages.size, g.G.shape[0])
            g.ub_pos = ub_all[idx].reshape(shape)
            g.lb_pos = lb_all[idx].reshape(shape)

        # input parametrisation (decision z: increments in the condensed Delta-u form,
        # absolute inputs otherwise; the sparse form always uses absolute inputs)
        if self._z_is_du:
            Tz_c = np.kron(np.tril(np.ones((Nc, Nc))), np.eye(m))
            Dz = np.eye(nz)
        else:
            Tz_c = np.eye(nz)
            Dz = np.eye(nz) - np.eye(nz, k=-m)
        self._Tz_c, self._Dz = Tz_c, Dz

        # sparsity patterns: every entry a model/weight change could touch --------------
        oz, oe = self._col_input, self._col_slack
        Amask = np.zeros((self._n_row, self._n_var), dtype=bool)
        Amask[r0 : r0 + n_u, oz : oz + nz] = Tz_c != 0
        if n_du:
            Amask[r0 + n_u : o, oz : oz + nz] = Dz != 0
        con_rows = np.concatenate([hard_c, soft_c, soft2_c])
        con_at = np.concatenate([np.arange(o, nh), np.arange(nh, self._n_bound_row)])
        if sparse:
            hold = np.minimum(np.arange(Np), Nc - 1)
            for t in range(Np):  # -x_{t+1} + A x_t + B u_t + offset = 0
                rows = slice(t * n, (t + 1) * n)
                Amask[rows, t * n : (t + 1) * n] |= np.eye(n, dtype=bool)
                if t:
                    Amask[rows, (t - 1) * n : t * n] = True
                Amask[rows, oz + hold[t] * m : oz + (hold[t] + 1) * m] = True
            for k, rr in zip(con_rows, con_at, strict=True):  # dense block on x_stage
                st = cs[k] - 1
                Amask[rr, st * n : (st + 1) * n] = True
        else:
            # z-block j influences stage i iff j <= i - 1
            blk = np.arange(nz) // m
            Amask[con_at, :nz] = blk[None, :] <= (cs[con_rows, None] - 1)
        sl = np.arange(ns)
        Amask[nh + sl, oe + sl] = True
        if soft2_c.size:
            Amask[nh + ns + np.arange(soft2_c.size), oe + self._soft2_slack] = True
        Amask[self._n_bound_row + sl, oe + sl] = True
        Pmask = np.zeros((self._n_var, self._n_var), dtype=bool)
        Pmask[oz : oz + nz, oz : oz + nz] = np.triu(np.ones((nz, nz), dtype=bool))
        if sparse:
            blk_n = np.triu(np.ones((n, n), dtype=bool))
            for t in range(Np):
                Pmask[t * n : (t + 1) * n, t * n : (t + 1) * n] = blk_n
        Pmask[oe + sl, oe + sl] = True
        self._Amask, self._Pmask = Amask, Pmask
        self._A_rows, self._A_cols, self._A_ptr, self._A_ind = _csc_pattern(Amask)
        self._P_rows, self._P_cols, self._P_ptr, self._P_ind = _csc_pattern(Pmask)

        # warm-start shift maps --------------------------------------------------------
        key_to_con = {
            (g_, s_, r_): k for k, (g_, s_, r_) in enumerate(zip(cg, cs, cr, strict=True))
        }

        def next_con(k: int) -> int:
            return key_to_con.get((cg[k], cs[k] + 1, cr[k]), k)

        soft_index = {int(c): i for i, c in enumerate(soft_c)}
        soft2_index = {int(c): i for i, c in enumerate(soft2_c)}
        hard_index = {int(c): i for i, c in enumerate(hard_c)}
        esrc = np.array([soft_index[next_con(int(c))] for c in soft_c], dtype=np.int64)
        stage_next = np.minimum(np.arange(Np) + 1, Np - 1)
        xsrc = (stage_next[:, None] * n + np.arange(n)[None, :]).ravel() if sparse else []
        zsrc = np.arange(nz) + m
        zsrc[-m:] = self._n_var if self._z_is_du else np.arange(nz - m, nz)  # nv -> appended 0
        zsrc[: nz - m] += oz
        if not self._z_is_du:
            zsrc[-m:] += oz
        self._xshift = np.concatenate([np.asarray(xsrc, dtype=np.int64), zsrc, oe + esrc]).astype(
            np.int64
        )
        ysrc = np.arange(self._n_row)
        if sparse:
            ysrc[:r0] = xsrc
        ublk = np.arange(n_u) + m
        ublk[-m:] -= m
        ysrc[r0 : r0 + n_u] = r0 + ublk
        if n_du:
            ysrc[r0 + n_u : o] = r0 + n_u + ublk
        ysrc[o:nh] = [o + hard_index[next_con(int(c))] for c in hard_c]
        ysrc[nh : nh + ns] = nh + esrc
        ysrc[nh + ns : self._n_bound_row] = [
            nh + ns + soft2_index[next_con(int(c))] for c in soft2_c
        ]
        ysrc[self._n_bound_row :] = self._n_bound_row + esrc
        self._yshift = ysrc.astype(np.int64)

    def _load(
        self,
        x0: ArrayLike,
        u_prev: ArrayLike,
        y_ref: ArrayLike,
        d: ArrayLike | None,
        u_ref: ArrayLike | None,
        x_ref_N: ArrayLike | None,
    ) -> np.ndarray:
        """Write one call's data into ``θ``; the data map to apply to it (ValueError on
        wrong shapes)."""
        th = self._theta
        s = self._slots
        if (x0.ndim if type(x0) is np.ndarray else np.ndim(x0)) != 1 or (
            u_prev.ndim if type(u_prev) is np.ndarray else np.ndim(u_prev)
        ) != 1:
            raise ValueError(
                f"solve(): x0 must have shape ({self.n},) and u_prev ({self.m},), got "
                f"{np.shape(x0)} and {np.shape(u_prev)}"
            )
        try:
            self._theta_x0[...] = x0
            self._theta_up[...] = u_prev
        except ValueError:
            raise ValueError(
                f"solve(): x0 must have shape ({self.n},) and u_prev ({self.m},), got "
                f"{np.shape(x0)} and {np.shape(u_prev)}"
            ) from None
        try:
            self._theta_r[...] = y_ref
        except ValueError:
            if self.p == 1 and np.shape(y_ref) == (self.Np,):
                th[s["r"]] = y_ref
            else:
                raise ValueError(
                    f"solve(): y_ref must have shape ({self.Np}, {self.p}) or ({self.p},), "
                    f"got {np.shape(y_ref)}"
                ) from None
        if self._has_xN:
            if x_ref_N is None:
                np.dot(self._Cpinv, self._theta_r[-1], out=self._theta_xN)
            else:
                self._theta_xN[...] = x_ref_N
        M = self._M_no_D
        if d is not None:
            d_arr = d if type(d) is np.ndarray else np.asarray(d, dtype=float)
            shape = d_arr.shape
            if shape == self._shape_D:
                self._theta_D[...] = d_arr
                if self._d_dirty == 1:
                    th[s["d"]] = 0.0
                self._d_dirty = 2
                M = self._M_full
            elif shape == (self.n,):
                th[s["d"]] = d_arr
                if self._d_dirty == 2:
                    th[s["D"]] = 0.0
                self._d_dirty = 1
            else:
                raise ValueError(
                    f"solve(): d must have shape ({self.n},) or ({self.Np}, {self.n}), "
                    f"got {d_arr.shape}"
                )
        elif self._d_dirty:
            th[s["d"]] = 0.0
            th[s["D"]] = 0.0
            self._d_dirty = 0
        if self._has_ur:
            if u_ref is not None:
                try:
                    th[s["ur"]].reshape(self.Np, self.m)[...] = u_ref
                except ValueError as exc:
                    raise ValueError(
                        f"solve(): u_ref must have shape ({self.Np}, {self.m}) or ({self.m},)"
                    ) from exc
                self._ur_dirty = True
            elif self._ur_dirty:
                th[s["ur"]] = 0.0
                self._ur_dirty = False

        return M
