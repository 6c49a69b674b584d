"""A machine file: one CMM with its scanner, in TOML (docs/your-machine.md).

It says how the carriages are stacked (the machine configuration), each
axis's travel, which error maps describe the machine, the scanner's optics
and noise, the mount (offset, pose, alignment library), the thermocouple
channels and their roles, and the artefact's expansion coefficient. Every
command takes ``--machine FILE``; without one the thesis machine (DEA Iota
1102 with a Hyscan 45C) is used, and said so. Bundled examples:
:func:`example_names`.

Units: mm, um, degrees, degrees C, ppm/K, converted to the package's units
(mm, degrees C, 1/K) here and nowhere else.
"""

from __future__ import annotations

import logging
import math
import os
import tomllib
from dataclasses import dataclass
from pathlib import Path

from . import _core
from ._arrays import as_triple
from ._validate import check_reproducibility, finite, nonnegative, parse_toml, positive
from .effects import channel_roles
from .errormap import ErrorMap, ErrorMapSet, data_path
from .errors import InputError, read_input_text
from .point_uncertainty import MapUncertainty
from .pose import MountOffset, Pose, check_pose_angles
from .scanner import Scanner
from .schemas import validate
# The thesis machine's thermocouple channels and the physical ranges of a machine file's numbers live with the
# machine file's schema (defined once there, used here and by the schema).
from .schemas.machine import CHANNELS, EXPANSION_RANGE_PPM, OFFSET_LIMIT_MM, TRAVEL_LIMIT_MM

__all__ = ["Machine", "configurations", "example_names", "example_text", "load_machine", "read_maps",
           "check_map_specs", "with_reproducibility"]

_log = logging.getLogger(__name__)

#: Where the machine comes from when no file is given.
_DEFAULT_SOURCE = "the thesis machine (default)"

#: Keys a machine file may hold, per table ('' is the top level).
_KEYS = {
    "": {"name", "kinematics", "travel", "maps", "scanner", "mount", "thermocouples", "expansion",
         "reproducibility", "uncertainty"},
    "travel": {"x", "y", "z"},
    "maps": {"bundled", "files"},
    "scanner": {"field_of_view_mm", "depth_of_view_mm", "points_per_profile", "profile_rate_hz", "noise_um"},
    "mount": {"offset_mm", "pose_deg", "alignments"},
    "expansion": {"artefact"},
    "reproducibility": {"per_scan_um", "source"},
    "uncertainty": {"position_um", "rotation_arcsec", "squareness_arcsec", "positioning_ppm", "reference_mm", "source"},
}

#: Tables a machine file must have: without them a machine would silently be
#: the thesis's (its chain, maps, mount and thermocouples).
_REQUIRED_TABLES = {
    "travel": "x, y, z = [low, high] in mm",
    "maps": "bundled = 'thesis' | 'appendix-b' or files = [...]",
    "mount": "offset_mm = [U1, V1, W1] and pose_deg = [alpha, beta, gamma]",
    "thermocouples": "channel = 'role' for each thermocouple",
}



def configurations() -> list[dict]:
    """The machine configurations the kernel knows: name, description and the
    stacking from the base up as (carriage, 'probe' or 'part')."""
    return _core.kinematics_configurations()


def example_names() -> list[str]:
    """Names of the bundled example machine files."""
    return sorted(p.name[: -len(".toml")] for p in data_path("machines").iterdir() if p.name.endswith(".toml"))


def example_text(name: str) -> str:
    """The text of the bundled example machine file ``name``."""
    if name not in example_names():
        raise InputError(f"machine example {name!r}: not one of {', '.join(example_names())}")
    return data_path("machines", f"{name}.toml").read_text(encoding="utf-8")


