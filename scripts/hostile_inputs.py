"""Attack the command line as a careless user, a full disk and a hostile
network would, and count what goes wrong in four classes:

- **data loss**: an input changed, a special file replaced by a regular one,
  an earlier output damaged, a temporary file left behind;
- **hang**: a command still running after ``--timeout`` seconds;
- **traceback**: a Python traceback, or an exit status other than 0 (done),
  1 (failed, or a failed conformance decision) and 2 (usage);
- **silent**: exit 0 with a wrong or incomplete answer, non-standard JSON,
  or a message that misleads (names the wrong cause or a Python argument
  the command line lacks).

    python scripts/hostile_inputs.py [--timeout 120] [--only NAME] [--list]

Every attack states what a correct tool does; the table printed at the end
counts, per class, the attacks tried and the ones that failed. Exit status 1
if any attack failed. Attacks that need root (device nodes, a full or
read-only file system on a tmpfs) are counted as skipped without it.
``fuzz_inputs.py`` is the random counterpart for the file readers.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import hashlib
import json
import os
import re
import shutil
import signal
import socket
import stat
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "data"
SCAN = DATA / "examples" / "sphere_scan.csv"
COMPENSATE = ["--maps", "thesis", "--pose", "90,90,0", "--offset", "1.001,264.505,129.575"]
CLASSES = ("data loss", "hang", "traceback", "silent")


class Skip(Exception):
    """The attack cannot be staged here (no root, no tmpfs)."""


class Failed(Exception):
    """The attack found a defect; ``kind`` is one of CLASSES."""

    def __init__(self, kind: str, detail: str):
        super().__init__(detail)
        self.kind = kind


@dataclass
class Result:
    code: int | None
    out: str
    err: str
    seconds: float

    @property
    def text(self) -> str:
        return self.out + self.err


TIMEOUT = 120.0


def cmmpose_exe() -> list[str]:
    exe = shutil.which("cmmpose")
    return [exe] if exe else [sys.executable, "-c", "from cmmpose.cli import main; main()"]


def cli(*args, cwd: Path, timeout: float | None = None, env: dict | None = None) -> Result:
    """Run one command; a timeout is a hang, a traceback or an odd exit status a crash."""
    t0 = time.monotonic()
    try:
        p = subprocess.run([*cmmpose_exe(), *map(str, args)], cwd=cwd, capture_output=True, text=True,
                           timeout=timeout or TIMEOUT, env={**os.environ, **(env or {})}, stdin=subprocess.DEVNULL)
    except subprocess.TimeoutExpired:
        raise Failed("hang", f"cmmpose {' '.join(map(str, args))}: still running after {timeout or TIMEOUT:.0f} s")
    r = Result(p.returncode, p.stdout, p.stderr, time.monotonic() - t0)
    if "Traceback (most recent call last)" in r.text or r.code not in (0, 1, 2):
        raise Failed("traceback", f"cmmpose {' '.join(map(str, args))[:120]}: exit {r.code}: {r.text.strip()[-300:]}")
    return r


def refused(r: Result, *, what: str, mentions: tuple[str, ...] = (), never: tuple[str, ...] = ()) -> None:
    """The command must refuse (exit 1 or 2) with a one-line message naming ``mentions``."""
    if r.code == 0:
        raise Failed("silent", f"{what}: accepted (exit 0)")
    low = r.text.lower()
    for m in mentions:
        if m.lower() not in low:
            raise Failed("silent", f"{what}: the message does not name {m!r}: {r.text.strip()[-300:]}")
    for m in never:
        if m.lower() in low:
            raise Failed("silent", f"{what}: the message misleads ({m!r}): {r.text.strip()[-300:]}")


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def leftovers(folder: Path, keep: set[str]) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name not in keep)


def need_root() -> None:
    if os.geteuid() != 0:
        raise Skip("needs root")


@contextlib.contextmanager
def tmpfs(work: Path, size: str = "256k"):
    """A small tmpfs at ``work/fs`` (a full or read-only disk to write to)."""
    need_root()
    mnt = work / "fs"
    mnt.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(mnt)],
                      capture_output=True).returncode:
        raise Skip("cannot mount a tmpfs")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


def fill(folder: Path) -> None:
    """Fill the file system of ``folder`` to the last byte."""
    fd = os.open(folder / "filler", os.O_WRONLY | os.O_CREAT)
    try:
        for block in (1 << 20, 4096, 1):
            with contextlib.suppress(OSError):
                while os.write(fd, b"\0" * block):
                    pass
    finally:
        os.close(fd)


def scan_copy(work: Path, name: str = "a.csv") -> Path:
    p = work / name
    shutil.copyfile(SCAN, p)
    return p


def small_run(work: Path, name: str = "run", *extra) -> Path:
    cli("simulate", "--seed", 1, *extra, "-o", work / name, cwd=work)
    return work / name


# ---------------------------------------------------------------------------------------------- data loss
def same_file(work: Path, spelling: str) -> None:
    a = scan_copy(work)
    before = digest(a)
    if spelling == "symlink":
        (work / "link.csv").symlink_to(a)
        out = "link.csv"
    elif spelling == "hardlink":
        os.link(a, work / "hard.csv")
        out = "hard.csv"
    elif spelling == "dotted":
        (work / "sub").mkdir()
        out = "sub/../a.csv"
    else:
        out = "a.csv"
    r = cli("compensate", "a.csv", out, *COMPENSATE, cwd=work)
    if digest(a) != before:
        raise Failed("data loss", f"compensate a.csv {out}: the input was overwritten (exit {r.code})")
    refused(r, what=f"compensate a.csv {out}", mentions=("a.csv",))


def device_output(work: Path) -> None:
    need_root()
    scan_copy(work)
    node = work / "null.csv"
    os.mknod(node, 0o666 | stat.S_IFCHR, os.makedev(1, 3))  # a private /dev/null
    cli("compensate", "a.csv", "null.csv", *COMPENSATE, cwd=work)
    if not stat.S_ISCHR(node.lstat().st_mode):
        raise Failed("data loss", "compensate to a character device replaced it by a regular file")
    if leftovers(work, {"a.csv", "null.csv"}):
        raise Failed("data loss", f"temporary files left: {leftovers(work, {'a.csv', 'null.csv'})}")


def fifo_output(work: Path) -> None:
    scan_copy(work)
    fifo = work / "out.csv"
    os.mkfifo(fifo)
    got: list[bytes] = []
    reader = threading.Thread(target=lambda: got.append(open(fifo, "rb").read()), daemon=True)
    reader.start()
    r = cli("compensate", "a.csv", "out.csv", *COMPENSATE, cwd=work)
    reader.join(timeout=30)
    if not stat.S_ISFIFO(fifo.lstat().st_mode):
        raise Failed("data loss", "compensate to a FIFO replaced it by a regular file")
    if reader.is_alive():
        with contextlib.suppress(OSError):  # unblock the reader
            os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))
        raise Failed("silent", f"compensate to a FIFO: nothing was written to it (exit {r.code})")
    lines = got[0].decode().splitlines() if got else []
    if r.code != 0 or len(lines) != 3905:
        raise Failed("silent", f"compensate to a FIFO: exit {r.code}, {len(lines)} lines read (want 3905)")


def directory_output(work: Path) -> None:
    scan_copy(work)
    (work / "out.csv").mkdir()
    (work / "out.csv" / "keep.txt").write_text("mine")
    r = cli("compensate", "a.csv", "out.csv", *COMPENSATE, cwd=work)
    if (work / "out.csv" / "keep.txt").read_text() != "mine":
        raise Failed("data loss", "compensate into a folder named like a file damaged it")
    refused(r, what="compensate to a folder", mentions=("out.csv",))


def full_disk(work: Path, writer: str) -> None:
    """Each writer, on a disk with no space left, fails with a clear message and
    leaves the earlier file (or run) whole and no temporary file behind."""
    scan_copy(work)
    if writer == "simulate":
        small_run(work, "old")
    with tmpfs(work, size="64m") as fs:
        earlier = fs / {"compensate": "prev.csv", "machine": "prev.toml", "artefact": "prev.toml", "model": "prev.json",
                        "simulate": "run", "map": "prev_map.csv", "report": "rep"}[writer]
        if writer == "simulate":
            shutil.copytree(work / "old", earlier)
            before = {p.name: digest(p) for p in earlier.iterdir() if p.is_file()}
        elif writer == "report":
            earlier.mkdir()
            (earlier / "evaluation.json").write_text('{"earlier": true}')
            before = {"evaluation.json": digest(earlier / "evaluation.json")}
        else:
            earlier.write_text("earlier content\n")
            before = {earlier.name: digest(earlier)}
        keep = {earlier.name, "filler"}
        if writer == "model":
            small_run(work, "r")
        if writer == "report":
            small_run(work, "r")
        fill(fs)
        args = {
            "compensate": ("compensate", "a.csv", earlier, *COMPENSATE, "--overwrite"),
            "machine": ("machine", "example", "moving-bridge", "-o", earlier, "--overwrite"),
            "artefact": ("artefact", "example", "ball-plate", "-o", earlier, "--overwrite"),
            "model": ("diagnose", "r", "--save-model", earlier, "--overwrite"),
            "simulate": ("simulate", "--seed", 2, "--overwrite", "-o", earlier),
            "map": ("map", "export", "thesis", "--format", "iso230-2", "-o", earlier, "--overwrite"),
            "report": ("evaluate", "r", "--report", earlier, "--overwrite"),
        }[writer]
        r = cli(*args, cwd=work)
        now = {p.name: digest(p) for p in (earlier.iterdir() if earlier.is_dir() else [earlier]) if p.is_file()} \
            if earlier.exists() else {}
        if any(now.get(k) != v for k, v in before.items()):
            raise Failed("data loss", f"{writer} on a full disk damaged the earlier {earlier.name} (exit {r.code})")
        extra = leftovers(fs, keep)
        if extra:
            raise Failed("data loss", f"{writer} on a full disk left {extra}")
        refused(r, what=f"{writer} on a full disk", never=("no such file",))


def read_only_output(work: Path) -> None:
    scan_copy(work)
    with tmpfs(work) as fs:
        if subprocess.run(["mount", "-o", "remount,ro", str(fs)], capture_output=True).returncode:
            raise Skip("cannot remount read-only")
        r = cli("compensate", "a.csv", fs / "out.csv", *COMPENSATE, cwd=work)
        refused(r, what="compensate to a read-only disk", mentions=("out.csv",))


def read_only_example(work: Path) -> None:
    """artefact example -o on a read-only file system: a one-line error naming the file, no traceback."""
    with tmpfs(work) as fs:
        if subprocess.run(["mount", "-o", "remount,ro", str(fs)], capture_output=True).returncode:
            raise Skip("cannot remount read-only")
        r = cli("artefact", "example", "ballbar", "-o", fs / "a.toml", cwd=work)
        refused(r, what="artefact example to a read-only disk", mentions=("a.toml", "read-only"))


def killed_mid_write(work: Path, sig: int) -> None:
    """SIGTERM or SIGHUP during a large write leaves the earlier output whole and no temporary file."""
    rows = np.loadtxt(SCAN, delimiter=",", skiprows=1)
    big = np.tile(rows, (300, 1))  # 1.2 million points: about a second of work
    np.save(work / "big.npy", big[:, :5])
    (work / "out.csv").write_text("earlier\n")
    proc = subprocess.Popen([*cmmpose_exe(), "compensate", "big.npy", "out.csv", *COMPENSATE], cwd=work,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and not leftovers(work, {"big.npy", "out.csv"}) and proc.poll() is None:
        time.sleep(0.02)
    proc.send_signal(sig)
    try:
        out, err = proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        raise Failed("hang", f"compensate ignored signal {sig} for 30 s")
    if "Traceback" in out + err:
        raise Failed("traceback", f"signal {sig}: {err.strip()[-300:]}")
    if (work / "out.csv").read_text() != "earlier\n":
        raise Failed("data loss", f"signal {sig} mid-write: the earlier output changed")
    if leftovers(work, {"big.npy", "out.csv"}):
        raise Failed("data loss", f"signal {sig} mid-write left {leftovers(work, {'big.npy', 'out.csv'})}")


def umask_respected(work: Path) -> None:
    scan_copy(work)
    old = os.umask(0o022)
    try:
        cli("compensate", "a.csv", "out.csv", *COMPENSATE, cwd=work)
    finally:
        os.umask(old)
    mode = stat.S_IMODE((work / "out.csv").stat().st_mode)
    if mode != 0o644:
        raise Failed("silent", f"output mode {mode:o} under umask 022 (want 644)")


# ---------------------------------------------------------------------------------------------- hangs
@contextlib.contextmanager
def server(answer: bytes | None):
    """A local TCP server that accepts and never answers (``answer`` None) or
    answers every connection with ``answer``."""
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    s.listen(16)
    s.settimeout(0.2)
    stop = threading.Event()
    held = []

    def loop():
        while not stop.is_set():
            try:
                c, _ = s.accept()
            except OSError:
                continue
            held.append(c)
            if answer is not None:
                with contextlib.suppress(OSError):
                    c.recv(4096)
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


def parquet_folder(work: Path) -> Path:
    rows = np.loadtxt(SCAN, delimiter=",", skiprows=1)
    folder = work / "pq"
    folder.mkdir()
    pq.write_table(pa.table({n: rows[:, k] for k, n in enumerate("u v D E F".split())}), folder / "part0.parquet")
    return folder


def scheduler(work: Path, kind: str) -> None:
    parquet_folder(work)
    if kind == "url":
        r = cli("compensate", "pq", "outpq", *COMPENSATE, "--temperature", 22, "--scheduler", "http://127.0.0.1:8787",
                cwd=work)
        refused(r, what="--scheduler http://...", mentions=("tcp://",))
        return
    answer = None if kind == "silent" else b"HTTP/1.1 200 OK\r\nContent-Length: 2\r\n\r\nok"
    with server(answer) as port:
        r = cli("compensate", "pq", "outpq", *COMPENSATE, "--temperature", 22, "--scheduler",
                f"tcp://127.0.0.1:{port}", cwd=work)
    refused(r, what=f"--scheduler at a {kind} server", mentions=(f"127.0.0.1:{port}",))


# ---------------------------------------------------------------------------------------------- tracebacks and misleading messages
def parquet_repeated_column(work: Path) -> None:
    rows = np.loadtxt(SCAN, delimiter=",", skiprows=1)[:10]
    cols = [pa.array(rows[:, k]) for k in range(5)] + [pa.array(rows[:, 0])]
    pq.write_table(pa.Table.from_arrays(cols, names=["u", "v", "D", "E", "F", "u"]), work / "dup.parquet")
    refused(cli("compensate", "dup.parquet", "out.csv", *COMPENSATE, cwd=work), what="Parquet repeated column",
            mentions=("dup.parquet",))


def ply_huge_count(work: Path) -> None:
    (work / "huge.ply").write_text("ply\nformat ascii 1.0\nelement vertex 1000000000000\nproperty double x\n"
                                   "property double y\nproperty double z\nend_header\n1 2 3\n")
    refused(cli("fit", "huge.ply", cwd=work), what="PLY declaring 1e12 vertices", mentions=("huge.ply",))


def toml_attack(work: Path, kind: str) -> None:
    text = (DATA / "machines" / "moving-bridge.toml").read_text()
    if kind == "deep":
        text += "\nx = " + "[" * 10000 + "]" * 10000 + "\n"
    else:
        text += "\nbig = " + "9" * 5001 + "\n"
    (work / "m.toml").write_text(text)
    refused(cli("machine", "check", "m.toml", cwd=work), what=f"TOML {kind}", mentions=("m.toml",))


def fits_header_only(work: Path) -> None:
    (work / "fits.csv").write_text("position,ball,x_mm,y_mm,z_mm,radius_mm\n")
    refused(cli("diagnose-fits", "fits.csv", cwd=work), what="diagnose-fits without rows", mentions=("fits.csv",))


def full_device_output(work: Path) -> None:
    need_root()
    scan_copy(work)
    node = work / "full.csv"
    os.mknod(node, 0o666 | stat.S_IFCHR, os.makedev(1, 7))  # a private /dev/full
    r = cli("compensate", "a.csv", "full.csv", *COMPENSATE, cwd=work)
    if not stat.S_ISCHR(node.lstat().st_mode):
        raise Failed("data loss", "compensate to /dev/full replaced the device")
    refused(r, what="compensate to /dev/full", mentions=("full.csv",))


def special_input(work: Path, kind: str) -> None:
    if kind == "fifo":
        os.mkfifo(work / "in.csv")
        name = "in.csv"
    else:
        name = "/dev/zero"
    r = cli("compensate", name, "out.csv", *COMPENSATE, cwd=work, timeout=60)
    refused(r, what=f"compensate from a {kind}", never=("no such file",))


def outlier_fit(work: Path) -> None:
    rng = np.random.default_rng(0)
    d = rng.normal(size=(500, 3))
    pts = 20.0 * d / np.linalg.norm(d, axis=1, keepdims=True)
    pts[17] = [1e12, 0, 0]
    np.savetxt(work / "ball.csv", pts, delimiter=",", header="x,y,z", comments="")
    r = cli("fit", "ball.csv", cwd=work)
    if r.code != 0:
        refused(r, what="a 1e12 mm outlier", never=("collinear",))


def empty_maps(work: Path) -> None:
    scan_copy(work)
    r = cli("compensate", "a.csv", "out.csv", "--maps", "", "--pose", "90,90,0", "--offset", "1.001,264.505,129.575",
            cwd=work)
    refused(r, what='--maps ""', never=("directory", "folder "))
    if r.code != 2:
        raise Failed("silent", f'--maps "": exit {r.code}, a usage error is 2')


def long_number_echo(work: Path) -> None:
    scan_copy(work)
    r = cli("compensate", "a.csv", "out.csv", *COMPENSATE, "--temperature", "9" * 300, cwd=work)
    refused(r, what="a 300-digit temperature")
    if "9" * 40 in r.text:
        raise Failed("silent", "a 300-digit temperature printed back in full")


def python_hint(work: Path) -> None:
    rows = SCAN.read_text().splitlines()
    rows[5] = "nan,0,450,275,-250,22"
    (work / "nan.csv").write_text("\n".join(rows) + "\n")
    r = cli("compensate", "nan.csv", "out.csv", *COMPENSATE, cwd=work)
    refused(r, what="a NaN row", never=("nan_policy=", "on_gap=", "out_of_range="))


# ---------------------------------------------------------------------------------------------- silent wrong answers
def relabelled_scan(work: Path, how: str) -> None:
    run = small_run(work)
    t = pq.read_table(run / "scans.parquet").to_pydict()
    if how == "ball=3":
        t["ball"][5] = 3
    elif how == "position=-1":
        t["position"][5] = -1
    else:  # a duplicate: scan 5 claims scan 4's position and ball
        t["position"][5], t["ball"][5] = t["position"][4], t["ball"][4]
    schema = pq.read_schema(run / "scans.parquet")
    pq.write_table(pa.table(t, schema=schema.remove_metadata()), run / "scans.parquet")
    for command in (("evaluate", "run"), ("standards", "acceptance", "run", "--mpe-form", 60, "--mpe-size", 10,
                                          "--mpe-length", "8+L/300")):
        name = " ".join(command[:2]) if command[0] == "standards" else command[0]
        r = cli(*command, cwd=work)
        if r.code == 0 and "skip" not in r.text.lower():
            raise Failed("silent", f"{name} with a scan labelled {how}: exit 0 and no word of it")
        if r.code != 0:
            refused(r, what=f"{name} with a scan labelled {how}")


def failed_acceptance_exit(work: Path) -> None:
    small_run(work, "run", "--jitter", 3, "--calibrated")
    r = cli("standards", "acceptance", "run", "--mpe-form", 0.01, "--mpe-size", 0.01, "--mpe-length", "0.01", cwd=work)
    if "FAIL" not in r.text:
        raise Failed("silent", "acceptance against a 0.01 um MPE did not fail")
    if r.code != 1:
        raise Failed("silent", f"acceptance FAIL exited {r.code} (want 1)")


def map_attack(work: Path, kind: str) -> None:
    src = (DATA / "maps" / "thesis_20C.csv").read_text().splitlines(keepends=True)
    if kind == "repeated key":
        i = next(k for k, line in enumerate(src) if "squareness_xy" in line)
        src.insert(i + 1, src[i].replace("-173", "-1000") if "-173" in src[i] else src[i])
    else:  # cut at a row boundary: the X table's last 4 rows (x > 800 mm, beyond the scan) gone
        last_x = max(k for k, line in enumerate(src) if line.startswith("X,"))
        del src[last_x - 3:last_x + 1]
    (work / "m.csv").write_text("".join(src))
    scan_copy(work)
    r = cli("compensate", "a.csv", "out.csv", "--maps", "m.csv", "--temperature", 20, "--pose", "90,90,0",
            "--offset", "1.001,264.505,129.575", cwd=work)
    refused(r, what=f"map CSV {kind}", mentions=("m.csv",))


def fits_attack(work: Path, kind: str) -> None:
    lines = [line for line in (DATA / "thesis" / "appendix_c_ballbar.csv").read_text().splitlines()
             if not line.startswith("#")]
    rows = list(csv.reader(lines))
    header, body = rows[0], rows[1:]
    if kind == "repeated row":
        body.append(list(body[3]))
        body[-1][header.index("x_mm")] = str(float(body[-1][header.index("x_mm")]) + 1.0)
    else:
        header = header + [header[2]]
        body = [b + [b[2]] for b in body]
    with open(work / "fits.csv", "w", newline="") as f:
        csv.writer(f).writerows([header, *body])
    refused(cli("diagnose-fits", "fits.csv", "--nominal-radius", 38.125, "--state", "compensated", cwd=work),
            what=f"diagnose-fits {kind}", mentions=("fits.csv",))


def positioning(work: Path, kind: str) -> None:
    rows = [("target_mm", "direction", "cycle", "deviation_um")]
    for t in range(0, 500, 50):
        for d in (1, -1):
            for c in range(1, 6):
                rows.append((t, d, c, 1.0 + 0.01 * t + 0.3 * c))
    if kind == "1e300":
        rows[7] = (*rows[7][:3], 1e300)
        rows[8] = (*rows[8][:3], -1e300)
    elif kind == "repeated row":
        rows.append(rows[4][:3] + (99.0,))
    else:
        rows = [r + (r[3],) for r in rows]
    with open(work / "pos.csv", "w", newline="") as f:
        csv.writer(f).writerows(rows)
    r = cli("standards", "iso230-2", "pos.csv", "--json", cwd=work)
    if kind == "1e300" and r.code == 0:
        def bad(x):
            raise ValueError(x)
        try:
            json.loads(r.out, parse_constant=bad)
        except ValueError as e:
            raise Failed("silent", f"iso230-2 --json printed non-standard JSON ({e})")
        return
    refused(r, what=f"iso230-2 {kind}", mentions=("pos.csv",))


def csv_writer_huge(work: Path) -> None:
    import cmmpose
    xyz = np.array([[1e305, -3e303, 1.7976931348623157e308], [1.0, 2.0, 3.0]])
    try:
        cmmpose.write_point_cloud(work / "big.csv", cmmpose.PointCloud(xyz))
    except cmmpose.Error:
        return
    back = cmmpose.read_point_cloud(work / "big.csv").xyz
    if not np.array_equal(back, xyz):
        raise Failed("silent", f"the CSV writer wrote {back[0].tolist()} for {xyz[0].tolist()}")


def ply_body_mismatch(work: Path) -> None:
    pts = np.loadtxt(SCAN, delimiter=",", skiprows=1)[:, :3]
    body = "\n".join(" ".join(f"{v:.4f}" for v in p) for p in pts)
    (work / "s.ply").write_text("ply\nformat ascii 1.0\nelement vertex 100\nproperty double x\nproperty double y\n"
                                f"property double z\nend_header\n{body}\n")
    refused(cli("fit", "s.ply", cwd=work), what="PLY body longer than its header", mentions=("s.ply",))


def run_table_cut(work: Path) -> None:
    run = small_run(work)
    t = pq.read_table(run / "points.parquet")
    pq.write_table(t.slice(0, t.num_rows - 100), run / "points.parquet")
    refused(cli("evaluate", "run", cwd=work), what="a points table cut short", mentions=("points",))


def thermocouple_attack(work: Path, kind: str, command: str) -> None:
    """A dropped thermocouple (one channel a constant 1e6 C, an open circuit) or
    a log that ends before the last points and is held: ``command`` must say
    which channel it dropped and why, or how many points it held and for how
    long, in its printed output and in its JSON (the temperature provenance)."""
    import dataclasses

    from cmmpose.run import Run

    saved = Run.load(small_run(work, "clean", *(("--calibrated",) if command == "acceptance" else ())))
    log = {k: np.array(v, dtype=float, copy=True) for k, v in saved.temperatures.items()}
    channel = saved.temperature_channels[0]["name"]
    if kind == "dropped":
        log[channel][:] = 1e6
    else:  # the logger stopped 5 s before the last point
        keep = log["t"] <= float(np.max(saved.points["t"])) - 5.0
        log = {k: v[keep] for k, v in log.items()}
    dataclasses.replace(saved, temperatures=log).save(work / "run")  # run.json counts the rows anew
    args = {"evaluate": ("evaluate", "run"), "diagnose": ("diagnose", "run", "--max-effects", 1),
            "acceptance": ("standards", "acceptance", "run", "--mpe-form", 60, "--mpe-size", 10, "--mpe-length",
                           "8+L/300")}[command]
    what = f"{command} with {'thermocouple ' + channel + ' at a constant 1e6 C' if kind == 'dropped' else 'a log held past its end'}"
    printed = cli(*args, cwd=work)
    if printed.code not in (0, 1):
        refused(printed, what=what)
        return
    text = " ".join(printed.text.split())
    said = (f"thermocouple {channel}" in text and "1e+06" in text) if kind == "dropped" else "does not cover" in text
    if not said:
        raise Failed("silent", f"{what}: exit {printed.code} and the printed output does not say so")
    r = cli(*args, "--json", cwd=work)
    try:
        doc = json.loads(r.out)
    except ValueError:
        raise Failed("silent", f"{what}: --json printed no JSON (exit {r.code})")
    log = {"evaluate": lambda d: d["provenance"]["temperature"].get("log"),
           "diagnose": lambda d: d["provenance"].get("temperature_log"),
           "acceptance": lambda d: d.get("temperature_log")}[command](doc) or {}
    if kind == "dropped":
        ok = any(d.get("channel") == channel and d.get("why") for d in log.get("channels_dropped", []))
    else:
        held = log.get("held") or {}
        ok = held.get("points", 0) > 0 and held.get("after_log_s", 0) > 0
    if not ok:
        raise Failed("silent", f"{what}: the JSON's temperature provenance does not say so: {json.dumps(log)[:200]}")


def machine_attack(work: Path, kind: str) -> None:
    text = (DATA / "machines" / "moving-bridge.toml").read_text()
    if kind == "no [mount]":
        out, skip = [], False
        for line in text.splitlines():
            if line.strip().startswith("["):
                skip = line.strip().startswith("[mount")
            if not skip:
                out.append(line)
        text = "\n".join(out) + "\n"
    elif kind == "negative expansion":
        lines = text.splitlines()
        k = next(i for i, line in enumerate(lines) if line.startswith("artefact ="))
        lines[k] = lines[k].split("=")[0] + "= -1e9"
        text = "\n".join(lines) + "\n"
    else:  # a number as a string
        lines = text.splitlines()
        k = next(i for i, line in enumerate(lines) if "=" in line and any(c.isdigit() for c in line.split("=")[1])
                 and not line.lstrip().startswith("#") and '"' not in line)
        key, value = lines[k].split("=", 1)
        lines[k] = f'{key}= "{value.split("#")[0].strip()}"'
        text = "\n".join(lines) + "\n"
    (work / "m.toml").write_text(text)
    r = cli("machine", "check", "m.toml", cwd=work)
    if r.code == 0 and not (kind == "no [mount]" and "default" in r.text.lower()):
        raise Failed("silent", f"machine check with {kind}: ok")


def alignment_units(work: Path) -> None:
    lib = work / "align.json"
    for name, pose, normal in (("A", "90,90,0", "0,0,1"), ("B", "90,90,90", "0,-1,0"), ("C", "180,90,0", "0,0,1")):
        cli("calibrate", "simulate-alignment", "--pose", pose, "--name", name, "-o", "al", cwd=work)
        cli("calibrate", "alignment", "--vernier", f"al/{name}-vernier.csv", "--plane-scan", f"al/{name}-plane.csv",
            "--plane-normal", normal, "--vernier-uncertainty", 9, "--reference-scan", f"al/{name}-sphere.csv", "--name", name, "--library", lib,
            "--maps", "thesis", "--temperature", 20, cwd=work)
    doc = json.loads(lib.read_text())
    text = json.dumps(doc)
    if '"degree' not in text and '"deg' not in text:
        raise Skip("the library names no angle unit")
    lib.write_text(text.replace('"degree"', '"radian"').replace('"deg"', '"rad"'))
    r = cli("calibrate", "offset", "A", "B", "C", "--library", lib, "--json", cwd=work)
    refused(r, what="an alignment library in radians", mentions=("align.json",))


def empty_option(work: Path, option: str, value: str) -> None:
    scan_copy(work)
    args = {"--maps": "thesis", "--pose": "90,90,0", "--offset": "1.001,264.505,129.575", option: value}
    r = cli("compensate", "a.csv", "out.csv", *[x for kv in args.items() for x in kv], cwd=work)
    refused(r, what=f"{option} {value!r}", mentions=(option,))
    if r.code != 2:
        raise Failed("silent", f"{option} {value!r}: exit {r.code}, a usage error is 2")


# ---------------------------------------------------------------------------------------------- one door out (issue 35)
def started_together(work: Path, command: str) -> None:
    """Two writers of one output started together: exactly one succeeds, the other fails with a clear
    message naming the output, and the output is whole (never both exit 0 with one result lost)."""
    if command == "compensate":
        scan_copy(work)
    target = work / {"simulate": "same", "artefact": "a.toml", "machine": "m.toml", "compensate": "x.csv"}[command]
    argv = {"simulate": [["simulate", "--seed", s, "-o", target] for s in (1, 2)],
            "artefact": [["artefact", "example", k, "-o", target] for k in ("ballbar", "sphere")],
            "machine": [["machine", "example", k, "-o", target] for k in ("thesis", "gantry")],
            "compensate": [["compensate", "a.csv", target, *COMPENSATE, "--temperature", t] for t in (21, 23)]}[command]
    procs = [subprocess.Popen([*cmmpose_exe(), *map(str, a)], cwd=work, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True, stdin=subprocess.DEVNULL) for a in argv]
    try:
        outs = [p.communicate(timeout=TIMEOUT) for p in procs]
    except subprocess.TimeoutExpired:
        for p in procs:
            p.kill()
        raise Failed("hang", f"two {command} -o {target.name}: still running after {TIMEOUT:.0f} s") from None
    codes = sorted(p.returncode for p in procs)
    if codes == [0, 0]:
        raise Failed("data loss", f"two {command} -o {target.name} started together both exit 0: one result is gone")
    if codes != [0, 1]:
        raise Failed("traceback", f"two {command} -o {target.name}: exits {codes}: {outs}")
    loser = outs[[p.returncode for p in procs].index(1)]
    if target.name not in loser[1] or "Traceback" in loser[1]:
        raise Failed("silent", f"two {command}: the refusal does not name {target.name}: {loser[1][-300:]}")
    extra = leftovers(work, {target.name, "a.csv"})
    if extra:
        raise Failed("data loss", f"two {command}: left {extra}")
    if command == "simulate":
        check = subprocess.run([sys.executable, "-c", f"import cmmpose.run as r; r.Run.load({str(target)!r})"],
                               capture_output=True, text=True)
        if check.returncode:
            raise Failed("data loss", f"two simulate -o same: the run left does not load: {check.stderr[-300:]}")


#: The commands that write a file, each with its arguments (run in a folder holding a.csv, the run r, m.csv and
#: linear.csv) and the output it writes: without --overwrite an existing one is refused before any work.
EXISTING_OUTPUTS = {
    "compensate": (("compensate", "a.csv", "o.csv", *COMPENSATE), "o.csv"),
    "evaluate --report": (("evaluate", "r", "--report", "R"), "R/evaluation.json"),
    "diagnose --save-model": (("diagnose", "r", "--save-model", "model.json", "--no-auto"), "model.json"),
    "diagnose --report": (("diagnose", "r", "--report", "D", "--no-auto"), "D/diagnose.html"),
    "diagnose --corrected-maps": (("diagnose", "r", "--corrected-maps", "cm.csv", "--no-auto"), "cm_30C.csv"),
    "map export": (("map", "export", "m.csv", "--format", "iso230-2", "-o", "e.csv"), "e.csv"),
    "map export linuxcnc": (("map", "export", "m.csv", "--format", "linuxcnc", "-o", "comp"), "comp/z.comp"),
    "map import": (("map", "import", "iso230-2", "linear.csv", "-o", "i.csv"), "i.csv"),
    "map plot": (("map", "plot", "m.csv", "-o", "p.png"), "p.png"),
    "map table-motion": (("map", "table-motion", "m.csv", "--carriage", "Y", "--measured-at", "0,0,0",
                          "--part-point", "300,100,50", "-o", "t.csv"), "t.csv"),
    "calibrate map": (("calibrate", "map", *sorted(map(str, (DATA / "examples" / "interferometer").glob("*.csv"))),
                       "--squareness", "-173,-19,21", "-o", "c.csv"), "c.csv"),
    "calibrate simulate-alignment": (("calibrate", "simulate-alignment", "--pose", "90,90,0", "--name", "A",
                                      "-o", "al"), "al/A-plane.csv"),
    "standards iso230-2 --report": (("standards", "iso230-2", str(DATA / "examples" / "interferometer" / "x_dx.csv"),
                                     "--report", "S"), "S/iso230-2.json"),
    "standards interim-check --report": (("standards", "interim-check", "r", "--report", "I"),
                                         "I/interim-check.md"),
    "artefact plan": (("artefact", "plan", "koba-0320", "-o", "plan.json"), "plan.json"),
    "demo --report": (("demo", "--report", "dm"), "dm/evaluation.json"),
}


def _outputs_inputs(work: Path) -> None:
    """What the EXISTING_OUTPUTS commands read: a.csv, the run r, the map m.csv and linear.csv."""
    scan_copy(work)
    small_run(work, "r")
    code = ("import sys, cmmpose\nm = cmmpose.ErrorMapSet.thesis().at(20)\nm.write(sys.argv[1])\n"
            "m.write(sys.argv[2], format='iso230-2')")
    subprocess.run([sys.executable, "-c", code, str(work / "m.csv"), str(work / "linear.csv")], check=True)


def existing_output(work: Path, command: str) -> None:
    """An output that exists, without --overwrite: refused (exit 1) before any work with one line naming it and
    --overwrite; the file, its modification time and the folder left as they were. With --overwrite the file
    is replaced."""
    _outputs_inputs(work)
    args, out = EXISTING_OUTPUTS[command]
    target = work / out
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_text("earlier\n")
    os.utime(target, (1_000_000_000, 1_000_000_000))
    before = sorted(str(p.relative_to(work)) for p in work.rglob("*"))
    t0 = time.monotonic()
    r = cli(*args, cwd=work)
    if target.read_text() != "earlier\n" or target.stat().st_mtime != 1_000_000_000:
        raise Failed("data loss", f"{command}: an existing {out} was replaced without --overwrite (exit {r.code})")
    after = sorted(str(p.relative_to(work)) for p in work.rglob("*"))
    if after != before:
        raise Failed("data loss", f"{command}: refused, but wrote {sorted(set(after) - set(before))[:4]}")
    refused(r, what=f"{command} over an existing {out}", mentions=(target.name, "use --overwrite to replace it"))
    if r.code != 1 or len([ln for ln in r.err.splitlines() if ln.startswith("Error:")]) != 1:
        raise Failed("silent", f"{command} over an existing {out}: exit {r.code}, not one line: {r.err[-300:]}")
    if time.monotonic() - t0 > 30:
        raise Failed("silent", f"{command} over an existing {out}: refused only after {time.monotonic() - t0:.0f} s")
    r = cli(*args, "--overwrite", cwd=work)
    if r.code not in (0, 1) or target.read_bytes() == b"earlier\n":
        raise Failed("silent", f"{command} --overwrite did not replace {out} (exit {r.code}): {r.text[-300:]}")


def overwrite_never_an_input(work: Path, command: str) -> None:
    """--overwrite replaces an earlier output, never an input: an output that is an input through a symbolic
    link is refused, the input unchanged."""
    _outputs_inputs(work)
    named, args = {
        "compensate": ("a.csv", ("compensate", "a.csv", "link.csv", *COMPENSATE)),
        "compensate (its --maps file)": ("m.csv", ("compensate", "a.csv", "link.csv", "--maps", "m.csv",
                                                   "--temperature", 20, "--pose", "90,90,0", "--offset",
                                                   "1.001,264.505,129.575")),
        "map import": ("linear.csv", ("map", "import", "iso230-2", "linear.csv", "-o", "link.csv")),
        "map export": ("m.csv", ("map", "export", "m.csv", "--format", "iso230-2", "-o", "link.csv")),
        "diagnose --save-model": ("r/run.json", ("diagnose", "r", "--save-model", "link.csv", "--no-auto")),
        "evaluate --report": ("r/run.json", ("evaluate", "r", "--report", "R")),
    }[command]
    if command == "evaluate --report":
        (work / "R").mkdir()
        (work / "R" / "evaluation.json").symlink_to(work / named)
    else:
        (work / "link.csv").symlink_to(work / named)
    before = digest(work / named)
    r = cli(*args, "--overwrite", cwd=work)
    if digest(work / named) != before:
        raise Failed("data loss", f"{command} --overwrite through a link to its input {named}: the input changed")
    refused(r, what=f"{command} --overwrite through a link to its input", mentions=(Path(named).name, "input"))


def _map_inputs(work: Path) -> tuple[list[str], dict[str, str]]:
    """The thesis maps as files in/cm_20C.csv, in/cm_25C.csv, in/cm_30C.csv: --maps arguments and digests."""
    (work / "in").mkdir()
    code = ("import cmmpose,sys\nfor m in cmmpose.ErrorMapSet.thesis().maps: "
            "m.write(f'{sys.argv[1]}/cm_{m.temperature:g}C.csv')")
    subprocess.run([sys.executable, "-c", code, str(work / "in")], check=True)
    files = sorted((work / "in").glob("cm_*C.csv"))
    return [a for f in files for a in ("--maps", str(f))], {f.name: digest(f) for f in files}


def corrected_maps_over_inputs(work: Path, via: str) -> None:
    """diagnose --corrected-maps in/cm.csv derives cm_20C.csv ... : never written over the input maps of
    those names, given by --maps or as a machine file's own maps; refused naming the input."""
    small_run(work, "r")
    maps, before = _map_inputs(work)
    if via == "machine":
        r = cli("machine", "example", "thesis", "-o", "m.toml", cwd=work)
        text = (work / "m.toml").read_text()
        files = ", ".join(f'"{work / "in" / n}"' for n in sorted(before))
        (work / "m.toml").write_text(text.replace('bundled = "thesis"', f"files = [{files}]"))
        maps = ["--machine", "m.toml"]
    r = cli("diagnose", "r", *maps, "--corrected-maps", "in/cm.csv", cwd=work)
    now = {p.name: digest(p) for p in (work / "in").iterdir()}
    if now != before:
        raise Failed("data loss", f"diagnose --corrected-maps over the {via} maps: the inputs changed (exit {r.code})")
    refused(r, what=f"diagnose --corrected-maps over the {via} maps", mentions=("cm_20C.csv", "input"))


