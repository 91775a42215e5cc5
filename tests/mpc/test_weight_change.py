"""A weight change is a data update: it gives the QP a cold construction gives.

``LinearMPC.set_weights`` rebuilds only the weight-dependent data on the matrices kept
per model; these tests check that the result equals a full rebuild (the path of the
constructor) bit for bit, for both QP forms, and, on every MPC env under a random
action sequence, that the controllers' QPs after many weight changes equal a cold
rebuild of the same model and weights and the tube MPC's closed forms a cold
composition; decisions from the same data then agree to the solver's tolerance
(OSQP's scaling is fixed at its setup).
"""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest
from test_mpc_core import random_instance

import train_envs  # noqa: F401
from train_envs._jit import enabled, implementation
from train_envs.controllers import make_controller
from train_envs.controllers.tube.closed_form import make_closed_form
from train_envs.mpc import LinearMPC
from train_envs.mpc.blas import single_thread_blas
from train_envs.scenarios import get_scenario
from train_envs.simulation import ClosedLoop

#: the arrays that make up the QP data and the condensed quantities built on them
_FIELDS = ("_P_dense", "_A_dense", "_M_full", "_M_no_D", "_H", "_Fq", "_Lth_c")


def _snapshot(mpc: LinearMPC) -> dict[str, np.ndarray]:
    return {k: np.array(getattr(mpc, k)) for k in _FIELDS}


def _cold(mpc: LinearMPC) -> dict[str, np.ndarray]:
    """The QP data of a full rebuild from the current model and weights."""
    mpc._struct = None
    mpc._build()
    return _snapshot(mpc)


def _equal(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> None:
    for k in _FIELDS:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)


@pytest.mark.parametrize("form", ["condensed", "sparse"])
@pytest.mark.parametrize("seed", range(6))
def test_set_weights_equals_cold_build(seed, form):
    case = random_instance(seed)
    inst = dict(case["inst"], form=form)
    rng = np.random.default_rng(100 + seed)
    mpc = LinearMPC(**inst)
    for _ in range(3):
        kw = {"Q": inst["Q"] * rng.uniform(0.1, 10.0), "R": inst["R"] * rng.uniform(0.1, 10.0)}
        if inst["S"] is not None:
            kw["S"] = inst["S"] * rng.uniform(0.1, 10.0)
        if inst["P"] is not None:
            kw["P"] = inst["P"] * rng.uniform(0.1, 10.0)
        if seed % 2:
            kw["stage_scales"] = {"Q": rng.uniform(0.5, 2.0, inst["Np"])}
        mpc.set_weights(**kw)
    warm = _snapshot(mpc)
    fresh = LinearMPC(**dict(inst, **{k: v for k, v in kw.items() if k != "stage_scales"}))
    if "stage_scales" in kw:
        fresh.set_weights(stage_scales=kw["stage_scales"])
    _equal(warm, _snapshot(fresh))
    _equal(warm, _cold(mpc))
    data = case["data"]
    args = (data["x0"], data["u_prev"], data["y_ref"])
    opts = {"d": data["d"], "u_ref": data["u_ref"], "x_ref_N": data["x_ref_N"]}
    # OSQP scales the data by factors fixed at its setup, so the two solves iterate
    # differently: equal to the solver's tolerance
    mpc.reset_solver()
    a, b = mpc.solve(*args, **opts), fresh.solve(*args, **opts)
    assert a.status == b.status
    np.testing.assert_allclose(a.u0, b.u0, rtol=1e-4, atol=1e-5)


