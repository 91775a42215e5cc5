"""A tube MPC's weight change reuses its weight-independent pieces and changes nothing.

The terminal weight comes from a Lyapunov system factorised once per loop
(:class:`LyapunovSolver`), the closed form's θ gather is kept per problem and the
weight checks and square roots are remembered per value; these tests check each
against the computation it replaces, bit for bit (the closed forms after random
actions: ``tests/mpc/test_weight_change.py``).
"""

from __future__ import annotations

import numpy as np
import pytest

import train_envs  # noqa: F401
from train_envs.controllers.tube.model import stopping_model, terminal_weight, tube_feedback
from train_envs.mpc.assembly import _checked_weight, _psd_sqrt
from train_envs.mpc.description import _weight
from train_envs.mpc.design import LyapunovSolver, terminal_cost_lyapunov


def _stable(n: int, rng: np.random.Generator) -> np.ndarray:
    A = rng.normal(size=(n, n))
    return 0.9 * A / max(abs(np.linalg.eigvals(A)))


@pytest.mark.parametrize("n", [3, 4, 11])
def test_lyapunov_solver_equals_scipy_direct_bit_for_bit(n):
    rng = np.random.default_rng(n)
    Acl = _stable(n, rng)
    solver = LyapunovSolver(Acl)
    for _ in range(20):
        L = rng.normal(size=(n, n)) * 10.0 ** rng.uniform(-6, 6)
        Q = L.T @ L
        np.testing.assert_array_equal(solver.solve(Q), terminal_cost_lyapunov(Acl, Q))
    P = solver.solve(np.eye(n))
    assert np.allclose(Acl.T @ P @ Acl - P + np.eye(n), 0.0, atol=1e-9)


def test_lyapunov_solver_rejects_an_unstable_loop():
    with pytest.raises(ValueError, match="Schur stable"):
        LyapunovSolver(np.diag([0.5, 1.0]))


def test_tube_terminal_weight_equals_the_lyapunov_solution_bit_for_bit():
    model = stopping_model(0.2, 0.4, 2)
    fb = tube_feedback(model, 10.0, 30.0, 10.0)
    rng = np.random.default_rng(0)
    for _ in range(20):
        q_s, q_v, r = 10.0 ** rng.uniform(-3, 4, 3)
        Qx = np.diag([q_s, q_v, 0.0, 0.0])
        K = fb.K.reshape(1, 4)
        ref = terminal_cost_lyapunov(fb.A_cl, Qx + r * (K.T @ K))
        np.testing.assert_array_equal(terminal_weight(fb.A_cl, fb.K, Qx, r), ref)


def test_remembered_weight_checks_and_square_roots_equal_fresh_ones():
    rng = np.random.default_rng(1)
    for _ in range(10):
        L = rng.normal(size=(4, 4))
        W = L.T @ L
        for _ in range(2):  # the second call is answered from the memo
            got = _checked_weight("P", W.copy(), 4)
            np.testing.assert_array_equal(got, _weight("P", W, 4))
            assert not got.flags.writeable
            lam, V = np.linalg.eigh(got)
            np.testing.assert_array_equal(_psd_sqrt(got), np.sqrt(lam)[:, None] * V.T)
    with pytest.raises(ValueError, match="positive semidefinite"):
        _checked_weight("P", -np.eye(4), 4)
