"""A sphere centre fitted to compensated points with their uncertainty
(cmmpose.centre_uncertainty): the common part of the points' covariance
passes to the centre whole, the independent part through the fit; checked
against the spread of fitted centres over Monte Carlo draws
(docs/uncertainty.md, section 5), and used by the E3125 distances.

Tolerance: the relative standard error of a standard deviation from M = 2000
draws is 1 / sqrt(2 x 1999) = 1.58 %; 3 of those (4.7 %) for the Monte Carlo,
plus 5 % for the approximation that the common part is one translation over
the sphere (a rotation error w moves the points by w x p, which changes by
|w| r over a ball of radius r = 12.7 mm against the digitizer's lever |p| of
295-302 mm here: 4 % of the move; measured: 3.5-3.7 % on y): 10 %.
"""

from __future__ import annotations

import numpy as np
import pytest

import cmmpose
from cmmpose import sim
from cmmpose.centre_uncertainty import e3125_uncertain, fit_uncertain_sphere, sphere_centre_uncertainty
from cmmpose.evaluation.point_monte_carlo import monte_carlo_points
from cmmpose.point_uncertainty import MapUncertainty, PoseUncertainty, UncertaintySources
from cmmpose.standards.e3125_distances import distance_errors, sphere_targets

POSE = (90.0, 90.0, 0.0)
OFFSET = cmmpose.MountOffset.thesis()
T = 22.5
MAP_U = MapUncertainty(position_um=((1.0, 0.5, 0.7), (0.6, 1.0, 0.8), (0.5, 0.6, 1.2)),
                       rotation_arcsec=((1.0, 0.8, 0.6), (0.7, 1.0, 0.9), (0.5, 0.6, 0.8)),
                       squareness_arcsec=(1.0, 0.8, 1.2), positioning_ppm=(3.0, 3.0, 3.0), source="test")
CASES = {
    # the pose and offset dominate (a calibration's 0.01 degree, 10-14 um)
    "all sources": UncertaintySources(map=MAP_U, temperature_k=0.3, scanner_scale_ppm=50.0,
                                      scanner_noise_um=(3.0, 8.0),
                                      pose=PoseUncertainty(np.diag([1e-4, 2e-4, 1.5e-4]),
                                                           np.diag([1e-4, 2e-4, 1e-4]) + 1e-5)),
    # the maps and temperature dominate, the noise is a visible share
    "maps, temperature, noise": UncertaintySources(map=MAP_U, temperature_k=0.3, scanner_noise_um=(3.0, 8.0)),
}
DRAWS = 2000
TOL = 0.10


@pytest.fixture(scope="module")
def maps():
    return cmmpose.ErrorMapSet.thesis()


@pytest.fixture(scope="module")
def scan(maps):
    return sim.simulate_reference_scan(maps, T)


@pytest.mark.parametrize("case", list(CASES))
def test_the_centres_spread_over_draws_is_the_stated_centre_uncertainty(maps, scan, case):
    src = CASES[case]
    radius = sim.reference_sphere().radius
    points = cmmpose.compensate(scan.uv, scan.scales, maps, POSE, OFFSET, T, uncertainty=src,
                                uncertainty_detail="split")
    free, fixed = fit_uncertain_sphere(points), fit_uncertain_sphere(points, radius)

    def centres(x):
        return np.concatenate([cmmpose.fit_sphere(x).centre, cmmpose.fit_sphere(x, radius).centre])

    mc = monte_carlo_points(scan.uv, scan.scales, maps, POSE, OFFSET, T, sources=src, draws=DRAWS, rng=7,
                            feature=centres)
    sd = mc.features.std(axis=0, ddof=1)
    for got, stated in ((sd[:3], free.centre), (sd[3:], fixed.centre)):
        assert np.all(np.abs(got / stated.u - 1) <= TOL), (got * 1e3, stated.u * 1e3)
        # the common part shrunk with the points' number would under-state the centre's uncertainty
        assert np.all(np.sqrt(np.diag(stated.shrunk)) < 0.2 * got)
        assert np.allclose(stated.covariance, stated.independent + stated.common)