@dataclass(frozen=True)
class Machine:
    """One CMM with its scanner.

    Attributes
    ----------
    name : str
        What the machine is called.
    kinematics : str
        Machine configuration (a name of :func:`configurations`).
    travel : tuple of 3 (float, float)
        Scale range of X, Y, Z, mm.
    map_files : tuple of Path
        Error map files (canonical CSV or controller files); empty for the
        bundled ``bundled_maps``.
    bundled_maps : str or None
        ``'thesis'`` (the bundled 20/25/30 C set) or ``'appendix-b'``.
    scanner : Scanner
        Field and depth of view (mm), points per profile, profile rate (Hz),
        noise (mm).
    offset : MountOffset
        Mount offset l1, mm.
    pose : Pose
        Default digitizer pose, degrees.
    alignments : Path or None
        Alignment library (JSON).
    thermocouples : dict of str -> str
        Channel name -> role.
    artefact_expansion : float
        Expansion coefficient of the artefact, 1/K.
    source : str
        Where the machine came from (a file, or the default).
    defaults : tuple of str
        The defaults taken for keys the file leaves out (``name``, the
        ``[scanner]`` keys, ``expansion.artefact``), one ``"key = value"``
        each; ``machine show`` and ``machine check`` state them. The
        configuration, travel, maps, mount and thermocouples have none.
    reproducibility_um : float or None
        The machine's per-scan centre reproducibility, um per axis (the sd
        of a sphere's fitted centre from one scan to the next, from a repeat
        test: ``[reproducibility] per_scan_um``); None when the file states
        none. ``cmmpose diagnose --machine FILE`` takes it as the noise
        floor of a run that repeats no scan (docs/diagnosis.md).
    reproducibility_source : str or None
        Where that figure comes from (``[reproducibility] source``).
    """

    # No defaults here: a machine is built from a file (the thesis's is a
    # bundled one), so the file and _parse are the one place they live.
    name: str
    kinematics: str
    travel: tuple[tuple[float, float], tuple[float, float], tuple[float, float]]
    map_files: tuple[Path, ...]
    bundled_maps: str | None
    scanner: Scanner
    offset: MountOffset
    pose: Pose
    alignments: Path | None
    thermocouples: dict
    artefact_expansion: float
    source: str
    #: The defaults taken for keys the file does not give, one "key = value" each.
    defaults: tuple[str, ...] = ()
    #: Per-scan centre reproducibility, um per axis, and where it comes from (None: not stated).
    reproducibility_um: float | None = None
    reproducibility_source: str | None = None
    #: The maps' stated uncertainty per component (``[uncertainty]``; None: the maps' own, if they state one).
    map_uncertainty: MapUncertainty | None = None

    @classmethod
    def thesis(cls) -> Machine:
        """The thesis machine, the default of every command."""
        return _parse(tomllib.loads(example_text("thesis")), _DEFAULT_SOURCE, None)

    @classmethod
    def example(cls, name: str) -> Machine:
        """The bundled example machine ``name`` (see :func:`example_names`)."""
        return _parse(tomllib.loads(example_text(name)), f"bundled example {name!r}", None)

    @property
    def is_default(self) -> bool:
        """Whether no machine file was given (the thesis machine stands in)."""
        return self.source == _DEFAULT_SOURCE

    def maps(self, specs=()) -> ErrorMap | ErrorMapSet:
        """The machine's error maps (or those named by ``specs``, as
        :func:`read_maps` takes them), stacked as its configuration says."""
        maps = read_maps(specs or (self.map_files or (self.bundled_maps,)))
        if self.map_uncertainty is not None and not specs:
            maps = maps.with_uncertainty(self.map_uncertainty)
        return maps.with_kinematics(self.kinematics)

    def maps_for_run(self, run, specs=()) -> ErrorMap | ErrorMapSet | None:
        """The maps ``run`` is compensated with: ``specs`` as given (stacked
        as this machine is), None for ``('none',)`` (uncompensated only), this
        machine's maps when it came from a file, else the bundled maps
        ``run.json`` names (on the run's configuration).

        Raises
        ------
        InputError
            The default machine, no ``specs`` and a run that names no bundled
            maps (``remedy='run_maps'``).
        """
        if tuple(specs) == ("none",):
            return None
        if specs or not self.is_default:
            return self.maps(specs)
        if run.maps.get("kind") == "bundled" and run.maps.get("name") == "thesis":
            return ErrorMapSet.thesis().with_kinematics(run.maps.get("kinematics", "thesis"))
        raise InputError("the run does not name bundled maps", what="maps", option="maps", cli_option="--maps",
                         remedy="run_maps")

    def maps_record(self, specs=()) -> dict:
        """What a simulated run's ``run.json`` records of the maps it was made
        with: the bundled thesis set (with this machine's configuration when
        not the thesis's), so that evaluating it finds them; ``{}`` for maps
        named by ``specs`` or files (then the maps are given again)."""
        if specs or self.bundled_maps != "thesis":
            return {}
        record = {"kind": "bundled", "name": "thesis"}
        if self.kinematics != "thesis":
            record["kinematics"] = self.kinematics
        return record

    def uncovered(self, ranges) -> list[tuple[str, tuple[float, float], tuple[float, float]]]:
        """The axes whose travel goes beyond a map's ``ranges`` ((lo, hi) of
        X, Y, Z, mm): (axis letter, travel, map range) each; points there
        cannot be compensated."""
        return [(axis, (lo, hi), (mlo, mhi)) for axis, (lo, hi), (mlo, mhi) in zip("XYZ", self.travel, ranges)
                if lo < mlo - 1e-9 or hi > mhi + 1e-9]

    def check(self) -> list[str]:
        """What is worth knowing about the machine beyond its own checks (the
        maps loaded and compared with the travel); raises on an error."""
        notes = []
        maps = self.maps()
        ranges = (maps.maps[0] if isinstance(maps, ErrorMapSet) else maps).ranges
        for axis, (lo, hi), (mlo, mhi) in self.uncovered(ranges)[:1]:
            raise InputError(f"{self.source}: travel.{axis.lower()} {lo:g}..{hi:g} mm goes beyond the maps' "
                             f"{mlo:g}..{mhi:g} mm: points there cannot be compensated")
        for axis, (lo, hi), (mlo, mhi) in zip("XYZ", self.travel, ranges):
            if lo > mlo + 1e-9 or hi < mhi - 1e-9:
                notes.append(f"the maps cover {axis} {mlo:g}..{mhi:g} mm, more than its travel {lo:g}..{hi:g} mm")
        notes += [f"{self.source}: {d} (the default; the file does not give it)" for d in self.defaults]
        roles = set(self.thermocouples.values())
        for role in ("x_scale", "y_scale", "z_scale"):
            if role not in roles:
                notes.append(f"no thermocouple has the role {role!r}: the machine temperature is the mean of the others")
        return notes

    def describe(self) -> list[tuple[str, str]]:
        """(field, value) rows for a table."""
        kin = {c["name"]: c for c in configurations()}[self.kinematics]
        maps = ", ".join(str(p) for p in self.map_files) if self.map_files else f"bundled {self.bundled_maps!r}"
        s = self.scanner
        return [
            ("machine", f"{self.name} ({self.source})"),
            ("configuration", f"{self.kinematics}: {kin['description']}"),
            ("stacking (base up)", ", ".join(f"{a} ({side})" for a, side in kin["stack"])),
            ("travel (mm)", ", ".join(f"{a} {lo:g}..{hi:g}" for a, (lo, hi) in zip("XYZ", self.travel))),
            ("maps", maps),
            ("scanner", f"u {s.u_range[0]:g}..{s.u_range[1]:g} mm, v {s.v_range[0]:g}..{s.v_range[1]:g} mm, "
                        f"{s.points_per_profile} points x {s.profile_rate:g} Hz, noise {s.noise * 1e3:g} um"),
            ("mount offset (mm)", ", ".join(f"{v:g}" for v in self.offset)),
            ("pose (deg)", ", ".join(f"{v:g}" for v in self.pose.as_tuple())),
            ("alignments", str(self.alignments) if self.alignments else "-"),
            ("thermocouples", ", ".join(f"{c}={r}" for c, r in self.thermocouples.items())),
            ("artefact expansion", f"{self.artefact_expansion * 1e6:g} ppm/K"),
            ("per-scan reproducibility", "not stated" if self.reproducibility_um is None else
             f"{self.reproducibility_um:g} um per axis" + (f" ({self.reproducibility_source})"
                                                            if self.reproducibility_source else "")),
            ("defaults taken", "; ".join(self.defaults) if self.defaults else "none: the file gives every key"),
        ]


