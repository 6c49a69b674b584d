"""The thermocouple logger: SCPI over RS-232, as bench data-acquisition units
with a thermocouple multiplexer speak it (docs/protocols.md, "Thermocouple
logger").

Every message is one line of ASCII ending in LF; a line may hold several
commands separated by ``;`` (a leading ``:`` returns to the root of the
command tree), and the answers to the queries in it come back on one line,
separated by ``;``. The recorder configures the logger once per connection::

    *RST;*CLS
    CONF:TEMP TC,E,(@101:111)
    UNIT:TEMP C
    FORM:READ:TIME ON;:FORM:READ:TIME:TYPE REL
    ROUT:SCAN (@101:111)
    SYST:ERR?                -> +0,"No error"

then polls ``READ?;:SYST:ERR?``. The answer holds one reading and one time
stamp per channel of the scan list, then the oldest entry of the error queue::

    +2.2512E+01,+1234.567,+2.2498E+01,+1234.580,...;+0,"No error"

Readings are degrees C, time stamps seconds since the logger's time base was
zeroed (power-up or ``*RST``). An error code other than 0 rejects the scan.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

__all__ = ["configure_commands", "POLL", "ERROR_QUERY", "ScpiScan", "ScpiReply", "parse_reply", "parse_error", "channel_list"]

#: The poll command: one scan and the oldest error.
POLL = "READ?;:SYST:ERR?"
#: Error queue query.
ERROR_QUERY = "SYST:ERR?"
_ERROR_RE = re.compile(r'^\s*([+-]?\d+)\s*,\s*"(.*)"\s*$')
_TAIL_RE = re.compile(r'(?:^|;)\s*([+-]?\d+)\s*,\s*"([^"]*)"\s*$')
TC_TYPES = ("B", "E", "J", "K", "N", "R", "S", "T")


def channel_list(channels) -> str:
    """SCPI channel list of channel numbers, e.g. ``(@101:111)`` or ``(@101,103)``.

    Parameters
    ----------
    channels : sequence of int
        Multiplexer channel numbers (slot * 100 + channel, e.g. 101).
    """
    ch = [int(c) for c in channels]
    if ch and ch == list(range(ch[0], ch[0] + len(ch))) and len(ch) > 1:
        return f"(@{ch[0]}:{ch[-1]})"
    return "(@" + ",".join(str(c) for c in ch) + ")"


def configure_commands(channels, tc_type: str = "E") -> list[str]:
    """The lines that configure the logger for a scan of ``channels``.

    Parameters
    ----------
    channels : sequence of int
        Multiplexer channel numbers, in scan order.
    tc_type : str
        Thermocouple type (B, E, J, K, N, R, S or T); the thesis machine uses type E.

    Returns
    -------
    list of str
        Lines to send (without the line end); the last is ``SYST:ERR?``.
    """
    if tc_type.upper() not in TC_TYPES:
        raise ValueError(f"thermocouple type {tc_type!r}: expected one of {', '.join(TC_TYPES)}")
    cl = channel_list(channels)
    return [
        "*RST;*CLS",
        f"CONF:TEMP TC,{tc_type.upper()},{cl}",
        "UNIT:TEMP C",
        "FORM:READ:TIME ON;:FORM:READ:TIME:TYPE REL",
        f"ROUT:SCAN {cl}",
        ERROR_QUERY,
    ]


def parse_error(text: str) -> tuple[int, str]:
    """An error-queue entry ``+0,"No error"`` as (code, message); raises ValueError."""
    m = _ERROR_RE.match(text)
    if not m:
        raise ValueError(f"not an SCPI error-queue entry: {text[:60]!r}")
    return int(m.group(1)), m.group(2)


@dataclass(frozen=True)
class ScpiScan:
    """One scan of the logger.

    Attributes
    ----------
    values : tuple of float
        One reading per channel, degrees C.
    times : tuple of float
        The logger's time stamp of each reading, s.
    """

    values: tuple[float, ...]
    times: tuple[float, ...]


@dataclass(frozen=True)
class ScpiReply:
    """A parsed answer to ``POLL``: a scan (None if the logger sent none), the
    error code and message (0 when all is well), and why it is rejected
    (None if it is a good scan)."""

    scan: ScpiScan | None
    error_code: int
    error_message: str
    reason: str | None
    detail: str = ""


def parse_reply(line: str, n_channels: int) -> ScpiReply:
    """Parse one answer line to ``READ?;:SYST:ERR?``.

    Parameters
    ----------
    line : str
        The line without its line end.
    n_channels : int
        Channels in the scan list.

    Returns
    -------
    ScpiReply
        ``reason`` is ``scpi_error`` (error code not 0), ``malformed`` (not two
        parts, wrong number of fields, a field not a number, time stamps going
        back within the scan) or None.
    """
    m = _TAIL_RE.search(line)
    if not m:
        return ScpiReply(None, 0, "", "malformed", f"no SCPI error-queue entry at the end of {line[-60:]!r}")
    code, msg = int(m.group(1)), m.group(2)
    parts = [line[: m.start()]] if m.start() > 0 else []
    parts.append(m.group(0).lstrip(";"))
    if code != 0:
        return ScpiReply(None, code, msg, "scpi_error", f"{code},{msg!r}")
    if len(parts) != 2:
        return ScpiReply(None, code, msg, "malformed", "no readings before the error-queue entry")
    fields = parts[0].split(",")
    if len(fields) != 2 * n_channels:
        return ScpiReply(None, code, msg, "malformed", f"{len(fields)} fields, expected {2 * n_channels} (reading, time per channel)")
    try:
        nums = [float(f) for f in fields]
    except ValueError:
        bad = next(f for f in fields if not _is_float(f))
        return ScpiReply(None, code, msg, "malformed", f"field {bad[:20]!r} is not a number")
    if not all(math.isfinite(x) for x in nums):
        return ScpiReply(None, code, msg, "malformed", "a field is not finite")
    values, times = tuple(nums[0::2]), tuple(nums[1::2])
    if any(b < a for a, b in zip(times, times[1:])):
        return ScpiReply(None, code, msg, "malformed", "time stamps go back within the scan")
    return ScpiReply(ScpiScan(values, times), code, msg, None)


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True
