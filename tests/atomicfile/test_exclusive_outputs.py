"""Issue 35, item 2: one door out. Every output is created exclusively (of two
writers of one name exactly one succeeds; an existing target is refused
without --overwrite, before any work), written beside its target under a
short temporary name and renamed; a group of files (a run, a map set) appears
whole or not at all; every derived name is checked against every input,
through links. Tests run as root, so a full disk is simulated by making the
system calls fail."""

from __future__ import annotations

import errno
import os
import subprocess
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner

import cmmpose
from cmmpose import atomicfile
from cmmpose.atomicfile import AtomicFile, FileGroup, write_text
from cmmpose.cli import main
from child_processes import ENV
from child_processes import one_error_line as one_line_failure
from cmmpose.errors import InputError, OutputError
from cmmpose.run import Run



def cli(*args):
    return CliRunner().invoke(main, [str(a) for a in args])




def scratch(folder: Path) -> list[str]:
    """Names in ``folder`` that a writer left behind (temporary files, stages)."""
    return sorted(p.name for p in folder.iterdir() if p.name.startswith(".") or p.name.endswith(".tmp"))


def fail_the_third_rename(monkeypatch) -> None:
    """The third file put in place fails (EIO): a group's first two are in place by then."""
    real, calls = atomicfile.files._put_in_place, []

    def put(tmp, dst, *a):
        calls.append(dst)
        if len(calls) == 3:
            raise OSError(errno.EIO, os.strerror(errno.EIO))
        return real(tmp, dst, *a)
    monkeypatch.setattr(atomicfile.files, "_put_in_place", put)


# -- one file: exclusive creation ---------------------------------------------------------


def test_two_writers_of_one_file_never_both_succeed(tmp_path):
    target = tmp_path / "x.txt"
    a = AtomicFile(target, "w", overwrite=False)
    b = AtomicFile(target, "w", overwrite=False)  # both started before either finished
    a.f.write("a\n")
    b.f.write("b\n")
    a.commit()
    with pytest.raises(OutputError, match="another writer created it"):
        b.commit()
    assert target.read_text() == "a\n"
    assert scratch(tmp_path) == []


def test_without_overwrite_an_existing_file_is_refused_at_once(tmp_path):
    target = tmp_path / "x.txt"
    target.write_text("mine\n")
    with pytest.raises(OutputError, match="exists"):
        AtomicFile(target, "w", overwrite=False)
    with pytest.raises(OutputError, match="exists"):
        atomicfile.check_output(target, overwrite=False)
    write_text(target, "new\n")  # the library's default replaces
    assert target.read_text() == "new\n"
    assert scratch(tmp_path) == []


def test_exclusive_creation_where_the_file_system_has_no_hard_links(tmp_path, monkeypatch):
    def no_links(*a, **k):
        raise OSError(errno.EPERM, os.strerror(errno.EPERM))
    monkeypatch.setattr(os, "link", no_links)
    target = tmp_path / "x.txt"
    a = AtomicFile(target, "w", overwrite=False)
    b = AtomicFile(target, "w", overwrite=False)
    a.f.write("a\n")
    b.f.write("b\n")
    a.commit()
    with pytest.raises(OutputError, match="another writer"):
        b.commit()
    assert target.read_text() == "a\n"
    assert scratch(tmp_path) == []


@pytest.mark.parametrize("command", [("machine", "example", "thesis"), ("artefact", "example", "ballbar")])
def test_example_files_are_created_exclusively(tmp_path, monkeypatch, command):
    """Another writer makes the file while this one works: this one fails, the other's file stays."""
    target = tmp_path / "x.toml"
    real = atomicfile.files._put_in_place

    def meanwhile(tmp, dst, overwrite, what="output"):
        Path(dst).write_text("the other writer's\n")
        return real(tmp, dst, overwrite, what)

    monkeypatch.setattr(atomicfile.files, "_put_in_place", meanwhile)
    one_line_failure(cli(*command, "-o", target), str(target), "another writer", "--overwrite")
    assert target.read_text() == "the other writer's\n"
    assert scratch(tmp_path) == []
    monkeypatch.undo()
    one_line_failure(cli(*command, "-o", target), str(target), "exists", "--overwrite")
    assert cli(*command, "-o", target, "--overwrite").exit_code == 0
    assert target.read_text() != "the other writer's\n"


