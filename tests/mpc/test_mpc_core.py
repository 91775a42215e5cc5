"""Tests of the linear-MPC QP engine (train_envs.mpc).

The reference solutions are built independently of the module: the prediction is
obtained by simulating the model step by step (never through the module's
prediction matrices), the condensed QP is assembled from those rollouts and solved
with scipy's SLSQP followed by an exact KKT solve on the identified active set.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg as sla
from scipy.optimize import minimize

from train_envs.mpc import (
    LinearMPC,
    MPCSolution,
    terminal_cost_dare,
    terminal_cost_lyapunov,
)

TIGHT = {"eps_abs": 1e-9, "eps_rel": 1e-9, "polishing": True, "max_iter": 200_000}


# ---------------------------------------------------------------------------
# random instances and an independent reference solver
# ---------------------------------------------------------------------------
def _psd(rng: np.random.Generator, k: int, floor: float) -> np.ndarray:
    M = rng.standard_normal((k, k))
    return M @ M.T / k + floor * np.eye(k)


def random_instance(seed: int) -> dict:
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 5))
    m = int(rng.integers(1, 3))
    p = int(rng.integers(1, n + 1))
    A = rng.standard_normal((n, n))
    A *= rng.uniform(0.7, 1.15) / max(np.abs(np.linalg.eigvals(A)))  # stable or unstable
    B = rng.standard_normal((n, m))
    C = rng.standard_normal((p, n))
    Np = int(rng.integers(3, 8))
    Nc = int(rng.integers(1, Np + 1))
    u_max = rng.uniform(0.2, 1.0, m)
    y_box = rng.uniform(0.5, 2.0, p)
    inst = dict(
        A=A,
        B=B,
        C=C,
        Np=Np,
        Nc=Nc,
        Q=_psd(rng, p, 0.1),
        R=np.diag(rng.uniform(0.05, 0.5, m)),
        S=np.diag(rng.uniform(0.01, 0.2, m)) if seed % 3 == 0 else None,
        P=_psd(rng, n, 0.1) if seed % 2 == 0 else None,
        u_min=-u_max,
        u_max=u_max,
        du_min=-rng.uniform(0.1, 0.5, m) if seed % 4 != 1 else None,
        du_max=rng.uniform(0.1, 0.5, m) if seed % 4 != 1 else None,
        y_min=np.where(rng.random(p) < 0.7, -y_box, -np.inf),
        y_max=y_box,
        soft_penalty=float(rng.uniform(5.0, 50.0)),
        soft_quadratic=float(rng.uniform(0.5, 5.0)),
        delta_u=bool(seed % 2),
    )
    data = dict(
        x0=rng.standard_normal(n) * 1.5,
        u_prev=rng.uniform(-1, 1, m) * u_max,
        y_ref=rng.standard_normal((Np, p)) * 2.0,
        d=rng.standard_normal((Np, n)) * 0.1 if seed % 5 != 0 else None,
        u_ref=rng.standard_normal((Np, m)) * 0.2 if inst["S"] is not None else None,
        x_ref_N=rng.standard_normal(n) if inst["P"] is not None else None,
        y_max_override=(y_box[None, :] * rng.uniform(0.6, 1.4, (Np, p))) if seed % 3 == 1 else None,
    )
    return {"inst": inst, "data": data}


def _sqrtm_psd(W: np.ndarray) -> np.ndarray:
    lam, V = np.linalg.eigh(W)
    return (V * np.sqrt(np.clip(lam, 0.0, None))) @ V.T


def reference_solve(inst: dict, data: dict) -> dict:
    """Condensed QP built from model rollouts, solved by SLSQP + exact KKT on the active set."""
    A, B, C = inst["A"], inst["B"], inst["C"]
    n, m = B.shape
    Np, Nc = inst["Np"], inst["Nc"]
    x0, up = data["x0"], data["u_prev"]
    d = np.zeros((Np, n)) if data["d"] is None else data["d"]
    nz = Nc * m

    def rollout(z: np.ndarray):
        Z = z.reshape(Nc, m)
        Uc = up + np.cumsum(Z, axis=0) if inst["delta_u"] else Z.copy()
        Uf = np.array([Uc[min(t, Nc - 1)] for t in range(Np)])
        dU = np.diff(np.vstack([up, Uc]), axis=0)
        x = x0.copy()
        X = []
        for t in range(Np):
            x = A @ x + B @ Uf[t] + d[t]
            X.append(x)
        X = np.array(X)
        return Uc, Uf, dU, X, X @ C.T

    def residual(z: np.ndarray) -> np.ndarray:
        Uc, Uf, dU, X, Y = rollout(z)
        parts = [((Y - data["y_ref"]) @ _sqrtm_psd(inst["Q"])).ravel()]
        parts.append((dU @ _sqrtm_psd(inst["R"])).ravel())
        if inst["S"] is not None:
            parts.append(((Uf - data["u_ref"]) @ _sqrtm_psd(inst["S"])).ravel())
        if inst["P"] is not None:
            parts.append(_sqrtm_psd(inst["P"]) @ (X[-1] - data["x_ref_N"]))
        return np.concatenate(parts)

    def affine(fun):
        f0 = np.asarray(fun(np.zeros(nz)), float).ravel()
        J = np.column_stack([np.asarray(fun(np.eye(nz)[i]), float).ravel() - f0 for i in range(nz)])
        return f0, J

    r0, Jr = affine(residual)
    Uc0, JU = affine(lambda z: rollout(z)[0])
    dU0, JdU = affine(lambda z: rollout(z)[2])
    Y0, JY = affine(lambda z: rollout(z)[4])

    # soft output rows: one slack per (stage, output) with a finite bound
    p = C.shape[0]
    ymin = np.tile(inst["y_min"], (Np, 1))
    ymax = np.tile(inst["y_max"], (Np, 1))
    if data["y_max_override"] is not None:
        ymax = data["y_max_override"]
    rows = [(i, j) for i in range(Np) for j in range(p)]
    ns = len(rows)
    rho, gam = inst["soft_penalty"], inst["soft_quadratic"]
    nw = nz + ns
    Hf = np.zeros((nw, nw))
    Hf[:nz, :nz] = 2.0 * Jr.T @ Jr
    Hf[nz:, nz:] = 2.0 * gam * np.eye(ns)
    f = np.concatenate([2.0 * Jr.T @ r0, np.full(ns, rho)])
    G, h = [], []

    def add(row_z: np.ndarray, row_e: np.ndarray, bound: float) -> None:
        if np.isfinite(bound):
            G.append(np.concatenate([row_z, row_e]))
            h.append(bound)

    zero_e = np.zeros(ns)
    for k in range(nz):
        add(JU[k], zero_e, inst["u_max"][k % m] - Uc0[k])
        add(-JU[k], zero_e, -(inst["u_min"][k % m] - Uc0[k]))
        if inst["du_max"] is not None:
            add(JdU[k], zero_e, inst["du_max"][k % m] - dU0[k])
            add(-JdU[k], zero_e, -(inst["du_min"][k % m] - dU0[k]))
    for s, (i, j) in enumerate(rows):
        e = np.zeros(ns)
        e[s] = -1.0
        add(JY[i * p + j], e, ymax[i, j] - Y0[i * p + j])
        add(-JY[i * p + j], e, -(ymin[i, j] - Y0[i * p + j]))
        add(np.zeros(nz), e, 0.0)
    G, h = np.array(G), np.array(h)

    res = minimize(
        lambda w: 0.5 * w @ Hf @ w + f @ w,
        np.zeros(nw),
        jac=lambda w: Hf @ w + f,
        constraints=[{"type": "ineq", "fun": lambda w: h - G @ w, "jac": lambda w: -G}],
        method="SLSQP",
        options={"ftol": 1e-15, "maxiter": 1000},
    )
    w = res.x
    # exact KKT solve on the active set found by SLSQP
    act = np.flatnonzero(h - G @ w < 1e-6)
    K = np.block([[Hf, G[act].T], [G[act], np.zeros((act.size, act.size))]])
    sol = np.linalg.lstsq(K, np.concatenate([-f, h[act]]), rcond=None)[0]
    w_kkt, lam = sol[:nw], sol[nw:]
    if np.all(G @ w_kkt <= h + 1e-9) and np.all(lam >= -1e-9):
        w = w_kkt
    else:  # pragma: no cover - diagnostic only
        assert res.success, res.message
    z, eps = w[:nz], w[nz:]
    Uc = rollout(z)[0]
    cost = float(np.sum((r0 + Jr @ z) ** 2) + rho * eps.sum() + gam * eps @ eps)
    return {"U": Uc, "eps": eps, "cost": cost}


def make_mpc(inst: dict, **extra) -> LinearMPC:
    kw = {k: v for k, v in inst.items() if k not in ("A", "B", "C")}
    kw.update(extra)
    return LinearMPC(inst["A"], inst["B"], inst["C"], **kw)


def with_data(method, data: dict, **extra):
    """Call ``solve`` (or ``unconstrained_cost``) with an instance's data."""
    return method(
        data["x0"],
        data["u_prev"],
        data["y_ref"],
        d=data["d"],
        u_ref=data["u_ref"],
        x_ref_N=data["x_ref_N"],
        **extra,
    )


