"""How often the diagnosis picks the thermocouple role a squareness really
follows: three runs diagnosed together (`--joint`), each with another axis
warm by K kelvin (x, y, z in turn, at 26, 27 and 25.5 C), the truth's
squareness read at one role's temperature (x, y or z scale, in turn over the
seeds), 8 um scanner noise and per-scan jitter.

Outcomes per trial:
- right: the true role's candidate added, every other role 'not chosen';
- undecided: the true role's candidate added but another role's 'aliased'
  with it, or another role's (or a squareness offset) added with the true
  role among those the run says it cannot tell apart (honest, not wrong);
- wrong: another role added and the true role 'not chosen' (or 'preferred');
- missed: nothing of the group added.

    python benches/sensor_choice.py [--seeds 30] [--kelvin 1,2,3] [--jitter-um 1.5]

Prints per K the counts and the 95 % Clopper-Pearson bounds of the right and
wrong rates, and the time per joint diagnosis.
"""

from __future__ import annotations

import argparse
import time

import cmmpose
from cmmpose.diagnosis.joint import diagnose_jointly
from cmmpose.effects.axis_temperature import AxisTemperature
from cmmpose.effects.squareness_temperature import SquarenessTemperature
from cmmpose.sim.runs import simulate_ballbar_run
from cmmpose.sim.scanner import Scanner

ROLES = ("x_scale", "y_scale", "z_scale")
#: (machine temperature C, the warm axis) of each run.
PLAN = ((26.0, 2), (27.0, 0), (25.5, 1))


def bounds(k: int, n: int) -> tuple[float, float]:
    """Two-sided 95 % Clopper-Pearson interval of a rate seen k times in n."""
    from scipy.stats import binomtest

    ci = binomtest(k, n).proportion_ci(0.95, method="exact")
    return float(ci.low), float(ci.high)


def trial(maps, kelvin: float, truth: str, seed: int, jitter_mm: float, points: int) -> str:
    runs = []
    for i, (temperature, axis) in enumerate(PLAN):
        offsets = [0.0, 0.0, 0.0]
        offsets[axis] = kelvin
        effects = [AxisTemperature(*offsets), SquarenessTemperature(sensor=truth)]
        runs.append(simulate_ballbar_run(maps, temperature, effects, jitter=jitter_mm, seed=1000 * seed + i,
                                         scanner=Scanner(points_per_profile=points))[0])
    d = diagnose_jointly(runs, maps, max_effects=3)
    found = {x["name"]: x for x in d.decisions()}
    true = f"squareness-temperature@{truth}"
    group = [n for n in found if n.startswith("squareness-temperature@")] + ["squareness"]
    added = [n for n in group if found.get(n, {}).get("decision", "").startswith("added")]
    if not added:
        return "missed"
    if added == [true]:
        rivals = [found[n]["decision"] for n in group[:-1] if n != true]
        return "right" if all(r == "not chosen" for r in rivals) else "undecided"
    if found.get(true, {}).get("decision") == "aliased" or any(true in g and added[0] in g for g in d.ambiguous):
        return "undecided"
    return "wrong"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=30, help="trials per K (the true role cycles x, y, z)")
    ap.add_argument("--kelvin", default="1,2,3", help="how warm the warm axis of each run is, K")
    ap.add_argument("--jitter-um", type=float, default=1.5, help="per-scan reproducibility, um per axis")
    ap.add_argument("--points-per-profile", type=int, default=256)
    args = ap.parse_args()
    maps = cmmpose.ErrorMapSet.thesis()
    print(f"sensor choice: 3 joint runs (one axis warm in each), thesis maps, 8 um scanner noise, "
          f"{args.jitter_um:g} um per-scan jitter, {args.points_per_profile} points per profile")
    print(f"{'K':>4} {'trials':>7} {'right':>6} {'undecided':>10} {'wrong':>6} {'missed':>7} "
          f"{'right 95%':>14} {'wrong 95%':>14} {'s/trial':>8}")
    for kelvin in (float(k) for k in args.kelvin.split(",")):
        counts = {"right": 0, "undecided": 0, "wrong": 0, "missed": 0}
        t0 = time.perf_counter()
        for seed in range(args.seeds):
            counts[trial(maps, kelvin, ROLES[seed % 3], seed, args.jitter_um * 1e-3, args.points_per_profile)] += 1
        n = args.seeds
        per = (time.perf_counter() - t0) / max(n, 1)
        r_lo, r_hi = bounds(counts["right"], n)
        w_lo, w_hi = bounds(counts["wrong"], n)
        print(f"{kelvin:>4g} {n:>7} {counts['right']:>6} {counts['undecided']:>10} {counts['wrong']:>6} "
              f"{counts['missed']:>7} {f'{r_lo:.0%}-{r_hi:.0%}':>14} {f'{w_lo:.0%}-{w_hi:.0%}':>14} {per:>8.2f}")


if __name__ == "__main__":
    main()
