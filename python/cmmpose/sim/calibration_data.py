"""Simulated alignment-calibration data with a known truth (thesis chapter 4,
section 5.3): optical-vernier points on the scan plane, plane scans taken while
the machine moves, reference-sphere scans at several poses, and the true
alignment readings to test the solvers of ``cmmpose.calibration`` against.

Pose errors to recover come from the effects: ``Alignment`` makes the
true pose the given (nominal) one plus its angles, ``MountOffset`` the
true offset the given one plus its lengths. Units: mm, degrees, degrees C, s.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .. import _core
from .._arrays import as_triple
from ..errormap import ErrorMap, ErrorMapSet
from ..errors import InputError, InputTypeError
from ..pose import MountOffset, pose_tuple
from .artefacts import Plane, Sphere, reference_sphere
from ..effects import Effect
from .machine import Temperature, TruthMachine
from .runs import simulate_reference_scan
from .scanner import AXES, ScanData, Scanner, Sweep, simulate_sweep

__all__ = [
    "VernierData",
    "PlaneScanData",
    "ReferenceScan",
    "true_pose_and_offset",
    "true_alignment_reading",
    "vernier_points",
    "plane_scan",
    "reference_sphere_scans",
    "VERNIER_NOISE",
]

#: Default standard uncertainty of a vernier position along the scan-plane
#: normal, mm. The thesis gives no figure for the optical vernier; its dual
#: photodiode finds the same laser line the scanner triangulates, so the
#: digitizer's probing uncertainty (Table 17: 9 um, 1 sigma) is taken.
VERNIER_NOISE = 0.009


def _maps(maps):
    return ErrorMapSet.thesis() if maps is None else maps


def _middle(maps) -> np.ndarray:
    """The middle of the machine's mapped volume, as scale readings (mm)."""
    m = maps.maps[0] if isinstance(maps, ErrorMapSet) else maps
    return np.array([(lo + hi) / 2 for lo, hi in m.ranges])


def _offset(offset) -> np.ndarray:
    return np.array(MountOffset.thesis() if offset is None else as_triple("offset", offset))


def true_pose_and_offset(pose, offset=None, effects: Sequence[Effect] = ()) -> tuple[np.ndarray, np.ndarray]:
    """The pose (degrees) and mount offset (mm) the scanner really has: the
    given (calibrated, nominal) ones changed by the effects' pose hooks
    (``Alignment``, ``MountOffset``)."""
    p = np.array(pose_tuple(pose), dtype=float)
    o = _offset(offset)
    for e in effects:
        p, o = e.pose(p, o)
    return np.asarray(p, dtype=float), np.asarray(o, dtype=float)


def _solve_readings(machine: TruthMachine, targets, local, pose_t, offset_t, temperature, t=0.0) -> np.ndarray:
    """Readings S (K, 3) at which the true point P(S) + R(S) E ((u, v, 0) - l1)
    lands on ``targets`` (K, 3) for scan-plane coordinates ``local`` (K, 2)."""
    e = np.asarray(_core.euler313(*pose_t))
    uvw = np.column_stack([local, np.zeros(len(local))])
    lever = uvw - offset_t  # (K, 3) in u, v, w
    states = machine.states(np.full(len(targets), float(t)), temperature)
    s = targets - lever @ e.T
    for _ in range(50):  # fixed point: the machine errors are micrometres per mm
        f = machine.frames(s, states)
        lever = uvw - offset_t * f["mount_scale"][:, None]
        x = f["p"] + np.einsum("kij,jl,kl->ki", f["r"], e, lever)
        ds = targets - x
        s = s + ds
        if np.abs(ds).max() < 1e-12:
            break
    return s


