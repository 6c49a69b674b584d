"""Validation of scalar and three-vector arguments, and of numbers read from
text files. Every message names the argument (or the file and line) at fault;
the exception class is ``InputError`` unless the caller passes another
(``error=``), e.g. ``CalibrationError`` or ``MapError``.

Arrays at the Python/Rust boundary are converted by :mod:`cmmpose._arrays`.
"""

from __future__ import annotations

import math
import re
import tomllib

import numpy as np

from .errors import InputError, MapError

#: A decimal number as map and point files write them: sign, digits, point,
#: exponent; ASCII only.
DECIMAL_NUMBER = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?", re.ASCII)

#: Spelled-out non-finite values: numbers, but refused as not finite.
_NON_FINITE = re.compile(r"[+-]?(?:nan|inf|infinity)", re.ASCII | re.IGNORECASE)

__all__ = ["finite", "nonnegative", "positive", "triple", "vector3", "parse_number", "parse_toml",
           "LENGTH_UNITS_MM", "LENGTH_UNIT_NAMES", "length_unit_slip", "MAX_REPRODUCIBILITY_MM",
           "check_reproducibility", "DECIMAL_NUMBER"]

#: Largest stated per-scan centre reproducibility, mm per axis: a sphere
#: scan's centre repeats to micrometres, and a whole uncompensated machine
#: errs by ~0.1 mm (the thesis machine: 71 um rms on a 404 mm bar). A
#: floor of more than 1 mm would call every effect insignificant; such a
#: value is a unit slip (nm, or mm written as um x 1000), not a measurement.
MAX_REPRODUCIBILITY_MM = 1.0

#: Length units a value is most often typed or read in by mistake for mm, by their size in mm (the unit hints
#: of the refusals of an implausible length: :func:`length_unit_slip`).
LENGTH_UNITS_MM = {"m": 1000.0, "in": 25.4, "cm": 10.0}
LENGTH_UNIT_NAMES = {"m": "metres", "in": "inches", "cm": "centimetres"}


def finite(name: str, value, *, error: type[Exception] = InputError) -> float:
    """A finite number.

    Parameters
    ----------
    name : str
        The argument's name, first in any message.
    value : object
        Anything ``float()`` accepts (a Python or NumPy number, a 0-d array,
        a numeric string).
    error : type of Exception, optional
        Raised on a bad value (default ``InputError``).

    Returns
    -------
    float

    Raises
    ------
    error
        ``"<name>: expected a number, got <value>"`` or
        ``"<name>: must be finite, got <value>"``.
    """
    v = _as_float(name, value, error)
    if not math.isfinite(v):
        raise error(f"{name}: must be finite, got {v}")
    return v


def _as_float(name: str, value, error: type[Exception]) -> float:
    """``float(value)``, refusing what converts only by accident (booleans)."""
    if _not_a_number(value):
        raise error(f"{name}: expected a number, got {value!r}")
    try:
        return float(value)
    except (TypeError, ValueError):
        raise error(f"{name}: expected a number, got {digits_cut(repr(value))}") from None
    except OverflowError:  # an integer beyond any float (a 400-digit number): not finite, not echoed
        raise error(f"{name}: must be finite, got {digits_cut(repr(value))}") from None


def _not_a_number(x) -> bool:
    """Booleans convert to floats by accident (a JSON ``true`` read as 1.0)."""
    return isinstance(x, (bool, np.bool_))


def _items(value) -> list:
    try:
        return list(value)
    except TypeError:
        return []


def nonnegative(name: str, value, *, error: type[Exception] = InputError) -> float:
    """A finite number >= 0 (e.g. a standard uncertainty).

    Parameters
    ----------
    name : str
        The argument's name, first in any message.
    value : object
        Anything ``float()`` accepts.
    error : type of Exception, optional
        Raised on a bad value (default ``InputError``).

    Returns
    -------
    float

    Raises
    ------
    error
        ``"<name>: expected a number, got <value>"`` or
        ``"<name>: must be finite and >= 0, got <value>"``.
    """
    v = _as_float(name, value, error)
    if not math.isfinite(v) or v < 0:
        raise error(f"{name}: must be finite and >= 0, got {v}")
    return v


def positive(name: str, value, *, error: type[Exception] = InputError) -> float:
    """A finite number > 0 (e.g. a wavelength).

    Parameters
    ----------
    name : str
        The argument's name, first in any message.
    value : object
        Anything ``float()`` accepts.
    error : type of Exception, optional
        Raised on a bad value (default ``InputError``).

    Returns
    -------
    float

    Raises
    ------
    error
        As :func:`nonnegative`, and ``"<name>: must be > 0, got 0"``.
    """
    v = nonnegative(name, value, error=error)
    if v == 0:
        raise error(f"{name}: must be > 0, got 0")
    return v


def _unit(unit: str | None) -> str:
    return f" ({unit})" if unit else ""


def triple(name: str, value, *, unit: str | None = None, nonnegative: bool = False,
           error: type[Exception] = InputError) -> tuple[float, float, float]:
    """Three finite numbers, as a tuple of floats.

    Parameters
    ----------
    name : str
        The argument's name, first in any message.
    value : iterable
        Three numbers.
    unit : str, optional
        Unit named in the messages, e.g. ``"mm"``.
    nonnegative : bool, optional
        Also require each value >= 0.
    error : type of Exception, optional
        Raised on a bad value (default ``InputError``).

    Returns
    -------
    tuple of 3 float

    Raises
    ------
    error
        ``"<name>: expected three numbers (<unit>), got <value>"``,
        ``"<name>: expected three finite numbers (<unit>), got <value>"`` or
        ``"<name>: must be >= 0, got <value>"``.
    """
    shown = digits_cut(repr(value))
    if any(_not_a_number(x) for x in _items(value)):
        raise error(f"{name}: expected three numbers{_unit(unit)}, got {shown}")
    try:
        vals = tuple(float(x) for x in value)
    except (TypeError, ValueError):
        raise error(f"{name}: expected three numbers{_unit(unit)}, got {shown}") from None
    except OverflowError:  # an integer beyond any float (a 400-digit number)
        vals = (math.inf,)
    if len(vals) != 3 or not all(math.isfinite(x) for x in vals):
        raise error(f"{name}: expected three finite numbers{_unit(unit)}, got {shown}")
    if nonnegative and min(vals) < 0:
        raise error(f"{name}: must be >= 0, got {shown}")
    return vals  # type: ignore[return-value]


