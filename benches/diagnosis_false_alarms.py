"""False alarms of the diagnosis on null machines (issue 33, "Done when": "on
null machines at most 1 % of runs carry any claim, 200 seeds per layout").
Each run has no error beyond the maps (the thesis machine, realistic per-scan
jitter on top of the 8 um scanner noise, the jitter stated as the per-scan
reproducibility); every claim such a run carries is false. A claim is what
``Diagnosis.claims`` counts (the same definition as the null machines of
benches/unseen_placements.py):

- ``effect``: a library (or user) effect added;
- ``map``: a map correction added (``map:...``, cmmpose.diagnosis.mapfamily);
- ``ambig.``: an open ambiguity set, or a group the run cannot tell apart;
- ``pattern``: a significant residual pattern of the final model;
- ``unexpl.``: an unexplained finding (periodic error, pattern the library
  cannot explain; cmmpose.diagnosis.unexplained);
- ``floor``: "N um is unexplained above a floor of M um" (the residuals
  not consistent with the noise floor; cmmpose.diagnosis.floor);
- ``2-axis``: an error varying with two axes at once reported unexplained.

Layouts: every one a user measures. ``b89`` and ``crossed``: a ballbar run
(cmmpose.sim.runs.simulate_ballbar_run); ``plate``: the KOBA 420 mm ball
plate in the XY, XZ and YZ planes in one run (the ``planes`` layout,
cmmpose.sim.artefact_runs); ``plate-joint``: the plate at two XY placements,
two runs diagnosed jointly (cmmpose.diagnosis.diagnose_jointly, as the
training runs of benches/unseen_placements.py).

``any`` counts the runs that carry at least one claim; ``pooled`` the
layouts together (the promise is each layout's, so the pool tests it with
a tighter interval). Per layout the bench
prints each count, the rate of runs with any claim with its two-sided 95 %
Clopper-Pearson interval, whether the promise (<= 1 %) holds, and the time
per diagnosis. At 200 seeds "<= 1 %" allows 2 runs with a claim; the verdict
"holds" needs the interval's upper end at or below 1 %, which 200 runs cannot
give (0 of 200 gives [0, 1.8 %]): "within" says the count is at most 1 % of
the runs, "broken" that the interval lies above 1 %.

    python benches/diagnosis_false_alarms.py [--seeds 200] [--first-seed 0] [--layouts b89,crossed,plate,plate-joint]
    python benches/diagnosis_false_alarms.py --seeds 2          # CI smoke
    python benches/diagnosis_false_alarms.py --log runs.jsonl   # one JSON line per run as it finishes

Figures (AMD EPYC, 2 cores shared with other work, one thread), seeds
1000-1199, which no change was studied on (docs/diagnosis.md, "False alarms"):

    RAYON_NUM_THREADS=1 python benches/diagnosis_false_alarms.py --seeds 200 --first-seed 1000 --log runs.jsonl

    layout       runs  effect     map  ambig. pattern unexpl.   floor  2-axis   any   rate    95% interval
    b89           200       0       0       1       0       0       0       0     1   0.5%    [0.0%, 2.8%]
    crossed       200       0       1       0       0       0       0       0     1   0.5%    [0.0%, 2.8%]
    plate         200       1       0       0       0       0       0       0     1   0.5%    [0.0%, 2.8%]
    plate-joint   200       1       0       1       0       0       0       0     1   0.5%    [0.0%, 2.8%]
    pooled        800                                                             4   0.5%   [0.1%, 1.3%]

Each within the promise (at most 2 of 200); 1-5 s per diagnosis on the
shared machine. With the noise floor tested at 0.01 (before issue 33's
change, cmmpose.diagnosis.floor.FLOOR_ALPHA) the same runs carried 4, 3, 1
and 2 claims (10 of 800): the floor's p-values are uniform on null runs, so
at 0.01 it alone made 1 % of them claim error above the floor. Every family
of tests whose rejection is a claim now runs at ALPHA = 1e-3, seven families
(cmmpose.diagnosis.statistics.CLAIM_FAMILIES): at most 0.7 % by the union
bound.
"""