def corrected_maps_full_disk(work: Path) -> None:
    """On a disk with room for one map of three, --corrected-maps leaves no part of the set and does not
    say 'unchanged' of files it changed."""
    small_run(work, "r")
    maps, _ = _map_inputs(work)
    with tmpfs(work, size="64m") as fs:
        spacer = fs / "spacer"
        spacer.write_bytes(b"\0" * 8192)  # room for two of the three maps when freed
        fill(fs)
        spacer.unlink()
        r = cli("diagnose", "r", *maps, "--corrected-maps", fs / "cm.csv", cwd=work)
        extra = leftovers(fs, {"filler"})
        if extra:
            raise Failed("data loss", f"--corrected-maps on a full disk left {extra} (exit {r.code})")
        refused(r, what="--corrected-maps on a full disk", mentions=("cm_",), never=("no such file",))


def evaluate_report_named_runs(work: Path) -> None:
    """evaluate of runs in folders named like its report files: refused before any report is written."""
    run = small_run(work, "r")
    shutil.copytree(run, work / "x" / "summary.csv")
    shutil.copytree(run, work / "y" / "b")
    r = cli("evaluate", "x/summary.csv", "y/b", "--report", "R", cwd=work)
    written = sorted(str(p.relative_to(work / "R")) for p in (work / "R").rglob("*")) if (work / "R").exists() else []
    if written:
        raise Failed("data loss" if r.code else "silent",
                     f"evaluate of a run named summary.csv wrote {written[:4]} (exit {r.code})")
    refused(r, what="evaluate of a run named summary.csv", mentions=("summary.csv",))


