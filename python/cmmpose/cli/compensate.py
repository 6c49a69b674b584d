"""``cmmpose compensate``: scanner points to machine coordinates (a file, or a folder of Parquet files on Dask)."""

from __future__ import annotations

import dataclasses
import os
import warnings
from pathlib import Path

import click
from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn
from rich.table import Table

from ..errormap import ErrorMapSet
from ..errors import AliasedChoiceWarning, Error, MapTemperatureWarning, ModelDomainWarning
from ..filecompensation import compensate_file
from ..formats.pointfiles import check_writable, output_format
from ..formats.pointformats.common import check_file
from .common import (aliased_choices_once, check_free, check_model_or_maps, command_inputs, console, fail,
                     json_option, kernel_report_rows, load_maps, load_model, machine_option, machine_row, map_specs,
                     model_doubts, model_options, offset_mm, overwrite_option, policy_options, pose_angles, say_caught,
                     scheduler_options, show, strict_model_exit, writing)
from .common import TEMPERATURE
from .uncertainty_options import budget_table, check_uncertainty_options, uncertainty_options, uncertainty_sources


@click.command("compensate")
@click.argument("points_in", metavar="IN", type=click.Path())
@click.argument("points_out", metavar="OUT", type=click.Path(writable=True))
@machine_option
@click.option("--maps", "maps", multiple=True, callback=map_specs,
              help="'thesis', 'appendix-b', or map files (.csv canonical, .txt controller); repeat for a set. "
                   "Default: the machine's maps.")
@click.option("--temperature", type=TEMPERATURE, default=None,
              help="Machine temperature in C for every point (default: the T column, if the file has one).")
@click.option("--pose", default=None, help="alpha,beta,gamma in degrees (Euler 3-1-3). Default: the machine's.")
@click.option("--offset", default=None, help="U1,V1,W1 mount offset in mm. Default: the machine's.")
@click.option("--alignment", default=None,
              help="Pose and offset from this alignment in the library (`cmmpose calibrate alignment --name`).")
@click.option("--library", "library_file", type=click.Path(dir_okay=False), default=None,
              help="Alignment library (JSON) for --alignment. Default: the machine file's mount.alignments.")
@policy_options(log_hold=False)
@click.option("--nan-policy", type=click.Choice(["raise", "propagate"]), default="raise", show_default=True,
              help="A row with NaN or infinity in IN: stop naming it, or write it as a NaN row.")
@json_option
@scheduler_options("For a folder IN: 'threads' (default), 'processes', or a Dask scheduler address tcp://host:port "
                   "(needs the dask extra).")
@model_options(", which read their inputs from IN's columns (t and scan_id for latency, T_<role> for a "
               "thermocouple role; docs/diagnosis.md).")
