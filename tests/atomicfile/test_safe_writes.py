"""Issue 23, data loss: every file cmmpose writes goes through
cmmpose.atomicfile. An output that is an input is refused; special files are
written as streams, never replaced; a full disk, a read-only folder, Ctrl-C,
SIGTERM or SIGHUP leave the earlier file whole and no temporary file behind;
outputs get the user's umask; `simulate --overwrite` swaps a complete run in.
Tests run as root, so a read-only folder or a full disk is simulated by
making the system calls fail."""

from __future__ import annotations

import errno
import hashlib
import json
import os
import signal
import stat
import subprocess
import sys
import textwrap
import threading
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner

import cmmpose
from cmmpose import atomicfile
from cmmpose.cli import main
from cmmpose.errors import InputError, OutputError, RunError
from cmmpose.run import Run
from child_processes import default_signals

POSE, OFFSET = (90.0, 90.0, 0.0), (1.001, 264.505, 129.575)


def cli(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def one_line_failure(result, *words):
    """Exit 1 with a one-line message naming ``words``, no traceback."""
    assert result.exit_code == 1, result.output
    assert isinstance(result.exception, SystemExit)
    text = result.output.strip()
    assert "Traceback" not in text, text
    errors = [line for line in text.splitlines() if line.startswith("Error:")]
    assert len(errors) == 1 and text.endswith(errors[0]), text  # notes before it are fine
    text = errors[0]
    for w in words:
        assert w in text, text
    return text


def scratch(folder: Path) -> list[str]:
    """Names in ``folder`` that a writer left behind (temporary files, stages)."""
    return sorted(p.name for p in folder.iterdir() if p.name.startswith(".") or p.name.endswith(".tmp"))


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def run_digest(run_dir: Path) -> dict[str, str]:
    return {str(p.relative_to(run_dir)): digest(p) for p in sorted(run_dir.rglob("*")) if p.is_file()}


@pytest.fixture
def scan(tmp_path):
    """A small scanner file u, v, D, E, F, T."""
    rng = np.random.default_rng(3)
    n = 40
    a = np.column_stack([rng.uniform(-30, 30, n), rng.uniform(-30, 30, n), rng.uniform(0, 900, n),
                         rng.uniform(0, 550, n), rng.uniform(-500, 0, n), rng.uniform(20.5, 29.5, n)]).round(4)
    p = tmp_path / "a.csv"
    p.write_text("u,v,D,E,F,T\n" + "".join(",".join(repr(float(x)) for x in row) + "\n" for row in a))
    return p


@pytest.fixture
def umask():
    old = os.umask(0o022)
    yield
    os.umask(old)


# -- an output that is an input ------------------------------------------------------------


@pytest.mark.parametrize("spelling", ["same", "dot", "absolute", "symlink", "hardlink"])
def test_compensate_refuses_its_input_as_output(scan, spelling, monkeypatch):
    monkeypatch.chdir(scan.parent)
    before = scan.read_bytes()
    out = {"same": "a.csv", "dot": "./a.csv", "absolute": str(scan)}.get(spelling)
    if spelling == "symlink":
        os.symlink("a.csv", scan.parent / "link.csv")
        out = "link.csv"
    elif spelling == "hardlink":
        os.link(scan, scan.parent / "hard.csv")
        out = "hard.csv"
    r = cli("compensate", "a.csv", out, "--maps", "thesis", "--temperature", "22")
    one_line_failure(r, out, "same file as the input", "a.csv")
    assert scan.read_bytes() == before
    assert scratch(scan.parent) == []


def test_check_not_input_passes_other_files_and_special_files(tmp_path):
    a = tmp_path / "a.csv"
    a.write_text("x\n")
    atomicfile.check_not_input(tmp_path / "b.csv", [a])  # not there yet
    (tmp_path / "b.csv").write_text("y\n")
    atomicfile.check_not_input(tmp_path / "b.csv", [a, None, "-"])
    atomicfile.check_not_input("/dev/null", ["/dev/null"])  # a stream, nothing replaced
    with pytest.raises(InputError, match="--save-model is the same file as the input"):
        atomicfile.check_not_input(tmp_path / "." / "a.csv", [a], "--save-model")


def test_map_commands_refuse_an_input_as_output(tmp_path):
    m = tmp_path / "m.csv"
    cmmpose.ErrorMap.appendix_b().write(m)
    before = m.read_bytes()
    r = cli("map", "export", str(m), "--format", "iso230-2", "-o", str(tmp_path / "." / "m.csv"))
    one_line_failure(r, "same file as the input")
    r = cli("map", "plot", str(m), "-o", str(m))
    one_line_failure(r, "same file as the input")
    iso = tmp_path / "x.csv"
    assert cli("map", "export", "appendix-b", "--format", "iso230-2", "-o", str(iso)).exit_code == 0
    iso_before = iso.read_bytes()
    r = cli("map", "import", "iso230-2", str(iso), "-o", str(iso))
    one_line_failure(r, "same file as the input")
    r = cli("map", "import", "iso230-2", str(iso), "--base", str(m), "-o", str(m))
    one_line_failure(r, "same file as the input")
    assert m.read_bytes() == before and iso.read_bytes() == iso_before


def test_diagnose_refuses_to_save_over_its_model_or_run(tmp_path):
    run_dir = tmp_path / "run"
    assert cli("simulate", "-o", run_dir).exit_code == 0
    before = run_digest(run_dir)
    r = cli("diagnose", run_dir, "--save-model", run_dir / "run.json")
    one_line_failure(r, "--save-model", "same file as the input")
    machine = tmp_path / "m.toml"
    assert cli("machine", "example", "thesis", "-o", machine).exit_code == 0
    r = cli("diagnose", run_dir, "--machine", machine, "--report", machine)
    one_line_failure(r, "--report", "same file as the input")
    assert run_digest(run_dir) == before


# -- special files ------------------------------------------------------------------------


@pytest.fixture
def no_rename_over(monkeypatch):
    """Fail the test if anything is renamed over a special file."""
    real = os.replace

    def guarded(src, dst, *a, **k):
        st = os.stat(dst) if os.path.exists(dst) else None
        assert st is None or stat.S_ISREG(st.st_mode), f"renamed over the special file {dst}"
        return real(src, dst, *a, **k)

    monkeypatch.setattr(os, "replace", guarded)


def test_dev_null_is_written_as_a_stream(scan, no_rename_over):
    before = os.stat("/dev/null")
    atomicfile.write_text("/dev/null", "hello\n")
    r = cli("compensate", scan, "/dev/null", "--maps", "thesis")
    assert r.exit_code == 0, r.output
    r = cli("machine", "example", "thesis", "-o", "/dev/null", "--overwrite")
    assert r.exit_code == 0, r.output
    after = os.stat("/dev/null")
    assert stat.S_ISCHR(after.st_mode) and after.st_rdev == before.st_rdev


def _read_fifo(path: Path, sink: list):
    with open(path, "rb") as f:
        sink.append(f.read())


@pytest.mark.parametrize("suffix", [".csv", ".npy", ".parquet", ".json"])
def test_a_fifo_is_written_as_a_stream(tmp_path, scan, suffix, no_rename_over):
    fifo = tmp_path / f"out{suffix}"
    os.mkfifo(fifo)
    got = []
    reader = threading.Thread(target=_read_fifo, args=(fifo, got), daemon=True)
    reader.start()
    if suffix == ".json":
        atomicfile.write_text(fifo, '{"a": 1}\n')
    else:
        r = cli("compensate", scan, fifo, "--maps", "thesis")
        assert r.exit_code == 0, r.output
    reader.join(timeout=30)
    assert not reader.is_alive()
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    assert scratch(tmp_path) == []
    data = got[0]
    if suffix == ".json":
        assert json.loads(data) == {"a": 1}
    elif suffix == ".csv":
        assert data.startswith(b"X,Y,Z") and data.count(b"\n") == 41
    elif suffix == ".npy":  # spooled: the header's count filled in, then copied into the FIFO
        assert data.startswith(b"\x93NUMPY")
        copy = tmp_path / "copy.npy"
        copy.write_bytes(data)
        assert np.load(copy).shape == (40, 3)
    else:
        copy = tmp_path / "copy.parquet"
        copy.write_bytes(data)
        assert pq.read_table(copy).num_rows == 40


def test_a_fifo_without_reader_times_out(tmp_path, monkeypatch):
    fifo = tmp_path / "f.csv"
    os.mkfifo(fifo)
    monkeypatch.setattr(atomicfile.files, "FIFO_OPEN_TIMEOUT", 0.2)
    with pytest.raises(OutputError, match="no reader opened the FIFO within 0.2 s"):
        atomicfile.write_text(fifo, "x\n")


def test_stdout_only_where_accepted(capsysbinary):
    with pytest.raises(InputError, match="standard output"):
        atomicfile.write_text("-", "x\n")
    atomicfile.write_bytes("-", b"abc\n", stdout=True)
    assert capsysbinary.readouterr().out == b"abc\n"


def test_a_folder_is_refused(tmp_path, scan):
    with pytest.raises(InputError, match="is a folder"):
        atomicfile.write_text(tmp_path, "x")
    one_line_failure(cli("compensate", scan, tmp_path, "--maps", "thesis"), "is a folder")
    r = cli("machine", "example", "thesis", "-o", tmp_path, "--overwrite")  # click's own check: a usage error
    assert r.exit_code == 2 and "is a directory" in r.output
    assert scratch(tmp_path) == []


def test_a_link_is_followed_and_kept(tmp_path):
    real = tmp_path / "real.json"
    real.write_text("old\n")
    link = tmp_path / "link.json"
    link.symlink_to(real)
    atomicfile.write_text(link, "new\n")
    assert link.is_symlink() and real.read_text() == "new\n"


# -- a full disk, a read-only folder ------------------------------------------------------


class _Failing:
    """A file object whose write (``on="write"``) or close (``on="close"``) raises ``err``."""

    def __init__(self, f, on, err):
        self._f, self._on, self._err = f, on, err

    def write(self, data):
        if self._on == "write":
            raise OSError(self._err, os.strerror(self._err))
        return self._f.write(data)

    def close(self):
        self._f.close()  # the descriptor is closed, and the flush "failed"
        if self._on == "close":
            raise OSError(self._err, os.strerror(self._err))

    def __getattr__(self, name):
        return getattr(self._f, name)


@pytest.fixture
def disk(monkeypatch, tmp_path):
    """``disk("write"|"close"|"fsync"|"mkstemp", errno)``: make writes into
    ``tmp_path`` (the disk the outputs are on) fail there."""

    def here(fd_or_dir) -> bool:
        where = os.readlink(f"/proc/self/fd/{fd_or_dir}") if isinstance(fd_or_dir, int) else str(fd_or_dir)
        return where.startswith(str(tmp_path))

    def arm(on, err=errno.ENOSPC):
        if on == "fsync":
            real_fsync = os.fsync

            def fsync(fd):
                if here(fd):
                    raise OSError(err, os.strerror(err))
                return real_fsync(fd)
            monkeypatch.setattr(os, "fsync", fsync)
        elif on == "mkstemp":
            real_make_temp = atomicfile.files._make_temp  # the temporary file beside the target

            def make_temp(folder):
                if here(os.path.abspath(folder)):
                    raise OSError(err, os.strerror(err))
                return real_make_temp(folder)
            monkeypatch.setattr(atomicfile.files, "_make_temp", make_temp)
        else:
            real = os.fdopen

            def fdopen(fd, *a, **k):
                f = real(fd, *a, **k)
                return _Failing(f, on, err) if here(fd) else f
            monkeypatch.setattr(os, "fdopen", fdopen)

    return arm


def _writers(tmp_path):
    """(name, target, write) for every library writer: each writes ``target``."""
    from cmmpose.acquire.plan import Plan
    from cmmpose.calibration.library import AlignmentLibrary, AlignmentRecord
    from cmmpose.model import Model
    from cmmpose.diagnosis.html import write_html_report
    from cmmpose.formats.linuxcnc import write_comp_files
    from cmmpose.evaluation.plots import plot_error_map

    em = cmmpose.ErrorMap.appendix_b()
    cloud = cmmpose.PointCloud(np.arange(30.0).reshape(10, 3), {"intensity": np.arange(10.0)})
    rec = AlignmentRecord(pose=(90.0, 90.0, 0.0), reading=(1.0, 2.0, 3.0), offset=OFFSET)
    out = [
        ("map csv", "m.csv", lambda p: em.write(p)),
        ("iso230-2", "x.csv", lambda p: em.write(p, format="iso230-2")),
        ("linuxcnc", "x.comp", lambda p: write_comp_files(em, {"X": p})),
        ("model", "model.json", lambda p: Model(em).save(p)),
        ("html", "r.html", lambda p: write_html_report(p, "t", [{"heading": "h", "text": "x"}])),
        ("library", "lib.json", lambda p: AlignmentLibrary(p).save("A0B0", rec, overwrite=True)),
        ("plan", "plan.json", lambda p: Plan().write(p)),
        ("plot", "m.png", lambda p: plot_error_map(em, p)),
    ]
    out += [(f"points {s}", f"p.{s}", lambda p: cmmpose.write_point_cloud(p, cloud))
            for s in ("csv", "npy", "parquet", "ply", "xyz", "pts", "e57")]
    return out


WRITERS = [w[0] for w in _writers(Path("."))]


@pytest.mark.parametrize("on", ["write", "close", "fsync", "mkstemp"])
@pytest.mark.parametrize("name", WRITERS)
def test_a_full_disk_leaves_the_earlier_file_whole(tmp_path, name, on, disk):
    if name == "points e57":
        pytest.importorskip("pye57")
        if on in ("write", "close"):
            pytest.skip("libE57Format writes the file by name, not through a Python file object")
    if name == "plot":
        pytest.importorskip("matplotlib")
    _, target, write = next(w for w in _writers(tmp_path) if w[0] == name)
    path = tmp_path / target
    write(path)  # the earlier file, complete
    before = digest(path)
    disk(on)
    with pytest.raises(OutputError) as exc:
        write(path)
    assert str(path) in str(exc.value) and "no space left" in str(exc.value)
    assert digest(path) == before
    assert scratch(tmp_path) == []


@pytest.mark.parametrize("err,words", [(errno.EROFS, "read-only file system"), (errno.EACCES, "permission denied"),
                                       (errno.ENOSPC, "no space left")])
@pytest.mark.parametrize("on", ["mkstemp", "write", "close"])
def test_cli_outputs_on_a_full_or_read_only_disk(tmp_path, scan, disk, err, words, on):
    """compensate, machine example, diagnose --save-model and evaluate --report: one line, exit 1."""
    run_dir = tmp_path / "run"
    assert cli("simulate", "-o", run_dir).exit_code == 0
    out = tmp_path / "x.csv"
    machine = tmp_path / "m.toml"
    model = tmp_path / "model.json"
    for p in (out, machine, model):
        p.write_text("earlier\n")
    report = tmp_path / "report"
    disk(on, err)
    cases = [(("compensate", scan, out, "--maps", "thesis", "--overwrite"), out),
             (("machine", "example", "thesis", "-o", machine, "--overwrite"), machine),
             (("diagnose", run_dir, "--save-model", model, "--max-effects", "0", "--no-auto", "--overwrite"), model),
             (("evaluate", run_dir, "--report", report), report / "evaluation.json")]
    for args, named in cases:
        one_line_failure(cli(*args), str(named), words)
    for p in (out, machine, model):
        assert p.read_text() == "earlier\n"
    assert scratch(tmp_path) == [] and (not report.exists() or scratch(report) == [])


# -- permissions ----------------------------------------------------------------------------


@pytest.mark.parametrize("mask,mode", [(0o022, 0o644), (0o077, 0o600), (0o002, 0o664)])
def test_outputs_get_the_umask(tmp_path, scan, umask, mask, mode):
    os.umask(mask)
    atomicfile.write_text(tmp_path / "a.json", "{}\n")
    assert stat.S_IMODE(os.stat(tmp_path / "a.json").st_mode) == mode
    assert cli("compensate", scan, tmp_path / "x.parquet", "--maps", "thesis").exit_code == 0
    assert stat.S_IMODE(os.stat(tmp_path / "x.parquet").st_mode) == mode
    assert cli("simulate", "-o", tmp_path / "run").exit_code == 0
    assert stat.S_IMODE(os.stat(tmp_path / "run").st_mode) == mode | 0o111 & ~mask
    assert stat.S_IMODE(os.stat(tmp_path / "run" / "run.json").st_mode) == mode


def test_a_replaced_file_keeps_its_permissions(tmp_path, umask):
    p = tmp_path / "a.json"
    p.write_text("old\n")
    os.chmod(p, 0o640)
    atomicfile.write_text(p, "new\n")
    assert stat.S_IMODE(os.stat(p).st_mode) == 0o640 and p.read_text() == "new\n"


# -- SIGTERM, SIGHUP, Ctrl-C ----------------------------------------------------------------

# A slow disk: the first write into a file (or a run's stage) announces itself and stalls.
_SLOW = textwrap.dedent("""
    import os, sys, time
    from cmmpose import run
    def slow():
        print("writing", flush=True)
        time.sleep(60)
    class Slow:
        def __init__(self, f):
            self._f = f
        def write(self, data):
            self._f.write(data[:1])
            self._f.flush()
            slow()
        def __getattr__(self, name):
            return getattr(self._f, name)
    real = os.fdopen
    os.fdopen = lambda *a, **k: Slow(real(*a, **k))
    run.Run._write_files = lambda self, stage, *a: (open(stage / "run.json", "w").write("{}"), slow())
    from cmmpose.cli import main
    main(sys.argv[1:])
""")


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP, signal.SIGINT])
@pytest.mark.parametrize("what", ["file", "run"])
def test_a_signal_mid_write_leaves_no_temporary_file(tmp_path, sig, what):
    if what == "file":
        target = tmp_path / "m.toml"
        target.write_text("earlier\n")
        args = ["machine", "example", "thesis", "-o", str(target), "--overwrite"]
    else:
        target = tmp_path / "run"
        assert cli("simulate", "-o", target).exit_code == 0
        before = run_digest(target)
        args = ["simulate", "-o", str(target), "--overwrite", "--seed", "5"]
    proc = subprocess.Popen([sys.executable, "-c", _SLOW, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, preexec_fn=default_signals)
    try:
        assert proc.stdout.readline().strip() == "writing"
        assert scratch(tmp_path), "nothing is being written"
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == (1 if sig == signal.SIGINT else 128 + sig), err  # click: Ctrl-C is "Aborted!", 1
    assert "Traceback" not in err
    assert scratch(tmp_path) == []
    if what == "file":
        assert target.read_text() == "earlier\n"
    else:
        assert run_digest(target) == before


# -- run directories ------------------------------------------------------------------------


@pytest.fixture
def old_run(tmp_path):
    run_dir = tmp_path / "run"
    assert cli("simulate", "-o", run_dir, "--seed", "1").exit_code == 0
    (run_dir / "notes.txt").write_text("mine\n")  # not the run's: left alone
    return run_dir


def test_simulate_overwrite_swaps_in_a_complete_run(old_run):
    before = run_digest(old_run)
    r = cli("simulate", "-o", old_run, "--seed", "2")
    one_line_failure(r, "not empty")
    assert run_digest(old_run) == before
    assert cli("simulate", "-o", old_run, "--seed", "2", "--overwrite").exit_code == 0
    after = run_digest(old_run)
    assert after["notes.txt"] == before["notes.txt"] and after["points.parquet"] != before["points.parquet"]
    assert set(after) == set(before)
    Run.load(old_run)
    assert scratch(old_run.parent) == []


@pytest.mark.parametrize("stage", ["write", "swap"])
def test_simulate_overwrite_failing_midway_leaves_the_old_run(old_run, monkeypatch, stage):
    before = run_digest(old_run)
    if stage == "write":  # the disk fills while the new run is written
        real = pq.write_table
        calls = []

        def write_table(*a, **k):
            calls.append(1)
            if len(calls) == 2:
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            return real(*a, **k)

        monkeypatch.setattr(pq, "write_table", write_table)
    else:  # a rename fails half-way through the swap: what moved is put back
        real = os.replace
        calls = []

        def replace(src, dst, *a, **k):
            calls.append(1)
            if len(calls) == 9:
                raise OSError(errno.EIO, os.strerror(errno.EIO))
            return real(src, dst, *a, **k)

        monkeypatch.setattr(os, "replace", replace)
    r = cli("simulate", "-o", old_run, "--seed", "2", "--overwrite")
    one_line_failure(r, str(old_run), "cannot write")
    monkeypatch.undo()
    assert run_digest(old_run) == before
    Run.load(old_run)
    assert scratch(old_run.parent) == []


def test_run_save_failure_is_a_run_error(old_run, disk):
    run = Run.load(old_run)
    before = run_digest(old_run)
    disk("fsync")
    with pytest.raises(RunError, match="no space left"):
        run.save(old_run, overwrite=True)
    assert run_digest(old_run) == before
    assert scratch(old_run.parent) == []