def load_machine(path: str | Path | None) -> Machine:
    """The machine of the file at ``path``, or the thesis machine for None.

    Raises
    ------
    InputError
        Naming the file and the key at fault: not TOML, an unknown key, a
        missing or malformed value, an unknown configuration or role, a map
        file that does not exist.
    """
    if path is None:
        return Machine.thesis()
    path = Path(path)
    # the one reader: a FIFO or /dev/zero refused as what it is (no wait, no endless read), the size bounded
    text = read_input_text(path, "machine file")
    doc = parse_toml(text, str(path))  # not TOML, nested 10,000 deep or a 5,001-digit integer: InputError
    return _parse(doc, str(path), path.parent)


def _parse(doc: dict, where: str, folder: Path | None) -> Machine:
    validate(doc, "machine", where)  # the one door in: every key typed and every number within its range
    _check_tables(doc, where)
    defaults: list[str] = []  # what the file leaves to the defaults, in the order the tables come
    if "name" not in doc:
        defaults.append('name = "unnamed machine"')
    name = _text(doc, "name", where, default="unnamed machine")
    kinematics = _kinematics(doc, where)
    travel_table = doc["travel"]
    travel = tuple(_pair(travel_table, axis, f"{where}: travel.{axis}", limit=TRAVEL_LIMIT_MM) for axis in "xyz")
    bundled, files = _maps(doc["maps"], where, folder)
    scanner = _scanner(doc.get("scanner", {}), where, defaults)
    offset, pose, alignments = _mount(doc["mount"], where, folder)
    tc = _thermocouples(doc["thermocouples"], where)
    expansion_ppm = _expansion(doc.get("expansion", {}), where, defaults)
    repro_um, repro_source = _reproducibility(doc, where)
    map_uncertainty = None
    if "uncertainty" in doc:
        map_uncertainty = MapUncertainty.from_dict(dict(doc["uncertainty"]), f"{where}: [uncertainty]")
    machine = Machine(name=name, kinematics=kinematics, travel=travel, map_files=files, bundled_maps=bundled,
                      scanner=scanner, offset=offset, pose=pose, alignments=alignments, thermocouples=dict(tc),
                      artefact_expansion=expansion_ppm * 1e-6, source=where, defaults=tuple(defaults),
                      reproducibility_um=repro_um, reproducibility_source=repro_source,
                      map_uncertainty=map_uncertainty)
    for d in defaults:
        _log.info("machine %s: %s (the default; the file does not give it)", where, d)
    _log.info("machine %s: %s, %s", where, name, kinematics)
    return machine