@uncertainty_options
@overwrite_option("Replace an existing OUT (for a folder IN: the files of the same names in OUT); never an input.")
def compensate_cmd(**flags) -> None:
    """Compensate scanner points IN (CSV, NPY, Parquet, PLY or XYZ: u, v, D, E, F[, T])
    into machine coordinates OUT (by suffix: CSV, NPY, Parquet, PLY, XYZ, PTS or E57;
    X, Y, Z in mm, E57 in metres). Any other column of IN (scan_id, intensity, ...)
    is written to OUT unchanged. An existing OUT is refused unless --overwrite.

    IN may be a folder of Parquet files (a dataset): OUT is then a folder that
    gets one Parquet file per input, named after it, with X, Y, Z and the
    input's other columns, compensated on the --scheduler in bounded memory.

    With --uncertainty, each point's standard uncertainty (k = 1) follows
    X, Y, Z (u_x_mm, u_y_mm, u_z_mm; with --uncertainty-detail also the
    covariance, mm^2), and a budget of its sources is printed."""
    from ..machine import load_machine

    o = CompensateOptions.from_flags(flags)
    if str(o.points_in) != "-" and not os.path.lexists(o.points_in):  # as evaluate's RUN_DIR: a usage error, exit 2
        raise click.BadParameter(f"{o.points_in}: no such file", param_hint="'IN'")
    check_uncertainty_options(o.uncertainty, uncertainty_detail=o.uncertainty_detail, **o.stated)
    check_model_or_maps(o.model_file, o.user_files, o.maps, o.strict_model)
    record = None
    try:
        _check_out(o)  # before any work: an existing OUT without --overwrite, an input, a missing folder
        machine = load_machine(o.machine_file)
        pose, offset = o.pose, o.offset
        if o.alignment is not None:
            if pose is not None or offset is not None:
                raise click.UsageError("give --alignment or --pose/--offset, not both")
            pose, offset, record = _aligned(o.alignment, o.library_file or machine.alignments)
        sources, origins = uncertainty_sources(machine, record, **o.stated) if o.uncertainty else (None, None)
    except Error as exc:
        raise fail(exc) from None
    u_args = {"uncertainty": sources, "uncertainty_detail": o.uncertainty_detail or "standard",
              "uncertainty_origins": origins}
    pose_t = pose_angles(pose, "--pose") if pose is not None else machine.pose.as_tuple()
    offset_t = offset_mm(offset, "--offset") if offset is not None else tuple(machine.offset)
    if Path(o.points_in).is_dir():
        if o.model_file is not None:
            raise click.UsageError(f"{o.points_in} is a folder: --model compensates a point file")
        return _compensate_dataset(o, machine, pose_t, offset_t, u_args)
    if o.scheduler is not None:
        raise click.BadParameter(f"{o.points_in} is a file; --scheduler is for a folder of Parquet files",
                                 param_hint="--scheduler")
    try:
        error_map = load_model(o.model_file, o.user_files) if o.model_file is not None else load_maps(o.maps, machine)
        if o.model_file is not None:
            _check_model_kinematics(error_map, o.model_file, machine)
        size = check_file(o.points_in).stat().st_size
        # One bar over reading, compensating and writing, by bytes of input;
        # memory stays bounded by a few chunks whatever the file's size.
        with Progress(TextColumn("compensating"), BarColumn(), TextColumn("{task.percentage:>3.0f}%"),
                      TimeRemainingColumn(), console=console, disable=size < (32 << 20)) as bar, \
                warnings.catch_warnings(record=True) as caught, aliased_choices_once():
            warnings.simplefilter("always", MapTemperatureWarning)
            warnings.simplefilter("always", AliasedChoiceWarning)
            warnings.simplefilter("always", ModelDomainWarning)
            task = bar.add_task("", total=size)
            with writing("OUT", [o.points_out], o.inputs, overwrite=o.overwrite):  # exclusive without --overwrite
                done = compensate_file(o.points_in, o.points_out, error_map, pose_t, offset_t, o.temperature,
                                       out_of_range=o.out_of_range, nan_policy=o.nan_policy,
                                       temperature_tolerance=o.temperature_tolerance,
                                       progress=lambda at, _: bar.update(task, completed=at), **u_args)
            bar.update(task, completed=size)
        say_caught(caught)
        doubts = model_doubts(caught)
    except Error as exc:
        raise fail(exc) from None
    report, elapsed, t_all = done.report, done.kernel_seconds, done.temperature
    n = report.points
    table = Table(title=f"cmmpose compensate: {o.points_in} -> {o.points_out}", show_header=False)
    machine_row(table, machine)
    table.add_row("points", f"{n:,}")
    table.add_row("maps", repr(error_map))
    table.add_row("temperature", t_all or "-")
    table.add_row("pose (deg)", ", ".join(f"{v:g}" for v in pose_t))
    table.add_row("offset (mm)", ", ".join(f"{v:g}" for v in offset_t))
    kernel_report_rows(table, report, o.temperature_tolerance)
    table.add_row("kernel time", f"{elapsed * 1e3:.1f} ms ({n / max(elapsed, 1e-9) / 1e6:.1f} M points/s)")
    show(table, o.as_json, {"input": str(o.points_in), "output": str(o.points_out), "machine": machine.name,
                            "points": n, "maps": repr(error_map), "temperature": t_all, "pose_deg": list(pose_t),
                            "offset_mm": list(offset_t), "kernel_report": dataclasses.asdict(report),
                            "kernel_seconds": elapsed, **({"model_doubts": doubts} if o.model_file else {}),
                            **_budget(done.uncertainty)})
    _print_budget(done.uncertainty, o.as_json)
    strict_model_exit(doubts, o.strict_model)


@dataclasses.dataclass(frozen=True)
class CompensateOptions:
    """What ``cmmpose compensate`` was asked, from its flags (each field the click parameter of its name): one
    object for the command and its helpers."""

    points_in: str
    points_out: str
    machine_file: str | None
    maps: tuple[str, ...]
    temperature: float | None
    #: --pose and --offset as given (text); None: the machine's, or the --alignment's.
    pose: str | None
    offset: str | None
    alignment: str | None
    library_file: str | None
    out_of_range: str | None
    temperature_tolerance: float | None
    nan_policy: str
    scheduler: str | None
    scheduler_timeout: float
    model_file: str | None
    user_files: tuple[str, ...]
    as_json: bool
    uncertainty: bool
    uncertainty_detail: str | None
    temperature_uncertainty: float | None
    scanner_noise: float | None
    scanner_scale_ppm: float | None
    uncertainty_off: tuple[str, ...]
    strict_model: bool
    overwrite: bool

    @classmethod
    def from_flags(cls, flags: dict) -> CompensateOptions:
        """The options from the command's click parameters (by their names)."""
        return cls(**{f.name: flags[f.name] for f in dataclasses.fields(cls)})

    @property
    def stated(self) -> dict:
        """The uncertainty sources' options as given (cmmpose.cli.uncertainty_options.uncertainty_sources)."""
        return {"temperature_uncertainty": self.temperature_uncertainty, "scanner_noise": self.scanner_noise,
                "scanner_scale_ppm": self.scanner_scale_ppm, "uncertainty_off": self.uncertainty_off}

    @property
    def inputs(self) -> list:
        """Every file the command reads (OUT is never one of them): IN, the model, its user effects, the machine
        file and its own maps, the map files of --maps and the alignment library."""
        return command_inputs([self.points_in, self.model_file, *self.user_files, self.machine_file,
                               self.library_file, *self.maps])


