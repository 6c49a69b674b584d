"""`cmmpose.scale.compensate_dataset` over a Parquet dataset of N points
(default 1e9) on this machine's cores, in bounded memory, against the
single-process kernel measured in the same run.

    python benches/dask_compensate.py [--points 1e9] [--scheduler threads] [--dir DIR]
    python benches/dask_compensate.py --points 2e6        # a smoke run (CI)

The dataset is scanner-like: profiles of 256 points (u across the line, v the
depth, 0.1 um steps), scale readings D, E, F and temperature T constant over
a profile and following a raster over the thesis maps' range, a scan_id column
passed through. It is generated file by file, one row group of 2**20 rows at
a time, so generating it takes bounded memory too. Files hold
``--file-points`` points (default 2.5e7: a round of 2e8 is 8 files, 4 per core).

Disk: 1e9 points are about 13 GB of input and 24 GB of output (X, Y, Z float64
do not compress). So that the run fits beside other work, the points go
through in rounds of at most ``--round-points`` (default 2e8): each round's
files are generated, compensated as one dataset on the same running cluster,
checked (the first 65,536 rows of each output against the in-process kernel,
bit for bit) and removed. The figures count only the compensation
(``compensate_dataset`` calls: reading, kernel, writing, scheduling).

Printed, with the ratios against the in-process baselines of the same run:

- dataset throughput, M points/s, and wall time of the compensation;
- kernel: ``cmmpose.compensate`` on in-memory blocks of 2**20 points
  (min(N, 2e7) points), the single-process kernel with no I/O;
- serial: the same per-file reading, kernel and writing in this process with
  no scheduler, over the first round's files (min(N, 1e8) points);
- peak memory: the largest resident set of this process and all its
  children together (sampled every 50 ms with psutil), while generating and
  while compensating; the bound asked is 2 GB.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import psutil
import pyarrow as pa
import pyarrow.parquet as pq

import cmmpose
from cmmpose import scale

MAPS = cmmpose.ErrorMapSet.thesis()
POSE = (90.0, 90.0, 0.0)
OFFSET = cmmpose.MountOffset.thesis()
PROFILE = 256
ROW_GROUP = 1 << 20
FILE_POINTS = 25_000_000
CHECK_ROWS = 1 << 16


class PeakRSS:
    """Largest summed RSS (bytes) of this process and its children while active."""

    def __init__(self, interval: float = 0.05):
        self.interval, self.peak, self._stop = interval, 0, threading.Event()
        self._me = psutil.Process()

    def _sample(self) -> int:
        total = 0
        for p in [self._me, *self._me.children(recursive=True)]:
            try:
                total += p.memory_info().rss
            except psutil.Error:
                pass
        return total

    def _loop(self):
        while not self._stop.is_set():
            self.peak = max(self.peak, self._sample())
            self._stop.wait(self.interval)

    def __enter__(self):
        self._thread = threading.Thread(target=self._loop, daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()
        self.peak = max(self.peak, self._sample())


def row_group(start: int, n: int) -> pa.Table:
    """Rows start..start+n of the synthetic scan (vectorised, no loop over points)."""
    i = np.arange(start, start + n, dtype=np.int64)
    k = i // PROFILE  # profile number
    j = i % PROFILE
    rng = np.random.default_rng(start)
    u = -30.0 + 60.0 * j / (PROFILE - 1)
    v = np.round(140.0 + 20.0 * np.sin(u / 9.0) + rng.normal(0.0, 0.01, n), 4)
    # a raster over the maps' range, 0.05 mm between profiles along X, a new line every 16,000 profiles
    d = np.round(20.0 + (k * 0.05) % 860.0, 4)
    e = np.round(20.0 + ((k // 17_200) * 12.5) % 510.0, 4)
    f = np.round(-250.0 + 200.0 * np.sin(k / 5e5), 4)
    t = np.round(21.0 + 3.0 * np.sin(k / 3e6) ** 2, 3)
    return pa.table({"u": u, "v": v, "D": d, "E": e, "F": f, "T": t, "scan_id": (k // 4000).astype(np.int32)})


def generate(folder: Path, first: int, n: int, per_file: int = FILE_POINTS) -> list[Path]:
    """Files of ``per_file`` points (the last shorter) holding points first..first+n."""
    folder.mkdir(parents=True, exist_ok=True)
    files = []
    for f0 in range(first, first + n, per_file):
        m = min(per_file, first + n - f0)
        path = folder / f"scan_{f0 // per_file:05d}.parquet"
        schema = row_group(0, 1).schema
        with pq.ParquetWriter(path, schema) as w:
            for r0 in range(f0, f0 + m, ROW_GROUP):
                w.write_table(row_group(r0, min(ROW_GROUP, f0 + m - r0)), row_group_size=ROW_GROUP)
        files.append(path)
    return files


def arrays(table: pa.Table):
    uv = np.column_stack([table["u"].to_numpy(), table["v"].to_numpy()])
    scales = np.column_stack([table[c].to_numpy() for c in ("D", "E", "F")])
    return uv, scales, table["T"].to_numpy()


def kernel_baseline(n: int) -> float:
    """Points/s of the in-process kernel on blocks of ROW_GROUP points (best of 3 passes)."""
    blocks = [arrays(row_group(s, min(ROW_GROUP, n - s))) for s in range(0, n, ROW_GROUP)]
    out = np.empty((ROW_GROUP, 3))
    best = np.inf
    for _ in range(3):
        t0 = time.perf_counter()
        for uv, scales, t in blocks:
            cmmpose.compensate(uv, scales, MAPS, POSE, OFFSET, t, out=out[: len(uv)])
        best = min(best, time.perf_counter() - t0)
    return n / best


def serial_baseline(files: list[Path], out: Path) -> tuple[float, int]:
    """Points/s of reading, compensating and writing the files one after another in this process."""
    kernel = scale.Compensator.make(MAPS, POSE, OFFSET)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    n = 0
    for f in files:
        m, *_ = scale.dataset._compensate_file(kernel, str(f), str(out / f.name), ["scan_id"], scale.BATCH_ROWS, None)
        n += m
    return n / (time.perf_counter() - t0), n


def check(src: Path, dst: Path) -> None:
    head = pq.ParquetFile(src).iter_batches(batch_size=CHECK_ROWS)
    table = pa.Table.from_batches([next(head)])
    want = cmmpose.compensate(*arrays(table)[:2], MAPS, POSE, OFFSET, arrays(table)[2])
    got_t = pa.Table.from_batches([next(pq.ParquetFile(dst).iter_batches(batch_size=CHECK_ROWS))])
    got = np.column_stack([got_t[c].to_numpy() for c in ("X", "Y", "Z")])
    if not np.array_equal(got.view(np.uint64), want.view(np.uint64)):
        sys.exit(f"{dst}: differs from the in-process kernel")
    if not np.array_equal(got_t["scan_id"].to_numpy(), table["scan_id"].to_numpy()):
        sys.exit(f"{dst}: scan_id not passed through")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--points", type=float, default=1e9)
    ap.add_argument("--round-points", type=float, default=2e8)
    ap.add_argument("--file-points", type=float, default=FILE_POINTS)
    ap.add_argument("--scheduler", default="threads", help="threads, processes or tcp://host:port")
    ap.add_argument("--dir", type=Path, default=None, help="work folder (default: a temporary one, removed)")
    a = ap.parse_args()
    n, per_round = int(a.points), int(a.round_points)
    if n < 1 or per_round < 1 or a.file_points < 1:
        sys.exit("--points, --round-points and --file-points must be positive")
    work = Path(tempfile.mkdtemp(prefix="cmmpose-dask-", dir=a.dir))
    print(f"{n:,} points in rounds of {per_round:,}, scheduler {a.scheduler}, "
          f"{psutil.cpu_count()} cores, kernel threads {cmmpose.thread_count()}, work folder {work}")
    try:
        k_rate = kernel_baseline(min(n, 20_000_000))
        print(f"kernel (in-process, no I/O): {k_rate / 1e6:.1f} M points/s")
        gen_s = comp_s = 0.0
        gen_peak = comp_peak = 0
        s_rate = None
        done = 0
        with scale.scheduler_client(a.scheduler) as client:
            round_no = 0
            while done < n:
                m = min(per_round, n - done)
                src, dst = work / f"in{round_no}", work / f"out{round_no}"
                with PeakRSS() as g:
                    t0 = time.perf_counter()
                    files = generate(src, done, m, int(a.file_points))
                    gen_s += time.perf_counter() - t0
                gen_peak = max(gen_peak, g.peak)
                if s_rate is None:
                    s_files, s_n = [], 0
                    for f in files:
                        if s_n >= 100_000_000:
                            break
                        s_files.append(f)
                        s_n += pq.read_metadata(f).num_rows
                    s_rate, _ = serial_baseline(s_files, work / "serial")
                    shutil.rmtree(work / "serial")
                    print(f"serial (in-process read, kernel, write; {s_n:,} points): {s_rate / 1e6:.1f} M points/s")
                with PeakRSS() as c:
                    result = scale.compensate_dataset(src, dst, MAPS, POSE, OFFSET, scheduler=client)
                comp_s += result.elapsed
                comp_peak = max(comp_peak, c.peak)
                for f in files:
                    check(f, dst / f.name)
                done += result.points
                print(f"  round {round_no}: {result.points:,} points in {result.elapsed:.1f} s "
                      f"({result.points / result.elapsed / 1e6:.1f} M points/s), peak {c.peak / 2**30:.2f} GiB",
                      flush=True)
                shutil.rmtree(src)
                shutil.rmtree(dst)
                round_no += 1
        rate = done / comp_s
        print(f"dataset: {done:,} points compensated in {comp_s:.1f} s: {rate / 1e6:.1f} M points/s "
              f"= {rate / k_rate:.2f} x the in-process kernel, {rate / s_rate:.2f} x serial in-process I/O + kernel")
        print(f"peak memory (this process and its children): compensating {comp_peak / 2**30:.2f} GiB, "
              f"generating {gen_peak / 2**30:.2f} GiB ({gen_s:.0f} s); bound 2 GB: "
              f"{'within' if max(comp_peak, gen_peak) < 2e9 else 'EXCEEDED'}")
        print("outputs: bit-identical to the in-process kernel on the rows checked")
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
