"""Optional compilation (numba) of the few scalar hot loops of the library.

:func:`compiled` returns a numba-compiled twin of a plain Python function, or None when
numba is missing or ``TRAIN_ENVS_NO_JIT=1`` (the callers then run the function itself,
or their numpy reference code; the tests compare both with the compiled one).  numba is
imported on first use only, so importing the package stays fast; compiled code is cached
on disk (``cache=True``): only the first process after an install or a change of the
source compiles.  No fast-math flags: the compiled loops do the same IEEE operations in
the same order as the Python source.

Call sites do not branch on compilation: a module registers its reference function with
:func:`register` (the table :data:`TWINS`), and call sites take
:func:`implementation` (the compiled twin or the reference, chosen once per process).

The helpers below are written once and called from the kernels of
:mod:`train_envs.controllers.tube.kernels` and the plant step.  numba's
disk cache checks only the file of the compiled function itself: after changing a helper
here, delete the ``*.nbi``/``*.nbc`` files under ``train_envs/**/__pycache__`` (``make
clean`` does) or the kernels keep the old helper.
"""

from __future__ import annotations

import functools
import os
import types
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

_CACHE: dict[Callable[..., Any], Callable[..., Any] | None] = {}


def enabled() -> bool:
    """Whether compiled twins are used (numba importable, not disabled)."""
    if os.environ.get("TRAIN_ENVS_NO_JIT", "") not in ("", "0"):
        return False
    try:
        import numba  # noqa: F401
    except ImportError:  # pragma: no cover - numba is a dependency
        return False
    return True


def compiled(
    func: Callable[..., Any], helpers: Mapping[str, Callable[..., Any]] | None = None
) -> Callable[..., Any] | None:
    """The compiled twin of ``func`` (made once per process), or None.

    ``helpers``: the functions ``func`` (and the helpers themselves) call, by the global
    name they call them by.  Compiled code can only call compiled code, so the twin and
    its compiled helpers are bound to a private namespace: the helpers' module globals
    under ``func``'s (so a helper from another module finds its constants); the Python
    function and helpers stay as they are.
    """
    if func not in _CACHE:
        if enabled():
            import numba

            glb: dict[str, Any] = {}
            for helper in (helpers or {}).values():
                if not isinstance(helper, Intrinsic):
                    glb.update(helper.__globals__)
            glb.update(func.__globals__)
            for name, helper in (helpers or {}).items():
                if isinstance(helper, Intrinsic):
                    glb[name] = helper.build()
                else:
                    glb[name] = _njit(numba, _rebind(helper, glb))
            _CACHE[func] = _njit(numba, _rebind(func, glb))
        else:
            _CACHE[func] = None
    return _CACHE[func]


def _njit(numba: Any, func: Callable[..., Any]) -> Callable[..., Any]:
    """``numba.njit`` with the disk cache where numba finds a writable place for it (the
    package's ``__pycache__`` or the user's cache directory), without it otherwise."""
    try:
        return numba.njit(cache=True, nogil=True)(func)
    except RuntimeError:  # "no locator available": compile in every process instead
        return numba.njit(nogil=True)(func)


def _rebind(func: Callable[..., Any], glb: dict[str, Any]) -> Callable[..., Any]:
    """``func`` with the global namespace ``glb`` (same code, name and module)."""
    out = types.FunctionType(func.__code__, glb, func.__name__, func.__defaults__, func.__closure__)
    out.__qualname__, out.__module__ = func.__qualname__, func.__module__
    out.__doc__ = func.__doc__
    return out


def bisect_right(xs: np.ndarray, x: float) -> int:
    """``bisect.bisect_right`` on a sorted array: the number of entries ``<= x`` (0 for a
    NaN ``x``, whose look-ups then give NaN anyway)."""
    lo, hi = 0, len(xs)
    while lo < hi:
        mid = (lo + hi) // 2
        if xs[mid] <= x:
            lo = mid + 1
        else:
            hi = mid
    return lo


_DGEMV: list[Any] = []


def numpy_dgemv() -> Any:
    """The ``cblas_dgemv`` of the OpenBLAS numpy itself is linked to, as a ctypes function,
    or None where numpy's wheel library is not found; compiled loops call it at its
    address (:func:`numpy_dgemv_address`, :data:`DGEMV`).

    A compiled matrix-vector product through it sums in the order of ``ndarray.dot``
    (the same library, kernel and arguments): ``A x`` of a C-contiguous ``A`` (m, n) is
    ``dgemv(102, 112, n, m, 1.0, A, n, x, 1, 0.0, y, 1)`` (column-major ``Aᵀ``,
    transposed), numpy's own call.
    """
    if not _DGEMV:
        import ctypes
        import glob

        libs = glob.glob(
            os.path.join(os.path.dirname(np.__file__), os.pardir, "numpy.libs", "*openblas64*")
        )
        fn = None
        if libs:
            try:
                fn = ctypes.CDLL(libs[0]).scipy_cblas_dgemv64_
            except (OSError, AttributeError):  # pragma: no cover - another numpy build
                fn = None
        if fn is not None:
            dp, i64 = ctypes.POINTER(ctypes.c_double), ctypes.c_int64
            fn.argtypes = [ctypes.c_int, ctypes.c_int, i64, i64, ctypes.c_double, dp, i64]
            fn.argtypes += [dp, i64, ctypes.c_double, dp, i64]
            fn.restype = None
        _DGEMV.append(fn)
    return _DGEMV[0]


