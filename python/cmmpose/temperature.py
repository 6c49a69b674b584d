"""Temperatures: one policy, and the functions that turn a thermocouple log
into temperatures (docs/conventions.md, "Temperatures outside the maps and
the log"; docs/thermal.md).

:class:`TemperaturePolicy` is the one frozen object that says how readings
become temperatures and what happens at the edges:

- map range (``out_of_range``: raise, clamp, extrapolate) and its tolerance
  (``temperature_tolerance``, K);
- the log's ends (``log_hold``, s: how long the last or first reading is held);
- gaps (``on_gap``: raise or interpolate; ``max_gap``, s);
- broken channels (``broken_channels``: drop them, noted, or raise);
- which sensor each role reads (``sensors``: role -> channel names).

Every library function that turns readings into temperatures accepts
``temperature_policy=`` (compensate, evaluate, diagnose, the standards,
scale-out, calibration) with the same default, ``TemperaturePolicy()``; the
command line builds its flags from the policy's fields
(:func:`temperature_options`), so every command offers the same flags with
the same defaults and help.

Why a module of its own at the package root: the policy is read by the map
code (``errormap``, ``compensation``, ``scale``) as much as by calibration,
evaluation, diagnosis and the standards, so it sits below all of them. It
imports only ``errors`` (``run`` and ``click`` load on first use), so any
layer imports it without a circle and ``import cmmpose`` stays light.

The log functions:

- :func:`check_log` finds what is wrong with a log: gaps in time, stuck
  channels, open-circuit or implausible readings, NaN; it gives a clean mask
  per channel and sample.
- :func:`temperatures_at` interpolates the clean samples in time at the
  points' time stamps and applies a combination: ``'machine_mean'`` (the
  thesis: mean of the axis-scale channels), ``'per_axis'`` (one temperature
  per axis, for per-carriage maps), ``'role:ROLE'`` (the clean channels of
  one thermocouple role) or ``'channel:NAME'``.
- :func:`per_scan_temperature` gives one temperature per scan (the time
  average over the scan's duration).
- :func:`run_temperatures` and :func:`run_sensor_temperatures` do it for a
  run under a :class:`TemperaturePolicy`, with the provenance (channels
  dropped and why, points held and how long, the channels each role read).

Units: times in s, temperatures in degrees C, temperature differences in K.
Rows in messages are counted from 0.
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
import math
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from ._lazy import LazyModule
from .errors import InputError, InputTypeError

click = LazyModule("click")
# The run format loads on first use: `cmmpose fit` and `compensate` import this
# module (through the maps) and never need it (tests/test_speed_footprint.py).
_run = LazyModule("cmmpose.run")

if TYPE_CHECKING:
    from .run import Run

__all__ = [
    "TemperaturePolicy",
    "DEFAULT_POLICY",
    "as_policy",
    "temperature_options",
    "TEMPERATURE_TOLERANCE",
    "LOG_HOLD",
    "OUT_OF_RANGE",
    "ON_GAP",
    "BROKEN_CHANNELS",
    "check_policy",
    "check_log_coverage",
    "LogProblem",
    "LogReport",
    "ThermalSummary",
    "ScanTemperatures",
    "check_log",
    "temperatures_at",
    "per_scan_temperature",
    "run_temperatures",
    "run_sensor_temperatures",
    "SensorTemperatures",
    "log_provenance",
    "log_notes",
    "PLAUSIBLE",
    "STUCK_AFTER",
    "STUCK_TOLERANCE",
    "GAP_FACTOR",
    "POLICIES",
    "AXIS_ROLES",
    "GRADIENT_WINDOW",
]

# -- the policy ---------------------------------------------------------------------
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
#: Default plausible range of a machine thermocouple reading, degrees C.
PLAUSIBLE = (0.0, 50.0)
#: Default: a channel flat for longer than this while others vary is stuck, s.
STUCK_AFTER = 300.0
#: Default: readings within this of each other count as constant, K.
STUCK_TOLERANCE = 1e-3
#: Default ``max_gap`` is this many times the median sample spacing.
GAP_FACTOR = 5.0
#: Readings this far from any room (|T| >= this, degrees C) are reported as an
#: open circuit (a data logger's burn-out value such as 999.9 C) rather than
#: merely implausible.
OPEN_CIRCUIT_ABOVE = 500.0
#: Combinations of :func:`temperatures_at` (plus ``'role:ROLE'`` and ``'channel:NAME'``).
POLICIES = ("machine_mean", "per_axis", "role:ROLE", "channel:NAME")
#: Roles of the axis-scale channels, in X, Y, Z order.
AXIS_ROLES = ("x_scale", "y_scale", "z_scale")
#: Width of the running mean of a sensor's departure from the machine mean, s.
GRADIENT_WINDOW = 300.0


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


def temperature_options(log: bool = True):
    """A click decorator adding the policy's flags, built from the fields of
    :class:`TemperaturePolicy` (same names, defaults and help on every
    command). The command receives ``temperature_policy`` (a
    :class:`TemperaturePolicy`) and, if its signature names them, the
    fields as keywords too (``out_of_range``, ``temperature_tolerance``,
    ``log_hold``, ...), so older commands keep their parameters.

    Parameters
    ----------
    log : bool
        Also the flags that read a thermocouple log (``--log-hold``,
        ``--on-gap``, ``--max-gap``, ``--broken-channels``, ``--sensor``);
        False: the map side only (a command given temperatures, not a log).
    """
    fields = [f for f in dataclasses.fields(TemperaturePolicy) if log or f.metadata.get("map_side")]

    def wrap(f):
        params = inspect.signature(f).parameters
        takes_all = any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values())

        @functools.wraps(f)
        def command(*args, **kwargs):
            values = {fl.name: kwargs.pop(fl.name) for fl in fields}
            sensors = values.get("sensors")
            if sensors is not None:
                values["sensors"] = tuple(sensors)
            try:
                policy = TemperaturePolicy(**values)
            except InputError as exc:
                flag = next((fl.metadata["flag"] for fl in fields if str(exc).startswith(fl.name)), None)
                raise click.BadParameter(str(exc).split(": ", 1)[-1], param_hint=flag) from None
            for name, value in values.items():
                if name in params or takes_all:
                    kwargs[name] = getattr(policy, name) if name != "sensors" else value
            if "temperature_policy" in params or takes_all:
                kwargs["temperature_policy"] = policy
            return f(*args, **kwargs)

        for fl in reversed(fields):
            meta = fl.metadata
            kw = {"help": meta["help"], "show_default": fl.default is not None and fl.default != ()}
            if "choices" in meta:
                kw["type"] = click.Choice(list(meta["choices"]))
            elif "type" in meta:
                kw["type"] = meta["type"]
            if meta.get("multiple"):
                kw["multiple"] = True
                kw["metavar"] = "ROLE=CHANNEL[,...]"
            kw["default"] = fl.default
            command = click.option(meta["flag"], fl.name, **kw)(command)
        return command

    return wrap


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
                         f"({lt[0]:g}..{lt[-1]:g} s), more than the {log_hold:g} s held at its ends",
                         row=i, value=float(t[i]), unit="s", option="log_hold", remedy="log_hold")


_KIND_LABEL = {"gap": "gap", "stuck": "stuck", "open_circuit": "open circuit", "implausible": "implausible",
               "nan": "NaN"}
#: Why a channel was dropped, by problem kind (for the provenance).
_WHY = {"stuck": "constant (stuck while the others vary)", "open_circuit": "open circuit (a burn-out reading)",
        "implausible": "out of the plausible range", "nan": "NaN or infinite"}
#: More runs than this of one kind on one channel are reported as one problem.
_MAX_RUNS_LISTED = 20


# -- the report ---------------------------------------------------------------------
@dataclass(frozen=True)
class LogProblem:
    """One problem found in a thermocouple log.

    Attributes
    ----------
    channel : str
        The channel's name; ``'t'`` for a gap in time (which affects every
        channel).
    kind : str
        ``'gap'`` (sample spacing above ``max_gap``), ``'stuck'`` (constant
        while the others vary), ``'open_circuit'`` (a burn-out reading such as
        999.9 C), ``'implausible'`` (outside the plausible range) or ``'nan'``
        (NaN or infinite).
    start, end : float
        First and last affected sample time, s; for a gap the two samples
        around it.
    samples : int
        Samples affected (0 for a gap).
    runs : int
        Separate stretches merged into this entry (1 unless the channel had
        many short ones).
    detail : str
        What was read, e.g. ``'reads 999.9 C'``.
    """

    channel: str
    kind: str
    start: float
    end: float
    samples: int
    runs: int = 1
    detail: str = ""

    def __str__(self) -> str:
        where = "log" if self.channel == "t" else self.channel
        if self.kind == "gap":
            lead = f"{where}: gap, {self.detail}" if self.runs == 1 else f"{where}: {self.runs} gaps, {self.detail}"
            return lead
        span = f"at {self.start:g} s" if self.start == self.end else f"from {self.start:g} s to {self.end:g} s"
        runs = f" in {self.runs} stretches" if self.runs > 1 else ""
        detail = f" ({self.detail})" if self.detail else ""
        return f"{where}: {_KIND_LABEL[self.kind]} {span}{runs}, {self.samples} samples{detail}"


@dataclass(frozen=True, eq=False)
class LogReport:
    """What :func:`check_log` found in a thermocouple log.

    Attributes
    ----------
    t : ndarray, shape (M,)
        Sample times, s.
    channels : tuple of str
        Channel names, in the order of the columns of ``clean``.
    roles : tuple of str
        Role of each channel (``cmmpose.run.CHANNEL_ROLES``).
    clean : ndarray of bool, shape (M, C)
        True where a sample of a channel is usable: finite, plausible and not
        stuck. Gaps in time do not clear it.
    problems : tuple of LogProblem
        Everything found, gaps first, then by channel.
    max_gap : float
        Largest sample spacing accepted, s.
    median_spacing : float
        Median sample spacing, s.
    plausible : tuple of 2 float
        Plausible reading range used, degrees C.
    stuck_after : float or None
        Stuck-channel window used, s (None: detection was off).
    stuck_tolerance : float
        Tolerance for "constant", K.
    """

    t: np.ndarray = field(repr=False)
    channels: tuple[str, ...]
    roles: tuple[str, ...]
    clean: np.ndarray = field(repr=False)
    problems: tuple[LogProblem, ...]
    max_gap: float
    median_spacing: float
    plausible: tuple[float, float]
    stuck_after: float | None
    stuck_tolerance: float

    @property
    def ok(self) -> bool:
        """True when nothing was found."""
        return not self.problems

    @property
    def gaps(self) -> tuple[LogProblem, ...]:
        """The gaps in time."""
        return tuple(p for p in self.problems if p.kind == "gap")

    @property
    def samples(self) -> int:
        """Number of samples M."""
        return int(self.t.shape[0])

    @property
    def dropped(self) -> dict[str, int]:
        """Unclean samples per channel."""
        return dict(zip(self.channels, (self.samples - self.clean.sum(axis=0)).tolist()))

    def problems_of(self, channel: str) -> tuple[LogProblem, ...]:
        """Problems of one channel (``'t'``: the gaps)."""
        self._index(channel)
        return tuple(p for p in self.problems if p.channel == channel)

    def clean_of(self, channel: str) -> np.ndarray:
        """Clean mask of one channel, shape (M,)."""
        return self.clean[:, self._index(channel)]

    @property
    def bad_channels(self) -> tuple[str, ...]:
        """Channels with at least one problem."""
        names = {p.channel for p in self.problems}
        return tuple(c for c in self.channels if c in names)

    def _index(self, channel: str) -> int:
        if channel == "t":
            return -1
        try:
            return self.channels.index(channel)
        except ValueError:
            raise InputError(f"channel {channel!r}: not in the log (channels {', '.join(self.channels)})") from None

    def __str__(self) -> str:
        t = self.t
        head = (f"Temperature log: {len(self.channels)} channels, {self.samples} samples, {t[0]:g} to {t[-1]:g} s "
                f"(median spacing {self.median_spacing:g} s, max_gap {self.max_gap:g} s)")
        wn = max([7] + [len(c) for c in self.channels])
        wr = max([4] + [len(r) for r in self.roles])
        lines = [head, f"{'channel':<{wn}}  {'role':<{wr}}  {'clean':>7}  {'dropped':>7}  problems"]
        dropped = self.dropped
        for c, r in zip(self.channels, self.roles):
            kinds = sorted({_KIND_LABEL[p.kind] for p in self.problems if p.channel == c})
            lines.append(f"{c:<{wn}}  {r:<{wr}}  {self.samples - dropped[c]:>7}  {dropped[c]:>7}  "
                         f"{', '.join(kinds) if kinds else '-'}")
        if self.ok:
            lines.append("OK: no problems found.")
        else:
            lines.append(f"Problems ({len(self.problems)}):")
            lines += [f"  {p}" for p in self.problems]
        return "\n".join(lines)

    def __repr__(self) -> str:
        return (f"LogReport(channels={len(self.channels)}, samples={self.samples}, ok={self.ok}, "
                f"problems={len(self.problems)})")


@dataclass(frozen=True, eq=False)
class ThermalSummary:
    """How :func:`temperatures_at` (or :func:`per_scan_temperature`) got its
    temperatures.

    Attributes
    ----------
    policy : str
        The policy applied.
    channels : tuple of str
        The channels the policy reads (e.g. the nine axis-scale channels).
    channels_used : tuple of str
        Those that contributed to at least one point.
    channels_excluded : tuple of str
        Those that contributed to no point (broken throughout, say).
    samples_dropped : int
        Unclean samples of the policy's channels, left out.
    dropped_by_channel : dict of str -> int
        Unclean samples per policy channel.
    points : int
        Number of points (time stamps).
    points_missing_channels : int
        Points at which at least one policy channel had no clean reading
        (the others were averaged).
    points_across_gaps : int
        Points whose temperature was interpolated across a gap wider than
        ``max_gap`` (only with ``on_gap='interpolate'``).
    points_held : int
        Points outside the log, given the log's end value (only with
        ``out_of_range='hold'``).
    report : LogReport
        The log check used.
    """

    policy: str
    channels: tuple[str, ...]
    channels_used: tuple[str, ...]
    channels_excluded: tuple[str, ...]
    samples_dropped: int
    dropped_by_channel: dict[str, int]
    points: int
    points_missing_channels: int
    points_across_gaps: int
    points_held: int
    report: LogReport = field(repr=False)

    def __str__(self) -> str:
        lines = [f"policy {self.policy!r}: {self.points} points from channels {', '.join(self.channels_used) or '-'}"]
        if self.channels_excluded:
            lines.append(f"  excluded (no clean reading where needed): {', '.join(self.channels_excluded)}")
        if self.samples_dropped:
            per = ", ".join(f"{c} {n}" for c, n in self.dropped_by_channel.items() if n)
            lines.append(f"  samples dropped: {self.samples_dropped} ({per})")
        if self.points_missing_channels:
            lines.append(f"  points averaged over fewer channels: {self.points_missing_channels}")
        if self.points_across_gaps:
            lines.append(f"  points interpolated across gaps wider than {self.report.max_gap:g} s: {self.points_across_gaps}")
        if self.points_held:
            lines.append(f"  points outside the log, held at its end values: {self.points_held}")
        return "\n".join(lines)


@dataclass(frozen=True, eq=False)
class ScanTemperatures:
    """One temperature per scan, from :func:`per_scan_temperature`.

    Attributes
    ----------
    scan_id : ndarray of int, shape (S,)
        Scan ids, ascending.
    start, end : ndarray, shape (S,)
        First and last point time of each scan, s.
    temperature : ndarray, shape (S,) or (S, 3)
        Time average of the policy temperature over each scan, degrees C
        (``'per_axis'``: X, Y, Z columns).
    n_points : ndarray of int, shape (S,)
        Points per scan.
    per_point : ndarray, shape (N,) or (N, 3)
        Each point's scan temperature, degrees C, in the order of the input
        points (ready for :func:`cmmpose.compensate`).
    summary : ThermalSummary
        Channels used and samples dropped (``points``: the input points).
    scans_across_gaps : int
        Scans whose average was interpolated across a gap wider than
        ``max_gap`` (only with ``on_gap='interpolate'``).
    """

    scan_id: np.ndarray
    start: np.ndarray
    end: np.ndarray
    temperature: np.ndarray
    n_points: np.ndarray
    per_point: np.ndarray = field(repr=False)
    summary: ThermalSummary = field(repr=False)
    scans_across_gaps: int = 0

    def __str__(self) -> str:
        temp = self.temperature
        lines = [f"{'scan':>6}  {'start (s)':>10}  {'end (s)':>10}  {'points':>7}  temperature (C)"]
        for k in range(len(self.scan_id)):  # one line per scan: a text table
            tk = temp[k]
            txt = f"{tk:.3f}" if temp.ndim == 1 else "  ".join(f"{v:.3f}" for v in tk)
            lines.append(f"{self.scan_id[k]:>6}  {self.start[k]:>10.3f}  {self.end[k]:>10.3f}  {self.n_points[k]:>7}  {txt}")
        if self.scans_across_gaps:
            lines.append(f"scans averaged across gaps in the log: {self.scans_across_gaps}")
        return "\n".join(lines + [str(self.summary)])


# -- reading the log ----------------------------------------------------------------
@dataclass(frozen=True)
class _Log:
    t: np.ndarray  # (M,)
    names: tuple[str, ...]
    roles: tuple[str, ...]
    values: np.ndarray  # (M, C)


def _channel_list(channels) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """Names and roles from ``[{'name':, 'role':}, ...]`` or ``[(name, role), ...]``."""
    if isinstance(channels, (str, bytes, Mapping)) or not isinstance(channels, Sequence):
        raise InputError("channels: expected a list of {'name': ..., 'role': ...} (Run.temperature_channels) "
                         f"or of (name, role) pairs, got {type(channels).__name__}")
    if not channels:
        raise InputError("channels: empty; the log needs at least one temperature channel")
    names, roles = [], []
    for k, ch in enumerate(channels):
        if isinstance(ch, Mapping):
            name, role = ch.get("name"), ch.get("role")
        elif isinstance(ch, Sequence) and not isinstance(ch, (str, bytes)) and len(ch) == 2:
            name, role = ch
        else:
            raise InputError(f"channels[{k}]: expected {{'name': ..., 'role': ...}} or a (name, role) pair, got {ch!r}")
        if not isinstance(name, str) or not name or name == "t":
            raise InputError(f"channels[{k}]: name must be a non-empty string other than 't', got {name!r}")
        if role not in _run.CHANNEL_ROLES:
            raise InputError(f"channels[{k}]: unknown role {role!r} of channel {name!r} (allowed: {', '.join(_run.CHANNEL_ROLES)})")
        if name in names:
            raise InputError(f"channels[{k}]: duplicate channel name {name!r}")
        names.append(name)
        roles.append(role)
    return tuple(names), tuple(roles)


def _read_log(temperatures, channels) -> _Log:
    """Check and convert a log: ``t`` finite and strictly increasing, every
    channel a float column of the same length (NaN allowed: check_log reports it)."""
    if isinstance(temperatures, _run.Run):
        if temperatures.temperatures is None:
            raise InputError("run has no temperature log (no temperature channels)")
        if channels is None:
            channels = temperatures.temperature_channels
        temperatures = temperatures.temperatures
    if not isinstance(temperatures, Mapping):
        raise InputError("temperatures: expected a dict with 't' (s) and one column per channel (C), or a Run, "
                         f"got {type(temperatures).__name__}")
    if channels is None:
        raise InputError("channels: required with a dict log (list of {'name': ..., 'role': ...})")
    names, roles = _channel_list(channels)
    if "t" not in temperatures:
        raise InputError("temperatures: no time column 't' (s)")
    t = _column(temperatures["t"], "t")
    if t.shape[0] < 2:
        raise InputError(f"temperatures: column 't' has {t.shape[0]} samples; a log needs at least 2")
    bad = ~np.isfinite(t)
    if bad.any():
        r = int(np.argmax(bad))
        raise InputError(f"temperatures: column 't' is {t[r]} at row {r}; times must be finite (s)")
    back = np.diff(t) <= 0
    if back.any():
        r = int(np.argmax(back)) + 1
        raise InputError(f"temperatures: column 't' not strictly increasing at row {r} "
                         f"(t = {t[r]:g} s after {t[r - 1]:g} s)")
    missing = [n for n in names if n not in temperatures]
    if missing:
        raise InputError(f"temperatures: no column for channel {missing[0]!r} (columns: "
                         f"{', '.join(map(str, temperatures))})")
    cols = []
    for n in names:
        c = _column(temperatures[n], n)
        if c.shape != t.shape:
            raise InputError(f"temperatures: column {n!r} has {c.shape[0]} samples but 't' has {t.shape[0]}")
        cols.append(c)
    return _Log(t, names, roles, np.column_stack(cols))


def _column(values, name: str) -> np.ndarray:
    try:
        a = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"temperatures: column {name!r} cannot be read as numbers ({exc})") from None
    if a.ndim != 1:
        raise InputError(f"temperatures: column {name!r} must be 1-D, got shape {a.shape}")
    return a


def _runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start and end (inclusive) indices of the runs of True in a 1-D mask."""
    d = np.diff(np.concatenate(([0], mask.astype(np.int8), [0])))
    return np.flatnonzero(d == 1), np.flatnonzero(d == -1) - 1


