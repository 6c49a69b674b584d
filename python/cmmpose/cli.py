"""The ``cmmpose`` command line."""

from __future__ import annotations

import json
import time
import warnings
from pathlib import Path

import click
import numpy as np
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn
from rich.table import Table

from . import effects as effects_registry
from ._arrays import as_triple
from ._json import dumps as strict_json
from .atomicfile import atomic_write, check_not_input, ensure_folder, raise_on_termination, write_text
from .compensation import warn_single_map
from .errormap import ErrorMap, ErrorMapSet
from .errors import CalibrationError, Error, InputError, MapTemperatureWarning
from .policy import LOG_HOLD, OUT_OF_RANGE, TEMPERATURE_TOLERANCE, cli_wording, shorten_numbers
from .pose import check_pose_angles
from .pointclouds import UNITS as POINT_UNITS
from .pointclouds import read_point_cloud, unit_factor
from .pointfiles import check_writable, read_points
from .filecompensation import compensate_file
from .pointformats._common import check_file
from .machine import example_names
from .metrics import STEEL_EXPANSION
from .scale import SCHEDULER_TIMEOUT, check_scheduler
from .cli_standards import (acceptance_cmd, acceptance_sphere_cmd, e3125_distances_cmd, interim_cmd, iso230_2_cmd,
                            map_specs)
from .cli_artefact import artefact_group, diagnose_plate_fits_cli, evaluate_artefact_run, simulate_artefact

console = Console(stderr=True)


def load_maps(specs: tuple[str, ...], machine=None) -> ErrorMap | ErrorMapSet:
    """'thesis' (bundled 20/25/30 C set), 'appendix-b' (22 C controller map),
    or paths: canonical .csv maps or controller .txt files; several make a
    set. With a machine: its maps when none are named, stacked as it is."""
    from .machine import read_maps

    return machine.maps(specs) if machine is not None else read_maps(specs)


def machine_option(f):
    """--machine FILE, the same on every command."""
    return click.option("--machine", "machine_file", type=click.Path(dir_okay=False), default=None,
                        help="Machine file (TOML: configuration, travel, maps, scanner, mount; "
                             "`cmmpose machine example`). Default: the thesis machine.")(f)


def machine_row(table, machine) -> None:
    """The machine a command used, in its summary table."""
    table.add_row("machine", f"{machine.name} ({machine.kinematics}; {machine.source})")


def kernel_report_rows(table, report, temperature_tolerance) -> None:
    """What the kernel clamped, held or extrapolated, in a summary table (rows only where it did)."""
    if report.clamped:
        x, y, z = report.clamped_position
        table.add_row("clamped", f"X {x}, Y {y}, Z {z}, temperature {report.clamped_temperature}")
    if report.held_temperature:
        table.add_row("held at the maps' edge",
                      f"{report.held_temperature:,} temperatures within {temperature_tolerance:g} K outside")
    if report.extrapolated_temperature:
        table.add_row("extrapolated", f"{report.extrapolated_temperature:,} temperatures, up to "
                                      f"{report.max_extrapolation:.2f} K beyond the maps")


def travel_notes(machine, built) -> list[str]:
    """Where a map misses the machine's travel (a point there cannot be compensated)."""
    return [f"the map covers {axis} {mlo:g}..{mhi:g} mm, less than {machine.name}'s travel {lo:g}..{hi:g} mm "
            f"({machine.source}): points beyond it cannot be compensated"
            for axis, (lo, hi), (mlo, mhi) in machine.uncovered(built.ranges)]


def triple(text: str, name: str) -> tuple[float, float, float]:
    if not text.strip():
        # An empty value would otherwise fall back to a default in silence.
        raise click.BadParameter("an empty value: give three comma-separated numbers, or leave the option out",
                                 param_hint=name)
    try:
        vals = tuple(float(x) for x in text.split(","))
    except ValueError:
        raise click.BadParameter(f"expected three comma-separated numbers, got {text!r}", param_hint=name) from None
    if len(vals) != 3:
        raise click.BadParameter(f"expected three comma-separated numbers, got {text!r}", param_hint=name)
    return vals  # type: ignore[return-value]


def pose_angles(text: str, name: str) -> tuple[float, float, float]:
    """Three pose angles alpha,beta,gamma in degrees from an option's ``text``:
    a usage error when empty, not three finite numbers or beyond +-360 deg."""
    try:
        return check_pose_angles(name, triple(text, name))
    except Error as exc:
        raise click.BadParameter(str(exc).removeprefix(f"{name}: "), param_hint=name) from None


def offset_mm(text: str, name: str) -> tuple[float, float, float]:
    """A mount offset U1,V1,W1 in mm from an option's ``text``: a usage error
    when empty or not three finite numbers."""
    try:
        return as_triple(name, triple(text, name))
    except Error as exc:
        raise click.BadParameter(str(exc).removeprefix(f"{name}: "), param_hint=name) from None


def check_outputs(outputs: dict, run_dirs=(), files=()) -> None:
    """``InputError`` if an output (flag -> path, None for not given) is one of the
    files the command reads: the runs' files (``cmmpose.run.RUN_FILES``) and ``files``
    (cmmpose.atomicfile.check_not_input: any spelling or link)."""
    from .run import RUN_FILES

    inputs = [Path(r) / n for r in run_dirs for n in RUN_FILES] + [f for f in files if f]
    for flag, path in outputs.items():
        check_not_input(path, inputs, flag)


def fail(exc: Exception) -> click.ClickException:
    """A library error as the CLI reports it: the Python argument names in
    the message replaced by this command's flags (or a note that it has none)."""
    return click.ClickException(cli_wording(str(exc), click.get_current_context(silent=True)))


def policy_options(log_hold: bool = True):
    """The temperature policy's flags, the same on every command (cmmpose.policy)."""

    def wrap(f):
        if log_hold:
            f = click.option("--log-hold", type=float, default=LOG_HOLD, show_default=True,
                             help="s: points this far outside the thermocouple log take its nearest reading "
                                  "(a recovered run); farther is an error.")(f)
        f = click.option("--temperature-tolerance", type=float, default=TEMPERATURE_TOLERANCE, show_default=True,
                         help="K: temperatures this close outside the maps are held at the edge and counted.")(f)
        f = click.option("--out-of-range", type=click.Choice(list(OUT_OF_RANGE)), default="raise",
                         show_default=True,
                         help="Beyond the tolerance: stop, clamp to the maps' ends, or extrapolate the maps "
                              "linearly in temperature (the largest distance is printed).")(f)
        return f

    return wrap


class _Commands(click.Group):
    """The command group: click's own messages (a bad option value echoed
    back) with numbers of more than 20 digits shortened (cmmpose.policy)."""

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except click.ClickException as exc:
            exc.message = shorten_numbers(exc.message)
            raise


def _scheduler_spec(ctx, param, value):
    """--scheduler: a usage error unless threads, processes or tcp://host:port."""
    try:
        return None if value is None else check_scheduler(value)
    except Error as exc:
        raise click.BadParameter(str(exc), param_hint="--scheduler") from None


def scheduler_options(help_text: str):
    """--scheduler and --scheduler-timeout, the same on every command that scales out (cmmpose.scale)."""

    def wrap(f):
        f = click.option("--scheduler-timeout", type=click.FloatRange(min=0, min_open=True, max=1e6),
                         default=SCHEDULER_TIMEOUT, show_default=True,
                         help="s: the longest wait for a scheduler at an address to accept the connection "
                              "and answer (a port that never answers is an error after it).")(f)
        return click.option("--scheduler", default=None, callback=_scheduler_spec, help=help_text)(f)

    return wrap


@click.group(cls=_Commands)
@click.version_option(package_name="cmmpose")
def main() -> None:
    """Error compensation of a laser line scanner on a CMM."""
    raise_on_termination()  # SIGTERM, SIGHUP: clean up temporary files as on Ctrl-C


@main.command("compensate")
@click.argument("points_in", metavar="IN", type=click.Path())
@click.argument("points_out", metavar="OUT", type=click.Path(writable=True))
@machine_option
@click.option("--maps", "maps", multiple=True, callback=map_specs,
              help="'thesis', 'appendix-b', or map files (.csv canonical, .txt controller); repeat for a set. "
                   "Default: the machine's maps.")
@click.option("--temperature", type=float, default=None,
              help="Machine temperature in C for every point (default: the T column, if the file has one).")
@click.option("--pose", default=None, help="alpha,beta,gamma in degrees (Euler 3-1-3). Default: the machine's.")
@click.option("--offset", default=None, help="U1,V1,W1 mount offset in mm. Default: the machine's.")
@click.option("--alignment", default=None,
              help="Pose and offset from this alignment in the library (`cmmpose calibrate alignment --name`).")
@click.option("--library", "library_file", type=click.Path(dir_okay=False), default=None,
              help="Alignment library (JSON) for --alignment. Default: the machine file's mount.alignments.")
@policy_options(log_hold=False)
@click.option("--nan-policy", type=click.Choice(["raise", "propagate"]), default="raise", show_default=True)
@scheduler_options("For a folder IN: 'threads' (default), 'processes', or a Dask scheduler address tcp://host:port "
                   "(needs the dask extra).")
