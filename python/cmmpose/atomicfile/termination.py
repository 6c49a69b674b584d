"""SIGTERM and SIGHUP as an exception, so that the clean-up of temporary files runs as on Ctrl-C
(:func:`raise_on_termination`, for the command line).
"""

from __future__ import annotations

import logging
import signal

_log = logging.getLogger("cmmpose")


class _Terminated(SystemExit):
    """SIGTERM or SIGHUP, raised so that ``finally`` blocks and :meth:`AtomicFile.abort` run."""


def raise_on_termination() -> None:
    """Make SIGTERM and SIGHUP raise ``SystemExit(128 + signal)`` in the main
    thread, as Ctrl-C raises ``KeyboardInterrupt``: every ``finally`` runs and
    no temporary file is left. For the command line (a library leaves the
    process's signal handlers alone); does nothing outside the main thread."""

    def handler(signum, frame):
        name = signal.Signals(signum).name
        _log.warning("%s received: stopping, removing temporary files", name)
        raise _Terminated(128 + signum)

    for sig in (signal.SIGTERM, getattr(signal, "SIGHUP", None)):
        if sig is None:
            continue
        try:
            if signal.getsignal(sig) in (signal.SIG_DFL, None):
                signal.signal(sig, handler)
        except (ValueError, OSError):  # not the main thread
            return