def _segment_range(values: np.ndarray, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """max - min of ``values`` (M,) or (M, K) over rows starts[i]..ends[i]
    (inclusive), ignoring NaN (all NaN gives NaN)."""
    pad = np.concatenate([values, np.full((1,) + values.shape[1:], np.nan)])
    idx = np.column_stack([starts, ends + 1]).ravel()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        hi = np.fmax.reduceat(pad, idx, axis=0)[::2]
        lo = np.fmin.reduceat(pad, idx, axis=0)[::2]
    return hi - lo


def _problems_from_mask(name: str, kind: str, mask: np.ndarray, t: np.ndarray, detail) -> list[LogProblem]:
    """One problem per run of True in ``mask`` (merged into one when there
    are more than _MAX_RUNS_LISTED runs). ``detail(start_index)`` -> str."""
    starts, ends = _runs(mask)
    if not len(starts):
        return []
    if len(starts) > _MAX_RUNS_LISTED:
        return [LogProblem(name, kind, float(t[starts[0]]), float(t[ends[-1]]), int(mask.sum()), len(starts),
                           detail(int(starts[0])))]
    counts = (ends - starts + 1).tolist()
    return [LogProblem(name, kind, float(t[s]), float(t[e]), n, 1, detail(int(s)))
            for s, e, n in zip(starts.tolist(), ends.tolist(), counts)]  # one entry per run, at most 20


# -- check_log ----------------------------------------------------------------------
def check_log(
    temperatures,
    channels=None,
    *,
    plausible: tuple[float, float] = PLAUSIBLE,
    max_gap: float | None = None,
    stuck_after: float | None = STUCK_AFTER,
    stuck_tolerance: float = STUCK_TOLERANCE,
) -> LogReport:
    """Find what is wrong with a thermocouple log.

    Parameters
    ----------
    temperatures : dict of str -> array_like, or Run
        The log: ``t`` (s, finite, strictly increasing, at least 2 samples)
        and one column per channel (degrees C), as ``Run.temperatures``; or a
        ``Run`` (its log and channels).
    channels : list of dict or of (str, str) pairs
        ``{'name': str, 'role': str}`` per channel (``Run.temperature_channels``)
        or ``(name, role)`` pairs (``cmmpose.sim.CHANNELS``); roles from
        ``cmmpose.run.CHANNEL_ROLES``. Only these columns are read. Optional
        with a Run.
    plausible : tuple of 2 float
        Lowest and highest believable reading, degrees C (inclusive). Readings
        outside are implausible; at 500 C or more from zero they are reported
        as an open circuit (a logger's burn-out value such as 999.9 C).
    max_gap : float, optional
        Largest sample spacing that is not a gap, s. Default 5 times the
        median spacing.
    stuck_after : float or None
        A channel constant (to within ``stuck_tolerance``) over a window
        longer than this, s, while another channel varies by more than the
        tolerance, or exactly constant while another changes at all (or it is
        the only channel), is stuck over that window. None turns detection off.
        A logger that quantises coarsely in a very stable room reads constant
        for long stretches: raise ``stuck_after`` for such logs.
    stuck_tolerance : float
        What counts as constant, K (>= 0).

    Returns
    -------
    LogReport
        Problems per channel with their times, and the clean mask
        (finite, plausible, not stuck) per channel and sample.

    Raises
    ------
    InputError
        A malformed log: no or non-increasing ``t``, NaN times, a missing
        channel column, columns of different lengths, bad options.
    """
    log = _read_log(temperatures, channels)
    lo, hi = _pair(plausible, "plausible")
    if not lo < hi:
        raise InputError(f"plausible: expected (low, high) with low < high (C), got {plausible!r}")
    if stuck_after is not None and not (np.isfinite(stuck_after) and stuck_after > 0):
        raise InputError(f"stuck_after: expected a positive time in s or None, got {stuck_after!r}")
    if not (np.isfinite(stuck_tolerance) and stuck_tolerance >= 0):
        raise InputError(f"stuck_tolerance: expected a non-negative temperature difference in K, got {stuck_tolerance!r}")
    t, v = log.t, log.values
    dt = np.diff(t)
    median = float(np.median(dt))
    if max_gap is None:
        max_gap = GAP_FACTOR * median
    elif not (np.isfinite(max_gap) and max_gap > 0):
        raise InputError(f"max_gap: expected a positive time in s, got {max_gap!r}")
    max_gap = float(max_gap)

    problems: list[LogProblem] = []
    # gaps in time: affect every channel
    gap = dt > max_gap
    gi = np.flatnonzero(gap)
    if len(gi) > _MAX_RUNS_LISTED:
        problems.append(LogProblem("t", "gap", float(t[gi[0]]), float(t[gi[-1] + 1]), 0, len(gi),
                                   f"{len(gi)} spacings above max_gap {max_gap:g} s between {t[gi[0]]:g} and "
                                   f"{t[gi[-1] + 1]:g} s (largest {dt[gi].max():g} s)"))
    else:
        problems += [LogProblem("t", "gap", float(t[i]), float(t[i + 1]), 0, 1,
                                f"no samples from {t[i]:g} s to {t[i + 1]:g} s ({dt[i]:g} s > max_gap {max_gap:g} s)")
                     for i in gi.tolist()]  # at most 20

    finite = np.isfinite(v)
    plaus = finite & (v >= lo) & (v <= hi)
    far = finite & ~plaus & (np.abs(v) >= OPEN_CIRCUIT_ABOVE)
    stuck = _stuck(t, v, plaus, stuck_after, stuck_tolerance)
    clean = plaus & ~stuck
    clean.flags.writeable = False
    t = t.copy()
    t.flags.writeable = False

    for c, name in enumerate(log.names):
        col = v[:, c]
        problems += _problems_from_mask(name, "nan", ~finite[:, c], t,
                                        lambda s, col=col: f"reads {col[s]}")
        problems += _problems_from_mask(name, "open_circuit", far[:, c], t,
                                        lambda s, col=col: f"reads {col[s]:g} C")
        problems += _problems_from_mask(name, "implausible", finite[:, c] & ~plaus[:, c] & ~far[:, c], t,
                                        lambda s, col=col: f"reads {col[s]:g} C, outside {lo:g} to {hi:g} C")
        problems += _problems_from_mask(name, "stuck", stuck[:, c], t,
                                        lambda s, col=col: f"holds {col[s]:g} C while others vary")
    return LogReport(t, log.names, log.roles, clean, tuple(problems), max_gap, median, (lo, hi),
                     None if stuck_after is None else float(stuck_after), float(stuck_tolerance))


def _pair(value, name: str) -> tuple[float, float]:
    try:
        a, b = (float(x) for x in value)
    except (TypeError, ValueError):
        raise InputError(f"{name}: expected two numbers (low, high), got {value!r}") from None
    return a, b


def _stuck(t, v, plaus, stuck_after, tol) -> np.ndarray:
    """(M, C) mask of samples in stuck windows (see check_log)."""
    m, n = v.shape
    stuck = np.zeros((m, n), dtype=bool)
    if stuck_after is None:
        return stuck
    others_v = np.where(plaus, v, np.nan)
    for c in range(n):  # loop over channels; each is vectorised over samples
        ok = plaus[:, c]
        link = ok[1:] & ok[:-1] & (np.abs(np.diff(v[:, c])) <= tol)
        starts, ends = _runs(link)  # link runs a..b-1 cover samples a..b
        ends = ends + 1
        long = (t[ends] - t[starts]) > stuck_after
        starts, ends = starts[long], ends[long]
        if not len(starts):
            continue
        own = _segment_range(v[:, c], starts, ends)
        if n > 1:
            rest = _segment_range(np.delete(others_v, c, axis=1), starts, ends)
            with np.errstate(invalid="ignore"):
                vary = np.any(rest > tol, axis=1)
                change = np.any(rest > 0, axis=1)
        else:
            vary = np.zeros(len(starts), dtype=bool)
            change = np.ones(len(starts), dtype=bool)
        hit = (own <= tol) & (vary | ((own == 0) & change))
        starts, ends = starts[hit], ends[hit]
        if len(starts):
            mark = np.zeros(m + 1, dtype=np.int32)
            np.add.at(mark, starts, 1)
            np.add.at(mark, ends + 1, -1)
            stuck[:, c] = np.cumsum(mark[:-1]) > 0
    return stuck


# -- temperatures at time stamps ----------------------------------------------------
def _groups(policy, log: _Log) -> tuple[str, list[tuple[str, list[int]]]]:
    """(label, [(group label, channel indices)]) of a policy."""
    if not isinstance(policy, str):
        raise InputError(f"policy: expected one of {', '.join(repr(p) for p in POLICIES)}, got {policy!r}")
    if policy == "machine_mean":
        idx = [k for k, r in enumerate(log.roles) if r in AXIS_ROLES]
        if not idx:
            raise InputError("policy 'machine_mean': the log has no axis-scale channel (roles x_scale, y_scale, "
                             f"z_scale); channels: {_describe_channels(log)}")
        return policy, [("axis-scale", idx)]
    if policy == "per_axis":
        out = []
        for role in AXIS_ROLES:
            idx = [k for k, r in enumerate(log.roles) if r == role]
            if not idx:
                raise InputError(f"policy 'per_axis': the log has no channel with role {role!r}; "
                                 f"channels: {_describe_channels(log)}")
            out.append((role, idx))
        return policy, out
    if policy.startswith("role:"):
        role = policy[len("role:"):]
        idx = [k for k, r in enumerate(log.roles) if r == role]
        if not idx:
            raise InputError(f"policy {policy!r}: no channel with role {role!r}; channels: {_describe_channels(log)}")
        return policy, [(role, idx)]
    if policy.startswith("channel:"):
        name = policy[len("channel:"):]
        if name not in log.names:
            raise InputError(f"policy {policy!r}: no channel {name!r} in the log (channels: {', '.join(log.names)})")
        return policy, [(f"channel {name}", [log.names.index(name)])]
    raise InputError(f"policy: unknown policy {policy!r}; expected one of {', '.join(repr(p) for p in POLICIES)}")


def _describe_channels(log: _Log) -> str:
    return ", ".join(f"{n} ({r})" for n, r in zip(log.names, log.roles))


def _times(t, name: str = "t") -> np.ndarray:
    try:
        a = np.asarray(t, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name}: cannot be read as times in s ({exc})") from None
    if a.ndim > 1:
        raise InputError(f"{name}: expected one time stamp per point, shape (N,), got {a.shape}")
    flat = a.reshape(-1)
    bad = ~np.isfinite(flat)
    if bad.any():
        r = int(np.argmax(bad))
        raise InputError(f"{name}: row {r} is {flat[r]}; time stamps must be finite (s)")
    return a


def _check_report(report, log: _Log, temperatures, channels) -> LogReport:
    if report is None:
        return check_log(temperatures, channels)
    if not isinstance(report, LogReport):
        raise InputTypeError(f"report: expected a LogReport from check_log, got {type(report).__name__}")
    if report.channels != log.names or report.t.shape != log.t.shape or not np.array_equal(report.t, log.t):
        raise InputError("report: made from a different log (its channels or sample times differ); "
                         "call check_log on this log")
    return report


def _option(value, name: str, allowed: tuple[str, ...]) -> str:
    if value not in allowed:
        raise InputError(f"{name}: expected one of {', '.join(repr(a) for a in allowed)}, got {value!r}")
    return value


@dataclass
class _Eval:
    values: np.ndarray  # (N, G)
    used: np.ndarray  # (C_policy,) bool: channel contributed to some point
    missing: np.ndarray  # (N,) bool: some policy channel not used at the point
    bridged: np.ndarray  # (N,) bool: a value came across a gap > max_gap
    idx: list[int]  # policy channel indices, in order


def _evaluate(tq: np.ndarray, log: _Log, rep: LogReport, groups, interpolate: bool) -> tuple[_Eval, np.ndarray, list]:
    """Group temperatures at times ``tq`` (inside the log). Returns the
    evaluation, a (N,) mask of points with no usable channel in some group,
    and per group that group's mask."""
    n = tq.shape[0]
    idx = sorted({k for _, g in groups for k in g})
    vals, strict, loose, far = {}, {}, {}, {}
    # one search in the log; each channel's clean samples are a subset of its rows
    jl = np.searchsorted(log.t, tq, side="right")
    for k in idx:  # loop over channels; vectorised over points
        keep = rep.clean[:, k]
        s, y = log.t[keep], log.values[keep, k]
        if not len(s):
            vals[k] = np.full(n, np.nan)
            strict[k] = loose[k] = far[k] = np.zeros(n, dtype=bool)
            continue
        j = np.concatenate(([0], np.cumsum(keep)))[jl]  # clean samples at or before tq: s[j-1] <= tq < s[j]
        has_l, has_r = j > 0, j < len(s)
        i0, i1 = np.maximum(j - 1, 0), np.minimum(j, len(s) - 1)
        left, right = s[i0], s[i1]
        exact = has_l & (left == tq)
        inside = has_l & has_r
        span = right - left
        wide = inside & ~exact & (span > rep.max_gap)
        strict[k] = exact | (inside & ~wide)
        loose[k] = exact | inside
        far[k] = wide
        with np.errstate(invalid="ignore", divide="ignore"):
            w = np.where(inside & (span > 0), (tq - left) / span, 0.0)
        yl = y[i0]
        vals[k] = yl + w * (y[i1] - yl)  # linear in time between the clean samples around tq
    out = np.full((n, len(groups)), np.nan)
    missing = np.zeros(n, dtype=bool)
    bridged = np.zeros(n, dtype=bool)
    used = dict.fromkeys(idx, False)
    none_any = np.zeros(n, dtype=bool)
    per_group = []
    for gi, (_, g) in enumerate(groups):  # at most 3 groups
        st = np.column_stack([strict[k] for k in g])
        need = ~st.any(axis=1)
        avail = st | (np.column_stack([loose[k] for k in g]) & need[:, None]) if interpolate else st
        v = np.column_stack([vals[k] for k in g])
        cnt = avail.sum(axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            out[:, gi] = np.where(avail, v, 0.0).sum(axis=1) / cnt
        out[cnt == 0, gi] = np.nan
        missing |= (cnt < len(g)) & (cnt > 0)
        bridged |= (avail & np.column_stack([far[k] for k in g])).any(axis=1)
        for col, k in enumerate(g):
            used[k] = used[k] or bool(avail[:, col].any())
        none_any |= cnt == 0
        per_group.append(cnt == 0)
    return _Eval(out, np.array([used[k] for k in idx]), missing, bridged, idx), none_any, per_group


def _why(row: int, tq: float, log: _Log, rep: LogReport, label: str, chans: list[int],
         can_bridge: bool) -> InputError:
    """The error for a point with no usable channel of a group."""
    where = f"point row {row} (t = {tq:g} s)"
    t = log.t
    k = int(np.searchsorted(t, tq, side="right")) - 1
    if 0 <= k < len(t) - 1 and t[k] < tq and t[k + 1] - t[k] > rep.max_gap:
        return InputError(f"{where} falls in a gap of the temperature log: no samples from {t[k]:g} s to "
                          f"{t[k + 1]:g} s ({t[k + 1] - t[k]:g} s > max_gap {rep.max_gap:g} s)", row=row,
                          option="on_gap", remedy="on_gap")
    names = [log.names[c] for c in chans]
    near = [str(p) for p in rep.problems
            if p.channel in names and p.start - rep.max_gap <= tq <= p.end + rep.max_gap]
    return InputError(f"{where}: no clean {label} reading ({', '.join(names)}) within max_gap {rep.max_gap:g} s"
                      + (f" [{'; '.join(near)}]" if near else ""), row=row,
                      option="on_gap" if can_bridge else None, remedy="on_gap_stretch" if can_bridge else None)


def _all_broken(log: _Log, rep: LogReport, groups, policy: str) -> None:
    for label, g in groups:
        if not rep.clean[:, g].any():
            names = [log.names[k] for k in g]
            why = "; ".join(str(p) for p in rep.problems if p.channel in names)
            raise InputError(f"policy {policy!r}: every {label} channel is unusable ({', '.join(names)}): {why}")


def _select(t, temperatures, channels, policy, report, on_gap, out_of_range):
    """Shared body of temperatures_at and per_scan_temperature."""
    log = _read_log(temperatures, channels)
    if isinstance(temperatures, _run.Run) and channels is None:
        channels = temperatures.temperature_channels
    rep = _check_report(report, log, temperatures, channels)
    interpolate = _option(on_gap, "on_gap", ("raise", "interpolate")) == "interpolate"
    hold = _option(out_of_range, "out_of_range", ("raise", "hold")) == "hold"
    label, groups = _groups(policy, log)
    _all_broken(log, rep, groups, label)
    t = _times(t)
    tq = t.reshape(-1)
    t0, t1 = log.t[0], log.t[-1]
    outside = (tq < t0) | (tq > t1)
    tq_eff = np.clip(tq, t0, t1) if hold else tq
    ev, none_any, per_group = _evaluate(tq_eff, log, rep, groups, interpolate)
    bad = none_any | (outside & ~hold)
    if bad.any():
        r = int(np.argmax(bad))
        if outside[r] and not hold:
            raise InputError(f"point row {r} (t = {tq[r]:g} s) is outside the temperature log ({t0:g} s to {t1:g} s)"
                             + (f"; {int(outside.sum())} points in all" if outside.sum() > 1 else ""),
                             row=r, option="out_of_range", remedy="log_end_hold")
        gi = next(i for i, m in enumerate(per_group) if m[r])
        glabel, g = groups[gi]
        can_bridge = not interpolate and _bridgeable(tq_eff[r], log, rep, g)
        raise _why(r, float(tq[r]), log, rep, glabel, g, can_bridge)
    names = tuple(log.names[k] for k in ev.idx)
    dropped = {log.names[k]: int(rep.samples - rep.clean[:, k].sum()) for k in ev.idx}
    summary = ThermalSummary(
        policy=label,
        channels=names,
        channels_used=tuple(n for n, u in zip(names, ev.used) if u),
        channels_excluded=tuple(n for n, u in zip(names, ev.used) if not u),
        samples_dropped=sum(dropped.values()),
        dropped_by_channel=dropped,
        points=int(tq.shape[0]),
        points_missing_channels=int(ev.missing.sum()),
        points_across_gaps=int(ev.bridged.sum()),
        points_held=int((outside & hold).sum()),
        report=rep,
    )
    return t, ev, summary, log, rep, groups, interpolate, hold


def _bridgeable(tq: float, log: _Log, rep: LogReport, g: list[int]) -> bool:
    """Would on_gap='interpolate' give a value at ``tq`` for some channel of ``g``?"""
    for k in g:  # loop over a group's channels
        s = log.t[rep.clean[:, k]]
        if len(s) and s[0] <= tq <= s[-1]:
            return True
    return False


def temperatures_at(
    t,
    temperatures,
    channels=None,
    *,
    policy: str = "machine_mean",
    report: LogReport | None = None,
    on_gap: str = "raise",
    out_of_range: str = "raise",
):
    """Temperature at each point's time stamp from the thermocouple log.

    Each channel's clean samples (see :func:`check_log`) are interpolated
    linearly in time at the time stamps; a channel counts at a time stamp
    only if clean samples lie on both sides of it no more than ``max_gap``
    apart (or one lies exactly on it). The policy then combines the channels
    that count, point by point.

    Parameters
    ----------
    t : array_like, shape (N,)
        Time stamps of the points, s (finite, any order; same clock as the
        log's ``t``).
    temperatures : dict of str -> array_like, or Run
        The log: ``t`` (s) and one column per channel (degrees C), as
        ``Run.temperatures``; or a Run (its log and channels).
    channels : list of dict or of (str, str) pairs
        Names and roles of the log's channels, as in :func:`check_log`.
        Optional with a Run.
    policy : str
        ``'machine_mean'``: mean of the axis-scale channels (roles x_scale,
        y_scale, z_scale), the thesis's machine temperature (section 6.4).
        ``'per_axis'``: mean of each axis's scale channels, X, Y, Z columns
        (for per-carriage maps). ``'role:ROLE'``: mean of the channels of one
        thermocouple role (a broken channel dropped as for the others).
        ``'channel:NAME'``: one channel.
    report : LogReport, optional
        A :func:`check_log` report of this log (to choose its options such as
        ``max_gap``, ``plausible``, ``stuck_after``); default ``check_log``
        with its defaults.
    on_gap : {'raise', 'interpolate'}
        A point in a gap of the log wider than ``max_gap`` s, or where no
        channel of the policy has a clean reading within ``max_gap`` s,
        raises ``InputError`` naming the first such row and time; or is
        interpolated across the gap (counted in ``points_across_gaps``). With
        ``'interpolate'``, channels are bridged across a long bad stretch only
        at points where no channel of the group has a close clean reading.
    out_of_range : {'raise', 'hold'}
        A point before the first or after the last sample of the log raises
        ``InputError`` naming the first such row and time, or takes the log's
        value at that end (counted in ``points_held``).

    Returns
    -------
    temperatures : ndarray, shape (N,), or (N, 3) for 'per_axis'
        Degrees C (a 0-d ``t`` gives a 0-d or (3,) result).
    summary : ThermalSummary
        Channels used and excluded, samples dropped, points averaged over
        fewer channels, interpolated across gaps or held.

    Raises
    ------
    InputError
        A malformed log (see :func:`check_log`), NaN time stamps, an unknown
        policy or channel, a policy with no channel of its role, every
        channel of the policy broken, or a point outside the log, in a gap
        or with no clean channel (naming the row and time).
    """
    t, ev, summary, *_ = _select(t, temperatures, channels, policy, report, on_gap, out_of_range)
    out = ev.values if policy == "per_axis" else ev.values[:, 0]
    return out.reshape(t.shape + out.shape[1:]), summary


def per_scan_temperature(
    t,
    scan_id,
    temperatures,
    channels=None,
    *,
    policy: str = "machine_mean",
    report: LogReport | None = None,
    on_gap: str = "raise",
    out_of_range: str = "raise",
) -> ScanTemperatures:
    """One temperature per scan: the time average of the policy temperature
    over the scan's duration (its first to last point time).

    The policy temperature is piecewise linear between log samples, so the
    average is exact: the trapezoid rule over the scan's ends and the log
    samples inside it. A scan of one point (or zero duration) takes the
    temperature at its time.

    Parameters
    ----------
    t : array_like, shape (N,)
        Time stamps of the points, s (``run.points['t']``).
    scan_id : array_like of int, shape (N,)
        Scan of each point (``run.points['scan_id']``).
    temperatures : dict of str -> array_like, or Run
        The log (``t`` in s, channels in degrees C) or a Run.
    channels : list of dict or of (str, str) pairs
        Names and roles of the channels (optional with a Run).
    policy : str
        As in :func:`temperatures_at`.
    report : LogReport, optional
        As in :func:`temperatures_at`.
    on_gap : {'raise', 'interpolate'}
        As in :func:`temperatures_at`; also a scan whose duration spans a gap
        of the log wider than ``max_gap`` s, or a stretch with no clean
        channel between its points, raises naming the scan, unless
        ``'interpolate'``.
    out_of_range : {'raise', 'hold'}
        As in :func:`temperatures_at` (time in s outside the log).

    Returns
    -------
    ScanTemperatures
        ``scan_id``, ``start``, ``end`` (s), ``temperature`` (degrees C, (S,)
        or (S, 3) for 'per_axis'), ``n_points``, ``per_point`` ((N,) or
        (N, 3), degrees C, each point's scan value) and ``summary``.

    Raises
    ------
    InputError
        As :func:`temperatures_at`; also ``scan_id`` not integers or of a
        different length from ``t``, a scan spanning a gap.
    """
    tt = _times(t)
    if tt.ndim != 1:
        raise InputError(f"t: expected shape (N,), got {tt.shape}")
    sid = np.asarray(scan_id)
    if sid.ndim != 1:
        raise InputError(f"scan_id: expected shape (N,), got {sid.shape}")
    if sid.shape != tt.shape:
        raise InputError(f"scan_id: has {sid.shape[0]} entries but t has {tt.shape[0]}; one scan id per point")
    if sid.dtype.kind not in "iu":
        if sid.dtype.kind == "f" and np.all(np.isfinite(sid)) and np.all(sid == np.round(sid)):
            sid = sid.astype(np.int64)
        else:
            raise InputError(f"scan_id: expected integers, got dtype {sid.dtype}")
    if not len(tt):
        raise InputError("t: no points")
    tt, ev, summary, log, rep, groups, interpolate, hold = _select(tt, temperatures, channels, policy, report,
                                                                   on_gap, out_of_range)
    ids, inv, n_pts = np.unique(sid, return_inverse=True, return_counts=True)
    s = len(ids)
    a = np.full(s, np.inf)
    b = np.full(s, -np.inf)
    np.minimum.at(a, inv, tt)
    np.maximum.at(b, inv, tt)
    lt = log.t
    if hold:
        a, b = np.clip(a, lt[0], lt[-1]), np.clip(b, lt[0], lt[-1])
    # a scan spanning a gap of the log
    gaps = np.flatnonzero(np.diff(lt) > rep.max_gap)
    if len(gaps) and not interpolate:
        g0, g1 = lt[gaps], lt[gaps + 1]
        span = (g0[None, :] < b[:, None]) & (g1[None, :] > a[:, None])  # (S, gaps)
        if span.any():
            k, gk = np.unravel_index(int(np.argmax(span)), span.shape)
            raise InputError(f"scan {ids[k]} ({a[k]:g} s to {b[k]:g} s) spans a gap of the temperature log: no samples "
                             f"from {g0[gk]:g} s to {g1[gk]:g} s ({g1[gk] - g0[gk]:g} s > max_gap {rep.max_gap:g} s)",
                             option="on_gap", remedy="on_gap")
    # knots: each scan's ends and the log samples strictly inside it
    i0 = np.searchsorted(lt, a, side="right")
    i1 = np.searchsorted(lt, b, side="left")
    n_in = np.maximum(i1 - i0, 0)
    first = np.concatenate(([0], np.cumsum(n_in + 2)[:-1]))
    q = np.empty(int((n_in + 2).sum()))
    q[first] = a
    q[first + n_in + 1] = b
    seg = np.repeat(np.arange(s), n_in)
    within = np.arange(int(n_in.sum())) - np.repeat(np.cumsum(n_in) - n_in, n_in)
    q[first[seg] + 1 + within] = lt[i0[seg] + within]
    kev, none_any, _ = _evaluate(q, log, rep, groups, interpolate)
    if none_any.any():
        j = int(np.argmax(none_any))
        k = int(np.searchsorted(first, j, side="right")) - 1
        raise InputError(f"scan {ids[k]} ({a[k]:g} s to {b[k]:g} s): no clean channel for policy {policy!r} at "
                         f"{q[j]:g} s inside the scan", option="on_gap", remedy="on_gap")
    y = kev.values  # (K, G)
    owner = np.repeat(np.arange(s), n_in + 2)
    dq = np.diff(q)
    area = 0.5 * (y[1:] + y[:-1]) * dq[:, None]
    same = owner[1:] == owner[:-1]
    integral = np.zeros((s, y.shape[1]))
    np.add.at(integral, owner[1:][same], area[same])
    dur = b - a
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(dur[:, None] > 0, integral / np.where(dur > 0, dur, 1.0)[:, None], y[first])
    temp = mean if policy == "per_axis" else mean[:, 0]
    per_point = temp[inv]
    across = np.zeros(s, dtype=bool)
    np.logical_or.at(across, owner, kev.bridged)
    if len(gaps):
        across |= ((lt[gaps][None, :] < b[:, None]) & (lt[gaps + 1][None, :] > a[:, None])).any(axis=1)
    for arr in (ids, a, b, temp, n_pts, per_point):
        arr.flags.writeable = False
    return ScanTemperatures(ids, a, b, temp, n_pts, per_point, summary, int(across.sum()))




# -- a run's temperatures under a policy --------------------------------------------
def _policy_channels(channels, policy: TemperaturePolicy) -> tuple[list[dict], dict[str, dict]]:
    """The run's channels with the roles the policy's ``sensors`` give them,
    and for each channel whose role changed: its role in the log and the one read."""
    out = [{"name": c.get("name"), "role": c.get("role")} for c in channels]
    names = [c["name"] for c in out]
    moved: dict[str, dict] = {}
    for role, chosen in policy.sensors:
        missing = [n for n in chosen if n not in names]
        if missing:
            raise InputError(f"sensors: role {role!r} names channel {missing[0]!r}, not in the log "
                             f"(channels: {', '.join(names)})")
        for c in out:
            if c["name"] in chosen and c["role"] != role:
                moved.setdefault(c["name"], {"log_role": c["role"]})["read_as"] = role
                c["role"] = role
            elif c["role"] == role and c["name"] not in chosen:
                moved.setdefault(c["name"], {"log_role": role})["read_as"] = None
                c["role"] = None
    return [c for c in out if c["role"] is not None], moved


def _check_broken(rep: LogReport, channels: list[dict], roles, policy: TemperaturePolicy) -> None:
    if policy.broken_channels != "raise":
        return
    read = [c["name"] for c in channels if c["role"] in roles]
    bad = [p for p in rep.problems if p.channel in read and p.kind != "gap"]
    if bad:
        name = bad[0].channel
        raise InputError(f"thermocouple {name}: broken ({'; '.join(str(p) for p in bad if p.channel == name)})",
                         option="broken_channels", remedy="broken_channels")


def _log_of(run: Run, policy: TemperaturePolicy, t) -> tuple[list[dict], dict, LogReport]:
    if not isinstance(run, _run.Run):
        raise InputTypeError(f"run: expected a cmmpose.Run, got {type(run).__name__}")
    if run.temperatures is None:
        raise InputError("run has no temperature log", option="temperature", remedy="temperature_explicit")
    check_log_coverage(run, t, policy.log_hold)
    channels, moved = _policy_channels(run.temperature_channels, policy)
    rep = check_log(run.temperatures, channels, max_gap=policy.max_gap)
    return channels, moved, rep


def run_temperatures(run: Run, t, temperature_policy: TemperaturePolicy | None = None, *,
                     log_hold: float | None = None) -> tuple[np.ndarray, dict]:
    """The machine temperature of a run at times ``t`` (the mean of the clean
    axis-scale thermocouples, thesis 6.4) under a policy, and its provenance.

    Parameters
    ----------
    run : Run
        A run with a thermocouple log.
    t : array_like
        Times, s (``run.points['t']``).
    temperature_policy : TemperaturePolicy, optional
        Default :data:`DEFAULT_POLICY`.
    log_hold : float, optional
        s: overrides the policy's ``log_hold``.

    Returns
    -------
    temperatures : ndarray
        Degrees C, the shape of ``t``.
    log : dict
        JSON-ready provenance (:func:`log_provenance`): channels used, each
        channel dropped (role, why, how many samples, what was done), the
        points held past the log's ends and for how many seconds, the
        channels each axis role read, points interpolated across gaps and
        the log side of the policy.

    Raises
    ------
    InputError
        No log, a point beyond ``log_hold``, a gap (``on_gap='raise'``), a
        broken channel (``broken_channels='raise'``), a sensor naming a
        channel the log lacks.
    """
    policy = as_policy(temperature_policy, log_hold=log_hold)
    t = np.asarray(t, dtype=float)
    channels, moved, rep = _log_of(run, policy, t)
    _check_broken(rep, channels, AXIS_ROLES, policy)
    # Points of a profile share a time stamp: interpolate the log once per time.
    ut, inv = np.unique(t, return_inverse=True)
    temps, summary = temperatures_at(ut, run.temperatures, channels, policy="machine_mean", report=rep,
                                     on_gap=policy.on_gap, out_of_range="hold")
    log_t = np.asarray(run.temperatures["t"], float)
    prov = log_provenance({"the machine temperature": summary}, t, log_t, policy=policy, channels=channels,
                          moved=moved, roles=AXIS_ROLES)
    return temps[inv].reshape(np.shape(t)), prov


@dataclass(frozen=True, eq=False)
class SensorTemperatures:
    """A run's temperatures as the diagnosis reads them, from
    :func:`run_sensor_temperatures`.

    Attributes
    ----------
    temperature : ndarray (N,)
        Machine mean at each time, C.
    axis_temperature : ndarray (N, 3) or None
        Mean of each axis's scale channels, C (None without all three roles).
    gradient : ndarray (N,) or None
        Granite top minus bottom, K, running mean over ``GRADIENT_WINDOW``.
    sensors : dict of str -> ndarray (N,)
        Each role of the log -> the machine mean plus the role's departure
        from it (running mean over ``GRADIENT_WINDOW``), C.
    provenance : dict
        As :func:`run_temperatures`'s, over every role read, plus
        ``roles_left_out`` (role -> why).
    """

    temperature: np.ndarray
    axis_temperature: np.ndarray | None
    gradient: np.ndarray | None
    sensors: dict
    provenance: dict


def _running_mean(t: np.ndarray, y: np.ndarray, window: float) -> np.ndarray:
    """Mean of y over [t - window/2, t + window/2] at every t (sorted t)."""
    c = np.concatenate([[0.0], np.cumsum(y)])
    lo = np.searchsorted(t, t - window / 2, side="left")
    hi = np.searchsorted(t, t + window / 2, side="right")
    return (c[hi] - c[lo]) / (hi - lo)


def run_sensor_temperatures(run: Run, t, temperature_policy: TemperaturePolicy | None = None) -> SensorTemperatures:
    """Every temperature the diagnosis reads of a run at times ``t``: the
    machine mean, each axis's scale temperature, the granite gradient and
    each thermocouple role, under a policy, with the provenance.

    A role whose channels are all broken (or that the policy cannot read
    where needed) is left out and named in ``provenance['roles_left_out']``;
    the machine mean must be readable.

    Parameters
    ----------
    run : Run
        A run with a thermocouple log.
    t : array_like, shape (N,)
        Times, s.
    temperature_policy : TemperaturePolicy, optional
        Default :data:`DEFAULT_POLICY`.
    """
    policy = as_policy(temperature_policy)
    t = np.asarray(t, dtype=float)
    channels, moved, rep = _log_of(run, policy, t)
    roles = tuple(dict.fromkeys(c["role"] for c in channels if c["role"]))
    _check_broken(rep, channels, roles, policy)
    log = run.temperatures
    ut, inv = np.unique(t, return_inverse=True)
    kw = {"report": rep, "on_gap": policy.on_gap, "out_of_range": "hold"}
    temps, machine = temperatures_at(ut, log, channels, policy="machine_mean", **kw)
    summaries = {"the machine temperature": machine}
    temps = temps[inv]
    axis_t = gradient = None
    if all(r in roles for r in AXIS_ROLES):
        axis_t = temperatures_at(ut, log, channels, policy="per_axis", **kw)[0][inv]
    tlog = np.asarray(log["t"], dtype=float)
    mean_log = temperatures_at(tlog, log, channels, policy="machine_mean", **kw)[0]
    logs: dict[str, np.ndarray] = {}
    sensors: dict[str, np.ndarray] = {}
    left_out: dict[str, str] = {}
    for role in roles:
        try:
            role_log, summaries[f"role {role}"] = temperatures_at(tlog, log, channels, policy=f"role:{role}", **kw)
        except InputError as e:  # every channel of the role broken: the role is not offered
            left_out[role] = str(e)
            continue
        logs[role] = role_log
        # A sensor's departure from the mean changes over minutes; its
        # per-sample noise (0.02 K) would otherwise move each profile
        # on its own and masquerade as sphere-form structure.
        departure = _running_mean(tlog, role_log - mean_log, GRADIENT_WINDOW)
        sensors[role] = np.ascontiguousarray(temps + np.interp(ut, tlog, departure)[inv], dtype=float)
    if "granite_top" in logs and "granite_bottom" in logs:
        # The granite's gradient changes over hours, so the noise of the two
        # groups is averaged out over GRADIENT_WINDOW first (0.02 K of noise
        # times 15 arc-second/K is 1 um at 0.7 m).
        g = _running_mean(tlog, logs["granite_top"] - logs["granite_bottom"], GRADIENT_WINDOW)
        gradient = np.interp(ut, tlog, g)[inv]
    prov = log_provenance(summaries, t, tlog, policy=policy, channels=channels, moved=moved, roles=roles)
    prov["roles_left_out"] = left_out
    return SensorTemperatures(temps, axis_t, gradient, sensors, prov)


def log_provenance(summaries, t, log_t, *, policy: TemperaturePolicy | None = None, channels=None,
                   moved: dict | None = None, roles=AXIS_ROLES) -> dict:
    """The provenance of temperatures taken from a thermocouple log.

    Parameters
    ----------
    summaries : ThermalSummary or dict of str -> ThermalSummary
        From :func:`temperatures_at`, by what each gave (``'the machine
        temperature'``, ``'role mount'``); one summary is the machine
        temperature's.
    t : ndarray
        The points' time stamps, s.
    log_t : ndarray
        The log's sample times, s.
    policy : TemperaturePolicy, optional
        The policy used (its log side is recorded).
    channels : list of dict, optional
        The channels with the roles read (default the summaries' report's).
    moved : dict, optional
        Channels whose role the policy changed (channel -> ``log_role``, ``read_as``).
    roles : sequence of str
        The roles whose channels are listed in ``sensors``.

    Returns
    -------
    dict
        ``channels_used``; ``channels_dropped``: each channel with unclean
        samples (``channel``, ``role``, ``why`` (constant, open circuit,
        out of the plausible range, NaN), ``samples_dropped`` of
        ``samples``, ``problems``, ``action``); ``held``: the points outside
        the log (``points``, ``before_log_s``, ``after_log_s``, ``max_s``,
        ``log_hold_s``, ``action``) or None; ``points_across_gaps``;
        ``sensors``: role -> ``read`` (channels that gave a reading) and
        ``left_out`` (channels of the role that gave none); ``moved``;
        ``policy`` (the log side of the policy).
    """
    if isinstance(summaries, ThermalSummary):
        summaries = {"the machine temperature": summaries}
    policy = DEFAULT_POLICY if policy is None else policy
    first = next(iter(summaries.values()))
    report = first.report
    role_of = dict(zip(report.channels, report.roles)) if channels is None else \
        {c["name"]: c["role"] for c in channels}
    dropped, seen = [], set()
    used: list[str] = []
    for what, summary in summaries.items():
        used += [c for c in summary.channels_used if c not in used]
        for channel in summary.channels:
            n = int(summary.dropped_by_channel.get(channel, 0))
            entirely = channel in summary.channels_excluded
            if channel in seen or (not n and not entirely):
                continue
            seen.add(channel)
            problems = report.problems_of(channel)
            dropped.append({
                "channel": channel, "role": role_of.get(channel),
                "why": sorted({_WHY[p.kind] for p in problems if p.kind in _WHY}),
                "samples_dropped": n, "samples": int(report.samples),
                "problems": [str(p) for p in problems],
                "action": (f"left out of {what} entirely" if entirely else
                           f"left out where unclean ({n} of {report.samples} samples); the other channels "
                           "averaged there"),
            })
    held = None
    t = np.asarray(t, dtype=float).ravel()
    if len(t) and len(log_t):
        before, after = t < log_t.min(), t > log_t.max()
        if before.any() or after.any():
            b = round(float(log_t.min() - t.min()), 3) if before.any() else 0.0
            a = round(float(t.max() - log_t.max()), 3) if after.any() else 0.0
            held = {"points": int(before.sum() + after.sum()), "before_log_s": b, "after_log_s": a,
                    "max_s": max(a, b), "log_hold_s": policy.log_hold,
                    "action": "held at the log's first or last reading"}
    sensors = {}
    for role in roles:
        names = [n for n, r in role_of.items() if r == role]
        if names:
            sensors[role] = {"read": [n for n in names if n in used],
                             "left_out": [n for n in names if n not in used]}
    return {"channels_used": used, "channels_dropped": dropped, "held": held,
            "points_across_gaps": int(first.points_across_gaps),
            "sensors": sensors, "moved": dict(moved or {}), "policy": policy.log_dict()}


def log_notes(log: dict) -> list[str]:
    """One line per dropped channel, for held points, for points interpolated
    across gaps and for the channels each role read (when a channel was
    dropped or the policy chose them), for a printed result's notes."""
    notes = [f"thermocouple {d['channel']}{' (' + d['role'] + ')' if d.get('role') else ''}: {d['action']} "
             f"({'; '.join(d['problems']) or 'unclean samples'})"
             for d in log.get("channels_dropped", [])]
    held = log.get("held")
    if held:
        span = " and ".join(f"{held[k]:g} s {side}" for k, side in (("before_log_s", "before its first sample"),
                                                                    ("after_log_s", "after its last sample"))
                            if held[k])
        notes.append(f"the temperature log does not cover {held['points']} points (up to {span}): "
                     f"they took its nearest reading (held; at most {held.get('log_hold_s', LOG_HOLD):g} s allowed)")
    if log.get("points_across_gaps"):
        notes.append(f"{log['points_across_gaps']} points took temperatures interpolated across gaps of the "
                     "temperature log")
    for name, m in log.get("moved", {}).items():
        notes.append(f"thermocouple {name}: logged as {m['log_role']}, "
                     + (f"read as {m['read_as']}" if m["read_as"] else "not read") + " (the policy's sensors)")
    if log.get("channels_dropped") or log.get("moved"):
        read = "; ".join(f"{role} {', '.join(s['read']) or 'none'}" for role, s in log.get("sensors", {}).items())
        if read:
            notes.append(f"thermocouples read: {read}")
    for role, why in log.get("roles_left_out", {}).items():
        notes.append(f"thermocouple role {role}: left out ({why})")
    return notes
