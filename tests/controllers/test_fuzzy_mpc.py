"""Paper 003's fuzzy constrained predictive controller and its backstepping compensator."""

from __future__ import annotations

import numpy as np
import pytest

from train_envs.controllers import make_controller
from train_envs.controllers.fuzzy_mpc import (
    BacksteppingCompensator,
    FuzzyMPCController,
    KothareLMI,
    ReducedTrainModel,
    TriangularMemberships,
)
from train_envs.lines.profiles import piecewise_speed_command
from train_envs.mpc import zoh
from train_envs.plants.multi_car import ActuatorParams
from train_envs.reference import Reference
from train_envs.simulation import simulate

KMH = 1 / 3.6


@pytest.fixture(scope="module")
def scenario(paper003):
    return paper003


@pytest.fixture(scope="module")
def ctrl(scenario):
    c = FuzzyMPCController(scenario)
    c.reset(scenario.control_context())
    return c


def _step_scenario(scenario, t_max: float = 150.0):
    """A 150 -> 200 km/h step at 20 s (1 s ramp), as in paper 003's Example 1."""
    prof = piecewise_speed_command(
        [(0.0, 150 * KMH), (20.0, 150 * KMH), (21.0, 200 * KMH), (t_max, 200 * KMH)]
    )
    return scenario.with_overrides(t_max_s=t_max, reference=Reference(prof, mode="time"))


# ----------------------------------------------------------------- memberships
def test_memberships_sum_to_one_and_interpolate():
    for centres in [(-15.0, 15.0), (-10.0, 0.0, 10.0), (-8.0, -2.0, 1.0, 9.0)]:
        mf = TriangularMemberships(centres)
        for e in np.linspace(-30, 30, 241):
            h = mf(e)
            assert h.shape == (len(centres),)
            assert np.all(h >= 0) and h.sum() == pytest.approx(1.0, abs=1e-14)
        # at a centre only that rule fires; beyond the ends the shoulders saturate
        for i, c in enumerate(centres):
            assert mf(c)[i] == pytest.approx(1.0)
        assert mf(-100)[0] == 1.0 and mf(100)[-1] == 1.0
    # the blend of the rule slopes is the exact aero slope c(2 v_r + e) on the sector
    mf = TriangularMemberships((-15.0, 0.0, 15.0))
    c, vr = 5.12, 50.0
    for e in np.linspace(-15, 15, 31):
        blend = sum(h * c * (2 * vr + eps) for h, eps in zip(mf(e), mf.centres, strict=True))
        assert blend == pytest.approx(c * (2 * vr + e), rel=1e-12)


@pytest.mark.parametrize("centres", [(1.0,), (0.0, 0.0), (2.0, 1.0), (0.0, float("nan"))])
def test_bad_memberships_raise(centres):
    with pytest.raises(ValueError, match="centres"):
        TriangularMemberships(centres)


# --------------------------------------------------------------------- model
def test_full_modal_model_matches_the_error_model(scenario):
    """With every mode kept, the modal model has the eigenvalues of 003's error model."""
    tr = scenario.train
    n = scenario.n_cars
    m = np.asarray(tr.car_masses) * (1 + tr.rotating_mass_factor)
    k = tr.coupler.stiffness_N_per_m
    b = np.full(n, tr.davis_b_Ns_per_m / n)
    c = np.zeros(n)
    c[0] = tr.davis_c_Ns2_per_m2
    full = ReducedTrainModel(m, k, 0.0, b, c, 0.5, n_modes=None)
    slopes = b + c * 2 * 50.0
    A_modal, _ = full.continuous(slopes)
    # direct (δ, e) model, 003 eq. 6
    D = full.D
    A = np.zeros((2 * n - 1, 2 * n - 1))
    A[: n - 1, n - 1 :] = D
    A[n - 1 :, : n - 1] = -np.diag(1 / m) @ D.T * k
    A[n - 1 :, n - 1 :] = -np.diag(slopes / m)
    ev1 = np.sort_complex(np.linalg.eigvals(A_modal))
    ev2 = np.sort_complex(np.linalg.eigvals(A))
    np.testing.assert_allclose(ev1, ev2, atol=1e-9)
    # and the measurement map inverts the output maps on the kept modes
    rng = np.random.default_rng(1)
    x = rng.standard_normal(full.nx)
    delta = full.C_d @ x / 100.0
    e = full.C_e @ x
    np.testing.assert_allclose(full.state(delta, e), x, atol=1e-9)


