"""``cmmpose compensate``: scanner points to machine coordinates (a file, or a folder of Parquet files on Dask)."""

from __future__ import annotations

import dataclasses
import os
import warnings
from pathlib import Path

import click
from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn
from rich.table import Table

from ..atomicfile import check_not_input
from ..errormap import ErrorMapSet
from ..errors import AliasedChoiceWarning, Error, MapTemperatureWarning, ModelDomainWarning
from ..filecompensation import compensate_file
from ..formats.pointfiles import check_writable, output_format
from ..formats.pointformats.common import check_file
from .common import (aliased_choices_once, check_model_or_maps, console, fail, json_option, kernel_report_rows,
                     load_maps, load_model, machine_option, machine_row, map_specs, model_doubts, model_options,
                     offset_mm, policy_options, pose_angles, say_caught, scheduler_options, show, strict_model_exit)
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
def compensate_cmd(points_in, points_out, machine_file, maps, temperature, pose, offset, alignment, library_file,
                   out_of_range, temperature_tolerance, nan_policy, scheduler, scheduler_timeout, model_file,
                   user_files, as_json, uncertainty, uncertainty_detail, temperature_uncertainty, scanner_noise,
                   scanner_scale_ppm, uncertainty_off, strict_model=False) -> None:
    """Compensate scanner points IN (CSV, NPY, Parquet, PLY or XYZ: u, v, D, E, F[, T])
    into machine coordinates OUT (by suffix: CSV, NPY, Parquet, PLY, XYZ, PTS or E57;
    X, Y, Z in mm, E57 in metres). Any other column of IN (scan_id, intensity, ...)
    is written to OUT unchanged.

    IN may be a folder of Parquet files (a dataset): OUT is then a folder that
    gets one Parquet file per input, named after it, with X, Y, Z and the
    input's other columns, compensated on the --scheduler in bounded memory.

    With --uncertainty, each point's standard uncertainty (k = 1) follows
    X, Y, Z (u_x_mm, u_y_mm, u_z_mm; with --uncertainty-detail also the
    covariance, mm^2), and a budget of its sources is printed."""
    from ..machine import load_machine

    if str(points_in) != "-" and not os.path.lexists(points_in):  # as evaluate's RUN_DIR: a usage error, exit 2
        raise click.BadParameter(f"{points_in}: no such file", param_hint="'IN'")
    stated = {"temperature_uncertainty": temperature_uncertainty, "scanner_noise": scanner_noise,
              "scanner_scale_ppm": scanner_scale_ppm, "uncertainty_off": uncertainty_off}
    check_uncertainty_options(uncertainty, uncertainty_detail=uncertainty_detail, **stated)
    record = None
    try:
        machine = load_machine(machine_file)
        if alignment is not None:
            if pose is not None or offset is not None:
                raise click.UsageError("give --alignment or --pose/--offset, not both")
            pose, offset, record = _aligned(alignment, library_file or machine.alignments)
        sources, origins = uncertainty_sources(machine, record, **stated) if uncertainty else (None, None)
    except Error as exc:
        raise fail(exc) from None
    u_args = {"uncertainty": sources, "uncertainty_detail": uncertainty_detail or "standard",
              "uncertainty_origins": origins}
    pose_t = pose_angles(pose, "--pose") if pose is not None else machine.pose.as_tuple()
    offset_t = offset_mm(offset, "--offset") if offset is not None else tuple(machine.offset)
    check_model_or_maps(model_file, user_files, maps, strict_model)
    if Path(points_in).is_dir():
        if model_file is not None:
            raise click.UsageError(f"{points_in} is a folder: --model compensates a point file")
        return _compensate_dataset(points_in, points_out, machine, maps, temperature, pose_t, offset_t, out_of_range,
                                   temperature_tolerance, nan_policy, scheduler or "threads", scheduler_timeout,
                                   as_json, u_args)
    if scheduler is not None:
        raise click.BadParameter(f"{points_in} is a file; --scheduler is for a folder of Parquet files",
                                 param_hint="--scheduler")
    try:
        check_writable(points_out)  # before any work: a missing folder is found now, not after
        output_format(points_out)  # an unknown suffix is refused now, listing the known ones
        check_not_input(points_out, [points_in, *([model_file] if model_file else []), *user_files], "OUT")
        error_map = load_model(model_file, user_files) if model_file is not None else load_maps(maps, machine)
        if model_file is not None:
            _check_model_kinematics(error_map, model_file, machine)
        size = check_file(points_in).stat().st_size
        # One bar over reading, compensating and writing, by bytes of input;
        # memory stays bounded by a few chunks whatever the file's size.
        with Progress(TextColumn("compensating"), BarColumn(), TextColumn("{task.percentage:>3.0f}%"),
                      TimeRemainingColumn(), console=console, disable=size < (32 << 20)) as bar, \
                warnings.catch_warnings(record=True) as caught, aliased_choices_once():
            warnings.simplefilter("always", MapTemperatureWarning)
            warnings.simplefilter("always", AliasedChoiceWarning)
            warnings.simplefilter("always", ModelDomainWarning)
            task = bar.add_task("", total=size)
            done = compensate_file(points_in, points_out, error_map, pose_t, offset_t, temperature,
                                   out_of_range=out_of_range, nan_policy=nan_policy,
                                   temperature_tolerance=temperature_tolerance,
                                   progress=lambda at, _: bar.update(task, completed=at), **u_args)
            bar.update(task, completed=size)
        say_caught(caught)
        doubts = model_doubts(caught)
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
    show(table, as_json, {"input": str(points_in), "output": str(points_out), "machine": machine.name,
                          "points": n, "maps": repr(error_map), "temperature": t_all, "pose_deg": list(pose_t),
                          "offset_mm": list(offset_t), "kernel_report": dataclasses.asdict(report),
                          "kernel_seconds": elapsed, **({"model_doubts": doubts} if model_file else {}),
                          **_budget(done.uncertainty)})
    _print_budget(done.uncertainty, as_json)
    strict_model_exit(doubts, strict_model)


