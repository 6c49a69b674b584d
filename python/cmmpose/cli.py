"""The ``cmmpose`` command line."""

from __future__ import annotations

import time
from pathlib import Path

import click
import numpy as np
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn
from rich.table import Table

from .compensation import compensate
from .errormap import ErrorMap, ErrorMapSet
from .errors import Error
from .pointfiles import read_points, write_points
from .report import KernelReport

console = Console(stderr=True)

#: Points per call when a progress bar is shown.
CHUNK = 1_000_000


def load_maps(specs: tuple[str, ...]) -> ErrorMap | ErrorMapSet:
    """'thesis' (bundled 20/25/30 C set), 'appendix-b' (22 C controller map),
    or paths: canonical .csv maps or controller .txt files; several make a set."""
    maps = []
    for spec in specs:
        if spec == "thesis":
            if len(specs) > 1:
                raise click.BadParameter("'thesis' is a whole set; give it alone", param_hint="--maps")
            return ErrorMapSet.thesis()
        if spec == "appendix-b":
            maps.append(ErrorMap.appendix_b())
        elif Path(spec).suffix.lower() == ".txt":
            maps.append(ErrorMap.read_controller_file(spec))
        else:
            maps.append(ErrorMap.read(spec))
    return maps[0] if len(maps) == 1 else ErrorMapSet(maps)


def triple(text: str, name: str) -> tuple[float, float, float]:
    try:
        vals = tuple(float(x) for x in text.split(","))
    except ValueError:
        raise click.BadParameter(f"expected three comma-separated numbers, got {text!r}", param_hint=name) from None
    if len(vals) != 3:
        raise click.BadParameter(f"expected three comma-separated numbers, got {text!r}", param_hint=name)
    return vals  # type: ignore[return-value]


@click.group()
@click.version_option(package_name="cmmpose")
def main() -> None:
    """Error compensation of a laser line scanner on a CMM."""


@main.command("compensate")
@click.argument("points_in", metavar="IN", type=click.Path(dir_okay=False))
@click.argument("points_out", metavar="OUT", type=click.Path(dir_okay=False, writable=True))
@click.option("--maps", "maps", multiple=True, default=("thesis",), show_default=True,
              help="'thesis', 'appendix-b', or map files (.csv canonical, .txt controller); repeat for a set.")
@click.option("--temperature", type=float, default=None,
              help="Machine temperature in C for every point (default: the T column, if the file has one).")
@click.option("--pose", default="90,90,0", show_default=True, help="alpha,beta,gamma in degrees (Euler 3-1-3).")
@click.option("--offset", default="1.001,264.505,129.575", show_default=True, help="U1,V1,W1 mount offset in mm.")
@click.option("--out-of-range", type=click.Choice(["raise", "clamp"]), default="raise", show_default=True)
@click.option("--nan-policy", type=click.Choice(["raise", "propagate"]), default="raise", show_default=True)
def compensate_cmd(points_in, points_out, maps, temperature, pose, offset, out_of_range, nan_policy) -> None:
    """Compensate scanner points IN (CSV or NPY: u, v, D, E, F[, T]) into machine
    coordinates OUT (CSV or NPY: X, Y, Z in mm)."""
    pose_t = triple(pose, "--pose")
    offset_t = triple(offset, "--offset")
    try:
        error_map = load_maps(maps)
        uv, scales, temps = read_points(points_in)
        if isinstance(error_map, ErrorMapSet):
            if temperature is None and temps is None:
                raise click.UsageError("a map set needs --temperature or a T column in the input")
            t_all = temperature if temperature is not None else temps
        else:
            t_all = None
        n = len(uv)
        out = np.empty((n, 3))
        totals = np.zeros(5, dtype=np.int64)
        start = time.perf_counter()
        with Progress(TextColumn("compensating"), BarColumn(), TextColumn("{task.completed:,}/{task.total:,} points"),
                      TimeRemainingColumn(), console=console, disable=n <= CHUNK) as bar:
            task = bar.add_task("", total=n)
            for lo in range(0, max(n, 1), CHUNK):
                hi = min(lo + CHUNK, n)
                t = t_all if t_all is None or np.isscalar(t_all) else t_all[lo:hi]
                xyz, rep = compensate(uv[lo:hi], scales[lo:hi], error_map, pose_t, offset_t, t,
                                      out_of_range=out_of_range, nan_policy=nan_policy, return_report=True)
                out[lo:hi] = xyz
                totals += [rep.points, *rep.clamped_position, rep.clamped_temperature]
                bar.advance(task, hi - lo)
        elapsed = time.perf_counter() - start
        write_points(points_out, out)
    except Error as exc:
        raise click.ClickException(str(exc)) from None
    table = Table(title=f"cmmpose compensate: {points_in} -> {points_out}", show_header=False)
    table.add_row("points", f"{n:,}")
    table.add_row("maps", repr(error_map))
    table.add_row("temperature", "per point (T column)" if t_all is not None and not np.isscalar(t_all)
                  else "-" if t_all is None else f"{t_all:g} C")
    table.add_row("pose (deg)", ", ".join(f"{v:g}" for v in pose_t))
    table.add_row("offset (mm)", ", ".join(f"{v:g}" for v in offset_t))
    report = KernelReport(int(totals[0]), tuple(int(x) for x in totals[1:4]), int(totals[4]), 0)
    if report.clamped:
        table.add_row("clamped", f"X {totals[1]}, Y {totals[2]}, Z {totals[3]}, temperature {totals[4]}")
    table.add_row("kernel time", f"{elapsed * 1e3:.1f} ms ({n / max(elapsed, 1e-9) / 1e6:.1f} M points/s)")
    Console().print(table)