def solve(mpc: LinearMPC, data: dict) -> MPCSolution:
    return with_data(mpc.solve, data, y_max=data["y_max_override"])


# ---------------------------------------------------------------------------
# optimality against the independent reference
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("form", ["condensed", "sparse"])
def test_matches_independent_reference_on_random_instances(form):
    active = 0
    for seed in range(24):
        case = random_instance(seed)
        inst, data = case["inst"], case["data"]
        ref = reference_solve(inst, data)
        mpc = make_mpc(inst, osqp_settings=TIGHT, form=form)
        sol = solve(mpc, data)
        assert not sol.fallback, (seed, sol.status)
        assert sol.status in ("solved", "solved (polished)"), (seed, sol.status)
        np.testing.assert_allclose(sol.U, ref["U"], atol=1e-5, err_msg=f"seed {seed}")
        np.testing.assert_allclose(sol.u0, ref["U"][0], atol=1e-5)
        assert sol.slack_max == pytest.approx(max(ref["eps"].max(), 0.0), abs=1e-5)
        assert sol.cost == pytest.approx(ref["cost"], rel=1e-6, abs=1e-6)
        u_act = np.any(np.isclose(np.abs(sol.U), inst["u_max"], atol=1e-7))
        active += bool(u_act or sol.slack_max > 1e-6)
    assert active >= 8  # the instances really exercise the constraints


