"""The exact finish of a capped OSQP solve (``_RecoveryMixin._exact``, DAQP).

``data/slow_qps.npz`` holds nine QPs recorded from the control steps of
``Stopping001-v0``, ``Yizhuang-v0`` and ``Section000-v0`` on which OSQP ran 600 to 4000
ADMM iterations (the longest, a median and the shortest such step per env at the
constant and random actions of ``benchmarks/bench_envs.py --osqp-tail``): ``P`` (upper
triangle), ``A``, ``q``, ``l``, ``u`` and the warm start OSQP got.  From OSQP's iterate at
the iteration cap the finish must meet the full QP's KKT conditions and reach the
optimum a tightly converged, polished OSQP reaches from scratch.
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import scipy.sparse as sp
from test_mpc_core import random_instance

from train_envs.mpc import LinearMPC
from train_envs.mpc.osqp_backend import _Backend, osqp_settings_with
from train_envs.mpc.recovery import KKT_TOL, _RecoveryMixin, _symmetric_P

_DATA = np.load(Path(__file__).parent / "data" / "slow_qps.npz", allow_pickle=False)
_N_QP = 9


def _qp(k: int) -> dict[str, np.ndarray]:
    return {f: _DATA[f"{k}_{f}"] for f in ("P", "A", "q", "l", "u", "wx", "wy")}


def _backend(qp: dict[str, np.ndarray], **overrides: object) -> _Backend:
    settings = osqp_settings_with(overrides)
    P, A = sp.csc_matrix(qp["P"]), sp.csc_matrix(qp["A"])
    return _Backend(P, qp["q"], A, qp["l"], qp["u"], settings, fast=True)


@pytest.mark.parametrize("k", range(_N_QP))
def test_exact_finish_of_a_capped_solve_is_the_optimum(k):
    qp = _qp(k)
    capped = _backend(qp)
    capped.warm_start(qp["wx"], qp["wy"])
    x, y, stats = capped.solve()
    assert stats[0] == 7 and stats[2] == osqp_settings_with(None)["max_iter"]  # at the cap

    host = SimpleNamespace(
        _P_dense=qp["P"], _A_dense=qp["A"], _v=qp["q"], _v_q=slice(None), _l=qp["l"], _u=qp["u"]
    )
    out = _RecoveryMixin._exact(host, x, y)
    assert isinstance(out, tuple), out
    w, lam, obj = out

    # the full QP's KKT conditions, checked here independently of the method
    Pu, A, q, lo, hi = qp["P"], qp["A"], qp["q"], qp["l"], qp["u"]
    P = Pu + Pu.T - np.diag(np.diag(Pu))
    assert np.max(np.abs(P @ w + q + A.T @ lam)) <= KKT_TOL * (1 + np.max(np.abs(q)))
    Aw = A @ w
    tol_hi, tol_lo = KKT_TOL * (1 + np.abs(hi)), KKT_TOL * (1 + np.abs(lo))
    assert np.all(Aw <= hi + tol_hi) and np.all(Aw >= lo - tol_lo)
    on_hi, on_lo = hi - Aw <= tol_hi, Aw - lo <= tol_lo
    big = np.abs(lam) > KKT_TOL * (1 + np.max(np.abs(lam)))
    assert np.all(on_hi[big & (lam > 0)]) and np.all(on_lo[big & (lam < 0)])
    assert obj == pytest.approx(0.5 * w @ P @ w + q @ w, rel=1e-12, abs=1e-12)

    # the optimum a tight OSQP solve reaches from a cold start: the same cost, and the
    # same point where OSQP's polishing succeeded (where it did not, OSQP's own
    # stationarity residual, up to 3e-7, is far above the finish's)
    tight = _backend(qp, eps_abs=1e-10, eps_rel=1e-10, max_iter=400_000, polishing=True)
    xr, _, sr = tight.solve()
    assert sr[0] == 1
    assert obj == pytest.approx(sr[4], rel=1e-8, abs=1e-8)
    if sr[5] == 1:
        np.testing.assert_allclose(w, xr, atol=1e-6 * (1 + np.max(np.abs(xr))))


def test_exact_finish_reports_an_infeasible_qp():
    """A QP whose rows cannot all hold gets DAQP's infeasibility flag, not a point."""
    qp = _qp(4)
    lo, hi = qp["l"], qp["u"]
    row = int(np.flatnonzero((hi < 1e29) & (hi > lo))[0])
    # the same row again, bounded from below above its upper bound
    A = np.vstack([qp["A"], qp["A"][row]])
    lo2, hi2 = np.append(lo, hi[row] + 1.0), np.append(hi, 1e30)
    host = SimpleNamespace(
        _P_dense=qp["P"], _A_dense=A, _v=qp["q"], _v_q=slice(None), _l=lo2, _u=hi2
    )
    assert _RecoveryMixin._exact(host, np.zeros(A.shape[1]), np.zeros(A.shape[0])) == -1