def compensate_cmd(points_in, points_out, machine_file, maps, temperature, pose, offset, alignment, library_file,
                   out_of_range, temperature_tolerance, nan_policy, scheduler, scheduler_timeout) -> None:
    """Compensate scanner points IN (CSV, NPY, Parquet, PLY or XYZ: u, v, D, E, F[, T])
    into machine coordinates OUT (by suffix: CSV, NPY, Parquet, PLY, XYZ, PTS or E57;
    X, Y, Z in mm, E57 in metres). Any other column of IN (scan_id, intensity, ...)
    is written to OUT unchanged.

    IN may be a folder of Parquet files (a dataset): OUT is then a folder that
    gets one Parquet file per input, named after it, with X, Y, Z and the
    input's other columns, compensated on the --scheduler in bounded memory."""
    from .machine import load_machine

    try:
        machine = load_machine(machine_file)
        if alignment is not None:
            if pose is not None or offset is not None:
                raise click.UsageError("give --alignment or --pose/--offset, not both")
            pose, offset = _aligned(alignment, library_file or machine.alignments)
    except Error as exc:
        raise fail(exc) from None
    pose_t = pose_angles(pose, "--pose") if pose is not None else machine.pose.as_tuple()
    offset_t = offset_mm(offset, "--offset") if offset is not None else tuple(machine.offset)
    if Path(points_in).is_dir():
        return _compensate_dataset(points_in, points_out, machine, maps, temperature, pose_t, offset_t, out_of_range,
                                   temperature_tolerance, nan_policy, scheduler or "threads", scheduler_timeout)
    if scheduler is not None:
        raise click.BadParameter(f"{points_in} is a file; --scheduler is for a folder of Parquet files",
                                 param_hint="--scheduler")
    try:
        check_writable(points_out)  # before any work: a missing folder is found now, not after
        check_not_input(points_out, [points_in], "OUT")
        error_map = load_maps(maps, machine)
        size = check_file(points_in).stat().st_size
        # One bar over reading, compensating and writing, by bytes of input;
        # memory stays bounded by a few chunks whatever the file's size.
        with Progress(TextColumn("compensating"), BarColumn(), TextColumn("{task.percentage:>3.0f}%"),
                      TimeRemainingColumn(), console=console, disable=size < (32 << 20)) as bar, \
                warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", MapTemperatureWarning)
            task = bar.add_task("", total=size)
            done = compensate_file(points_in, points_out, error_map, pose_t, offset_t, temperature,
                                   out_of_range=out_of_range, nan_policy=nan_policy,
                                   temperature_tolerance=temperature_tolerance,
                                   progress=lambda at, _: bar.update(task, completed=at))
            bar.update(task, completed=size)
        for w in caught:
            if issubclass(w.category, MapTemperatureWarning):
                console.print(f"[yellow]warning:[/] {escape(str(w.message))}")
            else:
                warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    except Error as exc:
        raise fail(exc) from None
    report, elapsed, t_all = done.report, done.kernel_seconds, done.temperature
    n = report.points
    table = Table(title=f"cmmpose compensate: {points_in} -> {points_out}", show_header=False)
    machine_row(table, machine)
    table.add_row("points", f"{n:,}")
    table.add_row("maps", repr(error_map))
    table.add_row("temperature", t_all or "-")
    table.add_row("pose (deg)", ", ".join(f"{v:g}" for v in pose_t))
    table.add_row("offset (mm)", ", ".join(f"{v:g}" for v in offset_t))
    kernel_report_rows(table, report, temperature_tolerance)
    table.add_row("kernel time", f"{elapsed * 1e3:.1f} ms ({n / max(elapsed, 1e-9) / 1e6:.1f} M points/s)")
    Console().print(table)



@main.command("effects")
def effects_cmd() -> None:
    """List the physical effects: name, where each acts, its parameters and what it is."""
    table = Table(title="Physical effects (cmmpose.effects)")
    for col in ("effect", "acts", "model parameters (prior)", "simulator fields", "what it is"):
        table.add_column(col, no_wrap=col == "effect")
    for name, cls in effects_registry.available().items():
        params = ", ".join(f"{p} {q.unit} ({q.prior:g})" for p, q in cls.params.items())
        fields_ = ", ".join(f"{k} {u}".strip() for k, u in cls.units().items())
        table.add_row(name, cls.acts, params, fields_, cls.summary)
    Console().print(table)

@main.command("simulate")
@click.option("--layout", type=click.Choice(["b89", "crossed"]), default="b89", show_default=True,
              help="20 ASME B89.4.1 positions (thesis Appendix C geometry) or the 8 crossed-ballbar positions.")
@click.option("--temperature", type=float, default=20.0, show_default=True, help="Machine temperature, C.")
@machine_option
@click.option("--maps", "maps", multiple=True, callback=map_specs,
              help="The machine's real maps: 'thesis', 'appendix-b' or map files. Default: the machine's.")
@click.option("--effect", "effects", multiple=True, metavar="NAME:param=value,...",
              help="Extra physics, repeatable, e.g. latency:seconds=0.005 (`cmmpose effects` lists them). One of: "
                   + "; ".join(f"{name} ({', '.join(f'{k} {u}'.strip() for k, u in cls.units().items())}): "
                               f"{cls.summary}" for name, cls in effects_registry.available().items()) + ".")
@click.option("--speed", type=float, default=35.0, show_default=True, help="Sweep speed, mm/s.")
@click.option("--bidirectional", is_flag=True, help="Alternate forward and reverse sweeps.")
@click.option("--jitter", type=float, default=0.0, show_default=True,
              help="Per-scan reproducibility: sd of where the artefact really sits at each sweep, um per axis.")
@click.option("--calibrated", is_flag=True, help="Record the bar length at 20 C and the ball radius as calibrated values.")
@click.option("--reference-pose", "reference_poses", multiple=True, metavar="A,B,G",
              help="After the ballbar, scan the reference sphere at this pose (degrees; repeatable).")
@click.option("--artefact", "artefact", default=None, metavar="FILE|NAME",
              help="Simulate this artefact file or bundled example (docs/artefacts.md) instead of the --layout.")
@click.option("--placement", "placements", multiple=True, metavar="PLACEMENT",
              help="With --artefact: where it sits, e.g. 'xy@z=-525,rot=45', 'planes', 'iso10360-2' (repeatable; "
                   "default the kind's layout).")
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("-o", "--output", "run_dir", required=True, type=click.Path(file_okay=False), help="Run directory to write.")
@click.option("--overwrite", is_flag=True, help="Replace an existing run in RUN_DIR.")
def simulate_cmd(layout, temperature, machine_file, maps, effects, speed, bidirectional, jitter, calibrated,
                 reference_poses, artefact, placements, seed, run_dir, overwrite) -> None:
    """Simulate a ballbar run (or, with --artefact, an artefact at its placements) on a virtual machine (default:
    the thesis's Iota 1102 + Hyscan 45C) and write it as a run directory."""
    from .machine import load_machine
    from .sim import parse_effect, simulate_ballbar_run

    if placements and artefact is None:
        raise click.UsageError("--placement needs --artefact")
    try:
        machine = load_machine(machine_file)
        parsed = [parse_effect(e) for e in effects]
        machine_maps = load_maps(maps, machine)
        if artefact is not None:
            for flag, given in (("--calibrated", calibrated), ("--reference-pose", reference_poses)):
                if given:
                    raise click.UsageError(f"{flag} is for ballbar runs, not with --artefact")
            return simulate_artefact(artefact, placements, machine, machine_maps, temperature, parsed, speed,
                                     bidirectional, jitter, seed, run_dir, overwrite,
                                     (TextColumn("simulating"), BarColumn(),
                                      TextColumn("{task.completed}/{task.total} sweeps")),
                                     lambda r: _with_machine(r, machine, maps))
        start = time.perf_counter()
        with Progress(TextColumn("simulating"), BarColumn(), TextColumn("{task.completed}/{task.total} sweeps"),
                      console=console) as bar:
            task = bar.add_task("", total=None)
            run, truth = simulate_ballbar_run(
                machine_maps, temperature, parsed, layout=layout, speed=speed, bidirectional=bidirectional, seed=seed,
                scanner=machine.scanner, offset=tuple(machine.offset), jitter=jitter * 1e-3,
                calibrated=("length", "radius") if calibrated else (),
                reference_poses=[pose_angles(p, "--reference-pose") for p in reference_poses],
                progress=lambda done, total: bar.update(task, completed=done, total=total))
        run = _with_machine(run, machine, maps)
        elapsed = time.perf_counter() - start
        run.save(run_dir, truth=truth, overwrite=overwrite)
    except Error as exc:
        raise fail(exc) from None
    table = Table(title=f"cmmpose simulate -> {run_dir}", show_header=False)
    machine_row(table, machine)
    table.add_row("layout", f"{layout} ({len(run.scans['scan_id'])} sweeps)")
    table.add_row("points", f"{run.n_points:,} ({run.n_points / len(run.scans['scan_id']):,.0f} per sphere)")
    table.add_row("temperature", f"{temperature:g} C")
    table.add_row("effects", ", ".join(effects) or "none")
    table.add_row("time", f"{elapsed:.2f} s")
    Console().print(table)


def _compensate_dataset(points_in, points_out, machine, maps, temperature, pose_t, offset_t, out_of_range,
                        temperature_tolerance, nan_policy, scheduler, scheduler_timeout) -> None:
    """`compensate DATASET_DIR OUT_DIR`: a folder of Parquet files on a Dask scheduler (cmmpose.scale)."""
    import logging

    from .scale import compensate_dataset, dataset_temperature_range

    logging.getLogger("distributed").setLevel(logging.WARNING)  # the local cluster's start-up chatter
    try:
        error_map = load_maps(maps, machine)
        given = temperature if temperature is not None else dataset_temperature_range(points_in)
        if isinstance(error_map, ErrorMap) and given is not None:  # T from the files' statistics, no data read
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", MapTemperatureWarning)
                note = warn_single_map(error_map, given, temperature_tolerance)
            if note:
                console.print(f"[yellow]warning:[/] {escape(note)}")
        with Progress(TextColumn("compensating"), BarColumn(), TextColumn("{task.percentage:>3.0f}%"),
                      TextColumn("{task.completed:,.0f} points"),
                      TimeRemainingColumn(), console=console) as bar:
            task = bar.add_task("", total=None)
            result = compensate_dataset(points_in, points_out, error_map, pose_t, offset_t, temperature,
                                        out_of_range=out_of_range, nan_policy=nan_policy,
                                        temperature_tolerance=temperature_tolerance, scheduler=scheduler,
                                        scheduler_timeout=scheduler_timeout, progress=lambda done, total: bar.update(task, completed=done, total=total))
    except Error as exc:
        raise fail(exc) from None
    report = result.report
    table = Table(title=f"cmmpose compensate: {points_in} -> {points_out}", show_header=False)
    machine_row(table, machine)
    table.add_row("files", f"{len(result.outputs)}")
    table.add_row("points", f"{result.points:,}")
    table.add_row("maps", repr(error_map))
    t_text = f"{temperature:g} C" if temperature is not None else "per point (T column)"
    table.add_row("temperature", t_text if isinstance(error_map, ErrorMapSet) else "-")
    table.add_row("pose (deg)", ", ".join(f"{v:g}" for v in pose_t))
    table.add_row("offset (mm)", ", ".join(f"{v:g}" for v in offset_t))
    table.add_row("scheduler", scheduler)
    kernel_report_rows(table, report, temperature_tolerance)
    table.add_row("wall time", f"{result.elapsed:.1f} s ({result.points / max(result.elapsed, 1e-9) / 1e6:.1f} M points/s)")
    Console().print(table)


