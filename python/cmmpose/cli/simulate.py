"""``cmmpose simulate`` and ``calibrate simulate-alignment``: virtual runs and alignment measurements."""

from __future__ import annotations

import dataclasses
import shlex
import time
from pathlib import Path

import click
import numpy as np
from rich.progress import BarColumn, Progress, TextColumn
from rich.table import Table

from .. import effects as effects_registry
from .._json import dumps as strict_json
from ..atomicfile import atomic_write, ensure_folder, write_text
from ..errors import Error
from .artefact import simulate_artefact
from .simulate_options import SimulateOptions
from .common import (SEED, check_free, command_inputs, console, fail, json_option, load_maps, machine_option,
                     machine_row, map_specs, overwrite_option, parse_effects, pose_angles, show, writing)
from .common import TEMPERATURE


@click.command("simulate")
@click.option("--layout", type=click.Choice(["b89", "crossed"]), default="b89", show_default=True,
              help="20 ASME B89.4.1 positions (thesis Appendix C geometry) or the 8 crossed-ballbar positions.")
@click.option("--temperature", type=TEMPERATURE, default=20.0, show_default=True, help="Machine temperature, C.")
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
@click.option("--repeat-scans", "repeat_scans", type=click.IntRange(0), default=None, metavar="N",
              help="Scan N balls again at the end (ball 1 and 2 of position 1, then 2, ...; of an --artefact its first "
                   "N balls), the artefact not moved: the "
                   "run then measures its own per-scan reproducibility, the diagnosis's noise floor "
                   "(docs/diagnosis.md). 6 or more gives a floor to about 20 %. Default 6 (every scan once more "
                   "if fewer); 0 repeats none.")
@click.option("--calibrated", is_flag=True, help="Record the bar length at 20 C and the ball radius as calibrated values.")
@click.option("--reference-pose", "reference_poses", multiple=True, metavar="A,B,G",
              help="After the ballbar, scan the reference sphere at this pose (degrees; repeatable).")
@click.option("--artefact", "artefact", default=None, metavar="FILE|NAME",
              help="Simulate this artefact file or bundled example (docs/artefacts.md) instead of the --layout.")
@click.option("--placement", "placements", multiple=True, metavar="PLACEMENT",
              help="With --artefact: where it sits, e.g. 'xy@z=-525,rot=45', 'planes', 'iso10360-2' (repeatable; "
                   "default the kind's layout).")
