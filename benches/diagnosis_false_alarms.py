"""False alarms of the diagnosis on noise-only runs: the share of simulated
runs with no effect beyond the maps (the thesis machine, realistic per-scan
jitter on top of the 8 um scanner noise) for which `cmmpose.diagnose` says
anything is missing: an effect added, a significant residual pattern of the
final model, or an unexplained finding. The goal is <= 5 % family-wise.

    python benches/diagnosis_false_alarms.py [--seeds 200] [--layouts b89,crossed] [--jitter-um 3]

Prints, per layout, how many runs raised each kind of message, with the
binomial 95 % upper bound of the rate, and the time per diagnosis.
"""

from __future__ import annotations

import argparse
import math
import time

import cmmpose
from cmmpose.sim.runs import simulate_ballbar_run
from cmmpose.sim.scanner import Scanner


def upper_95(k: int, n: int) -> float:
    """One-sided 95 % Clopper-Pearson upper bound of a rate seen k times in n."""
    from scipy.stats import binomtest

    return float(binomtest(k, n, alternative="less").proportion_ci(0.95, method="exact").high)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=200)
    ap.add_argument("--layouts", default="b89,crossed")
    ap.add_argument("--jitter-um", type=float, default=3.0, help="per-scan reproducibility, um per axis")
    ap.add_argument("--points-per-profile", type=int, default=256)
    args = ap.parse_args()
    maps = cmmpose.ErrorMapSet.thesis()
    print(f"noise-only runs: thesis maps, 8 um scanner noise, {args.jitter_um:g} um per-scan jitter, "
          f"{args.points_per_profile} points per profile")
    print(f"{'layout':8} {'runs':>5} {'added':>6} {'pattern':>8} {'unexpl.':>8} {'any':>5} {'rate':>6} "
          f"{'95% upper':>9} {'s/diag':>7}")
    for layout in args.layouts.split(","):
        counts = {"added": 0, "pattern": 0, "unexplained": 0, "any": 0}
        elapsed = 0.0
        for seed in range(args.seeds):
            run, _ = simulate_ballbar_run(maps, 22.5, [], layout=layout, jitter=args.jitter_um * 1e-3,
                                          seed=10_000 + seed, scanner=Scanner(points_per_profile=args.points_per_profile))
            t0 = time.perf_counter()
            d = cmmpose.diagnose(run, maps, max_effects=2)
            elapsed += time.perf_counter() - t0
            flags = {"added": bool(d.added), "pattern": any(p.significant for p in d.patterns),
                     "unexplained": bool(d.unexplained)}
            for k, v in flags.items():
                counts[k] += v
            counts["any"] += any(flags.values())
        n = args.seeds
        print(f"{layout:8} {n:5d} {counts['added']:6d} {counts['pattern']:8d} {counts['unexplained']:8d} "
              f"{counts['any']:5d} {counts['any'] / n:6.1%} {upper_95(counts['any'], n):9.1%} {elapsed / n:7.2f}")


if __name__ == "__main__":
    main()
