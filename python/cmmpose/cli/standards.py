"""``cmmpose standards``: the standards' commands (docs/standards.md):
``iso230-2`` (positioning of an axis), ``acceptance`` and
``acceptance-sphere`` (ISO 10360-8-style probing and length tests against
MPEs), ``interim-check`` (squareness and scale from one ballbar run) and
``e3125-distances``."""

from __future__ import annotations

import warnings
from dataclasses import dataclass, fields
from pathlib import Path

import click
from rich.console import Console
from rich.markup import escape

from .._json import dumps as strict_json
from ..atomicfile import ensure_folder, write_text
from ..errors import Error
from ..formats.pointclouds import UNITS
from ..temperature import TemperaturePolicy
from .common import (POSITIVE_MM, check_free, check_plot_path, command_inputs, console, expansion_ppm, map_specs,
                     overwrite_option, plot_option, policy_options, skip_incomplete_option, writing)
from .common import fail as _fail

__all__ = ["standards_group", "iso230_2_cmd", "acceptance_cmd", "acceptance_sphere_cmd", "interim_cmd", "e3125_distances_cmd"]






def _show(result, files, as_json: bool) -> None:
    """The result as JSON or as its rich table, then the files written."""
    if as_json:
        click.echo(strict_json(result.to_dict(), indent=2))
    else:
        Console(width=max(Console().width, 120)).print(result)
    for f in files:
        console.print(f"wrote {f}")


def _report_files(report_dir, stem: str) -> list[Path]:
    """The files --report writes in ``report_dir`` (the plot only where the command draws one)."""
    return [Path(report_dir) / f"{stem}{suffix}" for suffix in (".json", ".md", ".png")] if report_dir else []


def _check_outputs(stem: str, plot_path, report_dir, inputs, overwrite: bool) -> None:
    """Before any work: neither the plot nor a report file is one of the ``inputs`` (any spelling or link), nor,
    without ``overwrite``, an existing file (cmmpose.cli.common.check_free; the --report folder is made)."""
    check_free({"--plot": plot_path}, inputs, overwrite=overwrite)
    check_free({"--report": _report_files(report_dir, stem)}, inputs, overwrite=overwrite, folders_made=True)


def _outputs(result, stem: str, plot, plot_path, report_dir, inputs=(), overwrite: bool = False) -> list[Path]:
    """The plot at ``plot_path`` and the report in ``report_dir``, as asked, checked by :func:`_check_outputs`
    before any work, written as one group (created exclusively without ``overwrite``; all or none); the files
    written."""
    files = []
    try:
        with writing("--plot and --report" if plot_path and report_dir else "--plot" if plot_path else "--report",
                     [plot_path, *_report_files(report_dir, stem)], inputs, overwrite=overwrite):
            if plot_path:
                plot(plot_path)
                files.append(Path(plot_path))
            if report_dir:
                files += _write_report(result, report_dir, stem, plot)
    except OSError as exc:  # an unwritable path: named, no traceback
        raise click.ClickException(f"{exc.filename or plot_path or report_dir}: {exc.strerror or exc}") from None
    return files


#: Exit status of a conformance decision (``acceptance``, ``acceptance-sphere``): only a proven pass is 0.
DECISION_EXIT = {"pass": 0, "not proven": 1, "no decision": 1, "fail": 1}


def _exit_with_decision(result) -> None:
    """Exit 0 on a pass, 1 on a fail or a conformance not proven (stated on stderr), so a script can gate on it."""
    code = DECISION_EXIT[result.decision]
    if code:
        console.print(f"decision: {result.decision} (exit status {code})")
        raise click.exceptions.Exit(code)


def _write_report(result, directory, stem: str, plot=None) -> list[Path]:
    """``<stem>.json``, ``<stem>.md`` (a report section) and, given ``plot``
    (a callable taking the path) and matplotlib, ``<stem>.png`` in ``directory``."""
    folder = ensure_folder(directory)
    files = [folder / f"{stem}.json", folder / f"{stem}.md"]
    write_text(files[0], strict_json(result.to_dict(), indent=2))
    write_text(files[1], result.to_markdown())
    if plot is not None:
        try:
            import matplotlib  # noqa: F401
        except ImportError:
            console.print("matplotlib is not installed: no plot (pip install 'cmmpose[plot]')")
            return files
        plot(folder / f"{stem}.png")
        files.append(folder / f"{stem}.png")
    return files


