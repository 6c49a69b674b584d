"""Peak memory of `cmmpose compensate` against the input's size: CSV and
Parquet inputs of 5e6, 2e7 and 1e8 points (u, v, D, E, F, T and an integer
scan_id, in profiles of 1000 points as scanner data come), each compensated
into the same format. A pipeline with a bounded queue between a reader
thread, the kernel and a writer thread (:func:`cmmpose.compensate_file`)
keeps the peak flat in the input's size. NPY, binary PLY and XYZ inputs are
made too (``--formats``; ``ply-ascii`` is an ASCII PLY input, compensated
into a binary PLY).

    python benches/compensate_memory.py [--points 5e6,2e7,1e8] [--formats csv,parquet] [--dir DIR]
    python benches/compensate_memory.py --points 5e6,2e7 --formats npy,ply,xyz

The inputs are generated chunk by chunk into DIR (a temporary folder by
default; the 1e8-point CSV is about 6 GB and its output about 5 GB: check
the free space first) and removed at the end. Peak memory is the child's
maximum resident set (``resource.getrusage(RUSAGE_CHILDREN)`` of a fresh
process per run), in GB; the wall time in s.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pa_csv
import pyarrow.parquet as pq

#: File suffixes of the formats not named by theirs (the output of an
#: ASCII PLY input is a binary PLY: the command writes PLY binary).
SUFFIX = {"ply-ascii": "ply"}

#: Rows generated at a time (generation is bounded too).
GENERATE_ROWS = 1_000_000

#: Runs a command and prints its wall time (s) and its peak resident memory
#: (bytes; Linux reports ru_maxrss in KiB).
MEASURE = """
import resource, subprocess, sys, time
t0 = time.perf_counter()
rc = subprocess.run(sys.argv[1:], stdout=subprocess.DEVNULL).returncode
wall = time.perf_counter() - t0
print(rc, wall, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * 1024)
"""


def generate(path: Path, fmt: str, n: int) -> None:
    """``n`` scanner points into ``path``, a chunk at a time."""
    rng = np.random.default_rng(5)
    schema = pa.schema([(c, pa.float64()) for c in ("u", "v", "D", "E", "F", "T")] + [("scan_id", pa.int64())])
    dtype = np.dtype([(f.name, "<f8" if f.name != "scan_id" else "<i8") for f in schema])
    if fmt == "parquet":
        writer = pq.ParquetWriter(path, schema)
    elif fmt == "csv":
        writer = pa_csv.CSVWriter(path, schema)
    elif fmt == "xyz":  # a header line naming the columns, blank-separated values
        path.write_text("//" + " ".join(schema.names) + "\n")
        writer = pa_csv.CSVWriter(pa.OSFile(str(path), "ab"), schema,
                                  write_options=pa_csv.WriteOptions(include_header=False, delimiter=" "))
    elif fmt == "npy":  # a structured array, written through a memory map
        rows = np.lib.format.open_memmap(path, mode="w+", dtype=dtype, shape=(n,))
        writer = _ArrayWriter(rows)
    elif fmt == "ply":  # binary little endian, the rows appended after the header
        props = "".join(f"property {'double' if dtype[c].kind == 'f' else 'int'} {c}\n" for c in dtype.names)
        path.write_bytes(f"ply\nformat binary_little_endian 1.0\nelement vertex {n}\n{props}end_header\n".encode())
        dtype = np.dtype([(c, "<f8" if dtype[c].kind == "f" else "<i4") for c in dtype.names])
        writer = _ArrayWriter(path.open("ab"), dtype)
    elif fmt == "ply-ascii":  # the header, then blank-separated rows as text
        props = "".join(f"property {'double' if dtype[c].kind == 'f' else 'int'} {c}\n" for c in dtype.names)
        path.write_text(f"ply\nformat ascii 1.0\nelement vertex {n}\n{props}end_header\n")
        writer = pa_csv.CSVWriter(pa.OSFile(str(path), "ab"), schema,
                                  write_options=pa_csv.WriteOptions(include_header=False, delimiter=" "))
    else:
        raise SystemExit(f"no generator for {fmt!r}")
    with writer:
        for lo in range(0, n, GENERATE_ROWS):
            m = min(GENERATE_ROWS, n - lo)
            k = (lo + np.arange(m)) // 1000
            profiles = k[-1] - k[0] + 1
            scales = np.column_stack([rng.uniform(0, 900, profiles), rng.uniform(0, 550, profiles),
                                      rng.uniform(-500, 0, profiles)])[k - k[0]]
            cols = {"u": rng.uniform(-30, 30, m).round(4), "v": rng.uniform(110, 170, m).round(4),
                    "D": scales[:, 0].round(4), "E": scales[:, 1].round(4), "F": scales[:, 2].round(4),
                    "T": rng.uniform(20.5, 29.5, profiles)[k - k[0]].round(3), "scan_id": k // 100}
            writer.write_table(pa.table(cols, schema=schema))


class _ArrayWriter:
    """Tables appended to a memory-mapped structured array or a binary file, as rows of ``dtype``."""

    def __init__(self, target, dtype=None):
        self.target, self.dtype, self.at = target, dtype, 0

    def write_table(self, table) -> None:
        cols = {c: table[c].to_numpy() for c in table.column_names}
        n = table.num_rows
        if isinstance(self.target, np.ndarray):
            for c, v in cols.items():
                self.target[c][self.at:self.at + n] = v
        else:
            rows = np.empty(n, self.dtype)
            for c, v in cols.items():
                rows[c] = v
            self.target.write(rows.tobytes())
        self.at += n

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        if isinstance(self.target, np.ndarray):
            self.target.flush()
        else:
            self.target.close()


def measure(cmd: list[str]) -> tuple[float, float]:
    """Wall time (s) and peak resident memory (GB) of one run of ``cmd`` in a fresh process."""
    res = subprocess.run([sys.executable, "-c", MEASURE, *cmd], capture_output=True, text=True, check=True)
    rc, wall, peak = res.stdout.split()
    if rc != "0":
        raise SystemExit(f"{' '.join(cmd)} failed (exit {rc})")
    return float(wall), int(peak) / 1e9


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--points", default="5e6,2e7,1e8", help="comma-separated input sizes (points)")
    ap.add_argument("--formats", default="csv,parquet")
    ap.add_argument("--dir", type=Path, default=None)
    args = ap.parse_args()
    sizes = [int(float(s)) for s in args.points.split(",")]
    cmmpose_cli = shutil.which("cmmpose") or sys.exit("the cmmpose command is not on PATH (pip install .)")
    folder = Path(tempfile.mkdtemp(dir=args.dir, prefix="cmmpose-memory-"))
    print(f"{'format':8} {'points':>12} {'input GB':>9} {'generate s':>11} {'compensate s':>13} {'peak GB':>8}",
          flush=True)
    try:
        for fmt in args.formats.split(","):
            for n in sizes:
                suffix = SUFFIX.get(fmt, fmt)
                src, out = folder / f"in.{suffix}", folder / f"out.{suffix}"
                t0 = time.perf_counter()
                generate(src, fmt, n)
                made = time.perf_counter() - t0
                wall, peak = measure([cmmpose_cli, "compensate", str(src), str(out), "--maps", "thesis"])
                print(f"{fmt:8} {n:12,} {src.stat().st_size / 1e9:9.2f} {made:11.1f} {wall:13.1f} {peak:8.2f}",
                      flush=True)
                src.unlink()
                out.unlink()
    finally:
        shutil.rmtree(folder, ignore_errors=True)


if __name__ == "__main__":
    main()