def long_output_name(work: Path) -> None:
    """A legal 254-character output name works (the temporary name beside it is short)."""
    scan_copy(work)
    name = "o" * 250 + ".csv"
    r = cli("compensate", "a.csv", name, *COMPENSATE, cwd=work)
    if r.code != 0 or not (work / name).is_file():
        raise Failed("silent", f"compensate to a 254-character name: exit {r.code}: {r.text.strip()[-200:]}")
    r = cli("simulate", "--seed", 1, "-o", "r" * 254, cwd=work)
    if r.code != 0:
        raise Failed("silent", f"simulate into a 254-character folder: exit {r.code}: {r.text.strip()[-200:]}")


def unknown_output_suffix(work: Path) -> None:
    scan_copy(work)
    r = cli("compensate", "a.csv", "out.txt", *COMPENSATE, cwd=work)
    if (work / "out.txt").exists():
        raise Failed("silent", "compensate a.csv out.txt: wrote a file (CSV under a name that does not say so)")
    refused(r, what="compensate a.csv out.txt", mentions=("out.txt", ".csv", ".parquet"))


def wrong_map_name(work: Path) -> None:
    scan_copy(work)
    r = cli("compensate", "a.csv", "o.csv", "--maps", "thesiss", cwd=work)
    refused(r, what="--maps thesiss", mentions=("thesiss", "thesis", "appendix-b"), never=("no such file or directory",))


