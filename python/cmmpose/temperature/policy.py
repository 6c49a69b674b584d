"""The temperature policy: one frozen object saying how readings become
temperatures and what happens at the edges (docs/conventions.md,
"Temperatures outside the maps and the log").

:class:`TemperaturePolicy` holds:

- map range (``out_of_range``: raise, clamp, extrapolate) and its tolerance
  (``temperature_tolerance``, K);
- the log's ends (``log_hold``, s: how long the last or first reading is held);
- gaps (``on_gap``: raise or interpolate; ``max_gap``, s);
- broken channels (``broken_channels``: drop them, noted, or raise);
- which sensor each role reads (``sensors``: role -> channel names).

Every library function that turns readings into temperatures accepts
``temperature_policy=`` with the same default, ``TemperaturePolicy()``
(:data:`DEFAULT_POLICY`); each field carries its command-line flag and help
in its metadata, from which :mod:`cmmpose.cli.temperature_options` builds
every command's flags.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from .._lazy import LazyModule
from ..errors import InputError, InputTypeError

# The run format loads on first use (its channel roles check ``sensors``):
# `cmmpose fit` and `compensate` import the policy and never need it.
_run = LazyModule("cmmpose.run")

__all__ = ["TemperaturePolicy", "DEFAULT_POLICY", "MAP_FIELDS", "as_policy", "check_policy", "TEMPERATURE_TOLERANCE",
           "LOG_HOLD", "OUT_OF_RANGE", "ON_GAP", "BROKEN_CHANNELS"]

#: K: the thermocouples' uncertainty (thesis 6.4: 0.5 K class), within which
#: a temperature outside the maps is held at the edge.
TEMPERATURE_TOLERANCE = 0.5
#: s: how far outside the thermocouple log a point may lie and still take
#: the nearest reading (a logger sampling every few seconds, a recovered run).
LOG_HOLD = 120.0
#: Choices beyond the tolerance.
OUT_OF_RANGE = ("raise", "clamp", "extrapolate")
#: Choices for a point in a gap of the log (or a stretch with no clean channel).
ON_GAP = ("raise", "interpolate")
#: Choices for a channel check_log finds broken (NaN, open circuit, implausible, stuck).
BROKEN_CHANNELS = ("drop", "raise")


def check_policy(out_of_range: str, temperature_tolerance: float, log_hold: float | None = None) -> None:
    """Raise ``InputError`` naming the argument if the map-side policy is malformed."""
    if out_of_range not in OUT_OF_RANGE:
        raise InputError(f"out_of_range: expected one of {', '.join(map(repr, OUT_OF_RANGE))}, got {out_of_range!r}")
    for name, value in (("temperature_tolerance", temperature_tolerance), ("log_hold", log_hold)):
        if value is None and name == "log_hold":
            continue
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
            raise InputError(f"{name}: expected a finite number >= 0 ({'K' if 'temperature' in name else 's'}), "
                             f"got {value!r}")


def _cli(flag: str, help: str, **kw) -> dict:
    """A field's command-line option: its flag, help text and click keywords."""
    return {"flag": flag, "help": help, **kw}


def _sensors(value) -> tuple[tuple[str, tuple[str, ...]], ...]:
    """``sensors`` as sorted ``((role, (channel, ...)), ...)`` from a dict,
    pairs, or ``'ROLE=CH1,CH2'`` strings (the CLI's ``--sensor``)."""
    if value is None:
        return ()
    if isinstance(value, Mapping):
        items = list(value.items())
    elif isinstance(value, (str, bytes)) or not isinstance(value, Sequence):
        raise InputError(f"sensors: expected a dict role -> channel names, got {value!r}")
    else:
        items = []
        for k, item in enumerate(value):
            if isinstance(item, str):
                role, eq, names = item.partition("=")
                if not eq:
                    raise InputError(f"sensors[{k}]: expected 'ROLE=CHANNEL[,CHANNEL...]', got {item!r}")
                items.append((role.strip(), [n.strip() for n in names.split(",")]))
            elif isinstance(item, Sequence) and len(item) == 2:
                items.append(tuple(item))
            else:
                raise InputError(f"sensors[{k}]: expected a (role, channel names) pair or 'ROLE=CH,...', got {item!r}")
    out = {}
    for role, names in items:
        if role not in _run.CHANNEL_ROLES:
            raise InputError(f"sensors: unknown role {role!r} (allowed: {', '.join(_run.CHANNEL_ROLES)})")
        if role in out:
            raise InputError(f"sensors: role {role!r} given twice")
        names = (names,) if isinstance(names, str) else tuple(names)
        if not names or not all(isinstance(n, str) and n and n != "t" for n in names):
            raise InputError(f"sensors: role {role!r}: expected one or more channel names, got {names!r}")
        if len(set(names)) != len(names):
            raise InputError(f"sensors: role {role!r} names a channel twice: {', '.join(names)}")
        out[role] = names
    seen: dict[str, str] = {}
    for role, names in out.items():
        for n in names:
            if n in seen:
                raise InputError(f"sensors: channel {n!r} given to roles {seen[n]!r} and {role!r}; one role each")
            seen[n] = role
    return tuple(sorted(out.items()))