# ----------------------------------------------------------------------- LMI


def _lyapunov_decrease(h, A, B, F, W, R, P, scale):
    """PDC closed loop at memberships ``h``: asserts ``AclᵀPAcl − P + W + FhᵀRFh ⪯ 0``
    (to ``1e-6·scale``) and returns ``(Fh, Acl)``."""
    Ah = sum(hi * Ai for hi, Ai in zip(h, A, strict=True))
    Bh = sum(hi * Bi for hi, Bi in zip(h, B, strict=True))
    Fh = sum(hi * Fi for hi, Fi in zip(h, F, strict=True))
    Acl = Ah + Bh @ Fh
    M = Acl.T @ P @ Acl - P + W + Fh.T @ R @ Fh
    assert np.linalg.eigvalsh(0.5 * (M + M.T)).max() <= 1e-6 * scale
    return Fh, Acl


def test_lmi_solution_satisfies_its_constraints(ctrl):
    model = ctrl._model
    v_r = 50.0
    x = model.state(np.full(7, 0.01), np.full(8, -3.0))
    u_bar = np.full(8, 30.0)
    sol = ctrl.solve_lmi(x, v_r, u_bar)
    assert sol.status in ("optimal", "optimal_inaccurate")
    assert ctrl._lmi.problem.is_dpp()
    P, Q = sol.P, sol.Q
    assert np.linalg.eigvalsh(P).min() > 0 and np.linalg.eigvalsh(Q).min() > 0
    np.testing.assert_allclose(P, sol.gamma * np.linalg.inv(Q), rtol=1e-9)
    # the current state lies in the invariant ellipsoid, the bound covers its cost
    assert x @ sol.Q_inv @ x <= 1 + 1e-6
    assert x @ P @ x <= sol.gamma * (1 + 1e-6)
    A, B = model.rules(v_r, ctrl.memberships.centres)
    W, R = ctrl._W, ctrl._R
    rng = np.random.default_rng(0)
    r = len(A)
    hs = [np.eye(r)[i] for i in range(r)] + [rng.dirichlet(np.ones(r)) for _ in range(20)]
    scale = np.abs(P).max()
    for h in hs:
        # Lyapunov decrease by at least the stage cost, for every membership vector
        Fh, Acl = _lyapunov_decrease(h, A, B, sol.F, W, R, P, scale)
        assert np.abs(np.linalg.eigvals(Acl)).max() < 1.0
        # input constraint at the current state, every car
        u = model.C_u @ (Fh @ x)
        assert np.all(np.abs(u) <= u_bar * (1 + 1e-5))


def test_lmi_problem_is_shared_and_reused(scenario):
    a = FuzzyMPCController(scenario)
    b = FuzzyMPCController(scenario, q_v=2.0)
    ctx = scenario.control_context()
    a.reset(ctx)
    b.reset(ctx)
    assert a._lmi is b._lmi
    assert a._lmi is KothareLMI.shared(a._model.nx, a._model.nu, 8, 2)


def test_resolve_triggers(scenario):
    sc = scenario.with_overrides(t_max_s=30.0)
    every = simulate(sc, FuzzyMPCController(sc, lmi_period=1), seed=0).df
    events = simulate(sc, FuzzyMPCController(sc), seed=0).df
    n = len(every) - 1
    assert every["triggered"].iloc[:n].sum() == n
    assert events["triggered"].iloc[:n].sum() < n / 4
    # unchanged weights do not force a solve, changed ones do
    c = FuzzyMPCController(sc)
    c.reset(sc.control_context())
    c._force_solve = False
    c.set_params(**c.get_params())
    assert not c._force_solve
    c.set_params(q_v=1.0)
    assert c._force_solve


def _run(sc, c, steps, change=None):
    """``steps`` control steps of ``c`` on ``sc``; ``change(k)`` gives parameters set
    before step ``k`` (or None); returns the per-step ``triggered`` flags."""
    from train_envs.simulation import ClosedLoop

    loop = ClosedLoop(sc, c)
    loop.reset(seed=0)
    flags = []
    for k in range(steps):
        params = None if change is None else change(k)
        if params:
            c.set_params(**params)
        u, info = c.compute(loop.observe())
        loop.step(u)
        flags.append(info["triggered"])
    return flags


