"""One registry mechanism (cmmpose._registry, issue 34 item 5) for effects, artefact kinds, point formats and map
formats: a second entry of a taken name is refused, an unknown name is answered with the valid ones, and callers
dispatch on what an entry declares, never on its name (a plan for a new artefact kind, a map format of one file per
axis through `cmmpose map import/export`)."""

from __future__ import annotations

import inspect
import json
from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np
import pytest
from click.testing import CliRunner

import cmmpose
from cmmpose import ErrorMap, ErrorMapSet, artefacts, effects
from cmmpose._registry import Registry, discover
from cmmpose.cli import main
from cmmpose.errors import InputError
from cmmpose.formats import mapformats, pointformats
from cmmpose.formats.linearaxis import linear_components

# -- the mechanism ----------------------------------------------------------------------------------------------


def test_a_registry_refuses_a_second_entry_of_a_name_and_lists_in_a_stable_order():
    reg = Registry("widget")
    a, b = object(), object()
    reg.register("b", a)
    reg.register("a", b)
    assert reg.register("b", a) is a  # the same entry again is not a second one
    with pytest.raises(ValueError, match="widget 'b' is registered already.*a second entry of the same name"):
        reg.register("b", b)
    assert reg.get("b") is a and reg.names() == ["b", "a"] and list(reg) == ["b", "a"]  # registration order
    assert "a" in reg and "c" not in reg and [] not in reg and len(reg) == 2
    with pytest.raises(KeyError, match="widget 'c': unknown; known: b, a"):
        reg.get("c")
    with pytest.raises(ValueError, match="non-empty"):
        reg.register("", object())
    ordered = Registry("widget", order=str)
    for name in ("b", "c", "a"):
        ordered.register(name, name)
    assert ordered.names() == ["a", "b", "c"] and ordered.as_dict() == {"a": "a", "b": "b", "c": "c"}


def test_built_in_entries_load_on_the_first_read_only():
    calls = []
    reg = Registry("widget", load=lambda: (calls.append(1), reg.register("builtin", 1)))
    reg.register("plug-in", 2)  # registering does not load
    assert calls == []
    assert reg.names() == ["plug-in", "builtin"] and calls == [1]
    reg.get("builtin")
    assert calls == [1]


