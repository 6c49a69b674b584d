"""Wall time of a joint diagnosis (``cmmpose.diagnosis.joint.diagnose_jointly``)
of four full 20-position B89 runs (about 476,000 points each, a hidden
squareness and scale error, the runs at 21, 22.5, 24 and 26 C) with the
whole effect library, cross-validation and the map-correction candidates,
warm, in process; beside it, in the same run, one evaluation
(``cmmpose.evaluate``) of one of the runs, the unit of work, for the ratio.
Issue 25's target: <= 10 s on this 2-core machine. The diagnosis runs its
small dense linear algebra with one BLAS thread (cmmpose.diagnosis._blas,
through threadpoolctl when installed): the line below the CPU says which.

    python benches/joint_speed.py [--repeats 5] [--runs 4]

Prints the CPU model and load average first, then min-max of --repeats.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import cmmpose
from cmmpose.diagnosis._blas import threadpool_limits
from cmmpose.diagnosis.joint import diagnose_jointly
from cmmpose.sim import effects as E
from cmmpose.sim.runs import simulate_ballbar_run


def _cpu() -> str:
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            return next(line.split(":", 1)[1].strip() for line in f if line.startswith("model name"))
    except (OSError, StopIteration):
        return platform.processor() or "unknown CPU"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5, help="warm joint diagnoses timed")
    ap.add_argument("--runs", type=int, default=4, help="runs diagnosed together")
    args = ap.parse_args()
    print(f"CPU: {_cpu()}, {os.cpu_count()} cores; load average {os.getloadavg()[0]:.1f}")
    print("BLAS threads in the diagnosis: " + ("1 (threadpoolctl)" if threadpool_limits is not None else
                                                 "the BLAS's own (threadpoolctl not installed)"))
    temps = (21.0, 22.5, 24.0, 26.0, 23.0, 25.0)[:args.runs]
    hidden = [E.Squareness(yz=12.0), E.Scale(y=15.0)]
    runs = [simulate_ballbar_run(cmmpose.ErrorMapSet.thesis(), t, hidden, seed=10 + k)[0] for k, t in enumerate(temps)]
    print(f"{len(runs)} runs, {sum(len(r.points['u']) for r in runs):,} points")
    maps = cmmpose.ErrorMapSet.thesis()
    d = diagnose_jointly(runs, maps)  # warm: what loads on first use
    print(f"added: {', '.join(d.added) or 'nothing'}")
    joint, single = [], []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        cmmpose.evaluate(runs[0], maps)
        t1 = time.perf_counter()
        diagnose_jointly(runs, maps)
        t2 = time.perf_counter()
        single.append(t1 - t0)
        joint.append(t2 - t1)
    ratio = [j / s for j, s in zip(joint, single)]
    print(f"joint diagnosis of {len(runs)} runs: {min(joint):.2f}-{max(joint):.2f} s warm "
          f"(target <= 10 s); {min(ratio):.0f}-{max(ratio):.0f}x one evaluation of one run "
          f"({min(single) * 1e3:.0f}-{max(single) * 1e3:.0f} ms) timed beside it")


if __name__ == "__main__":
    main()