@click.command("iso230-2")
@click.argument("data_file", metavar="FILE", type=click.Path(exists=True, dir_okay=False))
@click.option("--no-air-correction", is_flag=True,
              help="Interferometer runs: do not correct linear readings for the refractive index of air.")
@click.option("--test-uncertainty", type=float, default=None,
              help="Expanded uncertainty (k = 2) of a measured deviation, um, stated with the results "
                   "(default for interferometer runs: the air correction's over the travel).")
@plot_option("--plot", "plot_path", help="Plot to write (PNG, PDF, SVG).")
@click.option("--report", "report_dir", type=click.Path(file_okay=False), default=None,
              help="Write iso230-2.json, iso230-2.md (a report section) and iso230-2.png here.")
@click.option("--json", "as_json", is_flag=True, help="Print JSON (the axis figures at the top level, um).")
@overwrite_option("Replace an existing --plot or --report file (never an input).")
def iso230_2_cmd(data_file, no_air_correction, test_uncertainty, plot_path, report_dir, as_json, overwrite) -> None:
    """ISO 230-2:2014 positioning accuracy and repeatability of one axis.

    FILE is a CSV with columns target_mm, direction (+1/-1), cycle,
    deviation_um, or a linear interferometer run (the files 'calibrate map'
    takes). Prints A, A_up, A_down, B, B_mean, E, E_up, E_down, M, R, R_up,
    R_down in um, and the figures per target.
    """
    from ..standards.iso230_2 import evaluate_iso230_2, load_positioning

    check_plot_path(plot_path, "--plot")
    try:
        _check_outputs("iso230-2", plot_path, report_dir, [data_file], overwrite)  # before any work
        data, u, note = load_positioning(data_file, air_correction=not no_air_correction)
        if test_uncertainty is not None:
            u, note = test_uncertainty, "given (--test-uncertainty)"
        result = evaluate_iso230_2(data, test_uncertainty_um=u, test_uncertainty_note=note)
        files = _outputs(result, "iso230-2", lambda p: result.plot(p, data), plot_path, report_dir, [data_file],
                         overwrite)
    except Error as exc:
        raise _fail(exc) from None
    _show(result, files, as_json)


@click.command("acceptance")
@click.argument("run_dir", metavar="RUN_DIR", type=click.Path(exists=True, file_okay=False))
@click.option("--mpe-form", required=True, help="MPE of the probing form error, um (e.g. 12).")
@click.option("--mpe-size", required=True, help="MPE of the probing size error, um (e.g. 10).")
@click.option("--mpe-length", required=True, help="MPE of the length measurement error, um: A or A+L/K, L in mm (e.g. 8+L/300).")
@click.option("--machine", "machine_file", type=click.Path(dir_okay=False), default=None,
              help="Machine file (kinematics, maps, artefact expansion); default the thesis machine.")
@click.option("--maps", "maps", multiple=True, callback=map_specs,
              help="Compensation maps ('thesis', files, or 'none' to test the uncompensated points); default: the "
                   "machine's, or as run.json says.")
@click.option("--temperature", type=float, default=None, help="Machine and part temperature, C (default: the run's log).")
@click.option("--calibrated-length", type=POSITIVE_MM, default=None,
              help="Certified centre distance at 20 C, mm (default: the run's).")
@click.option("--calibrated-radius", type=POSITIVE_MM, default=None,
              help="Certified ball radius, mm (default: the run's).")
@click.option("--expansion", type=float, default=None, callback=expansion_ppm,
              help="Artefact expansion coefficient for lengths at 20 C, ppm/K (default: the machine's).")
@click.option("--u-length-cert", type=float, default=0.0, show_default=True, help="Standard uncertainty of the certified length, um.")
@click.option("--u-diameter-cert", type=float, default=0.0, show_default=True, help="Standard uncertainty of a certified diameter, um.")
@click.option("--u-form-cert", type=float, default=0.0, show_default=True, help="Standard uncertainty of the spheres' form, um.")
@click.option("--u-expansion", type=float, default=1.0, show_default=True, help="Standard uncertainty of the expansion coefficient, ppm/K.")
@click.option("--u-part-temperature", type=float, default=0.2, show_default=True, help="Standard uncertainty of the part temperature, K.")
@plot_option("--plot", "plot_path", help="Plot to write (PNG, PDF, SVG).")
@click.option("--report", "report_dir", type=click.Path(file_okay=False), default=None,
              help="Write acceptance.json, acceptance.md (a report section) and acceptance.png here.")