def _check_tables(doc: dict, where: str) -> None:
    """Every table a table, every key known, every required table there."""
    for table, allowed in _KEYS.items():
        part = doc if table == "" else doc.get(table, {})
        if not isinstance(part, dict):
            raise InputError(f"{where}: [{table}] must be a table")
        unknown = sorted(set(part) - allowed)
        if unknown:
            prefix = f"{table}." if table else ""
            raise InputError(f"{where}: unknown key {prefix}{unknown[0]} (known: {', '.join(sorted(allowed))})")
    missing = [t for t in _REQUIRED_TABLES if t not in doc]
    if missing:
        raise InputError(f"{where}: [{missing[0]}] is missing ({_REQUIRED_TABLES[missing[0]]}); "
                         "a machine file states it (cmmpose machine example)")


def _kinematics(doc: dict, where: str) -> str:
    """The machine configuration's name: required, one of the known ones."""
    known = [c["name"] for c in configurations()]
    if "kinematics" not in doc:
        raise InputError(f"{where}: kinematics is missing (one of {', '.join(known)}); "
                         "without it the machine's chain is unknown")
    kinematics = _text(doc, "kinematics", where, default="")
    if kinematics not in known:
        raise InputError(f"{where}: kinematics = {kinematics!r} is not one of {', '.join(known)}")
    return kinematics


