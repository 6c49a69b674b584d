"""The Parquet point writer's encodings against pyarrow's defaults, in the
same run: `cmmpose.formats.pointfiles.PointWriter` writing 10,000,000 compensated
points (X, Y, Z float64 in profiles of 1000 points, as scanner data come, and
an integer scan_id) in chunks of 1,000,000, once with the encodings chosen
per column kind (``cmmpose.formats.pointformats.common.parquet_options``: no
dictionary and BYTE_STREAM_SPLIT + zstd for reals, a dictionary for
integers) and once with pyarrow's defaults (a dictionary on every column,
snappy). Runs alternate; min-max of ``--repeats`` each, and the file sizes.

    python benches/parquet_writer.py [--points 10000000] [--repeats 5] [--dir DIR]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

from cmmpose.formats import pointfiles
from cmmpose.formats.pointformats import parquet as parquet_format


def profile_points(n: int) -> tuple[np.ndarray, np.ndarray]:
    """X, Y, Z (mm) of ``n`` points in profiles of 1000 along X, 0.1 mm apart in Y, and their scan_id."""
    rng = np.random.default_rng(1)
    k = np.arange(n)
    x = 100 + 0.05 * (k % 1000) + rng.normal(0, 0.002, n)
    y = -200 + 0.1 * (k // 1000) + rng.normal(0, 0.002, n)
    z = 30 + 5 * np.sin(x / 20) * np.cos(y / 30) + rng.normal(0, 0.005, n)
    return np.column_stack([x, y, z]), k // 100_000


def write(path: Path, xyz: np.ndarray, scan_id: np.ndarray, chunk: int = 1_000_000) -> float:
    t0 = time.perf_counter()
    w = pointfiles.PointWriter(path)
    for lo in range(0, len(xyz), chunk):
        w.write(xyz[lo:lo + chunk], {"scan_id": scan_id[lo:lo + chunk]})
    w.close()
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--points", type=int, default=10_000_000)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--dir", type=Path, default=None)
    args = ap.parse_args()
    xyz, scan_id = profile_points(args.points)
    chosen = parquet_format.parquet_options
    times = {"per column kind": [], "pyarrow defaults": []}
    sizes, reads = {}, {k: [] for k in times}
    with tempfile.TemporaryDirectory(dir=args.dir) as folder:
        for _ in range(args.repeats):
            for name in times:
                parquet_format.parquet_options = chosen if name == "per column kind" else (lambda schema: {})
                path = Path(folder) / f"{name.replace(' ', '_')}.parquet"
                times[name].append(write(path, xyz, scan_id))
                sizes[name] = path.stat().st_size
                t0 = time.perf_counter()
                pq.read_table(path)
                reads[name].append(time.perf_counter() - t0)
    parquet_format.parquet_options = chosen
    base = np.array(times["pyarrow defaults"])
    print(f"{args.points:,} points, min-max of {args.repeats} runs (alternating)")
    print(f"{'encodings':18} {'write s':>11} {'x defaults':>11} {'read s':>11} {'MB':>6}")
    for name, t in times.items():
        ratio = np.array(t) / base
        print(f"{name:18} {min(t):5.2f}-{max(t):<5.2f} {ratio.min():5.2f}-{ratio.max():<5.2f} "
              f"{min(reads[name]):5.2f}-{max(reads[name]):<5.2f} {sizes[name] / 1e6:6.0f}")


if __name__ == "__main__":
    main()
