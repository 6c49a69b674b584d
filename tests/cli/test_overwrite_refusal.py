"""Issue 35, item 2 ("one door out"), for every command that writes a file: an existing output is refused
before any work (exit status 1, one line naming the file and saying ``use --overwrite to replace it``; the
file, its modification time and everything else left as they were, and nothing loaded or computed),
``--overwrite`` replaces it, and an output that is one of the command's inputs (here through a symbolic link)
is refused even with ``--overwrite``."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner

import cmmpose
import cmmpose.diagnosis
import cmmpose.machine
import cmmpose.run
from cmmpose import atomicfile
from cmmpose.calibration import interferometer
from cmmpose.cli import main
from child_processes import ENV
from child_processes import one_error_line as refused
from cmmpose.formats import mapformats
from cmmpose.standards import iso230_2

INTERFEROMETER = Path(cmmpose.data_path("examples", "interferometer"))
#: The modification time given to every earlier output (s since the epoch): a refusal leaves it.
EARLIER_MTIME = 1_000_000_000


def cli(*args):
    return CliRunner().invoke(main, [str(a) for a in args])




def earlier(path: Path) -> Path:
    """An earlier output at ``path``: its text and an old modification time, to be left as they are."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("earlier\n")
    os.utime(path, (EARLIER_MTIME, EARLIER_MTIME))
    return path


def unchanged(path: Path) -> bool:
    return path.read_text() == "earlier\n" and path.stat().st_mtime == EARLIER_MTIME