def test_unconstrained_first_is_exact_and_falls_back_to_osqp():
    """The shortcut returns the reference optimum when no constraint is active and leaves
    every other instance to OSQP; both kinds occur among these instances."""
    shortcut = osqp_runs = 0
    for seed in range(40):
        case = random_instance(seed)
        inst, data = case["inst"], case["data"]
        if seed % 2:  # loose boxes so that some optima are unconstrained
            inst = {
                k: (
                    10.0 * v
                    if k in ("u_min", "u_max", "du_min", "du_max", "y_min", "y_max")
                    and v is not None
                    else v
                )
                for k, v in inst.items()
            }
            data = {**data, "y_max_override": None}
        ref = reference_solve(inst, data)
        sol = solve(
            make_mpc(inst, osqp_settings=TIGHT, form="condensed", unconstrained_first=True), data
        )
        assert not sol.fallback
        np.testing.assert_allclose(sol.U, ref["U"], atol=1e-5, err_msg=f"seed {seed}")
        assert sol.cost == pytest.approx(ref["cost"], rel=1e-6, abs=1e-6)
        if sol.status == "solved (unconstrained)":
            shortcut += 1
            assert sol.iterations == 0 and sol.solve_time_s == 0.0 and sol.slack_max == 0.0
        else:
            osqp_runs += 1
    assert shortcut >= 5 and osqp_runs >= 5


def pinned_instance(seed: int, loose: bool, p_pin: float) -> tuple:
    """A random instance in absolute-input form with a share ``p_pin`` of its inputs
    pinned (equal bounds, at zero or a random value); ``loose``: boxes 10x wider.
    Returns ``(inst, data, lo, hi, pin, val)``."""
    case = random_instance(seed)
    inst = {**case["inst"], "delta_u": False}
    if loose:
        for k in ("u_min", "u_max", "du_min", "du_max", "y_min", "y_max"):
            if inst[k] is not None:
                inst[k] = 10.0 * inst[k]
    data = {**case["data"], "y_max_override": None}
    rng = np.random.default_rng(seed)
    Nc, m = inst["Nc"], inst["B"].shape[1]
    lo = np.tile(inst["u_min"], (Nc, 1))
    hi = np.tile(inst["u_max"], (Nc, 1))
    pin = rng.random((Nc, m)) < p_pin
    val = np.where(rng.random((Nc, m)) < 0.5, 0.0, rng.uniform(-0.5, 0.5, (Nc, m)))
    lo[pin] = hi[pin] = val[pin]
    return inst, data, lo, hi, pin, val


def test_unconstrained_first_with_pinned_inputs_is_exact():
    """Inputs fixed by equal per-stage bounds (a hold, move blocking) keep the shortcut
    exact: its plan and cost equal a tight OSQP solve of the same pinned problem."""
    hits = pinned_nonzero = 0
    for seed in range(1, 40, 2):  # absolute-input form (delta_u=False)
        inst, data, lo, hi, pin, val = pinned_instance(seed, loose=True, p_pin=0.4)
        fast = make_mpc(inst, osqp_settings=TIGHT, form="condensed", unconstrained_first=True)
        ref = make_mpc(inst, osqp_settings=TIGHT, form="condensed")
        for mpc in (fast, ref):
            mpc.set_base_bounds(u_min=lo, u_max=hi)
        a, b = solve(fast, data), solve(ref, data)
        assert not a.fallback and not b.fallback
        np.testing.assert_allclose(a.U, b.U, atol=1e-6, err_msg=f"seed {seed}")
        assert a.cost == pytest.approx(b.cost, rel=1e-6, abs=1e-7)
        if a.status == "solved (unconstrained)":
            hits += 1
            np.testing.assert_array_equal(a.U[pin], val[pin])  # exactly the pinned values
            pinned_nonzero += bool(pin.any() and np.any(val[pin] != 0.0))
    assert hits >= 5 and pinned_nonzero >= 2


def test_unconstrained_cost_bounds_the_solve_and_equals_it_when_exact():
    """``unconstrained_cost`` is a lower bound on ``solve``'s cost for the same data (every
    row and slack penalty can only raise the optimum) and equals it bit for bit when the
    solve is decided by the unconstrained shortcut (free and pinned inputs)."""
    exact = below = pinned_nonzero = 0
    for seed in range(40):  # absolute-input form (delta_u=False), some inputs pinned
        # odd seeds: loose boxes, where the shortcut decides many instances
        inst, data, lo, hi, pin, val = pinned_instance(seed, loose=bool(seed % 2), p_pin=0.3)
        mpc = make_mpc(inst, osqp_settings=TIGHT, form="condensed", unconstrained_first=True)
        mpc.set_base_bounds(u_min=lo, u_max=hi)
        lb = with_data(mpc.unconstrained_cost, data)
        sol = solve(mpc, data)
        assert lb is not None
        if sol.fallback:  # pins that make the hard rows infeasible: no cost to compare
            continue
        if sol.status == "solved (unconstrained)":
            exact += 1
            assert lb == sol.cost
            pinned_nonzero += bool(np.any(val[pin] != 0.0))
        else:
            below += 1
            assert lb <= sol.cost + 1e-7 * max(1.0, abs(sol.cost)), (seed, lb, sol.cost)
    assert exact >= 5 and below >= 5 and pinned_nonzero >= 2
    # not available: shortcut off, sparse form
    case = random_instance(0)
    args = (case["data"]["x0"], case["data"]["u_prev"], case["data"]["y_ref"])
    assert make_mpc(case["inst"]).unconstrained_cost(*args, d=case["data"]["d"]) is None
    sparse = make_mpc(case["inst"], form="sparse", unconstrained_first=True)
    assert sparse.unconstrained_cost(*args, d=case["data"]["d"]) is None


