"""The building blocks of the document schemas and the one check of a
document against one (:func:`check`): JSON Schema (draft 2020-12) dicts,
validated with :mod:`jsonschema`, and each refusal said in one line that
names the file and the key path (``m.json: effects[2].params.xy: 1e+30 is
above the maximum 3600 (arc-second)``).

The bounds every kind shares (docs/formats.md, "Schemas"):

- temperatures of a machine or an artefact: :data:`TEMPERATURE_C` (-50 to
  150 C: colder or hotter is no CMM's room, and -273.15 C is never reached);
- lengths and positions: +-:data:`LENGTH_MM` (100 m);
- angles: +-:data:`ANGLE_DEG` (one turn);
- counts of balls, channels, files: :data:`MAX_ITEMS`; integers that must
  fit a C long (int64): :data:`INT64`;
- ids and names: :data:`TEXT` (no control characters, at most
  :data:`MAX_NAME` characters).

A number must also be finite: NaN and the infinities (TOML has them, Python's
JSON reader takes them) fail the ``number`` type here, as they are not JSON
numbers at all.
"""

from __future__ import annotations

import json
import math
import numbers

import jsonschema
from jsonschema import Draft202012Validator

from ..errors import Error, InputError

__all__ = ["DRAFT", "TEMPERATURE_C", "LENGTH_MM", "ANGLE_DEG", "MAX_ITEMS", "MAX_NAME", "INT64", "TEXT",
           "number", "integer", "nullable", "text", "triple", "pair", "obj", "array", "check", "key_path", "short",
           "loads_json", "no_repeats", "validator", "own_words", "BOUNDS"]

#: The JSON Schema dialect of every schema.
DRAFT = "https://json-schema.org/draft/2020-12/schema"
#: The base of the schemas' ``$id`` (a name, not an address: the files are docs/schemas/<kind>.schema.json).
ID_BASE = "urn:cmmpose:schema:"
#: A machine's or an artefact's temperature, C: above absolute zero by far, within a physical band.
TEMPERATURE_C = (-50.0, 150.0)
#: |length or position|, mm (100 m: beyond the largest CMM's travel).
LENGTH_MM = 1e5
#: |angle|, degrees.
ANGLE_DEG = 360.0
#: The most items (balls, channels, files, effects, rows of a matrix) a list or table may hold.
MAX_ITEMS = 100_000
#: The longest id or name, characters.
MAX_NAME = 1_000
#: The range of an integer stored as a C long.
INT64 = (-(2**63), 2**63 - 1)
#: No control character (C0, DEL, C1): a name printed in a terminal cannot move the cursor or recolour it.
NO_CONTROL = "^[^\\u0000-\\u001F\\u007F-\\u009F]*$"
#: An id or a name: text without control characters.
TEXT = {"type": "string", "minLength": 1, "maxLength": MAX_NAME, "pattern": NO_CONTROL}


def number(lo: float, hi: float, unit: str, description: str = "", *, exclusive_lo: bool = False) -> dict:
    """A finite number within ``lo``..``hi`` (``exclusive_lo``: above ``lo``) in ``unit``."""
    out = {"type": "number", ("exclusiveMinimum" if exclusive_lo else "minimum"): lo, "maximum": hi}
    if unit:
        out["x-unit"] = unit
    if description:
        out["description"] = description
    return out


def nullable(schema: dict) -> dict:
    """``schema`` (a number's or a table's) or null."""
    return {**schema, "type": [schema["type"], "null"]}


def integer(lo: int, hi: int, description: str = "") -> dict:
    """A whole number within ``lo``..``hi`` (written as an integer, never 10.5 nor true)."""
    out = {"type": "integer", "minimum": lo, "maximum": hi}
    if description:
        out["description"] = description
    return out


def text(description: str = "", **more) -> dict:
    """A :data:`TEXT` (an id or a name) with a description."""
    return {**TEXT, **({"description": description} if description else {}), **more}


def triple(item: dict, description: str = "") -> dict:
    """Three ``item`` s ([x, y, z])."""
    return array(item, 3, 3, description)