@main.command("simulate-alignment")
@machine_option
@click.option("--pose", "pose_text", required=True, help="Nominal pose alpha,beta,gamma of the trunnion stop, degrees.")
@click.option("--name", required=True, help="Name of the pose, e.g. A90B90: the files are NAME-vernier.csv, ...")
@click.option("--temperature", type=float, default=20.0, show_default=True, help="Machine temperature, C.")
@click.option("--effect", "effects", multiple=True, metavar="NAME:param=value,...",
              help="What the calibration should find, e.g. alignment:alpha=0.03 or mount-offset:u=0.02 "
                   "(`cmmpose effects`); repeatable.")
@click.option("--vernier-points", type=click.IntRange(3), default=3, show_default=True,
              help="Optical-vernier positions (the thesis uses 3).")
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("-o", "--output", "out_dir", required=True, type=click.Path(file_okay=False),
              help="Folder for the measurement files.")
def simulate_alignment_cmd(machine_file, pose_text, name, temperature, effects, vernier_points, seed, out_dir) -> None:
    """Simulate the measurements that align the scanner at one pose (thesis chapter 4): optical-vernier
    positions, a plane scan and a reference-sphere scan, as `cmmpose calibrate alignment` reads them.

    Writes NAME-vernier.csv (x,y,z, mm), NAME-plane.csv and NAME-sphere.csv (u,v,D,E,F, mm) and
    NAME-truth.json (the plane's normal, the true pose, reading and offset), and prints the command
    that calibrates from them."""
    from .machine import load_machine
    from .sim import parse_effect
    from .sim.calibration_data import VERNIER_NOISE, plane_scan, reference_sphere_scans, vernier_points as vernier

    nominal = pose_angles(pose_text, "--pose")
    try:
        machine = load_machine(machine_file)
        parsed = [parse_effect(e) for e in effects]
        maps = machine.maps()
        offset = tuple(machine.offset)
        rng = np.random.default_rng(seed)
        common = {"maps": maps, "temperature": temperature, "effects": parsed}
        v = vernier(nominal, offset, n=vernier_points, seed=rng, **common)
        plane = plane_scan(nominal, offset, scanner=machine.scanner, seed=rng, **common)
        sphere = reference_sphere_scans([nominal], offset, scanner=machine.scanner,
                                        seed=int(rng.integers(1 << 30)), **common)[0]
        folder = ensure_folder(out_dir)
        files = {k: folder / f"{name}-{k}.csv" for k in ("vernier", "plane", "sphere")}
        with atomic_write(files["vernier"]) as f:
            np.savetxt(f, v.points, delimiter=",", header="x,y,z", comments="", fmt="%.9f")
        for k, d in (("plane", plane), ("sphere", sphere.data)):
            with atomic_write(files[k]) as f:
                np.savetxt(f, np.column_stack([d.uv, d.scales]), delimiter=",", header="u,v,D,E,F",
                           comments="", fmt="%.9f")
        normal = [float(c) for c in plane.plane.normal]
        truth = {"units": {"pose": "degree", "reading": "mm", "offset": "mm", "vernier_uncertainty": "um"},
                 "nominal_pose": list(nominal), "plane_normal": normal,
                 "true_pose": [float(c) for c in sphere.true_pose], "true_reading": [float(c) for c in sphere.true_reading],
                 "true_offset": [float(c) for c in sphere.true_offset], "vernier_uncertainty": VERNIER_NOISE * 1e3,
                 "temperature": temperature, "effects": list(effects), "seed": seed}
        write_text(folder / f"{name}-truth.json", strict_json(truth, indent=2))
    except Error as exc:
        raise fail(exc) from None
    for f in files.values():
        console.print(f"wrote {f}")
    machine_arg = f" --machine {machine_file}" if machine_file else " --maps thesis"
    console.print("calibrate with:\n  cmmpose calibrate alignment" + machine_arg
                  + f" --temperature {temperature:g} --vernier {files['vernier']} --vernier-uncertainty "
                  f"{VERNIER_NOISE * 1e3:g} --plane-scan {files['plane']} --plane-normal "
                  + ",".join(f"{c + 0.0:.6g}" for c in normal) + f" --reference-scan {files['sphere']} --name {name} "
                  "--library LIBRARY", soft_wrap=True)


@main.command("fit")
@click.argument("scan", type=click.Path(exists=True, dir_okay=False))
@click.option("--units", type=click.Choice(sorted(POINT_UNITS)), default=None,
              help="Units of the file's coordinates (and of --scanner-origin, --start). Default: the format's "
                   "(mm; metres for E57).")
@click.option("--radius", type=float, default=None,
              help="Calibrated sphere radius, mm (fixed in the fit). Default: fitted (free radius).")
@click.option("--segment", type=click.Choice(["none", "e3125"]), default="none", show_default=True,
              help="e3125: segment the sphere from a raw scan about the scanner's line of sight (needs --radius).")
@click.option("--scanner-origin", default="0,0,0", show_default=True,
              help="The scanner's origin in the file's frame, x,y,z in --units (for --segment e3125).")
@click.option("--rule", type=click.Choice(["none", "mad", "e3125"]), default=None,
              help="Outlier rule without segmentation (docs/fitting.md): mad (repeated, median-centred) or e3125 "
                   "(one pass at 3 standard deviations).")
@click.option("--reject", type=float, default=None, help="Multiple k of the rule's sigma (default 3.5 for mad, 3 for e3125).")
@click.option("--start", default=None,
              help="Where the fit starts: algebraic, lmeds (high breakdown: for heavy outliers) or a centre x,y,z "
                   "in --units.")
@click.option("--json", "as_json", is_flag=True, help="Print the result as JSON.")
def fit_cmd(scan, units, radius, segment, scanner_origin, rule, reject, start, as_json) -> None:
    """Fit a sphere to the point cloud SCAN (CSV, NPY, Parquet, PLY, XYZ, PTS, E57): centre (mm), radius,
    points used and the centre's standard uncertainty. With --segment e3125 a raw scan is segmented in the
    manner of ASTM E3125 first (closest-point start, cone and cylinder about the line of sight, radius fixed)."""
    from .errors import IllConditionedFit
    from .fitting import e3125, fit_sphere

    if radius is not None and not (np.isfinite(radius) and radius > 0):
        raise click.BadParameter(f"expected a positive radius in mm, got {radius}", param_hint="--radius")
    if segment == "e3125" and radius is None:
        raise click.UsageError("--segment e3125 fits with the radius fixed at its calibrated value: give --radius (mm)")
    if segment == "e3125" and (rule or reject is not None):
        raise click.UsageError("--segment e3125 applies the standard's own rule: --rule and --reject do not apply")
    try:
        scale = unit_factor(scan, units)  # --start and --scanner-origin are in the file's units
    except Error as exc:
        raise fail(exc) from None
    start_value = None
    if start is not None:
        start_value = start if start in ("algebraic", "lmeds") else tuple(v * scale for v in triple(start, "--start"))
        if segment == "e3125" and isinstance(start_value, str):
            raise click.BadParameter("with --segment e3125 give a centre x,y,z (or nothing: the closest-point start)",
                                     param_hint="--start")
    origin = tuple(v * scale for v in triple(scanner_origin, "--scanner-origin"))
    try:
        cloud = read_point_cloud(scan, units=units)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", IllConditionedFit)
            if segment == "e3125":
                res = e3125(cloud.xyz, radius, origin, start=start_value)
                out = {"file": str(scan), "method": "e3125 segmentation, radius fixed", **res.to_dict()}
            else:
                f = fit_sphere(cloud.xyz, radius, rule=rule, reject=reject, start=start_value)
                out = {"file": str(scan), "method": "least squares" + (f", rule {rule or 'mad'}" if (rule or reject)
                                                                        else "") + (", radius fixed" if radius else ""),
                       "centre_mm": f.centre.tolist(), "radius_mm": float(f.radius), "n_points": int(f.n_points),
                       "n_raw": len(cloud.xyz), "centre_uncertainty_mm": f.centre_uncertainty.tolist(),
                       "radius_uncertainty_mm": f.radius_uncertainty if radius is None else 0.0,
                       "rms_mm": float(f.rms), "polar_coverage_deg": float(f.polar_coverage),
                       "centre_radius_correlation": (None if radius is not None
                                                     else float(f.centre_radius_correlation))}
    except Error as exc:
        raise fail(exc) from None
    notes = [str(w.message) for w in caught if issubclass(w.category, IllConditionedFit)]
    out["warnings"] = notes
    if as_json:
        click.echo(strict_json(out, indent=2))
    else:
        table = Table(title=f"sphere fit of {scan}", show_header=False)
        table.add_row("method", out["method"])
        table.add_row("centre (mm)", ", ".join(f"{v:.6f}" for v in out["centre_mm"]))
        u = out.get("centre_uncertainty_mm")
        if u is not None:
            table.add_row("u(centre) (um)", ", ".join(f"{v * 1e3:.2f}" for v in u))
        table.add_row("radius (mm)", f"{out['radius_mm']:.6f}")
        table.add_row("points used / in file", f"{out['n_points']} / {out['n_raw']}")
        Console().print(table)
    for note in notes:
        console.print(f"[yellow]warning:[/] {escape(note)}")


def _aligned(name: str, library_file) -> tuple[str, str]:
    """--pose and --offset text of the alignment ``name`` in the library."""
    from .calibration.library import AlignmentLibrary

    if library_file is None:
        raise click.UsageError("--alignment needs --library FILE (or mount.alignments in the machine file)")
    if not Path(library_file).is_file():
        raise click.BadParameter(f"{library_file}: no such alignment library", param_hint="--library")
    record = AlignmentLibrary(library_file).load(name)
    return ",".join(map(repr, record.as_pose().as_tuple())), ",".join(map(repr, record.as_offset()))


def _with_machine(run, machine, specs):
    """The simulated run's record of its maps: the bundled thesis set on
    another configuration says which (so that evaluate finds it); maps from
    files are not named (evaluate then needs --maps or --machine)."""
    import dataclasses

    if specs or machine.bundled_maps != "thesis":
        return dataclasses.replace(run, maps={})
    record = {"kind": "bundled", "name": "thesis"}
    if machine.kinematics != "thesis":
        record["kinematics"] = machine.kinematics
    return dataclasses.replace(run, maps=record)


def _maps_for_run(run, specs: tuple[str, ...], machine=None):
    """--maps as given (stacked as --machine says), 'none' for uncompensated
    only, the machine's maps, or what run.json names."""
    if specs == ("none",):
        return None
    if specs or (machine is not None and not machine.is_default):
        return load_maps(specs, machine)
    if run.maps.get("kind") == "bundled" and run.maps.get("name") == "thesis":
        return ErrorMapSet.thesis().with_kinematics(run.maps.get("kinematics", "thesis"))
    raise click.UsageError("the run does not name bundled maps: give --maps or --machine (or --maps none)")