def true_alignment_reading(centre, pose, offset=None, *, maps=None, temperature: Temperature = 20.0,
                           effects: Sequence[Effect] = (), t: float = 0.0) -> np.ndarray:
    """The scale reading (D0, E0, F0, mm) at which the true laser origin sits at
    ``centre`` on the truth machine: what :func:`cmmpose.calibration.reference_centre_reading`
    should recover.

    Parameters
    ----------
    centre : array_like, shape (3,)
        Sphere centre in machine coordinates, mm.
    pose : Pose or sequence of 3 float
        Calibrated (nominal) pose, degrees; effects make the true one.
    offset : sequence of 3 float, optional
        Calibrated mount offset, mm; default the thesis digitizer.
    maps : ErrorMap or ErrorMapSet, optional
        The machine's errors; default the thesis maps.
    temperature : float or callable
        Machine temperature, C, or a function of time (s).
    effects : sequence of Effect
        As in the scans.
    t : float
        Time, s (for a time-dependent temperature).
    """
    machine = TruthMachine(_maps(maps), effects)
    pose_t, off_t = true_pose_and_offset(pose, offset, effects)
    c = np.asarray(as_triple("centre", centre))[None, :]
    return _solve_readings(machine, c, np.zeros((1, 2)), pose_t, off_t, temperature, t)[0]


@dataclass(frozen=True)
class VernierData:
    """Optical-vernier readings and their truth.

    Attributes
    ----------
    points : ndarray (n, 3)
        Scale readings D, E, F (mm) at which the laser line fell on the
        vernier, in the order taken (counter-clockwise about +w).
    field : ndarray (n, 2)
        Where the vernier was in the scan plane each time, u and v, mm.
    hsv : ndarray (3,)
        The vernier's position in machine coordinates, mm.
    true_pose : ndarray (3,)
        alpha, beta, gamma the scanner really had, degrees.
    true_offset : ndarray (3,)
        The mount offset it really had, mm.
    """

    points: np.ndarray
    field: np.ndarray
    hsv: np.ndarray
    true_pose: np.ndarray
    true_offset: np.ndarray


def vernier_points(pose, offset=None, n: int = 5, noise: float = VERNIER_NOISE, *, maps=None,
                   temperature: Temperature = 20.0, effects: Sequence[Effect] = (),
                   hsv=None, spread: float = 25.0, seed=None) -> VernierData:
    """Optical-vernier alignment data (thesis section 4.3): the scale readings at
    which the laser line lands on a fixed vernier (HSV) placed at ``n``
    well-spaced points of the field of view.

    The vernier sits at ``hsv``; for the k-th point the machine is driven to
    the reading at which the true scan plane passes through it with the
    vernier at (u_k, v_k) = ``spread`` (cos t_k, sin t_k), t_k = 90 + 360 k / n
    degrees: counter-clockwise seen from +w. The vernier's null is found
    within ``noise`` along the scan plane's normal (Gaussian).

    Parameters
    ----------
    pose : Pose or sequence of 3 float
        Calibrated (nominal) pose, degrees; ``Alignment`` in ``effects``
        makes the true one.
    offset : sequence of 3 float, optional
        Mount offset, mm; default the thesis digitizer.
    n : int
        Number of points, >= 3.
    noise : float
        Standard deviation along the normal, mm (default 9 um, see ``VERNIER_NOISE``).
    maps : ErrorMap or ErrorMapSet, optional
        The machine's errors; default the thesis maps.
    temperature : float or callable
        Machine temperature, C (time 0 s).
    effects : sequence of Effect
        Extra physics of the truth machine.
    hsv : array_like, shape (3,), optional
        Vernier position, machine coordinates, mm. Default: where the
        readings fall in the middle of the mapped volume (error-free model,
        nominal pose and offset).
    spread : float
        Radius of the circle of vernier positions in the scan plane, mm
        (field of view +-30 mm).
    seed : int or Generator, optional
        Noise source.

    Returns
    -------
    VernierData
    """
    n = int(n)
    if n < 3:
        raise InputError(f"n: the vernier needs at least 3 points, got {n}")
    if not (np.isfinite(noise) and noise >= 0):
        raise InputError(f"noise: must be >= 0 (mm), got {noise}")
    if not (np.isfinite(spread) and 0 < spread <= 30):
        raise InputError(f"spread: must be in (0, 30] mm (the field of view), got {spread}")
    rng = np.random.default_rng(seed)
    maps = _maps(maps)
    machine = TruthMachine(maps, effects)
    pose_t, off_t = true_pose_and_offset(pose, offset, effects)
    if hsv is None:
        hsv = _middle(maps) - np.asarray(_core.euler313(*pose_tuple(pose))) @ _offset(offset)
    h = np.asarray(as_triple("hsv", hsv))
    ang = np.radians(90.0 + 360.0 * np.arange(n) / n)
    local = spread * np.column_stack([np.cos(ang), np.sin(ang)])
    s = _solve_readings(machine, np.tile(h, (n, 1)), local, pose_t, off_t, temperature)
    w = np.asarray(_core.euler313(*pose_t))[:, 2]
    s = s + rng.normal(0.0, noise, n)[:, None] * w if noise else s
    return VernierData(points=s, field=local, hsv=h, true_pose=pose_t, true_offset=off_t)