@click.option("--json", "as_json", is_flag=True, help="Print JSON instead of the table.")
@skip_incomplete_option
@policy_options()
@overwrite_option("Replace an existing --plot or --report file (never an input).")
def acceptance_cmd(**flags) -> None:
    """Probing form and size errors and length measurement errors of RUN_DIR (in the manner of ISO 10360-8),
    each decided against its MPE: pass (|E| + U <= MPE), fail (|E| - U > MPE) or not proven.

    Exit status: 0 when the decision is pass; 1 when it is fail or not
    proven (conformance not shown), or on an error; 2 on a usage error.
    """
    from ..machine import load_machine
    from ..run import Run
    from ..standards.acceptance import acceptance_test

    o = AcceptanceOptions.from_flags(flags)
    check_plot_path(o.plot_path, "--plot")
    inputs = command_inputs([o.machine_file, *o.maps], [o.run_dir])
    try:
        _check_outputs("acceptance", o.plot_path, o.report_dir, inputs, o.overwrite)  # before any work
        machine = load_machine(o.machine_file)
        run = Run.load(o.run_dir)
        model = machine.maps_for_run(run, o.maps)
        result = acceptance_test(
            run, model, o.temperature, mpe_form=o.mpe_form, mpe_size=o.mpe_size, mpe_length=o.mpe_length,
            calibrated_length=o.calibrated_length, calibrated_radius=o.calibrated_radius,
            u_length_certificate_um=o.u_length_cert, u_diameter_certificate_um=o.u_diameter_cert,
            u_form_certificate_um=o.u_form_cert,
            expansion_ppm_per_K=machine.artefact_expansion * 1e6 if o.expansion is None else o.expansion,
            u_expansion_ppm_per_K=o.u_expansion, u_part_temperature_K=o.u_part_temperature,
            skip_incomplete=o.skip_incomplete, temperature_policy=o.temperature_policy)
        files = _outputs(result, "acceptance", result.plot, o.plot_path, o.report_dir, inputs, o.overwrite)
    except Error as exc:
        raise _fail(exc) from None
    _show(result, files, o.as_json)
    _exit_with_decision(result)


@dataclass(frozen=True)
class AcceptanceOptions:
    """What ``cmmpose standards acceptance`` was asked, from its flags (each field the click parameter of its
    name; the temperature policy's flags as ``temperature_policy``)."""

    run_dir: str
    mpe_form: str
    mpe_size: str
    mpe_length: str
    machine_file: str | None
    maps: tuple[str, ...]
    temperature: float | None
    calibrated_length: float | None
    calibrated_radius: float | None
    #: --expansion, ppm/K; None: the machine's artefact expansion.
    expansion: float | None
    u_length_cert: float
    u_diameter_cert: float
    u_form_cert: float
    u_expansion: float
    u_part_temperature: float
    plot_path: str | None
    report_dir: str | None
    as_json: bool
    skip_incomplete: bool
    temperature_policy: TemperaturePolicy
    overwrite: bool

    @classmethod
    def from_flags(cls, flags: dict) -> AcceptanceOptions:
        """The options from the command's click parameters (by their names)."""
        return cls(**{f.name: flags[f.name] for f in fields(cls)})


@click.command("interim-check")
@click.argument("run_dir", metavar="RUN_DIR", type=click.Path(exists=True, file_okay=False))
@click.option("--machine", "machine_file", type=click.Path(dir_okay=False), default=None,
              help="Machine file (kinematics, maps, artefact expansion); default the thesis machine.")
@click.option("--maps", "maps", multiple=True, callback=map_specs,
              help="Compensation maps: the check is of what they leave ('none': of the raw machine); default: the "
                   "machine's, or as run.json says.")
@click.option("--temperature", type=float, default=None, help="Machine temperature, C (default: the run's log).")
@click.option("--calibrated-length", type=POSITIVE_MM, default=None,
              help="Certified bar length at 20 C, mm (default: the run's); without one, scale mismatches.")
@click.option("--u-length-cert", type=float, default=0.0, show_default=True, help="Standard uncertainty of the certified length, um.")
@click.option("--u-temperature", type=float, default=0.2, show_default=True, help="Standard uncertainty of the temperature, K.")
@click.option("--report", "report_dir", type=click.Path(file_okay=False), default=None,
              help="Write interim-check.json and interim-check.md (a report section) here.")