@pytest.mark.parametrize(
    "name, scen",
    [
        ("mpc", "paper001_stopping"),
        ("sempc", "paper000_single_section"),
        ("adaptive_mpc", "paper002_cruise"),
    ],
)
def test_replace_weights_gives_the_data_of_set_weights(name, scen):
    """The controllers' unchecked weight path (``replace_weights``: weights they build
    from checked parameters, a Riccati solution as ``P``) gives the QP data of the
    checked ``set_weights`` bit for bit, over random tunable parameters; a wrong shape
    is still refused."""
    sc = get_scenario(scen)
    ctrl = make_controller(name, scenario=sc)
    ClosedLoop(sc, ctrl).reset(seed=0)
    mpc = ctrl._mpc
    specs = ctrl.tunable_params()
    rng = np.random.default_rng(7)
    for _ in range(8):
        units = rng.uniform(-1.0, 1.0, len(specs))
        ctrl.set_params(**{p.name: p.from_unit(u) for p, u in zip(specs, units, strict=True)})
        got = _snapshot(mpc)
        kw = {k: getattr(mpc, "_" + k) for k in ("Q", "R", "S", "P")}
        mpc.set_weights(**{k: np.array(v) for k, v in kw.items() if v is not None})
        _equal(got, _snapshot(mpc))
    with pytest.raises(ValueError, match=r"Q must have shape \(\d+, \d+\)"):
        mpc.replace_weights(Q=np.eye(mpc.p + 1))


@pytest.mark.parametrize("form", ["condensed", "sparse"])
@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("changes", [1, 2])
def test_deferred_matrix_update_gives_the_solves_of_an_immediate_one(seed, form, changes):
    """OSQP gets new matrix values before its next call, not at each weight change.
    One change per solve (and a solver reset after a change) gives the solutions of
    sending every change at once, bit for bit; with several changes between solves
    OSQP is refactorised once instead of per change, and its rescaling of the data at
    each update makes the iterates differ in the last bits: the same solution to its
    tolerance. (Without the rescue, so that OSQP runs at every solve: the exact finish
    run first after a capped solve would skip OSQP calls and gather changes.)"""
    case = random_instance(seed)
    inst = dict(case["inst"], form=form, rescue=False)
    data = case["data"]
    args = (data["x0"], data["u_prev"], data["y_ref"])
    opts = {"d": data["d"], "u_ref": data["u_ref"], "x_ref_N": data["x_ref_N"]}
    lazy, eager = LinearMPC(**inst), LinearMPC(**inst)
    rng = np.random.default_rng(200 + seed)
    for k in range(6):
        for _ in range(changes):
            kw = {"Q": inst["Q"] * rng.uniform(0.1, 10.0), "R": inst["R"] * rng.uniform(0.1, 10.0)}
            for mpc in (lazy, eager):
                mpc.set_weights(**kw)
            eager._flush_matrices()
        if k == 3:
            for mpc in (lazy, eager):
                mpc.reset_solver()
        a, b = lazy.solve(*args, **opts), eager.solve(*args, **opts)
        assert a.status == b.status
        if changes == 1:
            assert a.iterations == b.iterations and a.cost == b.cost
            np.testing.assert_array_equal(a.U, b.U)
        else:
            np.testing.assert_allclose(a.U, b.U, rtol=1e-4, atol=1e-5)


def _qps(ctrl) -> list[LinearMPC]:
    """The controller's QPs with its current parameters (tube MPCs: one per hold)."""
    problems = getattr(ctrl, "_problems", None)
    if problems is not None:
        out = []
        for M in sorted(problems):
            prob = ctrl._problem(M)
            ctrl._sync_qp(prob)  # the core gets the weights when it next solves
            out.append(prob.mpc)
        return out
    return [ctrl._mpc]


def after_random_actions(env_id: str, steps: int = 8) -> gym.Env:
    """The env after ``steps`` uniformly random actions (seeded; stops at an episode end)."""
    env = gym.make(env_id)
    env.reset(seed=0)
    env.action_space.seed(0)
    for _ in range(steps):
        _, _, term, trunc, _ = env.step(env.action_space.sample())
        if term or trunc:
            break
    return env


