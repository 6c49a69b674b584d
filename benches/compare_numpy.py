"""Throughput and memory of the Rust kernel against the NumPy reference
(tests/support/numpy_reference.py) on the same inputs, in the same run.

    python benches/compare_numpy.py [--points 1000000] [--repeats 5]

The NumPy reference runs single-threaded (BLAS threads pinned to 1). The Rust
kernel is timed in child processes started with RAYON_NUM_THREADS=1 and =2
(rayon's pool size is fixed at first use), on identical inputs (same seed).
Peak memory per call is measured with tracemalloc, which sees NumPy array
buffers, including the output array the Rust kernel fills.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import tracemalloc  # noqa: E402

import numpy as np  # noqa: E402

import cmmpose  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "support"))
import numpy_reference as nr  # noqa: E402

POSE = (90.0, 90.0, 0.0)
OFFSET = (1.001, 264.505, 129.575)


def inputs(n: int):
    rng = np.random.default_rng(12345)
    scales = np.column_stack([rng.uniform(0, 900, n), rng.uniform(0, 550, n), rng.uniform(-500, 0, n)])
    uv = np.column_stack([rng.uniform(-30, 30, n), rng.uniform(110, 170, n)])
    temps = rng.uniform(20.0, 30.0, n)
    return uv, scales, temps


#: Points per scanner profile: a Hyscan 45C profile holds up to 1024 points
#: that share one scale reading, time and temperature.
PROFILE = 1000


def profile_inputs(n: int):
    """Scan-structured data: profiles of PROFILE points sharing a reading and a temperature."""
    uv, scales, temps = inputs(n)
    k = np.arange(n) // PROFILE
    return uv, np.ascontiguousarray(scales[k * PROFILE]), np.ascontiguousarray(temps[k * PROFILE])


def best_time(fn, repeats: int) -> float:
    fn()  # warm up (page faults, caches, thread pool)
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def peak_bytes(fn) -> int:
    tracemalloc.start()
    tracemalloc.reset_peak()
    fn()
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return peak


def cases(n: int):
    uv, scales, temps = inputs(n)
    puv, pscales, ptemps = profile_inputs(n)
    maps = cmmpose.ErrorMapSet.thesis()
    blended = maps.at(22.5)
    ref_maps = [{"temperature": m.temperature, "squareness": m.squareness, **{c: m.table(c) for c in "XYZ"}} for m in maps.maps]
    return {
        "one map (22.5 C)": (
            lambda: cmmpose.compensate(uv, scales, maps, POSE, OFFSET, 22.5),
            lambda: nr.compensate(uv, scales, ref_maps, POSE, OFFSET, 22.5),
        ),
        "per-point temperature": (
            lambda: cmmpose.compensate(uv, scales, maps, POSE, OFFSET, temps),
            lambda: nr.compensate(uv, scales, ref_maps, POSE, OFFSET, temps),
        ),
        "profiles, temperature": (
            lambda: cmmpose.compensate(puv, pscales, maps, POSE, OFFSET, ptemps),
            lambda: nr.compensate(puv, pscales, ref_maps, POSE, OFFSET, ptemps),
        ),
        "position error only": (
            lambda: blended.position_error(scales),
            lambda: nr.position_error(ref_maps, scales, 22.5),
        ),
    }


def child(n: int, repeats: int) -> None:
    """Time the Rust side only; print JSON."""
    out = {name: best_time(rust, repeats) for name, (rust, _) in cases(n).items()}
    out["threads"] = cmmpose.thread_count()
    print(json.dumps(out))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        child(args.points, args.repeats)
        return
    n = args.points
    rust = {}
    for threads in (1, 2):
        env = dict(os.environ, RAYON_NUM_THREADS=str(threads))
        res = subprocess.run([sys.executable, __file__, "--child", "--points", str(n), "--repeats", str(args.repeats)],
                             env=env, capture_output=True, text=True, check=True)
        rust[threads] = json.loads(res.stdout)
    print(f"cmmpose {cmmpose.__version__}, {n:,} points, same inputs (seed 12345), best of {args.repeats}")
    print(f"{'case':24} {'numpy Mpt/s':>12} {'rust 1T':>10} {'rust 2T':>10} {'1T/numpy':>9} {'2T/numpy':>9} {'2T/1T':>6}"
          f" {'numpy peak MB':>14} {'rust peak MB':>13}")
    for name, (rust_fn, numpy_fn) in cases(n).items():
        t_np = best_time(numpy_fn, max(1, args.repeats // 2))
        t1, t2 = rust[1][name], rust[2][name]
        mem_np, mem_rs = peak_bytes(numpy_fn), peak_bytes(rust_fn)
        print(f"{name:24} {n / t_np / 1e6:12.2f} {n / t1 / 1e6:10.1f} {n / t2 / 1e6:10.1f} {t_np / t1:8.1f}x {t_np / t2:8.1f}x"
              f" {t1 / t2:5.2f}x {mem_np / 1e6:14.1f} {mem_rs / 1e6:13.1f}")
    print("Output alone is 24 MB per million points; the Rust kernel allocates nothing else per point.")


if __name__ == "__main__":
    main()
