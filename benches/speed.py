"""The kernel rows of the README's speed table, each against a baseline
measured in the same run:

- compensation on profile-structured scan data and on random readings, in
  M points/s, against the NumPy reference (tests/support/numpy_reference.py) and
  against this machine's streaming limit for the same arrays
  (``_core.streaming_reference``: the same reads and writes with one add
  per value);
- the fixed cost of one call (1 point, and 1,000 points), against NumPy's;
- a fresh output array per call against ``out=`` (profile data, with a
  temperature per point): the cost of the new array's page faults;
- the diagnosis's model kernel (effects switched on) against plain
  compensation of the same run.

    python benches/speed.py [--points 4000000] [--repeats 7] [--only kernel]

The first line names the CPU and the load average: compare ratios
between machines, not absolute figures. Inputs are larger than the 32 MB L3 cache by default, so the figures are
memory figures. Outputs are preallocated (``out=``) for the kernel and the
streaming reference alike, so neither pays for page faults. Each figure is
the best of ``--repeats`` calls; run the script 5 times for a min-max.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
import timeit
from pathlib import Path

for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import numpy as np  # noqa: E402

import cmmpose  # noqa: E402
from cmmpose import _core  # noqa: E402
from cmmpose.model import Model  # noqa: E402
from cmmpose.pose import digitizer  # noqa: E402
from cmmpose.sim import effects as E  # noqa: E402
from cmmpose.sim.runs import simulate_ballbar_run  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "support"))
import numpy_reference as nr  # noqa: E402

POSE = (90.0, 90.0, 0.0)
OFFSET = (1.001, 264.505, 129.575)
#: Points per scanner profile (a Hyscan 45C profile holds up to 1024).
PROFILE = 1000
#: Points the NumPy reference is timed on (its rate does not depend on N).
NUMPY_POINTS = 200_000


def cpu_model() -> str:
    """The CPU's model name (Linux /proc/cpuinfo; else what ``platform`` says)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown CPU"


def best(fn, repeats: int) -> float:
    fn()  # warm up: page faults, caches, the thread pool
    return min(timeit.repeat(fn, number=1, repeat=repeats))


def inputs(n: int, profiles: bool):
    rng = np.random.default_rng(12345)
    scales = np.column_stack([rng.uniform(0, 900, n), rng.uniform(0, 550, n), rng.uniform(-500, 0, n)])
    uv = np.column_stack([rng.uniform(-30, 30, n), rng.uniform(110, 170, n)])
    temps = rng.uniform(20.0, 30.0, n)
    if profiles:
        k = np.arange(n) // PROFILE * PROFILE
        scales, temps = np.ascontiguousarray(scales[k]), np.ascontiguousarray(temps[k])
    return uv, scales, temps


def reference_maps(maps):
    return [{"temperature": m.temperature, "squareness": m.squareness, **{c: m.table(c) for c in "XYZ"}}
            for m in maps.maps]


