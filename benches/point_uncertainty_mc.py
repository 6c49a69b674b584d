"""Each compensated point's stated uncertainty against Monte Carlo (GUM
Supplement 1), the centre of a sphere fitted to such points likewise, and
coverage on truth-machine runs: the figures of docs/uncertainty.md, section 5.

    python benches/point_uncertainty_mc.py [--points 10000] [--draws 8000] [--centre-draws 4000] [--runs 2000]

1. Points: every source alone and all at once (on the thesis map set at
   22.5 C and on one map), each drawn from its stated distribution and the
   points compensated by the plain kernel (cmmpose.evaluation.point_monte_carlo);
   per case the largest |MC sd / stated u - 1| per axis over the points (a
   coordinate a source hardly moves, u under 1 % of the point's largest, is
   compared on that 1 %), and the share within 5 %.
2. Centres: the reference sphere scan, free and fixed radius, the spread of
   the fitted centres against cmmpose.centre_uncertainty's u, and what the
   fit gives when every point's covariance is taken as independent.
3. Coverage: the truth machine scans the reference sphere with maps,
   temperature, pose, offset and scanner scale off their stated values by
   one draw each; the share of the points' and centres' errors within k = 2.
"""

from __future__ import annotations

import argparse
import logging
import platform
import time
import warnings
from dataclasses import replace

import numpy as np

import cmmpose
from cmmpose import sim
from cmmpose.centre_uncertainty import fit_uncertain_sphere
from cmmpose.evaluation.point_monte_carlo import draw_map_errors, monte_carlo_points, perturbed_maps
from cmmpose.point_uncertainty import SOURCES, MapUncertainty, PoseUncertainty, UncertaintySources

T = 22.5
OFFSET = cmmpose.MountOffset.thesis()
MAP_U = MapUncertainty(position_um=((1.0, 0.5, 0.7), (0.6, 1.0, 0.8), (0.5, 0.6, 1.2)),
                       rotation_arcsec=((1.0, 0.8, 0.6), (0.7, 1.0, 0.9), (0.5, 0.6, 0.8)),
                       squareness_arcsec=(1.0, 0.8, 1.2), positioning_ppm=(3.0, 3.0, 3.0), source="bench")
POSE_U = PoseUncertainty(np.diag([1e-4, 2e-4, 1.5e-4]), np.diag([1e-4, 2e-4, 1e-4]) + 1e-5)
ALL = UncertaintySources(map=MAP_U, temperature_k=0.3, scanner_scale_ppm=50.0, scanner_noise_um=(3.0, 8.0),
                         pose=POSE_U)


def cpu_name() -> str:
    try:
        for line in open("/proc/cpuinfo", encoding="utf-8"):
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def scan(n: int, seed: int = 36):
    rng = np.random.default_rng(seed)
    scales = np.column_stack([rng.uniform(10, 890, n), rng.uniform(10, 540, n), rng.uniform(-490, -10, n)])
    uv = np.column_stack([rng.uniform(-20, 20, n), rng.uniform(90, 130, n)])
    return uv, scales


def model_case(maps):
    model = cmmpose.Model(maps).add("scale", [10.0, -5.0, 3.0]).add("squareness", [2.0, 1.0, -1.0])
    names = ["scale.x", "scale.y", "scale.z", "squareness.xy", "squareness.yz", "squareness.zx"]
    sd = np.array([2.0, 1.5, 3.0, 0.8, 0.6, 1.0])
    corr = np.eye(6)
    corr[0, 3] = corr[3, 0] = 0.6
    corr[1, 4] = corr[4, 1] = -0.5
    return replace(model, uncertainty={"scale": sd[:3], "squareness": sd[3:]},
                   covariance={"parameters": names, "matrix": (corr * np.outer(sd, sd)).tolist()})


def points_table(n: int, draws: int) -> None:
    maps = cmmpose.ErrorMapSet.thesis()
    uv, scales = scan(n)
    pose = (30.0, 60.0, 20.0)
    alone = lambda name: ALL.without(*(s for s in SOURCES if s != name))  # noqa: E731
    cases = [(f"{s} alone", maps, T, alone(s))
             for s in ("map", "temperature", "scanner_scale", "scanner_noise", "pose")]
    cases += [("model alone", model_case(maps), T, alone("model")), ("all, map set", maps, T, ALL),
              ("all, one map", maps.at(T).with_uncertainty(None), None, ALL)]
    print(f"1. points: {n} readings over the thesis maps' travel, pose {pose}, {draws} draws "
          f"(MC relative error of an sd 1/sqrt(2(M-1)) = {100 / np.sqrt(2 * (draws - 1)):.2f} %)")
    print(f"{'case':22s} {'largest |MC/u - 1| x, y, z (%)':>32s} {'mean (%)':>9s} {'within 5 %':>11s} {'s':>6s}")
    for name, m, t, src in cases:
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", cmmpose.ModelDomainWarning)
            stated = cmmpose.compensate(uv, scales, m, pose, OFFSET, t, uncertainty=src,
                                        uncertainty_detail="covariance")
            mc = monte_carlo_points(uv, scales, m, pose, OFFSET, t, sources=src, draws=draws, rng=1)
        ref = np.maximum(stated.u, 0.01 * stated.u.max(axis=1, keepdims=True))
        rel = (mc.u - stated.u) / ref
        worst = np.abs(rel).max(axis=0) * 100
        print(f"{name:22s} {worst[0]:10.2f} {worst[1]:10.2f} {worst[2]:10.2f} {rel.mean() * 100:+9.2f} "
              f"{np.mean(np.abs(rel) <= 0.05) * 100:10.2f}% {time.perf_counter() - t0:6.1f}")