@main.command("simulate")
@click.option("--layout", type=click.Choice(["b89", "crossed"]), default="b89", show_default=True,
              help="20 ASME B89.4.1 positions (thesis Appendix C geometry) or the 8 crossed-ballbar positions.")
@click.option("--temperature", type=float, default=20.0, show_default=True, help="Machine temperature, C.")
@click.option("--maps", "maps", multiple=True, default=("thesis",), show_default=True,
              help="The machine's real maps: 'thesis', 'appendix-b' or map files.")
@click.option("--effect", "effects", multiple=True, metavar="NAME:param=value,...",
              help="Extra physics, repeatable (see docs/simulation.md), e.g. latency:seconds=0.005.")
@click.option("--speed", type=float, default=35.0, show_default=True, help="Sweep speed, mm/s.")
@click.option("--bidirectional", is_flag=True, help="Alternate forward and reverse sweeps.")
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("-o", "--output", "run_dir", required=True, type=click.Path(file_okay=False), help="Run directory to write.")
@click.option("--overwrite", is_flag=True, help="Replace an existing run in RUN_DIR.")
def simulate_cmd(layout, temperature, maps, effects, speed, bidirectional, seed, run_dir, overwrite) -> None:
    """Simulate a ballbar run on the virtual Iota 1102 + Hyscan 45C and write it as a run directory."""
    from .sim import parse_effect, simulate_ballbar_run

    try:
        parsed = [parse_effect(e) for e in effects]
        machine_maps = load_maps(maps)
        start = time.perf_counter()
        with Progress(TextColumn("simulating"), BarColumn(), TextColumn("{task.completed}/{task.total} sweeps"),
                      console=console) as bar:
            task = bar.add_task("", total=None)
            run, truth = simulate_ballbar_run(
                machine_maps, temperature, parsed, layout=layout, speed=speed, bidirectional=bidirectional, seed=seed,
                progress=lambda done, total: bar.update(task, completed=done, total=total))
        elapsed = time.perf_counter() - start
        run.save(run_dir, truth=truth, overwrite=overwrite)
    except Error as exc:
        raise click.ClickException(str(exc)) from None
    table = Table(title=f"cmmpose simulate -> {run_dir}", show_header=False)
    table.add_row("layout", f"{layout} ({len(run.scans['scan_id'])} sweeps)")
    table.add_row("points", f"{run.n_points:,} ({run.n_points / len(run.scans['scan_id']):,.0f} per sphere)")
    table.add_row("temperature", f"{temperature:g} C")
    table.add_row("effects", ", ".join(effects) or "none")
    table.add_row("time", f"{elapsed:.2f} s")
    Console().print(table)


if __name__ == "__main__":
    main()