@click.option("--json", "as_json", is_flag=True, help="Print JSON instead of the table.")
@skip_incomplete_option
@policy_options()
@overwrite_option("Replace the files of an earlier --report (never an input).")
def interim_cmd(run_dir, machine_file, maps, temperature, calibrated_length, u_length_cert, u_temperature,
                report_dir, as_json, skip_incomplete, temperature_policy, overwrite) -> None:
    """Interim check of RUN_DIR, in the manner of the ballbar and gauge products: three scale and three
    squareness values with their uncertainties (k = 2). Next to it, 'cmmpose diagnose' gives the full diagnosis."""
    from ..machine import load_machine
    from ..run import Run
    from ..standards.interim import interim_check

    inputs = command_inputs([machine_file, *maps], [run_dir])
    try:
        _check_outputs("interim-check", None, report_dir, inputs, overwrite)  # before any work
        machine = load_machine(machine_file)
        run = Run.load(run_dir)
        model = machine.maps_for_run(run, maps)
        result = interim_check(run, model, temperature, calibrated_length=calibrated_length,
                               u_length_certificate_um=u_length_cert, expansion_ppm_per_K=machine.artefact_expansion * 1e6,
                               u_temperature_K=u_temperature, skip_incomplete=skip_incomplete,
                               temperature_policy=temperature_policy)
        files = _outputs(result, "interim-check", None, None, report_dir, inputs, overwrite)
    except Error as exc:
        raise _fail(exc) from None
    except OSError as exc:
        raise click.ClickException(f"{exc.filename}: {exc.strerror or exc}") from None
    _show(result, files, as_json)


@click.command("acceptance-sphere")
@click.argument("scan", type=click.Path(exists=True, dir_okay=False))
@click.option("--radius", type=POSITIVE_MM, required=True, help="Certified sphere radius, mm.")
@click.option("--mpe-form", required=True, help="MPE of the probing form error, um.")
@click.option("--mpe-size", required=True, help="MPE of the probing size error, um.")
@click.option("--units", type=click.Choice(sorted(UNITS)), default=None,
              help="Units of the file's coordinates (as 'cmmpose fit'). Default: the format's.")
@click.option("--segment", type=click.Choice(["none", "e3125"]), default="none", show_default=True,
              help="e3125: segment the sphere from a raw scan about the scanner's line of sight first.")
@click.option("--scanner-origin", default="0,0,0", show_default=True,
              help="The scanner's origin in the file's frame, x,y,z in --units (for --segment e3125).")
@click.option("--u-form-cert", type=float, default=0.0, show_default=True, help="Standard uncertainty of the sphere's form, um.")
@click.option("--u-diameter-cert", type=float, default=0.0, show_default=True, help="Standard uncertainty of the certified diameter, um.")
@click.option("--json", "as_json", is_flag=True, help="Print JSON instead of the table.")
def acceptance_sphere_cmd(scan, radius, mpe_form, mpe_size, units, segment, scanner_origin, u_form_cert, u_diameter_cert,
                          as_json) -> None:
    """Probing form and size errors of one scan of a calibrated sphere (a point cloud: CSV, NPY, Parquet, PLY,
    XYZ, PTS, E57), each decided against its MPE: pass (|E| + U <= MPE), fail (|E| - U > MPE) or not proven.

    Exit status: 0 when the decision is pass; 1 when it is fail, not
    proven or no decision (conformance not shown; no decision: the size is
    not determined by a scan of too small a cap, the notes say why), or on an
    error; 2 on a usage error.
    """
    from ..fitting import e3125
    from ..formats.pointclouds import read_point_cloud, unit_factor
    from ..standards.acceptance import probing_test
    from .common import triple

    try:
        scale = unit_factor(scan, units)  # --scanner-origin is in the file's units
        xyz = read_point_cloud(scan, units=units).xyz
        if segment == "e3125":
            origin = tuple(v * scale for v in triple(scanner_origin, "--scanner-origin"))
            xyz = xyz[e3125(xyz, radius, origin).segmentation.mask]
        result = probing_test(xyz, radius, mpe_form=mpe_form, mpe_size=mpe_size, u_form_certificate_um=u_form_cert,
                              u_diameter_certificate_um=u_diameter_cert,
                              item=f"{Path(scan).name}" + (" (E3125 segment)" if segment == "e3125" else ""))
    except Error as exc:
        raise _fail(exc) from None
    if as_json:
        click.echo(strict_json(result.to_dict(), indent=2))
    else:
        Console(width=max(Console().width, 120)).print(result)
    _exit_with_decision(result)


