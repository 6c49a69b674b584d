"""``cmmpose calibrate``: digitizer alignment, mount offset, error maps from interferometer runs."""

from __future__ import annotations

import dataclasses
import warnings

import click
import numpy as np
from rich.console import Console
from rich.table import Table

from .._json import dumps as strict_json
from ..atomicfile import check_not_input
from ..errormap import ErrorMapSet
from ..errors import CalibrationError, Error, GeometryError
from ..formats.pointclouds import read_point_cloud
from ..formats.pointfiles import read_points
from ..pose import Pose
from .common import json_option, console, fail, load_maps, machine_option, map_specs, offset_mm, travel_notes, triple
from .common import TEMPERATURE
from .common import check_free, check_plot_path, command_inputs, overwrite_option, plot_option, writing


@click.group("calibrate")
def calibrate() -> None:
    """Calibration solvers: digitizer alignment, mount offset, error maps."""


#: Largest angle (degrees) between the vernier's w and the w of --nominal-pose,
#: and between the solved gamma and its gamma: a trunnion stop repeats its
#: pose to hundredths of a degree; 10 degrees apart is another stop (or, for
#: w, vernier points in the reverse order: 180).
NOMINAL_W_TOLERANCE_DEG = 10.0


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
@click.option("--temperature", type=TEMPERATURE, default=None,
              help="Machine temperature during the alignment, C (needed with a map set).")
@machine_option
@click.option("--maps", "maps", multiple=True, callback=map_specs,
              help="Error maps the readings are compensated with ('thesis' or files); default: the machine's "
                   "when --machine is given, else none (then the squareness shear biases alpha: a warning says so).")
@click.option("--vernier-uncertainty", type=float, default=None,
              help="Standard uncertainty of one vernier position along the normal, um (Type B). Default: from the "
                   "fit's residuals (N - 3 degrees of freedom; three points need this option).")
@click.option("--nominal-pose", default=None,
              help="The trunnion index's nominal alpha,beta,gamma in degrees: gamma is searched within 90 degrees of "
                   "its gamma, which catches an inward --plane-normal (the scan alone fits it at gamma + 180).")
@click.option("--replace", is_flag=True, help="Replace the alignment already stored under --name (default: refuse).")
@click.option("--json", "as_json", is_flag=True, help="Print the stored record as JSON instead of the table.")
def calibrate_alignment_cmd(**flags) -> None:
    """Align the digitizer at one trunnion pose: alpha, beta from vernier points, gamma from plane
    scans, D0 E0 F0 from a reference-sphere scan; store the result in the library (an existing
    --name only with --replace).

    With --plane-normal and sweeps along the face, the scan fits gamma + 180 degrees with the
    opposite normal as well: the normal's sign picks the branch. It is checked against
    --nominal-pose, else against two or more other alignments in the library (the mount offset
    must fit them), else a note says it was not checked."""
    from ..machine import load_machine

    o = AlignmentOptions.from_flags(flags)
    o.check()
    try:
        machine = load_machine(o.machine_file)
        library_file, library = _alignment_library(o, machine)
        record, ref, branch_note = _solve_alignment(o, machine, library)
        library.save(o.name, record, overwrite=o.replace)
    except Error as exc:
        raise fail(exc) from None
    if o.as_json:  # the note in the document (as `calibrate map --json` does), stdout stays one JSON document
        click.echo(strict_json({"name": o.name, "library": str(library_file), **record.to_dict(),
                                "notes": [branch_note] if branch_note else []}, indent=2))
        return
    if branch_note:
        console.print(f"note: {branch_note}")
    table = Table(title=f"alignment {o.name!r} -> {library_file}", show_header=False)
    table.add_row("alpha, beta, gamma (deg)", ", ".join(f"{v:.4f}" for v in record.pose))
    table.add_row("u (deg)", ", ".join(f"{v:.4f}" for v in record.pose_uncertainty))
    table.add_row("D0, E0, F0 (mm)", ", ".join(f"{v:.4f}" for v in record.reading))
    table.add_row("u, the reading's own (mm)", ", ".join(f"{v:.4f}" for v in record.reading_uncertainty))
    total = np.sqrt(np.diag(ref.covariance))
    table.add_row("u, with the pose's (mm)", ", ".join(f"{v:.4f}" for v in total))
    Console().print(table)


