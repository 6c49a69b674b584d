"""Artefacts a CMM measures (docs/artefacts.md): ballbars, ball plates, step
gauges and spheres, one module per kind, found through this registry as
effects and map formats are. An artefact file (TOML) is a calibration
certificate: calibrated ball centres in the artefact's own frame with their
standard uncertainties, the ball radius, the coefficient of expansion and the
certificate's reference temperature. Bundled examples: :func:`example_names`.

Units in the file: mm, um, ppm/K, degrees C; converted here and nowhere else.
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np

from .._registry import Registry
from ..errormap import data_path
from .._validate import parse_toml, vector3
from ..errors import InputError, InputTypeError, MissingFileError, read_input_text
from ..schemas import validate
# The ranges of an artefact file's numbers live with its schema (defined once there, used here and by the schema).
from ..schemas.artefact import EXPANSION_RANGE_PPM, REFERENCE_TEMPERATURE_RANGE_C
from .base import Artefact, ArtefactKind

__all__ = ["Artefact", "ArtefactKind", "REGISTRY", "available", "get", "example_names", "example_text",
           "load_artefact", "parse_artefact", "from_dict", "EXPANSION_RANGE_PPM", "REFERENCE_TEMPERATURE_RANGE_C"]

#: Keys an artefact file may hold, per table ('' is the top level, 'balls' each ball).
_KEYS = {
    "": {"kind", "name", "certificate", "reference_temperature_C", "expansion_ppm_per_K", "radius", "balls"},
    "radius": {"nominal_mm", "calibrated_mm", "u_um"},
    "balls": {"id", "xyz_mm", "u_um"},
}

#: The artefact kinds by name: each public module's ``ArtefactKind`` subclasses, by their ``kind``.
REGISTRY: Registry[type[ArtefactKind]] = Registry(
    "artefact kind", order=str,
    unknown=lambda kind, names: InputError(f"artefact kind {kind!r}: unknown; known: {', '.join(names)}"),
).discover(__name__, __path__, ArtefactKind, "kind")


def available() -> dict[str, type[ArtefactKind]]:
    """Artefact kinds by name, sorted."""
    return REGISTRY.as_dict()


def get(kind: str) -> type[ArtefactKind]:
    """The artefact kind ``kind``; ``InputError`` naming the known ones."""
    return REGISTRY.get(kind)


def example_names() -> list[str]:
    """Names of the bundled example artefact files (``data/artefacts``)."""
    return sorted(p.name[: -len(".toml")] for p in data_path("artefacts").iterdir() if p.name.endswith(".toml"))


def example_text(name: str) -> str:
    """The text of the bundled example ``name``, or of a kind's default example."""
    if name in REGISTRY:
        name = REGISTRY.get(name).example
    if name not in example_names():
        raise InputError(f"artefact example {name!r}: not a kind ({', '.join(available())}) "
                         f"nor an example ({', '.join(example_names())})")
    return data_path("artefacts", f"{name}.toml").read_text(encoding="utf-8")


def load_artefact(path) -> Artefact:
    """The artefact of the file at ``path``, or of a bundled example or kind
    given by name.

    Raises
    ------
    InputError
        Naming the file and the key at fault: not TOML, an unknown or missing
        key, a repeated ball, a missing uncertainty, a non-physical number.
    """
    text_path = Path(path)
    if not text_path.exists() and str(path) in set(example_names()) | set(REGISTRY):
        name = str(path)
        return parse_artefact(tomllib.loads(example_text(name)), f"bundled artefact {name!r}")
    try:  # the one reader: a FIFO or /dev/zero refused as what it is, the size bounded
        text = read_input_text(text_path, "artefact file")
    except MissingFileError:
        raise MissingFileError(f"{path}: no such artefact file (nor a bundled example: "
                               f"{', '.join(example_names())})", file=str(path)) from None
    return parse_artefact(parse_toml(text, str(path)), str(path))


def from_dict(doc: dict, where: str = "run.json: artefact.definition") -> Artefact:
    """The artefact of :meth:`Artefact.to_dict` (as embedded in a run)."""
    if not isinstance(doc, dict):
        raise InputTypeError(f"{where}: expected an artefact table, got {type(doc).__name__}")
    return parse_artefact(doc, where)


