"""`cmmpose compensate` end to end on files of 10,000,000 points (read,
compensate, write, one progress bar), in each point-file format, against
the I/O floor measured in the same run: the same libraries reading the same
file and writing an output of the same size with no compensation.

    python benches/compensate_files.py [--points 10000000] [--repeats 5] [--dir DIR]

Each figure is the min-max over ``--repeats`` runs of a fresh process
(`/usr/bin/time` gives the wall time and the peak resident memory). The
input has a T column (the thesis map set, a temperature per point) and comes
in profiles of 1000 points, as scanner data does. The files are written
once into DIR (a temporary folder by default; about 1.5 GB) and removed at
the end.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pa_csv
import pyarrow.parquet as pq

#: Reads IN and writes OUT with the point files' own readers and writers and
#: no compensation: the floor under `cmmpose compensate`.
FLOOR = """
import sys
from cmmpose.formats.pointfiles import PointWriter, point_chunks
_, chunks = point_chunks(sys.argv[1])
w = PointWriter(sys.argv[2])
for uv, scales, temps, done in chunks:
    w.write(scales)
w.close()
"""


def make_inputs(folder: Path, n: int) -> dict[str, Path]:
    rng = np.random.default_rng(5)
    k = np.arange(n) // 1000
    profiles = n // 1000 + 1
    scales = np.column_stack([rng.uniform(0, 900, profiles), rng.uniform(0, 550, profiles),
                              rng.uniform(-500, 0, profiles)])[k]
    temps = rng.uniform(20.5, 29.5, profiles)[k]
    table = pa.table({"u": rng.uniform(-30, 30, n).round(4), "v": rng.uniform(110, 170, n).round(4),
                      "D": scales[:, 0].round(4), "E": scales[:, 1].round(4), "F": scales[:, 2].round(4),
                      "T": temps.round(3)})
    files = {"csv": folder / "in.csv", "npy": folder / "in.npy", "parquet": folder / "in.parquet"}
    pa_csv.write_csv(table, files["csv"])
    np.save(files["npy"], np.column_stack([table[c].to_numpy() for c in table.column_names]))
    pq.write_table(table, files["parquet"])
    return files


def timed(cmd: list[str]) -> tuple[float, float]:
    """Wall time (s) and peak resident memory (GB) of one run of `cmd`."""
    res = subprocess.run(["/usr/bin/time", "-f", "%e %M", *cmd], capture_output=True, text=True)
    if res.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{res.stderr[-2000:]}")
    wall, kb = res.stderr.strip().splitlines()[-1].split()
    return float(wall), int(kb) / 1e6


def span(values) -> str:
    return f"{min(values):.2f}-{max(values):.2f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--points", type=int, default=10_000_000)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--dir", type=Path, default=None)
    args = ap.parse_args()
    folder = Path(tempfile.mkdtemp(dir=args.dir, prefix="cmmpose-bench-"))
    cmmpose_cli = shutil.which("cmmpose") or sys.exit("the cmmpose command is not on PATH (pip install .)")
    try:
        files = make_inputs(folder, args.points)
        print(f"{args.points:,} points, min-max of {args.repeats} runs each")
        print(f"{'format':8} {'input MB':>9} {'cmmpose compensate s':>21} {'peak GB':>10} {'I/O floor s':>12} "
              f"{'x floor':>10}")
        for fmt, src in files.items():
            out = folder / f"out.{fmt}"
            runs = [timed([cmmpose_cli, "compensate", str(src), str(out)]) for _ in range(args.repeats)]
            floor = [timed([sys.executable, "-c", FLOOR, str(src), str(out)])[0] for _ in range(args.repeats)]
            walls = [w for w, _ in runs]
            print(f"{fmt:8} {src.stat().st_size / 1e6:9.0f} {span(walls):>21} {span([m for _, m in runs]):>10} "
                  f"{span(floor):>12} {min(walls) / min(floor):9.2f}x")
    finally:
        shutil.rmtree(folder, ignore_errors=True)


if __name__ == "__main__":
    main()