def missing_input_status(work: Path) -> None:
    """A missing input is a usage error (exit 2) in every command, naming what is missing."""
    scan_copy(work)
    for args in (("compensate", "nothing.csv", "o.csv", *COMPENSATE), ("evaluate", "nothing"),
                 ("standards", "iso230-2", "nothing.csv"), ("compensate", "a.csv", "o.csv", "--machine", "nothing"),
                 ("artefact", "show", "nothing.toml")):
        r = cli(*args, cwd=work)
        if r.code != 2 or "nothing" not in r.text:
            raise Failed("silent", f"{' '.join(args[:2])} of a missing input: exit {r.code} (want 2): "
                                   f"{r.text.strip()[-200:]}")


def special_document(work: Path, kind: str, door: str) -> None:
    """A FIFO with no writer, or /dev/zero, given as a document: refused at once as not a regular file."""
    scan_copy(work)
    if kind == "fifo":
        os.mkfifo(work / "doc")
        name = "doc"
    else:
        name = "/dev/zero"
    if door in ("model", "user-effect"):
        small_run(work, "r")
    args = {"machine": ("compensate", "a.csv", "o.csv", "--machine", name, *COMPENSATE),
            "maps": ("compensate", "a.csv", "o.csv", "--maps", name, "--pose", "90,90,0"),
            "positioning": ("standards", "iso230-2", name),
            "fits": ("diagnose-fits", name, "--artefact", "koba-0420"),
            "model": ("evaluate", "r", "--model", name),
            "user-effect": ("diagnose", "r", "--user-effect", name),
            "artefact": ("artefact", "show", name)}[door]
    r = cli(*args, cwd=work, timeout=60)
    refused(r, what=f"{door} file a {kind}", mentions=(name, "not a regular file"), never=("no such file",))


def _saved_model(work: Path) -> dict:
    """A model as ``Model.save`` writes it (the thesis maps and a squareness), as a dict."""
    code = ("import sys, cmmpose\nfrom cmmpose.model import Model\n"
            "Model(cmmpose.ErrorMapSet.thesis()).with_values('squareness', [1.0, 2.0, 3.0]).save(sys.argv[1])")
    subprocess.run([sys.executable, "-c", code, str(work / "good.json")], check=True)
    return json.loads((work / "good.json").read_text())


def schema_attack(work: Path, kind: str) -> None:
    """A document its schema refuses (issue 35, cmmpose.schemas): the command fails with one line naming the
    file and the key, never a traceback, and a long number is not echoed."""
    scan_copy(work)
    if kind in ("machine -300 C", "machine 400-digit number", "machine repeated key"):
        text = (DATA / "machines" / "moving-bridge.toml").read_text()
        text = {"machine -300 C": text.replace("artefact = 12.0", "artefact = -300.0"),
                "machine 400-digit number": text.replace("noise_um = 8.0", "noise_um = 1" + "0" * 399),
                "machine repeated key": text.replace("noise_um = 8.0", "noise_um = 8.0\nnoise_um = 80.0")}[kind]
        (work / "m.toml").write_text(text)
        r = cli("compensate", "a.csv", "o.csv", "--machine", "m.toml", *COMPENSATE, cwd=work)
        key = {"machine -300 C": "expansion.artefact", "machine 400-digit number": "scanner.noise_um",
               "machine repeated key": "line"}[kind]
        refused(r, what=kind, mentions=("m.toml", key))
    elif kind == "artefact -300 C":
        text = (DATA / "artefacts" / "koba-0320.toml").read_text()
        (work / "p.toml").write_text(text.replace("reference_temperature_C = 20.0", "reference_temperature_C = -300.0"))
        r = cli("artefact", "check", "p.toml", cwd=work)
        refused(r, what=kind, mentions=("p.toml", "reference_temperature_C"))
    else:
        doc = _saved_model(work)
        text = json.dumps(doc)
        if kind == "model 1e30 squareness":
            doc["effects"][0]["params"]["xy"] = 1e30
            text, key = json.dumps(doc), "effects[0].params.xy"
        elif kind == "model -300 C":
            doc["temperature"] = -300.0
            text, key = json.dumps(doc), "temperature"
        elif kind == "model text temperature":
            doc["temperature"] = "twenty"
            text, key = json.dumps(doc), "temperature"
        elif kind == "model repeated key":
            text, key = text.replace('"effects":', '"effects": [], "effects":', 1), "'effects' is repeated"
        else:  # a 400-digit number
            text, key = text.replace('"xy": 1.0', '"xy": 1' + "0" * 399, 1), "effects[0].params.xy"
        (work / "m.json").write_text(text)
        r = cli("compensate", "a.csv", "o.csv", "--model", "m.json", "--pose", "90,90,0", cwd=work)
        refused(r, what=kind, mentions=("m.json", key))
    if "0" * 40 in r.text:
        raise Failed("silent", f"{kind}: a 400-digit number printed back in full")
    if (work / "o.csv").exists():
        raise Failed("silent", f"{kind}: refused, yet an output was written")


# ---------------------------------------------------------------------------------------------- issue 35, the rest
_JOURNAL = """
import sys
import numpy as np
from cmmpose.acquire.protocol import encode_profile
from cmmpose.acquire.store import SCANNER, JournalWriter, encode_record
from cmmpose.sim.instruments import synthetic_profiles

folder, kind = sys.argv[1], sys.argv[2]
writer = JournalWriter(folder + "/journal.cmmj", fsync=False)
records = []
for i, p in enumerate(synthetic_profiles(40, points=64, rate=40.0, per_scan=10)):
    uv, scales, scan = np.array(p.uv, dtype=np.float32), list(p.scales), p.scan
    if 10 <= i < 14:  # frames of scan 1
        if kind == "nan scale":
            scales[1] = float("nan")
        elif kind == "inf scale":
            scales[0] = float("inf")
        elif kind == "nan point":
            uv[[2, 5]] = np.nan
        elif kind == "huge scan":
            scan = 2**31 + 5
    records.append(encode_record(SCANNER, 1.7e9 + 0.025 * i, encode_profile(i, 25_000 * i, scan, scales, uv)))
writer.write_block(records)
writer.close()
"""