@dataclass(frozen=True)
class PlaneScanData:
    """A plane scanned by one or more sweeps, and its truth.

    Attributes
    ----------
    uv : ndarray (N, 2)
        Reported scan-plane coordinates, mm.
    scales : ndarray (N, 3)
        Recorded scale readings, mm.
    t : ndarray (N,)
        Time stamps, s.
    sweep : ndarray (N,)
        Index of the sweep each point belongs to.
    true_xyz : ndarray (N, 3)
        True positions, mm.
    plane : Plane
        The artefact (its ``normal`` faces the scanner).
    true_pose, true_offset : ndarray (3,)
        What the scanner really had, degrees and mm.
    """

    uv: np.ndarray
    scales: np.ndarray
    t: np.ndarray
    sweep: np.ndarray
    true_xyz: np.ndarray
    plane: Plane
    true_pose: np.ndarray
    true_offset: np.ndarray


def _nearest_axis(v: np.ndarray) -> tuple[int, float]:
    i = int(np.argmax(np.abs(v)))
    return i, float(np.sign(v[i]))


def plane_scan(pose, offset=None, *, plane: Plane | None = None, axes: Sequence[str] | None = None,
               centre=None, length: float = 60.0, speed: float = 10.0, maps=None,
               temperature: Temperature = 20.0, effects: Sequence[Effect] = (), scanner: Scanner | None = None,
               seed=0) -> PlaneScanData:
    """A flat plane scanned while the machine moves (thesis section 4.3, gamma).

    Each sweep moves one axis by ``length`` centred on the reading at which
    the laser origin sits at ``centre`` (error-free model, nominal pose).

    Parameters
    ----------
    pose : Pose or sequence of 3 float
        Calibrated (nominal) pose, degrees; ``Alignment`` in ``effects``
        makes the true one.
    offset : sequence of 3 float, optional
        Mount offset, mm; default the thesis digitizer.
    plane : Plane, optional
        The artefact. Default: a 300 mm disc through ``centre`` whose normal is
        the machine axis nearest to the scanner's v (a face like the granite
        table, seen from the scanner).
    axes : sequence of {'X', 'Y', 'Z'}, optional
        One sweep per entry. Default: one sweep along the machine axis nearest to w.
    centre : array_like, shape (3,), optional
        Where the laser origin is at mid-sweep, mm. Default: where the
        mid-sweep reading is the middle of the mapped volume.
    length, speed : float
        Sweep travel (mm) and speed (mm/s).
    maps, temperature, effects, scanner
        As in :func:`cmmpose.sim.simulate_sweep` (default maps: the thesis's).
    seed : int or Generator
        Noise source.

    Returns
    -------
    PlaneScanData
    """
    e = np.asarray(_core.euler313(*pose_tuple(pose)))
    l1 = _offset(offset)
    maps = _maps(maps)
    c = _middle(maps) - e @ l1 if centre is None else np.asarray(as_triple("centre", centre))
    if plane is None:
        i, sg = _nearest_axis(e[:, 1])
        normal = np.zeros(3)
        normal[i] = sg
        plane = Plane(c, normal, radius=300.0)
    if axes is None:
        axes = ("XYZ"[_nearest_axis(e[:, 2])[0]],)
    if len(axes) == 0:
        raise InputError("axes: at least one sweep")
    rng = np.random.default_rng(seed)
    machine = TruthMachine(maps, effects)
    s_mid = c + e @ l1
    parts = []
    for k, ax in enumerate(axes):  # one simulated sweep each
        if ax not in AXES:
            raise InputError(f"axes[{k}]: expected 'X', 'Y' or 'Z', got {ax!r}")
        start = s_mid.copy()
        start[AXES[ax]] -= length / 2
        d = simulate_sweep(machine, plane, pose, l1, Sweep(start=tuple(start), axis=ax, length=length, speed=speed),
                           temperature, scanner=scanner, t0=60.0 * k, rng=rng)
        parts.append((k, d))
    pose_t, off_t = true_pose_and_offset(pose, l1, effects)
    return PlaneScanData(
        uv=np.concatenate([d.uv for _, d in parts]), scales=np.concatenate([d.scales for _, d in parts]),
        t=np.concatenate([d.t for _, d in parts]),
        sweep=np.concatenate([np.full(len(d.t), k, np.int32) for k, d in parts]),
        true_xyz=np.concatenate([d.true_xyz for _, d in parts]), plane=plane, true_pose=pose_t, true_offset=off_t)


