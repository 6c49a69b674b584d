"""``cmmpose map`` (with ``map plot``): exchange of linear-axis results (docs/formats.md) and plots of maps."""

from __future__ import annotations

import os
from pathlib import Path

import click
from rich.markup import escape

from ..atomicfile import ensure_folder
from ..errormap import ErrorMapSet
from .._json import dumps as strict_json
from ..errors import Error, InputError
from .common import (check_free, check_plot_path, command_inputs, console, console_log, fail, json_option, load_maps,
                     machine_option, map_specs, overwrite_option, plot_option, travel_notes, warn, writing)
from .common import TEMPERATURE


def _units_option(f):
    """--units of the map files, one meaning with every command's --units: the length unit of the file's values."""
    return click.option("--units", type=click.Choice(["mm", "in"]), default="mm", show_default=True,
                        callback=lambda ctx, param, value: "inch" if value == "in" else value,
                        help="Length unit of the files' values (linuxcnc: the machine units; 'in' as in `cmmpose "
                             "fit`).")(f)


def _maps_argument(value):
    """MAPS of `map plot`: as --maps everywhere, an empty name or one that is neither bundled nor a file is a
    usage error (exit 2)."""
    try:
        return map_specs(None, None, value)
    except click.BadParameter as exc:
        raise click.BadParameter(exc.message, param_hint="MAPS") from None


@click.command("plot")
@click.argument("maps", nargs=-1, callback=lambda ctx, param, value: _maps_argument(value))
@plot_option("-o", "--output", "out", required=True, help="PNG (or PDF, SVG) to write.")
@machine_option
@overwrite_option()
def plot_map_cmd(maps, out, machine_file, overwrite) -> None:
    """Plot error-map components against position (like thesis Figures 3-7 to 3-18).
    MAPS: 'thesis', 'appendix-b', or map files (several make a set); default: the machine's."""
    from ..machine import load_machine
    from ..evaluation.plots import plot_error_map

    try:
        if not maps and machine_file is None:
            raise click.UsageError("give MAPS or --machine")
        inputs = command_inputs([*maps, machine_file])
        check_free({"--output": out}, inputs, overwrite=overwrite)  # before any work
        check_plot_path(out, "--output")
        error_map = load_maps(tuple(maps), load_machine(machine_file) if machine_file else None)
        with writing("--output", [out], inputs, overwrite=overwrite):  # created exclusively without --overwrite
            plot_error_map(error_map, out)
    except Error as exc:
        raise fail(exc) from None
    console.print(f"wrote {out}")


class _MapFormatChoice(click.Choice):
    """The registered map file formats that can be read (``map import``) or written (``map export``), listed from
    the registry (:mod:`cmmpose.formats.mapformats`) when first asked: the built-in formats load on first use."""

    def __init__(self, written: bool):
        self._written = written
        super().__init__((), case_sensitive=True)

    @property
    def choices(self):
        from ..formats import mapformats

        return tuple(n for n in mapformats.names() if not self._written or mapformats.get(n).write is not None)

    @choices.setter
    def choices(self, value) -> None:  # click sets it in __init__; the registry decides
        pass


#: ``map import`` options that shape the map built (not a file format's own): refused with a format whose reader
#: does not take them, when given. The others (``--comp-file-type``, ``--units``) go to the formats that take them.
_MAP_OPTIONS = {"base": "--base", "temperature": "--temperature", "hold_ends": "--hold-ends"}


def _map_spec(spec: str, what: str):
    """One map: 'appendix-b', 'thesis@T' (the bundled set at T degrees C) or a map file of any registered format."""
    from ..errormap import ErrorMap, ErrorMapSet

    if spec == "appendix-b":
        return ErrorMap.appendix_b()
    if spec.startswith("thesis@"):
        try:
            t = float(spec.split("@", 1)[1])
        except ValueError:
            raise click.BadParameter(f"expected thesis@<temperature C>, got {spec!r}", param_hint=what) from None
        return ErrorMapSet.thesis().at(t)
    if not os.path.lexists(spec):  # a name that names no file: a usage error (exit 2) as in every command
        raise click.BadParameter(f"{spec!r} is neither 'appendix-b', 'thesis@<temperature C>' nor a map file "
                                 "that exists", param_hint=what)
    return ErrorMap.read(spec, format="auto")



@click.group("map")
def map_group() -> None:
    """Error maps: plot them; import and export linear-axis results (ISO 230-2 style CSV, LinuxCNC
    compensation files); convert a moving table's own measured motion into map components."""