def test_unconstrained_affine_maps_reproduce_the_shortcut():
    """The explicit maps of the unconstrained optimum (free inputs and inputs pinned at
    zero) give, for the data vector of a solve, the plan, predictions and cost of that
    solve whenever the solve was decided by the shortcut; a pin at a non-zero value, the
    sparse form and a solver without the shortcut have no maps."""
    hits = nonzero_pins = 0
    for seed in range(40):
        inst, data, lo, hi, pin, val = pinned_instance(seed, loose=True, p_pin=0.3)
        mpc = make_mpc(inst, osqp_settings=TIGHT, form="condensed", unconstrained_first=True)
        mpc.set_base_bounds(u_min=lo, u_max=hi)
        aff = mpc.unconstrained_affine()
        if np.any(val[pin] != 0.0):
            assert aff is None
            nonzero_pins += 1
            continue
        assert aff is not None and aff.ntheta == mpc._theta.size
        sol = solve(mpc, data)
        if sol.status != "solved (unconstrained)":
            continue
        hits += 1
        th = mpc._theta  # the data vector this solve loaded
        assert th[0] == 1.0
        np.testing.assert_allclose(aff.U @ th, sol.U.ravel(), rtol=1e-9, atol=1e-10)
        np.testing.assert_allclose(aff.X @ th, sol.X.ravel(), rtol=1e-9, atol=1e-10)
        np.testing.assert_allclose(aff.Y @ th, sol.Y.ravel(), rtol=1e-9, atol=1e-10)
        r = aff.R @ th
        assert float(r @ r) == pytest.approx(sol.cost, rel=1e-9, abs=1e-12)
        np.testing.assert_array_equal((aff.Z @ th)[pin.ravel()], 0.0)
    assert hits >= 5 and nonzero_pins >= 3
    du_hits = 0
    for seed in range(40):  # the increment form of the random instances
        case = random_instance(seed)
        inst, data = case["inst"], {**case["data"], "y_max_override": None}
        for k in ("u_min", "u_max", "du_min", "du_max", "y_min", "y_max"):
            if inst[k] is not None:
                inst = {**inst, k: 10.0 * inst[k]}
        mpc = make_mpc(inst, osqp_settings=TIGHT, form="condensed", unconstrained_first=True)
        aff = mpc.unconstrained_affine()
        sol = solve(mpc, data)
        if aff is None or sol.status != "solved (unconstrained)":
            continue
        du_hits += 1
        th = mpc._theta
        np.testing.assert_allclose(aff.U @ th, sol.U.ravel(), rtol=1e-9, atol=1e-10)
        r = aff.R @ th
        assert float(r @ r) == pytest.approx(sol.cost, rel=1e-9, abs=1e-12)
    assert du_hits >= 3
    case = random_instance(0)
    assert make_mpc(case["inst"]).unconstrained_affine() is None
    sparse = make_mpc(case["inst"], form="sparse", unconstrained_first=True)
    assert sparse.unconstrained_affine() is None


@pytest.mark.parametrize("form", ["condensed", "sparse"])
def test_default_settings_are_accurate_on_random_instances(form):
    """With the default OSQP tolerances the plan is still within 1e-3 of the optimum."""
    for seed in range(24, 32):
        case = random_instance(seed)
        ref = reference_solve(case["inst"], case["data"])
        sol = solve(make_mpc(case["inst"], form=form), case["data"])
        assert not sol.fallback
        np.testing.assert_allclose(sol.U, ref["U"], atol=1e-3)


def test_delta_u_and_absolute_forms_give_the_same_plan():
    case = random_instance(7)
    inst, data = case["inst"], case["data"]
    a = solve(make_mpc(inst, delta_u=True, osqp_settings=TIGHT), data)
    b = solve(make_mpc(inst, delta_u=False, osqp_settings=TIGHT), data)
    np.testing.assert_allclose(a.U, b.U, atol=1e-6)
    np.testing.assert_allclose(a.X, b.X, atol=1e-6)


@pytest.mark.parametrize("form", ["condensed", "sparse"])
def test_predicted_trajectory_matches_simulation(form):
    case = random_instance(4)
    inst, data = case["inst"], case["data"]
    sol = solve(make_mpc(inst, osqp_settings=TIGHT, form=form), data)
    x = data["x0"].copy()
    for t in range(inst["Np"]):
        u = sol.U[min(t, inst["Nc"] - 1)]
        x = inst["A"] @ x + inst["B"] @ u + data["d"][t]
        np.testing.assert_allclose(sol.X[t], x, atol=1e-7)
        np.testing.assert_allclose(sol.Y[t], inst["C"] @ x, atol=1e-7)


# ---------------------------------------------------------------------------
# analytic unconstrained gain, terminal weights
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("form", ["condensed", "sparse"])
@pytest.mark.parametrize("seed", [0, 1, 2, 3, 6, 9])
def test_unconstrained_first_move_equals_analytic_gain(seed, form):
    case = random_instance(seed)
    inst, data = dict(case["inst"]), case["data"]
    big = 1e6
    inst.update(
        u_min=-big * np.ones(inst["B"].shape[1]),
        u_max=big * np.ones(inst["B"].shape[1]),
        du_min=None,
        du_max=None,
        y_min=None,
        y_max=None,
    )
    data = dict(data, y_max_override=None)
    mpc = make_mpc(inst, osqp_settings=TIGHT, form=form)
    sol = solve(mpc, data)
    gain = mpc.gain_unconstrained()
    u_gain = gain.apply(
        data["x0"], data["u_prev"], data["y_ref"], data["d"], data["u_ref"], data["x_ref_N"]
    )
    np.testing.assert_allclose(sol.u0, u_gain, rtol=1e-6, atol=1e-7)
    # state feedback part: a pure regulator (zero references, no disturbance)
    m = inst["B"].shape[1]
    zero_data = dict(data, y_ref=np.zeros_like(data["y_ref"]), d=None, u_prev=np.zeros(m))
    if data["u_ref"] is not None:
        zero_data["u_ref"] = np.zeros_like(data["u_ref"])
    if data["x_ref_N"] is not None:
        zero_data["x_ref_N"] = np.zeros_like(data["x_ref_N"])
    sol0 = solve(mpc, zero_data)
    np.testing.assert_allclose(sol0.u0, gain.Kx @ data["x0"], rtol=1e-6, atol=1e-7)


