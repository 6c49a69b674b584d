"""How the command line words the library's errors: from their fields
(:meth:`cmmpose.errors.Error.render`: a remedy names the running command's
flag, or says it has none; :func:`cli_wording`), and numbers of more than
20 digits shortened (:func:`shorten_numbers`). No message is rewritten: an
error that names a Python argument carries it as a field (``option``,
``remedy``, :data:`cmmpose.errors.REMEDIES`) where it is raised.

The temperature policy itself (:class:`~cmmpose.temperature.TemperaturePolicy`,
``TEMPERATURE_TOLERANCE``, ``LOG_HOLD``, ``OUT_OF_RANGE``, ``check_policy``)
lives in :mod:`cmmpose.temperature` (docs/conventions.md, "Temperatures
outside the maps and the log").
"""

from __future__ import annotations

import re

from .errors import Error

__all__ = ["cli_wording", "shorten_numbers"]

# A number of more digits than a float holds (echoed back from a hostile input): printed as a float.
_LONG_NUMBER = re.compile(r"(?<![\w.])[-+]?\d{21,}(?:\.\d*)?(?![\w.])")
# A decimal of more than 20 digits after its point (1e-320 printed in full): as a float, 6 significant digits.
_LONG_DECIMAL = re.compile(r"(?<![\w.])[-+]?\d*\.\d{21,}(?![\w.])")
# Any other run of that many digits (inside a quoted value): its first 20, then '...'.
_LONG_DIGITS = re.compile(r"\d{21,}")


def shorten_numbers(message: str) -> str:
    """``message`` with numbers of more than 20 digits shortened: a number
    alone as a float (``1e+300``), digits inside other text to their first 20
    and ``'...'`` with the count (a 300-digit input is not printed back); a
    decimal of more than 20 digits after its point in six significant digits
    (a temperature of 1e-320 C is not printed with 320 digits)."""
    message = _LONG_DECIMAL.sub(lambda m: f"{float(m[0]):.6g}", message)
    message = _LONG_NUMBER.sub(lambda m: f"{float(m[0]):.6g}", message)
    return _LONG_DIGITS.sub(lambda m: f"{m[0][:20]}...({len(m[0])} digits)", message)


def cli_wording(message, context=None) -> str:
    """An error as the command line says it: worded from its fields
    (:meth:`Error.render` with the running command's flags: a remedy names
    the flag, or says the command has none), with numbers of more than 20
    digits shortened (:func:`shorten_numbers`).

    Parameters
    ----------
    message : Error, other exception, or str
        The library's error (worded from its fields), or a message said as
        it is.
    context : click.Context, optional
        The command running (``click.get_current_context(silent=True)``): a
        remedy whose flag this command lacks says so. None: every flag counts
        as present.
    """
    flags = None
    if context is not None and getattr(context, "command", None) is not None:
        flags = {o for p in context.command.params for o in getattr(p, "opts", ())}
    text = message.render("cli", flags) if isinstance(message, Error) else str(message)
    return shorten_numbers(text)
