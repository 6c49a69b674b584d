"""The artefact commands of the ``cmmpose`` command line (docs/artefacts.md):
``artefact example|show|check``, and what ``simulate --artefact`` and
``evaluate`` do with an artefact run. ``cmmpose.cli`` adds the group and
calls :func:`simulate_artefact` and :func:`evaluate_artefact_run`."""

from __future__ import annotations

import contextlib
import json
import time
import warnings
from pathlib import Path
from typing import TYPE_CHECKING

import click
import numpy as np
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from .. import artefacts
from ..atomicfile import ensure_folder, write_text
from .._json import dumps as strict_json
from ..errors import Error, InputError, ModelDomainWarning
from .common import (check_free, command_inputs, json_option, table_data, console, show, machine_option,
                     model_doubts, overwrite_option, print_model_check, say_caught, strict_model_exit, writing)
from .common import fail as _fail

if TYPE_CHECKING:
    from .simulate_options import SimulateOptions

__all__ = ["artefact_group", "simulate_artefact", "evaluate_artefact_run", "diagnose_plate_fits_cli"]




def _write_text(path: Path, text: str, overwrite: bool = True) -> None:
    """Write ``text`` at ``path`` (its folder made if missing), atomically (:mod:`cmmpose.atomicfile`;
    ``overwrite=False``: created exclusively, an existing file refused)."""
    ensure_folder(path.parent if str(path.parent) else ".")
    write_text(path, text, overwrite=overwrite)


@click.group("artefact")
def artefact_group() -> None:
    """Artefact files: calibrated ball plates, step gauges, ballbars and spheres (docs/artefacts.md)."""


@artefact_group.command("example")
@click.argument("name", metavar="KIND|NAME")
@click.option("-o", "--output", "out", required=True, type=click.Path(dir_okay=False), help="Artefact file to write.")
@click.option("--overwrite", is_flag=True, help="Replace an existing file.")
def artefact_example_cmd(name, out, overwrite) -> None:
    """Write a bundled example artefact file to edit: a KIND (ball-plate, step-gauge, ballbar, sphere) or a NAME
    (koba-0620, koba-0420, koba-0320, apmp-plate, step-gauge-31x20, thesis-ballbar, reference-sphere)."""
    known = [*artefacts.available(), *artefacts.example_names()]
    if name not in known:
        raise click.BadParameter(f"{name!r} is not one of {', '.join(known)}", param_hint="KIND|NAME")
    path = Path(out)
    try:  # one door out: created exclusively (of two writers one fails), an existing file only with --overwrite
        _write_text(path, artefacts.example_text(name), overwrite=overwrite)
    except Error as exc:
        raise _fail(exc) from None
    console.print(f"wrote {escape(str(path))}: the {name} example (cmmpose artefact show {escape(str(path))})")


def _show(path, check: bool, as_json: bool = False) -> None:
    try:
        a = artefacts.load_artefact(path)
    except Error as exc:
        raise _fail(exc) from None
    kind = artefacts.get(a.kind)
    table = Table(title=f"cmmpose artefact: {escape(a.source)}", show_header=False)
    lo, hi = a.centres.min(axis=0), a.centres.max(axis=0)
    for key, value in (
        ("kind", f"{a.kind}: {kind.summary}"),
        ("name", a.name),
        ("certificate", a.certificate),
        ("balls", f"{a.n_balls} (ids {artefacts.base.id_ranges(a.ids)})"),
        ("extent (mm)", ", ".join(f"{ax} {l:.3f}..{h:.3f}" for ax, l, h in zip("xyz", lo, hi))),
        ("radius (mm)", f"nominal {a.nominal_radius:g}, calibrated {a.calibrated_radius:g} (u {a.u_radius * 1e3:g} um)"),
        ("u of centres (um)", f"{a.u_centres.min() * 1e3:g}..{a.u_centres.max() * 1e3:g}"),
        ("expansion", f"{a.expansion * 1e6:g} ppm/K"),
        ("reference temperature", f"{a.reference_temperature:g} C"),
        ("placements", f"e.g. --placement {kind.layout}"),
    ):
        table.add_row(key, escape(value))
    if as_json:
        show(table, True, table_data(table) | ({"ok": True} if check else {}))
        return
    Console().print(table)
    if check:
        console.print("ok: every key known, every ball with its uncertainties, the geometry fits the kind")


@artefact_group.command("show")
@click.argument("path", metavar="FILE|NAME")
@json_option
def artefact_show_cmd(path, as_json) -> None:
    """Print what an artefact file (or a bundled example) says."""
    _show(path, check=False, as_json=as_json)


