"""``cmmpose compensate --uncertainty``: the options that state the sources
of each point's uncertainty, the sources built from them, the machine file
and the alignment, and the budget printed after writing
(docs/uncertainty.md, "Per point"; docs/formats.md, "Uncertainty columns").

The design follows :meth:`cmmpose.point_uncertainty.UncertaintySources.without`:
every source is on with the value stated for it, and ``--uncertainty-off
SOURCE`` (repeatable) switches one off by its name.
"""

from __future__ import annotations

import math
import re

import click
from rich.table import Table

from ..errors import InputError
from ..point_uncertainty import DETAILS, SOURCES, PoseUncertainty, UncertaintySources

__all__ = ["uncertainty_options", "uncertainty_sources", "budget_table", "OPTION_NAMES"]

#: The options that only mean something with --uncertainty (parameter name -> flag).
OPTION_NAMES = {"uncertainty_detail": "--uncertainty-detail", "temperature_uncertainty": "--temperature-uncertainty",
                "scanner_noise": "--scanner-noise", "scanner_scale_ppm": "--scanner-scale-ppm",
                "uncertainty_off": "--uncertainty-off"}


def _checked(field: str, flag: str, value):
    """``value`` checked as UncertaintySources checks ``field`` (finite, >= 0,
    within the bound of its kind), else a usage error naming ``flag``."""
    try:
        UncertaintySources(**{field: value})
    except InputError as exc:
        raise click.BadParameter(re.sub(r"^\w+(\[\d\])?: ", "", str(exc)), param_hint=flag) from None
    return value


def _k(ctx, param, value):
    return None if value is None else _checked("temperature_k", "--temperature-uncertainty", value)


def _ppm(ctx, param, value):
    return None if value is None else _checked("scanner_scale_ppm", "--scanner-scale-ppm", value)


def _noise(ctx, param, value):
    """--scanner-noise UM or U_UM,V_UM: one value for u and v, or one each."""
    if value is None:
        return None
    try:
        parts = tuple(float(p) for p in value.split(","))
    except ValueError:
        raise click.BadParameter(f"{value!r}: expected um, one value or two (u,v)",
                                 param_hint="--scanner-noise") from None
    if len(parts) not in (1, 2) or not all(math.isfinite(p) for p in parts):
        raise click.BadParameter(f"{value!r}: expected one or two finite values, um", param_hint="--scanner-noise")
    parts = parts * 2 if len(parts) == 1 else parts
    return _checked("scanner_noise_um", "--scanner-noise", parts)


def uncertainty_options(f):
    """--uncertainty and the options stating its sources (docs/uncertainty.md)."""
    options = [
        click.option("--uncertainty", is_flag=True, default=False,
                     help="Also write each point's standard uncertainty (k = 1): columns u_x_mm, u_y_mm, u_z_mm "
                          "(docs/formats.md), and print the budget. Sources: the maps' stated uncertainty, the "
                          "machine file's scanner noise, the --alignment's covariance, a --model's parameter "
                          "covariance, and the options below."),
        click.option("--uncertainty-detail", type=click.Choice(DETAILS), default=None,
                     help="With --uncertainty: 'standard' (u only, the default), 'covariance' (also the six "
                          "covariance columns cov_xx_mm2 ..., mm^2), 'split' (also their part common to nearby "
                          "points, cov_common_xx_mm2 ...)."),
        click.option("--temperature-uncertainty", type=float, default=None, callback=_k, metavar="K",
                     help="With --uncertainty: standard uncertainty of the machine temperature, K (acts through a "
                          "map set's thermal sensitivity). Default 0."),
        click.option("--scanner-noise", default=None, callback=_noise, metavar="UM",
                     help="With --uncertainty: the scanner's noise, um, one value for u and v or U,V. Default: the "
                          "machine file's scanner.noise_um (on v)."),
        click.option("--scanner-scale-ppm", type=float, default=None, callback=_ppm, metavar="PPM",
                     help="With --uncertainty: the scanner's relative scale uncertainty, ppm of u, v. Default 0."),
        click.option("--uncertainty-off", type=click.Choice(SOURCES), multiple=True,
                     help="With --uncertainty: switch a source off (repeat for several), e.g. for a budget."),
    ]
    for option in reversed(options):
        f = option(f)
    return f


def check_uncertainty_options(uncertainty: bool, **given) -> None:
    """A usage error (exit 2) naming the first option of ``given`` set without --uncertainty."""
    if uncertainty:
        return
    for name, value in given.items():
        if value not in (None, (), False):
            raise click.UsageError(f"{OPTION_NAMES[name]} states a source of --uncertainty; add --uncertainty "
                                   f"(or leave {OPTION_NAMES[name]} out)")


def uncertainty_sources(machine, record, *, temperature_uncertainty, scanner_noise, scanner_scale_ppm,
                        uncertainty_off) -> tuple[UncertaintySources, dict]:
    """The sources of the options, the machine and the alignment ``record``
    (or None), and where each value comes from (source name -> text)."""
    origins = {"temperature": "--temperature-uncertainty" if temperature_uncertainty is not None else "not given",
               "scanner_scale": "--scanner-scale-ppm" if scanner_scale_ppm is not None else "not given"}
    if scanner_noise is not None:
        noise, origins["scanner_noise"] = scanner_noise, "--scanner-noise"
    else:
        noise = (machine.scanner.noise_u * 1e3, machine.scanner.noise * 1e3)
        stated = not any(d.startswith("scanner.noise_um") for d in machine.defaults)
        origins["scanner_noise"] = (f"machine {machine.source}: scanner.noise_um (on v)" if stated else
                                    f"the default scanner.noise_um (on v; machine {machine.source} states none)")
    pose = None
    if record is not None:
        pose = PoseUncertainty.from_record(record)
        origins["pose"] = f"--alignment: {pose.source}"
    else:
        origins["pose"] = "none (--alignment gives an alignment's covariance)"
    sources = UncertaintySources(temperature_k=temperature_uncertainty or 0.0,
                                 scanner_scale_ppm=scanner_scale_ppm or 0.0, scanner_noise_um=noise, pose=pose,
                                 off=tuple(uncertainty_off))
    return sources, origins


def budget_table(tally, title: str) -> Table:
    """The budget of a compensation with uncertainty: each source on or off,
    its value and where it comes from, and u over the points (rms, largest)."""
    table = Table(title=title)
    for column in ("source", "", "value", "from"):
        table.add_column(column)
    for row in tally.budget:
        table.add_row(row["source"], "on" if row["on"] else "off", row["value"], row["from"])
    rms, top = tally.rms_um, tally.max_um
    table.add_row("u (k = 1)", "", f"over {tally.points:,} points: rms X {rms[0]:.3g}, Y {rms[1]:.3g}, "
                  f"Z {rms[2]:.3g} um; max X {top[0]:.3g}, Y {top[1]:.3g}, Z {top[2]:.3g} um", "")
    return table
