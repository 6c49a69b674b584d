"""The acquisition plan: what the serial streams do not carry. The scanner's
records name their sweep by number; the plan says what each sweep measured
(pose, feature, artefact position, ball) and which thermocouple channel is
which. A plan is a JSON file (docs/protocols.md, "Plan")::

    {
      "artefact": {"kind": "ballbar", ...},
      "maps": {"kind": "bundled", "name": "thesis"},
      "metadata": {},
      "poses": [{"pose_id": 0, "alpha": 90, "beta": 90, "gamma": 0, "U1": 1.001, "V1": 264.505, "W1": 129.575}],
      "scans": [{"scan_id": 0, "pose_id": 0, "feature": "ball", "position": 1, "ball": 1,
                 "sweep_axis": "X", "sweep_direction": 1, "sweep_speed": 35.0}],
      "temperature_channels": [{"name": "X1", "role": "x_scale", "channel": 101}, ...]
    }

A plan for an artefact run (a ball plate or step gauge at one or more
placements; docs/artefacts.md) is made by :func:`artefact_plan` (``cmmpose
artefact plan``): its ``artefact`` embeds the artefact's definition and the
resolved placements as a simulated run's does, and each scan row says which
ball of which placement it measures with which pose, and the sweep: its axis,
direction and speed, and, for the operator or the part program, the scale
readings it starts from (``sweep_start_mm``, D, E, F) and its length
(``sweep_length_mm``). A plan whose scans name a ball the artefact lacks or
a placement it does not record is refused when read.

Every plan is checked completely when it is read, before a port is opened,
so that a recording is never made that cannot become a run: each scan's pose
exists (without ``poses``: pose 0), pose and scan ids are unique, sweep axes
and directions are those a run allows, channel names and multiplexer channel
numbers are unique (two thermocouples on one channel would log the same
readings twice), and the whole plan is storable as JSON. Errors name the
plan file and the scan, pose or channel at fault.

Every key is optional. Without ``poses`` one pose is used (the thesis
digitizer unless given); a sweep missing from ``scans`` gets that pose,
feature ``unknown``, position and ball -1, and its sweep axis, direction and
speed estimated from its scale readings. Without ``temperature_channels`` the
thesis's 11 thermocouples on channels 101..111.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

from .. import artefacts, placement
from ..atomicfile import write_text
from ..errors import AcquisitionError, InputError, MissingFileError, read_input_text
from ..machine import CHANNELS
from ..schemas import loads_json, validate
from ..schemas import short
from ..run import CHANNEL_ROLES, POSES_COLUMNS, SCANS_COLUMNS, Run
from ..schemas.run import SWEEP_AXES

__all__ = ["Plan", "DEFAULT_CHANNELS", "plan_from_run", "artefact_plan"]

#: The thesis's thermocouples (name, role), in log order (cmmpose.machine.CHANNELS).
DEFAULT_CHANNELS = CHANNELS
_KEYS = ("artefact", "maps", "metadata", "poses", "scans", "temperature_channels")


@dataclass
class Plan:
    """What the streams do not say; see the module docstring.

    Attributes
    ----------
    artefact, maps, metadata : dict
        Copied into run.json.
    poses : list of dict
        Rows of the poses table (degrees, mm).
    scans : list of dict
        Rows of the scans table, keyed by the scanner's sweep number ``scan_id``.
    temperature_channels : list of dict
        ``name``, ``role`` and multiplexer ``channel`` (e.g. 101), in scan order.
    """

    artefact: dict = field(default_factory=dict)
    maps: dict = field(default_factory=dict)
    metadata: dict = field(default_factory=dict)
    poses: list = field(default_factory=list)
    scans: list = field(default_factory=list)
    temperature_channels: list = field(default_factory=list)
    #: Whether the channels are the defaults (the plan listed none): a machine file's may replace them.
    channels_defaulted: bool = field(default=False, repr=False, compare=False)

    def __post_init__(self):
        # Every type checked now, not when the run is assembled after the
        # whole recording.
        for name in ("artefact", "maps", "metadata"):
            if not isinstance(getattr(self, name), dict):
                raise AcquisitionError(f"plan: {name}: expected a JSON object, got {type(getattr(self, name)).__name__}")
        for name in ("poses", "scans", "temperature_channels"):
            if not isinstance(getattr(self, name), list):
                raise AcquisitionError(f"plan: {name}: expected a list, got {type(getattr(self, name)).__name__}")
        for name, spec in (("poses", POSES_COLUMNS), ("scans", SCANS_COLUMNS)):
            for k, row in enumerate(getattr(self, name)):
                if not isinstance(row, dict):
                    raise AcquisitionError(f"plan: {name}[{k}]: expected an object, got {type(row).__name__}")
                for c, dt in spec.items():
                    if c in row and not _fits(row[c], dt):
                        raise AcquisitionError(f"plan: {name}[{k}]: {c} = {_shown(row[c])} is not "
                                               f"{'a string' if dt == 'str' else f'an integer that fits its {dt} column' if dt != 'float64' else 'a finite number'}")
        if not self.temperature_channels:
            self.channels_defaulted = True
            self.temperature_channels = [{"name": n, "role": r, "channel": 101 + k} for k, (n, r) in enumerate(DEFAULT_CHANNELS)]
        for k, ch in enumerate(self.temperature_channels):
            if not isinstance(ch, dict) or "name" not in ch or ch.get("role") not in CHANNEL_ROLES:
                raise AcquisitionError(f"plan: temperature_channels[{k}]: needs 'name' and a 'role' of {', '.join(CHANNEL_ROLES)}")
            ch.setdefault("channel", 101 + k)
            if not isinstance(ch["name"], str) or not _fits(ch["channel"], "int32"):
                raise AcquisitionError(f"plan: temperature_channels[{k}]: 'name' must be a string and 'channel' an "
                                       f"integer, got {_shown(ch['name'])}, {_shown(ch['channel'])}")
        for k, p in enumerate(self.poses):
            missing = [c for c in POSES_COLUMNS if c not in p]
            if missing:
                raise AcquisitionError(f"plan: poses[{k}]: missing {missing[0]!r}")
        for k, s in enumerate(self.scans):
            missing = [c for c in SCANS_COLUMNS if c not in s]
            if missing:
                raise AcquisitionError(f"plan: scans[{k}]: missing {missing[0]!r}")
        seen: dict[int, int] = {}
        for k, s in enumerate(self.scans):
            if int(s["scan_id"]) in seen:
                raise AcquisitionError(f"plan: scans[{k}]: scan_id {s['scan_id']} is also scans[{seen[int(s['scan_id'])]}]")
            seen[int(s["scan_id"])] = k
        self._check_references()
        self._check_artefact()
        try:
            json.dumps(self.to_dict(), allow_nan=False)
        except (TypeError, ValueError) as exc:
            raise AcquisitionError(f"plan: not storable as JSON ({exc})") from None

    def _check_references(self) -> None:
        """Everything the run's tables will require of the plan, checked when it
        is read (not when the run is assembled after the recording): unique pose
        ids, every scan's pose among them, sweep axes and directions the run
        allows, unique channel names and multiplexer channel numbers."""
        poses: dict[int, int] = {}
        for k, p in enumerate(self.poses):
            pid = int(p["pose_id"])
            if pid in poses:
                raise AcquisitionError(f"plan: poses[{k}]: pose_id {pid} is also poses[{poses[pid]}]")
            poses[pid] = k
        for k, s in enumerate(self.scans):
            what = f"plan: scans[{k}] (scan_id {s['scan_id']})"
            pid = int(s["pose_id"])
            if poses and pid not in poses:
                raise AcquisitionError(f"{what}: pose_id {pid} is not a pose of the plan (poses: "
                                       f"{', '.join(str(i) for i in sorted(poses))})")
            if not poses and pid != 0:
                raise AcquisitionError(f"{what}: pose_id {pid}, but the plan lists no poses (the one pose used "
                                       f"then is pose_id 0)")
            if s["sweep_axis"] not in SWEEP_AXES:
                raise AcquisitionError(f"{what}: sweep_axis {s['sweep_axis']!r} is not one of {', '.join(SWEEP_AXES)}")
            if s["sweep_direction"] not in (1, -1):
                raise AcquisitionError(f"{what}: sweep_direction {s['sweep_direction']!r} is not +1 or -1")
        names: dict[str, int] = {}
        numbers: dict[int, int] = {}
        for k, ch in enumerate(self.temperature_channels):
            what = f"plan: temperature_channels[{k}]"
            name, number = ch["name"], int(ch["channel"])
            if not name or name == "t":
                raise AcquisitionError(f"{what}: name {name!r} is not allowed (empty, or the time column 't')")
            if name in names:
                raise AcquisitionError(f"{what}: name {name!r} is also temperature_channels[{names[name]}]")
            if number <= 0:
                raise AcquisitionError(f"{what}: channel {number} of {name!r} is not a multiplexer channel number "
                                       f"(slot * 100 + channel, e.g. 101)")
            if number in numbers:
                other = numbers[number]
                raise AcquisitionError(f"{what}: {name!r} on channel {number}, which is also "
                                       f"{self.temperature_channels[other]['name']!r} "
                                       f"(temperature_channels[{other}]); each thermocouple needs its own channel")
            names[name], numbers[number] = k, k

    def _check_artefact(self) -> None:
        """An artefact plan's scans against its artefact and placements."""
        definition = self.artefact.get("definition")
        if definition is None:
            return
        try:
            art = artefacts.from_dict(definition, "plan: artefact.definition")
        except InputError as exc:
            raise AcquisitionError(str(exc)) from None
        recorded = self.artefact.get("placements")
        n = len(recorded) if isinstance(recorded, list) else 0
        ids = set(art.ids.tolist())
        for k, s in enumerate(self.scans):
            if s["feature"] != "ball":
                continue
            if not 1 <= int(s["position"]) <= n:
                raise AcquisitionError(f"plan: scans[{k}]: position {s['position']} is not one of the artefact's "
                                       f"{n} placements (1..{n})")
            if int(s["ball"]) not in ids:
                raise AcquisitionError(f"plan: scans[{k}]: ball {s['ball']} is not a ball of {art.name} "
                                       f"(balls {min(ids)}..{max(ids)})")

    @property
    def channels(self) -> list[tuple[str, int]]:
        """(name, multiplexer channel) in scan order."""
        return [(ch["name"], int(ch["channel"])) for ch in self.temperature_channels]

    @classmethod
    def read(cls, path) -> Plan:
        """Read a plan JSON file (errors name the file).

        The one door in (issue 35): the file is read as a regular file only
        (a FIFO or a device is refused at once, its size bounded), a key
        repeated in one object is refused, the plan is checked in its own
        words (:class:`Plan`) and then validated against its schema
        (:mod:`cmmpose.schemas.plan`: every key typed, every number within
        its range, the file and the key named)."""
        path = Path(path)
        try:
            text = read_input_text(path, "plan", error=AcquisitionError)
        except MissingFileError as exc:
            raise AcquisitionError(f"{path}: not a readable plan ({exc})", file=str(path)) from None
        doc = loads_json(text, path, "plan", error=AcquisitionError)
        if not isinstance(doc, dict):
            raise AcquisitionError(f"{path}: a plan is a JSON object")
        extra = [k for k in doc if k not in _KEYS]
        if extra:
            raise AcquisitionError(f"{path}: unknown key {extra[0]!r} (allowed: {', '.join(_KEYS)})")
        try:
            plan = cls(**doc)
        except AcquisitionError as exc:
            raise AcquisitionError(f"{path}: {exc}") from None
        validate(doc, "plan", path, error=AcquisitionError)
        return plan

    def with_machine_channels(self, machine) -> Plan:
        """This plan, or where it lists no thermocouple channels, a copy with
        the machine file's thermocouples (in the file's order, on multiplexer
        channels 101, 102, ...), checked as a plan file's channels are.

        Parameters
        ----------
        machine : cmmpose.machine.Machine
            The machine file's contents (its ``thermocouples``: name -> role).
        """
        if not self.channels_defaulted:
            return self
        doc = self.to_dict()
        doc["temperature_channels"] = [{"name": name, "role": role, "channel": 101 + k}
                                       for k, (name, role) in enumerate(machine.thermocouples.items())]
        return type(self)(**doc)

    def write(self, path) -> None:
        """Write as JSON (atomically, :mod:`cmmpose.atomicfile`)."""
        doc = {k: getattr(self, k) for k in _KEYS}
        write_text(path, json.dumps(doc, indent=2, allow_nan=False) + "\n")

    def to_dict(self) -> dict:
        """JSON-ready dict."""
        return {k: getattr(self, k) for k in _KEYS}