def recover_attack(work: Path, kind: str) -> None:
    """A recorded scanner frame holding a NaN or an infinite scale reading, NaN points or a scan number beyond
    int32: ``acquire --recover`` builds a run from the journal all the same (the good frames kept, the bad points
    left out and counted), never fails and loses the recording (issue 35, item 3)."""
    rec = work / "rec"
    rec.mkdir()
    subprocess.run([sys.executable, "-c", _JOURNAL, str(rec), kind], check=True)
    journal = digest(rec / "journal.cmmj")
    r = cli("acquire", "--recover", "-o", rec, cwd=work)
    if digest(rec / "journal.cmmj") != journal:
        raise Failed("data loss", f"acquire --recover with a {kind} changed the journal (exit {r.code})")
    if r.code != 0:
        raise Failed("data loss", f"acquire --recover with a {kind} built no run (exit {r.code}): {r.text.strip()[-300:]}")
    code = ("import sys, json, numpy as np\nfrom cmmpose.run import Run\nr = Run.load(sys.argv[1])\n"
            "ok = np.isfinite(r.uv).all() and np.isfinite(r.scales).all() and (r.points['scan_id'] >= 0).all()\n"
            "print(json.dumps([int(r.n_points), bool(ok), r.metadata['acquisition']['scanner']]))")
    out = subprocess.run([sys.executable, "-c", code, str(rec)], capture_output=True, text=True)
    if out.returncode:
        raise Failed("data loss", f"acquire --recover with a {kind}: the run does not load: {out.stderr[-300:]}")
    n, finite, scanner = json.loads(out.stdout)
    want = 40 * 64 - {"nan scale": 4 * 64, "inf scale": 4 * 64, "nan point": 4 * 2, "huge scan": 0}[kind]
    if n != want or not finite:
        raise Failed("silent", f"acquire --recover with a {kind}: {n} points (want {want}), all finite: {finite}")
    said = scanner.get("renumbered_scans") if kind == "huge scan" else scanner.get("excluded", {}).get("scans")
    if not said:
        raise Failed("silent", f"acquire --recover with a {kind}: the run's metadata does not name what was left out "
                               f"or renumbered: {json.dumps(scanner)[:200]}")


def _library_file(work: Path) -> Path:
    """An alignment library of three poses written by the library itself (hand-made records)."""
    code = ("import sys\nfrom cmmpose.calibration import AlignmentLibrary, AlignmentRecord\n"
            "lib = AlignmentLibrary(sys.argv[1])\n"
            "for name, pose, reading in (('A', (90, 90, 0), (450, 275, -250)), ('B', (90, 90, 90), (452, 276, -249)),"
            " ('C', (180, 90, 0), (449, 277, -251))):\n"
            "    lib.save(name, AlignmentRecord(pose=pose, reading=reading, offset=(1.001, 264.505, 129.575),"
            " reading_uncertainty=(0.001, 0.001, 0.001), temperature=20.0))\n")
    subprocess.run([sys.executable, "-c", code, str(work / "lib.json")], check=True)
    return work / "lib.json"


def library_attack(work: Path, kind: str) -> None:
    """An alignment library that its schema refuses (issue 35, item 1): compensate --alignment and calibrate
    offset fail with one line naming the file and the key, never a traceback, the file left as it was."""
    lib = _library_file(work)
    scan_copy(work)
    text = lib.read_text()
    key = {"repeated key": "'temperature' is repeated", "temperature 1e6": "poses.A.temperature",
           "400-digit number": "reading", "pose 1e9 degrees": "poses.A.pose[0]",
           "escape in a name": "holds a control character"}[kind]
    if kind == "repeated key":
        text = text.replace('"temperature": 20.0', '"temperature": 20.0, "temperature": 99.0', 1)
    elif kind == "temperature 1e6":
        text = text.replace('"temperature": 20.0', '"temperature": 1e6', 1)
    elif kind == "400-digit number":
        text = text.replace("450.0", "1" + "0" * 399, 1)
    elif kind == "pose 1e9 degrees":
        text = text.replace("90.0", "1e9", 1)
    else:
        text = text.replace('"A": {', '"A\\u001b[2J": {', 1)
    lib.write_text(text)
    for args in (("compensate", "a.csv", "o.csv", "--alignment", "B", "--library", "lib.json", "--maps", "thesis"),
                 ("calibrate", "offset", "A", "B", "C", "--library", "lib.json")):
        r = cli(*args, cwd=work)
        refused(r, what=f"{args[0]}: an alignment library with {kind}", mentions=("lib.json", key))
        if "\x1b" in r.text or "0" * 40 in r.text:
            raise Failed("silent", f"an alignment library with {kind}: its text printed back raw")
    if lib.read_text() != text or (work / "o.csv").exists():
        raise Failed("data loss", f"an alignment library with {kind}: refused, yet a file was written or changed")


def store_unknown_pose(work: Path) -> None:
    """calibrate offset --store naming a pose the library lacks changes nothing and names the pose."""
    lib = _library_file(work)
    before = digest(lib)
    r = cli("calibrate", "offset", "A", "B", "NOPE", "--library", "lib.json", "--store", cwd=work)
    if digest(lib) != before:
        raise Failed("data loss", f"calibrate offset --store with an unknown pose changed the library (exit {r.code})")
    refused(r, what="calibrate offset --store with an unknown pose", mentions=("NOPE",))
    if leftovers(work, {"lib.json"}):
        raise Failed("data loss", f"calibrate offset --store with an unknown pose left {leftovers(work, {'lib.json'})}")


def plan_attack(work: Path, kind: str) -> None:
    """An acquisition plan that its schema refuses (issue 35, item 1): acquire fails at once, before opening a
    port, with one line naming the file and the key; a FIFO with no writer is refused, not waited on."""
    r = cli("artefact", "plan", "koba-0320", "--placement", "xy", "-o", "p.json", cwd=work)
    if r.code:
        raise Failed("silent", f"artefact plan: exit {r.code}: {r.text.strip()[-200:]}")
    text = (work / "p.json").read_text()
    doc = json.loads(text)
    key = {"repeated key": "'scans' is repeated", "sweep speed 1e30": "scans[0].sweep_speed",
           "400-digit ball": "scans[0]", "scan id beyond int32": "scans[0]", "escape in a channel": "control",
           "fifo": "not a regular file"}[kind]
    if kind == "repeated key":
        text = text.replace('"scans":', '"scans": [], "scans":', 1)
    elif kind == "sweep speed 1e30":
        doc["scans"][0]["sweep_speed"] = 1e30
        text = json.dumps(doc)
    elif kind == "400-digit ball":
        text = json.dumps(doc).replace('"ball": 1,', '"ball": 1' + "0" * 399 + ",", 1)
    elif kind == "scan id beyond int32":
        doc["scans"][0]["scan_id"] = 2**31
        text = json.dumps(doc)
    elif kind == "escape in a channel":
        doc["temperature_channels"] = [{"name": "X1\x1b[2J", "role": "x_scale", "channel": 101}]
        text = json.dumps(doc)
    (work / "p.json").unlink()
    if kind == "fifo":
        os.mkfifo(work / "p.json")
    else:
        (work / "p.json").write_text(text)
    with server(None) as port:
        r = cli("acquire", "--scanner", f"socket://127.0.0.1:{port}", "--plan", "p.json", "--duration", 1,
                "-o", "rec", cwd=work, timeout=60)
    refused(r, what=f"a plan with {kind}", mentions=("p.json", key))
    if "\x1b" in r.text or "0" * 40 in r.text:
        raise Failed("silent", f"a plan with {kind}: its text printed back raw")
    if (work / "rec").exists():
        raise Failed("silent", f"a plan with {kind}: refused, yet a recording was started")


def sigint_during_plan_fifo(work: Path) -> None:
    """acquire --plan FIFO answers SIGINT and SIGTERM at once (refused before any wait, or stopped)."""
    os.mkfifo(work / "p.json")
    with server(None) as port:
        for sig in (signal.SIGINT, signal.SIGTERM):
            proc = subprocess.Popen([*cmmpose_exe(), "acquire", "--scanner", f"socket://127.0.0.1:{port}", "--plan",
                                     "p.json", "-o", "rec"], cwd=work, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                    text=True, stdin=subprocess.DEVNULL)
            time.sleep(1.5)
            if proc.poll() is None:
                proc.send_signal(sig)
            try:
                out, err = proc.communicate(timeout=5)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.communicate()
                raise Failed("hang", f"acquire --plan FIFO ignored signal {sig} for 5 s")
            if "Traceback" in out + err:
                raise Failed("traceback", f"acquire --plan FIFO, signal {sig}: {err.strip()[-300:]}")


def thread_env(work: Path) -> None:
    """RAYON_NUM_THREADS=100000: the thread count from the environment is bounded, the answer as quick."""
    scan_copy(work)
    r = cli("compensate", "a.csv", "o.csv", *COMPENSATE, cwd=work, env={"RAYON_NUM_THREADS": "100000"}, timeout=60)
    if r.code != 0 or r.seconds > 30:
        raise Failed("hang", f"RAYON_NUM_THREADS=100000: exit {r.code} after {r.seconds:.0f} s")


def big_plate(work: Path) -> None:
    """artefact check of a plate of 10,000 balls: refused at once by its schema (no n x n distance array)."""
    lines = [(DATA / "artefacts" / "koba-0320.toml").read_text().split("[[balls]]")[0].split("balls = [")[0]]
    body = ",\n".join(f"  {{ id = {i + 1}, xyz_mm = [{30.0 * (i % 100):.1f}, {30.0 * (i // 100):.1f}, 0.0], "
                      f"u_um = [0.4, 0.4, 0.6] }}" for i in range(10_000))
    (work / "big.toml").write_text(lines[0] + "balls = [\n" + body + "\n]\n")
    r = cli("artefact", "check", "big.toml", cwd=work, timeout=60)
    refused(r, what="a plate of 10,000 balls", mentions=("big.toml", "balls"))
    if r.seconds > 20:
        raise Failed("hang", f"artefact check of 10,000 balls took {r.seconds:.0f} s")


def artefact_attack(work: Path, kind: str) -> None:
    """An artefact file its schema refuses: a radius of 5e-324 mm, a ball id beyond int64, terminal escapes in
    its name (never printed raw)."""
    text = (DATA / "artefacts" / "koba-0320.toml").read_text()
    if kind == "radius 5e-324":
        text, key = re.sub(r"nominal_mm = [0-9.]+", "nominal_mm = 5e-324", text), "radius.nominal_mm"
        text = re.sub(r"calibrated_mm = [0-9.]+", "calibrated_mm = 5e-324", text)
    elif kind == "ball id beyond int64":
        text, key = text.replace("{ id = 2,", "{ id = 99999999999999999999,", 1), "balls[1].id"
    elif kind == "repeated key":
        text, key = re.sub(r"^(reference_temperature_C = .*)$", r"\1\nreference_temperature_C = 35.0", text, count=1,
                           flags=re.M), "line"
    else:
        text, key = re.sub(r'^name = "', 'name = "\\\\u001b[2J\\\\u001b[31m', text, count=1, flags=re.M), "name"
    (work / "p.toml").write_text(text)
    for args in (("artefact", "check", "p.toml"), ("artefact", "show", "p.toml"),
                 ("simulate", "--artefact", "p.toml", "-o", "r")):
        r = cli(*args, cwd=work)
        refused(r, what=f"{' '.join(args[:2])}: an artefact with {kind}", mentions=("p.toml", key))
        if "\x1b" in r.text:
            raise Failed("silent", f"{' '.join(args[:2])}: terminal escapes from the artefact file printed raw")
    if (work / "r").exists():
        raise Failed("silent", f"an artefact with {kind}: refused, yet a run was written")


def simulate_option(work: Path, option: str, value: str) -> None:
    """simulate with a speed or jitter that measures nothing (1e-320, 1e308): refused naming the option's
    quantity, never an empty run written as success nor a traceback."""
    r = cli("simulate", option, value, "-o", "r", cwd=work)
    refused(r, what=f"simulate {option} {value}", mentions=(option.removeprefix("--"),))
    if (work / "r").exists():
        raise Failed("silent", f"simulate {option} {value}: refused, yet a run was written")


def user_effect_attack(work: Path, kind: str) -> None:
    """A user effect returning complex values (never truncated with a warning) or named with terminal escapes
    (never printed raw): refused naming the file."""
    small_run(work, "r")
    name = "ripple\\x1b[2J" if kind == "escape" else "ripple"
    dtype = "complex" if kind == "complex" else "float"
    (work / "ue.py").write_text(
        "import numpy as np\nfrom cmmpose.model import UserEffect\n\n\ndef correction(inputs, a_um):\n"
        f"    out = np.zeros((len(inputs['D']), 3), dtype={dtype})\n"
        "    out[:, 0] = a_um * 1e-3 * np.sin(inputs['D'] / 10.0)" + (" * (1 + 1j)" if kind == "complex" else "")
        + "\n    return out\n\n\n"
        f"EFFECT = UserEffect.create('{name}', correction, {{'a_um': ('um', 1.0)}}, physics='x', reveal='y')\n")
    r = cli("diagnose", "r", "--user-effect", "ue.py", "--max-effects", 1, cwd=work)
    refused(r, what=f"a user effect with {kind}", mentions=("complex" if kind == "complex" else "control",),
            never=("ComplexWarning",))
    if "\x1b" in r.text:
        raise Failed("silent", "a user effect's name with terminal escapes printed raw")


