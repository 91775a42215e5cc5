"""Optional compilation (numba) of the few scalar hot loops of the library.

:func:`compiled` returns a numba-compiled twin of a plain Python function, or None when
numba is missing or ``TRAIN_ENVS_NO_JIT=1`` (then the callers run their numpy / Python
reference code, which the tests compare with the compiled one).  numba is imported on
first use only, so importing the package stays fast; compiled code is cached on disk
(``cache=True``): only the first process after an install or a change of the source
compiles.  No fast-math flags: the compiled loops do the reference's IEEE operations in
the reference's order.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any

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


def compiled(func: Callable[..., Any]) -> Callable[..., Any] | None:
    """The compiled twin of ``func`` (made once per process), or None."""
    if func not in _CACHE:
        if enabled():
            import numba

            _CACHE[func] = numba.njit(cache=True, nogil=True)(func)
        else:
            _CACHE[func] = None
    return _CACHE[func]
