"""Child processes for tests that signal a command."""

import signal


def default_signals():
    """``preexec_fn`` of a child the test will signal: SIGTERM, SIGHUP and SIGINT at their default disposition.
    A suite run under nohup, or in the background of a shell, inherits SIGHUP or SIGINT ignored, which the
    command rightly keeps ignoring (then the signal a test sends would do nothing)."""
    for sig in (signal.SIGTERM, signal.SIGHUP, signal.SIGINT):
        signal.signal(sig, signal.SIG_DFL)