def arabic_digits(work: Path) -> None:
    """--placement and --pose with Arabic-Indic digits are refused, not read as 525 and 90."""
    r = cli("simulate", "--artefact", "koba-0320", "--placement", "xy@z=-٥٢٥", "-o", "r", cwd=work)
    refused(r, what="--placement xy@z=-٥٢٥", mentions=("placement",))
    scan_copy(work)
    r = cli("compensate", "a.csv", "o.csv", "--maps", "thesis", "--pose", "٩٠,90,0", "--offset",
            "1.001,264.505,129.575", cwd=work)
    refused(r, what="--pose ٩٠,90,0", mentions=("--pose",))


def plan_sigma(work: Path) -> None:
    """plan --sigma 1e-320: refused (a noise of nothing promises uncertainties of nothing), not printed with
    320 digits."""
    small_run(work, "r", "--repeat-scans", 0)
    r = cli("plan", "r", "--sigma", "1e-320", cwd=work)
    refused(r, what="plan --sigma 1e-320", mentions=("--sigma",))
    if "0" * 40 in r.text:
        raise Failed("silent", "plan --sigma 1e-320: printed with hundreds of digits")


def model_other_kinematics(work: Path) -> None:
    """compensate --model of a model stacked for another configuration than the machine's: refused naming both,
    as evaluate and diagnose refuse it."""
    scan_copy(work)
    code = ("import sys, cmmpose\nfrom cmmpose.model import Model\n"
            "Model(cmmpose.ErrorMapSet.thesis().with_kinematics('gantry')).save(sys.argv[1])")
    subprocess.run([sys.executable, "-c", code, str(work / "mg.json")], check=True)
    r = cli("compensate", "a.csv", "o.csv", "--model", "mg.json", "--pose", "90,90,0", cwd=work)
    refused(r, what="compensate --model stacked for a gantry on the thesis machine", mentions=("gantry", "thesis"))
    if (work / "o.csv").exists():
        raise Failed("silent", "compensate --model of another configuration: refused, yet written")


def joint_copy(work: Path) -> None:
    """A joint diagnosis of a run and its copy with only ``created`` changed: refused (it would shrink every
    uncertainty by sqrt 2)."""
    small_run(work, "r")
    shutil.copytree(work / "r", work / "c")
    doc = json.loads((work / "c" / "run.json").read_text())
    doc["created"] = "2020-01-01T00:00:00Z"
    (work / "c" / "run.json").write_text(json.dumps(doc))
    r = cli("diagnose", "r", "c", "--joint", "--max-effects", 1, cwd=work)
    refused(r, what="a joint diagnosis of a run and its copy", mentions=("copy",))


def uncertainty_option(work: Path, option: str, value: str) -> None:
    """compensate --uncertainty with an absurd stated uncertainty: a usage error (exit 2) naming the option."""
    scan_copy(work)
    r = cli("compensate", "a.csv", "o.csv", *COMPENSATE, "--uncertainty", option, value, cwd=work)
    refused(r, what=f"--uncertainty {option} {value}", mentions=(option,))
    if r.code != 2 or (work / "o.csv").exists():
        raise Failed("silent", f"--uncertainty {option} {value}: exit {r.code} (want 2), output written: "
                               f"{(work / 'o.csv').exists()}")


def map_uncertainty_header(work: Path, kind: str) -> None:
    """A map file whose ``# uncertainty:`` header line is out of range, repeats a key or is not JSON: refused
    naming the file, its line and the key."""
    code = "import sys, cmmpose\ncmmpose.ErrorMapSet.thesis().maps[0].write(sys.argv[1])"
    subprocess.run([sys.executable, "-c", code, str(work / "m.csv")], check=True)
    text = (work / "m.csv").read_text()
    edit, key = {"negative": (('"positioning_ppm": [2.5', '"positioning_ppm": [-1'), "positioning_ppm"),
                 "1e30": (('"positioning_ppm": [2.5', '"positioning_ppm": [1e30'), "positioning_ppm"),
                 "repeated key": (('"positioning_ppm"', '"source": "x", "positioning_ppm"'), "source"),
                 "not JSON": (("# uncertainty: {", "# uncertainty: {{"), "uncertainty")}[kind]
    if edit[0] not in text:
        raise Skip("the map file has no uncertainty header")
    (work / "m.csv").write_text(text.replace(*edit, 1))
    scan_copy(work)
    r = cli("compensate", "a.csv", "o.csv", "--maps", "m.csv", "--temperature", 20, "--pose", "90,90,0",
            "--offset", "1.001,264.505,129.575", "--uncertainty", cwd=work)
    refused(r, what=f"a map's uncertainty header {kind}", mentions=("m.csv", key))


def machine_uncertainty(work: Path, kind: str) -> None:
    """A machine file whose [uncertainty] table is out of range, has an unknown key or a NaN: refused naming
    the file and the key."""
    text = (DATA / "machines" / "moving-bridge.toml").read_text()
    table = {"1e9 ppm": "[uncertainty]\npositioning_ppm = [1e9, 1.0, 1.0]\n",
             "unknown key": "[uncertainty]\npositioning_pm = [1.0, 1.0, 1.0]\n",
             "nan": "[uncertainty]\nsquareness_arcsec = [nan, 1.0, 1.0]\n"}[kind]
    key = {"1e9 ppm": "uncertainty.positioning_ppm", "unknown key": "positioning_pm",
           "nan": "uncertainty.squareness_arcsec"}[kind]
    if "[uncertainty]" in text:
        raise Skip("the bundled machine file has its own [uncertainty]")
    (work / "m.toml").write_text(text + "\n" + table)
    scan_copy(work)
    r = cli("compensate", "a.csv", "o.csv", "--machine", "m.toml", "--uncertainty", cwd=work)
    refused(r, what=f"a machine file's [uncertainty] with {kind}", mentions=("m.toml", key))


def run_json_attack(work: Path, kind: str) -> None:
    """A run.json out of range or with a repeated key: refused naming the file and the key."""
    run = small_run(work, "r")
    text = (run / "run.json").read_text()
    doc = json.loads(text)
    if kind == "repeated key":
        text, key = text.replace('"metadata":', '"maps": {}, "metadata":', 1), "'maps' is repeated"
    elif kind == "negative row count":
        doc["rows"]["points"] = -1
        text, key = json.dumps(doc), "rows.points"
    else:  # a radius of 1e30 mm
        doc["artefact"]["ball_radius_mm"] = 1e30
        text, key = json.dumps(doc), "artefact.ball_radius_mm"
    (run / "run.json").write_text(text)
    for args in (("evaluate", "r"), ("diagnose", "r", "--max-effects", 1)):
        refused(cli(*args, cwd=work), what=f"{args[0]}: a run.json with {kind}", mentions=("run.json", key))


def nan_model_temperature(work: Path) -> None:
    """A model file with a NaN temperature: refused naming the file and its 'temperature', never blamed on the
    points' T column."""
    scan_copy(work)
    doc = _saved_model(work)
    doc["temperature"] = float("nan")
    (work / "m.json").write_text(json.dumps(doc))
    r = cli("compensate", "a.csv", "o.csv", "--model", "m.json", "--pose", "90,90,0", cwd=work)
    refused(r, what="a model at NaN C", mentions=("m.json", "temperature"), never=("column",))


def existing_run_kept(work: Path) -> None:
    """simulate -o an existing run without --overwrite: refused before any work, the run unchanged."""
    run = small_run(work, "r")
    before = {p.name: digest(p) for p in run.iterdir() if p.is_file()}
    r = cli("simulate", "--seed", 2, "-o", "r", cwd=work)
    after = {p.name: digest(p) for p in run.iterdir() if p.is_file()}
    if after != before:
        raise Failed("data loss", f"simulate -o an existing run without --overwrite changed it (exit {r.code})")
    refused(r, what="simulate -o an existing run", mentions=("--overwrite",))


def wrong_names(work: Path) -> None:
    """A wrong name lists the valid ones: --format, an artefact kind, a machine example, an effect, a source of
    uncertainty, a layout."""
    scan_copy(work)
    for args, valid in ((("map", "export", "thesis@20", "--format", "cvs", "-o", "x.csv"), ("csv", "iso230-2")),
                        (("artefact", "example", "ball-plates", "-o", "a.toml"), ("ball-plate", "ballbar")),
                        (("machine", "example", "gantri", "-o", "m.toml"), ("gantry", "moving-bridge")),
                        (("simulate", "--effect", "squarenes:xy=5", "-o", "r"), ("squareness", "scale")),
                        (("simulate", "--layout", "b98", "-o", "r"), ("b89",)),
                        (("compensate", "a.csv", "o.csv", *COMPENSATE, "--uncertainty", "--uncertainty-off", "mapp"),
                         ("map", "temperature"))):
        r = cli(*args, cwd=work)
        refused(r, what=" ".join(map(str, args[:3])), mentions=valid)
        if r.code != 2:
            raise Failed("silent", f"{' '.join(map(str, args[:3]))}: a wrong name exits {r.code} (a usage error is 2)")
    small_run(work, "r", "--repeat-scans", 0)
    r = cli("plan", "r", "--plan-for", "squarenes", cwd=work)
    refused(r, what="plan --plan-for squarenes", mentions=("squareness", "roll"))
    if r.code != 2:
        raise Failed("silent", f"plan --plan-for squarenes: exits {r.code} (a usage error is 2)")


def missing_input_more(work: Path) -> None:
    """A missing input is a usage error (exit 2) in every other command too, naming what is missing."""
    for args in (("diagnose", "nothing"), ("fit", "nothing.csv"), ("diagnose-fits", "nothing.csv"),
                 ("calibrate", "offset", "A", "B", "C", "--library", "nothing.json"),
                 ("map", "import", "iso230-2", "nothing.csv", "-o", "x.csv"), ("map", "plot", "nothing.csv", "-o", "p.png"),
                 ("map", "export", "nothing.csv", "--format", "iso230-2", "-o", "y.csv"), ("machine", "check", "nothing.toml"),
                 ("plan", "nothing"), ("acquire", "--recover", "-o", "nothing"),
                 ("standards", "acceptance", "nothing", "--mpe-form", 1, "--mpe-size", 1, "--mpe-length", 1),
                 ("evaluate", "nothing", "--model", "nothing.json")):
        r = cli(*args, cwd=work)
        if r.code != 2 or "nothing" not in r.text:
            raise Failed("silent", f"{' '.join(map(str, args[:3]))} of a missing input: exit {r.code} (want 2): "
                                   f"{r.text.strip()[-200:]}")


def markup_in_names(work: Path, where: str) -> None:
    """Text from a file that Rich would read as markup (``[/bold][red]``) in an artefact's name, or in a file's
    name: printed as text, never a MarkupError traceback."""
    if where == "artefact":
        text = (DATA / "artefacts" / "koba-0320.toml").read_text()
        (work / "p.toml").write_text(re.sub(r'^name = "', 'name = "[/bold][red]', text, count=1, flags=re.M))
        cli("simulate", "--artefact", "p.toml", "--seed", 1, "--repeat-scans", 0, "-o", "r", cwd=work)
        commands = (("artefact", "show", "p.toml"), ("evaluate", "r"), ("plan", "r", "--budget", 1))
    else:
        rows = ["target_mm,direction,cycle,deviation_um"] + [f"{t},{d},{c},{1.0 + 0.01 * t + 0.3 * c}"
                                                            for t in range(0, 500, 50) for d in (1, -1)
                                                            for c in range(1, 6)]
        (work / "[").mkdir()
        (work / "[" / "b].csv").write_text("\n".join(rows) + "\n")
        commands = (("standards", "iso230-2", "[/b].csv"),)
    for args in commands:
        r = cli(*args, cwd=work)
        if r.code != 0 or "[/bold][red]KOBA" not in r.text and "[/b].csv" not in r.text:
            raise Failed("silent", f"{' '.join(map(str, args[:2]))} of a name holding Rich markup: exit {r.code}, "
                                   f"not printed as written: {r.text.strip()[-200:]}")


