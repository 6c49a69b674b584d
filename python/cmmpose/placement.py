"""Where an artefact sits in the machine (docs/artefacts.md, "Placements").

A placement turns the artefact's own frame into the machine frame H:
``x_H = R (x_artefact - centroid) + centre``, with ``R`` a rotation and
``centre`` where the centroid of the artefact's balls goes (mm). Placements
are written as readable shorthands or named layouts::

    placement := LAYOUT | PLANE [ "@" SETTING { "," SETTING } ]
    PLANE     := "xy" | "xz" | "yz"     the artefact's x and y axes along these machine axes;
                                         its +z (the side its balls face) along xy: +Z, xz: -Y, yz: +X
    SETTING   := ("x" | "y" | "z") "=" MM      where the balls' centroid goes, mm (each axis not
                                                 given: where the ram at mid-travel sees it)
               | "rot" "=" DEGREES              turned about the plane's normal, from its first
                                                 axis towards its second
    LAYOUT    := "planes"        the three placements xy, xz, yz (ball plates)
               | "iso10360-2"    the seven positions of ISO 10360-2 for bars and step gauges

e.g. ``xy@z=-525,rot=45``: in the XY plane with its centroid at Z = -525 mm,
turned 45 degrees. :func:`plan` then chooses, for every ball, a pose of the
pose library that views the balls' side and keeps the ram's sweep inside the
machine's travel, or names the ball and the axis that leave it.

Units: mm, degrees.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from . import _core
from .errors import InputError
from .layouts import W_AXIS_ANGLES, sweep_readings

__all__ = [
    "LAYOUTS",
    "PLANES",
    "PROFILES_PER_BALL",
    "SWEEP_MARGIN",
    "BallScan",
    "Placement",
    "Sweep",
    "ball_speed",
    "check_repeat_scans",
    "parse",
    "plan",
    "pose_library",
    "run_record",
    "sweep_of",
]

#: Travel beyond the ball on each side of a sweep, mm (as ``cmmpose.sim.runs``).
SWEEP_MARGIN = 5.0
#: Fewest scanner profiles across a ball: a smaller ball is swept more slowly.
PROFILES_PER_BALL = 12
#: The artefact's x and y axes in the machine frame, by plane.
PLANES = {"xy": ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0)),
          "xz": ((1.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
          "yz": ((0.0, 1.0, 0.0), (0.0, 0.0, 1.0))}
#: Named layouts and what they are.
LAYOUTS = {"planes": "a ball plate in the XY, XZ and YZ planes (three placements)",
           "iso10360-2": "the seven positions of ISO 10360-2: the four space diagonals of the travel, then "
                         "parallel to X, Y and Z, all through its middle"}
#: Smallest cosine between the scanner's view (v, part -> sensor) and the
#: side the balls face for a pose to be used (60 degrees).
MIN_VIEW_COSINE = 0.5
_NUMBER = re.compile(r"^[+-]?([0-9]+\.?[0-9]*|\.[0-9]+)([eE][+-]?[0-9]+)?$")  # ASCII digits: "٥٢٥" is not 525


@dataclass(frozen=True)
class Placement:
    """One placement: ``x_H = rotation @ (x_artefact - centroid) + centre``.

    Attributes
    ----------
    label : str
        The shorthand it came from (or the layout and position).
    rotation : ndarray (3, 3)
        Artefact frame -> machine frame.
    centre : ndarray (3,)
        Where the centroid of the balls goes, mm; NaN for an axis left to
        :func:`plan` (where the ram at mid-travel sees it).
    """

    label: str
    rotation: np.ndarray
    centre: np.ndarray

    def to_dict(self) -> dict:
        return {"label": self.label, "rotation": [[float(round(x, 15)) for x in r] for r in self.rotation],
                "centre_mm": [float(x) for x in self.centre]}

    @classmethod
    def from_dict(cls, doc: dict) -> Placement:
        return cls(str(doc["label"]), np.array(doc["rotation"], float), np.array(doc["centre_mm"], float))


@dataclass(frozen=True)
class BallScan:
    """One ball to scan: placement number (1-based), ball id, its centre in
    the machine frame at the certificate's temperature (mm) and the pose
    (alpha, beta, gamma, degrees) chosen to scan it."""

    position: int
    ball: int
    centre: np.ndarray
    pose: tuple[float, float, float]


def _rot_z(degrees: float) -> np.ndarray:
    a = math.radians(degrees)
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _frame(x_axis, y_axis) -> np.ndarray:
    x, y = np.asarray(x_axis, float), np.asarray(y_axis, float)
    return np.column_stack([x, y, np.cross(x, y)])


def parse(text: str, travel=None) -> list[Placement]:
    """The placements a shorthand or layout name says (see the module's grammar).

    Parameters
    ----------
    text : str
        e.g. ``'xy@z=-525,rot=45'``, ``'planes'``, ``'iso10360-2'``.
    travel : sequence of 3 (lo, hi), optional
        The machine's travel, mm: the ISO 10360-2 diagonals follow its box
        (default a cube).

    Raises
    ------
    InputError
        Naming the placement and the part at fault.
    """
    if not isinstance(text, str) or not text.strip():
        raise InputError(f"placement {text!r}: empty; write e.g. 'xy@z=-525,rot=45' or one of {', '.join(LAYOUTS)}")
    text = text.strip()
    if text == "planes":
        return [Placement(f"planes/{p}", _frame(*PLANES[p]), np.full(3, np.nan)) for p in ("xy", "xz", "yz")]
    if text == "iso10360-2":
        return _iso10360_2(travel)
    plane, at, rest = text.partition("@")
    plane = plane.strip().lower()
    if plane not in PLANES:
        raise InputError(f"placement {text!r}: {plane!r} is not a plane (xy, xz, yz) nor a layout "
                         f"({', '.join(LAYOUTS)})")
    if at and not rest.strip():
        raise InputError(f"placement {text!r}: nothing after '@' (write e.g. {plane}@z=-525,rot=45)")
    centre = np.full(3, np.nan)
    rot = 0.0
    seen = set()
    for item in (p.strip() for p in rest.split(",")) if at else ():
        key, eq, value = item.partition("=")
        key = key.strip().lower()
        if not eq or key not in ("x", "y", "z", "rot"):
            raise InputError(f"placement {text!r}: {item!r} is not x=MM, y=MM, z=MM or rot=DEGREES")
        if key in seen:
            raise InputError(f"placement {text!r}: {key} is given twice")
        seen.add(key)
        if not _NUMBER.match(value.strip()) or not math.isfinite(float(value)) or abs(float(value)) > 1e6:
            raise InputError(f"placement {text!r}: {key}={value.strip()!r} is not a number of "
                             f"{'degrees' if key == 'rot' else 'mm'}")
        if key == "rot":
            rot = float(value)
        else:
            centre["xyz".index(key)] = float(value)
    return [Placement(text, _frame(*PLANES[plane]) @ _rot_z(rot), centre)]


def _iso10360_2(travel) -> list[Placement]:
    span = np.ones(3) if travel is None else np.array([hi - lo for lo, hi in travel], float)
    directions = [("diagonal +X+Y+Z", (1, 1, 1)), ("diagonal -X+Y+Z", (-1, 1, 1)), ("diagonal +X-Y+Z", (1, -1, 1)),
                  ("diagonal -X-Y+Z", (-1, -1, 1)), ("along X", (1, 0, 0)), ("along Y", (0, 1, 0)),
                  ("along Z", (0, 0, 1))]
    out = []
    for k, (name, sign) in enumerate(directions, start=1):
        d = np.array(sign, float) * span
        d /= np.linalg.norm(d)
        up = np.array([0.0, 0.0, 1.0]) if abs(d[2]) < 0.99 else np.array([0.0, -1.0, 0.0])
        z = up - (up @ d) * d
        z /= np.linalg.norm(z)
        out.append(Placement(f"iso10360-2/{k} ({name})", np.column_stack([d, np.cross(z, d), z]), np.full(3, np.nan)))
    return out


def pose_library(machine_pose) -> list[tuple[float, float, float]]:
    """The poses a scan may use: the machine's own, then the trunnion's
    indexed poses (W along +-X, +-Y; gamma in 15-degree steps from -90 to 90)."""
    poses = [tuple(float(x) for x in machine_pose)]
    for alpha, beta in W_AXIS_ANGLES.values():
        for gamma in range(-90, 91, 15):
            p = (float(alpha), float(beta), float(gamma))
            if p not in poses:
                poses.append(p)
    return poses


@dataclass(frozen=True)
class Sweep:
    """The ram's sweep through one ball: along ``axis`` ('X', 'Y' or 'Z')
    from the scale readings ``start`` (D, E, F, mm) for ``length`` mm in
    ``direction`` (+1 or -1), with the scan plane a ball radius and
    SWEEP_MARGIN beyond the ball at each end (as ``cmmpose.sim.runs`` sweeps)."""

    axis: str
    start: tuple[float, float, float]
    length: float
    direction: int


def sweep_of(centre, pose, offset, radius: float, direction: int = 1) -> Sweep:
    """The sweep that scans the ball at ``centre`` (mm, frame H) with ``pose``
    (degrees) and mount ``offset`` (U1, V1, W1, mm): along the machine axis
    nearest to the scan plane's travel."""
    ends = sweep_readings(centre, pose, offset, radius=radius)
    a = int(np.argmax(np.abs(ends[1] - ends[0])))
    lo, hi = sorted((ends[0][a], ends[1][a]))
    start = ends[0].copy()
    start[a] = lo - SWEEP_MARGIN if direction == 1 else hi + SWEEP_MARGIN
    return Sweep("XYZ"[a], tuple(float(x) for x in start), float(hi - lo + 2 * SWEEP_MARGIN), int(direction))


def ball_speed(speed: float, radius: float, profile_rate: float) -> float:
    """Sweep speed for a ball of ``radius`` mm: ``speed`` mm/s, or slower so
    that PROFILES_PER_BALL profiles (``profile_rate`` per s) cross it."""
    return min(float(speed), 2 * radius * profile_rate / PROFILES_PER_BALL)


def run_record(artefact, placements) -> dict:
    """What a run records of its artefact (run.json's ``artefact``): kind,
    name, radii, the embedded definition and the resolved placements."""
    return {"kind": artefact.kind, "name": artefact.name, "ball_radius_mm": artefact.nominal_radius,
            "calibrated_radius_mm": artefact.calibrated_radius, "source": artefact.source,
            "definition": artefact.to_dict(), "placements": [p.to_dict() for p in placements]}


def _sweep_box(centre, pose, offset, radius) -> np.ndarray:
    """(3, 2) lowest and highest scale reading of the sweep through a ball, mm."""
    ends = sweep_readings(centre, pose, offset, radius=radius)
    a = int(np.argmax(np.abs(ends[1] - ends[0])))
    box = np.column_stack([ends.min(axis=0), ends.max(axis=0)])
    box[a] += (-SWEEP_MARGIN, SWEEP_MARGIN)
    return box


def _outside(box, travel) -> list[tuple[int, float, float]]:
    return [(k, box[k, 0], box[k, 1]) for k, (lo, hi) in enumerate(travel)
            if box[k, 0] < lo - 1e-9 or box[k, 1] > hi + 1e-9]


def _fits(plane, artefact, machine, travel, offset, library) -> bool:
    """Whether ``artefact`` in ``plane`` (centred where the ram sees it) is in reach."""
    try:
        _plan_one(0, Placement(plane, _frame(*PLANES[plane]), np.full(3, np.nan)), artefact, machine, travel, offset,
                  library)
    except InputError:
        return False
    return True


def _plan_one(k, pl, artefact, machine, travel, offset, library) -> tuple[Placement, list[BallScan]]:
    """One placement resolved and a pose per ball (see :func:`plan`)."""
    mid = travel.mean(axis=1)
    r = artefact.nominal_radius
    normal = pl.rotation[:, 2]
    views = [(float(_core.euler313(*p)[:, 1] @ normal), i, p) for i, p in enumerate(library)]
    candidates = [p for score, _, p in sorted(views, key=lambda s: (-round(s[0], 9), s[1])) if score >= MIN_VIEW_COSINE]
    if not candidates:
        raise InputError(f"placement {k} ({pl.label}): no pose of the pose library views the balls' side")
    seen_at_origin = _sweep_box(np.zeros(3), candidates[0], offset, r).mean(axis=1)
    centre = np.where(np.isnan(pl.centre), mid - seen_at_origin, pl.centre)
    pl = Placement(pl.label, pl.rotation, centre)
    placed = (artefact.centres - artefact.centroid) @ pl.rotation.T + centre
    scans = []
    for bid, x in zip(artefact.ids, placed):
        for pose in candidates:
            if not _outside(_sweep_box(x, pose, offset, r), travel):
                break
        else:
            axis, lo, hi = _outside(_sweep_box(x, candidates[0], offset, r), travel)[0]
            tlo, thi = travel[axis]
            name = "XYZ"[axis]
            need = f"{lo:.1f}..{hi:.1f}" if hi - lo > 0.05 else f"{lo:.1f}"
            # The whole artefact's span on that axis with the best-aligned pose: more than the travel
            # means no centre on this machine holds it in this orientation.
            boxes = np.array([_sweep_box(y, candidates[0], offset, r)[axis] for y in placed])
            span = float(boxes[:, 1].max() - boxes[:, 0].min())
            whole = (f"; its balls' sweeps span {span:.0f} mm of {name} with that pose, more than the {thi - tlo:g} mm "
                     f"travel: it cannot stand so on this machine (docs/artefacts.md, 'Which placements fit')"
                     if span > thi - tlo + 1e-9 else "")
            raise InputError(
                f"placement {k} ({pl.label}): ball {bid} at X {x[0]:.1f}, Y {x[1]:.1f}, Z {x[2]:.1f} mm is out "
                f"of reach: its sweep needs {name} {need} mm with pose "
                f"{','.join(f'{a:g}' for a in candidates[0])}, beyond the {name} travel {tlo:g}..{thi:g} "
                f"mm of {machine.name}, and no other pose of the pose library keeps it in travel{whole}")
        scans.append(BallScan(k, int(bid), x, pose))
    return pl, scans


def plan(placements, artefact, machine) -> tuple[list[Placement], list[BallScan]]:
    """Resolve the placements on ``machine`` and choose a pose per ball.

    Parameters
    ----------
    placements : sequence of Placement
    artefact : cmmpose.artefacts.Artefact
    machine : cmmpose.machine.Machine
        Its travel, mount offset and pose.

    Returns
    -------
    placements : list of Placement
        With every centre axis filled in.
    scans : list of BallScan
        Every ball of every placement, in order.

    Raises
    ------
    InputError
        A ball whose sweep leaves the travel with every pose of the pose
        library that views the balls' side, naming the placement, the ball
        and the axis (and saying so when the artefact spans more of that
        axis than its travel); a plane of the layout ``planes`` the
        artefact cannot stand in, naming the planes it fits in.
    """
    travel = np.array(machine.travel, float)
    offset = tuple(machine.offset)
    library = pose_library(machine.pose.as_tuple())
    resolved, scans = [], []
    for k, pl in enumerate(placements, start=1):
        try:
            pl, mine = _plan_one(k, pl, artefact, machine, travel, offset, library)
        except InputError as exc:
            layout, _, plane = pl.label.partition("/")
            if layout != "planes":
                raise
            fit = [q for q in PLANES if q == plane or _fits(q, artefact, machine, travel, offset, library)]
            fit = [q for q in fit if q != plane]
            advice = (f"it fits in {' and '.join(q.upper() for q in fit)}: give placements that fit instead of "
                      f"'planes', e.g. " + " ".join(f"--placement {q}" for q in fit) +
                      f" --placement {fit[0]}@rot=90") if fit else "it fits in none of the three planes"
            raise InputError(f"layout 'planes': {artefact.name} cannot stand in the {plane.upper()} plane of "
                             f"{machine.name}; {advice} ({exc})") from None
        resolved.append(pl)
        scans += mine
    return resolved, scans


#: Sweeps the command line repeats at the end of a simulated run or a plan unless told otherwise: the run then
#: carries its own noise floor (docs/diagnosis.md, "Is it noise?"; 6 give the floor to about 20 %).
DEFAULT_REPEAT_SCANS = 6


def check_repeat_scans(repeat_scans, n_scans: int) -> int:
    """``repeat_scans`` (sweeps repeated at the end of a run or plan: the
    first ones again, the artefact not moved) checked: a whole number from 0
    to ``n_scans`` (each scan at most once more); None is the command line's
    default, :data:`DEFAULT_REPEAT_SCANS` (every scan once more if fewer).

    Raises
    ------
    InputError
        Naming ``repeat_scans`` and the range.
    """
    import numbers

    if repeat_scans is None:
        return min(DEFAULT_REPEAT_SCANS, int(n_scans))
    if isinstance(repeat_scans, bool) or not isinstance(repeat_scans, numbers.Integral) or \
            not 0 <= repeat_scans <= n_scans:
        raise InputError(f"repeat_scans: expected a whole number of sweeps from 0 to {n_scans} (each scan once more "
                         f"at most), got {repeat_scans!r}", what="repeat_scans", option="repeat_scans",
                         cli_option="--repeat-scans", remedy="repeat_scans")
    return int(repeat_scans)