@artefact_group.command("check")
@click.argument("path", metavar="FILE|NAME")
@json_option
def artefact_check_cmd(path, as_json) -> None:
    """Check an artefact file: keys, numbers, repeated balls, uncertainties, geometry."""
    _show(path, check=True, as_json=as_json)


@artefact_group.command("plan")
@click.argument("path", metavar="FILE|NAME")
@click.option("--placement", "placements", multiple=True,
              help="Where the artefact sits (repeatable; e.g. xy@z=-450,rot=90, planes, iso10360-2; "
                   "default: the kind's layout).")
@machine_option
@click.option("--speed", type=float, default=35.0, show_default=True, help="Sweep speed, mm/s.")
@click.option("--bidirectional", is_flag=True, help="Alternate the sweep direction from ball to ball.")
@click.option("--repeat-scans", "repeat_scans", type=click.IntRange(0), default=None, metavar="N",
              help="Scan the first N balls again at the end, the artefact not moved: the run then measures its own "
                   "per-scan reproducibility, the diagnosis's noise floor (docs/diagnosis.md). Default 6 (every scan "
                   "once more if fewer); 0 repeats none.")
@click.option("-o", "--output", "out", required=True, type=click.Path(dir_okay=False),
              help="Plan file (JSON) for `cmmpose acquire --plan`.")
@overwrite_option()
def artefact_plan_cmd(path, placements, machine_file, speed, bidirectional, out, repeat_scans=0,
                      overwrite=False) -> None:
    """Write the acquisition plan of an artefact run: the pose and sweep of every ball of every placement
    (docs/artefacts.md, 'Recording a plate'), for `cmmpose acquire --plan`."""
    from ..acquire.plan import artefact_plan
    from ..machine import load_machine

    inputs = command_inputs([path, machine_file])
    try:
        check_free({"--output": out}, inputs, overwrite=overwrite)  # before any work
        machine = load_machine(machine_file)
        artefact = artefacts.load_artefact(path)
        plan = artefact_plan(artefact, list(placements) or [artefacts.get(artefact.kind).layout], machine,
                             speed=speed, bidirectional=bidirectional, repeat_scans=repeat_scans)
        with writing("--output", [out], inputs, overwrite=overwrite):  # created exclusively without --overwrite
            plan.write(out)
    except Error as exc:
        raise _fail(exc) from None
    table = Table(title=f"cmmpose artefact plan -> {escape(str(out))}")
    for c in ("scan", "placement", "ball", "pose", "sweep"):
        table.add_column(c)
    labels = [p["label"] for p in plan.artefact["placements"]]
    poses = {p["pose_id"]: f"{p['alpha']:g},{p['beta']:g},{p['gamma']:g}" for p in plan.poses}
    for s in plan.scans:
        start = ", ".join(f"{x:.1f}" for x in s["sweep_start_mm"])
        table.add_row(str(s["scan_id"]), escape(f"{s['position']}: {labels[s['position'] - 1]}"), str(s["ball"]),
                      poses[s["pose_id"]], f"{'+' if s['sweep_direction'] > 0 else '-'}{s['sweep_axis']} "
                      f"{s['sweep_length_mm']:.1f} mm from {start} at {s['sweep_speed']:g} mm/s")
    Console(width=max(120, Console().width)).print(table)
    console.print(f"wrote {escape(str(out))}: {len(plan.scans)} sweeps, {len(plan.poses)} poses "
                  f"(cmmpose acquire --plan {escape(str(out))} ...)")


