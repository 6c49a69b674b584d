"""A model file: the JSON a :class:`cmmpose.model.Model` is saved to (its maps as CSV text, its effects with their
values, uncertainty and alternatives, its domain and covariance, the temperature policy) and read back from, every
part checked and a problem named with the file and the key (docs/formats.md, "Model file").

The functions take a model and return what its constructor takes, so that this module does not import the class
it serves (``Model.to_dict``, ``Model.save`` and ``Model.load`` call them)."""

from __future__ import annotations

import logging
import math
import tempfile
from pathlib import Path

import numpy as np

from .._json import dumps as strict_json
from ..atomicfile import write_text
from ..errormap import ErrorMap, ErrorMapSet
from ..errors import Error, InputError, MapError, read_input_text
from ..schemas import loads_json, validate
from ..schemas.model import MODEL_SCHEMA
from ..temperature import LOG_HOLD, TEMPERATURE_TOLERANCE, TemperaturePolicy
from .alternatives import Alternative
from .domain import Domain
from .names import resolve
from .spec import EffectSpec


def model_document(model) -> dict:
    """The JSON document of ``model`` (a :class:`cmmpose.model.Model`), maps included."""
    maps = model.maps.maps if isinstance(model.maps, ErrorMapSet) else [model.maps]
    texts = []
    with tempfile.TemporaryDirectory() as d:
        for i, m in enumerate(maps):
            p = Path(d) / f"map{i}.csv"
            m.write(p)
            texts.append(p.read_text())
    return {
        "schema": MODEL_SCHEMA,
        "schema_version": 1,
        "maps": {"kind": "set" if isinstance(model.maps, ErrorMapSet) else "map", "csv": texts,
                 "kinematics": model.maps.kinematics},
        "temperature": model.temperature,
        "out_of_range": model.out_of_range,
        "temperature_tolerance_K": model.temperature_tolerance,
        "log_hold_s": model.log_hold,
        "temperature_policy": model.policy.to_dict(),
        **({"temperature_log": model.thermal} if model.thermal else {}),
        "effects": [{"name": s.name, "kind": s.kind, "params": dict(zip(s.params, map(float, v))),
                     "units": dict(zip(s.params, s.units))} | _uncertainty_entry(model, s) for s, v in model.effects],
        **({"alternatives": [a.to_dict() for a in model.alternatives if a.chosen in model.names]}
           if model.alternatives else {}),
        **({"domain": model.domain.to_dict()} if model.domain is not None else {}),
        **({"covariance": {"parameters": list(model.covariance["parameters"]),
                           "matrix": np.asarray(model.covariance["matrix"], float).tolist()}}
           if model.covariance else {}),
    }


def write_model(model, path) -> Path:
    """Write ``model`` as JSON to ``path``, atomically; a NaN or an inf it holds is refused."""
    path = Path(path)
    doc = model_document(model)
    if _holds_nan(doc):
        raise InputError(f"{path}: the model holds a value that is not a number (NaN): not written")
    try:
        # Standard JSON only (cmmpose._json): an undetermined uncertainty (inf) is written null and named
        # in the top-level "non_finite" list; load reads null back as inf.
        text = strict_json(doc, indent=1)
    except ValueError:
        raise InputError(f"{path}: the model holds a value that is not finite (inf): not written") from None
    write_text(path, text)
    return path


def read_model(path, user_effects=()) -> tuple:
    """The arguments of ``Model(...)``, in order, read from a model file and checked; ``user_effects``: the specs
    of the user-defined effects it names."""
    path = Path(path)
    text = read_input_text(path, "model file")  # a FIFO or /dev/zero refused as such, the size bounded
    doc = loads_json(text, path, "model file")  # not JSON, or a key repeated in an object: InputError
    if not isinstance(doc, dict) or doc.get("schema") != MODEL_SCHEMA or doc.get("schema_version") != 1:
        raise InputError(f"{path}: not a {MODEL_SCHEMA} version 1 file", file=str(path))
    validate(doc, "model", path)  # the one door in: every key typed and every number within its range
    try:
        model_maps = _saved_maps(doc["maps"], path)
        users = _user_specs(user_effects)
        effects, unc = _saved_effects(doc["effects"], users, path)
        alternatives = _saved_alternatives(doc.get("alternatives") or [], users, [s.name for s, _ in effects], path)
        domain = Domain.from_dict(doc["domain"], str(path)) if doc.get("domain") is not None else None
        covariance = _saved_covariance(doc.get("covariance"), effects, path)
        return (model_maps, tuple(effects), doc.get("temperature"), doc.get("out_of_range", "raise"),
                doc.get("temperature_tolerance_K", TEMPERATURE_TOLERANCE), doc.get("log_hold_s", LOG_HOLD),
                unc, _saved_policy(doc.get("temperature_policy"), path), doc.get("temperature_log") or {},
                alternatives, domain, covariance)
    except Error:  # already names the file and what is wrong in it
        raise
    except (KeyError, TypeError, ValueError) as e:
        raise InputError(f"{path}: malformed model file ({type(e).__name__}: {e})") from None


