"""Issue 23, hangs and tracebacks: a scheduler that never answers or is an
HTTP server, special files as inputs, files that used to raise tracebacks
(Parquet with a repeated column, a PLY declaring 1e12 vertices, TOML nested
10,000 deep or with a 5,001-digit integer, sphere fits with a header and no
rows) and misleading messages (a far outlier called "collinear", Python
argument names on the command line, ``--maps ""``, a 300-digit number
printed back). Each through the command line: exit code and a one-line
message naming what is at fault."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import shutil
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner

import cmmpose
from cmmpose.cli import main
from cmmpose.errors import SchedulerError
from repo import REPO

ROOT = REPO
SCAN = ROOT / "data" / "examples" / "sphere_scan.csv"
COMPENSATE = ["--maps", "thesis", "--pose", "90,90,0", "--offset", "1.001,264.505,129.575"]


def cli(*args, cwd=None):
    """The command's result; a traceback fails the test (catch_exceptions=False)."""
    runner = CliRunner()
    with contextlib.chdir(cwd) if cwd else contextlib.nullcontext():
        return runner.invoke(main, [str(a) for a in args], catch_exceptions=False)


def one_line_error(result) -> str:
    """The message of a refused command: one 'Error: ...' line, no traceback."""
    assert "Traceback" not in result.output
    lines = [ln for ln in result.output.splitlines() if ln.startswith("Error:")]
    assert len(lines) == 1, result.output
    return lines[0]


@contextlib.contextmanager
def server(answer: bytes | None = None):
    """A local TCP server: accepts and never answers, or sends ``answer`` at once."""
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    s.listen(8)
    held, stop = [], threading.Event()

    def loop():
        s.settimeout(0.1)
        while not stop.is_set():
            try:
                c, _ = s.accept()
            except OSError:
                continue
            held.append(c)
            if answer is not None:
                c.sendall(answer)

    t = threading.Thread(target=loop, daemon=True)
    t.start()
    try:
        yield s.getsockname()[1]
    finally:
        stop.set()
        t.join(timeout=2)
        for c in held:
            c.close()
        s.close()


@pytest.fixture
def dataset(tmp_path):
    rows = np.loadtxt(SCAN, delimiter=",", skiprows=1)
    folder = tmp_path / "pq"
    folder.mkdir()
    pq.write_table(pa.table({n: rows[:, k] for k, n in enumerate("u v D E F".split())}), folder / "part0.parquet")
    return folder


# -- hangs -----------------------------------------------------------------------------------------

def test_a_scheduler_that_never_answers_is_an_error_within_the_timeout(tmp_path, dataset):
    pytest.importorskip("distributed")
    with server() as port:
        address = f"tcp://127.0.0.1:{port}"
        t0 = time.monotonic()
        r = cli("compensate", dataset, tmp_path / "out", *COMPENSATE, "--temperature", 22, "--scheduler", address,
                "--scheduler-timeout", 1)
        elapsed = time.monotonic() - t0
        assert r.exit_code == 1
        msg = one_line_error(r)
        assert address in msg and "no Dask handshake within 1 s" in msg and "--scheduler-timeout" in msg
        assert elapsed < 20
        t0 = time.monotonic()
        with pytest.raises(SchedulerError, match=rf"{address}: accepted the connection but sent no Dask handshake"):
            with cmmpose.scale.scheduler_client(address, timeout=0.5):
                pass
        assert time.monotonic() - t0 < 10


def test_a_scheduler_address_that_is_an_http_server_says_what_it_must_be(tmp_path, dataset):
    pytest.importorskip("distributed")
    with server(b"HTTP/1.1 200 OK\r\nContent-Length: 2\r\n\r\nok") as port:
        r = cli("compensate", dataset, tmp_path / "out", *COMPENSATE, "--temperature", 22, "--scheduler",
                f"tcp://127.0.0.1:{port}", "--scheduler-timeout", 5)
    assert r.exit_code == 1
    msg = one_line_error(r)
    assert f"127.0.0.1:{port}" in msg and "not as a Dask scheduler" in msg and "'HTTP/1.1'" in msg


@pytest.mark.parametrize("spec", ["http://127.0.0.1:8787", "tcp://127.0.0.1", "gpu"])
def test_a_malformed_scheduler_spec_is_a_usage_error(tmp_path, dataset, spec):
    r = cli("compensate", dataset, tmp_path / "out", *COMPENSATE, "--temperature", 22, "--scheduler", spec)
    assert r.exit_code == 2
    assert "tcp://host:port" in r.output and "Traceback" not in r.output