def test_new_weights_take_effect_at_the_latest_after_the_delay(scenario):
    """A weight change is taken by the next re-solve, at the latest
    ``weights_delay_steps`` steps later; ``0`` solves at the next step."""
    sc = scenario.with_overrides(t_max_s=60.0)
    for delay in (0, 4):
        c = FuzzyMPCController(sc, weights_delay_steps=delay)
        flags = _run(sc, c, 30, lambda k: {"q_v": 2.0} if k == 20 else None)
        assert sum(flags[20 : 20 + delay + 1]) >= 1
        if delay == 0:
            assert flags[20] == 1.0
        assert c._weights_since is None


def test_between_a_weight_change_and_its_solve_the_last_feasible_gains_act(scenario):
    """Until the solve that takes new weights, the cached solution (gains F_j and their
    ellipsoid) is the one of the last feasible solve; that solve uses the new weights."""
    from train_envs.simulation import ClosedLoop

    sc = scenario.with_overrides(t_max_s=60.0)
    delay = 6
    c = FuzzyMPCController(sc, weights_delay_steps=delay)
    loop = ClosedLoop(sc, c)
    loop.reset(seed=0)
    for _ in range(30):  # past the first solves
        loop.step(c.compute(loop.observe())[0])
    sol = c._sol
    c.set_params(q_v=4.0, q_dx=3e-3, r_e=0.05)
    seen = []
    for _ in range(delay + 1):
        before = c._sol
        u, info = c.compute(loop.observe())
        loop.step(u)
        seen.append(info["triggered"])
        if info["triggered"]:
            break
        assert before is sol and c._sol is sol  # the last feasible gains, unchanged
    assert seen[-1] == 1.0 and len(seen) <= delay + 1
    assert c._weights_since is None and c._sol is not sol
    # the taking solve used the new weights: re-solving it with them gives its γ
    W, R = c._model.weights(4.0, 3e-3, 0.05)
    new = c._sol
    A, B = c._model.rules(c._v_solve, c.memberships.centres)
    u_bar = np.sqrt(c._lmi.ubar2.value)
    again = c._lmi.solve(A, B, new.x, W, R, c._model.C_u, u_bar, c.floor)
    assert again.gamma == pytest.approx(new.gamma, rel=1e-9)
    assert not np.isclose(new.gamma, sol.gamma, rtol=1e-3)


def test_weights_changing_every_step_do_not_force_a_solve_every_step(scenario):
    """Weights changed at every step (an RL agent): with ``weights_delay_steps=0`` every
    step solves the LMI; with a delay only the re-solve events do (the state leaving or
    shrinking inside the cached ellipsoid), and at least one per ``delay + 1`` steps."""
    sc = scenario.with_overrides(t_max_s=60.0)
    steps, delay = 60, 20
    specs = FuzzyMPCController.PARAMS[:3]
    counts = {}
    for d in (0, delay):
        rng = np.random.default_rng(0)

        def change(k, rng=rng):
            units = rng.uniform(-1, 1, 3)
            return {p.name: p.from_unit(a) for p, a in zip(specs, units, strict=True)}

        flags = _run(sc, FuzzyMPCController(sc, weights_delay_steps=d), steps, change)
        counts[d] = sum(flags)
        gaps = np.diff(np.flatnonzero(flags))
        assert gaps.max() <= d + 1  # a change made right after a solve waits d steps
    assert counts[0] == steps
    assert counts[delay] <= steps / 2


# ---------------------------------------------------------------- compensator
def _actuator_response(comp: BacksteppingCompensator | None, steps: int = 12) -> float:
    """Integral squared error of F against a unit step of u_d (fine simulation)."""
    w_n, z, T, h = 2.0, 0.8, 0.5, 0.01
    Ac = np.array([[0.0, 1.0], [-(w_n**2), -2 * z * w_n]])
    Bc = np.array([[0.0], [w_n**2]])
    Ph, Gh = zoh(Ac, Bc, h)
    x = np.zeros(2)
    ise = 0.0
    big = np.array([1e9])
    for _ in range(steps):
        F = x[:1]
        if comp is None:
            w = 1.0
        else:
            w_arr, Fd = comp.command(np.array([1.0]), F, -big, big)
            assert Fd[0] == pytest.approx(x[1], abs=1e-9)  # dead-beat rate estimate
            w = float(w_arr[0])
        for _ in range(int(T / h)):
            x = Ph @ x + Gh[:, 0] * w
            ise += (x[0] - 1.0) ** 2 * h
    return ise