def temperature_option(work: Path, value: str) -> None:
    """--temperature below absolute zero (-273.16 C, even with --out-of-range extrapolate) or of 1e6 C: a usage
    error naming the option; 1e-320 C is said in a sensible precision, never with 320 digits."""
    scan_copy(work)
    extra = ("--out-of-range", "extrapolate") if value == "-273.16" else ()
    r = cli("compensate", "a.csv", "o.csv", *COMPENSATE, "--temperature", value, *extra, cwd=work)
    if value == "1e-320":
        refused(r, what="--temperature 1e-320", mentions=("temperature",))
        if "0" * 40 in r.text or "digits)" in r.text:
            raise Failed("silent", f"--temperature 1e-320 printed with hundreds of digits: {r.text.strip()[-200:]}")
        return
    refused(r, what=f"--temperature {value}", mentions=("--temperature",))
    if r.code != 2 or (work / "o.csv").exists():
        raise Failed("silent", f"--temperature {value}: exit {r.code} (want 2)")


def plate_fits_attack(work: Path, kind: str) -> None:
    """diagnose-fits --artefact of fitted centres with a placement beyond a C long (never an OverflowError), or
    in um or inches (never "scale x -999000 ppm"): refused naming the file."""
    cli("simulate", "--artefact", "koba-0420", "--placement", "planes", "--seed", 1, "--repeat-scans", 0, "-o", "r",
        cwd=work)
    cli("evaluate", "r", "--report", "rep", cwd=work)
    rows = list(csv.reader((work / "rep" / "centres.csv").read_text().splitlines()))
    header, body = rows[0], rows[1:]
    if kind == "placement beyond C long":
        k = header.index("placement")
        body = [[("9" * 25 if i == k and v == "1" else v) for i, v in enumerate(r)] for r in body]
        words = ("fits.csv", "placement")
    else:
        factor = 1000.0 if kind == "centres in um" else 1 / 25.4
        cols = [header.index(c) for c in ("x_mm", "y_mm", "z_mm")]
        body = [[(repr(float(v) * factor) if i in cols else v) for i, v in enumerate(r)] for r in body]
        words = ("fits.csv", "um" if kind == "centres in um" else "inches")
    with open(work / "fits.csv", "w", newline="") as f:
        csv.writer(f).writerows([header, *body])
    r = cli("diagnose-fits", "fits.csv", "--artefact", "koba-0420", "--state", "compensated", cwd=work)
    refused(r, what=f"diagnose-fits --artefact of {kind}", mentions=words, never=("OverflowError",))
    if "0" * 40 in r.text or "9" * 25 in r.text:
        raise Failed("silent", f"diagnose-fits of {kind}: a 25-digit number printed back")


