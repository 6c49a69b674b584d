"""``cmmpose machine``: machine files."""

from __future__ import annotations

from pathlib import Path

import click
from rich.console import Console
from rich.table import Table

from ..atomicfile import write_text
from ..errors import Error
from ..machine import example_names
from .common import json_option, show, console, fail


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
    if path.exists() and not overwrite:
        raise click.ClickException(f"{path}: exists (give --overwrite to replace it)")
    try:
        write_text(path, example_text(name))  # atomic: a full disk leaves the earlier file whole
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
