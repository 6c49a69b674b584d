"""Child processes for tests: the environment a child command runs in, the signals it can be sent, and how a
command's one-line refusal reads."""

import os
import signal
from pathlib import Path

import cmmpose

#: A child imports the cmmpose these tests import (installed, or a source tree on PYTHONPATH), not the clone's
#: python/ folder, which holds no compiled core when the package was installed as a wheel.
ENV = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in (str(Path(cmmpose.__file__).parent.parent),
                                                                os.environ.get("PYTHONPATH", "")) if p)}


def one_error_line(result, *words, code=1) -> str:
    """A click result that exits ``code`` with one ``Error:`` line naming ``words`` and no traceback: the line."""
    assert result.exit_code == code, result.output
    assert isinstance(result.exception, SystemExit), result.exception
    text = result.output.strip()
    assert "Traceback" not in text, text
    errors = [line for line in text.splitlines() if line.startswith("Error:")]
    assert len(errors) == 1, text
    for w in words:
        assert w in errors[0], errors[0]
    return errors[0]


def default_signals():
    """``preexec_fn`` of a child the test will signal: SIGTERM, SIGHUP and SIGINT at their default disposition.
    A suite run under nohup, or in the background of a shell, inherits SIGHUP or SIGINT ignored, which the
    command rightly keeps ignoring (then the signal a test sends would do nothing)."""
    for sig in (signal.SIGTERM, signal.SIGHUP, signal.SIGINT):
        signal.signal(sig, signal.SIG_DFL)