def _maps(maps: dict, where: str, folder: Path | None) -> tuple[str | None, tuple]:
    """[maps]: bundled maps by name, or map files (relative to the machine file's folder) that exist."""
    if ("bundled" in maps) == ("files" in maps):
        raise InputError(f"{where}: [maps] needs one of bundled = 'thesis' | 'appendix-b' or files = [...]")
    if "bundled" in maps:
        bundled = maps["bundled"]
        if bundled not in ("thesis", "appendix-b"):
            raise InputError(f"{where}: maps.bundled = {bundled!r} is not 'thesis' or 'appendix-b'")
        return bundled, ()
    if not (isinstance(maps["files"], list) and maps["files"] and all(isinstance(f, str) for f in maps["files"])):
        raise InputError(f"{where}: maps.files must be a non-empty list of file names")
    files = tuple((folder or Path(".")) / f for f in maps["files"])
    missing = [str(f) for f in files if not f.is_file()]
    if missing:
        raise InputError(f"{where}: maps.files: no such file {missing[0]}")
    return None, files


def _scanner(sc: dict, where: str, defaults: list) -> Scanner:
    """[scanner]: each value given or the default (named in ``defaults``)."""
    scanner_defaults = Scanner()
    for key, value in (("field_of_view_mm", list(scanner_defaults.u_range)),
                       ("depth_of_view_mm", list(scanner_defaults.v_range)),
                       ("points_per_profile", scanner_defaults.points_per_profile),
                       ("profile_rate_hz", scanner_defaults.profile_rate),
                       ("noise_um", scanner_defaults.noise * 1e3)):
        if key not in sc:
            defaults.append(f"scanner.{key} = {value!r}")
    return Scanner(
        u_range=_pair(sc, "field_of_view_mm", f"{where}: scanner.field_of_view_mm",
                      default=scanner_defaults.u_range),
        v_range=_pair(sc, "depth_of_view_mm", f"{where}: scanner.depth_of_view_mm",
                      default=scanner_defaults.v_range),
        points_per_profile=_integer(sc, "points_per_profile", f"{where}: scanner.points_per_profile",
                                    scanner_defaults.points_per_profile),
        profile_rate=_setting(sc, "profile_rate_hz", f"{where}: scanner.profile_rate_hz",
                              scanner_defaults.profile_rate, positive),
        noise=_setting(sc, "noise_um", f"{where}: scanner.noise_um", scanner_defaults.noise * 1e3,
                       nonnegative) * 1e-3,
    )


def _mount(mount: dict, where: str, folder: Path | None) -> tuple[MountOffset, Pose, Path | None]:
    """[mount]: the offset (within reach), the pose, and the alignment library's file if named."""
    for key in ("offset_mm", "pose_deg"):
        if key not in mount:
            raise InputError(f"{where}: mount.{key} is missing ({_REQUIRED_TABLES['mount']})")
    offset_where = f"{where}: mount.offset_mm"
    offset = MountOffset(*as_triple(offset_where, mount["offset_mm"]))
    if max(map(abs, offset)) > OFFSET_LIMIT_MM:
        raise InputError(f"{offset_where}: {list(offset)} mm is beyond +-{OFFSET_LIMIT_MM:g} mm")
    pose = Pose(*check_pose_angles(f"{where}: mount.pose_deg", mount["pose_deg"]))
    alignments = None
    if "alignments" in mount:
        if not isinstance(mount["alignments"], str) or not mount["alignments"]:
            raise InputError(f"{where}: mount.alignments must be a file name")
        alignments = (folder or Path(".")) / mount["alignments"]
    return offset, pose, alignments


