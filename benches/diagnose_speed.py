"""Wall time of ``cmmpose.diagnose`` on a full 20-position B89 run (about
500,000 points, the Hyscan at 1024 points per profile) with the whole
effect library, and of its unit of work, one model evaluation (compensate
every point, fit every sphere), against the NumPy way of doing that same
evaluation (tests/support/numpy_reference.py for the compensation, SciPy
least_squares for the geometric sphere fits), in the same run.

    python benches/diagnose_speed.py [--repeats 5] [--cold 5] [--reference-spheres 4]

The diagnosis is timed warm (in this process, after one call that loads
what it loads on first use: min-max of --repeats calls) and cold (--cold
fresh interpreters running this script with --cold-child: every import of
the script from its first line, cmmpose's and cmmpose.sim's among them,
plus the first call; the simulation of the run is not counted; min-max).

The diagnosis needs about 30 such evaluations for the sensitivities plus a
few per effect added; the NumPy way would take that many times the
reference figure printed here.
"""

from __future__ import annotations

import time

_START = time.perf_counter()  # a cold run counts every import from here

import argparse  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

import cmmpose  # noqa: E402
from cmmpose.model import Model  # noqa: E402
from cmmpose.diagnosis.identify import Problem  # noqa: E402
from cmmpose.sim import effects as E  # noqa: E402
from cmmpose.sim.runs import simulate_ballbar_run  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "support"))
import numpy_reference as nr  # noqa: E402


def best_of(f, repeats):
    min_max, out = spread_of(f, repeats)
    return min_max[0], out


def spread_of(f, repeats):
    """(min, max) wall time in s of ``repeats`` calls of f, and its last result."""
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        out = f()
        times.append(time.perf_counter() - t)
    return (min(times), max(times)), out


def simulated_run():
    return simulate_ballbar_run(temperature=22.5, effects=[E.Squareness(yz=20.0)], jitter=0.0015, seed=1)[0]


def cold_diagnosis(runs):
    """(import s, first diagnose s) of ``runs`` fresh interpreters running
    this script with --cold-child."""
    out = []
    for _ in range(runs):
        text = subprocess.run([sys.executable, __file__, "--cold-child"], check=True, capture_output=True,
                              text=True).stdout
        out.append(tuple(float(x) for x in text.split()))
    return out


def cold_child() -> None:
    """Print the import time (this script's imports, cmmpose's among them,
    from its first line) and the first diagnosis's time, s; the simulation
    between them is not counted."""
    t_import = time.perf_counter() - _START
    run = simulated_run()
    t = time.perf_counter()
    cmmpose.diagnose(run)
    print(t_import, time.perf_counter() - t)


def numpy_evaluation(run, maps_np, temperature, n_spheres):
    """Compensate with the NumPy reference, fit the first n_spheres with SciPy."""
    from scipy.optimize import least_squares

    xyz = np.empty((run.n_points, 3))
    for pose_id in np.unique(run.scans["pose_id"]):
        scans = run.scans["scan_id"][run.scans["pose_id"] == pose_id]
        rows = np.isin(run.points["scan_id"], scans)
        pose, offset = run.pose(int(pose_id))
        xyz[rows] = nr.compensate(run.uv[rows], run.scales[rows], maps_np, pose, offset, temperature[rows])
    sid = run.points["scan_id"]
    for s in np.unique(sid)[:n_spheres]:
        p = xyz[sid == s]
        c0 = p.mean(axis=0)
        least_squares(lambda q: np.linalg.norm(p - q[:3], axis=1) - q[3],
                      np.r_[c0, np.linalg.norm(p - c0, axis=1).mean()], method="lm")
    return xyz


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5, help="warm diagnoses (and Rust evaluations) timed")
    ap.add_argument("--cold", type=int, default=5, help="fresh interpreters timed for the cold diagnosis")
    ap.add_argument("--reference-spheres", type=int, default=4,
                    help="spheres the SciPy reference fits (scaled up to all of them in the ratio)")
    ap.add_argument("--cold-child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.cold_child:
        cold_child()
        return

    run = simulated_run()
    n_spheres = len(np.unique(run.points["scan_id"]))
    print(f"run: {run.n_points} points, {n_spheres} spheres, {cmmpose.thread_count()} threads")

    cold = cold_diagnosis(args.cold)
    total = [a + b for a, b in cold]
    print(f"diagnose cold (fresh interpreter: import cmmpose + first call), {args.cold} runs: "
          f"{min(total):.2f}-{max(total):.2f} s (import {min(a for a, _ in cold):.2f}-{max(a for a, _ in cold):.2f} s, "
          f"first call {min(b for _, b in cold):.2f}-{max(b for _, b in cold):.2f} s)")
    cmmpose.diagnose(run)  # first use: lazy imports, caches
    (t_lo, t_hi), d = spread_of(lambda: cmmpose.diagnose(run), args.repeats)
    print(f"diagnose warm (full library, patterns, report data), {args.repeats} runs: {t_lo:.2f}-{t_hi:.2f} s "
          f"-> added {d.added}, rms {d.steps[0].figures.rms_accuracy_error * 1e3:.2f} -> "
          f"{d.steps[-1].figures.rms_accuracy_error * 1e3:.2f} um")
    model = Model(cmmpose.ErrorMapSet.thesis())
    prob = Problem(model, run, candidates={})
    t_rust, _ = best_of(lambda: prob.observe(model), args.repeats)

    maps_np = []
    for m in cmmpose.ErrorMapSet.thesis().maps:
        maps_np.append({"temperature": m.temperature, "X": m.table("X"), "Y": m.table("Y"), "Z": m.table("Z"),
                        "squareness": m.squareness})
    temperature = prob.inputs.temperature
    k = min(args.reference_spheres, n_spheres)
    t_np, xyz_np = best_of(lambda: numpy_evaluation(run, maps_np, temperature, k), 1)
    t0 = time.perf_counter()
    numpy_evaluation(run, maps_np, temperature, 0)
    t_comp = time.perf_counter() - t0
    t_np_all = t_comp + (t_np - t_comp) * n_spheres / max(k, 1)
    agree = np.abs(xyz_np - model.compensate(run)).max()
    print(f"one evaluation (compensate + {n_spheres} sphere fits): Rust {t_rust * 1e3:.0f} ms, "
          f"NumPy+SciPy {t_np_all:.2f} s (fits scaled from {k}) -> {t_np_all / t_rust:.0f}x; "
          f"points agree to {agree:.1e} mm")
    print(f"the diagnosis did about {30 + 4 * len(d.added)} evaluations: the NumPy way would need "
          f"~{(30 + 4 * len(d.added)) * t_np_all:.0f} s for them alone")


if __name__ == "__main__":
    main()