def test_the_independent_part_through_the_fit_is_the_fits_own_for_equal_radial_noise(maps, scan):
    """Noise along every point's normal, the same at each: the propagated
    covariance is s^2 N, the fit's own (its residuals' s^2 aside)."""
    points = cmmpose.compensate(scan.uv, scan.scales, maps, POSE, OFFSET, T,
                                uncertainty=UncertaintySources(scanner_noise_um=8.0).without("map"),
                                uncertainty_detail="split")
    fit = cmmpose.fit_sphere(points.xyz)
    n = points.xyz - fit.centre
    n /= np.linalg.norm(n, axis=1)[:, None]
    s2 = 0.008 ** 2
    iso = np.einsum("ni,nj->nij", n, n) * s2  # radial noise s^2 n n^T
    radial = type(points)(points.xyz, points.u, iso[:, [0, 1, 2, 0, 0, 1], [0, 1, 2, 1, 2, 2]],
                          np.zeros((len(n), 6)), points.sources)
    cc = sphere_centre_uncertainty(radial, fit)
    own = fit.covariance[:3, :3] / fit.rms ** 2 * s2 * (fit.n_points - 4) / fit.n_points
    assert np.allclose(cc.independent, own, rtol=1e-3)
    assert np.all(cc.common == 0)


def test_points_without_the_split_are_refused(maps, scan):
    points = cmmpose.compensate(scan.uv, scan.scales, maps, POSE, OFFSET, T, uncertainty=True)
    with pytest.raises(cmmpose.InputError, match="uncertainty_detail='split'"):
        fit_uncertain_sphere(points)
    with pytest.raises(cmmpose.InputTypeError, match="UncertainPoints"):
        sphere_centre_uncertainty(points.xyz, cmmpose.fit_sphere(points.xyz))
    split = cmmpose.compensate(scan.uv, scan.scales, maps, POSE, OFFSET, T, uncertainty=True,
                               uncertainty_detail="split")
    with pytest.raises(cmmpose.InputError, match=f"made of {len(split.xyz[::10])} points"):
        sphere_centre_uncertainty(split, cmmpose.fit_sphere(split.xyz[::10]))


def test_e3125_distances_take_the_centres_uncertainty_from_the_points(maps):
    """Two balls scanned at one pose, their points compensated with their
    uncertainty: each target's covariance keeps the common part (tens of um
    from the pose), where the fit's residuals alone give a fraction of a um."""
    src = CASES["all sources"]
    scans, plain = {}, {}
    for name, centre in (("a", (300.0, 200.0, -420.0)), ("b", (600.0, 380.0, -400.0))):
        sphere = sim.Sphere(centre=centre, radius=12.7)
        d = sim.simulate_reference_scan(maps, T, POSE, tuple(OFFSET), sphere=sphere)
        pts = cmmpose.compensate(d.uv, d.scales, maps, POSE, OFFSET, T, uncertainty=src, uncertainty_detail="split")
        scans[name], plain[name] = pts, pts.xyz
    fit = cmmpose.fit_sphere(plain["a"], 12.7)
    origin = fit.centre + 150.0 * np.mean(plain["a"] - fit.centre, axis=0) / np.linalg.norm(
        np.mean(plain["a"] - fit.centre, axis=0))
    with_u = sphere_targets(scans, 12.7, origin)
    bare = sphere_targets(plain, 12.7, origin)
    for name in scans:
        assert np.allclose(with_u[name].centre, bare[name].centre)
        u, u_fit = np.sqrt(np.diag(with_u[name].covariance)), np.sqrt(np.diag(bare[name].covariance))
        assert np.all(u > 10 * u_fit)
        direct = e3125_uncertain(scans[name], 12.7, origin)
        assert np.allclose(with_u[name].covariance, direct.centre.covariance)
        assert np.allclose(direct.fit.centre_uncertainty, direct.centre.u)
    dist = float(np.linalg.norm(with_u["b"].centre - with_u["a"].centre))
    err = distance_errors(with_u, [("a", "b", dist, 0.0)]).errors[0]
    assert err.u_um > 10 * distance_errors(bare, [("a", "b", dist, 0.0)]).errors[0].u_um