def errormap_text_temperature(work: Path) -> None:
    """ErrorMap(..., temperature="22") and with_temperature(True): refused, not converted in silence."""
    code = ("import cmmpose\nm = cmmpose.ErrorMapSet.thesis().maps[0]\nout = []\n"
            "for make in (lambda: cmmpose.ErrorMap(m.table('X'), m.table('Y'), m.table('Z'), m.squareness, "
            "temperature='22'), lambda: m.with_temperature(True), lambda: m.with_temperature(float('nan'))):\n"
            "    try:\n        make()\n        out.append('accepted')\n"
            "    except cmmpose.Error as e:\n        out.append('refused' if 'temperature' in str(e) else str(e))\n"
            "print(' '.join(out))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    if "Traceback" in r.stderr:
        raise Failed("traceback", r.stderr.strip()[-300:])
    if r.stdout.split() != ["refused"] * 3:
        raise Failed("silent", f"ErrorMap temperatures '22', True, nan: {r.stdout.strip()}")


def alignment_attack(work: Path, kind: str) -> None:
    """calibrate alignment: three vernier points without --vernier-uncertainty (a usage error saying to give
    it, not a covariance message); a wrong --plane-normal with --nominal-pose (refused naming it) or without
    (said, never a silent gamma)."""
    cli("calibrate", "simulate-alignment", "--pose", "90,90,0", "--name", "A", "-o", "al", cwd=work)
    args = ["calibrate", "alignment", "--vernier", "al/A-vernier.csv", "--plane-scan", "al/A-plane.csv",
            "--reference-scan", "al/A-sphere.csv", "--name", "A", "--library", "lib.json", "--maps", "thesis",
            "--temperature", 20]
    if kind == "no vernier uncertainty":
        r = cli(*args, "--plane-normal", "0,0,1", cwd=work)
        refused(r, what="calibrate alignment of 3 vernier points", mentions=("--vernier-uncertainty",),
                never=("covariance",))
    elif kind == "wrong normal, nominal pose":
        r = cli(*args, "--plane-normal", "0,1,0", "--vernier-uncertainty", 9, "--nominal-pose", "90,90,0", cwd=work)
        refused(r, what="calibrate alignment with a wrong --plane-normal", mentions=("--plane-normal",))
    else:
        r = cli(*args, "--plane-normal", "0,1,0", "--vernier-uncertainty", 9, cwd=work)
        if r.code == 0 and "--plane-normal" not in r.text:
            raise Failed("silent", "calibrate alignment with a wrong --plane-normal: exit 0 and no word of it")
    if kind != "wrong normal, no nominal pose" and (work / "lib.json").exists():
        raise Failed("silent", f"calibrate alignment, {kind}: refused, yet the library was written")


def huge_sparse_document(work: Path) -> None:
    """A 300 MiB model file (sparse, read in no time): refused by its size before it is read."""
    scan_copy(work)
    with open(work / "m.json", "wb") as f:
        f.truncate(300 << 20)
    r = cli("compensate", "a.csv", "o.csv", "--model", "m.json", "--pose", "90,90,0", cwd=work, timeout=60)
    refused(r, what="a 300 MiB model file", mentions=("m.json", "bytes"))
    if r.seconds > 10:
        raise Failed("hang", f"a 300 MiB model file: {r.seconds:.0f} s to refuse")


def escapes_in_files(work: Path, kind: str) -> None:
    """Terminal escape sequences in a point file's value, a fit file's value or a map's source line: never
    printed raw (a message quotes what it echoes, control characters escaped)."""
    if kind == "point file":
        (work / "e.csv").write_text("u,v,D,E,F\n1,2\x1b[2J\x1b[31m,450,275,-250\n")
        args = ("compensate", "e.csv", "o.csv", *COMPENSATE, "--temperature", 20)
    elif kind == "fit file":
        (work / "e.csv").write_text("x,y,z\n1,2\x1b]0;pwned\x07,3\n")
        args = ("fit", "e.csv")
    else:
        code = "import sys, cmmpose\ncmmpose.ErrorMapSet.thesis().maps[0].write(sys.argv[1])"
        subprocess.run([sys.executable, "-c", code, str(work / "m.csv")], check=True)
        text = (work / "m.csv").read_text()
        (work / "m.csv").write_text(text.replace("# source: ", "# source: \x1b[2J\x1b[31m", 1))
        scan_copy(work)
        args = ("compensate", "a.csv", "o.csv", "--maps", "m.csv", "--temperature", 20, "--pose", "90,90,0",
                "--offset", "1.001,264.505,129.575", "--json")
    r = cli(*args, cwd=work)
    if "\x1b" in r.text or "\x07" in r.text:
        raise Failed("silent", f"{kind} with terminal escapes: printed raw (exit {r.code})")
    if kind != "map source":
        refused(r, what=f"a {kind} with terminal escapes", mentions=("e.csv",))



def beyond_a_machine(work: Path, kind: str) -> None:
    """Numbers no machine gives (a map component of 1e30 um, u = 1e300 mm, a point's T of -300 C under
    --out-of-range clamp): refused naming the file and the row, never compensated into a finite nonsense."""
    code = "import sys, cmmpose\ncmmpose.ErrorMapSet.thesis().maps[0].write(sys.argv[1])"
    subprocess.run([sys.executable, "-c", code, str(work / "m.csv")], check=True)
    maps, points = "thesis", "p.csv"
    row = "1,120,499.575,275,-47.37,21.8"
    if kind == "map":
        lines = [ln for ln in (work / "m.csv").read_text().splitlines() if not ln.startswith("# sha256")]
        lines = ["X,25,1e30,0,0,0,0.57,-0.37" if ln.startswith("X,25,") else ln for ln in lines]
        (work / "m.csv").write_text("\n".join(lines) + "\n")
        maps, mentions = "m.csv", ("m.csv", "1e30 um")
        (work / points).write_text(f"u,v,D,E,F,T\n{row}\n")
    elif kind == "u":
        (work / points).write_text(f"u,v,D,E,F,T\n{row}\n1e300,120,499.575,275,-47.37,21.8\n")
        mentions = ("p.csv", "row 1", "1e300 mm")
    else:
        (work / points).write_text(f"u,v,D,E,F,T\n{row}\n1,120,499.575,275,-47.37,-300\n")
        mentions = ("p.csv", "row 1", "-300 C")
    r = cli("compensate", points, "o.csv", "--maps", maps, "--pose", "90,90,0", "--offset", "1.001,264.505,129.575",
            "--out-of-range", "clamp", cwd=work)
    refused(r, what=f"a {kind} beyond a machine's numbers", mentions=mentions)
    if (work / "o.csv").exists():
        raise Failed("silent", f"a {kind} beyond a machine's numbers: refused, yet an output was written")


ATTACKS = {
    "data loss": {
        "compensate a.csv a.csv": lambda w: same_file(w, "plain"),
        "output via a symlink to the input": lambda w: same_file(w, "symlink"),
        "output via a hard link to the input": lambda w: same_file(w, "hardlink"),
        "output spelled sub/../a.csv": lambda w: same_file(w, "dotted"),
        "output a character device": device_output,
        "output a FIFO": fifo_output,
        "output a folder": directory_output,
        "full disk: compensate": lambda w: full_disk(w, "compensate"),
        "full disk: machine example": lambda w: full_disk(w, "machine"),
        "full disk: artefact example --overwrite": lambda w: full_disk(w, "artefact"),
        "full disk: diagnose --save-model": lambda w: full_disk(w, "model"),
        "full disk: simulate --overwrite": lambda w: full_disk(w, "simulate"),
        "full disk: map export": lambda w: full_disk(w, "map"),
        "full disk: evaluate --report": lambda w: full_disk(w, "report"),
        "SIGTERM mid-write": lambda w: killed_mid_write(w, signal.SIGTERM),
        "SIGHUP mid-write": lambda w: killed_mid_write(w, signal.SIGHUP),
        "SIGINT mid-write": lambda w: killed_mid_write(w, signal.SIGINT),
        "umask 022 gives 0644": umask_respected,
        "two simulate -o same started together": lambda w: started_together(w, "simulate"),
        "two artefact example -o same started together": lambda w: started_together(w, "artefact"),
        "two machine example -o same started together": lambda w: started_together(w, "machine"),
        "two compensate to one OUT started together": lambda w: started_together(w, "compensate"),
        **{f"an existing output without --overwrite: {c}": (lambda w, c=c: existing_output(w, c))
           for c in EXISTING_OUTPUTS},
        **{f"--overwrite through a link to an input: {c}": (lambda w, c=c: overwrite_never_an_input(w, c))
           for c in ("compensate", "compensate (its --maps file)", "map import", "map export",
                     "diagnose --save-model", "evaluate --report")},
        "diagnose --corrected-maps over its --maps files": lambda w: corrected_maps_over_inputs(w, "given"),
        "diagnose --corrected-maps over a machine's maps": lambda w: corrected_maps_over_inputs(w, "machine"),
        "full disk: diagnose --corrected-maps": corrected_maps_full_disk,
        "evaluate: runs named like its report files": evaluate_report_named_runs,
        "acquire --recover: a NaN scale reading in a frame": lambda w: recover_attack(w, "nan scale"),
        "acquire --recover: an infinite scale reading": lambda w: recover_attack(w, "inf scale"),
        "acquire --recover: NaN points in a frame": lambda w: recover_attack(w, "nan point"),
        "acquire --recover: a scan number beyond int32": lambda w: recover_attack(w, "huge scan"),
        "calibrate offset --store with an unknown pose": store_unknown_pose,
        "simulate -o an existing run without --overwrite": existing_run_kept,
    },
    "hang": {
        "scheduler that never answers": lambda w: scheduler(w, "silent"),
        "scheduler that is an HTTP server": lambda w: scheduler(w, "http"),
        "scheduler given as http://": lambda w: scheduler(w, "url"),
        "input a FIFO with no writer": lambda w: special_input(w, "fifo"),
        "--machine a FIFO with no writer": lambda w: special_document(w, "fifo", "machine"),
        "--model a FIFO with no writer": lambda w: special_document(w, "fifo", "model"),
        "--user-effect a FIFO with no writer": lambda w: special_document(w, "fifo", "user-effect"),
        "artefact file a FIFO with no writer": lambda w: special_document(w, "fifo", "artefact"),
        "--maps a FIFO with no writer": lambda w: special_document(w, "fifo", "maps"),
        "iso230-2 of a FIFO with no writer": lambda w: special_document(w, "fifo", "positioning"),
        "diagnose-fits of a FIFO with no writer": lambda w: special_document(w, "fifo", "fits"),
        "acquire --plan a FIFO with no writer": lambda w: plan_attack(w, "fifo"),
        "acquire --plan FIFO: SIGINT and SIGTERM": sigint_during_plan_fifo,
        "RAYON_NUM_THREADS=100000": thread_env,
        "artefact check of a 10,000-ball plate": big_plate,
        "a 300 MiB model file": huge_sparse_document,
    },
    "traceback": {
        "Parquet with a repeated column": parquet_repeated_column,
        "ASCII PLY declaring 1e12 vertices": ply_huge_count,
        "TOML nested 10,000 deep": lambda w: toml_attack(w, "deep"),
        "TOML with a 5,001-digit integer": lambda w: toml_attack(w, "big"),
        "diagnose-fits: header, no rows": fits_header_only,
        "output /dev/full": full_device_output,
        "read-only output": read_only_output,
        "artefact example -o on a read-only disk": read_only_example,
        "input /dev/zero": lambda w: special_input(w, "zero"),
        "one 1e12 mm outlier in a fit": outlier_fit,
        '--maps ""': empty_maps,
        "a 300-digit temperature": long_number_echo,
        "CLI hint names a Python argument": python_hint,
        "--machine /dev/zero": lambda w: special_document(w, "zero", "machine"),
        "--model /dev/zero": lambda w: special_document(w, "zero", "model"),
        "artefact file /dev/zero": lambda w: special_document(w, "zero", "artefact"),
        "model with a 400-digit number": lambda w: schema_attack(w, "model 400-digit number"),
        "machine with a 400-digit number": lambda w: schema_attack(w, "machine 400-digit number"),
        'model with "temperature": "twenty"': lambda w: schema_attack(w, "model text temperature"),
        "simulate --speed 1e-320": lambda w: simulate_option(w, "--speed", "1e-320"),
        "artefact of radius 5e-324 mm": lambda w: artefact_attack(w, "radius 5e-324"),
        "alignment library with a 400-digit number": lambda w: library_attack(w, "400-digit number"),
        "plan with a 400-digit ball number": lambda w: plan_attack(w, "400-digit ball"),
        "plan with a scan id beyond int32": lambda w: plan_attack(w, "scan id beyond int32"),
        "Rich markup in an artefact's name": lambda w: markup_in_names(w, "artefact"),
        "Rich markup in a file's name": lambda w: markup_in_names(w, "file"),
        "diagnose-fits: a placement beyond a C long": lambda w: plate_fits_attack(w, "placement beyond C long"),
        "ErrorMap(temperature='22')": errormap_text_temperature,
    },
    "silent": {
        "evaluate/acceptance: a scan labelled ball=3": lambda w: relabelled_scan(w, "ball=3"),
        "evaluate/acceptance: a scan labelled position=-1": lambda w: relabelled_scan(w, "position=-1"),
        "evaluate/acceptance: a duplicated scan": lambda w: relabelled_scan(w, "duplicate"),
        "acceptance FAIL exits 1": failed_acceptance_exit,
        "map CSV: a repeated key": lambda w: map_attack(w, "repeated key"),
        "map CSV: cut at a row boundary": lambda w: map_attack(w, "cut"),
        "diagnose-fits: a repeated (position, ball)": lambda w: fits_attack(w, "repeated row"),
        "diagnose-fits: a repeated column": lambda w: fits_attack(w, "repeated column"),
        "iso230-2: 1e300 in --json": lambda w: positioning(w, "1e300"),
        "iso230-2: a repeated row": lambda w: positioning(w, "repeated row"),
        "iso230-2: a repeated column": lambda w: positioning(w, "repeated column"),
        "CSV writer: values near the float limit": csv_writer_huge,
        "PLY: body longer than the header says": ply_body_mismatch,
        "run: points table cut short": run_table_cut,
        "machine TOML: no [mount]": lambda w: machine_attack(w, "no [mount]"),
        "machine TOML: expansion -1e9": lambda w: machine_attack(w, "negative expansion"),
        "machine TOML: a number as a string": lambda w: machine_attack(w, "string number"),
        "alignment library in radians": alignment_units,
        '--pose ""': lambda w: empty_option(w, "--pose", ""),
        '--offset ""': lambda w: empty_option(w, "--offset", ""),
        "--pose 1e9,90,0": lambda w: empty_option(w, "--pose", "1e9,90,0"),
        "evaluate: a thermocouple at a constant 1e6 C": lambda w: thermocouple_attack(w, "dropped", "evaluate"),
        "evaluate: a log that ends early and is held": lambda w: thermocouple_attack(w, "held", "evaluate"),
        "diagnose: a thermocouple at a constant 1e6 C": lambda w: thermocouple_attack(w, "dropped", "diagnose"),
        "diagnose: a log that ends early and is held": lambda w: thermocouple_attack(w, "held", "diagnose"),
        "acceptance: a thermocouple at a constant 1e6 C": lambda w: thermocouple_attack(w, "dropped", "acceptance"),
        "acceptance: a log that ends early and is held": lambda w: thermocouple_attack(w, "held", "acceptance"),
        "a 254-character output name": long_output_name,
        "compensate a.csv out.txt": unknown_output_suffix,
        "--maps thesiss": wrong_map_name,
        "a missing input: exit 2 everywhere": missing_input_status,
        "model with a squareness of 1e30 arc-seconds": lambda w: schema_attack(w, "model 1e30 squareness"),
        "model at -300 C": lambda w: schema_attack(w, "model -300 C"),
        "model with a repeated key": lambda w: schema_attack(w, "model repeated key"),
        "machine: an expansion of -300": lambda w: schema_attack(w, "machine -300 C"),
        "machine with a repeated key": lambda w: schema_attack(w, "machine repeated key"),
        "artefact certificate at -300 C": lambda w: schema_attack(w, "artefact -300 C"),
        "simulate --speed 1e308": lambda w: simulate_option(w, "--speed", "1e308"),
        "simulate --jitter 1e308": lambda w: simulate_option(w, "--jitter", "1e308"),
        "a map component of 1e30 um": lambda w: beyond_a_machine(w, "map"),
        "a point's u of 1e300 mm": lambda w: beyond_a_machine(w, "u"),
        "a point's T of -300 C under --out-of-range clamp": lambda w: beyond_a_machine(w, "T"),
        "artefact with a ball id beyond int64": lambda w: artefact_attack(w, "ball id beyond int64"),
        "artefact named with terminal escapes": lambda w: artefact_attack(w, "escape"),
        "artefact with a repeated key": lambda w: artefact_attack(w, "repeated key"),
        "terminal escapes in a point file's value": lambda w: escapes_in_files(w, "point file"),
        "terminal escapes in a fit file's value": lambda w: escapes_in_files(w, "fit file"),
        "terminal escapes in a map's source line": lambda w: escapes_in_files(w, "map source"),
        "user effect returning complex values": lambda w: user_effect_attack(w, "complex"),
        "user effect named with terminal escapes": lambda w: user_effect_attack(w, "escape"),
        "Arabic-Indic digits in --placement and --pose": arabic_digits,
        "plan --sigma 1e-320": plan_sigma,
        "compensate --model stacked for another configuration": model_other_kinematics,
        "joint diagnosis of a run and its copy": joint_copy,
        "diagnose-fits --artefact: centres in um": lambda w: plate_fits_attack(w, "centres in um"),
        "diagnose-fits --artefact: centres in inches": lambda w: plate_fits_attack(w, "centres in inches"),
        "model at NaN C": nan_model_temperature,
        "--temperature -273.16 with --out-of-range extrapolate": lambda w: temperature_option(w, "-273.16"),
        "--temperature 1e6": lambda w: temperature_option(w, "1e6"),
        "--temperature 1e-320 said in six digits": lambda w: temperature_option(w, "1e-320"),
        "--uncertainty --temperature-uncertainty 1e9": lambda w: uncertainty_option(w, "--temperature-uncertainty",
                                                                                     "1e9"),
        "--uncertainty --scanner-noise nan": lambda w: uncertainty_option(w, "--scanner-noise", "nan"),
        "--uncertainty --scanner-scale-ppm -5": lambda w: uncertainty_option(w, "--scanner-scale-ppm", "-5"),
        "map # uncertainty: a negative ppm": lambda w: map_uncertainty_header(w, "negative"),
        "map # uncertainty: 1e30 ppm": lambda w: map_uncertainty_header(w, "1e30"),
        "map # uncertainty: a repeated key": lambda w: map_uncertainty_header(w, "repeated key"),
        "map # uncertainty: not JSON": lambda w: map_uncertainty_header(w, "not JSON"),
        "machine [uncertainty]: 1e9 ppm": lambda w: machine_uncertainty(w, "1e9 ppm"),
        "machine [uncertainty]: an unknown key": lambda w: machine_uncertainty(w, "unknown key"),
        "machine [uncertainty]: nan": lambda w: machine_uncertainty(w, "nan"),
        "run.json with a repeated key": lambda w: run_json_attack(w, "repeated key"),
        "run.json with a negative row count": lambda w: run_json_attack(w, "negative row count"),
        "run.json with a 1e30 mm ball": lambda w: run_json_attack(w, "huge radius"),
        "alignment library with a repeated key": lambda w: library_attack(w, "repeated key"),
        "alignment library at 1e6 C": lambda w: library_attack(w, "temperature 1e6"),
        "alignment library with a pose of 1e9 degrees": lambda w: library_attack(w, "pose 1e9 degrees"),
        "alignment library: terminal escapes in a pose name": lambda w: library_attack(w, "escape in a name"),
        "plan with a repeated key": lambda w: plan_attack(w, "repeated key"),
        "plan with a sweep speed of 1e30": lambda w: plan_attack(w, "sweep speed 1e30"),
        "plan: terminal escapes in a channel name": lambda w: plan_attack(w, "escape in a channel"),
        "a wrong name lists the valid ones": wrong_names,
        "calibrate alignment: 3 vernier points, no --vernier-uncertainty":
            lambda w: alignment_attack(w, "no vernier uncertainty"),
        "calibrate alignment: a wrong --plane-normal, --nominal-pose": lambda w: alignment_attack(
            w, "wrong normal, nominal pose"),
        "calibrate alignment: a wrong --plane-normal alone": lambda w: alignment_attack(
            w, "wrong normal, no nominal pose"),
        "a missing input: exit 2 in the other commands": missing_input_more,
    },
}


def main(argv=None) -> int:
    global TIMEOUT
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--timeout", type=float, default=TIMEOUT, help="seconds before a command counts as hung")
    ap.add_argument("--only", action="append", default=[], help="run the attacks whose name contains this")
    ap.add_argument("--list", action="store_true", help="list the attacks and exit")
    args = ap.parse_args(argv)
    TIMEOUT = args.timeout
    if args.list:
        for cls, attacks in ATTACKS.items():
            for name in attacks:
                print(f"{cls:10s}  {name}")
        return 0
    table = {cls: {"tried": 0, "failed": 0, "skipped": 0} for cls in CLASSES}
    failures = []
    for cls, attacks in ATTACKS.items():
        for name, attack in attacks.items():
            if args.only and not any(o in name for o in args.only):
                continue
            work = Path(tempfile.mkdtemp(prefix="cmmpose-hostile-"))
            t0 = time.monotonic()
            try:
                attack(work)
                verdict = "ok"
            except Skip as e:
                verdict = f"skipped ({e})"
                table[cls]["skipped"] += 1
            except Failed as e:
                verdict = f"FAILED [{e.kind}] {e}"
                table[cls]["failed"] += 1
                failures.append((cls, name, e.kind))
            except Exception as e:  # the script's own staging went wrong: count it, show it
                verdict = f"FAILED [staging] {type(e).__name__}: {e}"
                table[cls]["failed"] += 1
                failures.append((cls, name, "staging"))
            finally:
                subprocess.run(["umount", "-l", str(work / "fs")], capture_output=True) if (work / "fs").is_dir() \
                    else None
                shutil.rmtree(work, ignore_errors=True)
            table[cls]["tried"] += 1
            print(f"{cls:10s}  {name:48s}  {time.monotonic() - t0:6.1f} s  {verdict}", flush=True)
    print("\n| class | attacks | failed | skipped |\n|---|---|---|---|")
    for cls in CLASSES:
        t = table[cls]
        print(f"| {cls} | {t['tried']} | {t['failed']} | {t['skipped']} |")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