def parse_artefact(doc: dict, where: str) -> Artefact:
    """An artefact from a parsed file (``where`` names it in messages)."""
    validate(doc, "artefact", where)  # the one door in: every key typed and every number within its range
    for table, allowed in _KEYS.items():
        parts = [doc] if table == "" else (doc.get(table) if table == "balls" else [doc.get(table, {})])
        if table == "balls":
            if not isinstance(parts, list) or not parts:
                raise InputError(f"{where}: balls: missing (a list of {{ id = 1, xyz_mm = [x, y, z], "
                                 f"u_um = [ux, uy, uz] }})" if parts is None else
                                 f"{where}: balls: expected a non-empty list of tables")
        for k, part in enumerate(parts):
            label = f"balls[{k}]" if table == "balls" else table
            if not isinstance(part, dict):
                raise InputError(f"{where}: {label or 'the file'} must be a table")
            unknown = sorted(set(part) - allowed)
            if unknown:
                prefix = f"{label}." if table else ""
                raise InputError(f"{where}: unknown key {prefix}{unknown[0]} (known: {', '.join(sorted(allowed))})")
    kind = _text(doc, "kind", where)
    cls = get(kind) if kind in REGISTRY else None
    if cls is None:
        raise InputError(f"{where}: kind = {kind!r} is not one of {', '.join(available())}")
    name = _text(doc, "name", where)
    certificate = _text(doc, "certificate", where)
    t_ref = _field_number(doc, "reference_temperature_C", where)
    lo, hi = REFERENCE_TEMPERATURE_RANGE_C
    if not lo <= t_ref <= hi:
        raise InputError(f"{where}: reference_temperature_C = {t_ref:g} is outside {lo:g}..{hi:g} C")
    alpha = _field_number(doc, "expansion_ppm_per_K", where)
    lo, hi = EXPANSION_RANGE_PPM
    if not lo <= alpha <= hi:
        raise InputError(f"{where}: expansion_ppm_per_K = {alpha:g} is not physical: a solid's coefficient of "
                         f"expansion is between {lo:g} and {hi:g} ppm/K (steel 11.5, Invar 1, Zerodur 0)")
    if "radius" not in doc:
        raise InputError(f"{where}: [radius]: missing (nominal_mm, calibrated_mm, u_um)")
    radius = doc["radius"]
    nominal = _field_number(radius, "nominal_mm", f"{where}: radius")
    calibrated = _field_number(radius, "calibrated_mm", f"{where}: radius")
    u_radius = _field_number(radius, "u_um", f"{where}: radius")
    if nominal <= 0 or calibrated <= 0:
        raise InputError(f"{where}: radius: nominal_mm and calibrated_mm must be > 0 mm, got {nominal:g}, {calibrated:g}")
    if abs(calibrated - nominal) > 0.05 * nominal:
        raise InputError(f"{where}: radius.calibrated_mm = {calibrated:g} differs from nominal_mm = {nominal:g} by "
                         f"more than 5 %: a diameter given as a radius?")
    if u_radius < 0:
        raise InputError(f"{where}: radius.u_um must be >= 0 um, got {u_radius:g}")
    ids, centres, u = [], [], []
    for k, ball in enumerate(doc["balls"]):
        w = f"{where}: balls[{k}]"
        if "id" not in ball:
            raise InputError(f"{w}: id: missing (the ball's number)")
        bid = ball["id"]
        if not isinstance(bid, int) or isinstance(bid, bool) or bid < 1:
            raise InputError(f"{w}.id: expected a whole number >= 1, got {bid!r}")
        if bid in ids:
            raise InputError(f"{w}.id: ball {bid} is repeated (also balls[{ids.index(bid)}])")
        ids.append(bid)
        centres.append(_field_vector(ball, "xyz_mm", w))
        if "u_um" not in ball:
            raise InputError(f"{w}.u_um: missing: every calibrated centre needs its standard uncertainties "
                             f"[ux, uy, uz] in um (the certificate's)")
        uu = _field_vector(ball, "u_um", w)
        if np.any(uu < 0):
            raise InputError(f"{w}.u_um: standard uncertainties must be >= 0 um, got {uu.tolist()}")
        u.append(uu * 1e-3)
    centres = np.array(centres)
    gaps = np.linalg.norm(centres[:, None, :] - centres[None, :, :], axis=2)
    np.fill_diagonal(gaps, np.inf)
    i, j = np.unravel_index(int(np.argmin(gaps)), gaps.shape) if len(ids) > 1 else (0, 0)
    if len(ids) > 1 and gaps[i, j] < 2 * nominal:
        i, j = sorted((int(i), int(j)))
        raise InputError(f"{where}: balls[{i}] (ball {ids[i]}) and balls[{j}] (ball {ids[j]}) are "
                         f"{gaps[i, j]:.3f} mm apart, less than a ball's diameter ({2 * nominal:g} mm): "
                         f"a ball repeated under another number?")
    artefact = Artefact(kind=kind, name=name, certificate=certificate, ids=np.array(ids), centres=centres,
                        u_centres=np.array(u), nominal_radius=nominal, calibrated_radius=calibrated,
                        u_radius=u_radius * 1e-3, expansion=alpha * 1e-6, reference_temperature=t_ref, source=where)
    cls.check(artefact, where)
    return artefact


def _text(doc: dict, key: str, where: str) -> str:
    if key not in doc:
        raise InputError(f"{where}: {key}: missing")
    value = doc[key]
    if not isinstance(value, str) or not value.strip():
        raise InputError(f"{where}: {key} must be a non-empty text, got {value!r}")
    return value


def _is_number(value) -> bool:
    """A TOML integer or float (never a string or a boolean that ``float()`` would take)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _field_number(doc: dict, key: str, where: str) -> float:
    """The number ``doc[key]``: present, written as a number, finite and below 1e9."""
    if key not in doc:
        raise InputError(f"{where}: {key}: missing")
    value = doc[key]
    if not _is_number(value) or not math.isfinite(value) or abs(value) > 1e9:
        raise InputError(f"{where}: {key}: expected a number, got {value!r}")
    return float(value)


def _field_vector(doc: dict, key: str, where: str) -> np.ndarray:
    """The three numbers ``doc[key]`` as written in the file (no strings), each finite and below 1e9."""
    if key not in doc:
        raise InputError(f"{where}.{key}: missing")
    value = doc[key]
    if not (isinstance(value, list) and len(value) == 3 and all(_is_number(v) for v in value)):
        raise InputError(f"{where}.{key}: expected three numbers [x, y, z], got {value!r}")
    out = vector3(f"{where}.{key}", value)
    if np.abs(out).max() > 1e9:
        raise InputError(f"{where}.{key}: expected three numbers [x, y, z] below 1e9, got {value!r}")
    return out


