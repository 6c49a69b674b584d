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
import re

import numpy as np

from .errors import InputError

__all__ = ["TEMPERATURE_TOLERANCE", "LOG_HOLD", "OUT_OF_RANGE", "check_policy", "check_log_coverage", "cli_wording",
           "shorten_numbers", "SCHEDULER_TIMEOUT_HINT"]

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
SKIP_INCOMPLETE_HINT = "pass skip_incomplete=True to evaluate the complete positions only and list the others"
_CLI_SKIP = "use --skip-incomplete to evaluate the complete positions only and list the others"


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


#: The hint cmmpose.scale gives when a scheduler does not answer in time.
SCHEDULER_TIMEOUT_HINT = "scheduler_timeout= sets the limit"

# Hints naming a Python argument: (the hint, the CLI flag that does the same, the CLI's words, what a command
# without that flag says instead, or a function of the command's flags giving it). Literal strings, or compiled
# patterns whose groups the replacements use.
_HINTS = (
    (_PYTHON_TEMPERATURE, "--out-of-range", _CLI_TEMPERATURE,
     " (this command has no option to clamp or extrapolate the maps)"),
    (_PYTHON_POSITION, "--out-of-range", _CLI_POSITION, " (this command has no option to clamp it)"),
    (_PYTHON_LOG, "--log-hold", _CLI_LOG, "this command has no option to hold the log's readings"),
    (SKIP_INCOMPLETE_HINT, "--skip-incomplete", _CLI_SKIP, "complete or relabel the positions"),
    ("pass nan_policy='propagate' to get NaN rows instead", "--nan-policy",
     "use --nan-policy propagate to get NaN rows instead", "this command has no option to let NaN rows through"),
    (re.compile(r"pass on_gap='interpolate' to interpolate across (it|the bad stretch)"), None, "",
     lambda flags: r"the command line has no option to interpolate across \1"
     + (" (give the machine temperature with --temperature instead)" if "--temperature" in flags else "")),
    ("pass out_of_range='clamp' to clamp instead", "--out-of-range", "use --out-of-range clamp to clamp instead",
     "this command has no option to clamp it"),
    ("pass out_of_range='hold' to use the log's end values", None, "",
     "the command line has no option to hold the log's end values this far"),
    ("pass temperature= (C)", "--temperature", "give --temperature (C)", "record a temperature log with the run"),
    ("pass temperature= explicitly", "--temperature", "give --temperature (C)",
     "record a temperature log with the run"),
    ("pass overwrite=True / --overwrite to replace it", "--overwrite", "use --overwrite to replace it",
     "choose another folder"),
    ("pass overwrite=True to replace", "--overwrite", "use --overwrite to replace", "remove it first to replace"),
    (SCHEDULER_TIMEOUT_HINT, "--scheduler-timeout", "--scheduler-timeout SECONDS sets the limit",
     "no option of this command sets the limit"),
)
# A number of more digits than a float holds (echoed back from a hostile input): printed as a float.
_LONG_NUMBER = re.compile(r"(?<![\w.])[-+]?\d{21,}(?:\.\d*)?(?![\w.])")
# Any other run of that many digits (inside a quoted value): its first 20, then '...'.
_LONG_DIGITS = re.compile(r"\d{21,}")


def shorten_numbers(message: str) -> str:
    """``message`` with numbers of more than 20 digits shortened: a number
    alone as a float (``1e+300``), digits inside other text to their first 20
    and ``'...'`` with the count (a 300-digit input is not printed back)."""
    message = _LONG_NUMBER.sub(lambda m: f"{float(m[0]):.6g}", message)
    return _LONG_DIGITS.sub(lambda m: f"{m[0][:20]}...({len(m[0])} digits)", message)


def cli_wording(message: str, context=None) -> str:
    """An error message as the command line says it: the hints that name a
    Python argument name the command's flag instead, or say the command has
    none, and numbers of more than 20 digits are shortened
    (:func:`shorten_numbers`).

    Parameters
    ----------
    message : str
        The library's message.
    context : click.Context, optional
        The command running (``click.get_current_context(silent=True)``): a
        hint whose flag this command lacks says so. None: every flag counts
        as present.
    """
    flags = None
    if context is not None and getattr(context, "command", None) is not None:
        flags = {o for p in context.command.params for o in getattr(p, "opts", ())}
    for hint, flag, cli, missing in _HINTS:
        has = flag is not None and (flags is None or flag in flags)
        if callable(missing):
            missing = missing(flags if flags is not None else {"--temperature"})
        if isinstance(hint, str):
            message = message.replace(hint, cli if has else missing)
        else:
            message = hint.sub(cli if has else missing, message)
    return shorten_numbers(message)