def write_report(evaluation, directory: Path, maps=None) -> list[Path]:
    """evaluation.json, lengths.csv and, with matplotlib, plots; returns the files."""
    ensure_folder(directory)
    files = [directory / "evaluation.json", directory / "lengths.csv"]
    write_text(files[0], evaluation.to_json(indent=2))
    rows = [{"result": r.label, **row} for r in evaluation.results for row in r.rows()]
    header = list(rows[0])
    write_text(files[1], "\n".join([",".join(header)] + [",".join(str(row[k]) for k in header) for row in rows])
               + "\n")
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        console.print(escape("matplotlib is not installed: no plots (pip install 'cmmpose[plot]')"))
        return files
    from .plots import plot_ballbar_lengths, plot_error_map

    plot_ballbar_lengths(evaluation.results, directory / "ballbar_lengths.png")
    files.append(directory / "ballbar_lengths.png")
    if maps is not None:
        plot_error_map(maps, directory / "error_map.png")
        files.append(directory / "error_map.png")
    return files


@main.command("evaluate")
@click.argument("run_dir", metavar="RUN_DIR...", nargs=-1, required=True, type=click.Path(exists=True, file_okay=False))
@machine_option
@click.option("--maps", "maps", multiple=True, callback=map_specs,
              help="Compensation maps ('thesis', files, or 'none'); default: the machine's, or as run.json says.")
@click.option("--temperature", type=float, default=None, help="Machine temperature, C (default: the run's thermocouple log).")
@policy_options()
@click.option("--expansion", type=float, default=None,
              help=f"Artefact expansion coefficient for lengths at 20 C, ppm/K (default: the machine's, "
                   f"{STEEL_EXPANSION * 1e6:g} for the thesis machine).")
@click.option("--reject", type=float, default=None, help="Robust sphere fits: reject beyond this many robust sigmas.")
@click.option("--report", "report_dir", type=click.Path(file_okay=False), default=None, help="Write JSON, CSV and plots here.")
@click.option("--u-temperature", type=float, default=None,
              help="Standard uncertainty of the machine temperature reading, K (default 0.2).")
@click.option("--u-map", type=float, default=None,
              help="Standard uncertainty of each axis's map scale, ppm (default: the interferometer's air, ~1.4).")
@click.option("--u-model", type=float, default=0.0, show_default=True,
              help="Standard uncertainty of the residual model error, ppm of the length (0: left out of the budget).")
@click.option("--json", "as_json", is_flag=True, help="Print JSON instead of the table.")
@click.option("--skip-incomplete", is_flag=True,
              help="Leave out positions whose ball scans are missing, duplicated or mislabelled (listed in the "
                   "output, its JSON and the report); without it such a position is an error.")
@scheduler_options("Evaluate the runs on Dask: 'threads', 'processes' or a scheduler address tcp://host:port "
                   "(default with several runs: threads; needs the dask extra).")
def evaluate_cmd(run_dir, machine_file, maps, temperature, out_of_range, temperature_tolerance, log_hold, expansion,
                 reject, u_temperature, u_map, u_model, report_dir, as_json, skip_incomplete, scheduler,
                 scheduler_timeout) -> None:
    """Ballbar evaluation of RUN_DIR: lengths per position, uncompensated and compensated.

    With several runs (a fleet, or a day's runs), each is evaluated on the
    --scheduler and a summary table across them is printed; --report writes
    the summary (CSV), each run's report and a plot of the trend. One run:
    every figure with its uncertainty (k = 2) and budget (docs/uncertainty.md)."""
    from .evaluation import evaluate
    from .machine import load_machine
    from .run import Run

    try:
        machine = load_machine(machine_file)
        if expansion is None:
            expansion = machine.artefact_expansion * 1e6
        if len(run_dir) > 1 or scheduler is not None:
            # The table across runs carries no uncertainties: their options would do nothing.
            for flag, given in (("--u-temperature", u_temperature is not None), ("--u-map", u_map is not None),
                                ("--u-model", u_model != 0.0)):
                if given:
                    raise click.UsageError(f"{flag} takes one run: the table across runs has no uncertainties "
                                           "(evaluate each run on its own for them)")
            return _evaluate_fleet(run_dir, machine, maps, scheduler or "threads", report_dir, as_json,
                                   scheduler_timeout=scheduler_timeout,
                                   temperature=temperature, reject=reject, out_of_range=out_of_range,
                                   temperature_tolerance=temperature_tolerance, log_hold=log_hold,
                                   expansion=expansion * 1e-6, skip_incomplete=skip_incomplete)
        run_dir = run_dir[0]
        run = Run.load(run_dir)
        model = _maps_for_run(run, maps, machine)
        if "definition" in run.artefact:  # an artefact run (cmmpose simulate --artefact): cli_artefact
            return evaluate_artefact_run(run, model, temperature, reject, u_temperature, report_dir, as_json,
                                         {"out_of_range": out_of_range, "temperature_tolerance": temperature_tolerance,
                                          "log_hold": log_hold})
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", MapTemperatureWarning)
            ev = evaluate(run, model, temperature, reject=reject, out_of_range=out_of_range,
                          temperature_tolerance=temperature_tolerance, log_hold=log_hold, expansion=expansion * 1e-6,
                          skip_incomplete=skip_incomplete)
        for w in caught:
            console.print(f"[yellow]warning:[/] {escape(str(w.message))}")
        unc = _evaluation_uncertainty(run, ev, model, temperature, reject, out_of_range, temperature_tolerance,
                                      log_hold, u_temperature, u_map, u_model)
        files = write_report(ev, Path(report_dir), model) if report_dir else []
        if report_dir:
            files += [Path(report_dir) / "uncertainty.json", Path(report_dir) / "uncertainty.md"]
            write_text(files[-2], unc.to_json(indent=2))
            write_text(files[-1], unc.to_markdown())
    except Error as exc:
        raise fail(exc) from None
    if as_json:
        click.echo(strict_json({**ev.to_dict(), "uncertainty": unc.to_dict()}, indent=2))
    else:
        Console().print(ev)
        Console(width=max(Console().width, 130)).print(unc)
    for f in files:
        console.print(f"wrote {f}")


def _evaluation_uncertainty(run, ev, model, temperature, reject, out_of_range, temperature_tolerance, log_hold,
                            u_temperature, u_map, u_model):
    """u (k = 2) and budgets of every figure of ``ev`` (cmmpose.evaluation_uncertainty)."""
    from .evaluation_uncertainty import DEFAULT_U_TEMPERATURE_K, evaluation_uncertainty

    return evaluation_uncertainty(
        run, ev, model, temperature, reject=reject, out_of_range=out_of_range, temperature_tolerance=temperature_tolerance,
        log_hold=log_hold, u_temperature_K=DEFAULT_U_TEMPERATURE_K if u_temperature is None else u_temperature,
        u_map_ppm=u_map, u_model_ppm=u_model)


def _evaluate_fleet(run_dirs, machine, maps, scheduler, report_dir, as_json, *, scheduler_timeout,
                    **options) -> None:
    """`evaluate RUN...`: every run on a Dask scheduler (cmmpose.scale), then one table across them."""
    import logging

    from .evaluation import skipped_note
    from .scale import evaluate_runs, fleet_summary

    logging.getLogger("distributed").setLevel(logging.WARNING)  # the local cluster's start-up chatter
    if maps == ("none",):
        model = None
    elif maps or not machine.is_default:
        model = load_maps(maps, machine)
    else:
        model = "run"  # each run.json names its bundled maps
    with Progress(TextColumn("evaluating"), BarColumn(), TextColumn("{task.completed:.0f}/{task.total:.0f} runs"),
                  console=console) as bar:
        task = bar.add_task("", total=len(run_dirs))
        evaluations = evaluate_runs(run_dirs, model, scheduler=scheduler, scheduler_timeout=scheduler_timeout,
                                    progress=lambda done, total: bar.update(task, completed=done), **options)
    rows = fleet_summary(run_dirs, evaluations)
    files = []
    if report_dir:
        from .plots import plot_fleet_trend

        directory = ensure_folder(report_dir)
        for r, ev in zip(run_dirs, evaluations):
            files += write_report(ev, directory / Path(r).name, model if not isinstance(model, str) else None)
        summary = directory / "summary.csv"
        fields = list(rows[0].__dataclass_fields__)
        write_text(summary, "\n".join([",".join(fields)] + [",".join(str(getattr(row, f)) for f in fields)
                                                             for row in rows]) + "\n")
        files.append(summary)
        try:
            plot_fleet_trend(rows, directory / "trend.png")
            files.append(directory / "trend.png")
        except (ImportError, InputError) as exc:  # the table is still printed
            console.print(f"[yellow]no trend plot:[/] {escape(str(exc))}")
    if as_json:
        click.echo(strict_json([{**{k: (None if isinstance(v, float) and v != v else v) for k, v in row.__dict__.items()},
                                "skipped": ev.skipped} for row, ev in zip(rows, evaluations)],
                               indent=2))  # NaN (no value) as null: strict JSON
    else:
        table = Table(title=f"cmmpose evaluate: {len(rows)} runs on {scheduler}")
        table.add_column("run")
        table.add_column("created")
        table.add_column("temperature (C)", justify="right")
        for what in ("uncompensated", "compensated"):
            table.add_column(f"{what}\nrms (um)", justify="right")
            table.add_column("B89 (um)", justify="right")
        um = lambda x: "-" if x != x else f"{x * 1e3:.1f}"  # noqa: E731 - NaN: no value
        for row in rows:
            table.add_row(escape(row.run), row.created, "-" if row.temperature != row.temperature else f"{row.temperature:.2f}",
                          um(row.rms_uncompensated), um(row.b89_uncompensated), um(row.rms_compensated),
                          um(row.b89_compensated))
        Console(width=max(120, Console().width)).print(table)
        for row, ev in zip(rows, evaluations):
            if ev.skipped:
                console.print(f"[yellow]{escape(row.run)}:[/] {escape(skipped_note(ev.skipped))}")
    for f in files:
        console.print(f"wrote {f}")


@main.command("diagnose")
@click.argument("run_dirs", metavar="RUN_DIR...", nargs=-1, required=True, type=click.Path(exists=True, file_okay=False))
@machine_option
@click.option("--maps", "maps", multiple=True, callback=map_specs,
              help="Model maps ('thesis' or files); default: the machine's, or as run.json says.")
@click.option("--model", "model_file", type=click.Path(exists=True, dir_okay=False), default=None,
              help="Start from a model saved by an earlier diagnosis (its maps and effects).")