def test_discovery_refuses_a_key_used_twice(tmp_path, monkeypatch):
    pkg = tmp_path / "registry_probe_pkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("class Base:\n    key = ''\n")
    (pkg / "one.py").write_text("from . import Base\nclass One(Base):\n    key = 'same'\n")
    (pkg / "two.py").write_text("from . import Base\nclass Two(Base):\n    key = 'same'\n")
    (pkg / "_private.py").write_text("raise RuntimeError('a private module is never imported')\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    import registry_probe_pkg as probe

    with pytest.raises(ValueError, match="probe 'same' is registered already"):
        discover(probe.__name__, probe.__path__, probe.Base, "key", "probe")


# -- each registry refuses a duplicate and names the valid names ------------------------------------------------


def test_effects_refuse_a_second_entry_of_a_name():
    @dataclass(frozen=True)
    class Impostor(effects.Effect):
        name: ClassVar[str] = "scale"

    with pytest.raises(ValueError, match="effect 'scale' is registered already"):
        effects.REGISTRY.register("scale", Impostor)
    assert effects.get("scale") is not Impostor
    with pytest.raises(InputError, match=r"effect 'warp': unknown; available: squareness, scale, roll"):
        effects.get("warp")


def test_artefact_kinds_refuse_a_second_entry_of_a_name():
    class Impostor(artefacts.ArtefactKind):
        kind = "ballbar"

    with pytest.raises(ValueError, match="artefact kind 'ballbar' is registered already"):
        artefacts.REGISTRY.register("ballbar", Impostor)
    assert artefacts.get("ballbar") is not Impostor
    with pytest.raises(InputError, match="artefact kind 'hoop': unknown; known: ball-plate, ballbar, sphere, "
                                         "step-gauge"):
        artefacts.get("hoop")


def test_point_formats_refuse_a_second_entry_of_a_name():
    csv = pointformats.get("csv")
    with pytest.raises(ValueError, match="point-file format 'csv' is registered already"):
        pointformats.register(pointformats.PointFormat("csv", (".txt",), csv.chunks, csv.writer))
    assert pointformats.get("csv") is csv and pointformats.for_path("a.txt", default="npy").name == "npy"
    assert pointformats.register(csv) is csv  # the same entry again is not a second one
    with pytest.raises(InputError, match="unknown point-file format 'las'; known: csv, e57, npy, parquet, ply"):
        pointformats.get("las")


def test_map_formats_refuse_a_second_entry_of_a_name():
    csv = mapformats.get("csv")
    with pytest.raises(ValueError, match="map file format 'csv' is registered already"):
        mapformats.register("csv", sniff=lambda path: True, read=csv.read)
    assert mapformats.get("csv") is csv
    with pytest.raises(ValueError, match="map file format 'linuxcnc' is registered already"):
        mapformats.register("linuxcnc", read=csv.read)
    with pytest.raises(InputError, match="unknown map file format 'xlsx' "
                                         r"\(known: 'csv', 'controller', 'iso230-2', 'linuxcnc'\)"):
        mapformats.get("xlsx")


@pytest.mark.parametrize("args, listed", [
    (["import", "xlsx", "m.csv", "-o", "out.csv"], "'csv', 'controller', 'iso230-2', 'linuxcnc'"),
    (["export", "appendix-b", "--format", "controller", "-o", "out.txt"], "'csv', 'iso230-2', 'linuxcnc'"),
])
def test_the_map_commands_list_the_formats_of_the_registry(tmp_path, args, listed):
    res = CliRunner().invoke(main, ["map", *args], terminal_width=250)
    assert res.exit_code == 2 and listed in res.output, res.output


# -- dispatch on what a plug-in declares ------------------------------------------------------------------------


def _with_kind(monkeypatch, cls) -> None:
    """The artefact kinds with ``cls`` registered too, for this test only."""
    reg = Registry(artefacts.REGISTRY.what, order=str, unknown=lambda kind, names: InputError(f"{kind}: {names}"))
    for name, entry in artefacts.REGISTRY.items():
        reg.register(name, entry)
    reg.register(cls.kind, cls)
    monkeypatch.setattr(artefacts, "REGISTRY", reg)


@pytest.mark.parametrize("spans, like", [("line", "thesis-ballbar"), ("plane", "koba-0420"), ("point", None)])
def test_a_plan_for_a_new_artefact_kind_follows_what_it_declares(monkeypatch, spans, like, machine):
    from cmmpose.diagnosis import plan as plan_module

    class Probe(artefacts.ArtefactKind):
        kind = "probe-kind"
        summary = "a kind only this test knows"
        example = "thesis-ballbar"

    Probe.spans = spans
    _with_kind(monkeypatch, Probe)
    template = artefacts.load_artefact(like or "thesis-ballbar")
    probe = replace(template, kind="probe-kind")
    assert artefacts.get("probe-kind") is Probe
    if like is None:
        with pytest.raises(InputError, match="one ball cannot separate"):
            plan_module.candidate_placements(probe, machine)
        return
    got = plan_module.candidate_placements(probe, machine)
    want = plan_module.candidate_placements(template, machine)
    assert [p.label for p in got] == [p.label for p in want] and len(got) > 10
    # plan.py names no artefact kind: it reads what the kind declares
    source = inspect.getsource(plan_module)
    assert not any(f'"{k}"' in source for k in artefacts.available())


# -- map formats through the registry, LinuxCNC included ---------------------------------------------------------


def _cli(*args):
    return CliRunner().invoke(main, [str(a) for a in args], terminal_width=250)


def _linear(m: ErrorMap) -> dict:
    return {k: v[1] for k, v in linear_components(m).items()}


@pytest.mark.parametrize("fmt", ["csv", "iso230-2", "linuxcnc"])
def test_a_map_goes_out_and_back_in_each_written_format(tmp_path, fmt):
    original = ErrorMapSet.thesis().at(20.0)
    out = tmp_path / ("lc" if fmt == "linuxcnc" else "m.out")
    r = _cli("map", "export", "thesis@20", "--format", fmt, "-o", out, "--json")
    assert r.exit_code == 0, r.output
    written = json.loads(r.stdout)["output"]
    entry = mapformats.get(fmt)
    if entry.per_axis:  # one file per axis, named as the format declares
        assert written == [str(out / n) for n in ("x.comp", "y.comp", "z.comp")]
        files = [f"{a}={p}" for a, p in zip("XYZ", written)]
    else:
        assert written == str(out)
        files = [written]
    r = _cli("map", "import", fmt, *files, "-o", tmp_path / "back.csv")
    assert r.exit_code == 0, r.output
    back = ErrorMap.read(tmp_path / "back.csv")
    if fmt == "csv":  # the canonical file carries the whole map
        assert back == ErrorMap.read(out)
        for axis in "XYZ":
            np.testing.assert_allclose(back.table(axis), original.table(axis), atol=5e-4, rtol=0)
    for axis, dev in _linear(original).items():
        np.testing.assert_allclose(_linear(back)[axis], dev, atol=5e-4, rtol=0)
    # the library reads the same through the registry: a per-axis format from its folder or from AXIS -> file
    if entry.per_axis:
        assert mapformats.read(out, fmt) == mapformats.read(dict(zip("XYZ", written)), fmt) == back
    else:
        assert ErrorMap.read(out, format=fmt) == back


def test_a_controller_file_imports_through_the_registry(tmp_path):
    r = _cli("map", "import", "controller", cmmpose.data_path("errors_1102.txt"), "-o", tmp_path / "b.csv",
             "--temperature", "22")
    assert r.exit_code == 0, r.output
    back, want = ErrorMap.read(tmp_path / "b.csv"), ErrorMap.appendix_b()
    assert back.temperature == 22.0
    for axis in "XYZ":
        np.testing.assert_allclose(back.table(axis), want.table(axis), atol=5e-4, rtol=0)
    # an option that shapes the map and that the format's reader does not take is refused, not ignored
    r = _cli("map", "import", "controller", cmmpose.data_path("errors_1102.txt"), "-o", tmp_path / "c.csv",
             "--base", "appendix-b")
    assert r.exit_code == 2 and "--base: not an option of controller" in r.output, r.output
    assert not (tmp_path / "c.csv").exists()


def test_a_new_per_axis_map_format_goes_through_the_commands(tmp_path, monkeypatch):
    """A format that declares one file per axis is exported into a folder and imported from AXIS=FILE pairs, by
    its declaration: the commands name no format."""
    from cmmpose.formats.linuxcnc import read_comp_files, write_comp_files

    reg = Registry("map file format",
                   unknown=lambda name, known: InputError(f"unknown map file format {name!r} ({known})"))
    for name, entry in mapformats.REGISTRY.items():
        reg.register(name, entry)
    monkeypatch.setattr(mapformats, "REGISTRY", reg)
    seen = []

    def read(files, *, base=None, temperature=None, hold_ends=False):
        seen.append(("read", sorted(files)))
        return read_comp_files(files, base=base, temperature=temperature, hold_ends=hold_ends)

    def write(error_map, files):
        seen.append(("write", sorted(files)))
        write_comp_files(error_map, files)

    mapformats.register("axis-tables", read=read, write=write, per_axis="table-{axis}.txt", description="a test's")
    r = _cli("map", "export", "thesis@20", "--format", "axis-tables", "-o", tmp_path / "t")
    assert r.exit_code == 0, r.output
    assert sorted(p.name for p in (tmp_path / "t").iterdir()) == ["table-x.txt", "table-y.txt", "table-z.txt"]
    r = _cli("map", "import", "axis-tables", f"X={tmp_path / 't' / 'table-x.txt'}", "-o", tmp_path / "m.csv",
             "--temperature", "20")
    assert r.exit_code == 0, r.output
    assert seen == [("write", ["X", "Y", "Z"]), ("read", ["X"])]
    back = ErrorMap.read(tmp_path / "m.csv")
    np.testing.assert_allclose(_linear(back)["X"], _linear(ErrorMapSet.thesis().at(20.0))["X"], atol=5e-4, rtol=0)
    r = _cli("map", "import", "axis-tables", str(tmp_path / "t" / "table-x.txt"), "-o", tmp_path / "n.csv")
    assert r.exit_code == 2 and "expected AXIS=FILE" in r.output, r.output


def test_no_module_names_a_map_or_point_format_to_dispatch_on_it():
    from cmmpose.cli import map as map_cli

    source = inspect.getsource(map_cli)
    for name in mapformats.names():
        assert f'fmt == "{name}"' not in source and f"fmt == '{name}'" not in source
