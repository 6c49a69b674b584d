"""The type stubs match the extension module, and the CLI works end to end."""

import ast
import inspect
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import cmmpose
from cmmpose import _core
from cmmpose.cli import main

STUB = Path(cmmpose.__file__).with_name("_core.pyi")
EXAMPLE = Path(cmmpose.data_path("examples", "sphere_scan.csv"))


def stub_names():
    tree = ast.parse(STUB.read_text())
    top, members = set(), {}
    for node in tree.body:
        if isinstance(node, (ast.FunctionDef, ast.ClassDef)):
            top.add(node.name)
        if isinstance(node, ast.AnnAssign):
            top.add(node.target.id)
        if isinstance(node, ast.ClassDef):
            members[node.name] = {n.name for n in node.body if isinstance(n, ast.FunctionDef)}
    return top, members


def typed_dicts() -> set[str]:
    """Stub-only names: the TypedDicts describing dicts the module returns."""
    tree = ast.parse(STUB.read_text())
    return {n.name for n in tree.body if isinstance(n, ast.ClassDef)
            and any(getattr(b, "id", None) == "TypedDict" for b in n.bases)}


def test_stubs_cover_the_module_and_nothing_more():
    top, members = stub_names()
    typed = typed_dicts()
    public = {n for n in dir(_core) if not n.startswith("_")} | {"__version__"}
    assert public <= top, public - top
    assert {n for n in top if not n.startswith("_")} - typed <= public
    for cls in ("ErrorMap", "ErrorMapSet", "Digitizer"):
        real = {n for n in dir(getattr(_core, cls)) if not n.startswith("_")}
        assert real == members[cls] - {"__new__", "__eq__"}, (cls, real ^ (members[cls] - {"__new__", "__eq__"}))
    assert Path(cmmpose.__file__).with_name("py.typed").is_file()


def test_stub_function_signatures_match():
    tree = ast.parse(STUB.read_text())
    for node in tree.body:
        if isinstance(node, ast.FunctionDef) and not node.name.startswith("_"):
            sig = inspect.signature(getattr(_core, node.name))
            assert [a.arg for a in node.args.args + node.args.kwonlyargs] == list(sig.parameters), node.name


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


def test_cli_compensate_csv_matches_python(tmp_path):
    out = tmp_path / "out.csv"
    r = run("compensate", EXAMPLE, out, "--maps", "thesis", "--pose", "90,90,0", "--offset", "1.001,264.505,129.575")
    assert r.exit_code == 0, r.output
    got = np.loadtxt(out, delimiter=",", skiprows=1)
    raw = np.loadtxt(EXAMPLE, delimiter=",", skiprows=1)
    want = cmmpose.compensate(raw[:, :2], raw[:, 2:5], cmmpose.ErrorMapSet.thesis(), (90, 90, 0),
                              cmmpose.MountOffset.thesis(), raw[:, 5])
    assert got.shape == want.shape
    assert np.abs(got - want).max() <= 5e-7  # 6 decimals written
    assert "3,904" in r.output and "per point" in r.output


def test_cli_npy_and_scalar_temperature(tmp_path):
    raw = np.loadtxt(EXAMPLE, delimiter=",", skiprows=1)
    src = tmp_path / "in.npy"
    np.save(src, raw[:, :5])
    out = tmp_path / "out.npy"
    r = run("compensate", src, out, "--maps", "thesis", "--temperature", "22.5")
    assert r.exit_code == 0, r.output
    want = cmmpose.compensate(raw[:, :2], raw[:, 2:5], cmmpose.ErrorMapSet.thesis(), (90, 90, 0),
                              cmmpose.MountOffset.thesis(), 22.5)
    np.testing.assert_array_equal(np.load(out), want)


def test_cli_single_map_files(tmp_path):
    m = cmmpose.ErrorMap.appendix_b()
    path = tmp_path / "map.csv"
    m.write(path)
    out1, out2 = tmp_path / "a.npy", tmp_path / "b.npy"
    assert run("compensate", EXAMPLE, out1, "--maps", path).exit_code == 0
    assert run("compensate", EXAMPLE, out2, "--maps", "appendix-b").exit_code == 0
    np.testing.assert_array_equal(np.load(out1), np.load(out2))


