"""False alarms of the diagnosis on noise-only runs (issue 25: "<= 5 % of
noise-only runs raise any false message, family-wise, 200 seeds per
layout"). Each run has no effect beyond the maps (the thesis machine,
realistic per-scan jitter on top of the 8 um scanner noise); every message
such a run could raise counts as false:

- ``effect``: a library (or user) effect added;
- ``map``: a map correction added (``map:...``, cmmpose.diagnosis.mapfamily);
- ``pattern``: a significant residual pattern of the final model;
- ``unexpl.``: an unexplained finding (periodic error, pattern the library
  cannot explain; cmmpose.diagnosis.unexplained);
- ``floor``: "N um is unexplained above a floor of M um" (the residuals
  not consistent with the noise floor; cmmpose.diagnosis.floor);
- ``2-axis``: an error varying with two axes at once reported unexplained.

``any`` counts the runs that raised at least one (family-wise). Per layout
the bench prints each count, the family-wise rate with its two-sided 95 %
Clopper-Pearson interval, and the time per diagnosis.

    python benches/diagnosis_false_alarms.py [--seeds 200] [--layouts b89,crossed] [--jitter-um 3]
    python benches/diagnosis_false_alarms.py --smoke        # 3 seeds, coarse scans: that it runs
    python benches/diagnosis_false_alarms.py --log runs.jsonl   # one JSON line per run as it finishes
"""

from __future__ import annotations

import argparse
import json
import time

import cmmpose
from cmmpose.sim.runs import simulate_ballbar_run
from cmmpose.sim.scanner import Scanner

#: Message kinds, in the table's order.
KINDS = ("effect", "map", "pattern", "unexplained", "floor", "two_axis")
#: The promise: at most this share of noise-only runs raise any message.
PROMISE = 0.05


def interval_95(k: int, n: int) -> tuple[float, float]:
    """Two-sided 95 % Clopper-Pearson interval of a rate seen k times in n."""
    from scipy.stats import binomtest

    ci = binomtest(k, n).proportion_ci(0.95, method="exact")
    return float(ci.low), float(ci.high)


def messages(d) -> dict[str, bool]:
    """Which kinds of message the diagnosis ``d`` of a noise-only run raised."""
    added = list(d.added)
    noise = d.noise or {}
    return {"effect": any(not n.startswith("map:") for n in added),
            "map": any(n.startswith("map:") for n in added),
            "pattern": any(p.significant for p in (d.patterns or [])),
            "unexplained": bool(d.unexplained),
            "floor": noise.get("noise") is False,
            "two_axis": bool(d.two_axis)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=200, help="noise-only runs per layout (default 200)")
    ap.add_argument("--layouts", default="b89,crossed")
    ap.add_argument("--jitter-um", type=float, default=3.0, help="per-scan reproducibility, um per axis")
    ap.add_argument("--points-per-profile", type=int, default=256)
    ap.add_argument("--no-stated-floor", action="store_true",
                    help="do not state the per-scan reproducibility (the jitter) to the diagnosis: then a run that "
                         "repeats no scan has no noise floor and the floor message cannot be raised")
    ap.add_argument("--smoke", action="store_true", help="3 seeds with 64 points per profile: that the bench runs")
    ap.add_argument("--log", default=None, help="append one JSON line per run (layout, seed, messages, added)")
    args = ap.parse_args()
    if args.smoke:
        args.seeds, args.points_per_profile = 3, 64
    maps = cmmpose.ErrorMapSet.thesis()
    print(f"noise-only runs: thesis maps, 8 um scanner noise, {args.jitter_um:g} um per-scan jitter, "
          f"{args.points_per_profile} points per profile, {args.seeds} seeds per layout, "
          f"per-scan reproducibility {'not stated' if args.no_stated_floor else 'stated (the jitter)'}")
    head = " ".join(f"{k.replace('unexplained', 'unexpl.').replace('two_axis', '2-axis'):>7}" for k in KINDS)
    print(f"{'layout':8} {'runs':>5} {head} {'any':>5} {'rate':>6} {'95% interval':>15} {'s/diag':>7}")
    log = open(args.log, "a") if args.log else None
    try:
        for layout in args.layouts.split(","):
            counts = dict.fromkeys(KINDS, 0)
            anyk, elapsed = 0, 0.0
            for seed in range(args.seeds):
                run, _ = simulate_ballbar_run(maps, 22.5, [], layout=layout, jitter=args.jitter_um * 1e-3,
                                              seed=10_000 + seed,
                                              scanner=Scanner(points_per_profile=args.points_per_profile))
                t0 = time.perf_counter()
                d = cmmpose.diagnose(run, maps, max_effects=2,
                                     reproducibility_um=None if args.no_stated_floor else args.jitter_um)
                elapsed += time.perf_counter() - t0
                flags = messages(d)
                for k, v in flags.items():
                    counts[k] += v
                anyk += any(flags.values())
                if log is not None:
                    log.write(json.dumps({"layout": layout, "seed": seed, **flags, "added": list(d.added),
                                          "two_axis_found": [f.get("description") for f in d.two_axis],
                                          "floor_verdict": (d.noise or {}).get("verdict")}) + "\n")
                    log.flush()
            n = args.seeds
            lo, hi = interval_95(anyk, n)
            cells = " ".join(f"{counts[k]:7d}" for k in KINDS)
            verdict = "holds" if hi <= PROMISE else ("broken" if lo > PROMISE else "not shown at this n")
            print(f"{layout:8} {n:5d} {cells} {anyk:5d} {anyk / n:6.1%} {f'[{lo:.1%}, {hi:.1%}]':>15} "
                  f"{elapsed / n:7.2f}   <= {PROMISE:.0%}: {verdict}")
    finally:
        if log is not None:
            log.close()


if __name__ == "__main__":
    main()