def test_symmetric_P_follows_weight_and_model_changes():
    """The finish's full ``P`` is made once per ``P`` and follows every weight and
    model change (the assembly replaces ``_P_dense``, never writes into it)."""
    case = random_instance(3)
    inst = case["inst"]
    mpc = LinearMPC(**inst)

    def full(Pu: np.ndarray) -> np.ndarray:
        return Pu + Pu.T - np.diag(np.diag(Pu))

    P0 = _symmetric_P(mpc)
    np.testing.assert_array_equal(P0, full(mpc._P_dense))
    assert _symmetric_P(mpc) is P0  # cached
    mpc.set_weights(Q=inst["Q"] * 3.0, R=inst["R"] * 0.5)
    P1 = _symmetric_P(mpc)
    np.testing.assert_array_equal(P1, full(mpc._P_dense))
    assert not np.array_equal(P1, P0)
    mpc.set_model(inst["A"] * 0.99, inst["B"])
    np.testing.assert_array_equal(_symmetric_P(mpc), full(mpc._P_dense))


class _NoRefine(_RecoveryMixin):
    def _refine(self, x, y, max_iter=20):
        raise AssertionError("the refinement ran after DAQP's verdict")


def test_infeasibility_verdict_confirmed_by_daqp_skips_the_refinement():
    """After OSQP's primal-infeasibility verdict DAQP decides first; its verdict is
    final and reported with OSQP's status."""
    qp = _qp(4)
    lo, hi = qp["l"], qp["u"]
    row = int(np.flatnonzero((hi < 1e29) & (hi > lo))[0])
    A = np.vstack([qp["A"], qp["A"][row]])
    host = _NoRefine()
    host.__dict__.update(
        _P_dense=qp["P"],
        _A_dense=A,
        _v=qp["q"],
        _v_q=slice(None),
        _l=np.append(lo, hi[row] + 1.0),
        _u=np.append(hi, 1e30),
    )
    stats = (3, "primal infeasible", 40, 1e-4, 0.0, 0)
    _, _, out = host._rescue(np.zeros(A.shape[1]), np.zeros(A.shape[0]), stats)
    assert out[:3] == (3, "primal infeasible", 40) and out[3] >= 1e-4


def test_sparse_form_active_set_finish_reaches_daqps_optimum():
    """In the sparse form the finish first solves the KKT system of the active set
    OSQP's iterate names (one sparse LU); where it is accepted it is the point DAQP
    finds from the same iterate, to the KKT tolerance."""
    accepted = 0
    for seed in range(12):
        case = random_instance(seed)
        inst = dict(case["inst"], form="sparse", osqp_settings={"max_iter": 10})
        data = case["data"]
        mpc = LinearMPC(**inst)
        mpc.solve(data["x0"], data["u_prev"], data["y_ref"], d=data["d"])
        x, y, _ = mpc._backend.solve()  # an iterate of this call's QP, 10 iterations on
        mpc._sparse = False
        ref = mpc._exact(x, y)  # DAQP
        mpc._sparse = True
        out = mpc._exact(x, y)
        assert isinstance(ref, tuple) and isinstance(out, tuple)
        w, lam, obj = out
        scale = 1.0 + np.max(np.abs(ref[0]))
        np.testing.assert_allclose(w, ref[0], atol=1e-6 * scale)
        assert obj == pytest.approx(ref[2], rel=1e-8, abs=1e-8)
        P = _symmetric_P(mpc)
        lo, hi = np.maximum(mpc._l, -1e30), np.minimum(mpc._u, 1e30)
        eq = hi - lo <= 1e-12 * (1.0 + np.abs(hi))
        A, q = mpc._A_dense, mpc._v[mpc._v_q]
        accepted += mpc._active_set_kkt(x, y, P, A, q, lo, hi, eq) is not None
    assert accepted >= 3  # the others: a wrong guess of the active set, DAQP finishes


