"""Issue 35, one door in: one schema per document kind (cmmpose.schemas), every bundled file valid under it,
a broken document of each kind refused naming the file and the key, the published schemas equal to the
definitions, and property tests: documents generated from each schema pass, and the same documents with a
number pushed beyond its bound or a required key removed are refused with InputError (never another type)."""

from __future__ import annotations

import json
import math
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import cmmpose
from cmmpose import artefacts, schemas
from cmmpose.errormap import data_path
from cmmpose.errors import Error, InputError, RunError, RunFileError
from cmmpose.machine import example_names, example_text, load_machine
from cmmpose.model import Model
from cmmpose.run import Run
from cmmpose.schemas._common import NO_CONTROL, key_path, short
from repo import REPO

ROOT = REPO
DOCS_SCHEMAS = ROOT / "docs" / "schemas"


def _refused(kind, doc, path="doc.json", error=InputError) -> str:
    with pytest.raises(error) as info:
        schemas.validate(doc, kind, path)
    return str(info.value)


# -- every bundled document is valid ---------------------------------------------------------------------------

@pytest.mark.parametrize("name", example_names())
def test_every_bundled_machine_file_validates_and_loads(name):
    path = data_path("machines", f"{name}.toml")
    schemas.validate(tomllib.loads(path.read_text(encoding="utf-8")), "machine", path)
    assert load_machine(path).kinematics


@pytest.mark.parametrize("name", artefacts.example_names())
def test_every_bundled_artefact_file_validates_and_loads(name):
    path = data_path("artefacts", f"{name}.toml")
    schemas.validate(tomllib.loads(path.read_text(encoding="utf-8")), "artefact", path)
    assert artefacts.load_artefact(path).n_balls >= 1


def _toml_blocks(text: str) -> list[str]:
    return re.findall(r"```toml\n(.*?)```", text, flags=re.S)


def test_the_documented_examples_validate():
    """The TOML examples of the docs that are whole documents (an artefact file in docs/artefacts.md)."""
    found = 0
    for page in sorted((ROOT / "docs").glob("*.md")):
        for block in _toml_blocks(page.read_text(encoding="utf-8")):
            doc = tomllib.loads(block)
            kind = "artefact" if "balls" in doc else "machine" if "kinematics" in doc else None
            if kind:
                schemas.validate(doc, kind, f"{page.name} example")
                found += 1
    assert found >= 1


def _full_model(tmp_path) -> Path:
    """A saved model with every optional part: uncertainty (one undetermined), domain, alternative,
    covariance, a map correction and a temperature policy."""
    from cmmpose.model.alternatives import Alternative
    from cmmpose.model.domain import Domain
    from cmmpose.model.names import resolve

    model = Model(cmmpose.ErrorMapSet.thesis()).with_values("squareness", [1.0, -2.0, 3.0]) \
        .with_values("scale", [5.0, 0.0, -5.0]).with_values("map:dy(X):poly[0,900]", [0.5, -0.25])
    alt = Alternative("scale", resolve("roll"), np.array([1.0, 2.0, 3.0]), 0.4, "the data cannot tell them apart")
    model = model.__class__(model.maps, model.effects, 21.5, uncertainty={"squareness": np.array([0.1, np.inf, 0.3])},
                            alternatives=(alt,), domain=Domain("thesis", ((90.0, 90.0, 0.0),),
                                                               ((0.0, 900.0), (0.0, 550.0), (-500.0, 0.0)),
                                                               (20.0, 25.0), ("b89",), 2),
                            covariance={"parameters": ["squareness.xy", "scale.x"],
                                        "matrix": [[0.01, 0.001], [0.001, 0.04]]})
    return model.save(tmp_path / "full.json")


def test_a_saved_model_with_every_part_validates_and_loads_back(tmp_path):
    path = _full_model(tmp_path)
    doc = json.loads(path.read_text())
    assert {"domain", "alternatives", "covariance", "non_finite", "temperature_policy"} <= set(doc)
    schemas.validate(doc, "model", path)
    back = Model.load(path)
    assert back.names == ("squareness", "scale", "map:dy(X):poly[0,900]") and back.temperature == 21.5


