"""The sparse form's cost products from the residual maps' non-zeros (``_SparseCost``).

``Ewᵀ W Ew`` (upper triangle) and ``Ewᵀ W Eθ`` summed over the rows where both factors
are non-zero must equal the dense products: to rounding for any maps and weights (a
diagonal head with per-stage scales, a full tail), bit for bit where the maps' entries
are ±1 (the selection and differencing maps of the train MPCs) and an entry has at
most two terms (then no order of summation or fused multiply-add changes it), and
inside :class:`LinearMPC` the sparse form's ``P`` and data map must be those of the
dense products.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_mpc_core import random_instance

from train_envs.mpc import LinearMPC
from train_envs.mpc.assembly import _SparseCost, _stage_weights


def _maps(rng, unit: bool, per_row: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Random residual maps with up to ``per_row`` non-zeros in a row of ``Ew``."""
    n, oe, nt = (int(x) for x in rng.integers((4, 3, 2), (40, 30, 20)))
    Ew, Eth = np.zeros((n, oe)), np.zeros((n, nt))
    for r in range(n):
        for E, kmax in ((Ew, per_row + 1), (Eth, 3)):
            k = min(int(rng.integers(0, kmax)), E.shape[1])
            cols = rng.choice(E.shape[1], size=k, replace=False)
            E[r, cols] = rng.choice([-1.0, 1.0], k) if unit else rng.standard_normal(k)
    return Ew, Eth


def _weight(rng, n: int) -> object:
    nd = int(rng.integers(0, n + 1))  # rows of the diagonal head
    blocks = []
    if nd:
        scales = None if rng.random() < 0.5 else rng.uniform(0.5, 2.0, nd)
        blocks.append((scales, nd, np.diag(rng.uniform(0.1, 3.0, 1))))
    if n - nd:
        X = rng.standard_normal((n - nd, n - nd))
        blocks.append((None, 1, X @ X.T))
    return _stage_weights(blocks)


def _dense(Ew, Eth, wt):
    EwW = wt.right(Ew.T)
    Hw = EwW @ Ew
    return np.triu(0.5 * (Hw + Hw.T)), EwW @ Eth


@pytest.mark.parametrize("seed", range(40))
def test_products_equal_the_dense_ones_to_rounding(seed):
    rng = np.random.default_rng(seed)
    Ew, Eth = _maps(rng, unit=False)
    wt = _weight(rng, Ew.shape[0])
    Hu, Hq = _SparseCost(Ew, Eth).products(wt)
    ref_u, ref_q = _dense(Ew, Eth, wt)
    assert Hu.dtype == Hq.dtype == np.float64
    assert not np.tril(Hu, -1).any()
    np.testing.assert_allclose(Hu, ref_u, rtol=1e-13, atol=1e-13 * max(1.0, np.abs(ref_u).max()))
    np.testing.assert_allclose(Hq, ref_q, rtol=1e-13, atol=1e-13 * max(1.0, np.abs(ref_q).max()))


def test_unit_maps_with_a_diagonal_weight_give_the_dense_numbers_on_two_term_entries():
    checked = 0
    for seed in range(40):
        rng = np.random.default_rng(1000 + seed)
        Ew, Eth = _maps(rng, unit=True, per_row=2)
        wt = _stage_weights([(rng.uniform(0.5, 2.0, Ew.shape[0]), Ew.shape[0], np.eye(1))])
        Hu, Hq = _SparseCost(Ew, Eth).products(wt)
        ref_u, ref_q = _dense(Ew, Eth, wt)
        # entries of at most two terms (any order of summation gives their sum)
        nz, nzt = (Ew != 0).astype(int), (Eth != 0).astype(int)
        terms = np.triu(nz.T @ nz)
        two, two_q = terms <= 2, nz.T @ nzt <= 2
        checked += int((terms == 2).sum())
        np.testing.assert_array_equal(Hu[two], ref_u[two])
        np.testing.assert_array_equal(Hq[two_q], ref_q[two_q])
        atol = 1e-14 * max(1.0, np.abs(ref_u).max())
        np.testing.assert_allclose(Hu, ref_u, rtol=1e-14, atol=atol)
    assert checked > 100  # sums of two terms were compared


def test_maps_without_non_zeros():
    Ew, Eth = np.zeros((5, 3)), np.zeros((5, 2))
    wt = _stage_weights([(None, 5, np.eye(1))])
    Hu, Hq = _SparseCost(Ew, Eth).products(wt)
    assert Hu.shape == (3, 3) and Hq.shape == (3, 2)
    assert Hu.dtype == np.float64 and not Hu.any() and not Hq.any()


@pytest.mark.parametrize("seed", range(8))
def test_sparse_form_qp_data_are_those_of_the_dense_products(seed):
    case = random_instance(seed)
    mpc = LinearMPC(**dict(case["inst"], form="sparse"))
    wt = mpc._condensed_src[2]
    ref_u, ref_q = _dense(mpc._Ew, mpc._Eth_s, wt)
    oe = mpc._col_slack
    np.testing.assert_allclose(mpc._P_dense[:oe, :oe], 2.0 * ref_u, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(mpc._M_full[:oe], 2.0 * ref_q, rtol=1e-12, atol=1e-12)