def _saved_maps(doc: dict, path: Path) -> ErrorMap | ErrorMapSet:
    """The ``maps`` of a model file: its CSV texts read as maps (a problem names the file, not a temporary one),
    one map or a set, stacked as its ``kinematics`` says."""
    with tempfile.TemporaryDirectory() as d:
        maps = []
        for i, text in enumerate(doc["csv"]):
            p = Path(d) / f"map{i}.csv"
            p.write_text(text)
            try:
                maps.append(ErrorMap.read(p))
            except MapError as exc:  # name the user's file, not the temporary one
                raise MapError(str(exc).replace(str(p), f"{path} (maps.csv[{i}])")) from None
    kind = doc["kind"]
    if kind not in ("set", "map"):
        raise InputError(f"{path}: maps.kind must be 'set' or 'map', got {kind!r}")
    if not maps:
        raise InputError(f"{path}: maps.csv lists no map")
    if kind == "map" and len(maps) != 1:
        raise InputError(f"{path}: maps.kind 'map' needs exactly one map, got {len(maps)}")
    model_maps = ErrorMapSet(maps) if kind == "set" else maps[0]
    kinematics = doc.get("kinematics", "thesis")  # files before machine configurations: thesis
    if not isinstance(kinematics, str):
        raise InputError(f"{path}: maps.kinematics must be a configuration name, got {kinematics!r}")
    return model_maps.with_kinematics(kinematics)


def _user_specs(user_effects) -> dict:
    """The user-defined effects by name; two of one name are refused."""
    users = {}
    for u in user_effects:
        if users.get(u.name, u) is not u:  # which one the file means would depend on their order
            raise InputError(f"user_effects: two effects are named {u.name!r}: give each effect once",
                             what=u.name)
        users[u.name] = u
    return users


def _saved_effects(entries, users: dict, path: Path) -> tuple[list, dict]:
    """The ``effects`` of a model file: (spec, values) pairs, and the uncertainty of those that state it."""
    effects, unc = [], {}
    for e in entries:
        name = e["name"]
        spec = _saved_spec(name, e.get("kind"), users, path)
        if set(e["params"]) != set(spec.params):
            raise InputError(f"{path}: effect {name!r} has parameters {sorted(e['params'])}, "
                             f"expected {list(spec.params)}")
        values = [e["params"][p] for p in spec.params]
        bad = [p for p, v in zip(spec.params, values) if isinstance(v, bool) or not isinstance(v, (int, float))]
        if bad:
            raise InputError(f"{path}: effect {name!r}: parameter {bad[0]!r} = {e['params'][bad[0]]!r} "
                             f"is not a number")
        effects.append((spec, np.array([float(v) for v in values])))
        if "uncertainty" in e:  # optional: null is a parameter the data did not determine
            unc[name] = _saved_uncertainty(e["uncertainty"], spec, path)
    return effects, unc


def _saved_spec(name: str, kind, users: dict, path) -> EffectSpec:
    """The spec of a saved effect named ``name`` (a map correction is rebuilt from its name)."""
    if name.startswith(("map:", "cross:")):  # a map or cross-axis correction: rebuilt from its name
        return resolve(name)
    if kind == "python":
        if name not in users:
            raise InputError(f"{path}: effect {name!r} is user-defined", remedy="user_effects")
        return users[name]
    return resolve(name)


def _saved_alternatives(entries, users: dict, names, path) -> tuple:
    """The ``alternatives`` of a model file (files before them: none). An
    alternative to an effect the model lacks is refused; a user-defined one
    whose spec was not passed is left out, with a log line (the model still
    applies; only the check of that alternative is lost)."""
    out = []
    for i, e in enumerate(entries):
        name, chosen = e["name"], e["chosen"]
        if chosen not in names:
            raise InputError(f"{path}: alternatives[{i}] ({name}) is an alternative to {chosen!r}, "
                             f"which the model does not hold")
        # A map or cross-axis correction (kind "python", name "map:..." or "cross:...") is a library shape rebuilt
        # from its name (_saved_spec): only a user-defined effect needs its spec passed again.
        if e.get("kind") == "python" and not name.startswith(("map:", "cross:")) and name not in users:
            logging.getLogger("cmmpose.model.alternatives").warning(
                "%s: the alternative %s to %s is user-defined and was not passed: it is not checked", path, name,
                chosen)
            continue
        spec = _saved_spec(name, e.get("kind"), users, path)
        values = [e["params"][p] for p in spec.params]
        if any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in values):
            raise InputError(f"{path}: alternatives[{i}] ({name}): a parameter is not a number")
        out.append(Alternative(chosen, spec, np.array(values, float), float(e.get("in_sample_difference_um") or 0.0),
                               str(e.get("reason", ""))))
    return tuple(out)