@pytest.mark.parametrize("kind", ["fifo", "zero"])
def test_a_fifo_or_a_device_as_input_is_not_a_regular_file(tmp_path, kind):
    if kind == "fifo":
        name = tmp_path / "in.csv"
        os.mkfifo(name)
    else:
        name = Path("/dev/zero")
        if not name.exists():
            pytest.skip("no /dev/zero")
    # a subprocess, so that a regression (a read that waits for a writer) fails instead of hanging the suite
    exe = shutil.which("cmmpose")
    cmd = [exe] if exe else [sys.executable, "-c", "from cmmpose.cli import main; main()"]
    p = subprocess.run([*cmd, "compensate", str(name), str(tmp_path / "out.csv"), *COMPENSATE],
                       capture_output=True, text=True, timeout=60, stdin=subprocess.DEVNULL)
    assert p.returncode == 1 and "Traceback" not in p.stderr
    assert f"{name}: not a regular file but a {'FIFO' if kind == 'fifo' else 'character device'}" in p.stderr
    assert "no such file" not in p.stderr
    assert not (tmp_path / "out.csv").exists()


# -- tracebacks --------------------------------------------------------------------------------------

def test_parquet_with_a_repeated_column_names_it(tmp_path):
    rows = np.loadtxt(SCAN, delimiter=",", skiprows=1)[:10]
    cols = [pa.array(rows[:, k]) for k in range(5)] + [pa.array(rows[:, 0])]
    pq.write_table(pa.Table.from_arrays(cols, names=["u", "v", "D", "E", "F", "u"]), tmp_path / "dup.parquet")
    r = cli("compensate", tmp_path / "dup.parquet", tmp_path / "out.csv", *COMPENSATE)
    assert r.exit_code == 1
    assert "dup.parquet: column 'u' appears 2 times" in one_line_error(r)
    r = cli("fit", tmp_path / "dup.parquet")
    assert r.exit_code == 1 and "column 'u' appears 2 times" in one_line_error(r)
    (tmp_path / "set").mkdir()
    shutil.copy(tmp_path / "dup.parquet", tmp_path / "set")
    r = cli("compensate", tmp_path / "set", tmp_path / "out", *COMPENSATE, "--temperature", 22)
    assert r.exit_code == 1 and "dup.parquet: column 'u' appears twice" in one_line_error(r)


def test_an_ascii_ply_declaring_1e12_vertices_is_refused_before_allocating(tmp_path):
    (tmp_path / "huge.ply").write_text("ply\nformat ascii 1.0\nelement vertex 1000000000000\nproperty double x\n"
                                       "property double y\nproperty double z\nend_header\n1 2 3\n")
    r = cli("fit", tmp_path / "huge.ply")
    assert r.exit_code == 1
    assert "huge.ply: the PLY header declares 1,000,000,000,000 'vertex' rows" in one_line_error(r)


@pytest.mark.parametrize(("extra", "why"), [
    ("x = " + "[" * 10000 + "]" * 10000, "nested too deeply"),
    ("big = " + "9" * 5001, "an integer of more than 4,300 digits"),
])
def test_hostile_toml_is_a_clear_error_naming_the_file(tmp_path, extra, why):
    text = (ROOT / "data" / "machines" / "moving-bridge.toml").read_text()
    (tmp_path / "m.toml").write_text(text + "\n" + extra + "\n")
    r = cli("machine", "check", tmp_path / "m.toml")
    assert r.exit_code == 1
    msg = one_line_error(r)
    assert "m.toml: not a usable TOML file" in msg and why in msg
    art = (ROOT / "data" / "artefacts")
    first = sorted(art.glob("*.toml"))
    if first:
        (tmp_path / "a.toml").write_text(first[0].read_text() + "\n" + extra + "\n")
        r = cli("artefact", "check", tmp_path / "a.toml")
        assert r.exit_code == 1 and "a.toml: not a usable TOML file" in one_line_error(r)


def test_diagnose_fits_with_a_header_and_no_rows(tmp_path):
    (tmp_path / "fits.csv").write_text("position,ball,x_mm,y_mm,z_mm,radius_mm\n")
    r = cli("diagnose-fits", tmp_path / "fits.csv")
    assert r.exit_code == 1
    assert "fits.csv: no sphere fits (a header and no rows)" in one_line_error(r)