@dataclass(frozen=True)
class TemperaturePolicy:
    """How readings become temperatures, and what happens at the edges: the
    one policy of every command and function (docs/conventions.md).

    Frozen, hashable and picklable: pass one object to compensate, evaluate,
    diagnose, acceptance_test, interim_check and the scale-out functions.

    Parameters
    ----------
    out_of_range : {'raise', 'clamp', 'extrapolate'}
        A temperature farther than ``temperature_tolerance`` outside the
        maps' range (or a scale reading outside a table): stop naming the
        row, hold it at the edge (counted, ``ClampWarning``), or extend the
        maps linearly in temperature (counted, the largest distance reported).
    temperature_tolerance : float
        K: a temperature this close outside the maps is held at the edge
        map and counted (a machine at 20 C reads a hair under).
    log_hold : float
        s: a point this far before the first or after the last reading of
        the thermocouple log (a recovered run) takes the nearest reading,
        and the provenance says how many points and for how long; farther
        is an error.
    on_gap : {'raise', 'interpolate'}
        A point in a gap of the log wider than ``max_gap`` (or in a stretch
        where a role has no clean channel): stop naming the row, or
        interpolate across it (counted in the provenance).
    max_gap : float or None
        s: the widest sample spacing that is not a gap; None: 5 times the
        log's median spacing.
    broken_channels : {'drop', 'raise'}
        A channel ``check_log`` finds broken (NaN, an open circuit such as a
        constant 1e6 C, implausible readings, stuck while the others vary):
        leave its bad samples out and average the role's other channels
        (listed, with why, in the provenance), or stop naming it.
    sensors : dict of str -> sequence of str
        Which channels each role reads, e.g. ``{'x_scale': ('X1', 'X3')}``
        (a channel of the role not named is not read; a channel named takes
        the role). Empty: every channel reads its own role from the log.
        Stored as sorted ``((role, (channel, ...)), ...)``.
    """

    out_of_range: str = field(default="raise", metadata=_cli(
        "--out-of-range", "Beyond the tolerance: stop, clamp to the maps' ends, or extrapolate the maps "
        "linearly in temperature (the largest distance is printed).", choices=OUT_OF_RANGE, map_side=True))
    temperature_tolerance: float = field(default=TEMPERATURE_TOLERANCE, metadata=_cli(
        "--temperature-tolerance", "K: temperatures this close outside the maps are held at the edge and counted.",
        type=float, map_side=True))
    log_hold: float = field(default=LOG_HOLD, metadata=_cli(
        "--log-hold", "s: points this far outside the thermocouple log take its nearest reading "
        "(a recovered run); farther is an error.", type=float))
    on_gap: str = field(default="raise", metadata=_cli(
        "--on-gap", "A point in a gap of the thermocouple log (or where a role has no clean channel): "
        "stop, or interpolate across it (counted in the provenance).", choices=ON_GAP))
    max_gap: float | None = field(default=None, metadata=_cli(
        "--max-gap", "s: the widest spacing of the thermocouple log that is not a gap "
        "(default 5 times its median spacing).", type=float))
    broken_channels: str = field(default="drop", metadata=_cli(
        "--broken-channels", "A broken thermocouple (NaN, open circuit such as 1e6 C, implausible, stuck): "
        "leave it out where broken and say so, or stop.", choices=BROKEN_CHANNELS))
    sensors: tuple = field(default=(), metadata=_cli(
        "--sensor", "The thermocouples a role reads, e.g. x_scale=X1,X3 (repeatable; "
        "default every channel of the role in the log).", multiple=True))

    def __post_init__(self):
        check_policy(self.out_of_range, self.temperature_tolerance, self.log_hold)
        if self.on_gap not in ON_GAP:
            raise InputError(f"on_gap: expected one of {', '.join(map(repr, ON_GAP))}, got {self.on_gap!r}")
        if self.broken_channels not in BROKEN_CHANNELS:
            raise InputError(f"broken_channels: expected one of {', '.join(map(repr, BROKEN_CHANNELS))}, "
                             f"got {self.broken_channels!r}")
        mg = self.max_gap
        if mg is not None and (isinstance(mg, bool) or not isinstance(mg, (int, float)) or not math.isfinite(mg)
                               or mg <= 0):
            raise InputError(f"max_gap: expected a positive time in s or None, got {mg!r}")
        object.__setattr__(self, "temperature_tolerance", float(self.temperature_tolerance))
        object.__setattr__(self, "log_hold", float(self.log_hold))
        object.__setattr__(self, "max_gap", None if mg is None else float(mg))
        object.__setattr__(self, "sensors", _sensors(self.sensors))

    def replace(self, **changes) -> TemperaturePolicy:
        """A copy with ``changes`` (checked like a new policy)."""
        return dataclasses.replace(self, **changes)

    def sensor_channels(self, role: str) -> tuple[str, ...] | None:
        """The channels ``role`` reads by the policy, or None (the log's)."""
        return dict(self.sensors).get(role)

    def to_dict(self) -> dict:
        """JSON-ready, with units in the keys."""
        return {"out_of_range": self.out_of_range, "temperature_tolerance_K": self.temperature_tolerance,
                "log_hold_s": self.log_hold, "on_gap": self.on_gap, "max_gap_s": self.max_gap,
                "broken_channels": self.broken_channels, "sensors": {r: list(n) for r, n in self.sensors}}

    def log_dict(self) -> dict:
        """The log side of :meth:`to_dict` (what reads the thermocouple log)."""
        d = self.to_dict()
        return {k: d[k] for k in ("log_hold_s", "on_gap", "max_gap_s", "broken_channels", "sensors")}

    @classmethod
    def from_dict(cls, doc: Mapping) -> TemperaturePolicy:
        """The inverse of :meth:`to_dict` (missing keys take the defaults)."""
        if not isinstance(doc, Mapping):
            raise InputTypeError(f"temperature policy: expected a mapping, got {type(doc).__name__}")
        names = {"out_of_range": "out_of_range", "temperature_tolerance_K": "temperature_tolerance",
                 "log_hold_s": "log_hold", "on_gap": "on_gap", "max_gap_s": "max_gap",
                 "broken_channels": "broken_channels", "sensors": "sensors"}
        unknown = set(doc) - set(names)
        if unknown:
            raise InputError(f"temperature policy: unknown keys {', '.join(sorted(unknown))}")
        return cls(**{names[k]: v for k, v in doc.items()})

    def __str__(self) -> str:
        s = (f"out of range: {self.out_of_range}, tolerance {self.temperature_tolerance:g} K, log hold "
             f"{self.log_hold:g} s, gaps: {self.on_gap}"
             + (f" (max gap {self.max_gap:g} s)" if self.max_gap is not None else "")
             + f", broken channels: {self.broken_channels}")
        if self.sensors:
            s += ", sensors: " + "; ".join(f"{r} {', '.join(n)}" for r, n in self.sensors)
        return s