def listing(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """What the commands read: a ballbar run with calibrated values (B89 layout), a point file, an ISO 230-2
    table and a map file."""
    root = tmp_path_factory.mktemp("inputs")
    assert cli("simulate", "-o", root / "run", "--calibrated", "--jitter", "3", "--seed", "2").exit_code == 0
    (root / "a.csv").write_text("u,v,D,E,F,T\n0,0,450,275,-250,22\n1,-1,451,275,-250,22\n")
    assert cli("map", "export", "thesis@20", "--format", "iso230-2", "-o", root / "linear.csv").exit_code == 0
    cmmpose.ErrorMapSet.thesis().at(20).write(root / "map.csv")
    (root / "scan.xyz").write_text("0 0 0\n")
    (root / "pairs.csv").write_text("a,b,reference_mm\nS1,S2,100\n")
    return root


def _work(*args, **kwargs):
    raise AssertionError("work started before the output was checked")


@pytest.fixture
def no_work(monkeypatch):
    """Loading a machine, a run, a map or a table, reading an interferometer run, or diagnosing fails the test:
    a refusal must come before any of it."""
    from cmmpose.cli import map as map_cli

    work = _work
    monkeypatch.setattr(cmmpose.diagnosis, "diagnose", work)
    monkeypatch.setattr(cmmpose.machine, "load_machine", work)
    monkeypatch.setattr(cmmpose.run.Run, "load", work)
    monkeypatch.setattr(map_cli, "load_maps", work)
    monkeypatch.setattr(map_cli, "_map_spec", work)
    monkeypatch.setattr(mapformats, "read", work)
    monkeypatch.setattr(interferometer, "read_run", work)
    monkeypatch.setattr(iso230_2, "load_positioning", work)
    return monkeypatch


def _cases(root: Path, out: Path) -> dict:
    """Each command: its arguments, writing the output under ``out``, and the file refused (named)."""
    run = root / "run"
    acceptance = ["standards", "acceptance", run, "--mpe-form", "1000", "--mpe-size", "1000", "--mpe-length", "1000"]
    return {
        "compensate": (["compensate", root / "a.csv", out / "x.csv", "--maps", "thesis"], out / "x.csv"),
        "compensate parquet": (["compensate", root / "a.csv", out / "x.parquet", "--maps", "thesis"],
                               out / "x.parquet"),
        "evaluate --report": (["evaluate", run, "--report", out / "R"], out / "R" / "evaluation.json"),
        "evaluate --report (a budget)": (["evaluate", run, "--report", out / "R"], out / "R" / "uncertainty.md"),
        "diagnose --save-model": (["diagnose", run, "--save-model", out / "m.json", "--no-auto"], out / "m.json"),
        "diagnose --report": (["diagnose", run, "--report", out / "D", "--no-auto"], out / "D" / "diagnose.html"),
        "diagnose --corrected-maps": (["diagnose", run, "--corrected-maps", out / "cm.csv", "--no-auto"],
                                      out / "cm_25C.csv"),
        "diagnose --user-effect-skeleton": (["diagnose", run, "--user-effect-skeleton", out / "u.py", "--no-auto"],
                                            out / "u.py"),
        "map plot": (["map", "plot", "thesis", "-o", out / "p.png"], out / "p.png"),
        "map import": (["map", "import", "iso230-2", root / "linear.csv", "-o", out / "i.csv"], out / "i.csv"),
        "map export": (["map", "export", "thesis@20", "--format", "iso230-2", "-o", out / "e.csv"], out / "e.csv"),
        "map export linuxcnc": (["map", "export", "thesis@20", "--format", "linuxcnc", "-o", out / "comp"],
                                out / "comp" / "y.comp"),
        "map table-motion": (["map", "table-motion", root / "map.csv", "-o", out / "t.csv", "--carriage", "Y",
                              "--measured-at", "0,0,0", "--part-point", "300,100,50"], out / "t.csv"),
        "calibrate map": (["calibrate", "map", *sorted(INTERFEROMETER.glob("*.csv")), "--squareness",
                           "-173,-19,21", "-o", out / "c.csv"], out / "c.csv"),
        "calibrate map --plot": (["calibrate", "map", *sorted(INTERFEROMETER.glob("*.csv")), "--squareness",
                                  "-173,-19,21", "-o", out / "c2.csv", "--compare", "thesis@20", "--plot",
                                  out / "d.png"], out / "d.png"),
        "calibrate simulate-alignment": (["calibrate", "simulate-alignment", "--pose", "90,90,0", "--name", "A",
                                          "-o", out / "al"], out / "al" / "A-truth.json"),
        "iso230-2 --plot": (["standards", "iso230-2", INTERFEROMETER / "x_dx.csv", "--plot", out / "x.png"],
                            out / "x.png"),
        "iso230-2 --report": (["standards", "iso230-2", INTERFEROMETER / "x_dx.csv", "--report", out / "S"],
                              out / "S" / "iso230-2.md"),
        "acceptance --report": ([*acceptance, "--report", out / "A"], out / "A" / "acceptance.json"),
        "acceptance --plot": ([*acceptance, "--plot", out / "a.png"], out / "a.png"),
        "interim-check --report": (["standards", "interim-check", run, "--report", out / "I"],
                                   out / "I" / "interim-check.json"),
        "e3125-distances --plot": (["standards", "e3125-distances", f"S1={root / 'scan.xyz'}",
                                    f"S2={root / 'scan.xyz'}", "--pairs", root / "pairs.csv", "--radius", "50",
                                    "--plot", out / "e.png"], out / "e.png"),
        "artefact plan": (["artefact", "plan", "koba-0320", "-o", out / "plan.json"], out / "plan.json"),
        "demo --report": (["demo", "--report", out / "demo"], out / "demo" / "lengths.csv"),
    }


CASES = list(_cases(Path("."), Path(".")))
#: The commands whose --overwrite run is left to the refusal test: one that needs real scans, one the run gives
#: nothing to write (no unexplained structure: no skeleton), or one as slow as another case of the same code.
NOT_RUN = {"e3125-distances --plot", "diagnose --user-effect-skeleton", "evaluate --report (a budget)",
           "calibrate map --plot"}
#: The outputs whose names come from the maps (their temperatures): checked once the maps are read, before the
#: diagnosis.
NAMED_BY_THE_MAPS = {"diagnose --corrected-maps"}


@pytest.mark.parametrize("case", CASES)
def test_an_existing_output_is_refused_before_any_work(inputs, tmp_path, no_work, case):
    args, target = _cases(inputs, tmp_path / "out")[case]
    if case in NAMED_BY_THE_MAPS:  # the names come from the maps' temperatures: the run and maps are read first
        no_work.undo()
        no_work.setattr(cmmpose.diagnosis, "diagnose", _work)
    earlier(target)
    before = listing(tmp_path)
    line = refused(cli(*args), str(target), "exists", "use --overwrite to replace it")
    assert line.count("\n") == 0
    assert unchanged(target)
    assert listing(tmp_path) == before  # nothing else written either, and no temporary file left


@pytest.mark.parametrize("case", [c for c in CASES if c not in NOT_RUN])
def test_overwrite_replaces_it(inputs, tmp_path, case):
    args, target = _cases(inputs, tmp_path / "out")[case]
    earlier(target)
    r = cli(*args, "--overwrite")
    assert r.exit_code == 0, r.output
    assert target.read_bytes() != b"earlier\n"
    assert not [p for p in (tmp_path / "out").rglob(".cmmpose-*")]


def _input_cases(root: Path, link: Path) -> dict:
    """Each command with an output that is one of its inputs through the symbolic link ``link``, and the input
    named in the refusal."""
    run = root / "run"
    return {
        "compensate": (["compensate", root / "a.csv", link, "--maps", "thesis"], root / "a.csv"),
        "compensate (a --maps file)": (["compensate", root / "a.csv", link, "--maps", root / "map.csv"],
                                       root / "map.csv"),
        "diagnose --save-model": (["diagnose", run, "--save-model", link, "--no-auto"], run / "run.json"),
        "map import": (["map", "import", "iso230-2", root / "linear.csv", "-o", link], root / "linear.csv"),
        "map export": (["map", "export", root / "map.csv", "--format", "iso230-2", "-o", link], root / "map.csv"),
        "map table-motion": (["map", "table-motion", root / "map.csv", "-o", link, "--carriage", "Y",
                              "--measured-at", "0,0,0", "--part-point", "300,100,50"], root / "map.csv"),
        "map plot": (["map", "plot", root / "map.csv", "-o", link], root / "map.csv"),
        "iso230-2 --plot": (["standards", "iso230-2", root / "linear.csv", "--plot", link], root / "linear.csv"),
        "calibrate map": (["calibrate", "map", *sorted(INTERFEROMETER.glob("*.csv")), "--squareness", "-173,-19,21",
                           "-o", link, "--compare", root / "map.csv"], root / "map.csv"),
    }


@pytest.mark.parametrize("case", list(_input_cases(Path("."), Path("."))))
def test_an_output_naming_an_input_is_refused_even_with_overwrite(inputs, tmp_path, no_work, case):
    link = tmp_path / "link"
    args, named = _input_cases(inputs, link)[case]
    link.symlink_to(named)
    before = named.read_bytes()
    refused(cli(*args, "--overwrite"), "same file as the input", str(named))
    assert named.read_bytes() == before


def test_a_report_file_naming_a_run_file_is_refused_even_with_overwrite(inputs, tmp_path, no_work):
    report = tmp_path / "R"
    report.mkdir()
    (report / "evaluation.json").symlink_to(inputs / "run" / "run.json")
    before = (inputs / "run" / "run.json").read_bytes()
    refused(cli("evaluate", inputs / "run", "--report", report, "--overwrite"), "same file as the input", "run.json")
    assert (inputs / "run" / "run.json").read_bytes() == before


def test_a_derived_name_naming_an_input_is_refused_even_with_overwrite(inputs, tmp_path, no_work):
    """--corrected-maps cm.csv writes cm_20C.csv ... beside it: one of those through a link to an input map."""
    no_work.undo()  # the starting model's maps name the derived files: read first
    no_work.setattr(cmmpose.diagnosis, "diagnose", _work)
    maps = tmp_path / "maps"
    maps.mkdir()
    for m in cmmpose.ErrorMapSet.thesis().maps:
        m.write(maps / f"cm_{m.temperature:g}C.csv")
    before = {p.name: p.read_bytes() for p in maps.iterdir()}
    out = tmp_path / "out"
    out.mkdir()
    (out / "cm_25C.csv").symlink_to(maps / "cm_25C.csv")
    r = cli("diagnose", inputs / "run", *[a for p in sorted(maps.iterdir()) for a in ("--maps", p)],
            "--corrected-maps", out / "cm.csv", "--overwrite", "--no-auto")
    refused(r, "same file as the input", "cm_25C.csv")
    assert {p.name: p.read_bytes() for p in maps.iterdir()} == before
    assert sorted(p.name for p in out.iterdir()) == ["cm_25C.csv"]


def test_a_file_made_by_another_writer_meanwhile_is_never_replaced(inputs, tmp_path, monkeypatch):
    """The check before any work passed; another writer makes the file while this one works: this one fails
    naming it, and the other's file stays."""
    target = tmp_path / "x.csv"
    real = atomicfile.files._put_in_place

    def meanwhile(tmp, dst, overwrite, what="output"):
        Path(dst).write_text("the other writer's\n")
        return real(tmp, dst, overwrite, what)

    monkeypatch.setattr(atomicfile.files, "_put_in_place", meanwhile)
    refused(cli("compensate", inputs / "a.csv", target, "--maps", "thesis"), str(target), "another writer",
            "--overwrite")
    assert target.read_text() == "the other writer's\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.csv"]


