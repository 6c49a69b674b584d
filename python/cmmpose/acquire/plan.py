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

from ..atomicfile import write_text
from ..errors import AcquisitionError
from ..run import CHANNEL_ROLES, POSES_COLUMNS, SCANS_COLUMNS, Run

__all__ = ["Plan", "DEFAULT_CHANNELS", "plan_from_run"]

#: The thesis's thermocouples (name, role, multiplexer channel).
DEFAULT_CHANNELS = (
    ("X1", "x_scale"), ("X2", "x_scale"), ("X3", "x_scale"),
    ("Y1", "y_scale"), ("Y2", "y_scale"), ("Y3", "y_scale"),
    ("Z1", "z_scale"), ("Z2", "z_scale"), ("Z3", "z_scale"),
    ("GT", "granite_top"), ("GB", "granite_bottom"),
)  # fmt: skip
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
                        raise AcquisitionError(f"plan: {name}[{k}]: {c} = {row[c]!r} is not "
                                               f"{'a string' if dt == 'str' else 'an integer' if dt != 'float64' else 'a finite number'}")
        if not self.temperature_channels:
            self.temperature_channels = [{"name": n, "role": r, "channel": 101 + k} for k, (n, r) in enumerate(DEFAULT_CHANNELS)]
        for k, ch in enumerate(self.temperature_channels):
            if not isinstance(ch, dict) or "name" not in ch or ch.get("role") not in CHANNEL_ROLES:
                raise AcquisitionError(f"plan: temperature_channels[{k}]: needs 'name' and a 'role' of {', '.join(CHANNEL_ROLES)}")
            ch.setdefault("channel", 101 + k)
            if not isinstance(ch["name"], str) or not _fits(ch["channel"], "int32"):
                raise AcquisitionError(f"plan: temperature_channels[{k}]: 'name' must be a string and 'channel' an "
                                       f"integer, got {ch['name']!r}, {ch['channel']!r}")
        for k, p in enumerate(self.poses):
            missing = [c for c in POSES_COLUMNS if c not in p]
            if missing:
                raise AcquisitionError(f"plan: poses[{k}]: missing {missing[0]!r}")
        for k, s in enumerate(self.scans):
            missing = [c for c in SCANS_COLUMNS if c not in s]
            if missing:
                raise AcquisitionError(f"plan: scans[{k}]: missing {missing[0]!r}")

    @property
    def channels(self) -> list[tuple[str, int]]:
        """(name, multiplexer channel) in scan order."""
        return [(ch["name"], int(ch["channel"])) for ch in self.temperature_channels]

    @classmethod
    def read(cls, path) -> Plan:
        """Read a plan JSON file (errors name the file)."""
        path = Path(path)
        try:
            doc = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, ValueError) as exc:
            raise AcquisitionError(f"{path}: not a readable plan ({exc})") from None
        except RecursionError:
            raise AcquisitionError(f"{path}: not a readable plan (JSON nested too deeply)") from None
        if not isinstance(doc, dict):
            raise AcquisitionError(f"{path}: a plan is a JSON object")
        extra = [k for k in doc if k not in _KEYS]
        if extra:
            raise AcquisitionError(f"{path}: unknown key {extra[0]!r} (allowed: {', '.join(_KEYS)})")
        try:
            return cls(**doc)
        except AcquisitionError as exc:
            raise AcquisitionError(f"{path}: {exc}") from None

    def write(self, path) -> None:
        """Write as JSON (atomically, :mod:`cmmpose.atomicfile`)."""
        doc = {k: getattr(self, k) for k in _KEYS}
        write_text(path, json.dumps(doc, indent=2, allow_nan=False) + "\n")

    def to_dict(self) -> dict:
        """JSON-ready dict."""
        return {k: getattr(self, k) for k in _KEYS}


def _fits(value, dtype: str) -> bool:
    """Whether a JSON value is of a run column's type (booleans are not numbers)."""
    if dtype == "str":
        return isinstance(value, str)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    if dtype == "float64":
        return math.isfinite(value)
    return float(value).is_integer()


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
