"""Coverage of the uncertainties ``cmmpose evaluate`` states (k = 2): how
often the compensated figures' errors against the simulator's truth fall
within 2 (and 1, 3) stated standard uncertainties, over many simulated B89
runs with per-scan reproducibility switched on.

    python benches/evaluation_coverage.py [--runs 200] [--jitter 3]

Every run draws what the budget says is uncertain, at the stated standard
uncertainty, and hides it from the evaluation:

- per-scan reproducibility: the simulator's ``jitter`` (the ball's apparent
  centre moves from scan to scan; default 3 um per axis);
- the machine temperature reading: the evaluation is told T + dT, dT ~ N(0, u_T);
- each axis's map scale: a ``scale`` effect of N(0, u_map) ppm per axis;
- the artefact's expansion coefficient: an ``artefact-expansion`` effect of
  N(12, u_alpha) ppm/K while the evaluation uses 12 ppm/K.

The errors: each compensated length against the true bar length at the
machine temperature, the mean likewise, and the lengths and mean at 20 C
against the true length at 20 C.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import cmmpose
from cmmpose.evaluation.ballbar_uncertainty import (
    DEFAULT_U_EXPANSION_PPM_PER_K,
    DEFAULT_U_TEMPERATURE_K,
    default_map_ppm,
    evaluation_uncertainty,
)
from cmmpose.sim import parse_effect, simulate_ballbar_run
from cmmpose.sim.scanner import Scanner

ALPHA_PPM = 12.0


def one_run(i: int, args, maps) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Errors and stated u (um) of one simulated run, by figure."""
    rng = np.random.default_rng([args.seed, i])
    d_t = float(rng.normal(0.0, args.u_temperature))
    scale = [float(x) for x in rng.normal(0.0, args.u_map, 3)]
    alpha = ALPHA_PPM + float(rng.normal(0.0, args.u_expansion))
    effects = [parse_effect(f"scale:x={scale[0]!r},y={scale[1]!r},z={scale[2]!r}"),
               parse_effect(f"artefact-expansion:ppm_per_kelvin={alpha!r}")]
    run, truth = simulate_ballbar_run(maps, args.temperature, effects, jitter=args.jitter * 1e-3,
                                      scanner=Scanner(points_per_profile=args.points), seed=10_000 + i)
    told = args.temperature + d_t
    ev = cmmpose.evaluate(run, maps, told, expansion_ppm_per_K=ALPHA_PPM)
    unc = evaluation_uncertainty(run, ev, maps, told, u_temperature_K=args.u_temperature, u_map_ppm=args.u_map,
                                 u_expansion_ppm_per_K=args.u_expansion)["compensated"]
    res = ev.compensated
    true20 = truth[0]["true_lengths"]
    true_t = true20 * (1 + alpha * 1e-6 * (args.temperature - 20.0))
    u_l = np.array([f.u for f in unc.lengths])
    u_l20 = np.array([f.u for f in unc.lengths_20c])
    return {
        "length": ((res.lengths - true_t) * 1e3, u_l),
        "mean length": (np.array([(res.mean_length - true_t.mean()) * 1e3]), np.array([unc.mean.u])),
        "length at 20 C": ((res.lengths_at_20c - true20) * 1e3, u_l20),
        "mean length at 20 C": (np.array([(res.mean_length_at_20c - true20.mean()) * 1e3]), np.array([unc.mean_20c.u])),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=200)
    p.add_argument("--jitter", type=float, default=3.0, help="per-scan reproducibility, um per axis")
    p.add_argument("--temperature", type=float, default=22.5, help="machine temperature, C")
    p.add_argument("--u-temperature", type=float, default=DEFAULT_U_TEMPERATURE_K, help="K")
    p.add_argument("--u-map", type=float, default=default_map_ppm(), help="ppm per axis")
    p.add_argument("--u-expansion", type=float, default=DEFAULT_U_EXPANSION_PPM_PER_K, help="ppm/K")
    p.add_argument("--points", type=int, default=256, help="points per scanner profile (speed)")
    p.add_argument("--seed", type=int, default=17)
    args = p.parse_args()
    maps = cmmpose.ErrorMapSet.thesis()
    start = time.perf_counter()
    collected: dict[str, list] = {}
    for i in range(args.runs):
        for key, (err, u) in one_run(i, args, maps).items():
            collected.setdefault(key, []).append((err, u))
    elapsed = time.perf_counter() - start
    print(f"{args.runs} simulated B89 runs (thesis maps, {args.temperature:g} C, jitter {args.jitter:g} um, "
          f"u_T {args.u_temperature:g} K, u_map {args.u_map:.3g} ppm, u_alpha {args.u_expansion:g} ppm/K), "
          f"{elapsed:.0f} s")
    print(f"{'figure':<22}{'n':>7}{'sd error um':>13}{'mean u um':>11}{'within 1u':>11}{'within 2u':>11}{'within 3u':>11}")
    for key, items in collected.items():
        err = np.concatenate([e for e, _ in items])
        u = np.concatenate([u for _, u in items])
        z = np.abs(err) / u
        print(f"{key:<22}{len(err):>7}{np.std(err):>13.2f}{np.mean(u):>11.2f}"
              + "".join(f"{np.mean(z <= k):>11.1%}" for k in (1, 2, 3)))


if __name__ == "__main__":
    main()