def _budget(tally) -> dict:
    """With --uncertainty: the budget's JSON, under ``uncertainty``."""
    return {} if tally is None else {"uncertainty": tally.to_dict()}


def _print_budget(tally, as_json: bool) -> None:
    """With --uncertainty and without --json: the budget, after the summary."""
    if tally is not None and not as_json:
        show(budget_table(tally, "uncertainty budget (k = 1)"), False)


def _compensate_dataset(points_in, points_out, machine, maps, temperature, pose_t, offset_t, out_of_range,
                        temperature_tolerance, nan_policy, scheduler, scheduler_timeout, as_json=False,
                        u_args=None) -> None:
    """`compensate DATASET_DIR OUT_DIR`: a folder of Parquet files on a Dask scheduler (cmmpose.scale)."""
    import logging

    from ..scale import compensate_dataset

    logging.getLogger("distributed").setLevel(logging.WARNING)  # the local cluster's start-up chatter
    try:
        error_map = load_maps(maps, machine)
        with warnings.catch_warnings(record=True) as caught, Progress(TextColumn("compensating"), BarColumn(), TextColumn("{task.percentage:>3.0f}%"),
                      TextColumn("{task.completed:,.0f} points"),
                      TimeRemainingColumn(), console=console) as bar:
            task = bar.add_task("", total=None)
            result = compensate_dataset(points_in, points_out, error_map, pose_t, offset_t, temperature,
                                        out_of_range=out_of_range, nan_policy=nan_policy,
                                        temperature_tolerance=temperature_tolerance, scheduler=scheduler,
                                        scheduler_timeout=scheduler_timeout, progress=lambda done, total: bar.update(task, completed=done, total=total),
                                        **(u_args or {}))
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
    kernel_report_rows(table, report, temperature_tolerance)
    table.add_row("wall time", f"{result.elapsed:.1f} s ({result.points / max(result.elapsed, 1e-9) / 1e6:.1f} M points/s)")
    show(table, as_json, {"input": str(points_in), "output": str(points_out), "machine": machine.name,
                          "files": [str(f) for f in result.outputs], "points": result.points, "maps": repr(error_map),
                          "temperature": temperature, "pose_deg": list(pose_t), "offset_mm": list(offset_t),
                          "scheduler": scheduler, "kernel_report": dataclasses.asdict(report),
                          "wall_seconds": result.elapsed, **_budget(result.uncertainty)})
    _print_budget(result.uncertainty, as_json)


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