@dataclasses.dataclass(frozen=True)
class AlignmentOptions:
    """What ``cmmpose calibrate alignment`` was asked, from its flags (each field the click parameter of its
    name)."""

    vernier_file: str
    plane_files: tuple[str, ...]
    plane_normal: str | None
    ref_file: str | None
    offset: str | None
    name: str
    library_file: str | None
    temperature: float | None
    machine_file: str | None
    maps: tuple[str, ...]
    vernier_uncertainty: float | None
    nominal_pose: str | None
    replace: bool
    as_json: bool

    @classmethod
    def from_flags(cls, flags: dict) -> AlignmentOptions:
        """The options from the command's click parameters (by their names)."""
        return cls(**{f.name: flags[f.name] for f in dataclasses.fields(cls)})

    @property
    def normal(self) -> tuple[float, float, float] | None:
        """--plane-normal, nx, ny, nz."""
        return triple(self.plane_normal, "--plane-normal") if self.plane_normal else None

    @property
    def nominal(self) -> tuple[float, float, float] | None:
        """--nominal-pose, alpha, beta, gamma (deg)."""
        return triple(self.nominal_pose, "--nominal-pose") if self.nominal_pose else None

    @property
    def inputs(self) -> list:
        """The files the command reads: none may be the library it writes."""
        return [self.vernier_file, *self.plane_files, self.ref_file, self.machine_file, *self.maps]

    def check(self) -> None:
        """The usage errors, before anything is read."""
        _ = self.normal, self.nominal
        if not self.plane_files:
            raise click.UsageError("--plane-scan is needed to store an alignment (gamma; with --plane-normal, or "
                                   "two sweeps along different axes)")
        if not self.ref_file:
            raise click.UsageError("--reference-scan is needed to store an alignment (D0, E0, F0)")
        u = self.vernier_uncertainty
        if u is not None and not (u > 0 and np.isfinite(u)):
            raise click.BadParameter(f"expected a positive number of um, got {u}", param_hint="--vernier-uncertainty")


def _alignment_library(o: AlignmentOptions, machine):
    """The library file (--library, else the machine file's) and the library, checked before the work: not an
    input, and --name not stored already unless --replace."""
    from ..calibration import AlignmentLibrary

    library_file = o.library_file
    if library_file is None:
        if o.machine_file is None or machine.alignments is None:
            raise click.UsageError("give --library FILE (or --machine with mount.alignments)")
        library_file = machine.alignments
    check_not_input(library_file, o.inputs, "--library")
    library = AlignmentLibrary(library_file)
    if not o.replace and o.name in library:  # before the work: refuse to overwrite a stored calibration silently
        raise click.UsageError(f"{library_file}: pose {o.name!r} is already aligned; give --replace to replace "
                               "it, or another --name")
    return library_file, library


def _alignment_maps(o: AlignmentOptions, machine) -> dict:
    """The maps and temperature the readings are corrected with (``maps`` None: none given, with a warning)."""
    error_map = load_maps(o.maps, machine) if (o.maps or o.machine_file) else None
    if error_map is None:
        console.print("[yellow]warning:[/] no error map: the readings are taken as positions, and the "
                      "squareness shear biases alpha (give --maps or --machine)")
    elif isinstance(error_map, ErrorMapSet) and o.temperature is None:
        raise click.UsageError("a map set needs --temperature (the machine's during the alignment, C)")
    return {"maps": error_map, "temperature": o.temperature if error_map is not None else None}


