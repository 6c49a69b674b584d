"""How the command line words the library's errors: a message that names a
Python argument (``log_hold=``, ``skip_incomplete=True``, ...) said with the
CLI flag that does the same (:func:`cli_wording`), and numbers of more than
20 digits shortened (:func:`shorten_numbers`).

The temperature policy itself (:class:`~cmmpose.temperature.TemperaturePolicy`,
``TEMPERATURE_TOLERANCE``, ``LOG_HOLD``, ``OUT_OF_RANGE``, ``check_policy``)
lives in :mod:`cmmpose.temperature` (docs/conventions.md, "Temperatures
outside the maps and the log").
"""

from __future__ import annotations

import re

from .errors import REMEDIES, Error
from .temperature import BROKEN_HINT, LOG_HOLD_HINT

__all__ = ["cli_wording", "shorten_numbers", "SCHEDULER_TIMEOUT_HINT"]

# The errors of the kernel carry their remedy as a field (cmmpose.errors.REMEDIES) and are worded for the
# command line from it (Error.render). The hints below are for messages that still carry a Python argument in
# their text (Python-side raises, and a kernel error's text quoted inside another message).
_PYTHON_LOG = LOG_HOLD_HINT
_CLI_LOG = "use --log-hold S to hold the nearest reading that far"
SKIP_INCOMPLETE_HINT = "pass skip_incomplete=True to evaluate the complete positions only and list the others"
_CLI_SKIP = "use --skip-incomplete to evaluate the complete positions only and list the others"


#: The hint cmmpose.scale gives when a scheduler does not answer in time.
SCHEDULER_TIMEOUT_HINT = "scheduler_timeout= sets the limit"

# Hints naming a Python argument: (the hint, the CLI flag that does the same, the CLI's words, what a command
# without that flag says instead, or a function of the command's flags giving it). Literal strings, or compiled
# patterns whose groups the replacements use.
_HINTS = (
    (_PYTHON_LOG, "--log-hold", _CLI_LOG, "this command has no option to hold the log's readings"),
    (SKIP_INCOMPLETE_HINT, "--skip-incomplete", _CLI_SKIP, "complete or relabel the positions"),
    (re.compile(r"pass on_gap='interpolate' to interpolate across (it|the bad stretch)"), "--on-gap",
     r"use --on-gap interpolate to interpolate across \1",
     lambda flags: r"the command line has no option to interpolate across \1"
     + (" (give the machine temperature with --temperature instead)" if "--temperature" in flags else "")),
    (BROKEN_HINT, "--broken-channels", "use --broken-channels drop to leave its bad samples out",
     "this command has no option to leave a broken thermocouple out"),
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
    (re.compile(r"^reproducibility_um:"), "--reproducibility", "--reproducibility:", "reproducibility:"),
    (re.compile(r"^repeat_scans:"), "--repeat-scans", "--repeat-scans:", "repeat_scans:"),
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


def cli_wording(message, context=None) -> str:
    """An error message as the command line says it: the hints that name a
    Python argument name the command's flag instead, or say the command has
    none, and numbers of more than 20 digits are shortened
    (:func:`shorten_numbers`).

    Parameters
    ----------
    message : Error or str
        The library's error (worded from its fields, :meth:`Error.render`)
        or message.
    context : click.Context, optional
        The command running (``click.get_current_context(silent=True)``): a
        hint whose flag this command lacks says so. None: every flag counts
        as present.
    """
    flags = None
    if context is not None and getattr(context, "command", None) is not None:
        flags = {o for p in context.command.params for o in getattr(p, "opts", ())}
    if isinstance(message, Error):
        message = message.render("cli", flags)
    remedies = tuple((r.python, r.flag, r.cli, r.missing) for r in REMEDIES.values())
    for hint, flag, cli, missing in remedies + _HINTS:
        has = flag is not None and (flags is None or flag in flags)
        if callable(missing):
            missing = missing(flags if flags is not None else {"--temperature"})
        if isinstance(hint, str):
            message = message.replace(hint, cli if has else missing)
        else:
            message = hint.sub(cli if has else missing, message)
    return shorten_numbers(message)