def test_compensator_speeds_up_the_actuator_and_estimates_the_rate():
    plain = _actuator_response(None)
    comp = BacksteppingCompensator(2.0, 0.8, 0.5, c1=3.0, c2=3.0)
    assert comp.spectral_radius < 1
    assert _actuator_response(comp) < 0.7 * plain


def test_compensator_rejects_unstable_gains_and_bad_actuator():
    with pytest.raises(ValueError, match="c1=10.0, c2=10.0"):
        BacksteppingCompensator(2.0, 0.8, 0.5, c1=10.0, c2=10.0)
    with pytest.raises(ValueError, match="omega_n_radps"):
        BacksteppingCompensator(0.0, 0.8, 0.5)


# ---------------------------------------------------------------- closed loop
def _sampled_loop_radius(ctrl, F: np.ndarray, comp: BacksteppingCompensator | None) -> float:
    """Spectral radius of the sampled loop: reduced model + 2nd-order actuators + gain F."""
    from scipy.linalg import expm

    model = ctrl._model
    nx, nu = model.nx, model.nu
    Ac, Bc = model.continuous(model.b + model.c * 2 * 50.0)
    wn, ze, T = 2.0, 0.8, 0.5
    n = nx + 2 * nu
    A = np.zeros((n, n))
    B = np.zeros((n, nu))
    A[:nx, :nx] = Ac
    A[:nx, nx : nx + nu] = Bc
    A[nx : nx + nu, nx + nu :] = np.eye(nu)
    A[nx + nu :, nx : nx + nu] = -(wn**2) * np.eye(nu)
    A[nx + nu :, nx + nu :] = -2 * ze * wn * np.eye(nu)
    B[nx + nu :, :] = wn**2 * np.eye(nu)
    M = np.zeros((n + nu, n + nu))
    M[:n, :n] = A * T
    M[:n, n:] = B * T
    E = expm(M)
    K = np.zeros((nu, n))
    if comp is None:
        K[:, :nx] = F
    else:
        kF, kFd, ku = comp._k
        K[:, :nx] = ku * F
        K[:, nx : nx + nu] = kF * np.eye(nu)
        K[:, nx + nu :] = kFd * np.eye(nu)
    return float(np.abs(np.linalg.eigvals(E[:n, :n] + E[:n, n:] @ K)).max())


def test_actuator_degrades_and_compensator_restores_the_sampled_loop(ctrl):
    """003 §3.2: the actuator lag pushes the loop towards instability, Theorem 5 fixes it."""
    x = np.zeros(ctrl._model.nx)
    x[0] = 0.5
    sol = ctrl.solve_lmi(x, 50.0, np.full(8, 30.0))
    F = sol.F[0]
    comp = BacksteppingCompensator(2.0, 0.8, 0.5, c1=3.0, c2=3.0)
    r_act = _sampled_loop_radius(ctrl, F, None)
    r_comp = _sampled_loop_radius(ctrl, F, comp)
    assert r_comp < 0.98 and r_comp < r_act - 0.015


def test_tracks_the_ramp_with_compensator_within_the_coupler_bound(scenario):
    sc = scenario.with_overrides(t_max_s=260.0)
    res = simulate(sc, make_controller("fuzzy_mpc", sc), seed=0)
    df, m = res.df, res.metrics
    assert df["v_ref_mps"].iloc[-2] == pytest.approx(200 * KMH)
    assert abs(df["v_mps"].iloc[-2] - df["v_ref_mps"].iloc[-2]) < 0.1
    assert m["max_speed_error_mps"] < 0.5
    assert m["max_coupler_deformation_m"] <= sc.extra["coupler_def_max_m"]


def test_compensator_brings_the_actuator_case_close_to_no_actuator(scenario):
    sc = _step_scenario(scenario)
    kw = {"feedforward": "resistance"}
    ideal = simulate(
        sc.with_overrides(actuator=ActuatorParams(order=0)), FuzzyMPCController(sc, **kw)
    ).df
    act = simulate(sc, FuzzyMPCController(sc, compensator=False, **kw)).df
    comp = simulate(sc, FuzzyMPCController(sc, compensator=True, **kw)).df

    def dist(df, col):
        return float(np.sqrt(np.nanmean((df[col] - ideal[col]) ** 2)))

    assert dist(comp, "v_mps") < dist(act, "v_mps")
    assert dist(comp, "u_N") < dist(act, "u_N")
    # the step is tracked and the couplers stay inside 003's 0.07 m
    assert abs(comp["v_mps"].iloc[-2] - 200 * KMH) < 0.3
    assert comp["coupler_def_max_m"].abs().max() <= 0.07