@click.option("--temperature", type=float, default=None, help="Machine temperature, C (default: the run's thermocouple log).")
@policy_options()
@click.option("--add", "add", multiple=True, help="Add this effect first, whether significant or not (repeatable).")
@click.option("--no-auto", is_flag=True, help="Only rank the candidates (and add --add ones); add nothing automatically.")
@click.option("--max-effects", type=int, default=4, show_default=True, help="Most effects added automatically.")
@click.option("--report", "report_file", type=click.Path(dir_okay=False), default=None, help="Write a self-contained HTML report here.")
@click.option("--save-model", "model_out", type=click.Path(dir_okay=False), default=None, help="Write the final model (JSON) here.")
@click.option("--user-effect", "user_files", multiple=True, type=click.Path(exists=True, dir_okay=False),
              help="A Python file defining EFFECT (a cmmpose.diagnosis.UserEffect), added to the candidates "
                   "(repeatable; docs/user-effects.md).")
@click.option("--user-effect-skeleton", "skeleton_out", type=click.Path(dir_okay=False), default=None,
              help="Write a user-effect draft (Python) built on the first unexplained finding here.")
@click.option("--joint", is_flag=True,
              help="With several runs: one model for all (shared effect parameters, per-run noise levels; the same "
                   "artefact: one bar length), instead of one diagnosis per run.")
@click.option("--separate-artefacts", is_flag=True, help="With --joint: each run measured its own artefact.")
@scheduler_options("With several runs: where each run's diagnosis runs (threads, processes or tcp://host:port; "
                   "the [dask] extra; docs/scale-out.md).")
@click.option("--json", "as_json", is_flag=True, help="Print JSON instead of the tables.")
def diagnose_cmd(run_dirs, machine_file, maps, model_file, temperature, out_of_range, temperature_tolerance, log_hold,
                 add, no_auto, max_effects, report_file, model_out, user_files, skeleton_out, joint, separate_artefacts,
                 scheduler, scheduler_timeout, as_json) -> None:
    """Find which physical effect the model misses on RUN_DIR, add it, and show the error fall.
    Several RUN_DIRs are diagnosed one by one on a Dask scheduler, with one table across them."""
    from .diagnosis import diagnose
    from .machine import load_machine
    from .run import Run

    if joint:
        if len(run_dirs) < 2 or scheduler:
            raise click.UsageError("--joint takes two or more runs and runs in this process (no --scheduler)")
        if skeleton_out:
            raise click.UsageError("--user-effect-skeleton takes one run: diagnose the run of interest on its own")
        return _diagnose_joint(run_dirs, machine_file, maps, model_file, user_files, model_out, as_json, report_file,
                               temperature=temperature, out_of_range=out_of_range,
                               temperature_tolerance=temperature_tolerance, log_hold=log_hold, add=add,
                               auto=not no_auto, max_effects=max_effects, same_artefact=not separate_artefacts)
    if len(run_dirs) > 1 or scheduler:
        for flag, given in (("--report", report_file), ("--save-model", model_out), ("--user-effect", user_files),
                            ("--user-effect-skeleton", skeleton_out)):
            if given:
                raise click.UsageError(f"{flag} takes one run: diagnose the run of interest on its own")
        return _diagnose_fleet(run_dirs, machine_file, maps, model_file, scheduler or "threads", as_json,
                               scheduler_timeout=scheduler_timeout,
                               temperature=temperature, out_of_range=out_of_range,
                               temperature_tolerance=temperature_tolerance, log_hold=log_hold, add=add,
                               auto=not no_auto, max_effects=max_effects)
    run_dir = run_dirs[0]
    try:
        check_outputs({"--save-model": model_out, "--report": report_file, "--user-effect-skeleton": skeleton_out},
                      run_dirs, [model_file, machine_file, *user_files])
        machine = load_machine(machine_file)
        run = Run.load(run_dir)
        user = [_load_user_effect(f) for f in user_files]
        model = _starting_model(run, machine, maps, model_file, user, temperature=temperature,
                                out_of_range=out_of_range, temperature_tolerance=temperature_tolerance,
                                log_hold=log_hold)
        with console.status("diagnosing ..."):
            known = set(model.names)
            diag = diagnose(run, model, add=add, auto=not no_auto, max_effects=max_effects,
                            user_effects=[u for u in user if u.name not in known])
        files = []
        if skeleton_out:
            from .diagnosis.unexplained import user_effect_skeleton

            if diag.unexplained:
                write_text(skeleton_out, user_effect_skeleton(diag.unexplained[0]))
                files.append(skeleton_out)
            else:
                console.print("no unexplained structure: no user-effect draft written")
        if model_out:
            files.append(diag.model.save(model_out))
        if report_file:
            try:
                files.append(diag.write_report(report_file, run, run_dir=run_dir, model_file=model_out))
            except ImportError as exc:  # the diagnosis is still printed and the model saved
                console.print(f"[yellow]no HTML report:[/] {escape(str(exc))}")
    except Error as exc:
        raise fail(exc) from None
    _print_diagnosis(diag, files, as_json)


def _print_diagnosis(diag, files, as_json: bool) -> None:
    if as_json:
        click.echo(diag.to_json(indent=1))
    else:
        Console(width=150).print(diag)
    for f in files:
        console.print(f"wrote {f}")


def _starting_model(run, machine, maps, model_file, user, **policy):
    """The model a diagnosis starts from: a saved one (with its user effects),
    or the maps (--maps, the machine's, or the run's) with the temperature policy."""
    from .diagnosis import Model

    if model_file:
        return Model.load(model_file, user_effects=user)
    maps_ = _maps_for_run(run, maps, machine)
    if maps_ is None:
        raise click.BadParameter("the model needs maps ('none' is not a model)", param_hint="--maps")
    return Model(maps_, **policy)


def _diagnose_joint(run_dirs, machine_file, maps, model_file, user_files, model_out, as_json, report_file, *,
                    temperature, out_of_range, temperature_tolerance, log_hold, **options) -> None:
    """`diagnose RUN... --joint`: one model for several runs (cmmpose.diagnosis.joint); the
    report shows the first run's plots and every run's error at each step."""
    from .diagnosis.joint import diagnose_jointly
    from .machine import load_machine
    from .run import Run

    try:
        check_outputs({"--save-model": model_out, "--report": report_file}, run_dirs,
                      [model_file, machine_file, *user_files])
        machine = load_machine(machine_file)
        runs = [Run.load(r) for r in run_dirs]
        user = [_load_user_effect(f) for f in user_files]
        model = _starting_model(runs[0], machine, maps, model_file, user, temperature=temperature,
                                out_of_range=out_of_range, temperature_tolerance=temperature_tolerance,
                                log_hold=log_hold)
        with console.status(f"diagnosing {len(runs)} runs together ..."):
            diag = diagnose_jointly(runs, model, user_effects=[u for u in user if u.name not in set(model.names)],
                                    run_names=[str(r) for r in run_dirs], **options)
        files = [diag.model.save(model_out)] if model_out else []
        if report_file:
            try:
                files.append(diag.write_report(report_file, runs[0], run_dir=run_dirs[0], model_file=model_out))
            except ImportError as exc:  # the diagnosis is still printed and the model saved
                console.print(f"[yellow]no HTML report:[/] {escape(str(exc))}")
    except Error as exc:
        raise fail(exc) from None
    _print_diagnosis(diag, files, as_json)


def _diagnose_fleet(run_dirs, machine_file, maps, model_file, scheduler, as_json, *, scheduler_timeout, temperature,
                    out_of_range, temperature_tolerance, log_hold, **options) -> None:
    """`diagnose RUN...`: each run's diagnosis on a Dask scheduler (cmmpose.scale), one table across them."""
    from .diagnosis import Model
    from .machine import load_machine
    from .scale import diagnose_runs

    try:
        machine = load_machine(machine_file)
        model = "run"  # each run's bundled maps, on its worker
        if model_file:
            model = Model.load(model_file)
        elif maps == ("none",):
            raise click.BadParameter("the model needs maps ('none' is not a model)", param_hint="--maps")
        elif maps or machine_file:
            model = Model(load_maps(maps, machine))
        with Progress(TextColumn("diagnosing"), BarColumn(), TextColumn("{task.completed}/{task.total} runs"),
                      console=console) as bar:
            task = bar.add_task("", total=len(run_dirs))
            diags = diagnose_runs(run_dirs, model, scheduler=scheduler, scheduler_timeout=scheduler_timeout,
                                  progress=lambda done, total: bar.update(task, completed=done, total=total),
                                  temperature=temperature, out_of_range=out_of_range,
                                  temperature_tolerance=temperature_tolerance, log_hold=log_hold,
                                  **options)
    except Error as exc:
        raise fail(exc) from None
    if as_json:
        click.echo(strict_json({str(r): json.loads(d.to_json()) for r, d in zip(run_dirs, diags)}, indent=1))
        return
    table = Table(title=f"diagnosis of {len(run_dirs)} runs ({scheduler})")
    for col in ("run", "added (final values ± u)", "rms before (um)", "rms after (um)", "unexplained"):
        table.add_column(col, justify="left" if col in ("run", "added (final values ± u)", "unexplained") else "right")
    for r, d in zip(run_dirs, diags):
        added = "; ".join(f"{x['name']}: {x['reason'].split(' (final model)')[0]}" for x in d.decisions()
                          if x["decision"].startswith("added")) or "-"
        table.add_row(str(r), added, f"{d.steps[0].figures.rms_accuracy_error * 1e3:.2f}",
                      f"{d.steps[-1].figures.rms_accuracy_error * 1e3:.2f}",
                      "; ".join(f.input + ": " + f.description.split(":")[0] for f in d.unexplained) or "-")
    Console(width=160).print(table)


@main.command("diagnose-fits")
@click.argument("fits_file", metavar="FITS")
@click.option("--state", default=None, help="Rows of this state only (a 'state' column, e.g. compensated).")
@click.option("--nominal-radius", type=float, default=None, help="Calibrated ball radius, mm.")
@click.option("--reference-length", type=float, default=None, help="Calibrated bar length, mm (default: the mean).")
@click.option("--artefact", "artefact_spec", default=None, metavar="FILE|NAME",
              help="FITS holds measured centres of this artefact (ball plate, step gauge): columns placement, ball, "
                   "x_mm, y_mm, z_mm, radius_mm (docs/artefacts.md).")
@click.option("--temperature", type=float, default=None,
              help="With --artefact: the artefact's temperature while measured, C (default 20).")