def test_after_a_capped_solve_the_exact_finish_runs_first_and_gives_the_optimum():
    """Once OSQP has ended at its cap, the next solves of the same MPC run the exact
    finish from the warm start first (no ADMM iteration) and reach the optimum of a
    tightly converged OSQP on the same data; a reset clears that state."""
    firsts = 0
    for seed in range(12):
        case = random_instance(seed)
        data = case["data"]
        args = (data["x0"], data["u_prev"], data["y_ref"])
        opts = {"d": data["d"], "u_ref": data["u_ref"], "x_ref_N": data["x_ref_N"]}
        mpc = LinearMPC(**dict(case["inst"], osqp_settings={"max_iter": 20}))
        tight = LinearMPC(
            **dict(
                case["inst"],
                osqp_settings={"max_iter": 400_000, "eps_abs": 1e-10, "eps_rel": 1e-10},
                rescue=False,
            )
        )
        first = mpc.solve(*args, **opts)
        if first.iterations < 20:
            continue  # converged within the cap: OSQP stays first
        assert mpc._exact_first
        rng = np.random.default_rng(seed)
        for _ in range(3):  # the same problem at a moved reference
            y_ref = data["y_ref"] + 0.05 * rng.standard_normal(data["y_ref"].shape)
            sol = mpc.solve(args[0], args[1], y_ref, **opts)
            ref = tight.solve(args[0], args[1], y_ref, **opts)
            assert ref.status == "solved"
            if sol.iterations == 0:
                firsts += 1
                assert sol.status == "solved (polished)"
            np.testing.assert_allclose(sol.U, ref.U, atol=1e-5 * (1 + np.max(np.abs(ref.U))))
            assert sol.cost == pytest.approx(ref.cost, rel=1e-6, abs=1e-6)
        mpc.reset()
        assert not mpc._exact_first
    assert firsts >= 24


def test_singular_active_set_systems_in_a_row_send_the_problem_to_daqp(monkeypatch):
    """After ``_KKT_TRIES`` singular active-set KKT systems in a row a sparse-form problem
    goes to DAQP directly (scipy's SuperLU keeps memory of each failed factorisation of
    these systems), still with DAQP's optimum; ``reset`` lets it try the active set
    again."""
    import train_envs.mpc.recovery as recovery

    calls = []

    def singular(K):
        calls.append(K.shape)
        raise RuntimeError("Factor is exactly singular")

    case = random_instance(0)
    inst = dict(case["inst"], form="sparse", osqp_settings={"max_iter": 10})
    data = case["data"]
    mpc = LinearMPC(**inst)
    mpc.solve(data["x0"], data["u_prev"], data["y_ref"], d=data["d"])
    x, y, _ = mpc._backend.solve()
    mpc._sparse = False
    ref = mpc._exact(x, y)  # DAQP alone
    mpc._sparse = True
    monkeypatch.setattr(recovery, "spla", SimpleNamespace(splu=singular))
    mpc._kkt_singular = 0  # (the capped solve above may have met a singular one)
    for _ in range(recovery._KKT_TRIES + 3):
        out = mpc._exact(x, y)
        assert isinstance(out, tuple)
        np.testing.assert_array_equal(out[0], ref[0])
    assert len(calls) == recovery._KKT_TRIES
    mpc.reset()
    mpc._exact(x, y)
    assert len(calls) == recovery._KKT_TRIES + 1
