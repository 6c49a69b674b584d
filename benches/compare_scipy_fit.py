"""Geometric sphere fits: cmmpose against scipy.optimize.least_squares on the
same points, in the same run.

    python benches/compare_scipy_fit.py [--points 20000] [--big 200000] [--spheres 40] \
        [--per-sphere 12000] [--many 10000] [--per-many 100] [--scipy-many 300] [--repeats 7]

Data: points uniform in area on a 60 degree cap (random axis, seed 12345) of the
thesis ball (radius 38.125 mm, centre (450, 380, -420) mm) with 8 um Gaussian
noise along the normals.

SciPy side, the way a careful NumPy user writes it: points centred on their
mean, the algebraic start (linear least squares of |q|^2 = 2 c.q + k, the start
cmmpose uses too), residuals |q - c| - r vectorised in NumPy, the analytic
Jacobian (-(q - c)/|q - c|, -1) passed as ``jac``, method 'lm' (MINPACK) with
ftol = xtol = gtol = 1e-12 so that it runs to the minimum. Everything from the
centring on is timed. BLAS threads pinned to 1.

cmmpose side: ``cmmpose.fit_sphere`` / ``cmmpose.fit_spheres`` through the
Python API (conversion and the SphereFit result included), timed in child
processes started with RAYON_NUM_THREADS=1 and =2 (rayon's pool size is fixed
at first use). A single fit sums over its points in parallel only above 20,000
points (PARALLEL_MIN_POINTS, strictly more), so the 20,000-point fit is serial
with either thread count; the --big row shows the parallel path. fit_spheres
runs one task per sphere.

Batch: fit_spheres on 40 x 12,000 labelled points against a Python loop of the
SciPy fit over the 40 groups, split beforehand (the split is not timed).

Many small spheres: fit_spheres on 10,000 x 100 labelled points (results as
SphereFits arrays, the per-sphere SphereFit objects not built) against a Python
loop of the SciPy fit, timed on the first --scipy-many groups and scaled to all
of them (the loop is linear in the groups; 10,000 SciPy fits take ~10 s), and
against a Python loop of cmmpose.fit_sphere over the 10,000 groups split
beforehand, timed in full.

Times are best of --repeats after a warm-up; cmmpose's spread (worst of the
repeats) is printed beside its best, to show how loaded the machine was.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import numpy as np  # noqa: E402

import cmmpose  # noqa: E402

CENTRE = np.array([450.0, 380.0, -420.0])
RADIUS = 38.125  # thesis ball, 76.25 mm diameter
HALF_ANGLE = 60.0
NOISE = 0.008


def cap(rng, n: int, centre=CENTRE) -> np.ndarray:
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    e1 = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    cos_t = rng.uniform(np.cos(np.radians(HALF_ANGLE)), 1.0, n)
    sin_t = np.sqrt(1.0 - cos_t**2)
    phi = rng.uniform(0.0, 2.0 * np.pi, n)
    u = (sin_t * np.cos(phi))[:, None] * e1 + (sin_t * np.sin(phi))[:, None] * e2 + cos_t[:, None] * axis
    return centre + (RADIUS + rng.normal(0.0, NOISE, n))[:, None] * u


def inputs(args):
    rng = np.random.default_rng(12345)
    single = cap(rng, args.points)
    large = cap(rng, args.big)
    groups = [cap(rng, args.per_sphere, CENTRE + rng.uniform(-300, 300, 3)) for _ in range(args.spheres)]
    labels = np.repeat(np.arange(args.spheres), args.per_sphere)
    many = [cap(rng, args.per_many, CENTRE + rng.uniform(-300, 300, 3)) for _ in range(args.many)]
    many_labels = np.repeat(np.arange(args.many), args.per_many)
    return dict(single=single, large=large, groups=groups, all_points=np.vstack(groups), labels=labels,
                many=many, many_points=np.vstack(many), many_labels=many_labels)


def scipy_fit(points: np.ndarray):
    """Centre (3,) and radius by scipy.optimize.least_squares (method 'lm')."""
    from scipy.optimize import least_squares

    m = points.mean(axis=0)
    q = points - m
    # Algebraic start: |q|^2 = 2 c.q + k, r^2 = k + |c|^2.
    a = np.column_stack([2.0 * q, np.ones(len(q))])
    sol = np.linalg.lstsq(a, np.einsum("ij,ij->i", q, q), rcond=None)[0]
    x0 = np.r_[sol[:3], np.sqrt(sol[3] + sol[:3] @ sol[:3])]
    ones = -np.ones(len(q))

    def fun(x):
        return np.linalg.norm(q - x[:3], axis=1) - x[3]

    def jac(x):
        d = q - x[:3]
        return np.column_stack([-d / np.linalg.norm(d, axis=1)[:, None], ones])

    res = least_squares(fun, x0, jac=jac, method="lm", ftol=1e-12, xtol=1e-12, gtol=1e-12)
    return res.x[:3] + m, res.x[3], res.nfev


def times(fn, repeats: int) -> tuple[float, float]:
    """Best and worst of ``repeats`` timed calls after a warm-up, s."""
    fn()  # warm up (page faults, caches, thread pool)
    t = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        t.append(time.perf_counter() - t0)
    return min(t), max(t)


def best_time(fn, repeats: int) -> float:
    return times(fn, repeats)[0]


def cmmpose_cases(d):
    return {
        "single": lambda: cmmpose.fit_sphere(d["single"]),
        "big": lambda: cmmpose.fit_sphere(d["large"]),
        "batch": lambda: cmmpose.fit_spheres(d["all_points"], d["labels"]),
        "many": lambda: cmmpose.fit_spheres(d["many_points"], d["many_labels"]),
        "many_loop": lambda: [cmmpose.fit_sphere(g) for g in d["many"]],
    }


def child(args) -> None:
    """Time the cmmpose side only; print JSON."""
    d = inputs(args)
    out = {k: times(fn, args.repeats) for k, fn in cmmpose_cases(d).items()}
    out["threads"] = cmmpose.thread_count()
    print(json.dumps(out))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--points", type=int, default=20_000)
    ap.add_argument("--big", type=int, default=200_000)
    ap.add_argument("--spheres", type=int, default=40)
    ap.add_argument("--per-sphere", type=int, default=12_000)
    ap.add_argument("--many", type=int, default=10_000, help="small spheres for fit_spheres from Python")
    ap.add_argument("--per-many", type=int, default=100, help="points per small sphere")
    ap.add_argument("--scipy-many", type=int, default=300, help="small spheres SciPy is timed on (then scaled)")
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        child(args)
        return

    import scipy

    rust = {}
    for threads in (1, 2):
        env = dict(os.environ, RAYON_NUM_THREADS=str(threads))
        res = subprocess.run([sys.executable, __file__, "--child", "--points", str(args.points), "--big", str(args.big),
                              "--spheres", str(args.spheres), "--per-sphere", str(args.per_sphere),
                              "--many", str(args.many), "--per-many", str(args.per_many),
                              "--repeats", str(args.repeats)],
                             env=env, capture_output=True, text=True, check=True)
        rust[threads] = json.loads(res.stdout)
        assert rust[threads]["threads"] == threads, rust[threads]

    d = inputs(args)
    single, large, groups = d["single"], d["large"], d["groups"]
    sub = d["many"][:args.scipy_many]

    # Answers and their agreement (cmmpose here with the default pool).
    agree = {}
    for name, pts in (("single", single), ("big", large)):
        f = cmmpose.fit_sphere(pts)
        c, r, nfev = scipy_fit(pts)
        agree[name] = (np.abs(f.centre - c).max(), abs(f.radius - r), f.iterations, nfev)
    for name, fits, sets in (("batch", cmmpose.fit_spheres(d["all_points"], d["labels"]), groups),
                             ("many", cmmpose.fit_spheres(d["many_points"], d["many_labels"]), sub)):
        dc = dr = 0.0
        for k, g in enumerate(sets):
            c, r, _ = scipy_fit(g)
            dc, dr = max(dc, np.abs(fits.centre[k] - c).max()), max(dr, abs(fits.radius[k] - r))
        agree[name] = (dc, dr, None, None)

    scipy_times = {
        "single": best_time(lambda: scipy_fit(single), args.repeats),
        "big": best_time(lambda: scipy_fit(large), max(1, args.repeats // 2)),
        "batch": best_time(lambda: [scipy_fit(g) for g in groups], max(1, args.repeats // 2)),
        # Scaled from the first --scipy-many groups to all of them.
        "many": best_time(lambda: [scipy_fit(g) for g in sub], max(1, args.repeats // 2)) * args.many / len(sub),
    }
    labels_text = {
        "single": f"1 sphere x {args.points:,} pts",
        "big": f"1 sphere x {args.big:,} pts",
        "batch": f"{args.spheres} spheres x {args.per_sphere:,} pts",
        "many": f"{args.many:,} spheres x {args.per_many} pts*",
    }

    print(f"cmmpose {cmmpose.__version__}, SciPy {scipy.__version__}, NumPy {np.__version__}; "
          f"60 deg cap, r = {RADIUS} mm, 8 um noise, seed 12345; best of {args.repeats}")
    print("SciPy: least_squares(method='lm', analytic jac, tol 1e-12) from the algebraic start, centred points")
    print(f"{'case':28} {'scipy ms':>9} {'cmm 1T ms':>10} {'(worst)':>8} {'cmm 2T ms':>10} {'(worst)':>8}"
          f" {'1T/scipy':>9} {'2T/scipy':>9} {'2T/1T':>6} {'|dc| mm':>9} {'|dr| mm':>9} {'iter/nfev':>9}")
    for name in ("single", "big", "batch", "many"):
        t_sp, (t1, w1), (t2, w2) = scipy_times[name], rust[1][name], rust[2][name]
        dc, dr, it, nfev = agree[name]
        its = f"{it}/{nfev}" if it is not None else "-"
        print(f"{labels_text[name]:28} {t_sp * 1e3:9.2f} {t1 * 1e3:10.3f} {w1 * 1e3:8.3f} {t2 * 1e3:10.3f}"
              f" {w2 * 1e3:8.3f} {t_sp / t1:8.1f}x {t_sp / t2:8.1f}x {t1 / t2:5.2f}x {dc:9.1e} {dr:9.1e} {its:>9}")
    print("|dc|, |dr|: largest difference between the cmmpose and SciPy centre coordinates and radii (mm).")
    print(f"* SciPy timed on the first {len(sub)} spheres and scaled to {args.many:,}; |dc|, |dr| over those {len(sub)}.")
    print(f"A single fit of {args.points:,} points is serial in cmmpose (parallel above 20,000): 2T = 1T there.")
    print()
    print(f"{args.many:,} spheres x {args.per_many} pts from Python: fit_spheres (arrays) against a Python loop of "
          "fit_sphere over the groups split beforehand")
    print(f"{'threads':>8} {'fit_spheres ms':>15} {'(worst)':>8} {'loop ms':>9} {'(worst)':>8} {'loop/fit_spheres':>17}")
    for threads in (1, 2):
        (t, w), (tl, wl) = rust[threads]["many"], rust[threads]["many_loop"]
        print(f"{threads:8d} {t * 1e3:15.2f} {w * 1e3:8.2f} {tl * 1e3:9.1f} {wl * 1e3:8.1f} {tl / t:16.1f}x")


if __name__ == "__main__":
    main()