def kernel_rows(n: int, repeats: int) -> None:
    maps = cmmpose.ErrorMapSet.thesis()
    ref = reference_maps(maps)
    print(f"{'case':44} {'M pt/s':>8} {'limit':>7} {'of limit':>9} {'NumPy':>7} {'x NumPy':>8}")
    for name, profiles, temperature in (
        ("profiles of 1000, temperature per point", True, "per point"),
        ("random readings, one map (set at 22.5 C)", False, 22.5),
        ("random readings, temperature per point", False, "per point"),
    ):
        uv, scales, temps = inputs(n, profiles)
        t = temps if temperature == "per point" else temperature
        out = np.empty((n, 3))
        t_rust = best(lambda: cmmpose.compensate(uv, scales, maps, POSE, OFFSET, t, out=out), repeats)
        stream_t = temps if temperature == "per point" else None
        t_limit = best(lambda: _core.streaming_reference(uv, scales, stream_t, out=out), repeats)
        m = NUMPY_POINTS
        t_m = temps[:m] if temperature == "per point" else temperature
        t_np = best(lambda: nr.compensate(uv[:m], scales[:m], ref, POSE, OFFSET, t_m), max(1, repeats // 3))
        rate, limit, np_rate = n / t_rust / 1e6, n / t_limit / 1e6, m / t_np / 1e6
        print(f"{name:44} {rate:8.1f} {limit:7.1f} {100 * rate / limit:8.0f}% {np_rate:7.2f} {rate / np_rate:7.0f}x")


def call_overhead(repeats: int) -> None:
    maps = cmmpose.ErrorMapSet.thesis()
    blended = maps.at(22.5)
    ref = reference_maps(maps)
    print(f"\n{'one call (profile data, one map)':44} {'cmmpose':>9} {'out=':>9} {'NumPy':>9}")
    for n in (1, 1000):
        uv, scales, _ = inputs(n, True)
        out = np.empty((n, 3))
        number = 20_000 if n == 1 else 5_000

        def per_call(fn, number=number):
            return min(timeit.repeat(fn, number=number, repeat=repeats)) / number * 1e6

        t_c = per_call(lambda: cmmpose.compensate(uv, scales, blended, POSE, OFFSET))
        t_o = per_call(lambda: cmmpose.compensate(uv, scales, blended, POSE, OFFSET, out=out))
        t_n = per_call(lambda: nr.compensate(uv, scales, ref, POSE, OFFSET, 22.5), number=max(1, number // 50))
        print(f"{f'{n} point' + ('s' if n > 1 else ''):44} {t_c:7.1f}us {t_o:7.1f}us {t_n:7.0f}us")


def fresh_output(n: int, repeats: int) -> None:
    """A fresh output array per call (its pages faulted in by the kernel's
    writes) against ``out=`` (one buffer reused), on profile data."""
    maps = cmmpose.ErrorMapSet.thesis()
    uv, scales, temps = inputs(n, True)
    out = np.empty((n, 3))
    fresh = best(lambda: cmmpose.compensate(uv, scales, maps, POSE, OFFSET, temps), repeats)
    reused = best(lambda: cmmpose.compensate(uv, scales, maps, POSE, OFFSET, temps, out=out), repeats)
    print(f"\n{f'fresh output vs out= ({n:,} points, profiles, T)':44} {fresh * 1e3:7.1f}ms {reused * 1e3:7.1f}ms "
          f"{fresh / reused:7.2f}x")


def model_kernel(repeats: int) -> None:
    run, _ = simulate_ballbar_run(temperature=22.5, effects=[E.Squareness(yz=20.0)], jitter=0.0015, seed=1)
    model = Model(cmmpose.ErrorMapSet.thesis())
    inputs_ = model.inputs(run)
    named = inputs_.named()
    digs = [digitizer(p[:3], p[3:]) for p in model.poses(inputs_)]
    n = len(inputs_.uv)
    out = np.empty((n, 3))
    plain = best(lambda: cmmpose.compensate(inputs_.uv, inputs_.scales, model.maps, POSE, OFFSET,
                                            inputs_.temperature, out=out), repeats)
    print(f"\n{'diagnosis model kernel (' + f'{n:,} points of a B89 run)':44} {'ns/pt':>8} {'x plain':>8}")
    print(f"{'plain compensation (one pose)':44} {plain / n * 1e9:8.1f} {1:8.2f}")
    for label, effects in (
        ("model, no effect", {}),
        ("model, squareness", {"squareness": [1.0, 2.0, 3.0]}),
        ("model, 7 effects (2 on the scanner)", {
            "squareness": [1.0, 2.0, 3.0], "scale": [1.0, 2.0, 3.0], "axis-temperature": [0.5],
            "latency": [0.001], "granite-gradient": [1.0, 1.0, 1.0], "scanner-scale": [1e-4, 1e-4],
            "incidence": [1e-4, 1e-5]}),
    ):
        t = best(lambda: _core.compensate_model(
            inputs_.uv, inputs_.scales, model.maps._core, digs, model.policy, pose_index=inputs_.pose_index, inputs=named,
            effects=effects), repeats)
        print(f"{label:44} {t / n * 1e9:8.1f} {t / plain:8.2f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--points", type=int, default=4_000_000)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--only", choices=("kernel", "overhead", "fresh", "model"), action="append",
                    help="run only these sections (repeatable); default: all. `--only kernel` is the quick "
                         "check of the compensation rows")
    args = ap.parse_args()
    only = set(args.only or ("kernel", "overhead", "fresh", "model"))
    print(f"{cpu_model()}; load average {os.getloadavg()[0]:.1f}")
    print(f"cmmpose {cmmpose.__version__}, {cmmpose.thread_count()} threads, {args.points:,} points "
          f"(NumPy on {NUMPY_POINTS:,}), best of {args.repeats}")
    t0 = time.perf_counter()
    if "kernel" in only:
        kernel_rows(args.points, args.repeats)
    if "overhead" in only:
        call_overhead(args.repeats)
    if "fresh" in only:
        fresh_output(args.points, args.repeats)
    if "model" in only:
        model_kernel(args.repeats)
    print(f"\n({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