def pair(item: dict, description: str = "") -> dict:
    """Two ``item`` s ([low, high])."""
    return array(item, 2, 2, description)


def array(item: dict, lo: int = 0, hi: int = MAX_ITEMS, description: str = "") -> dict:
    """A list of ``lo`` to ``hi`` ``item`` s."""
    out = {"type": "array", "items": item, "minItems": lo, "maxItems": hi}
    if description:
        out["description"] = description
    return out


def obj(properties: dict, required=(), *, closed: bool = True, description: str = "", **more) -> dict:
    """An object (a TOML table) with ``properties``; ``closed``: no other key."""
    out = {"type": "object", "properties": properties}
    if required:
        out["required"] = list(required)
    if closed:
        out["additionalProperties"] = False
    if description:
        out["description"] = description
    return {**out, **more}


def _is_number(checker, value) -> bool:
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        return False
    return isinstance(value, int) or math.isfinite(value)  # a 400-digit integer is finite (and too big for a float)


#: A finite number only: NaN and the infinities are not JSON numbers (TOML writes them, Python's JSON reads them).
_TYPES = Draft202012Validator.TYPE_CHECKER.redefine("number", _is_number)
_Validator = jsonschema.validators.extend(Draft202012Validator, type_checker=_TYPES)


def validator(schema: dict):
    """A validator of ``schema`` (checked once to be a draft 2020-12 schema)."""
    Draft202012Validator.check_schema(schema)
    return _Validator(schema)


def key_path(parts) -> str:
    """``effects[2].params.xy`` from the parts of a path in a document."""
    out = ""
    for p in parts:
        out += f"[{p}]" if isinstance(p, int) else (f".{p}" if out else str(p))
    return out


def short(value, limit: int = 40) -> str:
    """``value`` as a message shows it: a number in a sensible precision (a
    400-digit integer as "a 400-digit integer"), text escaped and cut, a list
    or a table by its size."""
    if isinstance(value, bool) or value is None:
        return json.dumps(value)
    if isinstance(value, int):
        size = abs(value)
        digits = int(size.bit_length() * 0.30102999566398120) + 1  # exact after the correction below
        if digits > 1 and 10 ** (digits - 1) > size:
            digits -= 1
        if digits <= 20:
            return str(value)
        return f"a {'negative ' if value < 0 else ''}{digits}-digit integer"
    if isinstance(value, float):
        return f"{value:.6g}"
    if isinstance(value, str):
        shown = value if len(value) <= limit else value[:limit] + "..."
        return repr(shown)  # control characters escaped
    if isinstance(value, (list, tuple)):
        return f"a list of {len(value)}"
    if isinstance(value, dict):
        return f"a table of {len(value)} key(s)"
    return type(value).__name__


def given(value) -> str:
    """``value`` as the document wrote it: Python's ``repr`` of a float, a boolean or (short) text, as
    :func:`short` shows anything else (a 400-digit integer is not printed back)."""
    return repr(value) if isinstance(value, (bool, float)) else short(value)


_TYPE_WORDS = {"number": "a number", "integer": "a whole number", "string": "text", "array": "a list",
               "object": "a table", "boolean": "true or false", "null": "null"}


def _num(x) -> str:
    return f"{x:g}" if isinstance(x, float) else short(x)


def _key(path: str) -> str:
    """A key path as a message shows it: as written, or quoted (escaped) when it holds an odd character."""
    return path if path.isprintable() and len(path) <= 200 else short(path, 60)


#: Validators whose message names the key itself (no "key: " before it).
_OWN_KEY = ("additionalProperties", "enum", "required")
#: The validators of a number's range.
BOUNDS = ("minimum", "maximum", "exclusiveMinimum", "exclusiveMaximum")


def _template(error) -> str | None:
    """The node's own words for this error: ``x-messages[validator]``, else ``x-template`` (any validator)."""
    schema = error.schema if isinstance(error.schema, dict) else {}
    return schema.get("x-messages", {}).get(error.validator) or schema.get("x-template")