def _thermocouples(tc, where: str) -> dict:
    """[thermocouples]: at least one channel, each with a known role."""
    if not isinstance(tc, dict) or not tc:
        raise InputError(f"{where}: [thermocouples] must name at least one channel = role")
    roles = {r for _, r in CHANNELS} | set(channel_roles())
    for channel, role in tc.items():
        if not isinstance(role, str) or role not in roles:
            raise InputError(f"{where}: thermocouples.{channel} = {role!r} is not a known role "
                             f"({', '.join(sorted(roles))})")
    return tc


def _expansion(exp_table: dict, where: str, defaults: list) -> float:
    """[expansion]: the artefact's coefficient, ppm/K (steel's by default, named in ``defaults``), in range."""
    if "artefact" not in exp_table:
        defaults.append("expansion.artefact = 12.0 ppm/K (steel)")
    expansion_ppm = _setting(exp_table, "artefact", f"{where}: expansion.artefact", 12.0)
    lo, hi = EXPANSION_RANGE_PPM
    if not lo <= expansion_ppm <= hi:
        raise InputError(f"{where}: expansion.artefact = {expansion_ppm:g} ppm/K is outside {lo:g}..{hi:g} ppm/K "
                         "(a coefficient of expansion in ppm/K, e.g. 11.5 for steel)")
    return expansion_ppm


def with_reproducibility(text: str, per_scan_um: float, source: str, where: str = "machine file") -> str:
    """The machine file ``text`` with its ``[reproducibility]`` table set to
    ``per_scan_um`` (um per axis) and ``source``: the table's two keys
    replaced where it has one (its comments and the rest of the file kept),
    else the table added at the end. The result is parsed back and checked.

    Raises
    ------
    InputError
        ``text`` is not TOML, states its reproducibility other than as a
        ``[reproducibility]`` table, or the value is not plausible
        (:func:`cmmpose._validate.check_reproducibility`), naming ``where``.
    """
    import json
    import re

    um = check_reproducibility(f"{where}: reproducibility.per_scan_um", per_scan_um)
    doc = parse_toml(text, where)
    new = [f"per_scan_um = {um:.4g}", f"source = {json.dumps(str(source))}"]
    lines = text.splitlines()
    head = [i for i, line in enumerate(lines) if re.match(r"\s*\[reproducibility\]", line)]
    if head:
        start = head[0] + 1
        end = next((i for i in range(start, len(lines)) if re.match(r"\s*\[", lines[i])), len(lines))
        body = [line for line in lines[start:end] if not re.match(r"\s*(per_scan_um|source)\s*=", line)]
        while body and not body[-1].strip():  # the new keys go after the table's comments, blank lines after
            body.pop()
        tail = [""] if end < len(lines) else []
        lines = lines[:start] + body + new + tail + lines[end:]
    elif "reproducibility" in doc:
        raise InputError(f"{where}: states its reproducibility other than as a [reproducibility] table; "
                         "write it as one (per_scan_um = ..., source = ...)")
    else:
        while lines and not lines[-1].strip():
            lines.pop()
        lines += ["", "[reproducibility]  # per-scan centre reproducibility, um per axis (cmmpose machine "
                      "reproducibility)", *new]
    out = "\n".join(lines) + "\n"
    _reproducibility(parse_toml(out, where), where)  # reads back as written
    return out


def _reproducibility(doc: dict, where: str) -> tuple[float | None, str | None]:
    """``[reproducibility]``: ``per_scan_um`` (required in the table) checked
    as :func:`cmmpose._validate.check_reproducibility` does, and the optional
    ``source`` text; (None, None) without the table."""
    if "reproducibility" not in doc:
        return None, None
    table = doc["reproducibility"]
    if "per_scan_um" not in table:
        raise InputError(f"{where}: reproducibility.per_scan_um is missing (the per-scan centre reproducibility, "
                         "um per axis, from a repeat test: cmmpose machine reproducibility)")
    um = check_reproducibility(f"{where}: reproducibility.per_scan_um", table["per_scan_um"])
    source = table.get("source")
    if source is not None and (not isinstance(source, str) or not source.strip()):
        raise InputError(f"{where}: reproducibility.source must be a non-empty text, got {source!r}")
    return um, source