def simulate_artefact(o: SimulateOptions, machine, maps, effects, progress_columns, record_maps) -> None:
    """``cmmpose simulate --artefact A --placement P ...``: simulate, save, print a summary; ``maps`` and
    ``effects`` as loaded and parsed from ``o``; ``record_maps(run)`` gives the run with its record of the maps
    (as a ballbar run's)."""
    from rich.progress import Progress

    from ..sim.artefact_runs import simulate_artefact_run

    from ..run import check_run_target

    artefact_spec, placements, temperature, run_dir, overwrite = (o.artefact, o.placements, o.temperature, o.run_dir,
                                                                  o.overwrite)
    speed, bidirectional, jitter_um, seed, repeat_scans = o.speed, o.bidirectional, o.jitter, o.seed, o.repeat_scans
    try:
        check_run_target(run_dir, overwrite=overwrite)  # before any work
        artefact = artefacts.load_artefact(artefact_spec)
        start = time.perf_counter()
        with Progress(*progress_columns, console=console) as bar:
            task = bar.add_task("", total=None)
            run, truth = simulate_artefact_run(
                artefact, list(placements) or [artefacts.get(artefact.kind).layout], maps, temperature, effects,
                machine=machine, speed=speed, bidirectional=bidirectional, jitter=jitter_um * 1e-3, seed=seed,
                progress=lambda done, total: bar.update(task, completed=done, total=total), repeat_scans=repeat_scans)
        run = record_maps(run)
        elapsed = time.perf_counter() - start
        run.save(run_dir, truth=truth, overwrite=overwrite)
    except Error as exc:
        raise _fail(exc) from None
    table = Table(title=f"cmmpose simulate -> {escape(str(run_dir))}", show_header=False)
    table.add_row("machine", escape(f"{machine.name} ({machine.kinematics}; {machine.source})"))
    table.add_row("artefact", escape(f"{artefact.name} ({artefact.kind}, {artefact.n_balls} balls)"))
    for k, p in enumerate(run.artefact["placements"], start=1):
        table.add_row(f"placement {k}", escape(f"{p['label']}: centroid at "
                                               + ", ".join(f"{x:.1f}" for x in p["centre_mm"]) + " mm"))
    n = len(run.scans["scan_id"])
    table.add_row("points", f"{run.n_points:,} ({run.n_points / n:,.0f} per ball, {n} sweeps)")
    table.add_row("temperature", f"{temperature:g} C")
    table.add_row("effects", escape(", ".join(e.name for e in effects)) or "none")
    table.add_row("time", f"{elapsed:.2f} s")
    show(table, o.as_json)


def evaluate_artefact_run(run, model, temperature, reject, u_temperature, report_dir, as_json, policy,
                          strict_model: bool | None = None, outputs=None) -> None:
    """``cmmpose evaluate RUN_DIR`` on an artefact run: the table or JSON, and the report (written inside
    ``outputs``, the command's :func:`cmmpose.cli.common.writing` group: exclusive, whole or none); with a --model
    (``strict_model`` not None) its check against the plain maps (cmmpose.evaluation.model_check), and with
    --strict-model exit status 1 where the model was doubted."""
    from ..evaluation.artefact import evaluate_artefact
    from ..evaluation.ballbar_uncertainty import DEFAULT_U_TEMPERATURE_K
    from ..evaluation.model_check import check_model

    check = None
    try:
        options = dict(temperature=temperature, reject=reject,
                       u_temperature=DEFAULT_U_TEMPERATURE_K if u_temperature is None else u_temperature, **policy)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", ModelDomainWarning)
            ev = evaluate_artefact(run, model, **options)
            if strict_model is not None:
                check = check_model(run, model, evaluation=ev, **options)
        say_caught(caught)
        poses = dict(zip(run.scans["scan_id"].tolist(), run.scans["pose_id"].tolist()))
        files = []
        if report_dir:
            with outputs if outputs is not None else contextlib.nullcontext():
                files = write_artefact_report(ev, Path(report_dir), poses)
    except Error as exc:
        raise _fail(exc) from None
    if as_json:
        doc = json.loads(ev.to_json())
        click.echo(strict_json({**doc, **({"model_check": check.to_dict()} if check is not None else {})}, indent=2))
    else:
        Console(width=max(Console().width, 140)).print(ev)
        if check is not None:
            print_model_check(check)
    for f in files:
        console.print(f"wrote {escape(str(f))}")
    if check is not None:
        strict_model_exit(model_doubts(caught) + ([check.verdict] if check.worse else []), strict_model)