def test_a_saved_run_validates_and_one_with_an_embedded_artefact_too(tmp_path, simulated_run):
    simulated_run.save(tmp_path / "r")
    doc = json.loads((tmp_path / "r" / "run.json").read_text())
    schemas.validate(doc, "run", tmp_path / "r" / "run.json")
    doc["artefact"]["definition"] = artefacts.load_artefact("koba-0320").to_dict()
    schemas.validate(doc, "run", "run.json")
    assert Run.load(tmp_path / "r") == simulated_run


# -- the published schemas ----------------------------------------------------------------------------------------

@pytest.mark.parametrize("kind", list(schemas.KINDS))
def test_the_published_schema_is_what_the_definitions_give(kind):
    """docs/schemas/<kind>.schema.json never drifts: regenerate with ``python -m cmmpose.schemas``."""
    assert (DOCS_SCHEMAS / f"{kind}.schema.json").read_text(encoding="utf-8") == schemas.schema_text(kind)
    assert json.loads(schemas.schema_text(kind))["$schema"] == "https://json-schema.org/draft/2020-12/schema"


def test_the_schemas_are_written_atomically_where_asked(tmp_path):
    from cmmpose.schemas.__main__ import main

    assert main([str(tmp_path / "out")]) == 0
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == sorted(f"{k}.schema.json" for k in schemas.KINDS)
    assert (tmp_path / "out" / "model.schema.json").read_text() == schemas.schema_text("model")


def test_every_library_effect_unit_has_its_bound():
    """A new effect's unit must be given a range in UNIT_BOUNDS (else it would only have a user effect's)."""
    from cmmpose.effects import available
    from cmmpose.schemas.model import UNIT_BOUNDS

    units = {p.unit for effect in available().values() for p in effect.params.values()}
    assert units and units <= set(UNIT_BOUNDS), units - set(UNIT_BOUNDS)


def test_an_unknown_kind_names_the_known_ones():
    with pytest.raises(InputError, match="not one of model, machine, artefact, run, alignments, plan"):
        schemas.validate({}, "recipe", "p.json")


# -- one broken document per kind names the file and the key ------------------------------------------------------

def _model_doc() -> dict:
    return Model(cmmpose.ErrorMapSet.thesis()).with_values("squareness", [1.0, 2.0, 3.0]).to_dict()


@pytest.mark.parametrize("edit, words", [
    (lambda d: d["effects"][0]["params"].update(xy=1e30),
     r"m\.json: effects\[0\]\.params\.xy: 1e\+30 is above the maximum 3600 \(arc-second\)$"),
    (lambda d: d["effects"][0]["params"].update(yz=-10**400),
     r"effects\[0\]\.params\.yz: must be finite and >= -3600 arc-second, got a negative 401-digit integer$"),
    (lambda d: d.update(temperature=-300.0), r"m\.json: temperature: must be finite and >= -50 C, got -300$"),
    (lambda d: d.update(temperature="twenty"), r"temperature: expected a number or null, got 'twenty'"),
    (lambda d: d.update(temperture=20.0), r"m\.json: unknown key temperture \(known: "),
    (lambda d: d["effects"][0].update(name="squ\x1b[2Jareness"), r"effects\[0\]\.name: .*holds a control character"),
    (lambda d: d.update(out_of_range="ignore"), r"out_of_range = 'ignore' is not one of 'raise', 'clamp'"),
    (lambda d: d.pop("effects"), r"m\.json: effects: missing"),
])
def test_a_broken_model_file_names_the_file_and_the_key(tmp_path, edit, words):
    doc = _model_doc()
    edit(doc)
    path = tmp_path / "m.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(InputError, match=words) as info:
        Model.load(path)
    assert info.value.file == str(path) and "\n" not in str(info.value) and len(str(info.value)) < 400


def test_a_repeated_key_in_a_model_file_is_refused_naming_it(tmp_path):
    text = json.dumps(_model_doc())
    path = tmp_path / "m.json"
    path.write_text(text.replace('"temperature": null', '"temperature": 20.0, "temperature": null'))
    with pytest.raises(InputError, match=r"m\.json: the key 'temperature' is repeated in one object"):
        Model.load(path)
    path.write_text(text.replace('"kind": "kernel"', '"kind": "kernel", "kind": "python"'))
    with pytest.raises(InputError, match="the key 'kind' is repeated"):
        Model.load(path)


