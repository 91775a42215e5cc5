"""One BLAS thread in the small-matrix paths: building and re-weighting QPs, env steps.

The engine's matrices are small (tens to a few hundred rows); OpenBLAS's thread pool
only adds synchronisation there, and on a busy machine (more runnable threads than
cores) a parameter change of the train MPCs costs 6-40x more with its default
threads than with one (measurements: ``docs/design/mpc_engine.md``).  :func:`single_thread_blas`
limits every loaded BLAS to one thread for the duration of a ``with`` block through
threadpoolctl; nested blocks cost nothing (a depth counter), so an env step can hold
the limit while the controllers' rebuilds inside it ask for it again.
"""

from __future__ import annotations

import threading
from types import TracebackType
from typing import Any

__all__ = ["single_thread_blas"]

_CONTROLLER: Any = None


def _blas_libraries() -> list[Any]:
    """threadpoolctl's controllers of the BLAS libraries loaded at the first use (cached:
    building them scans the process's shared libraries, about a millisecond)."""
    global _CONTROLLER
    if _CONTROLLER is None:
        from threadpoolctl import ThreadpoolController

        _CONTROLLER = ThreadpoolController()
    return list(_CONTROLLER.select(user_api="blas").lib_controllers)


class _SingleThreadBLAS:
    """Re-entrant context: the outermost ``with`` sets the limit, the others count (the
    limit is process-wide, so the count is shared by all threads, under a lock).

    The outermost ``with`` reads each library's thread count and sets one thread only
    where it is above one (a few microseconds, ctypes calls); the exit restores exactly
    what it changed. threadpoolctl's own ``limit`` would query every library's full
    description on each entry, which costs about as much as a cheap env step.
    """

    def __init__(self) -> None:
        self._depth = 0
        self._saved: list[tuple[Any, int]] = []
        self._libs: list[Any] | None = None
        self._lock = threading.Lock()

    def __enter__(self) -> _SingleThreadBLAS:
        self.acquire()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.release()

    def acquire(self) -> None:
        """Enter the limit without a ``with`` block (pair with :meth:`release`): an env
        holds it from its construction to its ``close``, so that its steps do not set and
        restore the thread count each time."""
        with self._lock:
            if self._depth == 0:
                if self._libs is None:
                    self._libs = _blas_libraries()
                saved = []
                for lib in self._libs:
                    n = lib.get_num_threads()
                    if n is not None and n > 1:
                        lib.set_num_threads(1)
                        saved.append((lib, n))
                self._saved = saved
            self._depth += 1

    def release(self) -> None:
        """Leave the limit (the outermost release restores the thread counts)."""
        with self._lock:
            self._depth -= 1
            if self._depth == 0:
                saved, self._saved = self._saved, []
                for lib, n in saved:
                    lib.set_num_threads(n)


_SINGLE = _SingleThreadBLAS()


def single_thread_blas() -> _SingleThreadBLAS:
    """Context manager: BLAS limited to one thread inside (re-entrant, process-wide)."""
    return _SINGLE
