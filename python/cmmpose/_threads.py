"""The kernel's thread count from the environment, bounded (issue 35, item 4).

The compiled kernel runs its loops on a Rayon thread pool, sized by
``RAYON_NUM_THREADS`` when it first starts (default: one thread per core).
A count beyond :data:`MAX_THREADS_PER_CORE` threads per available core
(``RAYON_NUM_THREADS=100000``: thousands of threads on a 3,904-point file,
no answer in minutes) only costs memory and switching: it is lowered to that
bound before the pool starts, and said once in the log (docs/scale-out.md).
"""

from __future__ import annotations

import logging
import os

__all__ = ["bound_thread_count", "MAX_THREADS_PER_CORE", "thread_limit"]

#: Most kernel threads per available core.
MAX_THREADS_PER_CORE = 4

_log = logging.getLogger("cmmpose")


def thread_limit() -> int:
    """The most kernel threads: :data:`MAX_THREADS_PER_CORE` per core this process may run on."""
    try:
        cores = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        cores = os.cpu_count() or 1
    return MAX_THREADS_PER_CORE * max(cores, 1)


def bound_thread_count() -> int | None:
    """Lower ``RAYON_NUM_THREADS`` to :func:`thread_limit` when it asks for more (before the kernel's pool
    starts; a pool already started keeps its size). Returns the count set, or None when nothing changed
    (unset, within the bound, or not a whole number: the kernel then takes one thread per core)."""
    raw = os.environ.get("RAYON_NUM_THREADS")
    if raw is None:
        return None
    try:
        asked = int(raw.strip())
    except ValueError:
        return None
    limit = thread_limit()
    if asked <= limit:
        return None
    os.environ["RAYON_NUM_THREADS"] = str(limit)
    _log.info("RAYON_NUM_THREADS=%s lowered to %d (%d per available core)", raw.strip()[:20], limit,
              MAX_THREADS_PER_CORE)
    return limit