@click.option("--json", "as_json", is_flag=True)
def diagnose_fits_cmd(fits_file, state, nominal_radius, reference_length, artefact_spec, temperature,
                      as_json) -> None:
    """Diagnose a ballbar run from its sphere fits alone (centres, radii, points, fit rms per ball): FITS is a
    CSV (docs/appendix-c.md) or 'appendix-c' (thesis Appendix C, 20 C, nominal radius 38.125 mm). With
    --artefact, FITS holds the measured ball centres of a ball plate or step gauge at its placements."""
    if artefact_spec is not None or temperature is not None:
        return diagnose_plate_fits_cli(fits_file, artefact_spec, state, temperature, nominal_radius,
                                       reference_length, as_json)
    from .diagnosis.spheres import NOMINAL_RADIUS_MM, appendix_c_sphere_fits, diagnose_sphere_fits, read_sphere_fits

    try:
        if fits_file == "appendix-c":
            fits = appendix_c_sphere_fits(state or "compensated")
            nominal_radius = NOMINAL_RADIUS_MM if nominal_radius is None else nominal_radius
        else:
            if not Path(fits_file).is_file():
                raise click.BadParameter(f"{fits_file}: no such file", param_hint="FITS")
            fits = read_sphere_fits(fits_file, state)
        d = diagnose_sphere_fits(fits["centres"], fits["radii"], nominal_radius=nominal_radius,
                                 reference_length=reference_length, points=fits.get("points"),
                                 fit_rms=fits.get("fit_rms"))
    except Error as exc:
        raise fail(exc) from None
    if as_json:
        click.echo(strict_json(d.to_dict(), indent=1))
        return
    table = Table(title=f"sphere fits of {fits_file}" + (f" ({state})" if state else ""), show_header=False)
    table.add_row("positions", str(len(d.lengths)))
    table.add_row("rms accuracy error (um)", f"{d.rms_um:.2f}")
    table.add_row("mean radius (mm)", f"{d.radius_mean:.4f}" + ("" if d.nominal_radius is None else
                  f" ({d.radius_excess_um:+.1f} ± {d.radius_excess_u_um:.1f} um over {d.nominal_radius:g})"))
    table.add_row("radius scatter between balls (um)", f"{d.radius_sd_um:.1f}")
    Console().print(table)
    Console(width=150).print(d.patterns)


def _load_user_effect(path: str):
    """The EFFECT a user-effect file defines (the file is the user's own code, run as such)."""
    import importlib.util

    from .diagnosis import UserEffect

    spec = importlib.util.spec_from_file_location(f"cmmpose_user_effect_{Path(path).stem}", path)
    module = importlib.util.module_from_spec(spec)
    try:
        spec.loader.exec_module(module)
    except Error:
        raise
    except Exception as exc:  # the user's file: say where it failed
        raise InputError(f"{path}: the user effect file failed to run: {type(exc).__name__}: {exc}") from None
    effect = getattr(module, "EFFECT", None)
    if not isinstance(effect, UserEffect):
        raise InputError(f"{path}: must define EFFECT = UserEffect.create(...) (see docs/user-effects.md)")
    return effect


@main.command("demo")
@click.option("--temperature", type=float, default=22.5, show_default=True, help="Machine temperature, C (between two thesis maps).")
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--jitter", type=float, default=None,
              help="Per-scan reproducibility, um per axis (default 3: a real fixture and machine; 0: the "
                   "compensation's own floor).")
@click.option("--report", "report_dir", type=click.Path(file_okay=False), default="cmmpose-demo", show_default=True,
              help="Folder for the run, JSON, CSV and plots.")
@machine_option
def demo_cmd(temperature, seed, jitter, report_dir, machine_file) -> None:
    """Simulate the default B89 ballbar run on the bundled thesis maps (or the machine's), with a realistic
    per-scan reproducibility of 3 um, and evaluate it uncompensated and compensated: the error falls from
    about 70 um to about 4 um, the floor that reproducibility and the scanner's noise leave."""
    from .evaluation import evaluate
    from .machine import load_machine
    from .sim import REALISTIC_JITTER, simulate_ballbar_run

    jitter_mm = REALISTIC_JITTER if jitter is None else jitter * 1e-3

    start = time.perf_counter()
    try:
        machine = load_machine(machine_file)
        maps = load_maps((), machine)
        console.print(f"machine: {machine.name} ({machine.kinematics}; {machine.source})")
        with Progress(TextColumn("simulating"), BarColumn(), TextColumn("{task.completed}/{task.total} sweeps"),
                      console=console) as bar:
            task = bar.add_task("", total=None)
            run, truth = simulate_ballbar_run(maps, temperature, seed=seed, scanner=machine.scanner,
                                              offset=tuple(machine.offset), jitter=jitter_mm,
                                              progress=lambda d, n: bar.update(task, completed=d, total=n))
        run = _with_machine(run, machine, ())
        report = Path(report_dir)
        run.save(report / "run", truth=truth, overwrite=True)
        ev = evaluate(run, maps, temperature)
        files = write_report(ev, report, maps)
    except Error as exc:
        raise fail(exc) from None
    Console().print(ev)
    thesis = ("; thesis (Table 19, 20 C): 73.2 um uncompensated, 12.8 um compensated" if machine.is_default
              else "")
    console.print(f"{run.n_points:,} points, 40 spheres, {time.perf_counter() - start:.1f} s{thesis}")
    console.print(f"the compensated floor here: a per-scan reproducibility of {jitter_mm * 1e3:g} um per axis "
                  f"(--jitter) and the scanner's noise through the fits; the thesis's 12.8 um also holds what a "
                  f"simulation of these maps leaves out (thermal drift and gradients, residual map errors)")
    for f in [report / "run", *files]:
        console.print(f"wrote {f}")


@main.command("acquire")
@click.option("--scanner", default=None, help="Scanner + scales port: device path or pyserial URL (socket://, rfc2217://).")
@click.option("--thermo", default=None, help="Thermocouple logger port: device path or pyserial URL.")
@click.option("-o", "--output", "run_dir", required=True, type=click.Path(file_okay=False), help="Run directory to write.")
@click.option("--duration", type=float, default=None, help="Seconds to record (default: until Ctrl-C).")
@click.option("--plan", type=click.Path(exists=True, dir_okay=False), default=None,
              help="Plan JSON: scans, poses, channels, artefact, maps (docs/protocols.md).")
@click.option("--pose", default=None, help="alpha,beta,gamma in degrees, when the plan has no poses. Default: the machine's.")
@click.option("--offset", default=None, help="U1,V1,W1 in mm, when the plan has no poses. Default: the machine's.")
@machine_option
@click.option("--tc-type", default="E", show_default=True, help="Thermocouple type.")
@click.option("--thermo-interval", type=float, default=1.0, show_default=True, help="Seconds between logger scans.")
@click.option("--flush-interval", type=float, default=0.2, show_default=True, help="Longest wait before records reach disk, s.")
@click.option("--scanner-baud", type=int, default=921600, show_default=True)
@click.option("--thermo-baud", type=int, default=9600, show_default=True)
@click.option("--overwrite", is_flag=True, help="Replace a recording already in RUN_DIR.")
@click.option("--recover", is_flag=True, help="Rebuild RUN_DIR from its journal (after a crash); opens no ports.")
@click.option("--no-display", is_flag=True, help="No live display.")
def acquire_cmd(scanner, thermo, run_dir, duration, plan, pose, offset, machine_file, tc_type, thermo_interval,
                flush_interval, scanner_baud, thermo_baud, overwrite, recover, no_display) -> None:
    """Record the scanner + scales stream and the thermocouple logger into RUN_DIR
    (live display; Ctrl-C stops cleanly and closes the run)."""
    from .acquire import recover as recover_run
    from .acquire.display import record_live, summary_table
    from .machine import load_machine

    try:
        if recover:
            rec = recover_run(run_dir)
            console.print(repr(rec))
            run = rec.run
        else:
            if not (scanner or thermo):
                raise click.UsageError("give --scanner, --thermo or both")
            machine = load_machine(machine_file)
            pose_t = pose_angles(pose, "--pose") if pose is not None else machine.pose.as_tuple()
            offset_t = offset_mm(offset, "--offset") if offset is not None else tuple(machine.offset)
            run = record_live(run_dir, scanner, thermo, duration=duration, console=console, show=not no_display,
                              plan=_plan_for(plan, machine, machine_file), pose=pose_t, offset=offset_t, tc_type=tc_type,
                              thermo_interval=thermo_interval, flush_interval=flush_interval,
                              scanner_baudrate=scanner_baud, thermo_baudrate=thermo_baud, overwrite=overwrite)
    except Error as exc:
        raise fail(exc) from None
    Console().print(summary_table(run, run_dir))


def _plan_for(plan_file, machine, machine_file):
    """The plan to record with: the plan file's, with the machine file's
    thermocouple channels (in the file's order, multiplexer channels 101, 102,
    ...) where the plan lists none."""
    from .acquire.plan import Plan

    if machine_file is None:
        return plan_file
    plan = Plan.read(plan_file) if plan_file else Plan()
    listed = plan_file and json.loads(Path(plan_file).read_text(encoding="utf-8")).get("temperature_channels")
    if not listed:
        plan.temperature_channels = [{"name": name, "role": role, "channel": 101 + k}
                                     for k, (name, role) in enumerate(machine.thermocouples.items())]
        plan.__post_init__()  # the same checks as a plan file's channels
    return plan


@main.command("plot-map")
@click.argument("maps", nargs=-1)
@click.option("-o", "--output", "out", required=True, type=click.Path(dir_okay=False), help="PNG (or PDF, SVG) to write.")
@machine_option
def plot_map_cmd(maps, out, machine_file) -> None:
    """Plot error-map components against position (like thesis Figures 3-7 to 3-18).
    MAPS: 'thesis', 'appendix-b', or map files (several make a set); default: the machine's."""
    from .machine import load_machine
    from .plots import plot_error_map

    try:
        if not maps and machine_file is None:
            raise click.UsageError("give MAPS or --machine")
        check_not_input(out, [*maps, machine_file], "--output")
        plot_error_map(load_maps(tuple(maps), load_machine(machine_file) if machine_file else None), out)
    except Error as exc:
        raise fail(exc) from None
    console.print(f"wrote {out}")


@main.group("calibrate")
def calibrate() -> None:
    """Calibration solvers: digitizer alignment, mount offset, error maps."""


@calibrate.command("alignment")
@click.option("--vernier", "vernier_file", required=True, type=click.Path(exists=True, dir_okay=False),
              help="Optical-vernier points x, y, z (mm, machine; CSV with that header, NPY or any point-cloud format), "
                   "in order counter-clockwise seen from +w.")