from __future__ import annotations

import argparse
import json
import time
import warnings

import cmmpose
from cmmpose.artefacts import load_artefact
from cmmpose.diagnosis.joint import diagnose_jointly
from cmmpose.errormap import data_path
from cmmpose.sim.artefact_runs import simulate_artefact_run
from cmmpose.sim.runs import simulate_ballbar_run
from cmmpose.sim.scanner import Scanner

#: Claim kinds (``Diagnosis.claims``), in the table's order.
KINDS = ("effect", "map", "ambiguous", "pattern", "unexplained", "floor", "two_axis")
SHORT = {"ambiguous": "ambig.", "unexplained": "unexpl.", "two_axis": "2-axis"}
#: The promise (issue 33): at most this share of null runs carry any claim.
PROMISE = 0.01
LAYOUTS = ("b89", "crossed", "plate", "plate-joint")
PLATE = "koba-0420.toml"
#: The plate's placements: the three planes in one run; two XY placements diagnosed jointly.
PLATE_PLACEMENTS = {"plate": ["planes"], "plate-joint": ["xy@x=300,y=250,z=-400", "xy@x=560,y=300,z=-400"]}


def interval_95(k: int, n: int) -> tuple[float, float]:
    """Two-sided 95 % Clopper-Pearson interval of a rate seen k times in n."""
    from scipy.stats import binomtest

    ci = binomtest(k, n).proportion_ci(0.95, method="exact")
    return float(ci.low), float(ci.high)


def verdict(k: int, n: int, promise: float = PROMISE) -> str:
    lo, hi = interval_95(k, n)
    if hi <= promise:
        return "holds"
    if lo > promise:
        return "broken"
    return "within (count <= promise)" if k <= promise * n else "exceeded (count > promise)"