def _shown(value) -> str:
    """``value`` as a message shows it: its repr, a long integer by its size (never 400 digits echoed)."""
    return short(value) if isinstance(value, int) and not isinstance(value, bool) else repr(value)


#: The range of each integer column type of a run.
_INT_RANGES = {"int8": (-(2**7), 2**7 - 1), "int32": (-(2**31), 2**31 - 1), "int64": (-(2**63), 2**63 - 1)}


def _fits(value, dtype: str) -> bool:
    """Whether a JSON value is of a run column's type (booleans are not numbers; an integer within its
    column's range, never converted through a float: a 400-digit id is refused, not an OverflowError)."""
    if dtype == "str":
        return isinstance(value, str)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    if dtype == "float64":
        try:
            return math.isfinite(value)
        except OverflowError:  # an integer beyond any float
            return False
    if isinstance(value, float) and not (math.isfinite(value) and value.is_integer()):
        return False
    lo, hi = _INT_RANGES.get(dtype, _INT_RANGES["int64"])
    return lo <= value <= hi


def plan_from_run(run: Run) -> Plan:
    """The plan that describes ``run``: its scans, poses, channels, artefact and maps.

    Parameters
    ----------
    run : Run
        E.g. a simulated run to be played through simulated instruments.
    """
    def rows(table, spec):
        n = len(table[next(iter(spec))])
        return [{c: (table[c][i].item() if hasattr(table[c][i], "item") else table[c][i]) for c in spec} for i in range(n)]

    return Plan(
        artefact=dict(run.artefact), maps=dict(run.maps), metadata={"plan_from": "run"},
        poses=rows(run.poses, POSES_COLUMNS), scans=rows(run.scans, SCANS_COLUMNS),
        temperature_channels=[{"name": ch["name"], "role": ch["role"], "channel": 101 + k}
                              for k, ch in enumerate(run.temperature_channels)],
    )