def _saved_covariance(doc, effects, path) -> dict:
    """The ``covariance`` of a model file: its parameters must be the model's
    ('effect.param'), its matrix square, finite, symmetric and positive
    semi-definite (a negative variance or a correlation above 1 would make a
    predicted uncertainty imaginary or too small), in the parameters' units."""
    if doc is None:
        return {}
    known = {f"{s.name}.{p}" for s, _ in effects for p in s.params}
    try:
        names, m = list(doc["parameters"]), np.array(doc["matrix"], dtype=float)
    except (KeyError, TypeError, ValueError):
        raise InputError(f"{path}: covariance: expected parameters (a list of 'effect.param') and a matrix "
                         f"(a list of rows of numbers)", file=str(path), what="covariance") from None
    unknown = [n for n in names if n not in known]
    if unknown or len(set(names)) != len(names):
        raise InputError(f"{path}: covariance.parameters: {unknown or names} are not each one parameter of the "
                         f"model's effects", file=str(path), what="covariance.parameters")
    k = len(names)
    if m.shape != (k, k) or not np.all(np.isfinite(m)):
        raise InputError(f"{path}: covariance.matrix: expected {k} x {k} finite numbers, got shape {m.shape}",
                         file=str(path), what="covariance.matrix")
    scale = max(float(np.max(np.abs(m))), 1e-300) if k else 1.0
    if k and (np.max(np.abs(m - m.T)) > 1e-9 * scale or np.linalg.eigvalsh((m + m.T) / 2).min() < -1e-9 * scale):
        raise InputError(f"{path}: covariance.matrix is not symmetric positive semi-definite", file=str(path),
                         what="covariance.matrix")
    return {"parameters": names, "matrix": m}


def _saved_uncertainty(entry, spec: EffectSpec, path) -> np.ndarray:
    """The standard uncertainty of a saved effect's parameters, in its units:
    null (or absent) is a parameter the data did not determine (inf); a NaN,
    a negative value or one that is not a number is refused, naming the file,
    the effect and the parameter (an evaluation's budget would otherwise drop
    its row without a word)."""
    if not isinstance(entry, dict):
        raise InputError(f"{path}: effect {spec.name!r}: uncertainty must map each parameter to a number, "
                         f"got {entry!r}")
    out = []
    for p in spec.params:
        v = entry.get(p)
        if v is None:
            out.append(np.inf)
            continue
        if isinstance(v, bool) or not isinstance(v, (int, float)) or math.isnan(v) or v < 0:
            raise InputError(f"{path}: effect {spec.name!r}: the uncertainty of parameter {p!r} is {v!r}; expected "
                             f"a standard uncertainty >= 0 in {spec.units[spec.params.index(p)]}, or null for a "
                             f"parameter the data did not determine")
        out.append(float(v))
    return np.array(out)


def _saved_policy(doc, path) -> TemperaturePolicy | None:
    if doc is None:  # files before the policy was saved whole
        return None
    try:
        return TemperaturePolicy.from_dict(doc)
    except InputError as exc:
        raise InputError(f"{path}: temperature_policy: {exc}") from None


def _uncertainty_entry(model, spec: EffectSpec) -> dict:
    """``{"uncertainty": {param: u}}`` of an effect whose uncertainty the model knows (inf: undetermined,
    which :meth:`Model.save` writes null and names in ``non_finite``)."""
    u = model.uncertainty.get(spec.name)
    if u is None:
        return {}
    return {"uncertainty": {p: (float(x) if np.isfinite(x) else math.inf) for p, x in zip(spec.params, np.ravel(u))}}


def _holds_nan(obj) -> bool:
    if isinstance(obj, dict):
        return any(_holds_nan(v) for v in obj.values())
    if isinstance(obj, (list, tuple)):
        return any(_holds_nan(v) for v in obj)
    return isinstance(obj, float) and math.isnan(obj)