@click.option("--plane-scan", "plane_files", multiple=True, type=click.Path(exists=True, dir_okay=False),
              help="Scan(s) of a flat plane while moving (CSV u,v,D,E,F), for gamma: one with --plane-normal, or two "
                   "sweeps. Required to store an alignment.")
@click.option("--plane-normal", default=None, help="Known outward normal of the scanned plane, nx,ny,nz.")
@click.option("--reference-scan", "ref_file", default=None, type=click.Path(exists=True, dir_okay=False),
              help="Reference-sphere scan at this pose (CSV u,v,D,E,F) for D0, E0, F0.")
@click.option("--offset", default=None, help="U1,V1,W1 mount offset in mm. Default: the machine's.")
@click.option("--name", required=True, help="Name of the indexed trunnion pose, e.g. A90B90.")
@click.option("--library", "library_file", default=None, type=click.Path(dir_okay=False),
              help="Alignment library (JSON). Default: the machine file's mount.alignments.")
@click.option("--temperature", type=float, default=None,
              help="Machine temperature during the alignment, C (needed with a map set).")
@machine_option
@click.option("--maps", "maps", multiple=True, callback=map_specs,
              help="Error maps the readings are compensated with ('thesis' or files); default: the machine's "
                   "when --machine is given, else none (then the squareness shear biases alpha: a warning says so).")
@click.option("--vernier-uncertainty", type=float, default=None,
              help="Standard uncertainty of one vernier position along the normal, um (Type B). Default: from the "
                   "fit's residuals (N - 3 degrees of freedom; three points need this option).")
@click.option("--json", "as_json", is_flag=True, help="Print the stored record as JSON instead of the table.")
def calibrate_alignment_cmd(vernier_file, plane_files, plane_normal, ref_file, offset, name, library_file, temperature,
                            machine_file, maps, vernier_uncertainty, as_json) -> None:
    """Align the digitizer at one trunnion pose: alpha, beta from vernier points, gamma from plane
    scans, D0 E0 F0 from a reference-sphere scan; store the result in the library."""
    from .calibration import (AlignmentLibrary, AlignmentRecord, alpha_beta_from_vernier, calibrated_pose,
                              gamma_from_plane_scan, reference_centre_reading)
    from .machine import load_machine

    normal = triple(plane_normal, "--plane-normal") if plane_normal else None
    if not plane_files:
        raise click.UsageError("--plane-scan is needed to store an alignment (gamma; with --plane-normal, or two "
                               "sweeps along different axes)")
    if not ref_file:
        raise click.UsageError("--reference-scan is needed to store an alignment (D0, E0, F0)")
    if vernier_uncertainty is not None and not (vernier_uncertainty > 0 and np.isfinite(vernier_uncertainty)):
        raise click.BadParameter(f"expected a positive number of um, got {vernier_uncertainty}",
                                 param_hint="--vernier-uncertainty")
    try:
        machine = load_machine(machine_file)
        if library_file is None:
            if machine_file is None or machine.alignments is None:
                raise click.UsageError("give --library FILE (or --machine with mount.alignments)")
            library_file = machine.alignments
        check_not_input(library_file, [vernier_file, *plane_files, ref_file, machine_file, *maps], "--library")
        offset_t = offset_mm(offset, "--offset") if offset is not None else tuple(machine.offset)
        error_map = load_maps(maps, machine) if (maps or machine_file) else None
        if error_map is None:
            console.print("[yellow]warning:[/] no error map: the readings are taken as positions, and the "
                          "squareness shear biases alpha (give --maps or --machine)")
        elif isinstance(error_map, ErrorMapSet) and temperature is None:
            raise click.UsageError("a map set needs --temperature (the machine's during the alignment, C)")
        em = {"error_map": error_map, "temperature": temperature if error_map is not None else None}
        point_u = None if vernier_uncertainty is None else vernier_uncertainty * 1e-3
        vern = alpha_beta_from_vernier(read_point_cloud(vernier_file).xyz, point_uncertainty=point_u, **em)
        scans = [read_points(f) for f in plane_files]
        gam = gamma_from_plane_scan(np.vstack([sc[0] for sc in scans]), np.vstack([sc[1] for sc in scans]),
                                    vern.alpha, vern.beta, normal=normal, offset=offset_t,
                                    alpha_beta_covariance=vern.covariance, **em)
        cp = calibrated_pose(vern, gam)
        uv, scales, _ = read_points(ref_file)
        # The pose's covariance goes into the reading through its Jacobian; the
        # record keeps both apart (reading_uncertainty is the reading's own).
        ref = reference_centre_reading(uv, scales, cp.pose, offset_t, pose_covariance=cp.covariance, **em)
        residuals = {"vernier_rms": float(vern.fit.rms), "plane_rms": float(gam.rms)}
        record = AlignmentRecord.from_calibration(cp, ref, offset_t, temperature=temperature, residuals=residuals)
        AlignmentLibrary(library_file).save(name, record)
    except Error as exc:
        raise fail(exc) from None
    if as_json:
        click.echo(strict_json({"name": name, "library": str(library_file), **record.to_dict()}, indent=2))
        return
    table = Table(title=f"alignment {name!r} -> {library_file}", show_header=False)
    table.add_row("alpha, beta, gamma (deg)", ", ".join(f"{v:.4f}" for v in record.pose))
    table.add_row("u (deg)", ", ".join(f"{v:.4f}" for v in record.pose_uncertainty))
    table.add_row("D0, E0, F0 (mm)", ", ".join(f"{v:.4f}" for v in record.reading))
    table.add_row("u, the reading's own (mm)", ", ".join(f"{v:.4f}" for v in record.reading_uncertainty))
    total = np.sqrt(np.diag(ref.covariance))
    table.add_row("u, with the pose's (mm)", ", ".join(f"{v:.4f}" for v in total))
    Console().print(table)


@calibrate.command("offset")
@click.argument("names", nargs=-1, required=True)
@click.option("--library", "library_file", default=None, type=click.Path(exists=True, dir_okay=False),
              help="Alignment library (JSON). Default: the machine file's mount.alignments.")
@machine_option
@click.option("--tolerance", type=float, default=4.0, show_default=True,
              help="Largest standardised residual before the alignments count as disagreeing.")
@click.option("--json", "as_json", is_flag=True, help="Print the fit (offset, covariances, residuals, chi-square) as JSON.")
def calibrate_offset_cmd(names, library_file, machine_file, tolerance, as_json) -> None:
    """Mount offset U1, V1, W1 by least squares from three or more aligned poses NAMES in the library."""
    from .calibration import AlignmentLibrary, mount_offset
    from .machine import load_machine

    try:
        if library_file is None:
            machine = load_machine(machine_file)
            if machine.alignments is None:
                raise click.UsageError("give --library FILE (or --machine with mount.alignments)")
            library_file = machine.alignments
        lib = AlignmentLibrary(library_file)
        readings = []
        for n in names:
            try:  # the solver's reading back: full pose covariance, its Jacobian, the lever
                readings.append(lib.load(n).reference_reading())
            except CalibrationError as exc:
                raise CalibrationError(f"{library_file}: alignment {n!r}: {exc}") from None
        fit = mount_offset(readings, tolerance=tolerance)
    except Error as exc:
        raise fail(exc) from None
    if as_json:
        click.echo(strict_json({
            "poses": list(names), "units": {"offset": "mm", "centre": "mm", "residuals": "mm"},
            "offset": [float(v) for v in fit.offset], "covariance": np.asarray(fit.covariance).tolist(),
            "uncertainty": [float(v) for v in fit.uncertainty], "centre": [float(v) for v in fit.centre],
            "centre_covariance": np.asarray(fit.centre_covariance).tolist(),
            "residuals": {n: [float(v) for v in r] for n, r in zip(names, fit.residuals)},
            "chi2": float(fit.chi2), "dof": int(fit.dof), "p_value": float(fit.p_value),
        }, indent=2))
        return
    table = Table(title=f"mount offset from {', '.join(names)}")
    table.add_column("")
    table.add_column("U1 / x", justify="right")
    table.add_column("V1 / y", justify="right")
    table.add_column("W1 / z", justify="right")
    table.add_row("offset (mm)", *(f"{v:.4f}" for v in fit.offset))
    table.add_row("u (mm)", *(f"{v:.4f}" for v in fit.uncertainty))
    for n, r in zip(names, fit.residuals):
        table.add_row(f"residual {n} (um)", *(f"{v * 1e3:+.1f}" for v in r))
    table.caption = f"chi-square p = {fit.p_value:.3f} ({fit.dof} dof)"
    Console().print(table)


@calibrate.command("map")
@click.argument("run_files", nargs=-1, required=True, type=click.Path(exists=True, dir_okay=False))
@click.option("--squareness", required=True, help="S_xy,S_yz,S_zx in arc-seconds (thesis sign convention).")
@click.option("--temperature", type=float, default=None, help="Map temperature, C (default: mean material temperature).")
@click.option("--no-air-correction", is_flag=True, help="Do not correct linear readings for the refractive index of air.")
@click.option("-o", "--output", "out", required=True, type=click.Path(dir_okay=False), help="Canonical map CSV to write.")
@click.option("--compare", "compare_to", default=None, help="A map ('thesis@20', 'appendix-b' or a file) to compare with.")
@click.option("--plot", "plot_path", default=None, type=click.Path(dir_okay=False), help="Difference plot (with --compare).")
@machine_option
def calibrate_map_cmd(run_files, squareness, temperature, no_air_correction, out, compare_to, plot_path,
                      machine_file) -> None:
    """Build an error map from raw laser-interferometer RUN_FILES (docs/interferometer.md). With
    --machine, the map is checked against the machine's travel."""
    from .calibration.interferometer import build_map, compare_maps, plot_map_difference, read_run
    from .machine import load_machine

    sq = triple(squareness, "--squareness")
    try:
        for given, flag in ((out, "--output"), (plot_path, "--plot")):
            check_not_input(given, [*run_files, machine_file, compare_to], flag)
        runs = [read_run(f) for f in run_files]
        built = build_map(runs, sq, temperature, air_correction=not no_air_correction)
        notes = list(built.notes) + (travel_notes(load_machine(machine_file), built.map) if machine_file else [])
        built.map.write(out)
        if compare_to:
            if compare_to.startswith("thesis@"):
                other = ErrorMapSet.thesis().at(float(compare_to.split("@", 1)[1]))
            else:
                other = load_maps((compare_to,))
                if isinstance(other, ErrorMapSet):
                    raise click.BadParameter("give one map (e.g. thesis@20)", param_hint="--compare")
            comparison = compare_maps(built.map, other)
            Console().print(comparison.table())
            if plot_path:
                plot_map_difference(built.map, other, plot_path)
                console.print(f"wrote {plot_path}")
    except Error as exc:
        raise fail(exc) from None
    for note in notes:
        console.print(f"note: {note}")
    console.print(f"wrote {out}: {built.map!r}")



