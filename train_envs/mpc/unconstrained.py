r"""The unconstrained optimum of :class:`~train_envs.mpc.LinearMPC` (condensed form).

Without active rows the condensed QP :math:`\min \tfrac12 z^\top P_{zz} z + q_z^\top z`
has the minimiser :math:`z^* = -P_{zz}^{-1} q_z` (zero slacks).  With absolute inputs as
variables, input rows whose bounds coincide pin their variable; then
:math:`z_F = -P_{FF}^{-1} (q_F + P_{FP} z_P)`.  If :math:`z^*` meets every row it is the
QP's unique optimum (strictly convex cost).  The engine's one minimiser is
:meth:`_UnconstrainedMixin._unc_minimiser` (inverse formed once per matrix update and
used only where it inverts to 1e-9; reduced inverses cached per pinned pattern).  Built
on it: the ``unconstrained_first`` shortcut of :meth:`~train_envs.mpc.LinearMPC.solve`
(:meth:`_UnconstrainedMixin._unconstrained`), the lower bound
:meth:`_UnconstrainedMixin.unconstrained_cost` and the explicit affine maps
:meth:`_UnconstrainedMixin.unconstrained_affine` (the critical region of the empty
active set; Bemporad, Morari, Dua & Pistikopoulos, Automatica 38(1), 2002).
:meth:`_UnconstrainedMixin.gain_unconstrained` gives the first-move gain of the same
optimum from the normal equations, for analysis (:class:`UnconstrainedGain`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

_min_reduce = np.minimum.reduce


@dataclass(frozen=True)
class UnconstrainedGain:
    r"""Analytic first move of the unconstrained MPC (condensed normal equations).

    ``u0 = Kx x0 + Ku u_prev + Kr vec(y_ref) + Kd d + KD vec(D) + Kur vec(u_ref)
    + KxN x_ref_N``, where ``vec`` stacks the rows of the ``(Np, .)`` arrays, ``d`` is
    a constant affine term and ``D`` an ``(Np, n)`` sequence.  ``Kur`` / ``KxN`` are
    ``None`` when the controller has no ``S`` / state terminal weight.
    """

    Kx: np.ndarray
    Ku: np.ndarray
    Kr: np.ndarray
    Kd: np.ndarray
    KD: np.ndarray
    Kur: np.ndarray | None
    KxN: np.ndarray | None
    Np: int
    p: int
    Cpinv: np.ndarray  # default terminal reference x_ref_N = Cpinv @ y_ref[-1]

    def apply(
        self,
        x0: ArrayLike,
        u_prev: ArrayLike,
        y_ref: ArrayLike,
        d: ArrayLike | None = None,
        u_ref: ArrayLike | None = None,
        x_ref_N: ArrayLike | None = None,
    ) -> np.ndarray:
        """Evaluate the unconstrained first move for the given data."""
        m = self.Kx.shape[0]
        r = np.broadcast_to(np.asarray(y_ref, float), (self.Np, self.p))
        u = self.Kx @ np.asarray(x0, float) + self.Ku @ np.asarray(u_prev, float)
        u = u + self.Kr @ r.ravel()
        if d is not None:
            d_ = np.asarray(d, float)
            u = u + (self.Kd @ d_ if d_.ndim == 1 else self.KD @ d_.ravel())
        if self.Kur is not None and u_ref is not None:
            ur = np.broadcast_to(np.asarray(u_ref, float), (self.Np, m))
            u = u + self.Kur @ ur.ravel()
        if self.KxN is not None:
            xN = self.Cpinv @ r[-1] if x_ref_N is None else np.asarray(x_ref_N, float)
            u = u + self.KxN @ xN
        return u


@dataclass(frozen=True)
class UnconstrainedAffine:
    r"""The unconstrained optimum of a :class:`LinearMPC` as explicit functions of its data.

    With no active row the QP's optimum is affine in the data vector ``θ`` (the critical
    region of the empty active set of the multiparametric QP; Bemporad, Morari, Dua,
    Pistikopoulos, Automatica 38(1), 2002): ``z = Z θ`` (condensed decision, inputs pinned
    by the base bounds held at zero), the predicted states ``vec(X) = X θ`` (stages
    ``1..Np``, rows stacked), outputs ``vec(Y) = Y θ``, input plan ``vec(U) = U θ`` and
    the weighted residuals ``e = R θ`` of the cost, ``J = ‖R θ‖²`` (``MPCSolution.cost``:
    objective plus its data constant, here as a sum of squares: the solve forms it as
    the objective plus a constant, which cancel to its size, so for costs far below the
    constant this one is the more accurate).
    ``θ``'s layout is the controller's: ``θ[0] = 1`` and the named ``slots`` (index
    slices of ``x0``, ``up``, ``r``, ``xN``, ``d``, ``D``, ``ur``; ``r`` and ``D`` row
    major ``(Np, p)`` / ``(Np, n)``).  Valid while the weights and the pinned pattern
    are those it was made with (:meth:`LinearMPC.unconstrained_affine`); whether the
    optimum is feasible for given data is the caller's check.
    """

    Z: np.ndarray
    X: np.ndarray
    Y: np.ndarray
    U: np.ndarray
    R: np.ndarray
    slots: dict
    ntheta: int


class _UnconstrainedMixin:
    """The minimiser of the condensed QP without active rows, and what is built on it."""

    def _unc_minimiser(
        self, qz: np.ndarray, relax: bool, lower: np.ndarray
    ) -> tuple[np.ndarray, float] | None:
        """``(z, ½zᵀHz + qᵀz)`` of the minimiser with the pinned inputs at their values
        (read from the row bounds ``lower``) and no other row; None when the shortcut is
        not available (see :meth:`_unconstrained`)."""
        unc = self._unc_cache
        nz = self._nz
        if unc is None:
            Pu = self._P_dense[:nz, :nz]
            H = Pu + Pu.T - np.diag(np.diag(Pu))
            try:
                Hinv = np.linalg.inv(H)
                ok = np.abs(H @ Hinv - np.eye(nz)).max() < 1e-9
            except np.linalg.LinAlgError:
                ok = False
            unc = self._unc_cache = (
                (
                    np.ascontiguousarray(-Hinv),
                    np.ascontiguousarray(self._A_dense[:, :nz]),
                    H,
                    {},
                )
                if ok
                else False
            )
        if unc is False:
            return None
        mHinv, Az, H, reduced = unc
        r0 = self._row_input
        if self._z_is_du:
            key = None
        elif relax:  # this call's input rows are the reachable box: look at them
            pin = self._l[r0 : r0 + nz] == self._u[r0 : r0 + nz]
            key = pin.tobytes() if pin.any() else None
        else:  # the base input rows, which change only in set_base_bounds
            key = self._pin_key
            if key is False:
                pin = self._lower_base[r0 : r0 + nz] == self._upper_base[r0 : r0 + nz]
                key = self._pin_key = pin.tobytes() if pin.any() else None
        if key is not None:
            red = reduced.get(key)
            if red is None:
                pin = np.frombuffer(key, dtype=bool)
                free = np.flatnonzero(~pin)
                fixed = np.flatnonzero(pin)
                HFF = H[np.ix_(free, free)]
                try:
                    Mi = np.linalg.inv(HFF) if free.size else np.zeros((0, 0))
                    good = not free.size or np.abs(HFF @ Mi - np.eye(free.size)).max() < 1e-9
                except np.linalg.LinAlgError:
                    good = False
                if good:
                    # −H_FF⁻¹ embedded in the full space (zero rows/columns at the pinned
                    # variables): z = K (q + H z_P) + z_P without any gather or scatter
                    K = np.zeros((nz, nz))
                    K[np.ix_(free, free)] = -Mi
                    Hp = np.zeros((nz, nz))
                    Hp[:, fixed] = H[:, fixed]
                    red = (r0 + fixed, np.ascontiguousarray(K), Hp)
                else:
                    red = False
                reduced[key] = red
            if red is False:
                return None
            rows_p, K, Hp = red
            zp = lower[rows_p]
            if zp.any():
                zP = np.zeros(nz)
                zP[rows_p - r0] = zp
                z = np.dot(K, qz + np.dot(Hp, zP))
                z += zP
                obj = 0.5 * float(np.dot(z, np.dot(H, z))) + float(np.dot(qz, z))
            else:  # pinned at zero (a hold): the free part only
                z = np.dot(K, qz)
                obj = 0.5 * float(np.dot(qz, z))
        else:
            z = np.dot(mHinv, qz)
            obj = 0.5 * float(np.dot(qz, z))
        return z, obj

    def _unconstrained(
        self, q: np.ndarray, relax: bool
    ) -> tuple[np.ndarray, np.ndarray, float] | None:
        """``(x, y, objective)`` of the unconstrained minimiser if it is feasible, else None.

        Condensed QP ``min ½ wᵀPw + qᵀw``, ``w = [z; ε]``: ``z = −H_zz⁻¹ q_z`` with zero
        slacks.  If ``l ≤ A w ≤ u`` holds row by row, no constraint is active and ``w`` is
        the unique optimum (zero duals; at ε = 0 the slack rows' multipliers are the
        penalties themselves).  The inverse is formed once per matrix update and only
        used when it inverts ``H_zz`` to 1e-9.

        *Pinned inputs.*  With absolute inputs as variables (``delta_u=False``) an input
        row whose lower and upper bound coincide fixes its variable (e.g. the held
        increments of self-triggered MPC).  Then ``z`` is the minimiser over the free
        variables with the pinned ones at their values, ``z_F = −H_FF⁻¹ (q_F + H_FP z_P)``
        -- the optimum of the problem with only those equalities, hence of the QP when
        every other row holds.  The reduced inverse is cached per pinned pattern.  The
        returned duals are zero (a warm start only; the pinned rows' multipliers are
        not computed).
        """
        hit = self._unc_minimiser(q[: self._nz], relax, self._l)
        if hit is None:
            return None
        z, obj = hit
        Az = self._unc_cache[1]
        g = np.dot(Az, z)
        # l <= g <= u row by row (bounds are clipped to ±_BIG, so finite; NaN fails)
        if not (_min_reduce(g - self._l) >= 0.0 and _min_reduce(self._u - g) >= 0.0):
            return None
        x = np.zeros(self._n_var)
        x[: self._nz] = z
        return x, self._zero_duals(), obj

    def unconstrained_cost(
        self,
        x0: ArrayLike,
        u_prev: ArrayLike,
        y_ref: ArrayLike,
        *,
        d: ArrayLike | None = None,
        u_ref: ArrayLike | None = None,
        x_ref_N: ArrayLike | None = None,
    ) -> float | None:
        """A lower bound on the cost :meth:`solve` would return for the same data, exact
        when the problem's unconstrained optimum is feasible.

        It is the cost (``MPCSolution.cost``: objective plus its data constant) of the
        minimiser of the objective with the inputs pinned by the base bounds (equal
        ``u_min``/``u_max`` of :meth:`set_base_bounds`) at their values and every other row
        ignored.  Every constraint and the non-negative slack penalties can only raise the
        optimum, so the QP's optimal cost is at least this; when the minimiser satisfies
        every row it *is* the optimum and the value equals the cost that :meth:`solve`
        returns, bit for bit (same data map, same arithmetic).  It costs one
        matrix-vector product of the data map and one of the cached reduced inverse: no
        bounds, no feasibility check, no solver.  Use it to discard candidate problems
        whose cost cannot beat a known value (self-triggered MPC's hold lengths).  It
        loads the call's data as :meth:`solve` does and leaves the warm start, the kept
        plan and the last input untouched.

        Returns None when the bound is not available: ``unconstrained_first`` off, the
        sparse form, ``H`` (or its reduced block) not invertible to 1e-9, a previous input
        outside the input box (the solve would relax the input rows), non-finite data.
        Per-call bounds of :meth:`solve` do not enter (they do not change the minimiser).
        """
        if not self._unc_first:
            return None
        th = self._theta
        M = self._load(x0, u_prev, y_ref, d, u_ref, x_ref_N)
        tv = self._theta_no_D if M is self._M_no_D else th
        if not math.isfinite(np.dot(tv, tv)):
            return None
        if self._has_du and self._outside_box(self._theta_up.tolist()):
            return None
        v = self._v
        np.dot(M, tv, out=v)  # the full map, as solve() applies it: the same numbers
        hit = self._unc_minimiser(v[: self._nz], False, self._lower_base)
        if hit is None:
            return None
        Lv = v[self._v_cost]
        return hit[1] + float(np.dot(Lv, Lv))

    def unconstrained_affine(self) -> UnconstrainedAffine | None:
        """The unconstrained optimum as explicit affine maps of the data vector ``θ``.

        The same minimiser as :meth:`unconstrained_cost` and the unconstrained shortcut of
        :meth:`solve` (inputs pinned by equal base bounds held at their value), composed
        with the data map: see :class:`UnconstrainedAffine`.  A caller that evaluates
        many problems of a family for the same stage data (self-triggered MPC's hold
        lengths) composes these maps with its own data layout once and then needs one
        matrix-vector product per problem and step.  Its check that the optimum meets
        every row replaces the solve's; :meth:`adopt_unconstrained` then leaves the state
        a solve would.  Returns None where the shortcut is not available (see
        :meth:`unconstrained_cost`) or a pinned input is held at a non-zero value.  Costs
        a few small matrix products: make it once per weight or pin change.
        """
        if not self._unc_first or self._sparse:
            return None
        nz = self._nz
        if self._unc_minimiser(np.zeros(nz), False, self._lower_base) is None:
            return None
        mHinv, _, _, reduced = self._unc_cache
        key = None if self._z_is_du else self._pin_key
        if key is None:
            K = mHinv
        else:
            rows_p, K, _ = reduced[key]
            if np.any(self._lower_base[rows_p] != 0.0):
                return None
        Mf = self._M_full
        Z = K @ Mf[:nz]
        R = self._LwEz @ Z + self._Lth_c
        npn = self.Np * self.n
        traj = self._Wz_xy @ Z + self._M_xy
        X = traj[:npn]
        Y = X if self._y_is_x else traj[npn:]
        U = self._Wz_u @ Z + Mf[self._v_plan]
        return UnconstrainedAffine(
            Z=Z, X=X, Y=Y, U=U, R=R, slots=dict(self._slots), ntheta=Mf.shape[1]
        )

    def gain_unconstrained(self) -> UnconstrainedGain:
        """First-move gain of the unconstrained problem from the condensed normal equations.

        Without active constraints the minimiser is ``z* = -H^-1 F theta`` with
        ``H = Ez' W Ez`` and ``F = Ez' W Eth``; the first move is
        ``u0 = [Tz z* + Tu u_prev]_0``.  Requires ``H`` to be nonsingular.
        """
        m = self.m
        try:
            Z = -np.linalg.solve(self._H, 0.5 * self._Fq)  # (nz, ntheta)
        except np.linalg.LinAlgError as exc:
            raise ValueError("the condensed Hessian is singular (increase R or S)") from exc
        K = self._Tz_c[:m] @ Z
        if self._z_is_du:  # u0 = u_prev + du0
            K[:, self._slots["up"]] += np.eye(m)
        s = self._slots
        g = UnconstrainedGain(
            Kx=K[:, s["x0"]],
            Ku=K[:, s["up"]],
            Kr=K[:, s["r"]],
            Kd=K[:, s["d"]],
            KD=K[:, s["D"]],
            Kur=K[:, s["ur"]] if "ur" in s else None,
            KxN=K[:, s["xN"]] if "xN" in s else None,
            Np=self.Np,
            p=self.p,
            Cpinv=self._Cpinv.copy(),
        )
        return g

    def adopt_unconstrained(self, z: np.ndarray, U: np.ndarray) -> None:
        """Leave the state :meth:`solve` leaves after the unconstrained optimum ``z``.

        For a caller that evaluates the unconstrained law itself and checks the
        constraints on its own (the DMC's classic gain): the warm start of the next OSQP
        call and the plan kept for a fallback become those of the condensed decision
        ``z`` (``(nz,)``, zero slacks and duals) with input plan ``U`` (``(Nc, m)``), as
        if :meth:`solve` had returned them with ``unconstrained_first``.
        """
        if self._sparse:
            raise ValueError("adopt_unconstrained() needs the condensed form")
        self._ws_src = (z, None)
        self._plan = U
        self._plan_age = 0
        self._u_last = U[0]