def _vernier(o: AlignmentOptions, em: dict):
    """alpha, beta from the vernier points, checked against --nominal-pose."""
    from ..calibration import alpha_beta_from_vernier

    point_u = None if o.vernier_uncertainty is None else o.vernier_uncertainty * 1e-3
    vernier_points = read_point_cloud(o.vernier_file).xyz
    if len(vernier_points) == 3 and point_u is None:
        raise click.UsageError(f"{o.vernier_file}: three vernier points fit the plane exactly, leaving no "
                               "residuals to estimate their uncertainty from: give --vernier-uncertainty "
                               "(um; the vernier's null, Type B)")
    vern = alpha_beta_from_vernier(vernier_points, point_uncertainty=point_u, **em)
    nominal = o.nominal
    if nominal is not None:
        w_nominal = Pose(*nominal).matrix()[:, 2]
        off = float(np.degrees(np.arccos(np.clip(float(np.dot(vern.normal, w_nominal)), -1.0, 1.0))))
        if off > NOMINAL_W_TOLERANCE_DEG:
            raise CalibrationError(
                f"{o.vernier_file}: the vernier's scan-plane normal w {np.round(vern.normal, 4).tolist()} is "
                f"{off:.1f} deg from the w of --nominal-pose {o.nominal_pose} ({np.round(w_nominal, 4).tolist()}): "
                "is --nominal-pose this stop's trunnion index, and are the vernier points counter-clockwise "
                "seen from +w?")
    return vern


def _solve_alignment(o: AlignmentOptions, machine, library):
    """The alignment record, the reference reading and the branch note (None: none to say)."""
    from ..calibration import AlignmentRecord, calibrated_pose, gamma_from_plane_scan, reference_centre_reading

    offset_t = offset_mm(o.offset, "--offset") if o.offset is not None else tuple(machine.offset)
    em = _alignment_maps(o, machine)
    vern = _vernier(o, em)
    nominal = o.nominal
    scans = [read_points(f) for f in o.plane_files]
    uv, scales, _ = read_points(o.ref_file)

    def solve(plane_n):
        try:
            gam = gamma_from_plane_scan(np.vstack([sc[0] for sc in scans]), np.vstack([sc[1] for sc in scans]),
                                        vern.alpha, vern.beta, normal=plane_n, offset=offset_t,
                                        gamma0=None if nominal is None else nominal[2],
                                        alpha_beta_covariance=vern.covariance, **em)
        except CalibrationError as exc:  # name the files and flags the solver was given
            given = "--plane-scan" + (" with --plane-normal" if plane_n is not None else "") + (
                " and --nominal-pose" if nominal is not None else "")
            raise CalibrationError(f"{', '.join(map(str, o.plane_files))} ({given}): {exc.message}",
                                   **exc.fields) from None
        cp = calibrated_pose(vern, gam)
        # The pose's covariance goes into the reading through its Jacobian; the
        # record keeps both apart (reading_uncertainty is the reading's own).
        ref = reference_centre_reading(uv, scales, cp.pose, offset_t, pose_covariance=cp.covariance, **em)
        residuals = {"vernier_rms": float(vern.fit.rms), "plane_rms": float(gam.rms)}
        return gam, ref, AlignmentRecord.from_calibration(cp, ref, offset_t, temperature=o.temperature,
                                                          residuals=residuals)

    normal = o.normal
    gam, ref, record = solve(normal)
    if nominal is not None:
        off = abs((gam.gamma - nominal[2] + 180.0) % 360.0 - 180.0)
        if off > NOMINAL_W_TOLERANCE_DEG:
            raise CalibrationError(
                f"{', '.join(map(str, o.plane_files))}: gamma {gam.gamma:.4f} deg is {off:.1f} deg from the gamma "
                f"of --nominal-pose {o.nominal_pose}: is --nominal-pose this stop's trunnion index, and "
                "--plane-normal the scanned face's outward normal?")
    branch_note = None
    if gam.branch_from_normal and nominal is None:
        branch_note = _check_branch(library, o.name, record, lambda: solve(tuple(-c for c in normal))[2], normal,
                                    o.plane_files)
    return record, ref, branch_note