@main.group("machine")
def machine_group() -> None:
    """Machine files: one CMM with its scanner (configuration, travel, maps, scanner, mount, thermocouples)."""


@machine_group.command("example")
@click.argument("name", type=click.Choice(example_names()))
@click.option("-o", "--output", "out", required=True, type=click.Path(dir_okay=False), help="Machine file to write.")
@click.option("--overwrite", is_flag=True, help="Replace an existing file.")
def machine_example_cmd(name, out, overwrite) -> None:
    """Write the bundled example machine NAME to a file, to edit into your own."""
    from .machine import example_text

    path = Path(out)
    if path.exists() and not overwrite:
        raise click.ClickException(f"{path}: exists (give --overwrite to replace it)")
    try:
        write_text(path, example_text(name))  # atomic: a full disk leaves the earlier file whole
    except Error as exc:
        raise fail(exc) from None
    console.print(f"wrote {path}: the {name} example (cmmpose machine show {path})")


def _show_machine(machine_file, check: bool) -> None:
    from .machine import load_machine

    try:
        machine = load_machine(machine_file)
        notes = machine.check() if check else []
    except Error as exc:
        raise fail(exc) from None
    table = Table(title=f"cmmpose machine: {machine.source}", show_header=False)
    for key, value in machine.describe():
        table.add_row(key, value)
    Console().print(table)
    for note in notes:
        console.print(f"note: {note}")
    if check:
        console.print("ok: the file reads, its maps load and cover the travel")


@machine_group.command("show")
@click.argument("machine_file", metavar="FILE", required=False, type=click.Path(dir_okay=False))
def machine_show_cmd(machine_file) -> None:
    """Print what FILE says about the machine (default: the thesis machine)."""
    _show_machine(machine_file, check=False)


@machine_group.command("check")
@click.argument("machine_file", metavar="FILE", type=click.Path(dir_okay=False))
def machine_check_cmd(machine_file) -> None:
    """Check FILE: every key known and well-formed, the maps readable and covering the travel."""
    _show_machine(machine_file, check=True)


@machine_group.command("configurations")
def machine_configurations_cmd() -> None:
    """List the machine configurations (how the carriages are stacked)."""
    from .machine import configurations

    table = Table(title="Machine configurations (kinematics = ...)")
    for col in ("name", "stacking, base up", "what it is"):
        table.add_column(col)
    for c in configurations():
        table.add_row(c["name"], ", ".join(f"{a} ({side})" for a, side in c["stack"]), c["description"])
    Console().print(table)


# -- cmmpose map: exchange of linear-axis results (docs/formats.md) ------------------------------
# It uses this module's `main`, `console` and `fail` (and click, Path); its library imports are
# local, so that a reorganisation of the imports above leaves it alone.

_MAP_IMPORT_FORMATS = ("iso230-2", "linuxcnc")
_MAP_EXPORT_FORMATS = ("csv", "iso230-2", "linuxcnc")


def _map_spec(spec: str, what: str):
    """One map: 'appendix-b', 'thesis@T' (the bundled set at T degrees C) or a map file of any registered format."""
    from .errormap import ErrorMap, ErrorMapSet

    if spec == "appendix-b":
        return ErrorMap.appendix_b()
    if spec.startswith("thesis@"):
        try:
            t = float(spec.split("@", 1)[1])
        except ValueError:
            raise click.BadParameter(f"expected thesis@<temperature C>, got {spec!r}", param_hint=what) from None
        return ErrorMapSet.thesis().at(t)
    return ErrorMap.read(spec, format="auto")


class _ConsoleLog:
    """Library log lines (level INFO and above) printed as notes while a map command runs."""

    def __enter__(self):
        import logging

        from rich.markup import escape

        class Handler(logging.Handler):
            def emit(self, record):
                level = "warning" if record.levelno >= logging.WARNING else "note"
                console.print(f"{level}: {escape(record.getMessage())}")

        self.logger = logging.getLogger("cmmpose")
        self.handler = Handler(logging.INFO)
        self.level = self.logger.level
        self.logger.addHandler(self.handler)
        if self.logger.getEffectiveLevel() > logging.INFO:
            self.logger.setLevel(logging.INFO)
        return self

    def __exit__(self, *exc):
        self.logger.removeHandler(self.handler)
        self.logger.setLevel(self.level)
        return False


@main.group("map")
def map_group() -> None:
    """Import and export linear-axis results (ISO 230-2 style CSV, LinuxCNC compensation files)."""


@map_group.command("import")
@click.argument("fmt", metavar="FORMAT", type=click.Choice(_MAP_IMPORT_FORMATS))
@click.argument("files", metavar="FILE...", nargs=-1, required=True)
@click.option("-o", "--output", "out", required=True, type=click.Path(dir_okay=False), help="Canonical map CSV to write.")
@click.option("--base", default=None,
              help="Replace only the linear components of this map ('appendix-b', 'thesis@T' or a map file); "
                   "the results are interpolated onto its grid.")
@click.option("--temperature", type=float, default=None, help="Map temperature, C (default: the base's, else none).")
@click.option("--comp-file-type", type=click.Choice(["0", "1"]), default="0", show_default=True,
              help="linuxcnc: COMP_FILE_TYPE (0 = positions, 1 = trims).")
@click.option("--units", type=click.Choice(["mm", "inch"]), default="mm", show_default=True,
              help="linuxcnc: machine units of the files.")
@click.option("--hold-ends", is_flag=True, help="With --base: hold the end values where its grid runs beyond the targets.")
@machine_option
def map_import_cmd(fmt, files, out, base, temperature, comp_file_type, units, hold_ends, machine_file) -> None:
    """Build a canonical map from linear-axis results in FORMAT.

    iso230-2: one CSV file. linuxcnc: one AXIS=FILE per axis, e.g. X=x.comp Y=y.comp.
    The map keeps the mean of the two approach directions; axes without results
    are zero (or, with --base, keep the base's component). With --machine, the
    map is checked against the machine's travel.
    """
    from .errors import Error
    from .iso230 import read_iso230
    from .linuxcnc import read_comp_files
    from .machine import load_machine

    try:
        read = files if fmt == "iso230-2" else [f.partition("=")[2] for f in files]
        check_not_input(out, [*read, base, machine_file], "--output")
        base_map = None if base is None else _map_spec(base, "--base")
        with _ConsoleLog():
            if fmt == "iso230-2":
                if len(files) != 1:
                    raise click.UsageError(f"iso230-2 takes one FILE, got {len(files)}")
                built = read_iso230(files[0], base=base_map, temperature=temperature, hold_ends=hold_ends)
            else:
                pairs = {}
                for item in files:
                    axis, sep, path = item.partition("=")
                    if not sep or not path or axis.upper() not in ("X", "Y", "Z"):
                        raise click.BadParameter(f"expected AXIS=FILE with AXIS X, Y or Z, got {item!r}",
                                                 param_hint="FILE")
                    if axis.upper() in pairs:
                        raise click.BadParameter(f"axis {axis.upper()} given twice", param_hint="FILE")
                    pairs[axis.upper()] = path
                built = read_comp_files(pairs, comp_file_type=int(comp_file_type), units=units, base=base_map,
                                        temperature=temperature, hold_ends=hold_ends)
        notes = travel_notes(load_machine(machine_file), built) if machine_file else []
        built.write(out)
    except Error as exc:
        raise fail(exc) from None
    for note in notes:
        console.print(f"[yellow]warning:[/] {escape(note)}")
    console.print(f"wrote {out}: {built!r}")


@map_group.command("export")
@click.argument("map_spec", metavar="MAP", required=False)
@click.option("--format", "fmt", type=click.Choice(_MAP_EXPORT_FORMATS), required=True,
              help="Format to write (linuxcnc: one file per axis in the directory OUT).")
@click.option("-o", "--output", "out", required=True, type=click.Path(), help="File to write (linuxcnc: a directory).")
@click.option("--comp-file-type", type=click.Choice(["0", "1"]), default="0", show_default=True,
              help="linuxcnc: COMP_FILE_TYPE (0 = positions, 1 = trims).")
@click.option("--units", type=click.Choice(["mm", "inch"]), default="mm", show_default=True,
              help="linuxcnc: machine units to write.")
@machine_option
@click.option("--temperature", type=float, default=None,
              help="With --machine and a map set: the temperature to export the map at, C.")
def map_export_cmd(map_spec, fmt, out, comp_file_type, units, machine_file, temperature) -> None:
    """Write the linear components of MAP ('appendix-b', 'thesis@T' or a map file) in FORMAT;
    without MAP, the machine's map (--machine; a set at --temperature).

    iso230-2 and linuxcnc carry delta_x of X, delta_y of Y and delta_z of Z only,
    the same value in both approach directions; linuxcnc writes x.comp, y.comp
    and z.comp into the directory OUT.
    """
    from .errors import Error
    from .linuxcnc import write_comp_files

    from .machine import load_machine

    try:
        if map_spec is not None:
            source = _map_spec(map_spec, "MAP")
        elif machine_file is None:
            raise click.UsageError("give MAP or --machine")
        else:
            source = load_maps((), load_machine(machine_file))
            if isinstance(source, ErrorMapSet):
                if temperature is None:
                    raise click.UsageError("the machine's maps are a set: give --temperature (C)")
                source = source.at(temperature)
        inputs = [map_spec, machine_file]
        if fmt == "linuxcnc":
            folder = ensure_folder(out)
            files = {a: folder / f"{a.lower()}.comp" for a in ("X", "Y", "Z")}
            for f in files.values():
                check_not_input(f, inputs, "--output")
            write_comp_files(source, files, comp_file_type=int(comp_file_type), units=units)
            written = ", ".join(str(p) for p in files.values())
        else:
            check_not_input(out, inputs, "--output")
            source.write(out, format=fmt)
            written = out
    except Error as exc:
        raise fail(exc) from None
    except OSError as exc:
        raise click.ClickException(f"{out}: {exc.strerror or exc}") from None
    console.print(f"wrote {written}")


main.add_command(iso230_2_cmd)
main.add_command(acceptance_cmd)
main.add_command(acceptance_sphere_cmd)
main.add_command(interim_cmd)
main.add_command(e3125_distances_cmd)
main.add_command(artefact_group)


if __name__ == "__main__":
    main()
