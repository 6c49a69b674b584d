"""Simulated runs of an artefact at one or more placements (ball plates, step
gauges, ballbars, spheres; docs/artefacts.md): every ball of every placement
scanned by one sweep (the per-ball machinery of :mod:`cmmpose.sim.runs`),
stored as a ``cmmpose.Run`` that embeds the artefact and its placements, with
the truth kept apart."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import asdict

import numpy as np

from ..artefacts import Artefact
from ..effects import Effect, channels as effect_channels
from ..errormap import ErrorMap, ErrorMapSet
from ..errors import InputError
from ..placement import PROFILES_PER_BALL, Placement, ball_speed, check_repeat_scans, parse, plan, run_record
from ..run import Run
from .machine import Temperature, TruthMachine
from .runs import SCAN_INTERVAL, SweepRecorder, check_timing
from .scanner import Scanner
from .thermocouples import CHANNELS, thermocouple_log

__all__ = ["simulate_artefact_run", "PROFILES_PER_BALL"]

def simulate_artefact_run(
    artefact: Artefact,
    placements: Sequence[Placement | str],
    maps: ErrorMap | ErrorMapSet | None = None,
    temperature: Temperature = 20.0,
    effects: Sequence[Effect] = (),
    *,
    machine=None,
    scanner: Scanner | None = None,
    speed: float = 35.0,
    bidirectional: bool = False,
    jitter: float = 0.0,
    scan_interval: float = SCAN_INTERVAL,
    seed: int = 0,
    progress: Callable[[int, int], None] | None = None,
    repeat_scans: int = 0,
) -> tuple[Run, tuple[dict[str, np.ndarray], dict]]:
    """Simulate an artefact measured at one or more placements.

    Parameters
    ----------
    artefact : Artefact
        What is measured (``cmmpose.artefacts.load_artefact``); its balls
        really sit at its calibrated centres, expanded from the certificate's
        temperature to the machine's with its own coefficient (the part takes
        the machine mean temperature), times any ``artefact-expansion`` effect
        (an error in that coefficient).
    placements : sequence of Placement or str
        Where it sits (``cmmpose.placement``: shorthands or layout names).
    maps : ErrorMap or ErrorMapSet, optional
        The machine's real errors; default the machine's maps.
    temperature : float or callable
        Machine mean temperature, C, or a function of time (s).
    effects : sequence of Effect
        Extra physics, unknown to the compensation.
    machine : cmmpose.machine.Machine, optional
        Travel, mount offset, pose and scanner; default the thesis machine.
    scanner : Scanner, optional
        Default the machine's.
    speed : float
        Sweep speed, mm/s; balls too small for ``PROFILES_PER_BALL``
        profiles across them at this speed are swept more slowly (the
        scans table records each sweep's speed).
    bidirectional : bool
        Alternate forward and reverse sweeps.
    jitter : float
        Per-scan standard deviation of where each ball really sits, mm per axis.
    scan_interval : float
        Seconds between the starts of two sweeps.
    seed : int
        Noise seed.
    progress : callable, optional
        ``progress(done, total)`` after each sweep.
    repeat_scans : int
        Sweeps repeated at the end, the artefact not moved: the first
        ``repeat_scans`` balls' scans again (their own jitter, new noise), so
        the run measures its own per-scan reproducibility, the diagnosis's
        noise floor. 0 (the default) leaves the run as it was.

    Returns
    -------
    run : Run
        What the machine records: scans with ``feature`` 'ball', ``position``
        the placement (1-based) and ``ball`` the ball's id; ``run.artefact``
        embeds the artefact (``definition``) and the placements.
    truth : (dict of ndarray, dict)
        ``true_xyz`` (N, 3) mm of every point, ``ball_centres`` (S, 3) mm
        where each scan's ball really was; and the effects and placements.

    Raises
    ------
    InputError
        A placement that leaves the travel (naming the ball and the axis),
        bad options.
    """
    from ..machine import Machine

    machine = Machine.thesis() if machine is None else machine
    maps = machine.maps() if maps is None else maps
    scanner = scanner or machine.scanner
    check_timing(scan_interval, jitter, speed)
    if not placements:
        raise InputError("placements: none given")
    parsed: list[Placement] = []
    for p in placements:
        parsed += parse(p, machine.travel) if isinstance(p, str) else [p]
    resolved, ball_scans = plan(parsed, artefact, machine)
    repeat_scans = check_repeat_scans(repeat_scans, len(ball_scans))
    ball_scans = list(ball_scans) + list(ball_scans)[:repeat_scans]
    truth_machine = TruthMachine(maps, effects)
    rng = np.random.default_rng(seed)
    total = len(ball_scans)
    shifts = np.random.default_rng([seed, 0x6A17]).normal(0.0, jitter, (total, 3)) if jitter else np.zeros((total, 3))

    def mean_temperature(t):
        return float(temperature(np.array([t]))[0]) if callable(temperature) else float(temperature)

    def scale(t):
        T = mean_temperature(t)
        return float(artefact.scale_to(T)) * float(np.prod([e.artefact_scale(T) for e in effects]))

    rec = SweepRecorder(truth_machine, machine.offset, scanner, temperature, speed, scan_interval, shifts, rng,
                        progress, total)
    centres = []
    for scan_id, bs in enumerate(ball_scans):
        pl = resolved[bs.position - 1]
        c = artefact.centres[artefact.index(bs.ball)]
        centre = pl.rotation @ ((c - artefact.centroid) * scale(scan_id * scan_interval)) + pl.centre
        centres.append(centre + shifts[scan_id])
        direction = -1 if bidirectional and scan_id % 2 else 1
        rec.sweep_over(scan_id, bs.pose, centre, artefact.calibrated_radius, direction, "ball", bs.position, bs.ball,
                       speed=ball_speed(speed, artefact.nominal_radius, scanner.profile_rate))
    points, scans, pose_table, true_xyz = rec.tables()
    extra = [(c, r) for c, r in effect_channels() if r in truth_machine.role_offsets(np.zeros(1))]
    log = thermocouple_log(total * scan_interval, temperature, role_offsets=truth_machine.role_offsets,
                           extra_channels=extra, rng=rng)
    record = run_record(artefact, resolved)
    run = Run(
        points=points, scans=scans, poses=pose_table, temperatures=log,
        temperature_channels=[{"name": c, "role": r} for c, r in (*CHANNELS, *extra)],
        artefact=record, maps={},
        metadata={"simulated": True, "seed": seed, "speed_mm_s": speed, "jitter_mm": jitter,
                  **({"repeat_scans": int(repeat_scans)} if repeat_scans else {}),
                  "temperature_C": temperature if not callable(temperature) else "time series"},
    )
    truth = ({"true_xyz": true_xyz, "ball_centres": np.array(centres)},
             {"effects": [{"name": e.name, **asdict(e)} for e in effects],
              "placements": [p.to_dict() for p in resolved], "artefact": artefact.kind})
    return run, truth
