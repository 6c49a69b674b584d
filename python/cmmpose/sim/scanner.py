"""A line scanner (Hymarc Hyscan 45C, thesis Table 17) sweeping over an
artefact while one CMM axis moves: every profile time-stamped, the points of a
profile found in Rust (rust/core/src/scanner.rs)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import _core
from ..errors import InputError
from ..pose import Pose, digitizer, pose_tuple
from ..effects import Effect
from ..scanner import Scanner
from .machine import Temperature, TruthMachine

#: Most profiles one simulated sweep may take (a slower sweep is a typo: 1e-320 mm/s).
MAX_PROFILES_PER_SWEEP = 10_000

AXES = {"X": 0, "Y": 1, "Z": 2}


@dataclass(frozen=True)
class Sweep:
    """One CMM axis moving at constant speed while the scanner takes profiles.

    Parameters
    ----------
    start : array_like, shape (3,)
        Scale reading D, E, F (mm) at the first profile.
    axis : {'X', 'Y', 'Z'}
        The moving axis.
    length : float
        Travel, mm (> 0).
    speed : float
        mm/s (> 0).
    direction : {+1, -1}
        Forward (+1) or reverse (-1) along the axis.
    """

    start: tuple[float, float, float]
    axis: str = "X"
    length: float = 80.0
    speed: float = 10.0
    direction: int = 1

    def __post_init__(self):
        if self.axis not in AXES:
            raise InputError(f"axis: expected 'X', 'Y' or 'Z', got {self.axis!r}")
        if self.direction not in (1, -1):
            raise InputError(f"direction: expected +1 or -1, got {self.direction!r}")
        if not (self.length > 0 and self.speed > 0):
            raise InputError("length and speed must be positive (mm, mm/s)")

    def positions(self, t: np.ndarray) -> np.ndarray:
        """Scale readings (K, 3) mm at times t (s) after the first profile."""
        s = np.tile(np.asarray(self.start, dtype=float), (len(t), 1))
        s[:, AXES[self.axis]] += self.direction * self.speed * t
        return s


@dataclass
class ScanData:
    """One simulated sweep: what the machine records, and the truth.

    Attributes
    ----------
    t : ndarray (N,)
        Profile time stamp of each point, s.
    uv : ndarray (N, 2)
        Reported scan-plane coordinates, mm.
    scales : ndarray (N, 3)
        Recorded scale readings D, E, F, mm.
    profile : ndarray (N,)
        Profile index of each point.
    true_xyz : ndarray (N, 3)
        Where each point really is (before scanner noise and errors), mm.
    temperatures : dict of str -> ndarray
        The machine's real temperatures at each point, by name (see
        TruthMachine.states): ``temperature`` (N,) C, ``axis_temperature``
        (N, 3) C, ``gradient`` (N,) K, ...
    """

    t: np.ndarray
    uv: np.ndarray
    scales: np.ndarray
    profile: np.ndarray
    true_xyz: np.ndarray
    temperatures: dict


def simulate_sweep(
    machine: TruthMachine,
    artefact,
    pose: Pose | tuple,
    offset,
    sweep: Sweep,
    temperature: Temperature = 20.0,
    *,
    scanner: Scanner | None = None,
    effects: tuple[Effect, ...] | None = None,
    t0: float = 0.0,
    rng: np.random.Generator | int | None = None,
) -> ScanData:
    """Scan ``artefact`` with the digitizer at ``pose``/``offset`` during ``sweep``.

    Parameters
    ----------
    machine : TruthMachine
        The real machine.
    artefact : object with ``surfaces()``
        Sphere, Ballbar, Plane (``cmmpose.sim.artefacts``).
    pose : Pose or (alpha, beta, gamma)
        Calibrated digitizer pose, degrees.
    offset : sequence of 3 float
        Calibrated mount offset U1, V1, W1, mm.
    sweep : Sweep
        Axis motion.
    temperature : float or callable
        Machine mean temperature, C, or a function of time (s).
    scanner : Scanner, optional
        Default: Hyscan 45C.
    effects : tuple of Effect, optional
        Scanner-side effects (pose, latency, scanner hooks). Default: the
        machine's own effects list (one list drives both sides).
    t0 : float
        Time stamp of the first profile, s.
    rng : Generator or int, optional
        Noise source (seed).
    """
    scanner = scanner or Scanner()
    effects = machine.effects if effects is None else tuple(effects)
    rng = np.random.default_rng(rng)
    with np.errstate(over="ignore", divide="ignore"):
        span = float(sweep.length) / float(sweep.speed) * float(scanner.profile_rate)
    if not (np.isfinite(span) and span < MAX_PROFILES_PER_SWEEP):
        raise InputError(f"speed: {sweep.speed:.6g} mm/s over a {sweep.length:.6g} mm sweep at "
                         f"{scanner.profile_rate:g} profiles/s would take more than {MAX_PROFILES_PER_SWEEP:,} "
                         f"profiles: too slow (at least {sweep.length * scanner.profile_rate / MAX_PROFILES_PER_SWEEP:.3g}"
                         " mm/s)", what="speed", value=f"{sweep.speed:.6g}", unit="mm/s")
    n_profiles = int(np.floor(span)) + 1
    dt = np.arange(n_profiles) / scanner.profile_rate
    t = t0 + dt
    true_scales = sweep.positions(dt)
    states = machine.states(t, temperature)
    frames = machine.frames(true_scales, states)
    true_pose, true_offset = np.array(pose_tuple(pose), dtype=float), np.asarray(offset, dtype=float)
    for e in effects:
        true_pose, true_offset = e.pose(true_pose, true_offset)
    surfaces = [(k, [float(x) for x in v]) for k, v in artefact.surfaces()]
    pts = _core.scan_profiles(
        frames, digitizer(true_pose, true_offset), surfaces, u_range=tuple(scanner.u_range),
        v_range=tuple(scanner.v_range), points_per_profile=scanner.points_per_profile,
        max_incidence_deg=scanner.max_incidence,
    )
    index = pts["profile"]
    uv = np.column_stack([pts["u"], pts["v"]])
    theta = np.degrees(np.arccos(np.clip(pts["cos_incidence"], -1.0, 1.0)))
    scanner_terms = {k: v for e in effects if e.on_scanner for k, v in e.truth_terms().items()}
    if scanner_terms:
        # The scanner's own errors: the Rust terms, applied forward.
        uv = _core.scanner_forward(uv, inputs={"incidence": np.ascontiguousarray(theta)}, effects=scanner_terms)
    u, v = uv[:, 0], uv[:, 1]
    v = v + rng.normal(0.0, scanner.noise, len(v)) if scanner.noise else v
    u = u + rng.normal(0.0, scanner.noise_u, len(u)) if scanner.noise_u else u
    latency = sum(e.latency() for e in effects)
    recorded = sweep.positions(dt - latency)  # the scale latch precedes the profile by the latency
    return ScanData(
        t=t[index],
        uv=np.column_stack([u, v]),
        scales=recorded[index],
        profile=index,
        true_xyz=np.ascontiguousarray(pts["xyz"]),
        temperatures={k: v[index] for k, v in states.items()},
    )
