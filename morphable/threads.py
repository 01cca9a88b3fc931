"""One BLAS thread for the many small matrix products of a fit.

A landmark fit is thousands of products of matrices with tens to a few hundred rows. A
multi-threaded BLAS (OpenBLAS' default: a thread per core) spends more time waking and
synchronising its threads than it saves on such products, and when anything else runs on
the machine its spinning threads fight that work: on 2 cores with one other busy process a
fit took 2x as long (``python -m evaluation.bench_fitting --load 1``, docs/fitting.md).
Users fit in parallel (fit-batch and Dask workers, a notebook beside a training run), so the
library limits BLAS itself instead of asking for environment variables.

:class:`single_blas_thread` holds BLAS at one thread for the duration of a block or a call;
:class:`single_torch_thread` does the same for torch's intra-op threads, whose refinement of
a 64 px crop took 17x as long with its default two threads beside two busy processes
(6.7 s against 0.39 s for 10 steps; ``python -m evaluation.bench_fitting --load 2``).
It nests and is safe across Python threads (the first to enter sets the limit, the last to
leave restores what was there). threadpoolctl is imported on first use, so that ``import
morphable`` stays light; its scan of the loaded libraries (about a millisecond) is redone
only when modules were imported since the last one, which is how another BLAS arrives
(scipy ships its own OpenBLAS).

Examples
--------
>>> import numpy as np
>>> with single_blas_thread():
...     x = np.linalg.solve(np.eye(3), np.ones(3))
>>> @single_blas_thread()
... def small_solve(A, b):
...     return np.linalg.solve(A, b)
"""
from __future__ import annotations

import contextlib
import sys
import threading

__all__ = ["single_blas_thread", "single_torch_thread"]

_lock = threading.Lock()
_controller = None
_modules_seen = -1


def _blas_controller():
    global _controller, _modules_seen
    if _controller is None or len(sys.modules) != _modules_seen:
        from threadpoolctl import ThreadpoolController

        _controller = ThreadpoolController()
        _modules_seen = len(sys.modules)
    return _controller


class _HeldWhileUsed(contextlib.ContextDecorator):
    """A process-wide setting held while any block that asked for it runs: the first block to
    enter sets it (``_set`` returns what restores it), the last to leave restores it."""

    _depth = 0
    _saved = None

    def __enter__(self):
        cls = type(self)
        with _lock:
            if cls._depth == 0:
                cls._saved = self._set()
            cls._depth += 1
        return self

    def __exit__(self, *exc):
        cls = type(self)
        with _lock:
            cls._depth -= 1
            if cls._depth == 0:
                self._restore(cls._saved)
                cls._saved = None
        return False


class single_blas_thread(_HeldWhileUsed):
    """Context manager and decorator: BLAS (OpenBLAS, MKL, BLIS) runs one thread inside."""

    _depth = 0

    def _set(self):
        return _blas_controller().limit(limits=1, user_api="blas")

    def _restore(self, limiter):
        limiter.restore_original_limits()


class single_torch_thread(_HeldWhileUsed):
    """Context manager and decorator: torch's intra-op parallelism runs one thread inside
    (torch is imported on entry). Nests like :class:`single_blas_thread`."""

    _depth = 0

    def __enter__(self):
        import torch  # noqa: F401  (before the lock: the first import takes seconds)

        return super().__enter__()

    def _set(self):
        torch = sys.modules["torch"]
        before = torch.get_num_threads()
        torch.set_num_threads(1)
        return before

    def _restore(self, before):
        sys.modules["torch"].set_num_threads(before)