def _check_out(o: CompensateOptions) -> None:
    """The checks of OUT before any work: a file OUT by its suffix (a missing folder, an unknown format) and
    against every input; for a folder IN, each file OUT will get (named after its input). Without
    --overwrite, an existing one is refused (cmmpose.cli.common.check_free)."""
    if Path(o.points_in).is_dir():
        from ..scale import dataset_files

        if Path(o.points_out).is_dir():  # a missing OUT is made: nothing in it to replace
            check_free({"OUT": [Path(o.points_out) / f.name for f in dataset_files(o.points_in)]}, o.inputs,
                       overwrite=o.overwrite)
        return
    check_free({"OUT": o.points_out}, o.inputs, overwrite=o.overwrite)  # first: an input is named as such
    check_writable(o.points_out)  # a missing folder is found now, not after
    output_format(o.points_out)  # an unknown suffix is refused now, listing the known ones


def _budget(tally) -> dict:
    """With --uncertainty: the budget's JSON, under ``uncertainty``."""
    return {} if tally is None else {"uncertainty": tally.to_dict()}


def _print_budget(tally, as_json: bool) -> None:
    """With --uncertainty and without --json: the budget, after the summary."""
    if tally is not None and not as_json:
        show(budget_table(tally, "uncertainty budget (k = 1)"), False)


def _compensate_dataset(o: CompensateOptions, machine, pose_t, offset_t, u_args) -> None:
    """`compensate DATASET_DIR OUT_DIR`: a folder of Parquet files on a Dask scheduler (cmmpose.scale)."""
    import logging

    from ..scale import compensate_dataset

    points_in, points_out, temperature, scheduler = o.points_in, o.points_out, o.temperature, o.scheduler or "threads"
    logging.getLogger("distributed").setLevel(logging.WARNING)  # the local cluster's start-up chatter
    try:
        error_map = load_maps(o.maps, machine)
        with warnings.catch_warnings(record=True) as caught, \
                Progress(TextColumn("compensating"), BarColumn(), TextColumn("{task.percentage:>3.0f}%"),
                         TextColumn("{task.completed:,.0f} points"), TimeRemainingColumn(), console=console) as bar:
            task = bar.add_task("", total=None)
            result = compensate_dataset(points_in, points_out, error_map, pose_t, offset_t, temperature,
                                        out_of_range=o.out_of_range, nan_policy=o.nan_policy,
                                        temperature_tolerance=o.temperature_tolerance, scheduler=scheduler,
                                        scheduler_timeout=o.scheduler_timeout,
                                        progress=lambda done, total: bar.update(task, completed=done, total=total),
                                        overwrite=o.overwrite, **u_args)
        say_caught(caught)
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
    kernel_report_rows(table, report, o.temperature_tolerance)
    table.add_row("wall time", f"{result.elapsed:.1f} s ({result.points / max(result.elapsed, 1e-9) / 1e6:.1f} M points/s)")
    show(table, o.as_json, {"input": str(points_in), "output": str(points_out), "machine": machine.name,
                          "files": [str(f) for f in result.outputs], "points": result.points, "maps": repr(error_map),
                          "temperature": temperature, "pose_deg": list(pose_t), "offset_mm": list(offset_t),
                          "scheduler": scheduler, "kernel_report": dataclasses.asdict(report),
                          "wall_seconds": result.elapsed, **_budget(result.uncertainty)})
    _print_budget(result.uncertainty, o.as_json)


def _aligned(name: str, library_file) -> tuple[str, str, object]:
    """--pose and --offset text of the alignment ``name`` in the library, and its record."""
    from ..calibration.library import AlignmentLibrary

    if library_file is None:
        raise click.UsageError("--alignment needs --library FILE (or mount.alignments in the machine file)")
    if not Path(library_file).is_file():
        raise click.BadParameter(f"{library_file}: no such alignment library", param_hint="--library")
    record = AlignmentLibrary(library_file).load(name)
    return ",".join(map(repr, record.as_pose().as_tuple())), ",".join(map(repr, record.as_offset())), record


def _check_model_kinematics(model, model_file, machine) -> None:
    """A --model whose maps are stacked for another machine configuration than the machine's (its file's
    ``kinematics``, the thesis machine by default) is refused, as evaluate and diagnose refuse it for a run:
    every map error would act through the wrong lever arms."""
    from ..errors import InputError

    stacked = model.maps.kinematics
    if stacked != machine.kinematics:
        raise InputError(f"{model_file}: the model's maps are stacked as {stacked!r}, but the machine "
                         f"({machine.name}; {machine.source}) is configured as {machine.kinematics!r}: the model was "
                         f"found on (or made for) another machine; give its machine file (--machine, kinematics = "
                         f"{stacked!r})", file=str(model_file), what="kinematics", value=stacked)