def _machine_text() -> str:
    return example_text("moving-bridge")


@pytest.mark.parametrize("edit, words", [
    (lambda t: t.replace("noise_um = 8.0", "noise_um = 1e30"), r"scanner\.noise_um: 1e\+30 is above the maximum 10000"),
    (lambda t: t.replace("noise_um = 8.0", "noise_um = nan"), r"scanner\.noise_um: expected a finite number, got nan"),
    (lambda t: t.replace("noise_um = 8.0", "noise_um = 1" + "0" * 399), "a 400-digit integer is above the maximum"),
    (lambda t: t.replace("profile_rate_hz = 6.6", 'profile_rate_hz = "6.6"'), r"profile_rate_hz: expected a number"),
    (lambda t: t.replace("points_per_profile = 1024", "points_per_profile = 99999999999"),
     r"points_per_profile: 99999999999 is above the maximum 1000000"),
    (lambda t: t.replace('GB = "granite_bottom"', '"G\\u001b" = "granite_bottom"'), r"thermocouples: 'G\\x1b' holds"),
    (lambda t: t.replace("noise_um = 8.0", "noise_um = 8.0\nnoise_um = 9.0"), r"not a TOML file \(Cannot overwrite"),
    (lambda t: t.replace("noise_um = 8.0", "noise_um = 8.0\nnoise = 1"), r"unknown key scanner\.noise \(known:"),
])
def test_a_broken_machine_file_names_the_file_and_the_key(tmp_path, edit, words):
    path = tmp_path / "m.toml"
    path.write_text(edit(_machine_text()), encoding="utf-8")
    with pytest.raises(InputError, match=words) as info:
        load_machine(path)
    assert str(info.value).startswith(f"{path}: ") and "\n" not in str(info.value)


def _artefact_text() -> str:
    return data_path("artefacts", "koba-0320.toml").read_text(encoding="utf-8")


@pytest.mark.parametrize("edit, words", [
    (lambda t: t.replace("reference_temperature_C = 20.0", "reference_temperature_C = -300.0"),
     r"reference_temperature_C = -300 is outside 0\.\.40 C"),
    (lambda t: t.replace("{ id = 2,", "{ id = 99999999999999999999,"),
     r"balls\[1\]\.id: 99999999999999999999 is above the maximum 9223372036854775807"),
    (lambda t: t.replace("[59.9996, 0.0000, -0.0008]", "[5e9, 0.0000, -0.0008]"),
     r"balls\[1\]\.xyz_mm\[0\]: 5e\+09 is above the maximum 100000 \(mm\)"),
    (lambda t: t.replace('name = "KOBA', 'name = "\\u001b[31mKOBA'), r"a.toml: name: '\\x1b\[31mKOBA.*holds a control character"),
    (lambda t: t.replace('kind = "ball-plate"', 'kind = "ball-plate"\nkind = "ballbar"'), "Cannot overwrite"),
    (lambda t: t.replace("{ id = 2,", "{ mass = 1, id = 2,"), r"unknown key balls\[1\]\.mass"),
])
def test_a_broken_artefact_file_names_the_file_and_the_key(tmp_path, edit, words):
    path = tmp_path / "a.toml"
    path.write_text(edit(_artefact_text()), encoding="utf-8")
    with pytest.raises(InputError, match=words) as info:
        artefacts.load_artefact(path)
    assert str(info.value).startswith(f"{path}: ")


def test_an_artefact_of_too_many_balls_is_refused_before_any_work():
    doc = tomllib.loads(_artefact_text())
    doc["balls"] = [{"id": i + 1, "xyz_mm": [float(i), 0.0, 0.0], "u_um": [0.4, 0.4, 0.6]} for i in range(30_000)]
    with pytest.raises(InputError, match=r"big\.toml: balls: expected at most 1000 item\(s\), got 30000"):
        artefacts.parse_artefact(doc, "big.toml")