@map_group.command("table-motion")
@click.argument("map_spec", metavar="MAP")
@click.option("-o", "--output", "out", required=True, type=click.Path(dir_okay=False), help="Canonical map CSV to write.")
@click.option("--carriage", type=click.Choice(["X", "Y", "Z"], case_sensitive=False), required=True,
              help="The carriage that carries the part: its table in MAP holds the table's own motion as an "
                   "instrument riding on it read it.")
@click.option("--measured-at", required=True, metavar="X,Y,Z",
              help="mm: where on the table its translations were measured (the table's frame).")
@click.option("--part-point", required=True, metavar="X,Y,Z",
              help="mm: where the part sits on the table (same frame); the map is exact for points there.")
@json_option
@overwrite_option()
def map_table_motion_cmd(map_spec, out, carriage, measured_at, part_point, as_json, overwrite) -> None:
    """Turn a moving table's own measured motion into map components (the probe relative to the part):
    d = -(d_T + eps_T x (part point - measured at)), eps = -eps_T for that carriage; the other carriages and
    the squareness are kept (docs/conventions.md, moving tables). `map import` takes probe-relative results:
    convert a table's own results with this command first."""
    from ..formats.tablemotion import table_motion_to_map
    from .common import triple

    try:
        check_free({"--output": out}, [map_spec], overwrite=overwrite)  # before any work
        base = _map_spec(map_spec, "MAP")
        try:
            converted = table_motion_to_map(base, carriage, triple(measured_at, "--measured-at"),
                                            triple(part_point, "--part-point"))
        except InputError as exc:
            if exc.cli_option not in ("--measured-at", "--part-point"):
                raise
            raise click.BadParameter(exc.message.removeprefix(f"{exc.option}: "), param_hint=exc.cli_option) from None
        with writing("--output", [out], [map_spec], overwrite=overwrite):
            converted.write(out)
    except Error as exc:
        raise fail(exc) from None
    if as_json:
        click.echo(strict_json({"output": str(out), "map": repr(converted), "source": converted.source}, indent=2))
        return
    console.print(f"wrote {out}: {escape(converted.source)}")


@map_group.command("import")
@click.argument("fmt", metavar="FORMAT", type=_MapFormatChoice(written=False))
@click.argument("files", metavar="FILE...", nargs=-1, required=True)
@click.option("-o", "--output", "out", required=True, type=click.Path(dir_okay=False), help="Canonical map CSV to write.")
@click.option("--base", default=None,
              help="Replace only the linear components of this map ('appendix-b', 'thesis@T' or a map file); "
                   "the results are interpolated onto its grid.")
@click.option("--temperature", type=TEMPERATURE, default=None, help="Map temperature, C (default: the base's, else none).")
@click.option("--comp-file-type", type=click.Choice(["0", "1"]), default="0", show_default=True,
              help="linuxcnc: COMP_FILE_TYPE (0 = positions, 1 = trims).")
@_units_option
@click.option("--hold-ends", is_flag=True, help="With --base: hold the end values where its grid runs beyond the targets.")
@machine_option
@json_option
@overwrite_option()
def map_import_cmd(fmt, files, out, base, temperature, comp_file_type, units, hold_ends, machine_file, as_json,
                   overwrite) -> None:
    """Build a canonical map from linear-axis results in FORMAT (probe-relative results; a moving table's own
    motion, read by an instrument riding on it, is converted by `cmmpose map table-motion`).

    A format of one file (csv, controller, iso230-2): one FILE. A format of one file per axis (linuxcnc): one
    AXIS=FILE per axis, e.g. X=x.comp Y=y.comp.
    The map keeps the mean of the two approach directions; axes without results
    are zero (or, with --base, keep the base's component). With --machine, the
    map is checked against the machine's travel.
    """
    from ..errors import Error
    from ..formats import mapformats
    from ..machine import load_machine

    try:
        entry = mapformats.get(fmt)
        read = [f.partition("=")[2] for f in files] if entry.per_axis else files
        named = [f.partition("=")[2] for f in files if f.partition("=")[0] in tuple("XYZ")] if entry.per_axis \
            else files
        missing = [f for f in named if f and not os.path.lexists(f)]
        if missing:  # a name that names no file: a usage error (exit 2) as in every command
            raise click.BadParameter(f"{missing[0]}: cannot read (no such file)", param_hint="FILE...")
        inputs = command_inputs([*read, base, machine_file])
        check_free({"--output": out}, inputs, overwrite=overwrite)  # before any work
        base_map = None if base is None else _map_spec(base, "--base")
        takes = entry.read_options()
        options = {"base": base_map, "temperature": temperature, "hold_ends": hold_ends,
                   "comp_file_type": int(comp_file_type), "units": units}
        for name, flag in _MAP_OPTIONS.items():
            if options[name] not in (None, False) and name not in takes and takes != ["*"]:
                raise click.UsageError(f"{flag}: not an option of {fmt}, which takes "
                                       f"{', '.join('--' + t.replace('_', '-') for t in takes) or 'none'}")
        options = {k: v for k, v in options.items() if k in takes or takes == ["*"]}
        with console_log():
            if not entry.per_axis:
                if len(files) != 1:
                    raise click.UsageError(f"{fmt} takes one FILE, got {len(files)}")
                source = files[0]
            else:
                source = {}
                for item in files:
                    axis, sep, path = item.partition("=")
                    if not sep or not path or axis.upper() not in mapformats.AXES:
                        raise click.BadParameter(f"expected AXIS=FILE with AXIS X, Y or Z, got {item!r}",
                                                 param_hint="FILE")
                    if axis.upper() in source:
                        raise click.BadParameter(f"axis {axis.upper()} given twice", param_hint="FILE")
                    source[axis.upper()] = path
            built = mapformats.read(source, fmt, **options)
        notes = travel_notes(load_machine(machine_file), built) if machine_file else []
        with writing("--output", [out], inputs, overwrite=overwrite):
            built.write(out)
    except Error as exc:
        raise fail(exc) from None
    for note in notes:
        warn(note)
    if as_json:
        click.echo(strict_json({"output": str(out), "map": repr(built), "notes": notes}, indent=2))
        return
    console.print(f"wrote {out}: {built!r}")


