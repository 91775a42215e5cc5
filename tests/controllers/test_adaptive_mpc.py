"""Paper 002's adaptive MPC: estimator, excitation bound, closed loop against mpc002."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

import train_envs  # noqa: F401  (registers the env ids)
from train_envs.controllers import CONTROLLERS, make_controller
from train_envs.controllers.adaptive_mpc import (
    AdaptiveMPCConfig,
    GradientEstimator,
    excitation_box,
    feasible_target,
)
from train_envs.controllers.models import (
    coupled_cars_continuous,
    coupled_cars_relative_continuous,
    coupler_pattern,
    dead_time_maps,
    difference_matrix,
    discretise,
    point_lag_continuous,
)
from train_envs.reproduce import list_reproductions
from train_envs.reproduce.paper002 import compare_paper002, run_paper002, summarise_run
from train_envs.scenarios import DisturbanceSpec, get_scenario

SEEDS = (0, 1)
T_SHORT = 200.0  # 0 -> 40 m/s ramp and 100 s of cruise, Davis variation on


@pytest.fixture(scope="module")
def short_runs():
    return {
        (c, s): run_paper002(c, s, t_max_s=T_SHORT)
        for c in ("adaptive_mpc", "mpc002")
        for s in SEEDS
    }


# ----------------------------------------------------------------------------- estimator
def _random_system(rng, nx=4, nu=2):
    A = rng.normal(size=(nx, nx))
    A *= 0.8 / max(abs(np.linalg.eigvals(A)))
    B = rng.normal(size=(nx, nu))
    b = rng.normal(size=nx)
    return A, B, b


def test_estimator_converges_noiseless_persistent_excitation():
    rng = np.random.default_rng(0)
    nx, nu = 4, 2
    A, B, b = _random_system(rng, nx, nu)
    cb = 1.0
    theta = np.hstack([A, B, b[:, None] / cb])
    est = GradientEstimator(np.zeros_like(theta), lam=0.05, alpha=0.5)
    x = np.zeros(nx)
    errs = []
    for _ in range(3000):
        u = rng.normal(size=nu)  # white input: persistently exciting
        X = np.r_[x, u, cb]
        x_next = theta @ X
        est.update(X, x_next)
        errs.append(np.linalg.norm(est.theta - theta))
        x = x_next
    errs = np.array(errs)
    assert errs[-1] < 1e-6 * errs[0]
    # the parameter error decreases: block maxima fall monotonically
    blocks = errs[:2900].reshape(29, 100).max(axis=1)
    assert np.all(np.diff(blocks) < 0)


def test_update_never_increases_error_when_bound_holds():
    rng = np.random.default_rng(1)
    theta = rng.normal(size=(3, 5))
    lam, alpha = 0.1, 0.5
    est = GradientEstimator(np.zeros_like(theta), lam=lam, alpha=alpha)
    prev = np.linalg.norm(est.theta - theta)
    for _ in range(500):
        X = rng.normal(size=5)
        X *= math.sqrt(rng.uniform(0.0, (2 - alpha) / lam)) / np.linalg.norm(X)
        assert lam * X @ X < 2.0
        est.update(X, theta @ X)
        err = np.linalg.norm(est.theta - theta)
        assert err <= prev + 1e-12
        assert not est.last_clipped
        prev = err
    # a regressor beyond the bound: the raw law would increase the error ...
    X = rng.normal(size=5)
    X *= math.sqrt(3.0 / lam) / np.linalg.norm(X)  # λ||X||² = 3 > 2
    tt = est.theta + (theta - est.theta) * 0 + 0.3  # a parameter error along all directions
    raw = tt + lam * np.outer(theta @ X - tt @ X, X)
    e_tilde = theta - tt
    grows = np.linalg.norm(theta - raw) > np.linalg.norm(e_tilde)
    assert grows
    # ... the safeguarded update shrinks the step to λ_eff ||X||² = 2 − α and does not
    est.theta = tt.copy()
    est.update(X, theta @ X)
    assert est.last_clipped
    assert est.last_lam_eff * (X @ X) == pytest.approx(2.0 - alpha)
    assert np.linalg.norm(theta - est.theta) <= np.linalg.norm(e_tilde) + 1e-12
    # λ = 0 freezes the estimate
    frozen = GradientEstimator(np.ones((2, 3)), lam=0.0)
    frozen.update(np.ones(3), np.zeros(2))
    np.testing.assert_array_equal(frozen.theta, np.ones((2, 3)))
    assert frozen.regressor_bound == math.inf


def test_excitation_box_eq_26_28():
    e = np.array([1.0, 2.0])
    uc = np.array([0.0, 5.0, -3.0])
    lo_w, hi_w = np.full(3, -30.0), np.full(3, 30.0)
    lo, hi, half, ok = excitation_box(
        e, uc, lam=0.01, alpha=0.5, bias_regressor=5.0, u_lo=lo_w, u_hi=hi_w
    )
    expect = math.sqrt((1.5 / 0.01 - 5.0 - 25.0) / 3)  # sqrt(((2-α)/λ − ||e||² − c_b²)/m)
    assert half == pytest.approx(expect)
    np.testing.assert_allclose(lo, uc - expect)
    np.testing.assert_allclose(hi, uc + expect)
    assert ok
    # every u in the box keeps λ||X||² < 2 − α (ball ⊃ inscribed box)
    X = np.r_[e, hi - uc, 5.0]
    assert 0.01 * (X @ X) <= 1.5 + 1e-12
    # intersection with the window; an empty intersection pins the nearest bound
    lo, hi, _, ok = excitation_box(
        e,
        np.array([40.0, 0.0, -50.0]),
        lam=0.01,
        alpha=0.5,
        bias_regressor=5.0,
        u_lo=lo_w,
        u_hi=hi_w,
    )
    assert not ok
    assert lo[0] == hi[0] == 30.0 and lo[2] == hi[2] == -30.0
    assert lo[1] == pytest.approx(-expect) and hi[1] == pytest.approx(expect)
    # λ = 0: no bound
    lo, hi, half, ok = excitation_box(
        e, uc, lam=0.0, alpha=0.5, bias_regressor=5.0, u_lo=lo_w, u_hi=hi_w
    )
    assert half == math.inf and ok
    np.testing.assert_array_equal(lo, lo_w)


def test_feasible_target_keeps_total_force():
    lo, hi = np.full(4, -30.0), np.full(4, 30.0)
    u = np.array([[35.0, 20.0, 20.0, 20.0], [41.0, 29.0, 29.0, 29.0], [1.0, 2.0, 3.0, 4.0]])
    t = feasible_target(u, lo, hi)
    assert np.all(t <= hi) and np.all(t >= lo)
    assert t[0].sum() == pytest.approx(u[0].sum())  # feasible total: kept
    np.testing.assert_allclose(t[1], 30.0)  # infeasible total: all at the bound
    np.testing.assert_array_equal(t[2], u[2])  # inside: unchanged


# ------------------------------------------------------------------------- closed loop
def test_lambda_zero_equals_nonadaptive():
    for dist in (DisturbanceSpec(), DisturbanceSpec(davis_variation=True)):
        sc = get_scenario("paper002_cruise").with_overrides(t_max_s=20.0, disturbance=dist)
        a = run_paper002("adaptive_mpc", 3, scenario=sc, params={"lam": 0.0})
        b = run_paper002("mpc002", 3, scenario=sc)
        cols = [f"u{i}_kN" for i in range(1, 5)] + ["ev_max_mps", "coupler_force_kN"]
        np.testing.assert_allclose(a[cols].to_numpy(), b[cols].to_numpy(), rtol=1e-12, atol=1e-12)
        assert a["dR_hat_total_kN"].abs().max() == 0.0


def test_adaptive_beats_nonadaptive_same_seeds(short_runs):
    for s in SEEDS:
        ad = summarise_run(short_runs[("adaptive_mpc", s)])
        na = summarise_run(short_runs[("mpc002", s)])
        assert ad["max_ev_mps"] < na["max_ev_mps"]
        assert ad["max_coupler_force_kN"] < na["max_coupler_force_kN"]
        assert ad["rms_ev_mps"] < 0.5 * na["rms_ev_mps"]
        # bounded estimation: the learned resistance deviation stays close to the plant's
        assert ad["max_dR_error_kN"] < 0.5
        assert ad["max_dR_error_kN"] < 0.25 * na["max_dR_error_kN"]
        assert ad["max_est_error"] < na["max_est_error"]
        df = short_runs[("adaptive_mpc", s)]
        assert np.all(np.isfinite(df["est_error"].iloc[1:]))
        assert ad["fallback_steps"] == 0
        # the excitation box is unreachable only where the rate limit cannot follow the
        # feedforward's jump when the reference acceleration changes (t = 0 and 100 s)
        clipped = df["t_s"][df["bound_clipped"] > 0].to_numpy()
        near = np.min(np.abs(clipped[:, None] - np.array([0.0, 100.0])[None, :]), axis=1)
        assert len(clipped) <= 4 and np.all(near <= 2.0)


def test_force_rate_and_coupler_constraints_hold(short_runs):
    du = 20.0 * 0.5  # default rate 20 kN/s at T = 0.5 s
    for (c, s), df in short_runs.items():
        u = df[[f"u{i}_kN" for i in range(1, 5)]].to_numpy()
        assert np.abs(u).max() <= 30.0 + 1e-9, (c, s)
        assert np.abs(np.diff(u, axis=0)).max() <= du + 1e-6, (c, s)
        assert df["coupler_def_m"].abs().max() <= 0.02, (c, s)
        assert df["fallback"].sum() == 0, (c, s)


def test_excitation_box_holds_on_first_move(short_runs):
    df = short_runs[("adaptive_mpc", SEEDS[0])]
    half = df["excitation_half_width_kN"].to_numpy()
    assert np.all(np.isfinite(half)) and half.min() > 1.0
    assert np.all(np.isinf(short_runs[("mpc002", SEEDS[0])]["excitation_half_width_kN"]))


def test_model_refresh_pushes_estimated_matrices():
    sc = get_scenario("paper002_cruise").with_overrides(t_max_s=6.0)
    base = run_paper002("adaptive_mpc", 0, scenario=sc)
    ctrl = make_controller("adaptive_mpc", sc, model_refresh_tol=0.0)
    from train_envs.simulation import ClosedLoop

    loop = ClosedLoop(sc, ctrl)
    loop.reset(seed=0)
    refreshed = [bool(loop.step()["model_refreshed"]) for _ in range(12)]
    assert sum(refreshed) >= 10  # every step once the estimate moves
    # the pushed corrections are tiny: the commands barely change
    u = np.array([loop.dataframe()[f"u{i}_cmd_N"].to_numpy()[:12] for i in range(1, 5)]).T
    u0 = base[[f"u{i}_kN" for i in range(1, 5)]].to_numpy()[:12] * 1e3
    np.testing.assert_allclose(u, u0, atol=50.0)


# ------------------------------------------------------------------- API and plumbing
def test_info_and_registration():
    assert {"adaptive_mpc", "mpc002"} <= set(CONTROLLERS)
    sc = get_scenario("paper002_cruise")
    ctrl = make_controller("adaptive_mpc", sc)
    assert {p.name for p in ctrl.tunable_params()} == {"lam", "r_u", "q_v", "q_xi"}
    assert "lam" not in {p.name for p in make_controller("mpc002", sc).tunable_params()}
    from train_envs.simulation import ClosedLoop

    loop = ClosedLoop(sc, ctrl)
    loop.reset(seed=0)
    loop.step()
    info = loop.step()
    for key in ("est_error", "dR_hat_kN", "theta_norm", "excitation_half_width_kN", "solve_time_s"):
        assert key in info
    assert np.asarray(info["dR_hat_kN"]).shape == (4,)
    assert "TrainEnvs/Cruise002-v0" in gym.registry
    assert "paper002" in list_reproductions()


def test_compare_and_figure():
    table = compare_paper002(seeds=(0,), t_max_s=15.0, workers=1)
    assert set(table["controller"]) == {"adaptive_mpc", "mpc002"}
    assert {"max_ev_mps", "max_coupler_force_kN", "max_est_error", "paper_max_ev_mps"} <= set(
        table.columns
    )
    from train_envs.plots_papers import paper002_figure

    runs = {c: run_paper002(c, 0, t_max_s=10.0) for c in ("adaptive_mpc", "mpc002")}
    fig = paper002_figure(runs)
    assert len(fig.axes) == 4
    with pytest.raises(ValueError, match="at least one"):
        paper002_figure({})


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"Np": 0}, "Np"),
        ({"Np": 5, "Nc": 6}, "Nc"),
        ({"alpha": 2.0}, "alpha"),
        ({"bias_regressor": -1.0}, "bias_regressor"),
        ({"du_max_kN_per_s": 0.0}, "du_max_kN_per_s"),
        ({"model_refresh_tol": 2.0}, "model_refresh_tol"),
        ({"soft_penalty": math.nan}, "soft_penalty"),
    ],
)
def test_bad_config_raises(kwargs, match):
    with pytest.raises(ValueError, match=match):
        AdaptiveMPCConfig(**kwargs)
    with pytest.raises(ValueError, match=match):
        make_controller("adaptive_mpc", None, **kwargs)


def test_bad_params_raise():
    with pytest.raises(ValueError, match="lam"):
        make_controller("adaptive_mpc", None, lam=-0.01)
    with pytest.raises(ValueError, match=r"lam must lie in \[0, 0.0416667\)"):
        make_controller("adaptive_mpc", None, lam=0.05, bias_regressor=6.0)
    with pytest.raises(ValueError, match="r_u"):
        make_controller("adaptive_mpc", None, r_u=0.0)
    with pytest.raises(ValueError, match="no tunable parameter 'lam'"):
        make_controller("mpc002", None, lam=0.01)
    with pytest.raises(ValueError, match="lam"):
        GradientEstimator(np.zeros((2, 2)), lam=math.inf)
    with pytest.raises(ValueError, match="alpha"):
        GradientEstimator(np.zeros((2, 2)), lam=0.1, alpha=0.0)
    # a single-input scenario cannot run a per-car MPC
    sc = get_scenario("paper001_stopping")
    with pytest.raises(ValueError, match="needs a multi-car train"):
        make_controller("adaptive_mpc", sc)
    ctrl = make_controller("adaptive_mpc")
    with pytest.raises(ValueError, match="per-car inputs"):
        ctrl.reset(sc.control_context())


# ---------------------------------------------------------------------------------------
# shared linear prediction models (train_envs.controllers.models)
# ---------------------------------------------------------------------------------------
def test_coupled_models_agree_in_both_coordinates():
    """[ξ (mm), v] = T [q, v]: the relative model is the position model seen through T."""
    rng = np.random.default_rng(3)
    n = 4
    mi = rng.uniform(3e4, 6e4, n)
    slope = rng.uniform(10.0, 500.0, n)
    k, d = 8e5, 2e4
    Ap, Bp, Ep = coupled_cars_continuous(k, d, mi, slope)
    Ar, Br, Er = coupled_cars_relative_continuous(k, d, mi, slope)
    T = np.zeros((2 * n - 1, 2 * n))
    T[: n - 1, :n] = 1000.0 * difference_matrix(n)
    T[n - 1 :, n:] = np.eye(n)
    np.testing.assert_allclose(Ar @ T, T @ Ap, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(Br, T @ Bp, rtol=1e-12)
    np.testing.assert_allclose(Er, T @ Ep, rtol=1e-12)
    D = difference_matrix(n)
    np.testing.assert_array_equal(coupler_pattern(n), -D.T @ D)


def test_point_lag_dead_time_maps_match_stepping():
    """x(k+l) from the dead-time maps equals l steps of the discrete model."""
    kv, tau, dt, l = 2e-3, 0.7, 0.2, 3  # noqa: E741
    Ad, Bd, Ed = discretise(*point_lag_continuous(kv, tau), dt)
    Al, Gu, Gw = dead_time_maps(Ad, Bd[:, 0], Ed[:, 0], l)
    x0 = np.array([10.0, 5.0, 0.3])
    u = np.array([0.2, -0.1, 0.4])
    w = np.array([-0.01, 0.02, 0.0])
    x = x0.copy()
    for j in range(l):
        x = Ad @ x + Bd[:, 0] * u[j] + Ed[:, 0] * w[j]
    np.testing.assert_allclose(Al @ x0 + Gu @ u + Gw @ w, x, rtol=1e-12)
    # no lag: two states, the command is the acceleration
    Ad2, Bd2, _ = discretise(*point_lag_continuous(0.0, 0.0), dt)
    np.testing.assert_allclose(Ad2, [[1.0, dt], [0.0, 1.0]])
    np.testing.assert_allclose(Bd2[:, 0], [0.5 * dt * dt, dt])