def _templated(error, document) -> str:
    """The message of a node with its own words (:func:`_template`), a format string with the fields
    ``path`` (the key path), ``parent`` (its table's or list's), ``key`` (the last key), ``item`` (the
    item's name from ``x-item-names``), ``value`` (as shown), ``given`` (as written: Python's repr of a
    float, a boolean or text, the value as shown otherwise), ``name`` (the ``name`` of the nearest table
    above that has one) and, for a missing key, ``missing`` (its path), ``header`` (``[table]`` for a
    table) and ``hint`` (its description)."""
    name, node = None, document
    parts = list(error.absolute_path)
    for part in parts[:-1]:
        node = node[part]
        if isinstance(node, dict) and isinstance(node.get("name"), str):
            name = node["name"]
    key = parts[-1] if parts else ""
    names = error.schema.get("x-item-names", ())
    fields = {"path": _key(key_path(parts)), "parent": _key(key_path(parts[:-1])), "key": key,
              "item": names[key] if isinstance(key, int) and key < len(names) else key,
              "value": short(error.instance), "given": given(error.instance), "name": short(name), "missing": "",
              "header": "", "hint": ""}
    if error.validator == "required":
        missing = [k for k in error.validator_value if k not in error.instance][0]
        sub = error.schema.get("properties", {}).get(missing, {})
        fields["missing"] = _key(key_path([*parts, missing]))
        fields["header"] = f"[{fields['missing']}]" if sub.get("type") == "object" else fields["missing"]
        fields["hint"] = sub.get("description", "")
    return _template(error).format(**fields)


def own_words(schema: dict, words: str, validators=BOUNDS) -> dict:
    """``schema`` with ``words`` (a :func:`_templated` format) as its message when ``validators`` fail."""
    return {**schema, "x-messages": {**schema.get("x-messages", {}), **dict.fromkeys(validators, words)}}


def describe(error) -> str:
    """One line: what is wrong at the error's key (without the file and the key)."""
    v, schema, value = error.validator, error.schema, error.instance
    unit = f" {schema['x-unit']}" if schema.get("x-unit") else ""
    if v in ("minimum", "exclusiveMinimum"):
        sign = ">=" if v == "minimum" else ">"
        if schema.get("type") == "integer":
            return f"expected a whole number {sign} {_num(error.validator_value)}, got {short(value)}"
        return f"must be finite and {sign} {_num(error.validator_value)}{unit}, got {short(value)}"
    if v in ("maximum", "exclusiveMaximum"):
        word = "above the maximum" if v == "maximum" else "not below"
        return f"{short(value)} is {word} {_num(error.validator_value)}" + (f" ({unit.strip()})" if unit else "")
    if v == "type":
        want = error.validator_value
        want = " or ".join(_TYPE_WORDS.get(t, t) for t in ([want] if isinstance(want, str) else want))
        if isinstance(value, float) and not math.isfinite(value):
            want = want.replace("a number", "a finite number")
        return f"expected {want}, got {short(value)}"
    if v == "additionalProperties":
        known = sorted(schema.get("properties", {}))
        extra = sorted(k for k in value if k not in schema.get("properties", {}))
        return f"unknown key {_key(key_path([*error.absolute_path, extra[0]]))}" + \
            (f" (known: {', '.join(known)})" if known else "")
    if v == "required":
        missing = [k for k in error.validator_value if k not in value][0]
        hint = schema.get("properties", {}).get(missing, {}).get("description")
        return f"{_key(key_path([*error.absolute_path, missing]))}: missing" + (f" ({hint})" if hint else "")
    if v == "enum":
        what = schema.get("x-what")
        choices = ", ".join(map(short, error.validator_value))
        return f"{_key(key_path(error.absolute_path))} = {short(value)} is " + \
            (f"not a known {what} ({choices})" if what else f"not one of {choices}")
    if v == "const":
        return f"expected {short(error.validator_value)}, got {short(value)}"
    if v == "pattern":
        if error.validator_value == NO_CONTROL:
            return f"{short(value)} holds a control character"
        return f"{short(value)} does not match {error.validator_value}"
    if v in ("minItems", "maxItems"):
        word = "at least" if v == "minItems" else "at most"
        return f"expected {word} {error.validator_value} item(s), got {len(value)}"
    if v in ("minLength", "maxLength"):
        word = "at least" if v == "minLength" else "at most"
        return f"expected {word} {error.validator_value} character(s), got {len(value)}"
    if v in ("minProperties", "maxProperties"):
        word = "at least" if v == "minProperties" else "at most"
        return f"expected {word} {error.validator_value} key(s), got {len(value)}"
    return error.message if len(error.message) <= 200 else error.message[:200] + "..."