@dataclass(frozen=True)
class ReferenceScan:
    """One reference-sphere scan at one pose, and its truth.

    Attributes
    ----------
    pose : tuple of 3 float
        The calibrated (nominal) pose the scan was planned with, degrees.
    data : ScanData
        The scan (uv, scales, time stamps, true points).
    true_reading : ndarray (3,)
        The reading at which the true laser origin sits at the sphere centre, mm.
    true_pose, true_offset : ndarray (3,)
        What the scanner really had, degrees and mm.
    centre : ndarray (3,)
        True sphere centre, mm.
    """

    pose: tuple
    data: ScanData
    true_reading: np.ndarray
    true_pose: np.ndarray
    true_offset: np.ndarray
    centre: np.ndarray


def reference_sphere_scans(poses, offset=None, *, maps=None, temperature: float = 20.0,
                           effects: Sequence[Effect] = (), sphere: Sphere | None = None,
                           scanner: Scanner | None = None, speed: float = 10.0, seed: int = 0) -> list[ReferenceScan]:
    """Scan the reference sphere once at each pose (thesis Figure 4-7, section
    5.3: three alignments give the mount offset), with
    :func:`cmmpose.sim.simulate_reference_scan`.

    Parameters
    ----------
    poses : sequence of (alpha, beta, gamma)
        Calibrated (nominal) poses, degrees; e.g.
        ``cmmpose.calibration.STANDARD_POSES``.
    offset : sequence of 3 float, optional
        Mount offset the scans are planned with, mm; default the thesis digitizer.
        ``MountOffset`` in ``effects`` makes the true one.
    maps : ErrorMap or ErrorMapSet, optional
        The machine's errors; default the thesis maps.
    temperature : float
        Machine temperature, C.
    effects : sequence of Effect
        Extra physics.
    sphere : Sphere, optional
        Default ``reference_sphere()``.
    scanner : Scanner, optional
        Default Hyscan 45C (8 um noise).
    speed : float
        mm/s.
    seed : int
        Noise seed; each pose gets its own stream from it.

    Returns
    -------
    list of ReferenceScan
    """
    poses = [pose_tuple(p) for p in poses]
    if not poses:
        raise InputError("poses: at least one pose")
    maps = _maps(maps)
    if not isinstance(maps, (ErrorMap, ErrorMapSet)):
        raise InputTypeError(f"maps: expected an ErrorMap or ErrorMapSet, got {type(maps).__name__}")
    sphere = sphere or reference_sphere()
    l1 = _offset(offset)
    seeds = np.random.SeedSequence(seed).generate_state(len(poses))
    out = []
    for p, sd in zip(poses, seeds):  # one scan per pose
        d = simulate_reference_scan(maps, temperature, pose=p, offset=l1, effects=effects, sphere=sphere,
                                    scanner=scanner, speed=speed, seed=int(sd))
        pose_t, off_t = true_pose_and_offset(p, l1, effects)
        truth = true_alignment_reading(sphere.centre, p, l1, maps=maps, temperature=temperature, effects=effects)
        out.append(ReferenceScan(pose=p, data=d, true_reading=truth, true_pose=pose_t, true_offset=off_t,
                                 centre=np.asarray(sphere.centre, dtype=float)))
    return out