@pytest.mark.parametrize(
    "env_id",
    [
        "TrainEnvs/Stopping001-v0",
        "TrainEnvs/Section000-v0",
        "TrainEnvs/Cruise002-v0",
        "TrainEnvs/Yizhuang-v0",
        "TrainEnvs/Zurich-v0",
    ],
)
def test_env_qps_after_random_actions_equal_a_cold_rebuild(env_id):
    env = after_random_actions(env_id)
    ctrl = env.unwrapped.controller
    with single_thread_blas():  # as in the env step (BLAS results depend on threads)
        for mpc in _qps(ctrl):
            warm = _snapshot(mpc)
            _equal(warm, _cold(mpc))
    env.close()


def test_rsmpc_closed_forms_after_random_actions_equal_cold_ones():
    env = after_random_actions("TrainEnvs/Stopping001-v0")
    ctrl = env.unwrapped.controller
    seen = 0
    with single_thread_blas():
        for M in sorted(ctrl._problems):
            prob = ctrl._problem(M)
            warm = ctrl._explicit(prob)
            if warm is False:
                continue
            prob.frames = None
            cold = make_closed_form(prob, ctrl._layout)
            for k in ("cols", "T", "b"):
                np.testing.assert_array_equal(getattr(warm, k), getattr(cold, k), err_msg=k)
            assert (warm.Umap is None) == (cold.Umap is None)
            if warm.Umap is not None:
                np.testing.assert_array_equal(warm.Umap, cold.Umap)
            seen += 1
    assert seen >= 1
    env.close()


@pytest.mark.parametrize("n_cars", [1, 6])
def test_compiled_doubling_equals_reference(n_cars):
    """The compiled twin of the DARE doubling gives the reference's solution on the train
    MPCs' augmented models over random tunable weights: bit for bit where numpy and
    numba's LAPACK calls run the goldens' BLAS kernel; on another kernel (AVX-512, say)
    the products round differently and the 6-car model's conditioning (q_dv/q_s up to
    1e8) amplifies that, so there within 1e-8 of max |H| (the residual test's scale)."""
    from tests.golden.cases import GOLDEN_FILE, blas_kernel

    same_kernel = blas_kernel() == json.loads(GOLDEN_FILE.read_text()).get("blas")

    if not enabled():
        pytest.skip("compiled twins disabled")
    name, scen = (
        ("mpc", "paper001_stopping") if n_cars == 1 else ("sempc", "paper000_single_section")
    )
    sc = get_scenario(scen)
    ctrl = make_controller(name, scenario=sc)
    ClosedLoop(sc, ctrl).reset(seed=0)
    A, B = ctrl._Ad, ctrl._Bd
    n, m = B.shape
    Aa = np.block([[A, B], [np.zeros((m, n)), np.eye(m)]])
    Ba = np.vstack([B, np.eye(m)])
    fast = implementation("dare_doubling", compiled_twin=True)
    ref = implementation("dare_doubling", compiled_twin=False)
    rng = np.random.default_rng(n_cars)
    specs = ctrl.tunable_params()
    for _ in range(20):
        ctrl.set_params(
            **{
                p.name: p.from_unit(u)
                for p, u in zip(specs, rng.uniform(-1, 1, len(specs)), strict=True)
            }
        )
        Q, R, _ = ctrl._weights()
        Qa = np.zeros((n + m, n + m))
        Qa[:n, :n] = ctrl._C.T @ Q @ ctrl._C
        H1, ok1 = ref(Aa, Ba, Qa, np.ascontiguousarray(R), 1e-12)
        H2, ok2 = fast(Aa, Ba, Qa, np.ascontiguousarray(R), 1e-12)
        assert ok1 and ok2
        if same_kernel:
            np.testing.assert_array_equal(H1, H2)
        else:
            assert np.abs(H1 - H2).max() <= 1e-8 * np.abs(H1).max()
        # and it is the Riccati solution
        K = np.linalg.solve(R + Ba.T @ H1 @ Ba, Ba.T @ H1 @ Aa)
        res = Aa.T @ H1 @ Aa - Aa.T @ H1 @ Ba @ K + Qa - H1
        assert np.abs(res).max() <= 1e-8 * np.abs(H1).max()


