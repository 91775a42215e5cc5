"""The one-BLAS-thread context of the small-matrix paths (train_envs.mpc.blas)."""

from __future__ import annotations

import numpy as np

from train_envs.mpc import blas
from train_envs.mpc.blas import single_thread_blas


def _blas_threads() -> list[int]:
    """Threads of the BLAS libraries the limiter knows (those loaded at its first use)."""
    with single_thread_blas():  # makes the limiter's library list
        pass
    return [i["num_threads"] for i in blas._CONTROLLER.select(user_api="blas").info()]


def test_limits_blas_to_one_thread_re_entrantly_and_restores():
    np.dot(np.ones((2, 2)), np.ones((2, 2)))  # BLAS loaded
    before = _blas_threads()
    assert before
    with single_thread_blas():
        assert set(_blas_threads()) == {1}
        with single_thread_blas():  # nested: still one thread, nothing restored
            assert set(_blas_threads()) == {1}
        assert set(_blas_threads()) == {1}
    assert _blas_threads() == before


def test_restores_after_an_exception():
    before = _blas_threads()
    try:
        with single_thread_blas():
            raise RuntimeError("inside")
    except RuntimeError:
        pass
    assert _blas_threads() == before
    with single_thread_blas():
        assert set(_blas_threads()) == {1}
