"""Wall time of ``cmmpose.e3125`` (ASTM E3125-style segmentation and fit with
the radius fixed: closest-point start, least-median start on the first
region, cone and cylinder regions until they stop changing) on each of
NIST's raw scans in data/nist_dmg, in process, against one plain
fixed-radius least-squares fit of the points it kept (the same run).

    python benches/e3125_speed.py [--repeats 25] [--runs 5]

Each run takes the best of ``--repeats`` calls per scan (the machine's noise
only adds time); ``--runs`` runs give the min-max printed. The file is read
once, outside the timing.
"""

from __future__ import annotations

import argparse
import os
import sys
import timeit
from pathlib import Path

for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import numpy as np  # noqa: E402

import cmmpose  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from speed import cpu_model  # noqa: E402

NIST = Path(__file__).resolve().parents[1] / "data" / "nist_dmg"
RADIUS = 50.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=25)
    ap.add_argument("--runs", type=int, default=5)
    args = ap.parse_args()
    print(f"{cpu_model()}; load average {os.getloadavg()[0]:.1f}; cmmpose {cmmpose.__version__}, "
          f"{cmmpose.thread_count()} threads; best of {args.repeats} calls, min-max of {args.runs} runs")
    print(f"{'scan':8} {'points':>7} {'kept':>6} {'e3125 ms':>14} {'plain fit ms':>14} {'ratio':>12}")
    worst = []
    for path in sorted(NIST.glob("SPH*.xyz")):
        points = np.loadtxt(path) * 1000.0  # m -> mm
        res = cmmpose.e3125(points, RADIUS, (0.0, 0.0, 0.0))
        kept = np.ascontiguousarray(points[res.segmentation.mask])
        whole, plain, ratio = [], [], []
        for _ in range(args.runs):
            t = min(timeit.repeat(lambda: cmmpose.e3125(points, RADIUS, (0.0, 0.0, 0.0)), number=1,
                                  repeat=args.repeats))
            f = min(timeit.repeat(lambda: cmmpose.fit_sphere(kept, RADIUS), number=1, repeat=args.repeats))
            whole.append(t * 1e3)
            plain.append(f * 1e3)
            ratio.append(t / f)
        worst.append(max(whole))
        print(f"{path.stem:8} {len(points):7d} {res.n_points:6d} {min(whole):6.2f}-{max(whole):<6.2f} "
              f"{min(plain):6.3f}-{max(plain):<6.3f} {min(ratio):5.1f}-{max(ratio):<5.1f}x")
    print(f"slowest scan: {max(worst):.2f} ms (target < 5 ms)")


if __name__ == "__main__":
    main()