#: The default policy of every function and command.
DEFAULT_POLICY = TemperaturePolicy()
#: The policy's fields that the maps read (the rest read the log).
MAP_FIELDS = tuple(f.name for f in dataclasses.fields(TemperaturePolicy) if f.metadata.get("map_side"))


def as_policy(temperature_policy: TemperaturePolicy | None = None, **keywords) -> TemperaturePolicy:
    """The policy a function uses: ``temperature_policy`` (default
    :data:`DEFAULT_POLICY`) with the keywords that are not None put in
    (the older arguments ``out_of_range=``, ``temperature_tolerance=``,
    ``log_hold=``, ...: a keyword given wins)."""
    if temperature_policy is None:
        temperature_policy = DEFAULT_POLICY
    elif not isinstance(temperature_policy, TemperaturePolicy):
        raise InputError(f"temperature_policy: expected a cmmpose.TemperaturePolicy, "
                         f"got {type(temperature_policy).__name__}")
    given = {k: v for k, v in keywords.items() if v is not None}
    if not given:
        return temperature_policy
    # the argument's own name in the message, before the dataclass's
    check_policy(given.get("out_of_range", "raise"), given.get("temperature_tolerance", 0.0), given.get("log_hold"))
    return dataclasses.replace(temperature_policy, **given)