def artefact_plan(artefact, placements, machine=None, *, speed: float = 35.0, bidirectional: bool = False,
                  maps: dict | None = None, metadata: dict | None = None, repeat_scans: int = 0) -> Plan:
    """The plan of an artefact run: every ball of every placement, the pose
    that scans it and its sweep, as ``cmmpose.sim.artefact_runs`` scans it.

    Parameters
    ----------
    artefact : cmmpose.artefacts.Artefact or str
        The artefact (or a file or bundled example name).
    placements : sequence of str or cmmpose.placement.Placement
        Where it sits (shorthands or layout names; docs/artefacts.md).
    machine : cmmpose.machine.Machine, optional
        Travel, pose, mount offset and scanner; default the thesis machine.
    speed : float
        Sweep speed, mm/s (balls too small for PROFILES_PER_BALL profiles
        at this speed are swept more slowly).
    bidirectional : bool
        Alternate the sweep direction from ball to ball.
    maps : dict, optional
        run.json's ``maps``; default what the machine's ``maps_record``
        says (its bundled maps, so that the recorded run evaluates with them).
    metadata : dict, optional
        Copied into run.json.
    repeat_scans : int
        Scans repeated at the end, the artefact not moved: the first
        ``repeat_scans`` balls' scans again (same pose and sweep), so the
        recorded run measures its own per-scan reproducibility, the
        diagnosis's noise floor (docs/diagnosis.md). 0: each ball once.

    Returns
    -------
    Plan

    Raises
    ------
    InputError
        A placement out of reach (naming the ball and the axis), bad speed.
    """
    from ..machine import Machine

    machine = Machine.thesis() if machine is None else machine
    if isinstance(artefact, str):
        artefact = artefacts.load_artefact(artefact)
    if not (isinstance(speed, (int, float)) and math.isfinite(speed) and speed > 0):
        raise InputError(f"speed: must be > 0 mm/s, got {speed!r}")
    if not placements:
        raise InputError("placements: none given")
    parsed = []
    for p in placements:
        parsed += placement.parse(p, machine.travel) if isinstance(p, str) else [p]
    resolved, balls = placement.plan(parsed, artefact, machine)
    repeat_scans = placement.check_repeat_scans(repeat_scans, len(balls))
    balls = list(balls) + list(balls)[:repeat_scans]
    offset = tuple(float(x) for x in machine.offset)
    pose_ids: dict[tuple, int] = {}
    scans = []
    v = placement.ball_speed(speed, artefact.nominal_radius, machine.scanner.profile_rate)
    for scan_id, b in enumerate(balls):
        pid = pose_ids.setdefault(b.pose, len(pose_ids))
        direction = -1 if bidirectional and scan_id % 2 else 1
        sw = placement.sweep_of(b.centre, b.pose, offset, artefact.calibrated_radius, direction)
        scans.append({"scan_id": scan_id, "pose_id": pid, "feature": "ball", "position": b.position, "ball": b.ball,
                      "sweep_axis": sw.axis, "sweep_direction": direction, "sweep_speed": v,
                      "sweep_start_mm": [round(x, 4) for x in sw.start], "sweep_length_mm": round(sw.length, 4)})
    poses = [{"pose_id": i, "alpha": p[0], "beta": p[1], "gamma": p[2], "U1": offset[0], "V1": offset[1],
              "W1": offset[2]} for p, i in pose_ids.items()]
    return Plan(artefact=placement.run_record(artefact, resolved),
                maps=machine.maps_record() if maps is None else dict(maps),
                metadata={"plan_from": "artefact", "machine": machine.name,
                          **({"repeat_scans": int(repeat_scans)} if repeat_scans else {}), **(metadata or {})},
                poses=poses, scans=scans)