def check_map_specs(specs) -> tuple[str, ...]:
    """``specs`` (map names and files) as text, or ``InputError`` for an
    empty or blank one (``--maps ""``), which would otherwise name the
    current folder."""
    specs = tuple(str(s) for s in specs)
    for k, spec in enumerate(specs):
        if not spec.strip():
            which = f" (number {k + 1} of {len(specs)})" if len(specs) > 1 else ""
            raise InputError(f"maps: an empty name{which}; give 'thesis', 'appendix-b' or a map file")
        if spec not in MAP_NAMES and not os.path.lexists(spec):
            raise InputError(f"maps: {spec!r} is neither a bundled map name ({', '.join(MAP_NAMES)}) nor a file "
                             "that exists", what="maps", value=spec, allowed=MAP_NAMES, file=spec, option="maps",
                             cli_option="--maps")
    return specs


#: The map names every ``maps=`` / ``--maps`` takes besides files (``none``: uncompensated only, where accepted).
MAP_NAMES = ("thesis", "appendix-b", "none")


def read_maps(specs) -> ErrorMap | ErrorMapSet:
    """Error maps from names and files: ``'thesis'`` (the bundled 20/25/30 C
    set, alone), ``'appendix-b'`` (the 22 C controller map), controller
    files (``.txt``) and canonical maps (any other suffix); several make a
    set."""
    specs = list(check_map_specs(specs))
    if not specs:
        raise InputError("maps: none given")
    if "thesis" in specs:
        if len(specs) > 1:
            raise InputError("maps: 'thesis' is a whole set; give it alone")
        return ErrorMapSet.thesis()
    maps = []
    for spec in specs:
        if spec == "appendix-b":
            maps.append(ErrorMap.appendix_b())
        elif Path(spec).suffix.lower() == ".txt":
            maps.append(ErrorMap.read_controller_file(spec))
        else:
            maps.append(ErrorMap.read(spec))
    return maps[0] if len(maps) == 1 else ErrorMapSet(maps)


def _text(doc: dict, key: str, where: str, default: str) -> str:
    value = doc.get(key, default)
    if not isinstance(value, str) or not value:
        raise InputError(f"{where}: {key} must be a non-empty text, got {value!r}")
    return value


def _real(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _setting(table: dict, key: str, where: str, default: float, check=finite) -> float:
    """``table[key]`` (or ``default``), a TOML number (text is refused, not
    read as one), through one of the package's checks."""
    value = table.get(key, default)
    if not _real(value):
        raise InputError(f"{where}: expected a finite number, got {value!r}")
    return check(where, value)


def _integer(table: dict, key: str, where: str, default: int) -> int:
    value = table.get(key, default)
    if not isinstance(value, int) or isinstance(value, bool) or value < 2:
        raise InputError(f"{where}: expected a whole number >= 2, got {value!r}")
    return value


def _pair(table: dict, key: str, where: str, *, default=None, limit: float = math.inf) -> tuple[float, float]:
    if key not in table and default is None:
        raise InputError(f"{where}: missing (expected [low, high])")
    value = table.get(key, default)
    if not (isinstance(value, (list, tuple)) and len(value) == 2 and all(map(_real, value))):
        raise InputError(f"{where}: expected [low, high] numbers, got {value!r}")
    if not value[0] < value[1]:
        raise InputError(f"{where}: low must be below high, got {list(value)}")
    if max(abs(value[0]), abs(value[1])) > limit:
        raise InputError(f"{where}: {list(value)} mm is beyond +-{limit:g} mm")
    return float(value[0]), float(value[1])
