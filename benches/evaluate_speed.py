"""Wall time of the ballbar evaluation behind ``cmmpose evaluate RUN`` on the
default simulated run (``cmmpose simulate``: 20 B89 positions, about
476,000 points), in process, against the NumPy way of doing the same work
in the same run: uncompensated and compensated coordinates of every point
with tests/support/numpy_reference.py, and the 2 x 40 geometric sphere fits with
SciPy's least_squares (a few fitted, scaled up to all of them).

    python benches/evaluate_speed.py [--repeats 5] [--reference-spheres 4] [--no-reference]

Each timed evaluation gets a freshly loaded run (``Run.load``, timed on its
own), as the command does, so no per-run cache is warm; the maps are the
bundled thesis set the run names. Figures are min-max over --repeats.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import cmmpose
from cmmpose.evaluation.ballbar import evaluate, machine_temperature
from cmmpose.sim import simulate_ballbar_run

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "support"))
import numpy_reference as nr  # noqa: E402


def spread(times):
    return f"{min(times):.3f}-{max(times):.3f} s"


def numpy_evaluation(run, maps_np, n_spheres):
    """Both coordinate sets with the NumPy reference, the first n_spheres
    fits of each with SciPy; returns the compensated coordinates."""
    from scipy.optimize import least_squares

    # Log readings a little outside the maps are held at their edge, as the
    # kernel does within its temperature tolerance.
    lo, hi = min(m["temperature"] for m in maps_np), max(m["temperature"] for m in maps_np)
    temps = np.clip(machine_temperature(run, run.points["t"]), lo, hi)
    raw = np.empty((run.n_points, 3))
    comp = np.empty((run.n_points, 3))
    for pose_id in np.unique(run.scans["pose_id"]):
        rows = np.isin(run.points["scan_id"], run.scans["scan_id"][run.scans["pose_id"] == pose_id])
        pose, offset = run.pose(int(pose_id))
        raw[rows] = nr.uncompensated(run.uv[rows], run.scales[rows], pose, offset)
        comp[rows] = nr.compensate(run.uv[rows], run.scales[rows], maps_np, pose, offset, temps[rows])
    sid = run.points["scan_id"]
    for xyz in (raw, comp):
        for s in np.unique(sid)[:n_spheres]:
            p = xyz[sid == s]
            c0 = p.mean(axis=0)
            least_squares(lambda q: np.linalg.norm(p - q[:3], axis=1) - q[3],
                          np.r_[c0, np.linalg.norm(p - c0, axis=1).mean()], method="lm")
    return comp


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--reference-spheres", type=int, default=4,
                    help="spheres per coordinate set the SciPy reference fits (scaled up to all of them)")
    ap.add_argument("--no-reference", action="store_true", help="skip the NumPy+SciPy reference")
    args = ap.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        run, truth = simulate_ballbar_run(seed=0)
        run.save(Path(tmp) / "run", truth=truth)
        maps = cmmpose.ErrorMapSet.thesis()
        t_load, t_eval = [], []
        for _ in range(args.repeats):
            t = time.perf_counter()
            loaded = cmmpose.Run.load(Path(tmp) / "run")
            t_load.append(time.perf_counter() - t)
            t = time.perf_counter()
            ev = evaluate(loaded, maps)
            t_eval.append(time.perf_counter() - t)
    n_spheres = len(np.unique(run.points["scan_id"]))
    print(f"run: {run.n_points} points, {n_spheres} spheres, {cmmpose.thread_count()} threads")
    print(f"Run.load: {spread(t_load)}; evaluate (uncompensated + compensated, {2 * n_spheres} sphere fits), "
          f"{args.repeats} runs: {spread(t_eval)} -> rms {ev.results[0].rms_accuracy_error * 1e3:.1f} -> "
          f"{ev.results[1].rms_accuracy_error * 1e3:.1f} um")
    if args.no_reference:
        return
    maps_np = [{"temperature": m.temperature, "X": m.table("X"), "Y": m.table("Y"), "Z": m.table("Z"),
                "squareness": m.squareness} for m in maps.maps]
    k = min(args.reference_spheres, n_spheres)
    t = time.perf_counter()
    comp = numpy_evaluation(run, maps_np, k)
    t_k = time.perf_counter() - t
    t = time.perf_counter()
    numpy_evaluation(run, maps_np, 0)
    t_0 = time.perf_counter() - t
    t_np = t_0 + (t_k - t_0) * n_spheres / max(k, 1)
    agree = np.abs(comp - cmmpose.evaluation.ballbar._machine_coordinates(run, maps, machine_temperature(run, run.points["t"]))).max()
    print(f"NumPy+SciPy way of the same work: {t_np:.2f} s (fits scaled from {k} per set) -> "
          f"{t_np / min(t_eval):.0f}x the fastest evaluate; compensated points agree to {agree:.1e} mm")


if __name__ == "__main__":
    main()
