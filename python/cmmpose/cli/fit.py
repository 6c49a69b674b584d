"""``cmmpose fit``: a sphere fitted to one point cloud."""

from __future__ import annotations

import warnings

import click
import numpy as np
from rich.console import Console
from rich.table import Table

from .._json import dumps as strict_json
from ..errors import Error
from ..formats.pointclouds import UNITS as POINT_UNITS
from ..formats.pointclouds import read_point_cloud, unit_factor
from .common import fail, triple, warn


@click.command("fit")
@click.argument("scan", type=click.Path(exists=True, dir_okay=False))
@click.option("--units", type=click.Choice(sorted(POINT_UNITS)), default=None,
              help="Units of the file's coordinates (and of --scanner-origin, --start). Default: the format's "
                   "(mm; metres for E57).")
@click.option("--radius", type=float, default=None,
              help="Calibrated sphere radius, mm (fixed in the fit). Default: fitted (free radius).")
@click.option("--segment", type=click.Choice(["none", "e3125"]), default="none", show_default=True,
              help="e3125: segment the sphere from a raw scan about the scanner's line of sight (needs --radius).")
@click.option("--scanner-origin", default="0,0,0", show_default=True,
              help="The scanner's origin in the file's frame, x,y,z in --units (for --segment e3125).")
@click.option("--rule", type=click.Choice(["none", "mad", "e3125"]), default=None,
              help="Outlier rule without segmentation (docs/fitting.md): mad (repeated, median-centred) or e3125 "
                   "(one pass at 3 standard deviations).")
@click.option("--reject", type=float, default=None, help="Multiple k of the rule's sigma (default 3.5 for mad, 3 for e3125).")
@click.option("--start", default=None,
              help="Where the fit starts: algebraic, lmeds (high breakdown: for heavy outliers) or a centre x,y,z "
                   "in --units.")
@click.option("--json", "as_json", is_flag=True, help="Print the result as JSON.")
def fit_cmd(scan, units, radius, segment, scanner_origin, rule, reject, start, as_json) -> None:
    """Fit a sphere to the point cloud SCAN (CSV, NPY, Parquet, PLY, XYZ, PTS, E57): centre (mm), radius,
    points used and the centre's standard uncertainty. With --segment e3125 a raw scan is segmented in the
    manner of ASTM E3125 first (closest-point start, cone and cylinder about the line of sight, radius fixed)."""
    from ..errors import IllConditionedFit, ImplausibleFit
    from ..fitting import e3125, fit_sphere

    if radius is not None and not (np.isfinite(radius) and radius > 0):
        raise click.BadParameter(f"expected a positive radius in mm, got {radius}", param_hint="--radius")
    if segment == "e3125" and radius is None:
        raise click.UsageError("--segment e3125 fits with the radius fixed at its calibrated value: give --radius (mm)")
    if segment == "e3125" and (rule or reject is not None):
        raise click.UsageError("--segment e3125 applies the standard's own rule: --rule and --reject do not apply")
    try:
        scale = unit_factor(scan, units)  # --start and --scanner-origin are in the file's units
    except Error as exc:
        raise fail(exc) from None
    start_value = None
    if start is not None:
        start_value = start if start in ("algebraic", "lmeds") else tuple(v * scale for v in triple(start, "--start"))
        if segment == "e3125" and isinstance(start_value, str):
            raise click.BadParameter("with --segment e3125 give a centre x,y,z (or nothing: the closest-point start)",
                                     param_hint="--start")
    origin = tuple(v * scale for v in triple(scanner_origin, "--scanner-origin"))
    try:
        cloud = read_point_cloud(scan, units=units)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", IllConditionedFit)
            warnings.simplefilter("always", ImplausibleFit)
            if segment == "e3125":
                res = e3125(cloud.xyz, radius, origin, start=start_value)
                out = {"file": str(scan), "method": "e3125 segmentation, radius fixed", **res.to_dict()}
            else:
                f = fit_sphere(cloud.xyz, radius, rule=rule, reject=reject, start=start_value)
                out = {"file": str(scan), "method": "least squares" + (f", rule {rule or 'mad'}" if (rule or reject)
                                                                        else "") + (", radius fixed" if radius else ""),
                       "centre_mm": f.centre.tolist(), "radius_mm": float(f.radius), "n_points": int(f.n_points),
                       "n_raw": len(cloud.xyz), "centre_uncertainty_mm": f.centre_uncertainty.tolist(),
                       "radius_uncertainty_mm": f.radius_uncertainty if radius is None else 0.0,
                       "rms_mm": float(f.rms), "polar_coverage_deg": float(f.polar_coverage),
                       "centre_radius_correlation": (None if radius is not None
                                                     else float(f.centre_radius_correlation))}
    except Error as exc:
        raise fail(exc) from None  # a fit naming the points' likely unit: its remedy says --units
    notes = [str(w.message) for w in caught if issubclass(w.category, (IllConditionedFit, ImplausibleFit))]
    out["warnings"] = notes
    if as_json:
        click.echo(strict_json(out, indent=2))
    else:
        table = Table(title=f"sphere fit of {scan}", show_header=False)
        table.add_row("method", out["method"])
        table.add_row("centre (mm)", ", ".join(f"{v:.6f}" for v in out["centre_mm"]))
        u = out.get("centre_uncertainty_mm")
        if u is not None:
            table.add_row("u(centre) (um)", ", ".join(f"{v * 1e3:.2f}" for v in u))
        table.add_row("radius (mm)", f"{out['radius_mm']:.6f}")
        table.add_row("points used / in file", f"{out['n_points']} / {out['n_raw']}")
        Console().print(table)
    for note in notes:
        warn(note)  # once: the fit's log line said it too (cli.common.cli_warnings)
