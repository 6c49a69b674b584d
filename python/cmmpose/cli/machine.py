"""``cmmpose machine``: machine files."""

from __future__ import annotations

from pathlib import Path

import click
from rich.console import Console
from rich.table import Table

from ..atomicfile import check_output, write_text
from ..errors import Error
from ..machine import example_names
from .common import check_outputs, console, fail, json_option, map_specs, show


@click.group("machine")
def machine_group() -> None:
    """Machine files: one CMM with its scanner (configuration, travel, maps, scanner, mount, thermocouples)."""


@machine_group.command("example")
@click.argument("name", type=click.Choice(example_names()))
@click.option("-o", "--output", "out", required=True, type=click.Path(dir_okay=False), help="Machine file to write.")
@click.option("--overwrite", is_flag=True, help="Replace an existing file.")
def machine_example_cmd(name, out, overwrite) -> None:
    """Write the bundled example machine NAME to a file, to edit into your own."""
    from ..machine import example_text

    path = Path(out)
    try:  # one door out: created exclusively (of two writers one fails), an existing file only with --overwrite
        write_text(path, example_text(name), overwrite=overwrite)
    except Error as exc:
        raise fail(exc) from None
    console.print(f"wrote {path}: the {name} example (cmmpose machine show {path})")


def _show_machine(machine_file, check: bool, as_json: bool = False) -> None:
    from ..machine import load_machine

    try:
        machine = load_machine(machine_file)
        notes = machine.check() if check else []
    except Error as exc:
        raise fail(exc) from None
    table = Table(title=f"cmmpose machine: {machine.source}", show_header=False)
    for key, value in machine.describe():
        table.add_row(key, value)
    if as_json:
        show(table, True, {"source": str(machine.source), **dict(machine.describe()),
                           **({"notes": notes, "ok": True} if check else {})})
        return
    Console().print(table)
    for note in notes:
        console.print(f"note: {note}")
    if check:
        console.print("ok: the file reads, its maps load and cover the travel")


@machine_group.command("show")
@click.argument("machine_file", metavar="FILE", required=False, type=click.Path(dir_okay=False))
@json_option
def machine_show_cmd(machine_file, as_json) -> None:
    """Print what FILE says about the machine (default: the thesis machine)."""
    _show_machine(machine_file, check=False, as_json=as_json)


@machine_group.command("check")
@click.argument("machine_file", metavar="FILE", type=click.Path(dir_okay=False))
@json_option
def machine_check_cmd(machine_file, as_json) -> None:
    """Check FILE: every key known and well-formed, the maps readable and covering the travel."""
    _show_machine(machine_file, check=True, as_json=as_json)


@machine_group.command("configurations")
@json_option
def machine_configurations_cmd(as_json) -> None:
    """List the machine configurations (how the carriages are stacked)."""
    from ..machine import configurations

    table = Table(title="Machine configurations (kinematics = ...)")
    for col in ("name", "stacking, base up", "what it is"):
        table.add_column(col)
    for c in configurations():
        table.add_row(c["name"], ", ".join(f"{a} ({side})" for a, side in c["stack"]), c["description"])
    show(table, as_json, configurations())


@machine_group.command("reproducibility")
@click.argument("run_dirs", metavar="RUN_DIR...", nargs=-1, required=True,
                type=click.Path(exists=True, file_okay=False))
@click.option("--machine", "machine_file", required=True, type=click.Path(exists=True, dir_okay=False),
              help="The machine file to start from (`cmmpose machine example thesis -o M.toml`); it is not changed.")
@click.option("--maps", "maps", multiple=True, callback=map_specs,
              help="Maps that compensate the points before the spheres are fitted; default the machine's.")
@click.option("-o", "--output", "out", required=True, type=click.Path(dir_okay=False),
              help="The new machine file: the machine's, with [reproducibility] set.")
@click.option("--overwrite", is_flag=True, help="Replace an existing output file (never an input).")
@json_option
def machine_reproducibility_cmd(run_dirs, machine_file, maps, out, overwrite, as_json) -> None:
    """Estimate the machine's per-scan centre reproducibility (um per axis) from runs that repeat scans of a
    sphere, and write it into a copy of the machine file: `cmmpose diagnose --machine NEW` then takes it as the
    noise floor of runs that repeat no scan. Runs that repeat no scan are refused, by name."""
    from ..diagnosis.floor import reproducibility_from_runs
    from ..machine import load_machine, with_reproducibility
    from ..run import Run

    path = Path(out)
    try:
        check_outputs({"--output": out}, run_dirs, [machine_file])
        check_output(path, overwrite=overwrite, what="--output")
        machine = load_machine(machine_file)
        runs = [Run.load(r) for r in run_dirs]
        model = machine.maps_for_run(runs[0], maps)
        est = reproducibility_from_runs(runs, model, run_names=[str(r) for r in run_dirs])
        source = (f"cmmpose machine reproducibility: Type A from {est['scans']} repeated scans of {est['spheres']} "
                  f"spheres in {len(runs)} run{'s' if len(runs) > 1 else ''} ({', '.join(map(str, run_dirs))}); "
                  f"u = {est['u_um']:.2g} um on {est['dof']} dof")
        text = Path(machine_file).read_text(encoding="utf-8")
        write_text(path, with_reproducibility(text, est["per_scan_um"], source, where=str(machine_file)),
                   overwrite=overwrite)
    except Error as exc:
        raise fail(exc) from None
    table = Table(title=f"per-scan reproducibility -> {path}", show_header=False)
    table.add_row("per scan, per axis (um)", f"{est['per_scan_um']:.2f} ± {est['u_um']:.2f} ({est['dof']} dof)")
    table.add_row("x, y, z (um)", ", ".join(f"{v:.2f}" for v in est["per_axis_um"]))
    table.add_row("repeated scans", f"{est['scans']} scans of {est['spheres']} spheres scanned more than once")
    for r in est["runs"]:
        table.add_row(f"  {r['name']}", f"{r['per_scan_um']:.2f} um ({r['dof']} dof)")
    show(table, as_json, {"output": str(path), "machine": str(machine_file), **est})
    if not as_json:
        console.print(f"wrote {path} (cmmpose diagnose RUN --machine {path})")