# -- misleading messages -----------------------------------------------------------------------------

def test_a_far_outlier_is_named_not_called_collinear(tmp_path):
    d = np.random.default_rng(0).normal(size=(500, 3))
    pts = 20.0 * d / np.linalg.norm(d, axis=1, keepdims=True)
    pts[17] = [1e12, 0, 0]
    np.savetxt(tmp_path / "ball.csv", pts, delimiter=",", header="x,y,z", comments="")
    r = cli("fit", tmp_path / "ball.csv")
    assert r.exit_code == 1
    msg = one_line_error(r)
    assert "collinear" not in msg
    assert "row 17: (1e+12, 0, 0) mm" in msg and "absurd range" in msg
    # several spheres: the row of the input, whatever the order of the labels (sphere 2 holds row 17)
    fits = cmmpose.fit_spheres(pts, np.repeat([2, 1], 250), on_error="return")
    assert list(fits.labels) == [1, 2] and fits.error[0] is None
    assert "row 17:" in str(fits.error[1]) and "collinear" not in str(fits.error[1])


def test_hints_name_the_command_lines_flags_or_say_there_is_none(tmp_path, monkeypatch, simulated_run):
    rows = SCAN.read_text().splitlines()
    rows[5] = "nan,0,450,275,-250,22"
    (tmp_path / "nan.csv").write_text("\n".join(rows) + "\n")
    r = cli("compensate", tmp_path / "nan.csv", tmp_path / "out.csv", *COMPENSATE)
    assert r.exit_code == 1
    msg = one_line_error(r)
    assert "row 4" in msg and "use --nan-policy propagate" in msg and "nan_policy=" not in msg
    # a thermocouple log with a gap: evaluate names its option to interpolate across it (the temperature policy)
    run = simulated_run
    keep = (run.temperatures["t"] < 100) | (run.temperatures["t"] > 200)
    dataclasses.replace(run, temperatures={k: v[keep] for k, v in run.temperatures.items()}).save(tmp_path / "gap")
    r = cli("evaluate", tmp_path / "gap")
    assert r.exit_code == 1
    msg = one_line_error(r)
    assert "gap of the temperature log" in msg and "on_gap" not in msg
    assert "use --on-gap interpolate to interpolate across it" in msg
    r = cli("evaluate", tmp_path / "gap", "--on-gap", "interpolate", "--json")
    assert r.exit_code == 0, r.output
    assert json.loads(r.output)["provenance"]["temperature"]["log"]["points_across_gaps"] > 0


def test_the_library_keeps_its_python_hints():
    from cmmpose.errors import InputError
    from cmmpose.policy import cli_wording

    exc = InputError("x", option="nan_policy", remedy="nan_policy")  # the remedy a field, worded per interface
    assert str(exc) == "x (pass nan_policy='propagate' to get NaN rows instead)"
    assert cli_wording(exc) == "x (use --nan-policy propagate to get NaN rows instead)"

    class Ctx:  # a command without --nan-policy
        command = type("C", (), {"params": [type("P", (), {"opts": ["--maps"]})()]})()

    assert cli_wording(exc, Ctx()) == "x (this command has no option to let NaN rows through)"
    # a message is never rewritten: text that names a Python argument stays as it is
    assert cli_wording(str(exc)) == str(exc)


def test_an_empty_maps_value_is_a_usage_error(tmp_path):
    shutil.copy(SCAN, tmp_path / "a.csv")
    r = cli("compensate", tmp_path / "a.csv", tmp_path / "out.csv", "--maps", "", "--pose", "90,90,0",
            "--offset", "1.001,264.505,129.575")
    assert r.exit_code == 2
    assert "--maps" in r.output and "empty" in r.output and "directory" not in r.output.lower()
    assert not (tmp_path / "out.csv").exists()
    with pytest.raises(cmmpose.InputError, match="maps: an empty name"):
        cmmpose.machine.read_maps([""])


@pytest.mark.parametrize("value", ["9" * 300, "9" * 300 + "x"])
def test_a_300_digit_temperature_is_not_printed_back(tmp_path, value):
    shutil.copy(SCAN, tmp_path / "a.csv")
    r = cli("compensate", tmp_path / "a.csv", tmp_path / "out.csv", *COMPENSATE, "--temperature", value)
    assert r.exit_code in (1, 2) and "Traceback" not in r.output
    assert "9" * 40 not in r.output and "0" * 40 not in r.output
    assert "temperature" in r.output.lower()
