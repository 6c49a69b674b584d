"""Each point's uncertainty at streaming speed (issue 36): compensation with
``uncertainty=`` against plain compensation of the same points, and against
the NumPy way of getting the same standard uncertainties (one plain kernel
pass per source, moved by a step, the squared changes summed with NumPy),
all in the same run.

    python benches/point_uncertainty.py [--points 4000000] [--repeats 5]

Profile-structured data (1,000 points per profile sharing a scale reading
and a temperature), the thesis map set at a temperature per point, every
source switched on (the thesis maps' stated uncertainty, 0.2 K, 50 ppm
scanner scale, 9 um noise, a pose and offset covariance). The first line
names the CPU; each figure is the best of ``--repeats`` calls; run the
script 5 times for a min-max. Ratios are what carry between machines.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import numpy as np  # noqa: E402

import cmmpose  # noqa: E402
from cmmpose import ErrorMap, ErrorMapSet  # noqa: E402
from cmmpose.point_uncertainty import PoseUncertainty, UncertaintySources  # noqa: E402

POSE = (90.0, 90.0, 0.0)
OFFSET = (1.001, 264.505, 129.575)
PER_PROFILE = 1000


def cpu_name() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


def profile_data(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    k = max(n // PER_PROFILE, 1)
    uv = np.c_[rng.uniform(-30, 30, n), rng.uniform(110, 170, n)]
    readings = np.c_[rng.uniform(300, 500, k), rng.uniform(100, 400, k), rng.uniform(-400, -100, k)]
    scales = np.ascontiguousarray(np.repeat(readings, PER_PROFILE, axis=0)[:n])
    t = np.ascontiguousarray(np.repeat(rng.uniform(20.5, 24.0, k), PER_PROFILE)[:n])
    return uv, scales, t


def best(f, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        f()
        times.append(time.perf_counter() - t0)
    return min(times)


def numpy_way(uv, scales, t, maps, sources: UncertaintySources) -> np.ndarray:
    """u_x, u_y, u_z (mm) by moving each map source alone and summing the
    squared changes: one plain pass per source (the map components'
    constant parts and the temperature; the rest of the sources are the
    same count of passes again, so this under-counts the NumPy way's work)."""
    base = cmmpose.compensate(uv, scales, maps, POSE, OFFSET, t)
    var = np.zeros_like(base)
    m = sources.stated_map(maps)
    for carriage in range(3):
        for j in range(6):
            u = m.position_um[carriage][j] if j < 3 else m.rotation_arcsec[carriage][j - 3]
            if u == 0:
                continue
            moved = []
            for one in maps.maps:
                tables = [one.table(c).copy() for c in "XYZ"]
                tables[carriage][:, 1 + j] += 1.0
                moved.append(ErrorMap(*tables, one.squareness, one.temperature))
            step = cmmpose.compensate(uv, scales, ErrorMapSet(moved), POSE, OFFSET, t) - base
            var += np.square(step * u)  # step is per um or per arc-second
    for axis in range(3):
        if m.positioning_ppm[axis] == 0:
            continue
        moved = []
        for one in maps.maps:
            tables = [one.table(c).copy() for c in "XYZ"]
            start = maps.maps[0].table("XYZ"[axis])[0, 0]
            tables[axis][:, 1 + axis] += (tables[axis][:, 0] - start) * 1e-3  # 1 ppm, um
            moved.append(ErrorMap(*tables, one.squareness, one.temperature))
        step = cmmpose.compensate(uv, scales, ErrorMapSet(moved), POSE, OFFSET, t) - base
        var += np.square(step * m.positioning_ppm[axis])
    moved = cmmpose.compensate(uv, scales, maps, POSE, OFFSET, t + 0.1) - base
    var += np.square(moved / 0.1 * sources.temperature_k)
    return np.sqrt(var)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=4_000_000)
    ap.add_argument("--repeats", type=int, default=5)
    a = ap.parse_args()
    print(f"{cpu_name()}; {os.cpu_count()} CPUs, {cmmpose._core.thread_count()} kernel threads; "
          f"load {os.getloadavg()[0]:.2f}")
    uv, scales, t = profile_data(a.points)
    maps = ErrorMapSet.thesis()
    sources = UncertaintySources(temperature_k=0.2, scanner_scale_ppm=50.0, scanner_noise_um=9.0,
                                 pose=PoseUncertainty(np.eye(3) * 0.04 ** 2, np.eye(3) * 1e-4))
    args = (uv, scales, maps, POSE, OFFSET, t)
    n = len(uv)
    plain = best(lambda: cmmpose.compensate(*args), a.repeats)
    print(f"plain compensation           {n / plain / 1e6:8.1f} M points/s")
    for detail in ("standard", "covariance", "split"):
        s = best(lambda: cmmpose.compensate(*args, uncertainty=sources, uncertainty_detail=detail), a.repeats)
        print(f"with uncertainty, {detail:10s} {n / s / 1e6:8.1f} M points/s  {plain / s:6.1%} of plain")
    sample = slice(0, min(n, 400_000))
    sub = (uv[sample], scales[sample], t[sample])
    kernel = best(lambda: cmmpose.compensate(*sub[:2], maps, POSE, OFFSET, sub[2], uncertainty=sources.without(
        "scanner_scale", "scanner_noise", "pose")), 3)
    nway = best(lambda: numpy_way(*sub, maps, sources), 1)
    got = cmmpose.compensate(*sub[:2], maps, POSE, OFFSET, sub[2],
                             uncertainty=sources.without("scanner_scale", "scanner_noise", "pose")).u
    ref = numpy_way(*sub, maps, sources)
    agree = float(np.max(np.abs(got - ref) / np.maximum(ref, 1e-12)))
    print(f"the NumPy way (one pass per source, {len(sub[0]):,} points): kernel {nway / kernel:,.0f}x faster; "
          f"largest relative difference of u {agree:.1e}")


if __name__ == "__main__":
    main()
