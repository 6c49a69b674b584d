"""One temperature policy for every command and the API (docs/conventions.md,
"Temperatures outside the maps and the log").

- A temperature within ``TEMPERATURE_TOLERANCE`` (K) outside the maps' range
  is held at the edge and counted: a machine at its 20 C reference reads a
  hair under 20 C with ordinary thermocouple noise.
- Beyond it, ``out_of_range`` chooses: ``'raise'`` (stop, the default),
  ``'clamp'`` (hold at the edge) or ``'extrapolate'`` (extend the maps
  linearly in temperature; the largest distance is reported).
- A point up to ``LOG_HOLD`` s before the first or after the last reading of
  the thermocouple log (a run recovered after the recorder stopped) takes
  the nearest reading; farther, an error.

The same names are the Python arguments (``out_of_range``,
``temperature_tolerance``, ``log_hold``) and the CLI flags
(``--out-of-range``, ``--temperature-tolerance``, ``--log-hold``).
"""

from __future__ import annotations

import math

import numpy as np

from .errors import InputError

__all__ = ["TEMPERATURE_TOLERANCE", "LOG_HOLD", "OUT_OF_RANGE", "check_policy", "check_log_coverage", "cli_wording"]

#: K: the thermocouples' uncertainty (thesis 6.4: 0.5 K class), within which
#: a temperature outside the maps is held at the edge.
TEMPERATURE_TOLERANCE = 0.5
#: s: how far outside the thermocouple log a point may lie and still take
#: the nearest reading (a logger sampling every few seconds, a recovered run).
LOG_HOLD = 120.0
#: Choices beyond the tolerance.
OUT_OF_RANGE = ("raise", "clamp", "extrapolate")

# The sentences the Python layer appends to out-of-range errors (written by
# the bindings, rust/py/src/errors.rs) and what the CLI says instead.
_PYTHON_TEMPERATURE = (" (choices: out_of_range='clamp' holds it at the edge, 'extrapolate' extends the maps "
                       "linearly, or a wider temperature_tolerance in K)")
_CLI_TEMPERATURE = (" (choices: --out-of-range clamp holds it at the edge, --out-of-range extrapolate extends "
                    "the maps linearly, or a wider --temperature-tolerance K)")
_PYTHON_POSITION = " (choices: out_of_range='clamp' holds it at the table's end)"
_CLI_POSITION = " (choices: --out-of-range clamp holds it at the table's end)"
_PYTHON_LOG = "pass log_hold= (s) to hold the nearest reading that far"
_CLI_LOG = "use --log-hold S to hold the nearest reading that far"


def check_policy(out_of_range: str, temperature_tolerance: float, log_hold: float | None = None) -> None:
    """Raise ``InputError`` naming the argument if the policy is malformed."""
    if out_of_range not in OUT_OF_RANGE:
        raise InputError(f"out_of_range: expected one of {', '.join(map(repr, OUT_OF_RANGE))}, got {out_of_range!r}")
    for name, value in (("temperature_tolerance", temperature_tolerance), ("log_hold", log_hold)):
        if value is None and name == "log_hold":
            continue
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
            raise InputError(f"{name}: expected a finite number >= 0 ({'K' if 'temperature' in name else 's'}), "
                             f"got {value!r}")


def check_log_coverage(run, t, log_hold: float) -> None:
    """Raise ``InputError`` if a point lies more than ``log_hold`` s outside
    the run's thermocouple log, naming the first such row and time.

    Parameters
    ----------
    run : Run
        The run whose ``temperatures['t']`` (s) is the log.
    t : array_like, shape (N,)
        The points' time stamps, s.
    log_hold : float
        How far outside the log a point may lie, s.
    """
    lt = np.asarray(run.temperatures["t"], dtype=float)
    t = np.asarray(t, dtype=float)
    if not len(lt) or not len(t):
        return
    far = (t < lt[0] - log_hold) | (t > lt[-1] + log_hold)
    if np.any(far):
        i = int(np.argmax(far))
        gap = lt[0] - t[i] if t[i] < lt[0] else t[i] - lt[-1]
        raise InputError(f"point row {i}: t = {t[i]:g} s is {gap:.1f} s outside the temperature log "
                         f"({lt[0]:g}..{lt[-1]:g} s), more than the {log_hold:g} s held at its ends "
                         f"({_PYTHON_LOG}, or give the temperature)")


def cli_wording(message: str) -> str:
    """An error message with the Python argument names replaced by the CLI's flags."""
    return (message.replace(_PYTHON_TEMPERATURE, _CLI_TEMPERATURE).replace(_PYTHON_POSITION, _CLI_POSITION)
            .replace(_PYTHON_LOG, _CLI_LOG))