def test_terminal_cost_dare_satisfies_riccati():
    rng = np.random.default_rng(3)
    for _ in range(5):
        n, m = 4, 2
        A = rng.standard_normal((n, n)) * 0.6
        B = rng.standard_normal((n, m))
        Qx = _psd(rng, n, 0.5)
        R = _psd(rng, m, 0.5)
        P, K = terminal_cost_dare(A, B, Qx, R)
        ric = A.T @ P @ A - A.T @ P @ B @ np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A) + Qx - P
        assert np.max(np.abs(ric)) < 1e-8
        np.testing.assert_allclose(P, P.T, atol=1e-12)
        assert np.max(np.abs(np.linalg.eigvals(A - B @ K))) < 1.0
        # consistency: the Lyapunov weight of the LQR closed loop is the DARE solution
        P_lyap = terminal_cost_lyapunov(A - B @ K, Qx + K.T @ R @ K)
        np.testing.assert_allclose(P_lyap, P, rtol=1e-8, atol=1e-8)


def test_terminal_cost_lyapunov_satisfies_equation():
    rng = np.random.default_rng(5)
    for _ in range(5):
        A_cl = rng.standard_normal((5, 5))
        A_cl *= 0.9 / max(np.abs(np.linalg.eigvals(A_cl)))
        Qx = _psd(rng, 5, 0.2)
        P = terminal_cost_lyapunov(A_cl, Qx)
        assert np.max(np.abs(A_cl.T @ P @ A_cl - P + Qx)) < 1e-8
    with pytest.raises(ValueError, match="Schur stable"):
        terminal_cost_lyapunov(np.eye(2) * 1.1, np.eye(2))