def test_two_compensations_of_one_output_started_together(inputs, tmp_path):
    target = tmp_path / "x.csv"
    procs = [subprocess.Popen([sys.executable, "-m", "cmmpose.cli", "compensate", str(inputs / "a.csv"), str(target),
                               "--maps", "thesis", "--temperature", str(t)], env=ENV, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True)
             for t in (21, 23)]
    codes = [p.wait(timeout=120) for p in procs]
    assert sorted(codes) == [0, 1], codes
    loser = procs[codes.index(1)].communicate()[1]
    assert str(target) in loser and "--overwrite" in loser and "Traceback" not in loser
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.csv"]


def test_a_diagnosis_writes_all_its_outputs_or_none(inputs, tmp_path):
    """Without --overwrite, one existing output (the report) stops the model and the maps too: before any work,
    and none of them is written."""
    earlier(tmp_path / "D" / "diagnose.html")
    r = cli("diagnose", inputs / "run", "--save-model", tmp_path / "m.json", "--corrected-maps", tmp_path / "cm.csv",
            "--report", tmp_path / "D", "--no-auto")
    refused(r, "diagnose.html", "use --overwrite to replace it")
    assert listing(tmp_path) == ["D", "D/diagnose.html"]


def test_a_dataset_folder_refuses_an_existing_output_file(inputs, tmp_path, no_work):
    """compensate DATASET_DIR OUT_DIR: each file OUT_DIR would get (named after its input) is checked before
    any work; the other files in OUT_DIR do not matter."""
    pq = pytest.importorskip("pyarrow.parquet")
    import pyarrow as pa

    (tmp_path / "ds").mkdir()
    table = pa.table({"u": [0.0], "v": [0.0], "D": [450.0], "E": [275.0], "F": [-250.0]})
    for name in ("a.parquet", "b.parquet"):
        pq.write_table(table, tmp_path / "ds" / name)
    earlier(tmp_path / "out" / "b.parquet")
    earlier(tmp_path / "out" / "notes.txt")
    refused(cli("compensate", tmp_path / "ds", tmp_path / "out", "--maps", "appendix-b"),
            str(tmp_path / "out" / "b.parquet"), "use --overwrite to replace it")
    assert unchanged(tmp_path / "out" / "b.parquet") and sorted(p.name for p in (tmp_path / "out").iterdir()) == [
        "b.parquet", "notes.txt"]