@click.option("--seed", type=SEED, default=0, show_default=True, help="Seed of the random numbers (noise, jitter): the same seed, the same run.")
@json_option
@click.option("-o", "--output", "run_dir", required=True, type=click.Path(file_okay=False), help="Run directory to write.")
@click.option("--overwrite", is_flag=True, help="Replace an existing run in RUN_DIR.")
def simulate_cmd(**flags) -> None:
    """Simulate a ballbar run (or, with --artefact, an artefact at its placements) on a virtual machine (default:
    the thesis's Iota 1102 + Hyscan 45C) and write it as a run directory."""
    from ..machine import load_machine
    from ..sim import simulate_ballbar_run

    from ..run import check_run_target

    o = SimulateOptions.from_flags(flags)
    if o.placements and o.artefact is None:
        raise click.UsageError("--placement needs --artefact")
    try:
        check_run_target(o.run_dir, overwrite=o.overwrite)  # before any work (and exclusive when saved)
        machine = load_machine(o.machine_file)
        parsed = parse_effects(o.effects)
        machine_maps = load_maps(o.maps, machine)
        if o.artefact is not None:
            for flag, given in (("--calibrated", o.calibrated), ("--reference-pose", o.reference_poses)):
                if given:
                    raise click.UsageError(f"{flag} is for ballbar runs, not with --artefact")
            return simulate_artefact(o, machine, machine_maps, parsed,
                                     (TextColumn("simulating"), BarColumn(),
                                      TextColumn("{task.completed}/{task.total} sweeps")),
                                     lambda r: dataclasses.replace(r, maps=machine.maps_record(o.maps)))
        start = time.perf_counter()
        with Progress(TextColumn("simulating"), BarColumn(), TextColumn("{task.completed}/{task.total} sweeps"),
                      console=console) as bar:
            task = bar.add_task("", total=None)
            run, truth = simulate_ballbar_run(
                machine_maps, o.temperature, parsed, layout=o.layout, speed=o.speed, bidirectional=o.bidirectional,
                seed=o.seed, scanner=machine.scanner, offset=tuple(machine.offset), jitter=o.jitter * 1e-3,
                calibrated=("length", "radius") if o.calibrated else (),
                reference_poses=[pose_angles(p, "--reference-pose") for p in o.reference_poses],
                progress=lambda done, total: bar.update(task, completed=done, total=total),
                repeat_scans=o.repeat_scans)
        run = dataclasses.replace(run, maps=machine.maps_record(o.maps))
        elapsed = time.perf_counter() - start
        run.save(o.run_dir, truth=truth, overwrite=o.overwrite)
    except Error as exc:
        raise fail(exc) from None
    repeat_scans = int(run.metadata.get("repeat_scans", 0))
    table = Table(title=f"cmmpose simulate -> {o.run_dir}", show_header=False)
    machine_row(table, machine)
    table.add_row("layout", f"{o.layout} ({len(run.scans['scan_id'])} sweeps"
                  + (f", {repeat_scans} of them repeats)" if repeat_scans else ")"))
    table.add_row("points", f"{run.n_points:,} ({run.n_points / len(run.scans['scan_id']):,.0f} per sphere)")
    table.add_row("temperature", f"{o.temperature:g} C")
    table.add_row("effects", ", ".join(o.effects) or "none")
    table.add_row("time", f"{elapsed:.2f} s")
    show(table, o.as_json, {"run": str(o.run_dir), "machine": machine.name, "layout": o.layout,
                            "sweeps": len(run.scans["scan_id"]), "repeat_scans": repeat_scans, "points": run.n_points,
                            "temperature_C": o.temperature, "effects": list(o.effects), "seconds": elapsed})


def _exact_text(value: float) -> str:
    """``value`` in the shortest text that reads back to the same float (``21``, ``90.03``; -0 as 0)."""
    value = float(value) + 0.0
    short = f"{value:g}"
    return short if float(short) == value else repr(value)


@click.command("simulate-alignment")
@machine_option
@click.option("--pose", "pose_text", required=True, help="Nominal pose alpha,beta,gamma of the trunnion stop, degrees.")
@click.option("--name", required=True, help="Name of the pose, e.g. A90B90: the files are NAME-vernier.csv, ...")
@click.option("--temperature", type=TEMPERATURE, default=20.0, show_default=True, help="Machine temperature, C.")
@click.option("--effect", "effects", multiple=True, metavar="NAME:param=value,...",
              help="What the calibration should find, e.g. alignment:alpha=0.03 or mount-offset:u1=0.02 "
                   "(`cmmpose effects`); repeatable.")
@click.option("--vernier-points", type=click.IntRange(3), default=3, show_default=True,
              help="Optical-vernier positions (the thesis uses 3).")
@click.option("--seed", type=SEED, default=0, show_default=True, help="Seed of the random numbers: the same seed, the same measurements.")
@json_option
@click.option("-o", "--output", "out_dir", required=True, type=click.Path(file_okay=False),
              help="Folder for the measurement files.")