# ---------------------------------------------------------------------------
# soft constraints, rate limits, fallback
# ---------------------------------------------------------------------------
def double_integrator(dt: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    return np.array([[1.0, dt], [0.0, 1.0]]), np.array([[0.5 * dt * dt], [dt]])


def di_mpc(**kw) -> LinearMPC:
    A, B = double_integrator()
    args = dict(
        Np=15,
        Q=np.diag([1.0, 0.1]),
        R=0.5,
        u_min=-1.0,
        u_max=1.0,
        du_min=-0.2,
        du_max=0.2,
        y_min=[-np.inf, -1.0],
        y_max=[np.inf, 1.0],
    )
    args.update(kw)
    return LinearMPC(A, B, **args)


def assert_in_window(u0, u_prev, u_min=-1.0, u_max=1.0, du=0.2):
    assert np.all(np.isfinite(u0))
    assert np.all(u0 >= u_min) and np.all(u0 <= u_max)
    assert np.all(np.abs(u0 - u_prev) <= du + 1e-12)


@pytest.mark.parametrize("form", ["condensed", "sparse"])
def test_infeasible_initial_state_gives_bounded_command_and_positive_slack(form):
    mpc = di_mpc(form=form)
    up = np.array([0.5])
    sol = mpc.solve(np.array([0.0, 10.0]), up, np.zeros(2))  # speed 10, bound 1
    assert not sol.fallback
    assert sol.status in ("solved", "solved (polished)", "solved inaccurate")
    assert_in_window(sol.u0, up)
    assert sol.slack_max > 1.0
    assert sol.u0[0] == pytest.approx(0.3, abs=1e-4)  # brake at the maximal rate
    tight = di_mpc(osqp_settings=TIGHT, form=form).solve(np.array([0.0, 10.0]), up, np.zeros(2))
    assert tight.u0[0] == pytest.approx(0.3, abs=1e-9)
    # a hard (infinite-penalty) bound instead is infeasible -> safe fallback
    hard = di_mpc(soft_penalty={"y": np.inf}, form=form)
    sol_h = hard.solve(np.array([0.0, 10.0]), up, np.zeros(2))
    assert sol_h.fallback
    assert_in_window(sol_h.u0, up)


@pytest.mark.parametrize("form", ["condensed", "sparse"])
def test_primal_infeasibility_verdict_is_final(form):
    """A QP whose hard rows cannot be met (speed 10, hard bound 1, braking limited by the
    rate) is proven infeasible by OSQP: the cascade does not continue ADMM from the
    diverging iterate (the relaxed, polished attempt), it falls back at once."""
    hard = di_mpc(soft_penalty={"y": np.inf}, form=form)
    continued = []
    rescue = hard._backend.rescue
    hard._backend.rescue = lambda *a, **k: continued.append(1) or rescue(*a, **k)
    up = np.array([0.5])
    sol = hard.solve(np.array([0.0, 10.0]), up, np.zeros(2))
    assert sol.status_val in (3, 4) and sol.fallback
    assert not continued
    assert sol.iterations < hard.osqp_settings["max_iter"]  # OSQP's own iterations only
    assert_in_window(sol.u0, up)
    # the same QP with soft rows is feasible and solved
    soft = di_mpc(form=form).solve(np.array([0.0, 10.0]), up, np.zeros(2))
    assert not soft.fallback and soft.slack_max > 1.0


@pytest.mark.parametrize("form", ["condensed", "sparse"])
def test_rate_limits_never_violated_in_closed_loop(form):
    A, B = double_integrator()
    mpc = di_mpc(form=form)
    rng = np.random.default_rng(0)
    x = np.array([0.0, 0.0])
    u = np.zeros(1)
    worst = 0.0
    for k in range(200):
        target = 3.0 if (k // 50) % 2 == 0 else -3.0
        sol = mpc.solve(x, u, np.array([target, 0.0]))
        assert not sol.fallback
        assert_in_window(sol.u0, u)
        worst = max(worst, float(np.abs(sol.u0 - u).max()))
        u = sol.u0
        x = A @ x + B @ u + 0.01 * rng.standard_normal(2)
    assert worst == pytest.approx(0.2, abs=1e-9)  # the rate limit is actually reached


@pytest.mark.parametrize("form", ["condensed", "sparse"])
def test_previous_input_outside_box_moves_back_at_the_rate_limit(form):
    mpc = di_mpc(form=form)
    sol = mpc.solve(np.zeros(2), np.array([1.7]), np.zeros(2))
    assert not sol.fallback
    assert sol.u0[0] == pytest.approx(1.5, abs=1e-9)


@pytest.mark.parametrize("form", ["condensed", "sparse"])
def test_fallback_on_non_finite_data_uses_shifted_plan(form):
    mpc = di_mpc(form=form)
    x = np.array([0.0, 0.0])
    good = mpc.solve(x, np.zeros(1), np.array([2.0, 0.0]))
    assert not good.fallback
    d_bad = np.array([np.nan, 0.0])
    sol = mpc.solve(x, good.u0, np.array([2.0, 0.0]), d=d_bad)
    assert sol.fallback and sol.status == "invalid input"
    assert_in_window(sol.u0, good.u0)
    # next element of the last good plan, clipped to the box and the rate window
    expected = np.clip(good.U[1], np.maximum(-1.0, good.u0 - 0.2), np.minimum(1.0, good.u0 + 0.2))
    np.testing.assert_allclose(sol.u0, expected, rtol=0, atol=1e-15)
    assert np.max(np.abs(good.U[1] - expected)) < 1e-4  # i.e. essentially the plan itself
    assert np.all(np.isfinite(sol.U))
    # non-finite state and previous input: still a finite command inside the box
    sol2 = mpc.solve(np.array([np.inf, 0.0]), np.array([np.nan]), np.array([2.0, 0.0]))
    assert sol2.fallback and np.all(np.isfinite(sol2.u0))
    assert -1.0 <= sol2.u0[0] <= 1.0
    # recovery: the next valid call is solved normally
    sol3 = mpc.solve(x, sol.u0, np.array([2.0, 0.0]))
    assert not sol3.fallback and sol3.status in ("solved", "solved (polished)")


@pytest.mark.parametrize("form", ["condensed", "sparse"])
def test_fallback_on_solver_failure(form):
    mpc = di_mpc(osqp_settings={"max_iter": 1}, rescue=False, form=form)
    up = np.array([0.1])
    sol = mpc.solve(np.array([1.0, 0.5]), up, np.zeros(2))
    assert sol.fallback
    assert sol.status == "maximum iterations reached" and sol.status_val == 7
    assert_in_window(sol.u0, up)
    np.testing.assert_allclose(sol.u0, up)  # no plan yet: hold the previous input
    # with the rescue cascade: either a verified solution or again a safe fallback
    rescued = di_mpc(osqp_settings={"max_iter": 1}, form=form)
    sol_r = rescued.solve(np.array([1.0, 0.5]), up, np.zeros(2))
    assert sol_r.fallback or sol_r.status in ("solved (polished)", "solved inaccurate")
    assert_in_window(sol_r.u0, up)


def test_hard_output_constraint_is_respected():
    mpc = di_mpc(soft_penalty={"y": np.inf}, osqp_settings=TIGHT)
    sol = mpc.solve(np.array([0.0, 0.5]), np.zeros(1), np.array([5.0, 0.0]))
    assert not sol.fallback
    assert sol.slack_max == 0.0
    assert np.all(sol.Y[:, 1] <= 1.0 + 1e-7)
    soft = di_mpc(soft_penalty=1e-3, osqp_settings=TIGHT)  # a cheap violation is taken
    sol_s = soft.solve(np.array([0.0, 0.5]), np.zeros(1), np.array([5.0, 0.0]))
    assert sol_s.slack_max > 1e-3


def test_exact_penalty_recovers_hard_solution_when_feasible():
    hard = di_mpc(soft_penalty={"y": np.inf}, osqp_settings=TIGHT)
    soft = di_mpc(osqp_settings=TIGHT)  # rho = 1e5 is above the multipliers
    x0, up, r = np.array([0.0, 0.5]), np.zeros(1), np.array([5.0, 0.0])
    a, b = hard.solve(x0, up, r), soft.solve(x0, up, r)
    np.testing.assert_allclose(a.U, b.U, atol=1e-6)
    assert b.slack_max < 1e-7


# ---------------------------------------------------------------------------
# weights / model updates, API paths
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("form", ["condensed", "sparse"])
def test_set_weights_matches_fresh_controller(form):
    case = random_instance(0)
    inst, data = case["inst"], case["data"]
    mpc = make_mpc(inst, osqp_settings=TIGHT, form=form)
    before = solve(mpc, data)
    p, m = inst["C"].shape[0], inst["B"].shape[1]
    new = dict(
        Q=2.5 * np.eye(p),
        R=np.diag(np.linspace(0.2, 0.4, m)),
        S=0.3 * np.eye(m),
        P=np.eye(inst["A"].shape[0]),
        soft_penalty=20.0,
    )
    mpc.set_weights(**new)
    after = solve(mpc, data)
    fresh = solve(make_mpc(dict(inst, **new), osqp_settings=TIGHT, form=form), data)
    np.testing.assert_allclose(after.U, fresh.U, atol=1e-6)
    assert after.cost == pytest.approx(fresh.cost, rel=1e-7)
    assert np.max(np.abs(after.U - before.U)) > 1e-3  # the change mattered


@pytest.mark.parametrize("form", ["condensed", "sparse"])
def test_set_model_matches_fresh_controller_and_keeps_pattern(form):
    case = random_instance(3)
    inst, data = case["inst"], case["data"]
    B0 = inst["B"].copy()
    B0[0, :] = 0.0  # zeros in the first model must not shrink the sparsity pattern
    A0 = inst["A"].copy()
    A0[0, 1] = 0.0
    mpc = make_mpc(dict(inst, A=A0, B=B0), osqp_settings=TIGHT, form=form)
    solve(mpc, data)
    A1 = inst["A"] * 0.95
    B1 = inst["B"] + 0.1
    mpc.set_model(A1, B1)
    after = solve(mpc, data)
    fresh = solve(make_mpc(dict(inst, A=A1, B=B1), osqp_settings=TIGHT, form=form), data)
    np.testing.assert_allclose(after.U, fresh.U, atol=1e-6)


@pytest.mark.parametrize("form", ["condensed", "sparse"])
def test_public_osqp_api_path_gives_the_same_solution(form):
    case = random_instance(8)
    inst, data = case["inst"], case["data"]
    fast = solve(make_mpc(inst, osqp_settings=TIGHT, form=form), data)
    slow = solve(make_mpc(inst, osqp_settings=TIGHT, fast_osqp=False, form=form), data)
    np.testing.assert_allclose(fast.U, slow.U, atol=1e-8)
    assert fast.status == slow.status


def test_result_fields_and_timing():
    mpc = di_mpc()
    sol = mpc.solve(np.array([0.5, 0.0]), np.zeros(1), np.zeros(2))
    assert sol.U.shape == (15, 1) and sol.X.shape == (15, 2) and sol.Y.shape == (15, 2)
    assert sol.u0.shape == (1,) and sol.du0.shape == (1,)
    assert sol.iterations > 0 and sol.solve_time_s > 0 and sol.overhead_s > 0
    assert sol.ok and sol.status_val == 1
    assert np.isfinite(sol.cost)


# ---------------------------------------------------------------------------
# input validation
# ---------------------------------------------------------------------------
def _base_kwargs() -> dict:
    A, B = double_integrator()
    return dict(A=A, B=B, Np=5, Q=np.eye(2), R=1.0, u_min=-1.0, u_max=1.0)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"B": np.ones((3, 1))}, r"B must have shape \(2, m\)"),
        ({"A": np.ones((2, 3))}, "A must be square"),
        ({"A": np.array([[1.0, np.nan], [0.0, 1.0]])}, "A must contain only finite"),
        ({"C": np.ones((1, 3))}, r"C must have shape \(p, 2\)"),
        ({"R": -1.0}, "R must be positive semidefinite"),
        ({"Q": np.array([[1.0, 2.0], [0.0, 1.0]])}, "Q must be symmetric"),
        ({"Q": np.eye(3)}, r"Q must have shape \(2, 2\)"),
        ({"u_min": 5.0, "u_max": 1.0}, r"u_min\[0\] \(5.0\) > u_max\[0\] \(1.0\)"),
        ({"du_min": 0.5, "du_max": 0.1}, r"du_min\[0\] \(0.5\) > du_max\[0\] \(0.1\)"),
        ({"u_min": np.nan}, "u_min must contain only non-NaN"),
        ({"y_min": [0.0, 2.0], "y_max": [1.0, 1.0]}, r"y_min\[1\] \(2.0\) > y_max\[1\]"),
        ({"Np": 0}, "Np must be an integer >= 1"),
        ({"Nc": 7}, "Nc must be an integer with 1 <= Nc <= Np"),
        ({"H_y": np.ones((1, 2))}, "H_y and h_y must be given together"),
        ({"H_x": np.ones((1, 3)), "h_x": [1.0]}, r"H_x must have shape \(r, 2\)"),
        ({"soft_penalty": -1.0, "y_max": [1.0, 1.0]}, "must be > 0"),
        ({"soft_penalty": {"z": 1.0}}, "soft_penalty keys"),
        ({"soft_quadratic": -1.0}, "soft_quadratic must be finite and >= 0"),
        ({"terminal": "both"}, "terminal must be"),
        ({"form": "dense"}, "form must be"),
        ({"osqp_settings": {"no_such_setting": 1}}, "osqp_settings"),
    ],
)
def test_bad_inputs_raise_value_error_naming_the_field(change, message):
    kw = _base_kwargs()
    kw.update(change)
    A, B = kw.pop("A"), kw.pop("B")
    C = kw.pop("C", None)
    with pytest.raises(ValueError, match=message):
        LinearMPC(A, B, C, **kw)