@pytest.mark.parametrize("edit, words", [
    (lambda d: d["rows"].update(points=-1), r"run\.json: 'rows' must be an object .*: rows\.points is -1$"),
    (lambda d: d["rows"].update(points=2**63), r"rows\.points is 9223372036854775808$"),
    (lambda d: d["rows"].update(point=1), r"run\.json: 'rows' names an unknown table 'point'"),
    (lambda d: d["temperature_channels"][0].update(name="X\x1b"), r"temperature_channels\[0\]\.name: .*control"),
    (lambda d: d["artefact"].update(calibrated_length_mm=1e30), r"artefact\.calibrated_length_mm: 1e\+30 is above"),
    (lambda d: d["maps"].update(kinematics="cantilever"), r"maps\.kinematics = 'cantilever' is not one of"),
    (lambda d: d["metadata"].update(x=[1e300]), r"metadata\.x\[0\]: 1e\+300 is above the maximum 1e\+15"),
])
def test_a_broken_run_json_names_the_file_and_the_key(tmp_path, simulated_run, edit, words):
    simulated_run.save(tmp_path / "r")
    path = tmp_path / "r" / "run.json"
    doc = json.loads(path.read_text())
    edit(doc)
    path.write_text(json.dumps(doc))
    with pytest.raises(RunFileError, match=words) as info:
        Run.load(tmp_path / "r")
    assert isinstance(info.value, InputError) and isinstance(info.value, RunError)


def test_a_repeated_key_in_run_json_is_refused(tmp_path, simulated_run):
    simulated_run.save(tmp_path / "r")
    path = tmp_path / "r" / "run.json"
    path.write_text(path.read_text().replace('"metadata":', '"maps": {}, "metadata":', 1))
    with pytest.raises(RunError, match=r"run\.json: the key 'maps' is repeated"):
        Run.load(tmp_path / "r")


def test_short_shows_a_long_number_as_its_size():
    assert short(10**399) == "a 400-digit integer" and short(1e-320) == "9.99989e-321"
    assert short(12) == "12" and short("a\x1bb") == "'a\\x1bb'" and short("x" * 100).endswith("...'")
    assert key_path(["effects", 2, "params", "xy"]) == "effects[2].params.xy"


# -- property tests: documents generated from each schema ---------------------------------------------------------
# A strategy of our own, built from the schema: hypothesis-jsonschema (0.23.1, its latest) fails inside current
# hypothesis ("'many' object has no attribute 'more'"), and the subset of JSON Schema the cmmpose schemas use is
# small (types, const, enum, properties, additionalProperties, items, ranges, lengths, $ref, allOf of if/then).

_TEXT = st.text(st.characters(blacklist_categories=("Cc", "Cs")), min_size=1, max_size=8)
_MAX_DEPTH = 3


def _resolve(node: dict, root: dict) -> dict:
    while "$ref" in node:
        node = root["$defs"][node["$ref"].rsplit("/", 1)[1]]
    return node


def _number(node: dict):
    lo = node.get("minimum", node.get("exclusiveMinimum", -1e300))
    hi = node.get("maximum", 1e300)
    floats = st.floats(lo, hi, exclude_min="exclusiveMinimum" in node, allow_nan=False, allow_infinity=False)
    if node.get("type") == "integer" or (isinstance(node.get("type"), list) and "integer" in node["type"]):
        return st.integers(math.ceil(lo), math.floor(hi))
    ints = st.integers(math.ceil(lo) + ("exclusiveMinimum" in node and lo == math.ceil(lo)), math.floor(hi))
    return floats | ints if hi - lo >= 1 else floats


def _object(node: dict, root: dict, depth: int):
    props = node.get("properties", {})
    required = set(node.get("required", ()))
    fixed = {k: strategy(v, root, depth + 1) for k, v in props.items() if k in required}
    optional = {k: strategy(v, root, depth + 1) for k, v in props.items() if k not in required}
    base = st.fixed_dictionaries(fixed, optional=optional)
    extra = node.get("additionalProperties", True)
    if extra is False or extra is True or depth >= _MAX_DEPTH:
        out = base
    else:
        names = node.get("propertyNames", {})
        keys = st.sampled_from(names["enum"]) if "enum" in names else _TEXT
        more = st.dictionaries(keys.filter(lambda k: k not in props), strategy(extra, root, depth + 1),
                               min_size=node.get("minProperties", 0), max_size=max(node.get("minProperties", 0), 3))
        out = st.tuples(base, more).map(lambda pair: {**pair[1], **pair[0]})
    if "allOf" in node:  # the effects' own bounds (if/then on the name): keep the documents they allow
        check = schemas._common.validator({**node, "$defs": root.get("$defs", {})})
        out = out.filter(check.is_valid)
    return out