@overwrite_option("Replace the NAME-* files of an earlier simulation in the folder (never an input).")
def simulate_alignment_cmd(machine_file, pose_text, name, temperature, effects, vernier_points, seed, as_json,
                           out_dir, overwrite) -> None:
    """Simulate the measurements that align the scanner at one pose (thesis chapter 4): optical-vernier
    positions, a plane scan and a reference-sphere scan, as `cmmpose calibrate alignment` reads them.

    Writes NAME-vernier.csv (x,y,z, mm), NAME-plane.csv and NAME-sphere.csv (u,v,D,E,F, mm) and
    NAME-truth.json (the plane's normal, the true pose, reading and offset), and prints the command
    that calibrates from them."""
    from ..machine import load_machine
    from ..sim.calibration_data import VERNIER_NOISE, plane_scan, reference_sphere_scans
    from ..sim.calibration_data import vernier_points as vernier

    nominal = pose_angles(pose_text, "--pose")
    files = {k: Path(out_dir) / f"{name}-{k}.csv" for k in ("vernier", "plane", "sphere")}
    truth_file = Path(out_dir) / f"{name}-truth.json"
    try:
        # before any work: the four files, none an input (the machine file, its maps) nor, without
        # --overwrite, an earlier file (a folder still missing is made: nothing in it to replace)
        check_free({"--output": [*files.values(), truth_file]}, command_inputs([machine_file]), overwrite=overwrite,
                   folders_made=True)
        machine = load_machine(machine_file)
        parsed = parse_effects(effects)
        maps = machine.maps()
        offset = tuple(machine.offset)
        rng = np.random.default_rng(seed)
        common = {"maps": maps, "temperature": temperature, "effects": parsed}
        v = vernier(nominal, offset, n=vernier_points, seed=rng, **common)
        plane = plane_scan(nominal, offset, scanner=machine.scanner, seed=rng, **common)
        sphere = reference_sphere_scans([nominal], offset, scanner=machine.scanner,
                                        seed=int(rng.integers(1 << 30)), **common)[0]
        ensure_folder(out_dir)
        normal = [float(c) for c in plane.plane.normal]
        truth = {"units": {"pose": "degree", "reading": "mm", "offset": "mm", "vernier_uncertainty": "um"},
                 "nominal_pose": list(nominal), "plane_normal": normal,
                 "true_pose": [float(c) for c in sphere.true_pose], "true_reading": [float(c) for c in sphere.true_reading],
                 "true_offset": [float(c) for c in sphere.true_offset], "vernier_uncertainty": VERNIER_NOISE * 1e3,
                 "temperature": temperature, "effects": list(effects), "seed": seed}
        with writing("--output", [*files.values(), truth_file], command_inputs([machine_file]),
                     overwrite=overwrite):  # the four files, created exclusively, all or none
            with atomic_write(files["vernier"]) as f:
                np.savetxt(f, v.points, delimiter=",", header="x,y,z", comments="", fmt="%.9f")
            for k, d in (("plane", plane), ("sphere", sphere.data)):
                with atomic_write(files[k]) as f:
                    np.savetxt(f, np.column_stack([d.uv, d.scales]), delimiter=",", header="u,v,D,E,F",
                               comments="", fmt="%.9f")
            write_text(truth_file, strict_json(truth, indent=2))
    except Error as exc:
        raise fail(exc) from None
    q = lambda path: shlex.quote(str(path))  # noqa: E731 - a folder with a space stays one argument
    machine_arg = f" --machine {q(machine_file)}" if machine_file else " --maps thesis"
    # --nominal-pose: the pose simulated at, so the calibration checks the plane normal's branch (gamma within
    # 90 deg of it) instead of noting it unchecked; each angle as it reads back to the same number.
    pose_arg = ",".join(_exact_text(a) for a in nominal)
    command = ("cmmpose calibrate alignment" + machine_arg
               + f" --temperature {_exact_text(temperature)} --vernier {q(files['vernier'])} --vernier-uncertainty "
               f"{VERNIER_NOISE * 1e3:g} --plane-scan {q(files['plane'])} --plane-normal "
               + ",".join(f"{c + 0.0:.6g}" for c in normal) + f" --nominal-pose {pose_arg}"
               + f" --reference-scan {q(files['sphere'])} --name {q(name)} --library LIBRARY")
    if as_json:
        click.echo(strict_json({"files": {k: str(f) for k, f in files.items()}, "truth": truth,
                                "calibrate_with": command}, indent=2))
        return
    for f in files.values():
        console.print(f"wrote {f}")
    console.print("calibrate with:\n  " + command, soft_wrap=True)