def test_two_example_commands_started_together(tmp_path):
    target = tmp_path / "a.toml"
    procs = [subprocess.Popen([sys.executable, "-m", "cmmpose.cli", "artefact", "example", kind, "-o", str(target)],
                              env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for kind in ("ballbar", "sphere")]
    codes = [p.wait(timeout=120) for p in procs]
    assert sorted(codes) == [0, 1], codes
    loser = procs[codes.index(1)].communicate()[1]
    assert str(target) in loser and "Traceback" not in loser
    assert scratch(tmp_path) == []


# -- short temporary names ----------------------------------------------------------------


def test_a_name_as_long_as_the_file_system_allows(tmp_path):
    name = "a" * 250 + ".csv"  # 254 characters: legal (255 is the usual limit)
    write_text(tmp_path / name, "x\n")
    assert (tmp_path / name).read_text() == "x\n"
    em = cmmpose.ErrorMap.appendix_b()
    em.write(tmp_path / name)  # replaced through a temporary file beside it
    assert scratch(tmp_path) == []


def test_a_run_folder_named_as_long_as_allowed(tmp_path):
    run_dir = tmp_path / ("r" * 254)
    assert cli("simulate", "-o", run_dir, "--seed", "1").exit_code == 0
    assert cli("simulate", "-o", run_dir, "--seed", "2", "--overwrite").exit_code == 0
    Run.load(run_dir)
    assert scratch(tmp_path) == []


# -- run folders --------------------------------------------------------------------------


def test_simulate_refuses_a_full_folder_before_any_work(tmp_path, monkeypatch):
    import cmmpose.sim

    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "notes.txt").write_text("mine\n")

    def never(*a, **k):
        raise AssertionError("simulated before checking the output")
    monkeypatch.setattr(cmmpose.sim, "simulate_ballbar_run", never)
    one_line_failure(cli("simulate", "-o", tmp_path / "run"), "not empty", "--overwrite")


def test_a_run_filled_by_another_writer_meanwhile_is_never_mixed(tmp_path, monkeypatch):
    run_dir = tmp_path / "run"
    real = Run._write_files

    def meanwhile(self, stage, final, *a):
        final.mkdir(exist_ok=True)
        (final / "run.json").write_text("the other writer's\n")
        return real(self, stage, final, *a)

    monkeypatch.setattr(Run, "_write_files", meanwhile)
    one_line_failure(cli("simulate", "-o", run_dir, "--seed", "1"), str(run_dir), "another writer")
    assert [p.name for p in run_dir.iterdir()] == ["run.json"]
    assert (run_dir / "run.json").read_text() == "the other writer's\n"
    assert scratch(tmp_path) == []