def centres_table(draws: int) -> None:
    maps = cmmpose.ErrorMapSet.thesis()
    d = sim.simulate_reference_scan(maps, T)
    radius = sim.reference_sphere().radius
    pose = (90.0, 90.0, 0.0)
    cases = {"all sources": ALL, "maps, temperature, noise": UncertaintySources(map=MAP_U, temperature_k=0.3,
                                                                                  scanner_noise_um=(3.0, 8.0))}
    print(f"\n2. centres: the reference sphere scan ({len(d.uv)} points, r {radius} mm), {draws} draws")
    print(f"{'case':26s} {'fit':6s} {'stated u x, y, z (um)':>24s} {'MC sd (um)':>24s} {'MC/u - 1 (%)':>22s} "
          f"{'shrunk u (um)':>20s}")
    for name, src in cases.items():
        points = cmmpose.compensate(d.uv, d.scales, maps, pose, OFFSET, T, uncertainty=src, uncertainty_detail="split")
        fits = {"free": fit_uncertain_sphere(points), "fixed": fit_uncertain_sphere(points, radius)}
        mc = monte_carlo_points(d.uv, d.scales, maps, pose, OFFSET, T, sources=src, draws=draws, rng=7,
                                feature=lambda x: np.concatenate([cmmpose.fit_sphere(x).centre,
                                                                  cmmpose.fit_sphere(x, radius).centre]))
        sd = mc.features.std(axis=0, ddof=1)
        for (kind, f), got in zip(fits.items(), (sd[:3], sd[3:])):
            u, shrunk = f.centre.u, np.sqrt(np.diag(f.centre.shrunk))
            fmt = lambda v: " ".join(f"{x:7.2f}" for x in v)  # noqa: E731
            print(f"{name:26s} {kind:6s} {fmt(u * 1e3):>24s} {fmt(got * 1e3):>24s} {fmt((got / u - 1) * 100):>22s} "
                  f"{fmt(shrunk * 1e3):>20s}")


def coverage(runs: int) -> None:
    maps = cmmpose.ErrorMapSet.thesis()
    rng = np.random.default_rng(95)
    sphere = sim.reference_sphere()
    pose0 = np.array([90.0, 90.0, 0.0])
    scanner = cmmpose.scanner.Scanner(noise=8e-3, noise_u=3e-3)
    pts, cen, shr = [], [], []
    t0 = time.perf_counter()
    for r in range(runs):
        truth = perturbed_maps(maps, draw_map_errors(MAP_U, rng))
        pose = pose0 + rng.multivariate_normal(np.zeros(3), POSE_U.angle_covariance_deg2)
        offset = np.array(tuple(OFFSET)) + rng.multivariate_normal(np.zeros(3), POSE_U.offset_covariance_mm2)
        d = sim.simulate_reference_scan(truth, T + ALL.temperature_k * rng.normal(), tuple(pose), tuple(offset),
                                        sphere=sphere, scanner=scanner, seed=r)
        uv = d.uv * (1.0 + ALL.scanner_scale_ppm * 1e-6 * rng.normal())
        p = cmmpose.compensate(uv, d.scales, maps, tuple(pose0), OFFSET, T, uncertainty=ALL, uncertainty_detail="split")
        pts.append(np.mean(np.abs(p.xyz - d.true_xyz) <= 2 * p.u))
        f = fit_uncertain_sphere(p, sphere.radius)
        err = np.abs(f.fit.centre - sphere.centre)
        cen.append(err <= 2 * f.centre.u)
        shr.append(err <= 2 * np.sqrt(np.diag(f.centre.shrunk)))
    se = 100 * np.sqrt(0.9545 * 0.0455 / runs)
    print(f"\n3. coverage: {runs} truth-machine runs of the reference sphere ({len(d.uv)} points each), "
          f"{time.perf_counter() - t0:.0f} s; binomial se over runs {se:.2f} %")
    print(f"points within k = 2: {np.mean(pts) * 100:.2f} %; centres (radius fixed): {np.mean(cen) * 100:.2f} % "
          f"(x, y, z {', '.join(f'{v * 100:.1f}' for v in np.mean(cen, axis=0))} %); "
          f"with the common part shrunk by the fit: {np.mean(shr) * 100:.2f} %")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=10_000)
    ap.add_argument("--draws", type=int, default=8000)
    ap.add_argument("--centre-draws", type=int, default=4000)
    ap.add_argument("--runs", type=int, default=2000)
    a = ap.parse_args()
    logging.getLogger("cmmpose").setLevel(logging.ERROR)  # the model case's domain note, once per call
    print(f"CPU: {cpu_name()}; {cmmpose.thread_count()} threads")
    points_table(a.points, a.draws)
    centres_table(a.centre_draws)
    coverage(a.runs)


if __name__ == "__main__":
    main()