def test_bad_solve_and_update_arguments():
    kw = _base_kwargs()
    mpc = LinearMPC(kw.pop("A"), kw.pop("B"), **kw)
    with pytest.raises(ValueError, match="x0 must have shape"):
        mpc.solve(np.zeros(3), np.zeros(1), np.zeros(2))
    with pytest.raises(ValueError, match="y_ref must have shape"):
        mpc.solve(np.zeros(2), np.zeros(1), np.zeros((4, 2)))
    with pytest.raises(ValueError, match="d must have shape"):
        mpc.solve(np.zeros(2), np.zeros(1), np.zeros(2), d=np.zeros(5))
    with pytest.raises(ValueError, match="set_model must keep the dimensions"):
        mpc.set_model(np.eye(3), np.ones((3, 1)))
    with pytest.raises(ValueError, match="S was not given at construction"):
        mpc.set_weights(S=1.0)
    with pytest.raises(ValueError, match="R must be positive semidefinite"):
        mpc.set_weights(R=-2.0)


def test_block_structure_of_prediction_is_causal():
    """Independent check of the condensed sensitivities by finite differences."""
    A, B = double_integrator()
    mpc = LinearMPC(A, B, Np=6, Nc=3, Q=np.eye(2), R=0.1, u_min=-10, u_max=10)
    # dX/dz from the module against an explicit rollout
    Sx = mpc._Sx
    for j in range(3):
        dz = np.zeros(3)
        dz[j] = 1.0
        U = np.cumsum(dz)
        x = np.zeros(2)
        for t in range(6):
            x = A @ x + B @ U[min(t, 2)][None]
            np.testing.assert_allclose(Sx[2 * t : 2 * t + 2, j], x, atol=1e-12)
    assert sla.norm(Sx[:2, 1:]) == 0.0  # x_1 does not depend on later moves