def test_two_simulations_into_one_folder_started_together(tmp_path):
    run_dir = tmp_path / "same"
    procs = [subprocess.Popen([sys.executable, "-m", "cmmpose.cli", "simulate", "-o", str(run_dir), "--seed", s],
                              env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for s in ("1", "2")]
    codes = [p.wait(timeout=300) for p in procs]
    assert sorted(codes) == [0, 1], codes
    loser = procs[codes.index(1)].communicate()[1]
    assert str(run_dir) in loser and "Traceback" not in loser
    Run.load(run_dir)
    assert scratch(tmp_path) == []


# -- groups of files ----------------------------------------------------------------------


def _group(tmp_path, overwrite=True):
    with FileGroup(overwrite=overwrite, what="set"):
        for k in range(3):
            write_text(tmp_path / f"m{k}.csv", f"new {k}\n")


def test_a_group_appears_whole(tmp_path):
    (tmp_path / "m1.csv").write_text("old 1\n")
    _group(tmp_path)
    assert [(tmp_path / f"m{k}.csv").read_text() for k in range(3)] == ["new 0\n", "new 1\n", "new 2\n"]
    assert scratch(tmp_path) == []
    with pytest.raises(OutputError, match="exists"):
        _group(tmp_path, overwrite=False)


@pytest.mark.parametrize("on", ["write", "place"])
def test_a_group_that_fails_leaves_nothing_of_it(tmp_path, monkeypatch, on):
    (tmp_path / "m1.csv").write_text("old 1\n")
    if on == "write":  # the disk fills on the last member
        real_fsync, calls = os.fsync, []

        def fsync(fd):
            if os.readlink(f"/proc/self/fd/{fd}").endswith(".tmp"):
                calls.append(fd)
                if len(calls) == 3:
                    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            return real_fsync(fd)
        monkeypatch.setattr(os, "fsync", fsync)
    else:  # the last rename into place fails: the first two are taken out again
        fail_the_third_rename(monkeypatch)
    with pytest.raises(OutputError) as exc:
        _group(tmp_path)
    monkeypatch.undo()
    assert "nothing of the set was written" in str(exc.value)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m1.csv"]
    assert (tmp_path / "m1.csv").read_text() == "old 1\n"


# -- diagnose --corrected-maps --------------------------------------------------------------


@pytest.fixture(scope="module")
def maps_and_run(tmp_path_factory):
    """A simulated run and the thesis maps as files in/cm_20C.csv, in/cm_25C.csv, in/cm_30C.csv."""
    root = tmp_path_factory.mktemp("corrected")
    assert cli("simulate", "-o", root / "run", "--seed", "1").exit_code == 0
    (root / "in").mkdir()
    for m in cmmpose.ErrorMapSet.thesis().maps:
        m.write(root / "in" / f"cm_{m.temperature:g}C.csv")
    return root


def _digests(folder: Path) -> dict:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


@pytest.mark.parametrize("spelling", ["same", "dotdot", "symlink"])
def test_corrected_maps_never_over_the_input_maps(maps_and_run, spelling):
    root = maps_and_run
    before = _digests(root / "in")
    out = {"same": root / "in" / "cm.csv", "dotdot": root / "run" / ".." / "in" / "cm.csv"}.get(spelling)
    if spelling == "symlink":
        link = root / "linked"
        if not link.exists():
            link.symlink_to(root / "in")
        out = link / "cm.csv"
    maps = [a for m in sorted((root / "in").glob("cm_*C.csv")) for a in ("--maps", m)]
    r = cli("diagnose", root / "run", *maps, "--corrected-maps", out)
    one_line_failure(r, "--corrected-maps", "cm_20C.csv", "same file as the input")
    assert _digests(root / "in") == before


def test_corrected_maps_never_over_a_machine_files_maps(maps_and_run, tmp_path):
    root = maps_and_run
    before = _digests(root / "in")
    machine = tmp_path / "m.toml"
    assert cli("machine", "example", "thesis", "-o", machine).exit_code == 0
    files = ", ".join(f'"{p}"' for p in sorted((root / "in").glob("cm_*C.csv")))
    machine.write_text(machine.read_text().replace('bundled = "thesis"', f"files = [{files}]"))
    r = cli("diagnose", root / "run", "--machine", machine, "--corrected-maps", root / "in" / "cm.csv")
    one_line_failure(r, "--corrected-maps", "same file as the input", "cm_20C.csv")
    assert _digests(root / "in") == before


def test_corrected_maps_on_a_full_disk_leave_no_part_of_the_set(maps_and_run, tmp_path, monkeypatch):
    root = maps_and_run
    out = tmp_path / "out"
    out.mkdir()
    (out / "cm_25C.csv").write_text("earlier\n")
    real_fsync, calls = os.fsync, []

    def fsync(fd):
        where = os.readlink(f"/proc/self/fd/{fd}")
        if where.startswith(str(out)) and where.endswith(".tmp"):
            calls.append(fd)
            if len(calls) == 3:
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real_fsync(fd)

    monkeypatch.setattr(os, "fsync", fsync)
    maps = [a for m in sorted((root / "in").glob("cm_*C.csv")) for a in ("--maps", m)]
    r = cli("diagnose", root / "run", *maps, "--corrected-maps", out / "cm.csv", "--overwrite")
    monkeypatch.undo()
    one_line_failure(r, "cm_30C.csv", "no space left", "nothing of the --corrected-maps was written")
    assert sorted(p.name for p in out.iterdir()) == ["cm_25C.csv"]
    assert (out / "cm_25C.csv").read_text() == "earlier\n"
    r = cli("diagnose", root / "run", *maps, "--corrected-maps", out / "cm.csv", "--overwrite")
    assert r.exit_code == 0, r.output
    assert sorted(p.name for p in out.iterdir()) == ["cm_20C.csv", "cm_25C.csv", "cm_30C.csv"]


# -- evaluate: every report path checked before any is written --------------------------------


@pytest.fixture(scope="module")
def small_run(tmp_path_factory, simulated_run):
    root = tmp_path_factory.mktemp("runs")
    simulated_run.save(root / "run")
    return root / "run"


@pytest.mark.parametrize("name", ["summary.csv", "trend.png"])
def test_evaluate_runs_named_like_its_report_files_write_nothing(small_run, tmp_path, name):
    import shutil

    shutil.copytree(small_run, tmp_path / "a" / name)
    shutil.copytree(small_run, tmp_path / "b" / "other")
    report = tmp_path / "R"
    r = cli("evaluate", tmp_path / "a" / name, tmp_path / "b" / "other", "--report", report)
    one_line_failure(r, "--report", name)
    assert not report.exists() or not any(report.rglob("*"))


def test_evaluate_a_folder_where_a_report_file_goes_writes_nothing(small_run, tmp_path):
    report = tmp_path / "R"
    (report / "uncertainty.md").mkdir(parents=True)
    r = cli("evaluate", small_run, "--report", report)
    one_line_failure(r, "--report", "uncertainty.md", "is a folder")
    assert sorted(p.name for p in report.iterdir()) == ["uncertainty.md"]


# -- compensate: outputs by known suffix; --maps and missing inputs --------------------------


@pytest.fixture
def scan(tmp_path):
    p = tmp_path / "a.csv"
    p.write_text("u,v,D,E,F,T\n0,0,450,275,-250,22\n1,-1,451,275,-250,22\n")
    return p


@pytest.mark.parametrize("out", ["out.txt", "out"])
def test_compensate_refuses_an_unknown_output_suffix(scan, out):
    r = cli("compensate", scan, scan.parent / out, "--maps", "thesis", "--temperature", "22")
    one_line_failure(r, out, "unknown point-file suffix", ".csv", ".parquet", ".ply")
    assert not (scan.parent / out).exists()
    assert cli("compensate", scan, "/dev/null", "--maps", "thesis", "--temperature", "22").exit_code == 0  # a stream


def test_a_wrong_map_name_lists_the_valid_ones(scan):
    r = cli("compensate", scan, scan.parent / "o.csv", "--maps", "thesiss")
    one_line_failure(r, "--maps", "thesiss", "thesis, appendix-b, none", code=2)


@pytest.mark.parametrize("args, name", [
    (["compensate", "{missing}", "{tmp}/o.csv", "--maps", "thesis"], "IN"),
    (["compensate", "{scan}", "{tmp}/o.csv", "--machine", "{missing}"], "--machine"),
    (["compensate", "{scan}", "{tmp}/o.csv", "--maps", "{missing}"], "--maps"),
    (["evaluate", "{missing}"], "RUN_DIR"),
    (["standards", "iso230-2", "{missing}"], "FILE"),
    (["artefact", "show", "{missing}"], "no such artefact file"),
])
def test_a_missing_input_is_a_usage_error_everywhere(scan, args, name):
    values = {"missing": scan.parent / "nothing.here", "tmp": scan.parent, "scan": scan}
    r = cli(*[a.format(**values) for a in args])
    one_line_failure(r, name, "nothing.here", code=2)


# -- one door in: special files as documents -------------------------------------------------


@pytest.mark.parametrize("kind", ["fifo", "zero"])
@pytest.mark.parametrize("args, what", [
    (["compensate", "{scan}", "{tmp}/o.csv", "--machine", "{special}"], "machine file"),
    (["evaluate", "{run}", "--model", "{special}"], "model file"),
    (["diagnose", "{run}", "--user-effect", "{special}"], "user-effect file"),
    (["artefact", "show", "{special}"], "artefact file"),
    (["compensate", "{scan}", "{tmp}/o.csv", "--maps", "{special}"], "map file"),
    (["standards", "iso230-2", "{special}"], "positioning file"),
    (["diagnose-fits", "{special}", "--artefact", "koba-0420"], "table"),
])
def test_a_fifo_or_a_device_as_a_document_is_refused_at_once(scan, small_run, kind, args, what):
    special = scan.parent / "doc.fifo"
    if kind == "fifo":
        os.mkfifo(special)  # no writer: a read would wait for ever
    else:
        special = Path("/dev/zero")  # endless
    values = {"special": special, "tmp": scan.parent, "scan": scan, "run": small_run}
    p = subprocess.run([sys.executable, "-m", "cmmpose.cli", *[a.format(**values) for a in args]], env=ENV,
                       capture_output=True, text=True, timeout=60, stdin=subprocess.DEVNULL)
    assert p.returncode == 1, p.stderr
    assert "Traceback" not in p.stderr and "no such" not in p.stderr
    kind_text = "a FIFO (named pipe)" if kind == "fifo" else "a character device"
    assert f"{special}: not a regular file but {kind_text}; the {what} must be a regular file" in p.stderr


def test_the_reader_bounds_the_size(tmp_path):
    from cmmpose.errors import MissingFileError, read_input

    big = tmp_path / "big.json"
    big.write_bytes(b" " * 1000)
    with pytest.raises(InputError, match="more than a model file may hold"):
        read_input(big, "model file", limit=999)
    assert read_input(big, "model file", limit=1000) == b" " * 1000
    with pytest.raises(MissingFileError, match="no such model file"):
        read_input(tmp_path / "none.json", "model file")


def test_a_group_replaces_where_the_file_system_has_no_hard_links(tmp_path, monkeypatch):
    def no_links(*a, **k):
        raise OSError(errno.EPERM, os.strerror(errno.EPERM))
    monkeypatch.setattr(os, "link", no_links)
    (tmp_path / "m1.csv").write_text("old 1\n")
    _group(tmp_path)
    assert [(tmp_path / f"m{k}.csv").read_text() for k in range(3)] == ["new 0\n", "new 1\n", "new 2\n"]
    assert scratch(tmp_path) == []


def _machine_with_maps(tmp_path, folder: Path) -> Path:
    machine = tmp_path / "m.toml"
    assert cli("machine", "example", "thesis", "-o", machine).exit_code == 0
    files = ", ".join(f'"{p}"' for p in sorted(folder.glob("cm_*C.csv")))
    machine.write_text(machine.read_text().replace('bundled = "thesis"', f"files = [{files}]"))
    return machine


def test_map_export_never_over_a_machine_files_maps(maps_and_run, tmp_path):
    root = maps_and_run
    before = _digests(root / "in")
    machine = _machine_with_maps(tmp_path, root / "in")
    r = cli("map", "export", "--machine", machine, "--temperature", "20", "--format", "csv",
            "-o", root / "run" / ".." / "in" / "cm_20C.csv")
    one_line_failure(r, "--output", "same file as the input", "cm_20C.csv")
    assert _digests(root / "in") == before


def test_linuxcnc_files_appear_together(tmp_path, monkeypatch):
    fail_the_third_rename(monkeypatch)
    out = tmp_path / "comp"
    r = cli("map", "export", "appendix-b", "--format", "linuxcnc", "-o", out)
    one_line_failure(r, "z.comp", "nothing of the --output was written")
    assert list(out.iterdir()) == []


def test_diagnose_save_model_never_over_a_machine_files_map(maps_and_run, tmp_path):
    root = maps_and_run
    before = _digests(root / "in")
    machine = _machine_with_maps(tmp_path, root / "in")
    r = cli("diagnose", root / "run", "--machine", machine, "--save-model", root / "in" / "cm_25C.csv")
    one_line_failure(r, "--save-model", "same file as the input", "cm_25C.csv")
    assert _digests(root / "in") == before


def test_a_group_is_this_threads_only(tmp_path):
    import threading

    other = tmp_path / "other.txt"
    with FileGroup(what="set"):
        write_text(tmp_path / "m0.csv", "new 0\n")
        t = threading.Thread(target=write_text, args=(other, "another thread's\n"))
        t.start()
        t.join()
        assert other.read_text() == "another thread's\n"  # not held back for the group
        assert not (tmp_path / "m0.csv").exists()
    assert (tmp_path / "m0.csv").read_text() == "new 0\n"


def test_two_saves_into_one_alignment_library_keep_both(tmp_path, monkeypatch):
    """Each save reads the library, adds its pose and writes it back: two at once must not drop one."""
    import threading
    import time

    from cmmpose.calibration.library import AlignmentLibrary, AlignmentRecord

    path = tmp_path / "lib.json"
    real = AlignmentLibrary._read

    def slow_read(self):
        poses = real(self)
        time.sleep(0.3)  # both have read before either writes, unless they take turns
        return poses

    monkeypatch.setattr(AlignmentLibrary, "_read", slow_read)
    rec = AlignmentRecord(pose=(90.0, 90.0, 0.0), reading=(1.0, 2.0, 3.0), offset=(1.001, 264.505, 129.575))
    threads = [threading.Thread(target=AlignmentLibrary(path).save, args=(name, rec)) for name in ("A0B0", "A90B0")]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    monkeypatch.undo()
    assert AlignmentLibrary(path).names() == ["A0B0", "A90B0"]