@map_group.command("export")
@click.argument("map_spec", metavar="MAP", required=False)
@click.option("--format", "fmt", type=_MapFormatChoice(written=True), required=True,
              help="Format to write (linuxcnc: one file per axis in the directory OUT).")
@click.option("-o", "--output", "out", required=True, type=click.Path(), help="File to write (linuxcnc: a directory).")
@click.option("--comp-file-type", type=click.Choice(["0", "1"]), default="0", show_default=True,
              help="linuxcnc: COMP_FILE_TYPE (0 = positions, 1 = trims).")
@_units_option
@machine_option
@click.option("--temperature", type=TEMPERATURE, default=None,
              help="With --machine and a map set: the temperature to export the map at, C.")
@json_option
@overwrite_option("Replace an existing output file (linuxcnc: the axis files in OUT); never an input.")
def map_export_cmd(map_spec, fmt, out, comp_file_type, units, machine_file, temperature, as_json,
                   overwrite) -> None:
    """Write the linear components of MAP ('appendix-b', 'thesis@T' or a map file) in FORMAT;
    without MAP, the machine's map (--machine; a set at --temperature).

    iso230-2 and linuxcnc carry delta_x of X, delta_y of Y and delta_z of Z only,
    the same value in both approach directions; linuxcnc (a format of one file per
    axis) writes x.comp, y.comp and z.comp into the directory OUT.
    """
    from ..errors import Error
    from ..formats import mapformats
    from ..machine import load_machine

    try:
        entry = mapformats.get(fmt)
        inputs = command_inputs([map_spec, machine_file])  # a machine file's own maps are inputs too
        targets = entry.files(out) if entry.per_axis else {"": out}
        if not entry.per_axis or Path(out).is_dir():  # a folder still missing is made: nothing in it to replace
            check_free({"--output": list(targets.values())}, inputs, overwrite=overwrite)  # before any work
        if map_spec is not None:
            source = _map_spec(map_spec, "MAP")
        elif machine_file is None:
            raise click.UsageError("give MAP or --machine")
        else:
            source = load_maps((), load_machine(machine_file))
            if isinstance(source, ErrorMapSet):
                if temperature is None:
                    raise click.UsageError("the machine's maps are a set: give --temperature (C)")
                source = source.at(temperature)
        takes = entry.write_options()
        options = {k: v for k, v in {"comp_file_type": int(comp_file_type), "units": units}.items()
                   if k in takes or takes == ["*"]}
        if entry.per_axis:
            ensure_folder(out)
        with writing("--output", targets.values(), inputs, overwrite=overwrite):  # every axis's file or none
            mapformats.write(source, targets if entry.per_axis else out, fmt, **options)
        written = [str(p) for p in targets.values()] if entry.per_axis else out
    except Error as exc:
        raise fail(exc) from None
    except OSError as exc:
        raise click.ClickException(f"{out}: {exc.strerror or exc}") from None
    if as_json:
        click.echo(strict_json({"output": written if isinstance(written, list) else str(written),
                                "format": fmt}, indent=2))
        return
    console.print(f"wrote {', '.join(written) if isinstance(written, list) else written}")
