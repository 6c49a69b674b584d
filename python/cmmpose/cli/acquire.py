"""``cmmpose acquire``: recording a run from the scanner and the thermocouple logger."""

from __future__ import annotations

from dataclasses import dataclass, fields
import os

import click
from rich.console import Console

from ..acquire.scpi import TC_TYPES
from ..errors import Error
from .common import Positive, console, fail, machine_option, offset_mm, pose_angles


class ThermocoupleType(click.ParamType):
    """A thermocouple type the logger code configures (``cmmpose.acquire.scpi.TC_TYPES``), any case."""

    name = "[" + "|".join(TC_TYPES) + "]"

    def convert(self, value, param, ctx):
        if not isinstance(value, str) or value.upper() not in TC_TYPES:
            self.fail(f"{value!r} is not a thermocouple type ({', '.join(TC_TYPES)})", param, ctx)
        return value.upper()


SECONDS = Positive("seconds")
BAUD = click.IntRange(min=1)


@click.command("acquire")
@click.option("--scanner", default=None, help="Scanner + scales port: device path or pyserial URL (socket://, rfc2217://).")
@click.option("--thermo", default=None, help="Thermocouple logger port: device path or pyserial URL.")
@click.option("-o", "--output", "run_dir", required=True, type=click.Path(file_okay=False), help="Run directory to write.")
@click.option("--duration", type=SECONDS, default=None, help="Seconds to record (default: until Ctrl-C).")
@click.option("--plan", type=click.Path(exists=True, dir_okay=False), default=None,
              help="Plan JSON: scans, poses, channels, artefact, maps (docs/protocols.md).")
@click.option("--pose", default=None, help="alpha,beta,gamma in degrees, when the plan has no poses. Default: the machine's.")
@click.option("--offset", default=None, help="U1,V1,W1 in mm, when the plan has no poses. Default: the machine's.")
@machine_option
@click.option("--tc-type", type=ThermocoupleType(), default="E", show_default=True,
              help="Thermocouple type.")
@click.option("--thermo-interval", type=SECONDS, default=1.0, show_default=True, help="Seconds between logger scans.")
@click.option("--flush-interval", type=SECONDS, default=0.2, show_default=True, help="Longest wait before records reach disk, s.")
@click.option("--scanner-baud", type=BAUD, default=921600, show_default=True,
              help="Baud rate of the scanner + scales port (a serial device; ignored by socket:// URLs).")
@click.option("--thermo-baud", type=BAUD, default=9600, show_default=True,
              help="Baud rate of the thermocouple logger port.")
@click.option("--overwrite", is_flag=True, help="Replace a recording already in RUN_DIR.")
@click.option("--recover", is_flag=True, help="Rebuild RUN_DIR from its journal (after a crash); opens no ports.")
@click.option("--no-display", is_flag=True, help="No live display.")
def acquire_cmd(**flags) -> None:
    """Record the scanner + scales stream and the thermocouple logger into RUN_DIR
    (live display; Ctrl-C stops cleanly and closes the run)."""
    from ..acquire import recover as recover_run
    from ..acquire.display import record_live, summary_table
    from ..machine import load_machine

    o = AcquireOptions.from_flags(flags)
    try:
        if o.recover:
            if not os.path.lexists(o.run_dir):  # a name that names no folder: a usage error (exit 2) as everywhere
                raise click.BadParameter(f"{o.run_dir}: no such run directory to recover", param_hint="--output")
            rec = recover_run(o.run_dir)
            console.print(repr(rec))
            run = rec.run
        else:
            if not (o.scanner or o.thermo):
                raise click.UsageError("give --scanner, --thermo or both")
            machine = load_machine(o.machine_file)
            pose_t = pose_angles(o.pose, "--pose") if o.pose is not None else machine.pose.as_tuple()
            offset_t = offset_mm(o.offset, "--offset") if o.offset is not None else tuple(machine.offset)
            run = record_live(o.run_dir, o.scanner, o.thermo, duration=o.duration, console=console,
                              show=not o.no_display, plan=_plan_for(o.plan, machine, o.machine_file), pose=pose_t,
                              offset=offset_t, tc_type=o.tc_type, thermo_interval=o.thermo_interval,
                              flush_interval=o.flush_interval, scanner_baudrate=o.scanner_baud,
                              thermo_baudrate=o.thermo_baud, overwrite=o.overwrite)
    except Error as exc:
        raise fail(exc) from None
    Console().print(summary_table(run, o.run_dir))


@dataclass(frozen=True)
class AcquireOptions:
    """What ``cmmpose acquire`` was asked, from its flags (each field the click parameter of its name)."""

    scanner: str | None
    thermo: str | None
    run_dir: str
    duration: float | None
    plan: str | None
    pose: str | None
    offset: str | None
    machine_file: str | None
    tc_type: str
    thermo_interval: float
    flush_interval: float
    scanner_baud: int
    thermo_baud: int
    overwrite: bool
    recover: bool
    no_display: bool

    @classmethod
    def from_flags(cls, flags: dict) -> AcquireOptions:
        """The options from the command's click parameters (by their names)."""
        return cls(**{f.name: flags[f.name] for f in fields(cls)})


def _plan_for(plan_file, machine, machine_file):
    """The plan to record with (cmmpose.acquire.plan.Plan.with_machine_channels); a plan file alone when no
    machine file is given (the recorder reads it)."""
    from ..acquire.plan import Plan

    if machine_file is None:
        return plan_file
    return (Plan.read(plan_file) if plan_file else Plan()).with_machine_channels(machine)