def test_stage_weights_fill_the_block_diagonal_stage_by_stage():
    from train_envs.mpc.assembly import _psd_sqrt, _stage_weights

    rng = np.random.default_rng(7)
    A = rng.normal(size=(3, 3))
    full = A @ A.T
    blocks = [
        (rng.uniform(0.1, 3.0, 6), 6, np.diag([2.0, 0.0, 5.0])),
        (None, 4, np.array([[0.3]])),
        (rng.uniform(0.5, 2.0, 5), 5, np.array([[1.5]])),
        (None, 1, full),
    ]
    wt = _stage_weights(blocks)
    # the same matrices written stage by stage
    facs = [_psd_sqrt(X) for _, _, X in blocks]
    n = sum(k * X.shape[0] for _, k, X in blocks)
    W = np.zeros((n, n))
    Lw = np.zeros((sum(k * L.shape[0] for (_, k, _), L in zip(blocks, facs, strict=True)), n))
    r = c = 0
    for (scales, k, X), L in zip(blocks, facs, strict=True):
        for t in range(k):
            s_t = 1.0 if scales is None else float(scales[t])
            W[c : c + X.shape[0], c : c + X.shape[0]] = s_t * X if scales is not None else X
            Lw[r : r + L.shape[0], c : c + X.shape[0]] = (
                float(np.sqrt(scales[t])) * L if scales is not None else L
            )
            r += L.shape[0]
            c += X.shape[0]
    # its products are those of the dense matrices: exactly where a column of W (a row
    # of Lw) has one non-zero entry, the terminal block's product on its own rows and
    # columns (BLAS may sum a full dense row in another order)
    X = rng.normal(size=(5, n))
    Y = rng.normal(size=(n, 4))
    c0, r0 = n - 3, Lw.shape[0] - facs[-1].shape[0]

    def check(wt, W, Lw):
        XW, LY = wt.right(X), wt.factor(Y)
        assert np.array_equal(XW[:, :c0], (X @ W)[:, :c0])
        assert np.array_equal(XW[:, c0:], X[:, c0:] @ W[c0:, c0:])
        assert np.array_equal(LY[:r0], (Lw @ Y)[:r0])
        assert np.array_equal(LY[r0:], Lw[r0:, c0:] @ Y[c0:])
        np.testing.assert_allclose(XW, X @ W, rtol=1e-14, atol=1e-14)
        np.testing.assert_allclose(LY, Lw @ Y, rtol=1e-14, atol=1e-14)

    check(wt, W, Lw)
    # a zero stage scale leaves a zero factor row
    blocks[0] = (np.array([1.0, 0.0, 2.0, 0.0, 1.0, 3.0]), 6, blocks[0][2])
    Wz, Lz = W.copy(), Lw.copy()
    for t in range(6):
        s_t = float(blocks[0][0][t])
        Wz[3 * t : 3 * t + 3, 3 * t : 3 * t + 3] = s_t * blocks[0][2]
        Lz[2 * t : 2 * t + 2, 3 * t : 3 * t + 3] = float(np.sqrt(s_t)) * facs[0]
    check(_stage_weights(blocks), Wz, Lz)


def test_diagonal_factor_is_the_factor_eigh_gives():
    """A diagonal weight's factor without LAPACK equals the one from ``eigh`` bit for bit
    (rows, their order among equal weights, dropped zero weights)."""
    from train_envs.mpc.assembly import _diagonal_sqrt, _eigh_sqrt

    rng = np.random.default_rng(11)
    for _ in range(3000):
        n = int(rng.integers(1, 26))
        d = rng.choice([0.0, 1.0, 2.5, 1e-9, 1e6], n) * rng.choice([1.0, 1.0, 3.0], n)
        d[rng.random(n) < 0.3] = rng.uniform(0.0, 10.0)  # repeated values
        got = _diagonal_sqrt(d)
        want = _eigh_sqrt(*np.linalg.eigh(np.diag(d)))
        assert got.shape == want.shape
        assert got.tobytes() == want.tobytes()