def strategy(node: dict, root: dict, depth: int = 0):
    """Documents valid under ``node`` (the subset of JSON Schema the cmmpose schemas use)."""
    node = _resolve(node, root)
    if "const" in node:
        return st.just(node["const"])
    if "enum" in node:
        return st.sampled_from(node["enum"])
    types = node["type"] if isinstance(node["type"], list) else [node["type"]]
    if depth >= _MAX_DEPTH:  # a record nests no deeper
        types = [t for t in types if t not in ("object", "array")] or types
    options = []
    for t in types:
        if t == "null":
            options.append(st.none())
        elif t == "boolean":
            options.append(st.booleans())
        elif t in ("number", "integer"):
            options.append(_number({**node, "type": t}))
        elif t == "string":
            assert node.get("pattern", NO_CONTROL) == NO_CONTROL
            lo = node.get("minLength", 0)
            options.append(st.text(st.characters(blacklist_categories=("Cc", "Cs")), min_size=lo, max_size=lo + 8))
        elif t == "array":
            lo = node.get("minItems", 0)
            options.append(st.lists(strategy(node.get("items", {"type": "null"}), root, depth + 1), min_size=lo,
                                    max_size=min(node.get("maxItems", lo + 3), lo + 3)))
        elif t == "object":
            options.append(_object(node, root, depth))
    return st.one_of(options)


def _leaves(doc, node: dict, root: dict, path=()):
    """(path, schema) of every value of ``doc`` with the schema that types it (through properties, items,
    additionalProperties, $ref)."""
    node = _resolve(node, root)
    yield path, node, doc
    if isinstance(doc, dict):
        for k, v in doc.items():
            sub = node.get("properties", {}).get(k, node.get("additionalProperties"))
            if isinstance(sub, dict):
                yield from _leaves(v, sub, root, (*path, k))
    elif isinstance(doc, list) and isinstance(node.get("items"), dict):
        for i, v in enumerate(doc):
            yield from _leaves(v, node["items"], root, (*path, i))


def _set(doc, path, value):
    for p in path[:-1]:
        doc = doc[p]
    doc[path[-1]] = value


_PROPERTY = settings(max_examples=40, deadline=None, derandomize=True,
                     suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much,
                                            HealthCheck.data_too_large])


@pytest.mark.parametrize("kind", list(schemas.KINDS))
def test_documents_generated_from_the_schema_pass(kind):
    root = schemas.schema(kind)

    @_PROPERTY
    @given(strategy(root, root))
    def check(doc):
        schemas.validate(doc, kind, f"{kind}.doc")

    check()


@pytest.mark.parametrize("kind", list(schemas.KINDS))
def test_a_number_beyond_its_bound_or_a_missing_key_is_refused_naming_it(kind):
    root = schemas.schema(kind)

    @_PROPERTY
    @given(strategy(root, root), st.data())
    def check(doc, data):
        bounded = [(p, n) for p, n, v in _leaves(doc, root, root) if p and "maximum" in n
                   and isinstance(v, (int, float)) and not isinstance(v, bool)]
        needed = [(p, n) for p, n, v in _leaves(doc, root, root) if isinstance(v, dict) and n.get("required")]
        if bounded:
            path, node = data.draw(st.sampled_from(bounded))
            broken = json.loads(json.dumps(doc))
            big = data.draw(st.sampled_from([node["maximum"] * 2 + 1, 1e30, 10**400, math.inf]))
            _set(broken, path, big)
            message = _refused(kind, broken, f"{kind}.doc")
            assert message.startswith(f"{kind}.doc: ") and "\n" not in message and len(message) < 600
            assert key_path(path[:-1]) in message
            assert isinstance(path[-1], int) or path[-1] in message
        if needed:
            path, node = data.draw(st.sampled_from(needed))
            broken = json.loads(json.dumps(doc))
            target = broken
            for p in path:
                target = target[p]
            key = data.draw(st.sampled_from(sorted(node["required"])))
            del target[key]
            message = _refused(kind, broken, f"{kind}.doc")
            assert key in message and "missing" in message

    check()


