"""The registry of error-map file formats (cmmpose.formats.mapformats): the formats it
lists, dispatch by name and by sniffing, errors naming an unknown format, and
no import cycle between errormap, mapfiles and controller."""

import ast
import os
import subprocess
import sys
from pathlib import Path

import pytest

import cmmpose
from cmmpose import ErrorMap
from cmmpose.formats import mapformats

PACKAGE = Path(cmmpose.__file__).parent
THESIS_20C = cmmpose.data_path("maps", "thesis_20C.csv")
APPENDIX_B = cmmpose.data_path("errors_1102.txt")


def test_registry_lists_the_formats():
    assert mapformats.names() == ["csv", "controller", "iso230-2", "linuxcnc"]
    assert mapformats.get("csv").write is not None
    assert mapformats.get("controller").write is None  # read only
    assert mapformats.get("iso230-2").write is not None
    assert mapformats.get("linuxcnc").write is not None
    # one file per axis is what the format declares, not what its name says
    assert [n for n in mapformats.names() if mapformats.get(n).per_axis] == ["linuxcnc"]
    assert all(mapformats.get(n).description for n in mapformats.names())


@pytest.mark.parametrize("name", ["xlsx", "CSV", ""])
def test_unknown_format_name_is_named_in_the_error(tmp_path, name):
    with pytest.raises(cmmpose.InputError, match=f"unknown map file format {name!r}.*'csv', 'controller'"):
        ErrorMap.read(THESIS_20C, format=name)
    with pytest.raises(cmmpose.InputError, match=f"unknown map file format {name!r}"):
        ErrorMap.appendix_b().write(tmp_path / "m.csv", format=name)


def test_read_only_format_cannot_be_written(tmp_path):
    with pytest.raises(cmmpose.InputError, match="'controller' can be read but not written"):
        ErrorMap.appendix_b().write(tmp_path / "m.txt", format="controller")


def test_dispatch_by_name_and_by_sniffing(tmp_path):
    assert mapformats.detect(THESIS_20C) == "csv"
    assert mapformats.detect(APPENDIX_B) == "controller"
    assert ErrorMap.read(THESIS_20C, format="auto") == ErrorMap.read(THESIS_20C)
    assert ErrorMap.read(APPENDIX_B, format="controller", temperature=22.0) == ErrorMap.appendix_b()
    assert ErrorMap.read(APPENDIX_B, format="auto", temperature=22.0) == ErrorMap.appendix_b()
    other = tmp_path / "other.txt"
    other.write_text("neither format\n", encoding="utf-8")
    assert mapformats.detect(other) is None
    assert mapformats.detect(tmp_path / "missing.csv") is None
    with pytest.raises(cmmpose.MapError, match="not an error-map file of a known format"):
        ErrorMap.read(other, format="auto")


@pytest.mark.parametrize("module", ["cmmpose.formats.controller", "cmmpose.formats.mapfiles", "cmmpose.errormap", "cmmpose.formats.mapformats"])
def test_each_module_imports_alone(module):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(PACKAGE.parent), os.environ.get("PYTHONPATH", "")]))
    code = f"import {module}; from cmmpose.formats import mapformats; print(','.join(mapformats.names()))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "csv,controller,iso230-2,linuxcnc"


def imported_modules(name):
    """Every cmmpose module (dotted, under the package) that module ``name`` imports, at module level or inside
    functions, resolved from its relative imports."""
    path = PACKAGE / (name.replace(".", "/") + ".py")
    here = name.split(".")[:-1]
    tree = ast.parse(path.read_text(encoding="utf-8"))
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.level >= 1:
            base = here[:len(here) - (node.level - 1)]
            if node.module:
                found.add(".".join([*base, *node.module.split(".")]))
            else:
                found.update(".".join([*base, a.name]) for a in node.names)
    return found


def test_no_import_cycle_between_errormap_and_the_format_modules():
    formats = {f"formats.{m}" for m in ("mapfiles", "controller", "iso230", "linuxcnc", "linearaxis")}
    assert not imported_modules("errormap") & formats
    assert imported_modules("formats.mapformats") == {"errors", "_registry"}
    for fmt in ("mapfiles", "controller", "iso230", "linuxcnc"):
        assert {"errormap", "formats.mapformats"} <= imported_modules(f"formats.{fmt}")


def test_threads_reading_maps_at_once_in_a_fresh_process_all_see_the_formats():
    # The built-in formats load on first use; threads arriving together (a Dask scheduler's workers evaluating
    # several runs) each got "unknown map file format 'csv' (known: none)" while the first was still loading them.
    code = """
import threading, cmmpose
errors, start = [], threading.Barrier(8)
def load():
    start.wait()
    try:
        cmmpose.ErrorMapSet.thesis()
    except Exception as exc:
        errors.append(repr(exc))
threads = [threading.Thread(target=load) for _ in range(8)]
[t.start() for t in threads]
[t.join() for t in threads]
print(errors)
"""
    for _ in range(3):
        out = subprocess.run([sys.executable, "-W", "ignore", "-c", code], capture_output=True, text=True, timeout=120)
        assert out.returncode == 0 and out.stdout.strip() == "[]", (out.stdout, out.stderr)
