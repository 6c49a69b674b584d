"""One BLAS thread for the diagnosis's small dense linear algebra.

The diagnosis solves thousands of small least-squares problems (QR factors
of a few hundred rows, SVDs of a few dozen columns). A multi-threaded BLAS
(OpenBLAS's default: one thread per core) hands each of them to a thread
pool whose threads spin while they wait; on a machine whose cores are busy
with other work (the Rust kernel's rayon pool between the fits, or other
processes) that waiting costs far more than the arithmetic: ranking the
candidates of a four-run joint diagnosis took 3.1 s with two BLAS threads on
a loaded 2-core machine and 0.4 s with one. The point-level work runs in
the Rust kernel, which keeps its own threads.

:func:`one_blas_thread` limits the BLAS libraries NumPy and SciPy loaded to
one thread for the duration of a call (through ``threadpoolctl``, a dependency) and restores the previous
limits afterwards. The limit is process-wide while it holds; it covers the
libraries loaded when the outermost such call begins.
"""

from __future__ import annotations

import functools
import threading
from contextlib import contextmanager

from threadpoolctl import threadpool_limits

__all__ = ["one_blas_thread", "blas_limited"]

_state = threading.local()


@contextmanager
def blas_limited():
    """A context in which the BLAS libraries loaded now use one thread
    (nested contexts of one thread set the limit once, at the outermost)."""
    depth = getattr(_state, "depth", 0)
    if depth:
        _state.depth = depth + 1
        try:
            yield
        finally:
            _state.depth = depth
        return
    with threadpool_limits(limits=1, user_api="blas"):
        _state.depth = 1
        try:
            yield
        finally:
            _state.depth = 0


def one_blas_thread(fn):
    """Decorator: run ``fn`` inside :func:`blas_limited`."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with blas_limited():
            return fn(*args, **kwargs)

    return wrapper