def diagnose_plate_fits_cli(fits_file, artefact_spec, state, temperature, nominal_radius, reference_length,
                            as_json) -> None:
    """``cmmpose diagnose-fits FITS --artefact A``: the linear errors and radius patterns of an
    artefact's measured centres (:mod:`cmmpose.diagnosis.plate_fits`)."""
    import json

    from ..diagnosis.plate_fits import LINEAR_ERRORS, diagnose_plate_fits, read_plate_fits

    if artefact_spec is None:
        raise click.UsageError("--temperature takes --artefact (a ballbar's fits are at 20 C)")
    for flag, given in (("--nominal-radius", nominal_radius), ("--reference-length", reference_length)):
        if given is not None:
            raise click.UsageError(f"{flag} is a ballbar's: with --artefact the artefact file gives the radius "
                                   f"and the calibrated centres")
    if not Path(fits_file).exists():  # a FIFO or a device: the reader says what it is
        raise click.BadParameter(f"{fits_file}: no such file", param_hint="FITS")
    try:
        artefact = artefacts.load_artefact(artefact_spec)
        table = read_plate_fits(fits_file, state)
        d = diagnose_plate_fits(artefact, table, temperature=20.0 if temperature is None else temperature)
    except Error as exc:
        raise _fail(exc) from None
    if as_json:
        click.echo(json.dumps(d.to_dict(), indent=1, allow_nan=False))
        return
    table_out = Table(title=f"measured centres of {escape(artefact.name)}: {escape(str(fits_file))}")
    for col in ("linear error", "value ± u (k = 1)"):
        table_out.add_column(col)
    for (name, unit), v, u in zip(LINEAR_ERRORS, d.values, d.uncertainties):
        table_out.add_row(name, f"{v:+.2f} ± {u:.2f} {unit}" if np.isfinite(u) else
                          "undetermined (no placement shows it)")
    table_out.caption = (f"{sum(len(b) for b in d.balls)} balls at {len(d.placements)} placement(s): rms deviation "
                         f"{d.rms_um:.2f} um, {d.residual_rms_um:.2f} um without the linear errors; mean radius "
                         f"{d.radius_mean:.4f} mm (calibrated {d.nominal_radius:g})")
    Console(width=max(Console().width, 110)).print(table_out)
    Console(width=150).print(d.patterns)


#: The files of an artefact run's report (the plots only with matplotlib; ``deviations_<result>.png`` besides).
ARTEFACT_REPORT_FILES = ("evaluation.json", "deviations.csv", "lengths.csv", "centres.csv", "length_errors.png")


def write_artefact_report(ev, directory: Path, poses: dict | None = None) -> list[Path]:
    """evaluation.json, deviations.csv, lengths.csv, centres.csv and, with matplotlib, the plots; the files
    written."""
    if directory.exists() and not directory.is_dir():
        raise InputError(f"--report {directory}: exists and is not a directory")
    files = [directory / "evaluation.json", directory / "deviations.csv", directory / "lengths.csv",
             directory / "centres.csv"]
    _write_text(files[0], ev.to_json(indent=2) + "\n")
    # The measured centres at 20 C as `cmmpose diagnose-fits centres.csv --artefact A --state S` reads them.
    # ``poses`` (scan id -> pose id) adds which pose scanned each ball ('+'-joined when several did).
    centres = ["state,placement,ball,x_mm,y_mm,z_mm,radius_mm" + (",pose" if poses else "")]
    for r in ev.results:
        for p in r.placements:
            for b in p.balls:
                pose = "+".join(str(x) for x in sorted({poses[s] for s in b.scans})) if poses else ""
                centres.append(f"{r.label},{p.position},{b.ball},{b.measured[0]:.6f},{b.measured[1]:.6f},"
                               f"{b.measured[2]:.6f},{ev.artefact.calibrated_radius + b.radius_error:.6f}"
                               + (f",{pose}" if poses else ""))
    _write_text(files[3], "\n".join(centres) + "\n")
    rows = ["result,position,ball,deviation_x_um,deviation_y_um,deviation_z_um,u_x_um,u_y_um,u_z_um,deviation_um"]
    lines = ["result,position,ball_a,ball_b,length_mm,error_um,u_um"]
    for r in ev.results:
        for p in r.placements:
            for b in p.balls:
                d, u = b.deviation * 1e3, b.u * 1e3
                rows.append(f"{r.label},{p.position},{b.ball},{d[0]:.4f},{d[1]:.4f},{d[2]:.4f},"
                            f"{u[0]:.4f},{u[1]:.4f},{u[2]:.4f},{b.magnitude * 1e3:.4f}")
            for e in p.lengths:
                lines.append(f"{r.label},{p.position},{e.ball_a},{e.ball_b},{e.length:.5f},{e.error * 1e3:.4f},"
                             f"{e.u * 1e3:.4f}")
    _write_text(files[1], "\n".join(rows) + "\n")
    _write_text(files[2], "\n".join(lines) + "\n")
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        console.print("matplotlib is not installed: no plots (pip install 'cmmpose[plot]')")
        return files
    from ..evaluation.plots import plot_artefact_deviations, plot_length_errors

    for r in ev.results:
        path = directory / f"deviations_{r.label}.png"
        plot_artefact_deviations(ev.artefact, r, path)
        files.append(path)
    path = directory / "length_errors.png"
    plot_length_errors(ev.results, path)
    files.append(path)
    return files