def _best(errors):
    """The error to report: the deepest in the document, of those the most specific rule (the longest schema
    path: an effect's own bound before the bound of any parameter), an unknown key before a missing one (it is
    most often the missing one misspelt, as the loaders say); ``oneOf``/``anyOf`` descended into."""
    def depth(e):
        return -len(e.absolute_path), -len(e.absolute_schema_path), e.validator != "additionalProperties"

    best = min(errors, key=depth, default=None)
    while best is not None and best.context:
        best = min(best.context, key=depth)
    return best


def check(document, schema_validator, path, *, error=InputError) -> None:
    """Refuse ``document`` unless it matches the schema of ``schema_validator``.

    Parameters
    ----------
    document : dict
        As parsed from the file (JSON or TOML).
    schema_validator : jsonschema validator
        Of the file kind's schema (:func:`validator`).
    path : str or path-like
        The file, first in the message.
    error : type of InputError
        The class raised.

    Raises
    ------
    InputError (or ``error``)
        One line: the file, the key path and what is wrong there; the fields
        ``file``, ``what`` (the key path), ``value`` (the value as shown),
        ``allowed`` (lo, hi) and ``unit`` of a number out of its range.
    """
    try:
        found = _best(schema_validator.iter_errors(document))
    except RecursionError:
        raise error(f"{path}: nested too deeply to check", file=str(path)) from None
    if found is None:
        return
    key = key_path(found.absolute_path)
    templated = _template(found) is not None
    detail = _templated(found, document) if templated else describe(found)
    allowed = unit = None
    if found.validator in BOUNDS:
        s = found.schema
        allowed = (s.get("minimum", s.get("exclusiveMinimum")), s.get("maximum", s.get("exclusiveMaximum")))
        unit = s.get("x-unit")
    own = templated or found.validator in _OWN_KEY
    prefix = f"{path}: {key}: " if key and not own else f"{path}: "
    raise error(prefix + detail, file=str(path), what=key or None, value=short(found.instance),
                allowed=allowed, unit=unit)


def _no_repeats(path, error):
    """An ``object_pairs_hook`` that refuses a key given twice in one object, naming it and the file."""
    def hook(pairs):
        out = {}
        for k, v in pairs:
            if k in out:
                raise error(f"{path}: the key {short(k)} is repeated in one object (a JSON file states each key "
                            "once; a reader would keep only the last)", file=str(path), what=k)
            out[k] = v
        return out
    return hook


#: The ``object_pairs_hook`` of a reader keeping its own JSON error words (``no_repeats(path, error)``).
no_repeats = _no_repeats


def _no_constant(name):
    raise ValueError(f"{name} is not allowed")


def loads_json(text: str, path, what: str, *, error=InputError, constants: bool = True):
    """The document of a JSON file's ``text``: a repeated key in an object,
    a file that is not JSON or is nested too deeply, an integer longer than
    Python converts, or (``constants`` False) a bare NaN or Infinity is
    ``error`` naming the file (and the key)."""
    options = {} if constants else {"parse_constant": _no_constant}
    try:
        return json.loads(text, object_pairs_hook=_no_repeats(path, error), **options)
    except json.JSONDecodeError as exc:
        raise error(f"{path}:{exc.lineno}:{exc.colno}: invalid JSON ({exc.msg}): not a readable {what}",
                    file=str(path)) from None
    except RecursionError:
        raise error(f"{path}: JSON nested too deeply to be a {what}", file=str(path)) from None
    except Error:  # a repeated key, already named
        raise
    except ValueError as exc:
        why = "an integer of more than 4,300 digits" if "digits" in str(exc) else str(exc)
        raise error(f"{path}: invalid JSON ({why}): not a readable {what}", file=str(path)) from None