def test_no_compensator_without_second_order_actuator(scenario):
    sc = scenario.with_overrides(actuator=ActuatorParams(order=0))
    c = FuzzyMPCController(sc)
    c.reset(sc.control_context())
    assert c._comp is None
    c2 = FuzzyMPCController(scenario)
    c2.reset(scenario.control_context())
    assert c2._comp is not None and c2._comp.omega_n_radps == 2.0


# -------------------------------------------------------------------- inputs
@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"q_v": -1.0}, "q_v"),
        ({"r_e": 0.0}, "r_e"),
        ({"c1": 5.0}, "c1"),
        ({"lmi_period": -1}, "lmi_period"),
        ({"weights_delay_steps": -1}, "weights_delay_steps"),
        ({"feedforward": "bogus"}, "feedforward"),
        ({"resolve_shrink": 2.0}, "resolve_shrink"),
        ({"floor": 0.0}, "floor"),
        ({"n_modes": -1}, "n_modes"),
        ({"u_bound_N": -5.0}, "u_bound_N"),
        ({"centres_mps": (3.0, 1.0)}, "centres"),
    ],
)
def test_bad_params_raise(kwargs, field):
    with pytest.raises(ValueError, match=field):
        FuzzyMPCController(**kwargs)


def test_bad_context_raises(scenario):
    with pytest.raises(ValueError, match="n_modes"):
        FuzzyMPCController(scenario, n_modes=8).reset(scenario.control_context())
    single = scenario.with_overrides(input_mode="total")
    with pytest.raises(ValueError, match="per-car inputs"):
        FuzzyMPCController(single).reset(single.control_context())
    c = FuzzyMPCController(scenario)
    with pytest.raises(ValueError, match="q_dx"):
        c.set_params(q_dx=1e9)


def test_a_state_outside_the_ellipsoid_keeps_the_gains_only_on_a_certified_enlargement(ctrl):
    """The scaled solution (L·Q, L·Y_j, L·γ) satisfies the LMIs with the same gains; it
    is kept only if the input bound holds on the enlarged ellipsoid."""
    model = ctrl._model
    v_r = 50.0
    x = model.state(np.full(7, 0.01), np.full(8, -3.0))
    u_bar = np.full(8, 30.0)
    sol = ctrl.solve_lmi(x, v_r, u_bar)
    ctrl._sol, ctrl._force_solve, ctrl._fallback = sol, False, False
    ctrl._v_solve, ctrl._weights_since, ctrl._k, ctrl._k_solve = v_r, None, 0, 0
    peak = max(
        np.max(np.einsum("ij,jk,ik->i", model.C_u @ Y, sol.Q_inv, model.C_u @ Y)) for Y in sol.Y
    )
    lim = u_bar**2
    room = float(np.min(lim) / peak)  # largest admissible level
    assert room > 1.0
    L = 0.5 * (1.0 + room)
    xo = x * np.sqrt(L / float(x @ sol.Q_inv @ x))
    # too far out: a re-solve is due and the cached solution stays as it was
    assert ctrl._needs_solve(xo * np.sqrt(1.1 * room / L), v_r, lambda: u_bar)
    assert ctrl._sol is sol
    # within the certified enlargement: no re-solve, same gains, scaled certificate
    assert not ctrl._needs_solve(xo, v_r, lambda: u_bar)
    new = ctrl._sol
    assert all(np.array_equal(a, b) for a, b in zip(new.F, sol.F, strict=True))
    np.testing.assert_allclose(new.Q, L * sol.Q, rtol=1e-12)
    np.testing.assert_allclose(new.gamma, L * sol.gamma, rtol=1e-12)
    assert xo @ new.Q_inv @ xo <= 1 + 1e-9
    A, B = model.rules(v_r, ctrl.memberships.centres)
    W, R, P = ctrl._W, ctrl._R, new.gamma * np.linalg.inv(new.Q)
    scale = np.abs(P).max()
    rng = np.random.default_rng(1)
    r = len(A)
    for h in [np.eye(r)[i] for i in range(r)] + [rng.dirichlet(np.ones(r)) for _ in range(10)]:
        Fh, _ = _lyapunov_decrease(h, A, B, new.F, W, R, P, scale)
        # the largest force deviation on the enlarged ellipsoid is within u_bar
        CF = model.C_u @ Fh
        assert np.all(np.einsum("ij,jk,ik->i", CF, new.Q, CF) <= lim * (1 + 1e-9))
