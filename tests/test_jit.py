"""The optional compilation helper (train_envs._jit)."""

from __future__ import annotations

import numpy as np
import pytest

from train_envs import _jit
from train_envs._jit import dgemv_at


def _source_function(src: str, name: str):
    """A function with no source file (numba cannot cache it on disk)."""
    glb: dict = {}
    exec(src, glb)  # noqa: S102 - test fixture
    return glb[name]


def test_compiled_twin_calls_compiled_helpers_and_leaves_python_alone():
    if not _jit.enabled():
        pytest.skip("numba not available")
    # the helper reads TWO, a global of its own module that the kernel's module lacks
    twice = _source_function("TWO = 2.0\ndef twice(x):\n    return TWO * x\n", "twice")
    outer = _source_function("def outer(xs):\n    return twice(xs[0]) + 1.0\n", "outer")
    outer.__globals__["twice"] = twice
    fast = _jit.compiled(outer, {"twice": twice})
    assert fast is not None and fast is not outer
    assert fast(np.array([3.0])) == outer([3.0]) == 7.0
    # the Python function still calls the Python helper (bound in its own namespace)
    assert outer.__globals__["twice"] is twice
    assert _jit.compiled(outer) is fast  # made once per process


def test_compiled_is_none_when_disabled(monkeypatch):
    monkeypatch.setenv("TRAIN_ENVS_NO_JIT", "1")
    f = _source_function("def f(x):\n    return x\n", "f")
    assert not _jit.enabled()
    assert _jit.compiled(f) is None


def test_bisect_right_matches_the_standard_library():
    import bisect

    xs = [-1e30, 0.0, 1.0, 1.0, 2.5, 7.0]
    arr = np.array(xs)
    for x in [-2e30, -1.0, 0.0, 0.5, 1.0, 2.5, 3.0, 7.0, 8.0, float("inf")]:
        assert _jit.bisect_right(arr, x) == bisect.bisect_right(xs, x)


def test_registered_twin_is_chosen_by_the_table(monkeypatch):
    f = _source_function("def triple(x):\n    return 3.0 * x\n", "triple")
    assert _jit.register("test.triple", f) is f
    assert _jit.implementation("test.triple", compiled_twin=False) is f
    if _jit.enabled():
        fast = _jit.implementation("test.triple")
        assert fast is not f and fast(2.0) == f(2.0) == 6.0
        assert _jit.implementation("test.triple", compiled_twin=True) is fast
    monkeypatch.setenv("TRAIN_ENVS_NO_JIT", "1")
    _jit._CACHE.pop(f, None)
    assert _jit.implementation("test.triple") is f
    with pytest.raises(RuntimeError, match="unavailable"):
        _jit.implementation("test.triple", compiled_twin=True)
    with pytest.raises(KeyError, match="no registered twin"):
        _jit.implementation("test.nothing")
    del _jit.TWINS["test.triple"]


def test_a_twin_that_is_not_available_gives_the_reference():
    f = _source_function("def double(x):\n    return 2.0 * x\n", "double")
    _jit.register("test.double", f, available=lambda: False)
    assert _jit.implementation("test.double") is f
    with pytest.raises(RuntimeError, match="unavailable"):
        _jit.implementation("test.double", compiled_twin=True)
    del _jit.TWINS["test.double"]


def test_dgemv_at_an_address_sums_as_ndarray_dot():
    addr = _jit.numpy_dgemv_address()
    if not _jit.enabled() or addr == 0:
        pytest.skip("numba or numpy's OpenBLAS not available")

    def rows(g, A, X, out, m):
        for r in range(X.shape[0]):
            dgemv_at(g, m, A.shape[1], A, X[r], out[r])

    fast = _jit.compiled(rows, {"dgemv_at": _jit.DGEMV})
    rows(addr, *(np.eye(2),) * 3, 2)  # (the Python meaning runs too)
    rng = np.random.default_rng(1)
    for i in range(50):
        # all rows of square and wide matrices, and the first rows (the DMC's prediction)
        n, m = (15, 15) if i % 3 == 0 else (12, 15 if i % 3 == 1 else 9)
        A = rng.standard_normal((15, n)) * rng.uniform(0.1, 10.0)
        X = rng.standard_normal((8, n)) * rng.uniform(1e-3, 1e2)
        out = np.full((8, 15), np.nan)
        fast(addr, A, X, out, m)
        assert np.array_equal(out[:, :m], np.array([A[:m].dot(x) for x in X]))
        assert np.isnan(out[:, m:]).all()
