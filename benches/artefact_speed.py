"""Wall time of evaluating and diagnosing a ball-plate run (issue 24): a
KOBA 0420 (5 x 5 balls) at four placements on the thesis machine (the three
coordinate planes and the XY plane turned 90 degrees: 100 balls), swept
slowly enough for about 1e6 points, with a hidden squareness and scale
error. Timed in this process after one warm-up call each (what loads on
first use is not counted); the simulation is not timed.

    python benches/artefact_speed.py [--repeats 5] [--speed 3.5]

Prints min-max over --repeats calls of ``cmmpose.artefact_evaluation.evaluate_artefact``
(uncompensated and compensated with the thesis maps) and of ``cmmpose.diagnose``
(the whole effect library, residual patterns included), and the peak
resident memory of the process.
"""

from __future__ import annotations

import argparse
import platform
import resource
import time

from cmmpose import artefacts
from cmmpose.artefact_evaluation import evaluate_artefact
from cmmpose.diagnosis import diagnose
from cmmpose.errormap import ErrorMapSet
from cmmpose.sim import ScaleError, SquarenessOffset
from cmmpose.sim.artefact_runs import simulate_artefact_run

PLACEMENTS = ["planes", "xy@rot=90"]


def spread(f, repeats):
    """(min, max) wall time in s of ``repeats`` calls of f, after one warm-up call, and its last result."""
    out = f()
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        out = f()
        times.append(time.perf_counter() - t)
    return (min(times), max(times)), out


def cpu_name() -> str:
    try:
        for line in open("/proc/cpuinfo", encoding="utf-8"):
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=5, help="Timed calls of each (min-max printed).")
    ap.add_argument("--speed", type=float, default=3.5, help="Sweep speed, mm/s (3.5: about 1e6 points).")
    args = ap.parse_args(argv)
    plate = artefacts.load_artefact("koba-0420")
    run, _ = simulate_artefact_run(plate, PLACEMENTS, None, 20.0, [SquarenessOffset(6.0, -4.0, 3.0),
                                                                     ScaleError(8.0, -6.0, 5.0)],
                                   speed=args.speed, seed=1)
    maps = ErrorMapSet.thesis()
    n_balls = len(run.scans["scan_id"])
    print(f"KOBA 0420 at {len(run.artefact['placements'])} placements: {n_balls} balls, {run.n_points:,} points; "
          f"CPU: {cpu_name()}")
    (lo, hi), ev = spread(lambda: evaluate_artefact(run, maps), args.repeats)
    print(f"evaluate (uncompensated + compensated): {lo:.2f}-{hi:.2f} s over {args.repeats} runs "
          f"(rms deviation compensated {ev.compensated.rms * 1e3:.2f} um)")
    (lo, hi), d = spread(lambda: diagnose(run, maps), args.repeats)
    print(f"diagnose (effect library, patterns): {lo:.2f}-{hi:.2f} s over {args.repeats} runs "
          f"(added: {', '.join(d.added) or 'nothing'})")
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"peak resident memory: {peak:.0f} MB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
