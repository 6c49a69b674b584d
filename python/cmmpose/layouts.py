"""Ballbar test layouts: where the two balls of the thesis's optical ballbar sit
in the machine frame H, and a digitizer pose to scan them with.

Two layouts of the thesis (J. O. Harris, chapter 6) are provided:

- :func:`b89_positions`: the 20 ASME B89.4.1 positions (thesis section 6.3 and
  6.4, Figure 6-2), placed at the ball centres measured in Appendix C.
- :func:`crossed_ballbar_positions`: the 8 positions of the "initial
  squareness tests" with crossed ballbars (thesis section 6.2).

:func:`digitizer_pose_for` suggests the Euler 3-1-3 angles (alpha, beta, gamma)
to scan a position with, and :func:`sweep_readings` gives the scale readings
D, E, F the machine needs to sweep the scan plane through one ball.

Units: mm for positions and lengths, degrees for angles. All coordinates are in
the machine frame H (scale readings, X 0..900, Y 0..550, Z -500..0 on the DEA
Iota 1102 of the thesis) unless stated otherwise.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from importlib import resources

import numpy as np

from .errors import InputError, InputTypeError
from ._validate import vector3

__all__ = [
    "BallbarPosition",
    "b89_positions",
    "crossed_ballbar_positions",
    "digitizer_pose_for",
    "sweep_readings",
    "appendix_c_centres",
    "appendix_c_lengths",
    "appendix_c_bbox_centre",
    "BALL_RADIUS_MM",
    "B89_LENGTH_MM",
    "B89_CENTRE_MM",
    "B89_REACHABLE_CENTRE_MM",
    "CROSSED_CENTRES_MM",
    "CROSSED_W_AXES",
    "TRAVEL_MM",
    "W_AXIS_ANGLES",
]

#: Radius of the ballbar's balls, mm: 76.25 mm diameter (thesis section 6.1.1, line 1582).
BALL_RADIUS_MM = 76.25 / 2
#: Mean compensated ballbar length at 20 C, mm (Appendix C, Figure C 4, line 2120).
B89_LENGTH_MM = 404.2357
#: Scale ranges of the DEA Iota 1102 (thesis Tables 8-16), mm: (min, max) for X, Y, Z.
TRAVEL_MM = ((0.0, 900.0), (0.0, 550.0), (-500.0, 0.0))
#: Default point (mm, frame H) the bounding-box centre of the Appendix C ball
#: centres is moved to by :func:`b89_positions`: the middle of the travel.
B89_CENTRE_MM = (450.0, 275.0, -250.0)
#: Alternative centre (mm, frame H) for :func:`b89_positions` under which the
#: thesis digitizer, scanning every ball from straight above (pose 90, 90, 0),
#: reaches all 40 balls with its scale readings inside the travel; the balls
#: then lie partly below Z = -500. See :func:`b89_positions`.
B89_REACHABLE_CENTRE_MM = (320.0, 275.0, -550.0)
#: Default crossing points (mm, frame H) of the two crossed pairs of
#: :func:`crossed_ballbar_positions`: positions 1-2 (and 5-6), 3-4 (and 7-8).
CROSSED_CENTRES_MM = ((200.0, 200.0, -400.0), (550.0, 200.0, -400.0))
#: Digitizer W axis of crossed positions 1-8 (thesis lines 1608, 1615).
CROSSED_W_AXES = ("X", "X", "X", "X", "Y", "Y", "Y", "Y")
#: (alpha, beta) in degrees that put the digitizer's W axis along a machine axis
#: with v (part -> sensor) along +Z at gamma = 0. "X" and "Y" are the thesis's
#: (section 5.3, lines 1432-1434); the trunnion also allows -X and -Y (line 1282).
W_AXIS_ANGLES = {"X": (90.0, 90.0), "Y": (180.0, 90.0), "-X": (-90.0, 90.0), "-Y": (0.0, 90.0)}

_STATES = ("uncompensated", "compensated")


# -- the data of Appendix C -------------------------------------------------------------


def _appendix_c_rows() -> list[dict[str, str]]:
    path = resources.files("cmmpose").joinpath("data", "thesis", "appendix_c_ballbar.csv")
    with path.open("r", encoding="utf-8") as fh:
        return list(csv.DictReader(line for line in fh if not line.startswith("#")))


def _check_state(state: str) -> str:
    if state not in _STATES:
        raise InputError(f"state: expected 'uncompensated' or 'compensated', got {state!r}")
    return state


def appendix_c_centres(state: str = "compensated") -> np.ndarray:
    """Ball centres of thesis Appendix C, as printed.

    Parameters
    ----------
    state : {'compensated', 'uncompensated'}
        Which tables: "Pose Compensated" (Figures C 3, C 4) or "Uncompensated"
        (Figures C 1, C 2).

    Returns
    -------
    ndarray, shape (20, 2, 3)
        ``[position - 1, ball - 1]`` = centre X, Y, Z in mm, in the thesis's
        measuring frame (relative to the digitizer's reference sphere, not the
        machine frame H; X is negative throughout). Positions 14 and 18 are
        printed identically.
    """
    _check_state(state)
    out = np.full((20, 2, 3), np.nan)
    for r in _appendix_c_rows():
        if r["state"] == state:
            out[int(r["position"]) - 1, int(r["ball"]) - 1] = [float(r["x_mm"]), float(r["y_mm"]), float(r["z_mm"])]
    return out


def appendix_c_lengths(state: str = "compensated") -> np.ndarray:
    """Ballbar lengths printed in thesis Appendix C (Figures C 2, C 4), mm, shape (20,)."""
    _check_state(state)
    out = np.full(20, np.nan)
    for r in _appendix_c_rows():
        if r["state"] == state and r["ball"] == "2":
            out[int(r["position"]) - 1] = float(r["length_mm"])
    return out


# -- one position ----------------------------------------------------------------------


def _point(name: str, p) -> np.ndarray:
    """A read-only copy of three finite numbers (mm)."""
    a = vector3(name, p, unit="mm")
    a.flags.writeable = False
    return a


@dataclass(frozen=True)
class BallbarPosition:
    """One placement of the ballbar.

    Parameters
    ----------
    position : int
        Position number as in the thesis (1-based).
    ball1, ball2 : array_like, shape (3,)
        Ball centres in the machine frame H, mm. Stored as read-only float64
        arrays.

    Notes
    -----
    Two positions are equal when their numbers and ball centres are equal.
    """

    position: int
    ball1: np.ndarray
    ball2: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "position", int(self.position))
        object.__setattr__(self, "ball1", _point("ball1", self.ball1))
        object.__setattr__(self, "ball2", _point("ball2", self.ball2))
        if not np.any(self.ball2 != self.ball1):
            raise InputError(f"position {self.position}: ball1 and ball2 coincide")

    def __eq__(self, other) -> bool:
        if not isinstance(other, BallbarPosition):
            return NotImplemented
        return (self.position == other.position and np.array_equal(self.ball1, other.ball1)
                and np.array_equal(self.ball2, other.ball2))

    def __hash__(self) -> int:
        return hash((self.position, self.ball1.tobytes(), self.ball2.tobytes()))

    @property
    def length(self) -> float:
        """Centre-to-centre length, mm."""
        return float(np.linalg.norm(self.ball2 - self.ball1))

    @property
    def direction(self) -> np.ndarray:
        """Unit vector from ball1 to ball2, shape (3,)."""
        d = self.ball2 - self.ball1
        return d / np.linalg.norm(d)

    @property
    def midpoint(self) -> np.ndarray:
        """Middle of the bar, mm, shape (3,)."""
        return (self.ball1 + self.ball2) / 2.0

    @property
    def balls(self) -> np.ndarray:
        """Both centres, shape (2, 3), mm."""
        return np.stack([self.ball1, self.ball2])


def _length(length) -> float:
    L = B89_LENGTH_MM if length is None else float(length)
    if not (math.isfinite(L) and L > 0):
        raise InputError(f"length: must be a positive number of mm, got {length!r}")
    return L


# -- the B89 layout -------------------------------------------------------------------


def appendix_c_bbox_centre(state: str = "compensated") -> np.ndarray:
    """Centre of the axis-aligned bounding box of the 40 Appendix C ball centres
    (printed values, thesis measuring frame), mm, shape (3,)."""
    c = appendix_c_centres(state).reshape(-1, 3)
    return (c.min(axis=0) + c.max(axis=0)) / 2.0


def b89_positions(length: float | None = None, centre=None) -> list[BallbarPosition]:
    """The 20 ASME B89.4.1 ballbar positions at the places measured in the thesis.

    The geometry is taken from the "Pose Compensated" ball centres of thesis
    Appendix C (20 C; Figures C 3 and C 4, thesis.txt lines 2068-2119), the best
    estimate of where the bar really was. Each position keeps its measured
    midpoint and direction; both balls are put at +-length/2 along that
    direction, so every position has exactly the same length (the measured
    lengths scatter by 46 um). The whole layout is then translated into the
    machine frame H.

    Parameters
    ----------
    length : float, optional
        Centre-to-centre length, mm. Default 404.2357 mm
        (:data:`B89_LENGTH_MM`, the mean compensated length of Appendix C).
    centre : array_like, shape (3,), optional
        Point in frame H (mm) that the bounding-box centre of the 40 printed
        Appendix C ball centres is moved to. The translation is
        ``centre - appendix_c_bbox_centre()`` and does not depend on
        ``length``. Default :data:`B89_CENTRE_MM` = (450, 275, -250).

    Returns
    -------
    list of BallbarPosition
        Positions 1..20 in the thesis's numbering.

    Notes
    -----
    **Frame.** The Appendix C centres are in the digitizer's measuring frame
    (relative to its reference sphere: X runs from -569 to -74 mm), not in
    H, and the thesis does not give the offset between the two. The layout
    spans 495.6 x 476.5 x 404.2 mm (X, Y, Z; bounding-box centre
    (-321.318, -0.777, 91.589) mm in that frame).

    **Default translation.** ``centre`` defaults to the middle of the
    travel, (450, 275, -250) mm (:data:`B89_CENTRE_MM`). Every ball centre
    is then inside X 0..900, Y 0..550, Z -500..0: in X and Z with more than a
    ball radius (38.125 mm) to spare (X 202.2, Z 47.9 mm at the tightest), in
    Y with 36.7 mm on both sides. A full radius is impossible in Y for any
    translation: the layout is 476.5 mm wide in Y and 550 - 476.5 = 73.5 mm
    is less than two radii (76.25 mm).

    **Reachability.** Inside the travel box does not mean that the thesis
    digitizer can scan every ball. Looking down (pose 90, 90, 0) the ram's
    mount point sits V1 + radius = 302.6 mm above a ball whose top is at the
    laser origin (the middle of the depth of view, ``v_near = 0`` in
    :func:`sweep_readings`), so a ball must be at Z <= -302.6 mm for
    F <= 0, and the upper part of a 404 mm tall layout cannot be both inside
    Z -500..0 and reachable. Tilted views (gamma != 0, as from
    :func:`digitizer_pose_for`) move the ram by up to 302.6 mm sideways; with
    those poses the sweep readings of the 40 balls span 739 mm in Y and
    561 mm in Z (697 and 540 mm with ``v_near = 30``, the top of the depth
    of view; the same with W along -X), more than the 550 and 500 mm of
    travel, so no translation makes every ball reachable. With every ball
    scanned from straight above (pose 90, 90, 0, ``v_near = 0``) the
    translations that work are X 477.7..805.8, Y 238.0..311.5,
    Z -692.1..-596.3 mm (added to the printed centres); the middle of that
    window, rounded, is :data:`B89_REACHABLE_CENTRE_MM` = (320, 275, -550).
    Use it for simulations that must stay inside the error map: all 80
    readings are then at least 35 mm inside the travel, and the balls lie at
    Z -752..-348 mm, below the ram's own travel, as a real table does. At
    the default centre 10 balls are out of reach from straight above and 16
    with the poses of :func:`digitizer_pose_for`.

    **Duplicate.** Positions 14 and 18 are printed with identical values in
    all four Appendix C tables (same points, fit, radius, centres and
    length), most likely a copy error in the thesis. They are kept as
    printed, so positions 14 and 18 of this layout are the same bar.
    """
    L = _length(length)
    c = appendix_c_centres("compensated")
    shift = (np.asarray(B89_CENTRE_MM, dtype=float) if centre is None else _point("centre", centre)) \
        - appendix_c_bbox_centre("compensated")
    out = []
    for k in range(20):
        b1, b2 = c[k]
        d = (b2 - b1) / np.linalg.norm(b2 - b1)
        mid = (b1 + b2) / 2.0 + shift
        out.append(BallbarPosition(k + 1, mid - 0.5 * L * d, mid + 0.5 * L * d))
    return out


# -- the crossed-ballbar squareness test ----------------------------------------------


def crossed_ballbar_positions(length: float | None = None, centres=None, angle: float = 45.0) -> list[BallbarPosition]:
    """The 8 crossed-ballbar positions of the thesis's initial squareness tests.

    Parameters
    ----------
    length : float, optional
        Centre-to-centre length, mm. Default :data:`B89_LENGTH_MM`.
    centres : sequence of two array_like (3,), optional
        Crossing points (mm, frame H) of the pair 1-2 and of the pair 3-4.
        Default :data:`CROSSED_CENTRES_MM` = (200, 200, -400) and
        (550, 200, -400).
    angle : float
        Direction of positions 1 and 3 in the XY plane, degrees from +X
        towards +Y. Positions 2 and 4 are turned a further 90 degrees.

    Returns
    -------
    list of BallbarPosition
        Positions 1..8, horizontal bars. 1-4 are scanned with the digitizer W
        along X, 5-8 are the same four bars scanned with W along Y
        (:data:`CROSSED_W_AXES`): position k + 4 has the geometry of k.

    Notes
    -----
    What the thesis says (section 6.2.1, thesis.txt lines 1604-1617; 6.2.3,
    lines 1629-1631): position 1 was near the home position with the bar
    pointing at 45 degrees; the bar was then rotated 90 degrees (position 2);
    "Likewise, each pair of test positions overlapped". Four positions were
    measured with W along X, the same four again with W along Y, numbered
    5-8, and "positions 1 and 5 are the same position on the CMM table".
    Positions 1, 3, 5, 7 read long and 2, 4, 6, 8 short, the signature of
    the XY squareness error, so 1 and 3 share one diagonal direction and
    2 and 4 the other. The tests are called "crossed ballbars" (lines 1566,
    1588, 1784, 1790).

    What was chosen, because Figure 6-1 is not in the text: each pair is a
    cross, the second bar turned 90 degrees about the first bar's midpoint
    (the usual diagonal squareness test); pair 1-2 crosses near home,
    pair 3-4 elsewhere on the table, with the same directions. Ball 1 of
    position 1 is the end nearer home. The default crossing points keep all
    balls a radius inside the travel and reachable with W along X
    (pose 90, 90, 0) and W along Y (pose 180, 90, 0) by
    :func:`sweep_readings` at the default stand-off: with W along +Y the
    ram sits W1 = 129.6 mm on the +Y side of the ball, which limits the
    crossing points to Y <= 239 mm, so the second cross is moved along X.
    The bar height Z = -400 mm is also a choice; the thesis does not state it.
    """
    L = _length(length)
    if centres is None:
        centres = CROSSED_CENTRES_MM
    centres = list(centres)
    if len(centres) != 2:
        raise InputError(f"centres: expected two crossing points, got {len(centres)}")
    cs = [_point("centres[0]", centres[0]), _point("centres[1]", centres[1])]
    a = math.radians(float(angle))
    d1 = np.array([math.cos(a), math.sin(a), 0.0])
    d2 = np.array([-math.sin(a), math.cos(a), 0.0])
    bars = [(cs[0], d1), (cs[0], d2), (cs[1], d1), (cs[1], d2)]
    out = []
    for k in range(8):
        c, d = bars[k % 4]
        out.append(BallbarPosition(k + 1, c - 0.5 * L * d, c + 0.5 * L * d))
    return out


# -- digitizer pose -------------------------------------------------------------------


def _e313(alpha: float, beta: float, gamma: float) -> np.ndarray:
    """Euler 3-1-3 matrix of thesis eq. 7 (angles in degrees), from the core."""
    from . import _core

    return _core.euler313(alpha, beta, gamma)


def digitizer_pose_for(
    position: BallbarPosition,
    w_axis: str = "X",
    *,
    rule: str = "view_across_bar",
    step: float | None = 15.0,
    flat_tolerance: float = 15.0,
    travel_centre=None,
) -> tuple[float, float, float]:
    """Suggested digitizer pose (alpha, beta, gamma) for scanning a position.

    Parameters
    ----------
    position : BallbarPosition
        The bar (frame H).
    w_axis : {'X', 'Y', '-X', '-Y'}
        Machine axis the digitizer's W axis is aligned with; fixes alpha and
        beta (:data:`W_AXIS_ANGLES`). The thesis used 'X' for all B89 tests
        and 'X' and 'Y' for the crossed tests.
    rule : {'view_across_bar', 'scan_across_bar'}
        How gamma is chosen, see Notes.
    step : float or None
        Gamma is rounded to a multiple of ``step`` degrees: the trunnion
        indexes about W in 15 degree increments (thesis line 1282). None
        keeps the exact angle.
    flat_tolerance : float
        Degrees. When the bar is within this angle of the W axis its
        projection on the scan plane is too short to define a direction and
        gamma is 0 (scan from straight above).
    travel_centre : array_like (3,), optional
        Used only when gamma comes out as +-90 (sensor level with the balls):
        the sensor is put on the side of the bar facing this point, mm,
        frame H. Default: the middle of :data:`TRAVEL_MM`, (450, 275, -250).

    Returns
    -------
    tuple of float
        (alpha, beta, gamma) in degrees, Euler 3-1-3 (thesis eq. 7), with
        gamma in [-90, 90] so that v (part -> sensor) never points down.

    Notes
    -----
    The thesis (line 1588) says only that for the B89 tests "the W axis of
    the digitizer was always aligned with the X axis and the gamma angle
    selected based on the position of the ballbar"; Figure 6-3 shows one
    setting, gamma = -60 degrees, without saying for which position. For the
    crossed tests, with horizontal bars, it used gamma = 0 in both
    orientations (line 1615). The rule below reproduces that case:

    - ``'view_across_bar'`` (default): the viewing direction v is made
      perpendicular to the bar's projection on the scan plane, i.e. the scan
      line u runs along that projection. Then neither ball is seen through
      the bar: the bar leaves each ball at the rim of the cap the sensor
      sees. gamma is the same for both balls, as in the thesis (one gamma
      per position). A horizontal bar scanned with W along X or Y gives
      gamma = 0; a vertical bar gives +-90; a bar along W gives 0 (see
      ``flat_tolerance``).
    - ``'scan_across_bar'``: the scan line u is made perpendicular to the
      projected bar (v along it). This is the rule suggested when the thesis
      is silent; it gives gamma = +-90 for the thesis's horizontal crossed
      bars, where the thesis used 0, so it is not the default.

    The thesis prints (alpha, beta, gamma) = (0, -90, 0) for W along Y
    (line 1615). That pose has W along +Y but v along -Z (sensor below the
    part); section 5.3 (line 1434) and this package use (180, 90, 0), which
    has v along +Z. Both have the same W axis.

    The choice of gamma does not use the Appendix C data (which carry no
    angles), so it is a suggestion, not a transcription.
    """
    if w_axis not in W_AXIS_ANGLES:
        raise InputError(f"w_axis: expected one of {sorted(W_AXIS_ANGLES)}, got {w_axis!r}")
    if rule not in ("view_across_bar", "scan_across_bar"):
        raise InputError(f"rule: expected 'view_across_bar' or 'scan_across_bar', got {rule!r}")
    if not isinstance(position, BallbarPosition):
        raise InputTypeError(f"position: expected a BallbarPosition, got {type(position).__name__}")
    alpha, beta = W_AXIS_ANGLES[w_axis]
    m0 = _e313(alpha, beta, 0.0)
    u0, v0, w = m0[:, 0], m0[:, 1], m0[:, 2]
    d = position.direction
    du, dv = float(u0 @ d), float(v0 @ d)  # projection of the bar on the scan plane
    if math.hypot(du, dv) <= math.sin(math.radians(flat_tolerance)):
        return (alpha, beta, 0.0)
    # At gamma, u = cos g u0 + sin g v0 and v = -sin g u0 + cos g v0.
    if rule == "view_across_bar":  # v . d = 0:  tan g = dv / du
        g = math.degrees(math.atan2(dv, du))
    else:  # u . d = 0:  tan g = -du / dv
        g = math.degrees(math.atan2(-du, dv))
    # gamma and gamma +- 180 give the same line; keep v pointing up (g in [-90, 90]).
    if g > 90.0:
        g -= 180.0
    elif g < -90.0:
        g += 180.0
    if step:
        g = float(step) * round(g / float(step))
    if abs(abs(g) - 90.0) < 1e-9:
        # v = -sin(g) u0: choose the side that faces the travel centre.
        tc = np.array([np.mean(r) for r in TRAVEL_MM]) if travel_centre is None else _point("travel_centre", travel_centre)
        towards = float(u0 @ (tc - position.midpoint))
        g = -90.0 if towards >= 0.0 else 90.0
    return (alpha, beta, g + 0.0)


def sweep_readings(ball, pose, offset=None, *, v_near: float = 0.0, radius: float = BALL_RADIUS_MM) -> np.ndarray:
    """Scale readings at the start and end of a sweep of the scan plane through a ball.

    The laser origin is placed so that the ball's surface point nearest the
    sensor has scan-plane coordinates (u, v) = (0, ``v_near``); the ram then
    moves along W from the scan plane touching one side of the ball to the
    other. Uses the uncompensated model of docs/conventions.md (The compensation),
    X_H = S + E313 . ((u, v, 0) - l1), i.e. an error-free machine.

    Parameters
    ----------
    ball : array_like, shape (3,)
        Ball centre, mm, frame H.
    pose : Pose or sequence of 3 float
        (alpha, beta, gamma) in degrees.
    offset : sequence of 3 float, optional
        Mount offset (U1, V1, W1), mm. Default the thesis digitizer,
        (1.001, 264.505, 129.575).
    v_near : float
        v of the sphere point nearest the sensor, mm. Default 0: the laser
        origin in the middle of the 60 mm depth of view (140 mm stand-off,
        thesis Table 17), as in ``cmmpose.sim.Scanner``.
    radius : float
        Ball radius, mm.

    Returns
    -------
    ndarray, shape (2, 3)
        D, E, F (mm) with the scan plane at w = -radius and w = +radius from
        the centre.
    """
    from .pose import pose_tuple  # local: keeps the module importable for data-only use

    c = _point("ball", ball)
    m = _e313(*pose_tuple(pose))
    from .pose import MountOffset

    u1, v1, w1 = MountOffset.thesis() if offset is None else (float(x) for x in offset)
    v_c = float(v_near) - float(radius)
    # c = S + M ((0, v_c, w_c) - l1), w_c = centre's w relative to the scan plane.
    return np.stack([c + m @ np.array([u1, v1 - v_c, w1 - w_c]) for w_c in (float(radius), -float(radius))])