def numpy_dgemv_address() -> int:
    """The address of :func:`numpy_dgemv` (0 where it is not found): what compiled
    loops pass to :data:`DGEMV` (an integer argument costs the dispatcher nothing; a
    ctypes function is converted at every call)."""
    fn = numpy_dgemv()
    if fn is None:
        return 0
    import ctypes

    return int(ctypes.cast(fn, ctypes.c_void_p).value)


@dataclass(frozen=True)
class Intrinsic:
    """A helper of compiled code that is not a Python function: ``build()`` returns
    the numba object bound under its name (numba is imported only then)."""

    build: Callable[[], Any]


@functools.cache
def _dgemv_at() -> Any:
    """``dgemv_at(addr, m, n, A, x, y)``: ``y[:m] = A[:m] x`` for a C-contiguous ``A``
    with ``n`` columns, by a call of the ``cblas_dgemv`` at ``addr``
    (:func:`numpy_dgemv_address`): ``dgemv(102, 112, n, m, 1.0, A, n, x, 1, 0.0, y,
    1)``, the call of :func:`numpy_dgemv`'s docstring."""
    from llvmlite import ir
    from numba.core import types
    from numba.extending import intrinsic

    @intrinsic
    def dgemv_at(typingctx, addr, m, n, A, x, y):
        sig = types.void(addr, m, n, A, x, y)

        def codegen(context, builder, signature, args):
            i32, i64, dbl = ir.IntType(32), ir.IntType(64), ir.DoubleType()
            dp = dbl.as_pointer()
            fnty = ir.FunctionType(
                ir.VoidType(), [i32, i32, i64, i64, dbl, dp, i64, dp, i64, dbl, dp, i64]
            )
            ty = signature.args
            addr_v, m_v, n_v = (
                context.cast(builder, args[i], ty[i], types.int64) for i in range(3)
            )
            A_d, x_d, y_d = (
                context.make_array(ty[i])(context, builder, args[i]).data for i in (3, 4, 5)
            )
            fn = builder.inttoptr(addr_v, fnty.as_pointer())
            one, zero = ir.Constant(dbl, 1.0), ir.Constant(dbl, 0.0)
            inc = ir.Constant(i64, 1)
            builder.call(
                fn,
                [ir.Constant(i32, 102), ir.Constant(i32, 112), n_v, m_v, one, A_d, n_v, x_d,
                 inc, zero, y_d, inc],
            )  # fmt: skip
            return context.get_dummy_value()

        return sig, codegen

    return dgemv_at


def dgemv_at(addr: int, m: int, n: int, A: np.ndarray, x: np.ndarray, y: np.ndarray) -> None:
    """``y[:m] = A[:m] x`` (``A`` with ``n`` columns): the Python meaning of the helper
    :data:`DGEMV` that compiled loops call by this name (``addr`` unused here)."""
    y[:m] = A[:m, :n].dot(x[:n])


#: the helper ``dgemv_at`` of compiled loops: the intrinsic of :func:`_dgemv_at`
DGEMV = Intrinsic(_dgemv_at)


# ------------------------------------------------------------------ the table of twins
@dataclass(frozen=True)
class Twin:
    """A reference implementation and the source of its compiled twin.

    ``reference`` is the readable implementation and the fallback; ``source`` (default:
    ``reference`` itself) is the plain-Python function numba compiles, with the same
    signature and the same floating-point operations; ``helpers`` are the functions it
    calls by global name (see :func:`compiled`).
    """

    name: str
    reference: Callable[..., Any]
    source: Callable[..., Any]
    helpers: Mapping[str, Callable[..., Any]]
    available: Callable[[], bool] | None = None


#: name -> twin; each module that defines a reference registers it next to it
TWINS: dict[str, Twin] = {}


def register(
    name: str,
    reference: Callable[..., Any],
    *,
    source: Callable[..., Any] | None = None,
    helpers: Mapping[str, Callable[..., Any]] | None = None,
    available: Callable[[], bool] | None = None,
) -> Callable[..., Any]:
    """Register ``reference`` (and the source of its compiled twin) under ``name``;
    returns ``reference`` so it can be used as a decorator's result. Idempotent.
    ``available``: a predicate the twin also needs (e.g. :func:`numpy_dgemv` found)."""
    TWINS[name] = Twin(name, reference, source or reference, dict(helpers or {}), available)
    return reference


def implementation(name: str, *, compiled_twin: bool | None = None) -> Callable[..., Any]:
    """The implementation of ``name`` call sites use: the compiled twin where numba is
    available and not disabled (``TRAIN_ENVS_NO_JIT=1``), else the reference.

    ``compiled_twin=True`` / ``False`` asks for one of the two explicitly (the public
    switch of the equality tests); True raises ``RuntimeError`` where compilation is
    unavailable.
    """
    if name not in TWINS:
        raise KeyError(f"no registered twin {name!r}; registered: {', '.join(sorted(TWINS))}")
    twin = TWINS[name]
    if compiled_twin is False:
        return twin.reference
    ready = twin.available is None or twin.available()
    fast = compiled(twin.source, twin.helpers) if ready else None
    if fast is None:
        if compiled_twin:
            raise RuntimeError(f"compiled twin of {name!r} unavailable (numba missing or disabled)")
        return twin.reference
    return fast