def diagnose_null(layout: str, seed: int, maps, jitter_um: float, points_per_profile: int, stated: bool):
    """The diagnosis of one null run (or, ``plate-joint``, two) of ``layout``."""
    scanner = Scanner(points_per_profile=points_per_profile)
    reproducibility = None if not stated else jitter_um
    if layout in ("b89", "crossed"):
        run, _ = simulate_ballbar_run(maps, 22.5, [], layout=layout, jitter=jitter_um * 1e-3, seed=10_000 + seed,
                                      scanner=scanner)
        runs = [run]
    elif layout in PLATE_PLACEMENTS:
        plate = load_artefact(data_path("artefacts", PLATE))
        # ``plate``: the three planes in one run; ``plate-joint``: one run per placement
        groups = [PLATE_PLACEMENTS[layout]] if layout == "plate" else [[p] for p in PLATE_PLACEMENTS[layout]]
        runs = [simulate_artefact_run(plate, g, maps, jitter=jitter_um * 1e-3, seed=20_000 + 10 * seed + i,
                                      scanner=scanner)[0] for i, g in enumerate(groups)]
    else:
        raise SystemExit(f"unknown layout {layout!r}; known: {', '.join(LAYOUTS)}")
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if len(runs) == 1:
            d = cmmpose.diagnose(runs[0], maps, max_effects=2, reproducibility_um=reproducibility)
        else:
            d = diagnose_jointly(runs, maps, max_effects=2, reproducibility_um=reproducibility)
    return d, time.perf_counter() - t0


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=200, help="null runs per layout (default 200)")
    ap.add_argument("--first-seed", type=int, default=0,
                    help="the first seed (default 0): other seeds than those a change was studied on")
    ap.add_argument("--layouts", default=",".join(LAYOUTS), help="comma-separated: " + ", ".join(LAYOUTS))
    ap.add_argument("--jitter-um", type=float, default=3.0, help="per-scan reproducibility, um per axis")
    ap.add_argument("--points-per-profile", type=int, default=256)
    ap.add_argument("--no-stated-floor", action="store_true",
                    help="do not state the per-scan reproducibility (the jitter) to the diagnosis: then a run that "
                         "repeats no scan has no noise floor and the floor claim cannot be made")
    ap.add_argument("--smoke", action="store_true", help="3 seeds with 64 points per profile: that the bench runs")
    ap.add_argument("--log", default=None, help="append one JSON line per run (layout, seed, claims, added)")
    args = ap.parse_args(argv)
    if args.smoke:
        args.seeds, args.points_per_profile = 3, 64
    layouts = [x for x in args.layouts.split(",") if x]
    unknown = [x for x in layouts if x not in LAYOUTS]
    if unknown:
        ap.error(f"unknown layout(s) {unknown}; known: {', '.join(LAYOUTS)}")
    maps = cmmpose.ErrorMapSet.thesis()
    print(f"null runs: thesis maps, 8 um scanner noise, {args.jitter_um:g} um per-scan jitter, "
          f"{args.points_per_profile} points per profile, seeds {args.first_seed}-{args.first_seed + args.seeds - 1} "
          f"per layout, per-scan reproducibility {'not stated' if args.no_stated_floor else 'stated (the jitter)'}")
    head = " ".join(f"{SHORT.get(k, k):>7}" for k in KINDS)
    print(f"{'layout':11} {'runs':>5} {head} {'any':>5} {'rate':>6} {'95% interval':>15} {'s/diag':>7}")
    log = open(args.log, "a") if args.log else None
    total_any = 0
    try:
        for layout in layouts:
            counts = dict.fromkeys(KINDS, 0)
            anyk, elapsed = 0, 0.0
            for seed in range(args.first_seed, args.first_seed + args.seeds):
                d, dt = diagnose_null(layout, seed, maps, args.jitter_um, args.points_per_profile,
                                      not args.no_stated_floor)
                elapsed += dt
                flags = d.claims
                for k in KINDS:
                    counts[k] += flags[k]
                anyk += any(flags.values())
                if log is not None:
                    noise = d.noise or {}
                    log.write(json.dumps({"layout": layout, "seed": seed, **flags, "added": list(d.added),
                                          "ambiguous_groups": [list(a) for a in d.ambiguous],
                                          "open_ambiguity": len(d.open_ambiguity),
                                          "unexplained_found": [f.to_dict() for f in d.unexplained],
                                          "patterns_found": [p.to_dict() for p in
                                                             (d.patterns.significant if d.patterns else ())],
                                          "two_axis_found": [f.get("description") for f in d.two_axis],
                                          "floor_p": noise.get("p_value"), "floor_verdict": noise.get("verdict"),
                                          "seconds": dt}, default=str) + "\n")
                    log.flush()
            n = args.seeds
            lo, hi = interval_95(anyk, n)
            cells = " ".join(f"{counts[k]:7d}" for k in KINDS)
            print(f"{layout:11} {n:5d} {cells} {anyk:5d} {anyk / n:6.1%} {f'[{lo:.1%}, {hi:.1%}]':>15} "
                  f"{elapsed / n:7.2f}   <= {PROMISE:.0%}: {verdict(anyk, n)}", flush=True)
            total_any += anyk
        if len(layouts) > 1:  # the layouts pooled: the promise is the same for each, so the pool tests it tighter
            n = args.seeds * len(layouts)
            lo, hi = interval_95(total_any, n)
            print(f"{'pooled':11} {n:5d} {'':{8 * len(KINDS) - 1}} {total_any:5d} {total_any / n:6.1%} "
                  f"{f'[{lo:.1%}, {hi:.1%}]':>15} {'':7}   <= {PROMISE:.0%}: {verdict(total_any, n)}")
    finally:
        if log is not None:
            log.close()


if __name__ == "__main__":
    main()