def _check_branch(library, name, record, opposite, normal, plane_files) -> str | None:
    """Check the gamma branch the sign of --plane-normal picked against the
    library's other alignments: the mount offset must fit them with this
    record. Raise CalibrationError when only the opposite normal's record
    (``opposite()``) fits; return a note when the check cannot be made."""
    from ..calibration import mount_offset

    n_text = ",".join(f"{c:g}" for c in normal)
    flipped = ",".join(f"{0.0 - c:g}" for c in normal)
    unchecked = (f"the plane scan fits gamma {record.pose[2]:.4f} deg with --plane-normal {n_text} and gamma "
                 f"{record.pose[2] - 180.0 if record.pose[2] > 0 else record.pose[2] + 180.0:.4f} deg with {flipped} "
                 "equally well (its sweeps run along the face): the branch rests on --plane-normal being the "
                 "face's outward normal, unchecked; give --nominal-pose to check it")
    others = [n for n in library.names() if n != name]
    if len(others) < 2:
        return unchecked + " (or align two other poses in the library first)"
    readings = [library.load(n).reference_reading() for n in others]

    def fits(rec) -> bool | None:
        try:
            mount_offset([*readings, rec.reference_reading()])
        except GeometryError:
            return None
        except CalibrationError:
            return False
        return True

    this = fits(record)
    if this is None:
        return unchecked + f" (the library's {', '.join(others)} with it do not determine the mount offset)"
    if this:
        return None
    if fits(opposite()):
        raise CalibrationError(
            f"{', '.join(map(str, plane_files))} (--plane-scan with --plane-normal {n_text}): the alignment "
            f"disagrees with the library's {', '.join(others)} (the mount offset does not fit them), and agrees "
            f"with --plane-normal {flipped} (gamma + 180 deg): the scanner would be looking at the back of the face "
            f"with outward normal {n_text}. Is {flipped} the scanned face's outward normal (pointing towards the "
            "scanner)?")
    return (f"the alignment disagrees with the library's {', '.join(others)} (the mount offset does not fit them) "
            f"with either sign of --plane-normal: one of them is wrong; `cmmpose calibrate offset` says by how much")


@calibrate.command("offset")
@click.argument("names", nargs=-1, required=True)
@click.option("--library", "library_file", default=None, type=click.Path(exists=True, dir_okay=False),
              help="Alignment library (JSON). Default: the machine file's mount.alignments.")
@machine_option
@click.option("--tolerance", type=float, default=4.0, show_default=True,
              help="Largest standardised residual before the alignments count as disagreeing.")
@click.option("--json", "as_json", is_flag=True, help="Print the fit (offset, covariances, residuals, chi-square) as JSON.")
@click.option("--store", is_flag=True, help="Store the solved offset, with its covariance, in the NAMES' records of the "
              "library, where `compensate --alignment NAME` takes it from (their readings are kept).")
def calibrate_offset_cmd(names, library_file, machine_file, tolerance, as_json, store=False) -> None:
    """Mount offset U1, V1, W1 by least squares from three or more aligned poses NAMES in the library."""
    from ..calibration import AlignmentLibrary, mount_offset
    from ..machine import load_machine

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
        if store:
            lib.store_offset(names, fit)
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
            "stored_in": str(library_file) if store else None,
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
    table.caption = f"chi-square p = {fit.p_value:.3f} ({fit.dof} dof)" + (
        f"; stored in {library_file} for {', '.join(names)}" if store else
        "; not stored (--store puts it where `compensate --alignment` takes it from)")
    Console().print(table)