def _toml(value) -> str:
    """A TOML value (inline) of a generated document."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value) if isinstance(value, int) or math.isfinite(value) else ("inf" if value > 0 else "-inf")
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)
    if isinstance(value, list):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    return "{" + ", ".join(f"{_toml(k)} = {_toml(v)}" for k, v in value.items()) + "}"


@pytest.mark.parametrize("kind", ["machine", "artefact"])
def test_a_generated_toml_file_loads_or_is_refused_with_a_cmmpose_error(tmp_path, kind):
    """The loader behind the schema: a valid generated file loads or is an Error naming the file (a travel's
    ends swapped, balls too close, a map file that does not exist); a broken one is an InputError."""
    root = schemas.schema(kind)
    load = load_machine if kind == "machine" else artefacts.load_artefact
    path = tmp_path / f"g.{kind}.toml"

    @_PROPERTY
    @given(strategy(root, root), st.booleans())
    def check(doc, break_it):
        if break_it:
            doc = {**doc, "reference_temperature_C" if kind == "artefact" else "expansion": -1e300}
        path.write_text("\n".join(f"{_toml(k)} = {_toml(v)}" for k, v in doc.items()) + "\n", encoding="utf-8")
        try:
            load(path)
        except Error as exc:
            assert str(path) in str(exc)
            if break_it:
                assert isinstance(exc, InputError)
        else:
            assert not break_it

    check()


def test_a_generated_model_file_loads_or_is_refused_with_a_cmmpose_error(tmp_path):
    root = schemas.schema("model")
    path = tmp_path / "g.json"

    @_PROPERTY
    @given(strategy(root, root), st.sampled_from([None, "temperature", "effects"]))
    def check(doc, broken):
        if broken == "temperature":
            doc = {**doc, "temperature": -273.16}
        elif broken == "effects":
            doc = {**doc, "effects": [{"name": "squareness", "params": {"xy": 1e30, "yz": 0.0, "zx": 0.0}}]}
        path.write_text(json.dumps(doc))
        with pytest.raises(Error) as info:  # random map CSV text is never a map: refused, never a traceback
            Model.load(path)
        assert str(path) in str(info.value) or "maps.csv" in str(info.value)
        if broken:
            assert isinstance(info.value, InputError) and broken in str(info.value)

    check()


# -- the alignment library and the acquisition plan (issue 35, item 1) --------------------------------------------

def _library(tmp_path):
    from cmmpose.calibration import AlignmentLibrary, AlignmentRecord

    lib = AlignmentLibrary(tmp_path / "lib.json")
    lib.save("A90B90", AlignmentRecord(pose=(90.0, 90.0, 0.0), reading=(450.0, 275.0, -250.0),
                                       offset=(1.001, 264.505, 129.575), reading_uncertainty=(0.001,) * 3,
                                       pose_covariance=[[1e-4, 0, 0], [0, 1e-4, 0], [0, 0, 1e-4]],
                                       temperature=20.5, residuals={"sphere_rms": 0.004}, note="bench"))
    return lib


def test_a_saved_alignment_library_validates_and_loads(tmp_path):
    lib = _library(tmp_path)
    schemas.validate(json.loads(lib.path.read_text()), "alignments", lib.path)
    assert lib.load("A90B90").temperature == 20.5


@pytest.mark.parametrize("edit, words", [
    (lambda d: d["poses"]["A90B90"].update(temperature=1e6), r"lib\.json: poses\.A90B90\.temperature: 1e\+06 is above"),
    (lambda d: d["poses"]["A90B90"].update(pose=[900.0, 90.0, 0.0]), r"poses\.A90B90\.pose\[0\]: 900 is above the "
                                                                       r"maximum 360 \(degree\)"),
    (lambda d: d["poses"]["A90B90"].update(offset=[1e30, 0.0, 0.0]), r"poses\.A90B90\.offset\[0\]: 1e\+30 is above"),
    (lambda d: d["poses"]["A90B90"]["residuals"].update(sphere_rms=1e12), r"residuals\.sphere_rms: 1e\+12 is above"),
    (lambda d: d["poses"].update({"A\x1b[2J": d["poses"]["A90B90"]}), r"poses: 'A\\x1b\[2J' holds a control"),
])
def test_a_broken_alignment_library_is_refused_naming_the_file_and_the_key(tmp_path, edit, words):
    from cmmpose.errors import CalibrationError

    lib = _library(tmp_path)
    doc = json.loads(lib.path.read_text())
    edit(doc)
    lib.path.write_text(json.dumps(doc))
    with pytest.raises(CalibrationError, match=words) as info:
        lib.load("A90B90")
    assert str(lib.path) in str(info.value) and "\n" not in str(info.value)


def test_a_repeated_key_in_an_alignment_library_is_refused_and_the_file_left_alone(tmp_path):
    from cmmpose.calibration import mount_offset  # noqa: F401 - the package imports
    from cmmpose.errors import CalibrationError

    lib = _library(tmp_path)
    text = lib.path.read_text().replace('"temperature": 20.5', '"temperature": 20.5, "temperature": 99.0', 1)
    lib.path.write_text(text)
    with pytest.raises(CalibrationError, match=r"lib\.json: the key 'temperature' is repeated"):
        lib.load("A90B90")
    with pytest.raises(CalibrationError, match="repeated"):
        lib.save("B", lib_record())
    assert lib.path.read_text() == text


def lib_record():
    from cmmpose.calibration import AlignmentRecord

    return AlignmentRecord(pose=(0.0, 0.0, 0.0), reading=(1.0, 2.0, 3.0), offset=(0.0, 0.0, 0.0))


def _plan_doc():
    from cmmpose.acquire.plan import artefact_plan

    return artefact_plan("koba-0320", ["xy"]).to_dict()


def test_typical_plans_validate(tmp_path, simulated_run):
    from cmmpose.acquire.plan import Plan, plan_from_run

    for doc in (_plan_doc(), plan_from_run(simulated_run).to_dict(), {}):
        schemas.validate(json.loads(json.dumps(doc)), "plan", "p.json")
        (tmp_path / "p.json").write_text(json.dumps(doc))
        Plan.read(tmp_path / "p.json")


@pytest.mark.parametrize("edit, words", [
    (lambda d: d["scans"][0].update(sweep_speed=1e30), r"p\.json: scans\[0\]\.sweep_speed: 1e\+30 is above"),
    (lambda d: d["poses"][0].update(alpha=1e9), r"p\.json: poses\[0\]\.alpha: 1e\+09 is above the maximum 360"),
    (lambda d: d["scans"][0].update(scan_id=2**31), r"scans\[0\]: scan_id = 2147483648 is not an integer that fits"),
    (lambda d: d["scans"][0].update(ball=10**400), r"scans\[0\]: ball = .* is not an integer that fits its int32"),
    (lambda d: d["metadata"].update(x=[1e300]), r"p\.json: metadata\.x\[0\]: 1e\+300 is above the maximum 1e\+15"),
    (lambda d: d.update(temperature_channels=[{"name": "X\x1b[2J", "role": "x_scale"}]),
     r"temperature_channels\[0\]\.name: 'X\\x1b\[2J' holds a control character"),
    (lambda d: d["artefact"].update(calibrated_radius_mm="11"), r"artefact\.calibrated_radius_mm: expected a number"),
])
def test_a_broken_plan_is_refused_naming_the_file_and_the_key(tmp_path, edit, words):
    from cmmpose.acquire.plan import Plan
    from cmmpose.errors import AcquisitionError

    doc = _plan_doc()
    edit(doc)
    path = tmp_path / "p.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(AcquisitionError, match=words) as info:
        Plan.read(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value) and "0" * 40 not in str(info.value)


def test_a_repeated_key_in_a_plan_and_a_fifo_as_a_plan_are_refused(tmp_path):
    import os

    from cmmpose.acquire.plan import Plan
    from cmmpose.errors import AcquisitionError

    path = tmp_path / "p.json"
    path.write_text(json.dumps(_plan_doc()).replace('"scans":', '"scans": [], "scans":', 1))
    with pytest.raises(AcquisitionError, match=r"p\.json: the key 'scans' is repeated"):
        Plan.read(path)
    os.mkfifo(tmp_path / "fifo.json")
    with pytest.raises(AcquisitionError, match="not a regular file but a FIFO"):
        Plan.read(tmp_path / "fifo.json")
