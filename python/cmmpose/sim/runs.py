"""Whole simulated measurement runs: the ballbar layouts of the thesis scanned
ball by ball, with a thermocouple log, stored as a ``cmmpose.Run`` with its
truth kept apart."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import asdict

import numpy as np

from .. import layouts
from ..errormap import ErrorMap, ErrorMapSet
from .._validate import MAX_REPRODUCIBILITY_MM
from ..errors import InputError
from ..placement import check_repeat_scans
from ..pose import MountOffset
from ..run import Run
from .artefacts import BALL_RADIUS, Sphere, reference_sphere
from ..effects import Effect, channels as effect_channels
from .machine import Temperature, TruthMachine
from .scanner import Scanner, Sweep, simulate_sweep
from .thermocouples import CHANNELS, thermocouple_log

#: Pose used for the B89 layout: W along +X, scanned from straight above.
B89_POSE = (90.0, 90.0, 0.0)
#: Seconds between the starts of two sweeps (moving, settling).
SCAN_INTERVAL = 20.0
#: Travel beyond the ball on each side of a sweep, mm.
SWEEP_MARGIN = 5.0
#: A realistic per-scan reproducibility, mm per axis (``jitter``): the ball's
#: apparent centre moves from scan to scan by a few um on a real machine
#: (fixture, machine repeatability, the scan's own systematic errors); 3 um is
#: the figure of issue 17's measured runs. ``cmmpose demo`` uses it; the
#: functions default to 0 (an ideal fixture, the compensation's own floor).
REALISTIC_JITTER = 0.003


def _layout(name: str):
    if name == "b89":
        positions = layouts.b89_positions(centre=layouts.B89_REACHABLE_CENTRE_MM)
        return [(p, "X") for p in positions]
    if name == "crossed":
        return list(zip(layouts.crossed_ballbar_positions(), layouts.CROSSED_W_AXES))
    raise InputError(f"layout: expected 'b89' or 'crossed', got {name!r}")


def _pose(position, w_axis: str, layout: str) -> tuple[float, float, float]:
    if layout == "b89":
        return B89_POSE
    alpha, beta = layouts.W_AXIS_ANGLES[w_axis]
    return (alpha, beta, 0.0)



class SweepRecorder:
    """The per-ball scan machinery of every simulated run: one sweep of the
    scan plane through one ball, along the axis nearest to the scan's
    travel, recorded into the points, scans and poses tables.

    Parameters
    ----------
    machine : TruthMachine
    offset : MountOffset
        Calibrated mount offset, mm.
    scanner : Scanner
    temperature : float or callable
        Machine mean temperature, C, or a function of time (s).
    speed : float
        Default sweep speed, mm/s.
    scan_interval : float
        Seconds between the starts of two sweeps.
    placements : ndarray (S, 3)
        Per-scan displacement of where the ball really sits, mm (jitter).
    rng : Generator
        Scanner noise.
    progress : callable or None
        ``progress(done, total)`` after each sweep.
    total : int
        Sweeps planned (for ``progress``).
    """

    def __init__(self, machine, offset, scanner, temperature, speed, scan_interval, placements, rng, progress, total):
        self.machine, self.offset, self.scanner, self.temperature = machine, offset, scanner, temperature
        self.speed, self.scan_interval, self.placements, self.rng = speed, scan_interval, placements, rng
        self.progress, self.total = progress, total
        self.cols = {k: [] for k in ("scan_id", "t", "u", "v", "D", "E", "F")}
        self.scans = {k: [] for k in ("scan_id", "pose_id", "feature", "position", "ball", "sweep_axis",
                                      "sweep_direction", "sweep_speed")}
        self.poses: dict[tuple, int] = {}
        self.true_xyz: list[np.ndarray] = []

    def sweep_over(self, scan_id, pose, centre, radius, direction, feature, position, ball, speed=None):
        """Sweep the sphere nominally at ``centre`` (really at ``centre`` plus
        this scan's placement) along the axis nearest to the scan's travel,
        at ``speed`` mm/s (default the recorder's)."""
        speed = self.speed if speed is None else speed
        pose_id = self.poses.setdefault(pose, len(self.poses))
        ends = layouts.sweep_readings(centre, pose, self.offset, radius=radius)
        a = int(np.argmax(np.abs(ends[1] - ends[0])))
        lo, hi = sorted((ends[0][a], ends[1][a]))
        start = ends[0].copy()
        start[a] = lo - SWEEP_MARGIN if direction == 1 else hi + SWEEP_MARGIN
        sweep = Sweep(start=tuple(start), axis="XYZ"[a], length=hi - lo + 2 * SWEEP_MARGIN, speed=speed,
                      direction=direction)
        placed = np.asarray(centre, float) + self.placements[scan_id]
        d = simulate_sweep(self.machine, Sphere(tuple(placed), radius), pose, self.offset, sweep, self.temperature,
                           scanner=self.scanner, t0=scan_id * self.scan_interval, rng=self.rng)
        n = len(d.t)
        cols = self.cols
        cols["scan_id"].append(np.full(n, scan_id, np.int32))
        cols["t"].append(d.t)
        cols["u"].append(d.uv[:, 0])
        cols["v"].append(d.uv[:, 1])
        for j, c in enumerate("DEF"):
            cols[c].append(d.scales[:, j])
        self.true_xyz.append(d.true_xyz)
        for key, value in (("scan_id", scan_id), ("pose_id", pose_id), ("feature", feature), ("position", position),
                           ("ball", ball), ("sweep_axis", "XYZ"[a]), ("sweep_direction", direction),
                           ("sweep_speed", speed)):
            self.scans[key].append(value)
        if self.progress:
            self.progress(scan_id + 1, self.total)

    def tables(self) -> tuple[dict, dict, dict, np.ndarray]:
        """The points, scans and poses tables, and every point's true position (N, 3) mm."""
        points = {k: np.concatenate(v) for k, v in self.cols.items()}
        pose_items = sorted(self.poses.items(), key=lambda kv: kv[1])
        pose_table = {
            "pose_id": np.array([i for _, i in pose_items], np.int32),
            **{name: np.array([p[j] for p, _ in pose_items]) for j, name in enumerate(("alpha", "beta", "gamma"))},
            **{name: np.full(len(pose_items), self.offset[j]) for j, name in enumerate(("U1", "V1", "W1"))},
        }
        return points, {k: np.array(v) for k, v in self.scans.items()}, pose_table, np.concatenate(self.true_xyz)


#: Fewest profiles a simulated sweep must put across a ball (a faster sweep measures nothing).
MIN_PROFILES_PER_BALL = 3


def check_timing(scan_interval, jitter, speed) -> None:
    """A simulated run's time between scans (s, > 0), placement jitter and sweep speed (mm/s, > 0), checked."""
    if not (scan_interval > 0 and np.isfinite(scan_interval)):
        raise InputError(f"scan_interval: must be > 0 s, got {scan_interval!r}")
    check_jitter(jitter)
    if not (speed > 0 and np.isfinite(speed)):
        raise InputError(f"speed: must be > 0 mm/s, got {speed!r}")


def check_jitter(jitter: float) -> None:
    """``InputError`` unless ``jitter`` (mm per axis) is a per-scan reproducibility: finite, >= 0 and at most
    ``MAX_REPRODUCIBILITY_MM`` (a metre of jitter would scan empty space and write an empty run)."""
    if not (jitter >= 0 and np.isfinite(jitter)):
        raise InputError(f"jitter: must be >= 0 mm, got {jitter!r}")
    if jitter > MAX_REPRODUCIBILITY_MM:
        raise InputError(f"jitter: {jitter:.6g} mm is beyond {MAX_REPRODUCIBILITY_MM:g} mm per axis, more than any "
                         "per-scan reproducibility (check the unit: um on the command line)", what="jitter",
                         value=f"{jitter:.6g}", unit="mm")


def simulate_ballbar_run(
    maps: ErrorMap | ErrorMapSet | None = None,
    temperature: Temperature = 20.0,
    effects: Sequence[Effect] = (),
    *,
    layout: str = "b89",
    scanner: Scanner | None = None,
    offset=None,
    speed: float = 35.0,
    bidirectional: bool = False,
    jitter: float = 0.0,
    scan_interval: float = SCAN_INTERVAL,
    calibrated: Sequence[str] = (),
    reference_poses: Sequence = (),
    seed: int = 0,
    progress: Callable[[int, int], None] | None = None,
    repeat_scans: int = 0,
) -> tuple[Run, tuple[dict[str, np.ndarray], dict]]:
    """Simulate a ballbar test: every ball of every position scanned by one sweep.

    Parameters
    ----------
    maps : ErrorMap or ErrorMapSet, optional
        The machine's real errors; default the thesis maps (20, 25, 30 C).
    temperature : float or callable
        Machine mean temperature, degrees C, or a function of time (s).
    effects : sequence of Effect
        Extra physics (``cmmpose.sim.effects``), unknown to the compensation.
    layout : {'b89', 'crossed'}
        The 20 ASME B89.4.1 positions (at the measured Appendix C geometry,
        placed where the thesis digitizer reaches every ball) or the 8
        crossed-ballbar positions of section 6.2.
    scanner : Scanner, optional
        Default: Hyscan 45C, 8 um noise.
    offset : sequence of 3 float, optional
        Mount offset U1, V1, W1 in mm; default the thesis digitizer.
    speed : float
        Sweep speed, mm/s.
    bidirectional : bool
        Alternate forward and reverse sweeps (default: all forward).
    jitter : float
        Per-scan standard deviation of where the artefact really sits, mm per
        axis (fixture and machine repeatability between sweeps): a floor of a
        few micrometres under the ballbar figures, as on a real machine.
    scan_interval : float
        Seconds between the starts of two sweeps (default 20 s: the 20
        positions take about 13 minutes).
    calibrated : sequence of {'length', 'radius'}
        Record the bar length at 20 C and the ball radius as calibrated values
        in ``run.artefact`` (``calibrated_length_mm``, ``calibrated_radius_mm``).
    reference_poses : sequence of (alpha, beta, gamma)
        After the ballbar, scan the reference sphere (``reference_sphere()``)
        once at each of these poses (feature 'reference', position and ball
        -1): the same sphere seen from several poses.
    seed : int
        Noise seed; the same seed gives the same run.
    progress : callable, optional
        Called as ``progress(done, total)`` after each sweep.
    repeat_scans : int
        Sweeps to repeat at the end of the run (after the reference
        scans), each the same ball at the same pose again, the artefact not
        moved (its placement redrawn with ``jitter``, the scanner's noise
        new): ball 1 then ball 2 of position 1, then of position 2, ... So
        the run carries its own noise floor: the disagreement of a ball's
        repeated centres is the per-scan reproducibility (Type A;
        :mod:`cmmpose.diagnosis.floor`). 0 (the default) leaves the run as
        it was; the earlier sweeps are the same whatever the number.

    Returns
    -------
    run : Run
        What the machine records.
    truth : (dict of ndarray, dict)
        ``true_xyz`` (N, 3) mm of every point, ``ball_centres`` (P, 2, 3) mm,
        ``true_lengths`` (P,) mm; and a description of the effects. Save it with
        ``run.save(dir, truth=truth)``; analysis never reads it.
    """
    maps = ErrorMapSet.thesis() if maps is None else maps
    scanner = scanner or Scanner()
    offset = MountOffset.thesis() if offset is None else MountOffset(*(float(x) for x in offset))
    machine = TruthMachine(maps, effects)
    rng = np.random.default_rng(seed)
    plan = _layout(layout)
    calibrated = tuple(calibrated)
    _check_sweeps(calibrated, scan_interval, jitter, speed, scanner)
    reference_poses = [tuple(float(x) for x in p) for p in reference_poses]
    repeat_scans = check_repeat_scans(repeat_scans, 2 * len(plan))
    total = 2 * len(plan) + len(reference_poses) + repeat_scans

    # Jitter has its own stream, drawn up front: the same seed gives the
    # same artefact placements whatever effects change the point counts.
    placements = np.random.default_rng([seed, 0x6A17]).normal(0.0, jitter, (total, 3)) if jitter else np.zeros((total, 3))

    def mean_temperature(t):
        return float(temperature(np.array([t]))[0]) if callable(temperature) else float(temperature)

    def artefact_scale(t):
        return float(np.prod([e.artefact_scale(mean_temperature(t)) for e in effects]))
    rec = SweepRecorder(machine, offset, scanner, temperature, speed, scan_interval, placements, rng, progress, total)
    ref = reference_sphere()
    for sweep in _sweeps(plan, layout, reference_poses, ref, repeat_scans, bidirectional,
                         lambda k: artefact_scale((2 * k) * scan_interval)):
        rec.sweep_over(*sweep)
    points, scans, pose_table, true_xyz = rec.tables()
    duration = total * scan_interval
    # Each effect says how far each thermocouple role reads above the mean;
    # channels of roles the effects bring are logged when an effect warms them.
    extra = [(c, r) for c, r in effect_channels() if r in machine.role_offsets(np.zeros(1))]
    log = thermocouple_log(duration, temperature, role_offsets=machine.role_offsets, extra_channels=extra, rng=rng)
    lengths = np.array([p.length for p, _ in plan])
    artefact = _ballbar_artefact(layout, len(plan), lengths, calibrated, ref.radius if reference_poses else None)
    run = Run(
        points=points,
        scans=scans,
        poses=pose_table,
        temperatures=log,
        temperature_channels=[{"name": c, "role": r} for c, r in (*CHANNELS, *extra)],
        artefact=artefact,
        maps={"kind": "bundled", "name": "thesis"} if maps is not None else {},
        metadata={"simulated": True, "seed": seed, "speed_mm_s": speed, "jitter_mm": jitter,
                  **({"repeat_scans": repeat_scans} if repeat_scans else {}),
                  "temperature_C": temperature if not callable(temperature) else "time series"},
    )
    truth = (
        {"true_xyz": true_xyz, "ball_centres": np.array([[p.ball1, p.ball2] for p, _ in plan]),
         "true_lengths": lengths},
        {"effects": [{"name": e.name, **asdict(e)} for e in effects], "layout": layout},
    )
    return run, truth


def _sweeps(plan, layout: str, reference_poses, ref, repeat_scans: int, bidirectional: bool, bar_scale):
    """Every sweep of a ballbar test in the order it is scanned, as ``SweepRecorder.sweep_over`` takes it: each
    position's two balls (the bar's length scaled by ``bar_scale(position index)``), the reference sphere at each
    of its poses, then the repeated ball scans (the same ball again, where it was: its own jitter, new noise)."""
    for k, (position, w_axis) in enumerate(plan):
        pose = _pose(position, w_axis, layout)
        c1, c2 = np.asarray(position.ball1, float), np.asarray(position.ball2, float)
        c2 = c1 + (c2 - c1) * bar_scale(k)
        for b, centre in enumerate((c1, c2), start=1):
            scan_id = 2 * k + b - 1
            direction = -1 if bidirectional and scan_id % 2 else 1
            yield scan_id, pose, centre, BALL_RADIUS, direction, "ball", k + 1, b
    for j, rpose in enumerate(reference_poses):
        yield 2 * len(plan) + j, rpose, ref.centre, ref.radius, 1, "reference", -1, -1
    for j in range(repeat_scans):
        k, b = divmod(j, 2)
        position, w_axis = plan[k]
        c1, c2 = np.asarray(position.ball1, float), np.asarray(position.ball2, float)
        c2 = c1 + (c2 - c1) * bar_scale(k)
        scan_id = 2 * len(plan) + len(reference_poses) + j
        direction = -1 if bidirectional and (2 * k + b) % 2 else 1
        yield scan_id, _pose(position, w_axis, layout), (c1, c2)[b], BALL_RADIUS, direction, "ball", k + 1, b + 1


def _check_sweeps(calibrated: tuple, scan_interval, jitter, speed, scanner) -> None:
    """The ballbar simulation's options, checked: what is calibrated, the time between scans, the placement
    jitter, and a sweep speed at which enough profiles cross each ball."""
    if set(calibrated) - {"length", "radius"}:
        raise InputError(f"calibrated: expected a subset of ('length', 'radius'), got {calibrated!r}")
    check_timing(scan_interval, jitter, speed)
    fastest = 2 * BALL_RADIUS * scanner.profile_rate / MIN_PROFILES_PER_BALL
    if speed > fastest:
        raise InputError(f"speed: {speed:.6g} mm/s lets fewer than {MIN_PROFILES_PER_BALL} profiles cross a ball of "
                         f"radius {BALL_RADIUS:g} mm at {scanner.profile_rate:g} profiles/s: at most {fastest:.3g} mm/s",
                         what="speed", value=f"{speed:.6g}", unit="mm/s")


def _ballbar_artefact(layout: str, positions: int, lengths: np.ndarray, calibrated: tuple,
                      reference_radius: float | None) -> dict:
    """run.json's ``artefact`` of a simulated ballbar run: its calibrated values as asked, the reference
    sphere's radius when it was scanned."""
    artefact = {"kind": "ballbar", "layout": layout, "ball_radius_mm": BALL_RADIUS, "positions": positions}
    if "length" in calibrated:
        artefact["calibrated_length_mm"] = float(np.mean(lengths))
    if "radius" in calibrated:
        artefact["calibrated_radius_mm"] = BALL_RADIUS
    if reference_radius is not None:
        artefact["reference_sphere"] = {"radius_mm": reference_radius}
    return artefact


def simulate_reference_scan(
    maps: ErrorMap | ErrorMapSet | None = None,
    temperature: Temperature = 20.0,
    pose=B89_POSE,
    offset=None,
    effects: Sequence[Effect] = (),
    *,
    sphere: Sphere | None = None,
    scanner: Scanner | None = None,
    speed: float = 10.0,
    seed: int = 0,
):
    """Scan the reference sphere on its tower (thesis Figure 4-7) with the
    digitizer at ``pose``, sweeping along the axis nearest to w: the data the
    alignment calibration (D0, E0, F0 and the mount offset) starts from.

    Parameters
    ----------
    maps : ErrorMap or ErrorMapSet, optional
        The machine's real errors; default the thesis maps.
    temperature : float or callable
        Machine temperature, C, or a function of time (s).
    pose : sequence of 3 float
        Digitizer pose (alpha, beta, gamma), degrees.
    offset : sequence of 3 float, optional
        Mount offset, mm; default the thesis digitizer.
    effects : sequence of Effect
        Extra physics (e.g. ``Alignment`` for a pose to be recovered).
    sphere : Sphere, optional
        Default ``reference_sphere()``.
    scanner : Scanner, optional
        Default Hyscan 45C.
    speed : float
        mm/s.
    seed : int
        Noise seed.

    Returns
    -------
    ScanData
        Points, recorded readings and truth; ``sphere.centre`` is the true centre.
    """
    maps = ErrorMapSet.thesis() if maps is None else maps
    sphere = sphere or reference_sphere()
    offset = MountOffset.thesis() if offset is None else MountOffset(*(float(x) for x in offset))
    ends = layouts.sweep_readings(sphere.centre, pose, offset, radius=sphere.radius)
    a = int(np.argmax(np.abs(ends[1] - ends[0])))
    lo, hi = sorted((ends[0][a], ends[1][a]))
    start = ends[0].copy()
    start[a] = lo - SWEEP_MARGIN
    sweep = Sweep(start=tuple(start), axis="XYZ"[a], length=hi - lo + 2 * SWEEP_MARGIN, speed=speed)
    return simulate_sweep(TruthMachine(maps, effects), sphere, pose, offset, sweep, temperature,
                          scanner=scanner, rng=np.random.default_rng(seed))