@click.command("e3125-distances")
@click.argument("scans", metavar="NAME=SCAN...", nargs=-1, required=True)
@click.option("--pairs", "pairs_file", required=True, type=click.Path(exists=True, dir_okay=False),
              help="CSV of the pairs: a, b, reference_mm[, u_um] (the reference distance and its standard uncertainty).")
@click.option("--radius", type=float, required=True, help="Calibrated sphere radius, mm (fixed in the fits).")
@click.option("--units", type=click.Choice(sorted(UNITS)), default=None,
              help="Units of the scans' coordinates and of --scanner-origin (default: the format's).")
@click.option("--scanner-origin", default="0,0,0", show_default=True, help="The scanner's origin, x,y,z in --units.")
@click.option("--mpe", "mpe_text", default=None, help="MPE of the distance error, um: A or A+L/K, L in mm.")
@plot_option("--plot", "plot_path", help="Plot to write (PNG, PDF, SVG).")
@click.option("--report", "report_dir", type=click.Path(file_okay=False), default=None,
              help="Write e3125-distances.json, .md (a report section) and .png here.")
@click.option("--json", "as_json", is_flag=True, help="Print JSON instead of the table.")
@overwrite_option("Replace an existing --plot or --report file (never an input).")
def e3125_distances_cmd(scans, pairs_file, radius, units, scanner_origin, mpe_text, plot_path, report_dir,
                        as_json, overwrite) -> None:
    """Sphere-centre distance errors in the manner of ASTM E3125: each NAME=SCAN is a raw scan of one
    sphere target (any point-cloud format), segmented and fitted with the radius fixed; each pair of
    --pairs is compared with its reference distance (docs/standards.md)."""
    from ..errors import ImplausibleFit
    from ..formats.pointclouds import read_point_cloud, unit_factor
    from ..standards.acceptance import parse_mpe
    from ..standards.e3125_distances import distance_errors, read_pairs, sphere_targets

    check_plot_path(plot_path, "--plot")
    if not (radius > 0):
        raise click.BadParameter(f"expected a positive radius in mm, got {radius}", param_hint="--radius")
    try:
        origin = tuple(float(v) for v in scanner_origin.split(","))
    except ValueError:
        origin = ()
    if len(origin) != 3:
        raise click.BadParameter(f"expected x,y,z, got {scanner_origin!r}", param_hint="--scanner-origin")
    named = {}
    for item in scans:
        name, sep, path = item.partition("=")
        if not sep or not name or not path:
            raise click.BadParameter(f"expected NAME=SCAN, got {item!r}", param_hint="NAME=SCAN")
        if name in named:
            raise click.BadParameter(f"target {name!r} given twice", param_hint="NAME=SCAN")
        named[name] = path
    try:
        _check_outputs("e3125-distances", plot_path, report_dir, [*named.values(), pairs_file], overwrite)
        mpe = parse_mpe(mpe_text, "--mpe") if mpe_text else None
        clouds = {n: read_point_cloud(p, units=units).xyz for n, p in named.items()}
        scale = unit_factor(next(iter(named.values())), units)  # --scanner-origin is in the scans' units
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", ImplausibleFit)
            targets = sphere_targets(clouds, radius, tuple(v * scale for v in origin))
        result = distance_errors(targets, read_pairs(pairs_file), mpe)
        files = _outputs(result, "e3125-distances", result.plot, plot_path, report_dir,
                         [*named.values(), pairs_file], overwrite)
    except Error as exc:
        raise _fail(exc) from None
    _show(result, files, as_json)
    for w in caught:  # an implausible sphere fit (a wrong radius, an unsegmented scan): said, on stderr
        console.print(f"[yellow]warning:[/] {escape(str(w.message))}")


@click.group("standards")
def standards_group() -> None:
    """Standard evaluations: ISO 230-2 positioning, acceptance tests against MPEs, the interim check, ASTM E3125
    sphere-centre distances (docs/standards.md)."""


for _command in (iso230_2_cmd, acceptance_cmd, acceptance_sphere_cmd, interim_cmd, e3125_distances_cmd):
    standards_group.add_command(_command)