def test_auto_form_selection():
    A, B = double_integrator()
    small = LinearMPC(A, B, Np=10, Q=np.eye(2), R=1.0, u_min=-1, u_max=1)
    assert small.form == "condensed"
    big = LinearMPC(np.eye(12), np.ones((12, 2)), Np=20, Q=np.eye(12), R=1.0, u_min=-1, u_max=1)
    assert big.form == "sparse"


@pytest.mark.parametrize("form", ["condensed", "sparse"])
def test_per_stage_polyhedral_bounds_are_enforced(form):
    """A speed limit that drops ahead (time-varying h_x) is respected at every stage."""
    A, B = double_integrator()
    Np = 12
    h_stage = np.where(np.arange(Np) < 6, 1.0, 0.4)[:, None]
    mpc = LinearMPC(
        A,
        B,
        Np=Np,
        Q=np.diag([1.0, 0.0]),
        R=0.1,
        u_min=-2.0,
        u_max=2.0,
        H_x=[[0.0, 1.0]],
        h_x=[1.0],
        soft_penalty={"H_x": np.inf},
        osqp_settings=TIGHT,
        form=form,
    )
    sol = mpc.solve(np.array([0.0, 0.9]), np.zeros(1), np.array([10.0, 0.0]), h_x=h_stage)
    assert not sol.fallback
    assert np.all(sol.X[:, 1] <= h_stage[:, 0] + 1e-7)
    assert sol.X[5, 1] > 0.5  # the early stages use the higher limit
    # the override lasts for one call only
    sol2 = mpc.solve(np.array([0.0, 0.9]), np.zeros(1), np.array([10.0, 0.0]))
    assert np.all(sol2.X[:, 1] <= 1.0 + 1e-7) and sol2.X[-1, 1] > 0.5


@pytest.mark.parametrize("form", ["condensed", "sparse"])
def test_rescue_recovers_an_exact_solution(form):
    """A tight iteration budget is repaired by the polish/active-set cascade."""
    case = random_instance(2)
    inst, data = case["inst"], case["data"]
    ref = reference_solve(inst, data)
    plain = solve(make_mpc(inst, osqp_settings={"max_iter": 100}, rescue=False, form=form), data)
    assert plain.fallback  # the budget is too small for the tolerance ...
    sol = solve(make_mpc(inst, osqp_settings={"max_iter": 100}, form=form), data)
    assert not sol.fallback and sol.status == "solved (polished)"  # ... but not for the rescue
    np.testing.assert_allclose(sol.U, ref["U"], atol=1e-8)
    assert sol.cost == pytest.approx(ref["cost"], rel=1e-9)


def test_per_call_bounds_of_only_the_constrained_rows():
    """(Np, k) per-call bounds for the k rows constrained at construction equal the
    full-width form with infinities in the others; NaN there still falls back."""
    A = np.array([[1.0, 0.1], [0.0, 1.0]])
    B = np.array([[0.005], [0.1]])
    C = np.eye(2)
    kw = dict(
        Np=8,
        Q=np.diag([1.0, 0.1]),
        R=np.array([[0.01]]),
        u_min=[-2.0],
        u_max=[2.0],
        y_min=[-np.inf, -1.0],
        y_max=[np.inf, 0.4],
        soft_penalty=50.0,
    )
    x0, up, ref = np.array([0.0, 0.3]), np.array([0.0]), np.tile([2.0, 0.0], (8, 1))
    hi = np.linspace(0.2, 0.5, 8)
    full = LinearMPC(A, B, C, **kw).solve(
        x0, up, ref, y_max=np.column_stack([np.full(8, np.inf), hi])
    )
    narrow = LinearMPC(A, B, C, **kw).solve(x0, up, ref, y_max=hi[:, None])
    np.testing.assert_array_equal(full.U, narrow.U)
    assert full.Y[:, 1].max() <= 0.5 + 1e-6
    bad = hi[:, None].copy()
    bad[3, 0] = np.nan
    assert LinearMPC(A, B, C, **kw).solve(x0, up, ref, y_max=bad).fallback


def test_old_import_paths_reexport_the_engine():
    """``train_envs.controllers.mpc_core`` and ``train_mpc`` keep the engine's names."""
    import train_envs.controllers.mpc_core as old
    import train_envs.controllers.train_mpc as tm
    import train_envs.mpc as engine

    for name in old.__all__:
        assert getattr(old, name) is getattr(engine, name)
    for name in ("zoh", "augmented_terminal_cost", "dare_doubling"):
        assert getattr(tm, name) is getattr(engine, name)
    from train_envs.controllers.mpc_core import _BIG, _Backend, _matrix, _weight  # noqa: F401
