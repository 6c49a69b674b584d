"""Wall time of evaluating and diagnosing a ball-plate run (issue 24): a
KOBA 0420 (5 x 5 balls) at four placements on the thesis machine (the three
coordinate planes and the XY plane turned 90 degrees: 100 balls), swept
slowly enough for about 1e6 points, with a hidden squareness and scale
error. Timed in this process after one warm-up call each (what loads on
first use is not counted); the simulation is not timed.

    python benches/artefact_speed.py [--repeats 5] [--speed 3.5] [--artefact koba-0420] [--placement P ...]

The issue's KOBA 0620 case (5 x 5 balls at 133 mm: it stands only in the XY
plane of the thesis machine, so four XY placements at two heights and two
turns; --speed 3.5 for about 1e6 points, 35 for about 3e5):

    python benches/artefact_speed.py --artefact koba-0620 --placement xy --placement xy@rot=90 \
        --placement xy@z=-150 --placement xy@z=-400,rot=45

Prints min-max over --repeats calls of ``cmmpose.evaluation.artefact.evaluate_artefact``
(uncompensated and compensated with the thesis maps) and of ``cmmpose.diagnose``
(the whole effect library, residual patterns included; then also without the
map-correction candidates, ``map_corrections=False``), and the peak resident
memory of the process. The machine may be shared: each repeat times one
evaluation and one diagnosis back to back, and the ratio diagnosis /
evaluation (min-max) is what load does not change much.
"""

from __future__ import annotations

import argparse
import platform
import resource
import time

from cmmpose import artefacts
from cmmpose.evaluation.artefact import evaluate_artefact
from cmmpose.diagnosis import diagnose
from cmmpose.errormap import ErrorMapSet
from cmmpose.sim import Scale, Squareness
from cmmpose.sim.artefact_runs import simulate_artefact_run

PLACEMENTS = ["planes", "xy@rot=90"]


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
    ap.add_argument("--artefact", default="koba-0420", help="Bundled artefact (or file) measured.")
    ap.add_argument("--placement", action="append", default=None,
                    help=f"Placement shorthand, repeatable (default: {' '.join(PLACEMENTS)}).")
    args = ap.parse_args(argv)
    plate = artefacts.load_artefact(args.artefact)
    run, _ = simulate_artefact_run(plate, args.placement or PLACEMENTS, None, 20.0, [Squareness(6.0, -4.0, 3.0),
                                                                                     Scale(8.0, -6.0, 5.0)],
                                   speed=args.speed, seed=1)
    maps = ErrorMapSet.thesis()
    n_balls = len(run.scans["scan_id"])
    print(f"{plate.name} at {len(run.artefact['placements'])} placements: {n_balls} balls, {run.n_points:,} points; "
          f"CPU: {cpu_name()}")
    ev = evaluate_artefact(run, maps)  # warm-up calls: what loads on first use is not counted
    d = diagnose(run, maps)
    diagnose(run, maps, map_corrections=False)
    times = {"evaluate": [], "diagnose": [], "diagnose, no map corrections": []}
    for _ in range(args.repeats):
        for what, call in (("evaluate", lambda: evaluate_artefact(run, maps)), ("diagnose", lambda: diagnose(run, maps)),
                           ("diagnose, no map corrections", lambda: diagnose(run, maps, map_corrections=False))):
            t = time.perf_counter()
            out = call()
            times[what].append(time.perf_counter() - t)
            if what == "evaluate":
                ev = out
            elif what == "diagnose":
                d = out
    ev_t = times["evaluate"]
    print(f"evaluate (uncompensated + compensated): {min(ev_t):.2f}-{max(ev_t):.2f} s over {args.repeats} runs "
          f"(rms deviation compensated {ev.compensated.rms * 1e3:.2f} um)")
    for what in ("diagnose", "diagnose, no map corrections"):
        t = times[what]
        ratio = [a / b for a, b in zip(t, ev_t)]
        print(f"{what} (effect library, patterns): {min(t):.2f}-{max(t):.2f} s over {args.repeats} runs, "
              f"{min(ratio):.1f}-{max(ratio):.1f} x the evaluation timed beside it"
              + (f" (added: {', '.join(d.added) or 'nothing'})" if what == "diagnose" else ""))
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"peak resident memory: {peak:.0f} MB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
