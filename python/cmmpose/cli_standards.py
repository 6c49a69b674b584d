"""The standards' commands of the ``cmmpose`` command line (docs/standards.md):
``iso230-2`` (positioning of an axis), ``acceptance`` (ISO 10360-8-style
probing and length tests against MPEs) and ``interim-check`` (squareness and
scale from one ballbar run). ``cmmpose.cli`` adds them to its group."""

from __future__ import annotations

import json
from pathlib import Path

import click
from rich.console import Console

from .errors import Error
from .policy import cli_wording

__all__ = ["iso230_2_cmd"]

console = Console(stderr=True)


def _fail(exc: Exception) -> click.ClickException:
    return click.ClickException(cli_wording(str(exc)))


@click.command("iso230-2")
@click.argument("data_file", metavar="FILE", type=click.Path(exists=True, dir_okay=False))
@click.option("--no-air-correction", is_flag=True,
              help="Interferometer runs: do not correct linear readings for the refractive index of air.")
@click.option("--test-uncertainty", type=float, default=None,
              help="Expanded uncertainty (k = 2) of a measured deviation, um, stated with the results "
                   "(default for interferometer runs: the air correction's over the travel).")
@click.option("--plot", "plot_path", type=click.Path(dir_okay=False), default=None, help="Plot to write (PNG, PDF, SVG).")
@click.option("--json", "as_json", is_flag=True, help="Print JSON (the axis figures at the top level, um).")
def iso230_2_cmd(data_file, no_air_correction, test_uncertainty, plot_path, as_json) -> None:
    """ISO 230-2:2014 positioning accuracy and repeatability of one axis.

    FILE is a CSV with columns target_mm, direction (+1/-1), cycle,
    deviation_um, or a linear interferometer run (the files 'calibrate map'
    takes). Prints A, A_up, A_down, B, B_mean, E, E_up, E_down, M, R, R_up,
    R_down in um, and the figures per target.
    """
    from .standards.iso230_2 import evaluate_iso230_2, load_positioning

    try:
        data, u, note = load_positioning(data_file, air_correction=not no_air_correction)
        if test_uncertainty is not None:
            u, note = test_uncertainty, "given (--test-uncertainty)"
        result = evaluate_iso230_2(data, test_uncertainty_um=u, test_uncertainty_note=note)
        if plot_path:
            result.plot(plot_path, data)
    except Error as exc:
        raise _fail(exc) from None
    except OSError as exc:
        raise click.ClickException(f"{plot_path}: {exc.strerror or exc}") from None
    if as_json:
        click.echo(json.dumps(result.to_dict(), indent=2))
    else:
        Console(width=max(Console().width, 120)).print(result)
    if plot_path:
        console.print(f"wrote {Path(plot_path)}")
