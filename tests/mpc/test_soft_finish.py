"""The exact finish of a condensed QP with its slacks as DAQP's soft constraints
(``_RecoveryMixin._exact_soft``): the optimum and the verdicts of DAQP on the full QP.

From OSQP's iterate after a few ADMM iterations on random condensed MPCs with soft
output bounds (one- and two-sided, absolute inputs and increments as the decision), the
reduced QP's point must meet the full QP's KKT conditions (the method's own check) and
equal DAQP's point of the full QP (``_exact`` with the reduced route off); an
infeasible QP gets the same verdict.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_mpc_core import random_instance

from train_envs.mpc import LinearMPC
from train_envs.mpc import recovery as rec
from train_envs.mpc.recovery import KKT_TOL, _soft_structure, _symmetric_P


def _capped(seed: int, **over: object) -> tuple[LinearMPC, np.ndarray, np.ndarray]:
    """A condensed MPC of ``random_instance(seed)`` (longer horizon, every output row
    soft) with OSQP's iterate of its current QP after 10 ADMM iterations."""
    case = random_instance(seed)
    inst = dict(case["inst"], Np=int(case["inst"]["Np"]) + 6, osqp_settings={"max_iter": 10})
    inst["Nc"] = min(int(inst["Nc"]) + 3, inst["Np"])
    inst.update(over)
    data = case["data"]
    Np, p = inst["Np"], inst["C"].shape[0]
    rng = np.random.default_rng(seed + 100)
    y_ref = rng.standard_normal((Np, p)) * 3.0  # far outside the box: slacks > 0
    mpc = LinearMPC(**inst)
    mpc.solve(data["x0"], data["u_prev"], y_ref, d=None)
    x, y, _ = mpc._backend.solve()
    return mpc, x, y


def _args(mpc: LinearMPC) -> tuple[np.ndarray, ...]:
    P = _symmetric_P(mpc)
    lo, hi = np.maximum(mpc._l, -1e30), np.minimum(mpc._u, 1e30)
    eq = hi - lo <= 1e-12 * (1.0 + np.abs(hi))
    return P, mpc._A_dense, mpc._v[mpc._v_q], lo, hi, eq


def _full(mpc: LinearMPC, x: np.ndarray, y: np.ndarray, monkeypatch) -> object:
    """``_exact`` with the reduced route off: DAQP on the full QP."""
    with monkeypatch.context() as mp:
        mp.setattr(rec, "_SOFT_MIN_VARS", 10**9)
        return mpc._exact(x, y)


def test_soft_finish_is_the_full_qps_optimum(monkeypatch):
    positive_slack = two_sided = simple = 0
    for seed in range(24):
        mpc, x, y = _capped(seed)
        ref = _full(mpc, x, y, monkeypatch)
        out = mpc._exact_soft(x, y, *_args(mpc))
        assert isinstance(ref, tuple), (seed, ref)
        assert isinstance(out, tuple), (seed, out)
        w, lam, obj = out
        P, A, q, lo, hi, _ = _args(mpc)
        # the full QP's KKT conditions, checked here independently of the method
        assert np.max(np.abs(P @ w + q + A.T @ lam)) <= KKT_TOL * (1 + np.max(np.abs(q)))
        Aw = A @ w
        assert np.all(Aw <= hi + KKT_TOL * (1 + np.abs(hi)))
        assert np.all(Aw >= lo - KKT_TOL * (1 + np.abs(lo)))
        scale = 1.0 + np.max(np.abs(ref[0]))
        np.testing.assert_allclose(w, ref[0], atol=1e-7 * scale)
        assert obj == pytest.approx(ref[2], rel=1e-9, abs=1e-9)
        eps = w[mpc._col_slack :]
        positive_slack += bool(np.any(eps > 1e-6))
        hard, jl, *_ = _soft_structure(mpc, A)
        two_sided += bool(jl.size)
        simple += bool(np.array_equal(hard[: mpc._nz], np.arange(mpc._nz)))
    # what the cases cover: violated soft rows, lower-side rows, DAQP's simple bounds
    assert positive_slack >= 12 and two_sided >= 12 and simple >= 6


@pytest.mark.parametrize("delta_u", [False, True])
def test_simple_bounds_are_the_rows_that_are_the_identity_on_z(delta_u):
    mpc, _, _ = _capped(2, delta_u=delta_u, du_min=None, du_max=None)
    hard, _, rows, sense, rho, w_lin = _soft_structure(mpc, mpc._A_dense)
    nz, ns = mpc._nz, mpc._ns
    if not delta_u:  # absolute inputs: the input box rows are z itself
        np.testing.assert_array_equal(hard[:nz], np.arange(nz))
        assert rows.shape == (hard.size - nz + ns, nz)
    else:  # increments without a rate box: no row is the identity on z
        assert rows.shape == (hard.size + ns, nz)
    assert np.all(sense[hard.size :] == 8) and np.all(sense[: hard.size] == 0)
    np.testing.assert_array_equal(rho[hard.size :], 0.5 / mpc._gamma_s)
    np.testing.assert_array_equal(w_lin[hard.size :], mpc._rho_s)


def test_an_infeasible_qp_gets_the_full_qps_verdict(monkeypatch):
    # increments with a rate box (seed 3): the first input row is z_0 (offsets removed)
    # and z_0's rate row one of DAQP's simple bounds; the input row asked to lie above
    # the rate bound, both with consistent bounds, cannot hold together
    mpc, x, y = _capped(3)
    P, A, q, lo, hi, eq = _args(mpc)
    nz = mpc._nz
    assert mpc._has_du and np.array_equal(A[nz, :nz], A[0, :nz])  # the same row, z_0
    lo2, hi2 = lo.copy(), hi.copy()
    lo2[0] = hi[nz] + 1.0
    hi2[0] = lo2[0] + 1.0
    assert mpc._exact_soft(x, y, P, A, q, lo2, hi2, eq) == -1
    mpc._l, mpc._u = lo2, hi2
    assert _full(mpc, x, y, monkeypatch) == -1


def test_large_condensed_qps_take_the_reduced_route(monkeypatch):
    calls = []
    real = rec._RecoveryMixin._exact_soft

    def spy(self, *a):
        calls.append(a)
        return real(self, *a)

    monkeypatch.setattr(rec._RecoveryMixin, "_exact_soft", spy)
    mpc, x, y = _capped(4, Np=5, Nc=2)
    assert mpc._n_var < rec._SOFT_MIN_VARS
    mpc._exact(x, y)
    assert not calls  # a small QP: DAQP on the full QP
    monkeypatch.setattr(rec, "_SOFT_MIN_VARS", 1)
    assert isinstance(mpc._exact(x, y), tuple)
    assert len(calls) == 1