def _compare_map(spec: str):
    """The one map of ``calibrate map --compare``: 'thesis@T' (the bundled set at T C), 'appendix-b' or a file."""
    if spec.startswith("thesis@"):
        try:
            t = float(spec.split("@", 1)[1])
        except ValueError:
            raise click.BadParameter(f"expected thesis@<temperature C>, got {spec!r}", param_hint="--compare") from None
        return ErrorMapSet.thesis().at(t)
    other = load_maps((spec,))
    if isinstance(other, ErrorMapSet):
        raise click.BadParameter("give one map (e.g. thesis@20)", param_hint="--compare")
    return other


@calibrate.command("map")
@click.argument("run_files", nargs=-1, required=True, type=click.Path(exists=True, dir_okay=False))
@click.option("--squareness", required=True, help="S_xy,S_yz,S_zx in arc-seconds (thesis sign convention).")
@click.option("--temperature", type=TEMPERATURE, default=None, help="Map temperature, C (default: mean material temperature).")
@click.option("--no-air-correction", is_flag=True, help="Do not correct linear readings for the refractive index of air.")
@click.option("-o", "--output", "out", required=True, type=click.Path(dir_okay=False), help="Canonical map CSV to write.")
@click.option("--compare", "compare_to", default=None, help="A map ('thesis@20', 'appendix-b' or a file) to compare with.")
@plot_option("--plot", "plot_path", help="Difference plot (with --compare): PNG, PDF, SVG.")
@machine_option
@json_option
@overwrite_option("Replace an existing --output or --plot file (never an input).")
def calibrate_map_cmd(run_files, squareness, temperature, no_air_correction, out, compare_to, plot_path,
                      machine_file, as_json, overwrite) -> None:
    """Build an error map from raw laser-interferometer RUN_FILES (docs/interferometer.md). With
    --machine, the map is checked against the machine's travel."""
    from ..calibration.interferometer import (InterferometerWarning, build_map, compare_maps, plot_map_difference,
                                              read_run)
    from ..machine import load_machine

    sq = triple(squareness, "--squareness")
    if plot_path and not compare_to:
        raise click.UsageError("--plot draws the difference from a --compare map: give --compare")
    try:
        inputs = command_inputs([*run_files, machine_file, compare_to])
        check_free({"--output": out, "--plot": plot_path}, inputs, overwrite=overwrite)  # before any work
        check_free({"--output and --plot": [out, plot_path]}, overwrite=True)  # two names for one file
        check_plot_path(plot_path, "--plot")
        other = _compare_map(compare_to) if compare_to else None  # before the map is written
        runs = [read_run(f) for f in run_files]
        with warnings.catch_warnings():  # its notes, printed below (and in --json), not twice
            warnings.simplefilter("ignore", InterferometerWarning)
            built = build_map(runs, sq, temperature, air_correction=not no_air_correction)
        notes = list(built.notes) + (travel_notes(load_machine(machine_file), built.map) if machine_file else [])
        comparison = None
        with writing("--output" + (" and --plot" if plot_path else ""), [out, plot_path], inputs,
                     overwrite=overwrite):  # the map and its plot, created exclusively, both or neither
            built.map.write(out)
            if other is not None:
                comparison = compare_maps(built.map, other)
                if plot_path:
                    plot_map_difference(built.map, other, plot_path)
        if comparison is not None and not as_json:
            Console().print(comparison.table())
        if plot_path:
            console.print(f"wrote {plot_path}")
    except Error as exc:
        raise fail(exc) from None
    if as_json:
        click.echo(strict_json({"output": str(out), "map": repr(built.map), "notes": notes, "comparison": None
                                if comparison is None else {"max_difference": comparison.max_difference,
                                                            "squareness_difference_arcsec":
                                                                list(comparison.squareness_difference),
                                                            "temperature_difference_K":
                                                                comparison.temperature_difference}}, indent=2))
        return
    for note in notes:
        console.print(f"note: {note}")
    console.print(f"wrote {out}: {built.map!r}")