def digits_cut(text: str) -> str:
    """``text`` with every run of more than 20 digits said by its length (a 400-digit number is not echoed)."""
    return re.sub(r"\d{21,}", lambda m: f"<{len(m.group())} digits>", text)


def vector3(name: str, value, *, unit: str | None = None, error: type[Exception] = InputError) -> np.ndarray:
    """Three finite numbers, as a new float64 array of shape (3,).

    Parameters
    ----------
    name : str
        The argument's name, first in any message.
    value : array_like
        Three numbers.
    unit : str, optional
        Unit named in the messages, e.g. ``"mm"``.
    error : type of Exception, optional
        Raised on a bad value (default ``InputError``).

    Returns
    -------
    ndarray, shape (3,), float64
        A copy: changing ``value`` afterwards does not change it.

    Raises
    ------
    error
        ``"<name>: expected three numbers (<unit>), got <value>"`` or
        ``"<name>: expected three finite numbers (<unit>), got <value>"``.
    """
    try:
        a = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise error(f"{name}: expected three numbers{_unit(unit)}, got {value!r}") from None
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise error(f"{name}: expected three finite numbers{_unit(unit)}, got {value!r}")
    return a


def parse_number(text: str, where: str, what: str, *, error: type[Exception] = MapError) -> float:
    """A finite number read from a text file.

    Parameters
    ----------
    text : str
        The field as read (surrounding white space is ignored).
    where : str
        ``"<file>:<line>"``, first in any message.
    what : str
        The field's name (a column, a header key).
    error : type of Exception, optional
        Raised on a bad field (default ``MapError``).

    Returns
    -------
    float

    Raises
    ------
    error
        ``"<where>: <what> '<text>' is not a number"`` or
        ``"<where>: <what> is not finite (<text>)"``.
    """
    # Plain ASCII decimal numbers only: Python's float() also takes '1_0',
    # non-ASCII digits and 'infinity', which no map file means.
    if not (DECIMAL_NUMBER.fullmatch(text.strip()) or _NON_FINITE.fullmatch(text.strip())):
        raise error(f"{where}: {what} {text.strip()!r} is not a number")
    value = float(text)
    if not math.isfinite(value):
        raise error(f"{where}: {what} is not finite ({text.strip()})")
    return value


def parse_toml(text: str, where: str, *, error: type[Exception] = InputError) -> dict:
    """The document of a TOML file's ``text``, or ``error`` naming ``where``
    (the file) when it is not TOML, is nested deeper than Python's parser
    recurses (an array in an array 10,000 deep), or holds an integer longer
    than Python converts (more than 4,300 digits).

    Parameters
    ----------
    text : str
        The file's text.
    where : str
        The file, first in any message.
    error : type of Exception, optional
        Raised on a bad file (default ``InputError``).
    """
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{where}: not a TOML file ({exc})") from None
    except RecursionError:
        raise error(f"{where}: not a usable TOML file (arrays or tables nested too deeply to read)") from None
    except ValueError as exc:  # an integer of more digits than int() converts
        why = "an integer of more than 4,300 digits" if "digits" in str(exc) else str(exc)
        raise error(f"{where}: not a usable TOML file ({why})") from None


def length_unit_slip(ratio: float, tolerance: float, units=tuple(LENGTH_UNITS_MM)) -> tuple[str, float] | None:
    """The length unit (name, size in mm) among ``units`` whose size is
    ``ratio`` within the factor ``1 + tolerance``, or None: a value that
    should be ``ratio`` times larger in mm looks like one given in that unit.
    The nearest unit on a log scale is taken."""
    if not (math.isfinite(ratio) and ratio > 0) or not units:
        return None
    unit = min(units, key=lambda u: abs(math.log(ratio / LENGTH_UNITS_MM[u])))
    size = LENGTH_UNITS_MM[unit]
    return (unit, size) if abs(math.log(ratio / size)) < math.log1p(tolerance) else None


def check_reproducibility(where: str, value, *, error: type[Exception] = InputError, **context) -> float:
    """A stated per-scan centre reproducibility, um per axis, checked: a real
    number (not a boolean or text), finite, above 0 and at most
    ``MAX_REPRODUCIBILITY_MM`` (1000 um; more is a unit slip).

    Parameters
    ----------
    where : str
        What names the value in a message (a file and key, an option).
    value : float
        The reproducibility, um per axis.
    **context
        Passed to the error (``what``, ``option``, ``cli_option``).

    Returns
    -------
    float
        The value, um.
    """
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise error(f"{where}: expected a positive number of um, got {value!r}", **context)
    um = float(value)
    if not math.isfinite(um) or um <= 0:
        raise error(f"{where}: expected a positive number of um, got {value!r}", **context)
    if um > MAX_REPRODUCIBILITY_MM * 1e3:
        raise error(f"{where}: {um:g} um per axis is implausible for a sphere centre (more than "
                    f"{MAX_REPRODUCIBILITY_MM * 1e3:g} um, ten times a whole uncompensated machine's errors): "
                    f"a unit slip? (um expected)", **context)
    return um