@pytest.mark.parametrize(
    "args, fragment",
    [
        (["--temperature", "35"], "outside the maps' range [20, 30]"),
        (["--pose", "90,90"], "three comma-separated numbers"),
        (["--maps", "nope.csv"], "nope.csv"),
    ],
)
def test_cli_errors_are_clear(tmp_path, args, fragment):
    r = CliRunner().invoke(main, ["compensate", str(EXAMPLE), str(tmp_path / "o.csv"), *args])
    assert r.exit_code != 0
    assert fragment in r.output


def test_cli_bad_input_file(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("u,v,D,E,F\n1,2,3,4,5\n1,2,x,4,5\n")
    r = CliRunner().invoke(main, ["compensate", str(bad), str(tmp_path / "o.csv"), "--maps", "appendix-b"])
    assert r.exit_code != 0 and "bad.csv:3: value 'x' in column 3 is not a number" in r.output
    missing = tmp_path / "m.csv"
    missing.write_text("u,v,D,E\n1,2,3,4\n")
    r = CliRunner().invoke(main, ["compensate", str(missing), str(tmp_path / "o.csv"), "--maps", "appendix-b"])
    assert r.exit_code != 0 and "missing ['F']" in r.output
    r = CliRunner().invoke(main, ["compensate", str(tmp_path / "none.csv"), str(tmp_path / "o.csv")])
    assert r.exit_code != 0 and "no such file" in r.output


def test_cli_ragged_csv_row(tmp_path):
    bad = tmp_path / "ragged.csv"
    bad.write_text("u,v,D,E,F\n1,2,3,4,5\n1,2,3,4\n")
    r = CliRunner().invoke(main, ["compensate", str(bad), str(tmp_path / "o.csv"), "--maps", "appendix-b"])
    assert r.exit_code != 0 and "ragged.csv:3: expected 5 fields like the header, got 4" in r.output


def test_cli_simulate_writes_a_loadable_run(tmp_path):
    out = tmp_path / "run"
    r = run("simulate", "--layout", "crossed", "--temperature", "22.5", "--effect", "latency:seconds=0.004",
            "--effect", "scale:x=3", "--seed", "2", "-o", out)
    assert r.exit_code == 0, r.output
    loaded = cmmpose.Run.load(out)
    # 16 ball scans and, by default, 6 repeated (the run's own noise floor)
    assert len(loaded.scans["scan_id"]) == 16 + 6 and loaded.n_points > 10_000
    assert loaded.metadata["repeat_scans"] == 6
    _, info = cmmpose.load_truth(out)
    assert [e["name"] for e in info["effects"]] == ["latency", "scale"]
    again = CliRunner().invoke(main, ["simulate", "--layout", "crossed", "-o", str(out)])
    assert again.exit_code != 0  # refuses to overwrite without --overwrite


@pytest.mark.parametrize("effect, fragment", [("warp:x=1", "unknown"), ("latency:ms=3", "not one of")])
def test_cli_simulate_bad_effect(tmp_path, effect, fragment):
    r = CliRunner().invoke(main, ["simulate", "--effect", effect, "-o", str(tmp_path / "r")])
    assert r.exit_code != 0 and fragment in r.output


def test_cli_demo_and_evaluate(tmp_path):
    report = tmp_path / "demo"
    r = run("demo", "--report", report, "--seed", "3", "--jitter", "0")  # the compensation's own floor
    assert r.exit_code == 0, r.output
    assert "rms accuracy error" in r.output and "improvement" in r.output
    for name in ("evaluation.json", "lengths.csv", "ballbar_lengths.png", "error_map.png", "run/run.json"):
        assert (report / name).is_file(), name
    import json

    d = json.loads((report / "evaluation.json").read_text())
    unc, comp = d["results"]
    assert 0.060 < unc["rms_accuracy_error_mm"] < 0.080 and comp["rms_accuracy_error_mm"] < 0.001
    # evaluate the saved run again, maps from run.json, as JSON
    r = run("evaluate", report / "run", "--json", "--temperature", "22.5")
    assert r.exit_code == 0, r.output
    again = json.loads(r.output)
    assert again["results"][1]["rms_accuracy_error_mm"] == pytest.approx(comp["rms_accuracy_error_mm"], abs=2e-4)
    r = run("evaluate", report / "run", "--maps", "none", "--report", tmp_path / "rep2")
    assert r.exit_code == 0 and (tmp_path / "rep2" / "ballbar_lengths.png").is_file()


def test_cli_evaluate_errors(tmp_path):
    r = CliRunner().invoke(main, ["evaluate", str(tmp_path)])
    assert r.exit_code != 0 and "run.json" in r.output
