"""Robust sphere fits (issue 14): rejection centred on the median, the named
rules, the least-median-of-squares start, a starting centre, and the
conditioning warning of a free radius on a small cap."""

import logging
import warnings

import numpy as np
import pytest

import cmmpose
from cmmpose import IllConditionedFit, InputError

CENTRE = np.array([12.0, -30.0, 7.0])
R = 50.0


def cap(rng, half_angle=90.0, n=3000, noise=0.01, axis=(0.0, 0.3, 1.0)):
    """Points uniform in area on a cap of the sphere (CENTRE, R), mm, with
    Gaussian noise along the normal."""
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    u = np.cross(a, [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(a, u)
    ct = 1.0 - rng.uniform(size=n) * (1.0 - np.cos(np.radians(half_angle)))
    st = np.sqrt(1.0 - ct**2)
    phi = rng.uniform(0, 2 * np.pi, n)
    d = ct[:, None] * a + st[:, None] * (np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * v)
    return CENTRE + d * (R + noise * rng.standard_normal(n))[:, None]


def one_sided(rng, frac, push=5.0):
    """A hemisphere with the fraction ``frac`` of its points, all on one side
    (largest x), pushed ``push`` mm outward; the clean points first."""
    p = cap(rng)
    p = p[np.argsort(p[:, 0])]
    bad = int(round(frac * len(p)))
    if bad:
        d = p[-bad:] - CENTRE
        p[-bad:] = CENTRE + d * ((R + push) / np.linalg.norm(d, axis=1))[:, None]
    return p, len(p) - bad


def clutter(rng, frac, n=3000):
    """A hemisphere plus clutter off the sphere on one side: ``frac`` of all
    points uniform in a box beside it (a wall, a stand, a hand)."""
    m = int(round(frac * n))
    p = cap(rng, n=n - m)
    box = CENTRE + np.column_stack([rng.uniform(20, 90, m), rng.uniform(-40, 40, m), rng.uniform(-10, 60, m)])
    return np.vstack([p, box]), n - m


@pytest.mark.parametrize("frac", [0.0, 0.1, 0.2, 0.3, 0.4])
@pytest.mark.parametrize("make", [one_sided, clutter])
def test_fixed_radius_recovers_the_clean_centre_up_to_40_percent_one_sided(frac, make):
    rng = np.random.default_rng(int(frac * 100) + (7 if make is clutter else 0))
    pts, clean = make(rng, frac)
    f = cmmpose.fit_sphere(pts, R, start="lmeds", rule="mad")
    # 3000 points with 10 um noise: the clean fit is within ~1 um of the truth.
    clean_fit = cmmpose.fit_sphere(pts[:clean], R)
    assert np.linalg.norm(f.centre - CENTRE) < 2e-3
    assert np.linalg.norm(f.centre - clean_fit.centre) < 5e-4
    # Every outlier goes, but clutter that happens to lie on the sphere
    # (within the noise) is as good as a clean point.
    assert np.all(np.abs(f.residuals[clean:][f.inlier[clean:]]) < 0.05)
    assert f.inlier[clean:].sum() <= 0.02 * (len(pts) - clean)
    assert f.inlier[:clean].mean() > 0.99
    if frac >= 0.3:
        # Least squares alone, and the rule alone, are pulled off by the
        # contamination: the high-breakdown start is what recovers the centre.
        plain = cmmpose.fit_sphere(pts, R)
        assert np.linalg.norm(plain.centre - CENTRE) > 0.3


@pytest.mark.parametrize("frac", [0.0, 0.2, 0.4])
def test_free_radius_recovers_the_clean_sphere_up_to_40_percent(frac):
    rng = np.random.default_rng(40 + int(frac * 10))
    pts, clean = one_sided(rng, frac)
    f = cmmpose.fit_sphere(pts, start="lmeds", rule="mad")
    assert np.linalg.norm(f.centre - CENTRE) < 5e-3 and abs(f.radius - R) < 5e-3
    assert not f.inlier[clean:].any()


def test_rejection_is_centred_on_the_median():
    # 10 % of the points 5 mm out on one side, free radius: the least-squares
    # sphere grows, so the clean points' residuals sit well below zero
    # (median -0.16 mm against a 0.01 mm noise). The rule about the median
    # drops exactly the pushed points and comes back to the clean sphere.
    rng = np.random.default_rng(5)
    pts, clean = one_sided(rng, 0.1)
    first = cmmpose.fit_sphere(pts)
    assert np.median(first.residuals[:clean]) < -0.1
    f = cmmpose.fit_sphere(pts, reject=3.5)
    assert not f.inlier[clean:].any() and f.inlier[:clean].mean() > 0.99
    assert np.linalg.norm(f.centre - CENTRE) < 2e-3 and abs(f.radius - R) < 2e-3
    # reject=k alone keeps meaning the repeated MAD rule.
    g = cmmpose.fit_sphere(pts, reject=3.5, rule="mad")
    assert np.array_equal(g.centre, f.centre) and np.array_equal(g.inlier, f.inlier)


def test_e3125_rule_is_one_pass_at_three_standard_deviations():
    rng = np.random.default_rng(6)
    pts = cap(rng, half_angle=70.0, n=2000)
    pts[:5] = CENTRE + (pts[:5] - CENTRE) * (R + 1.0) / R  # five points 1 mm out
    f = cmmpose.fit_sphere(pts, R, rule="e3125")
    first = cmmpose.fit_sphere(pts, R)
    s = first.residuals.std(ddof=1)
    # The kept set is exactly |r| <= 3 s of the first fit, refitted once.
    assert np.array_equal(f.inlier, np.abs(first.residuals) <= 3 * s)
    again = cmmpose.fit_sphere(pts[f.inlier], R)
    assert np.allclose(again.centre, f.centre, atol=1e-9, rtol=0)
    assert not f.inlier[:5].any()
    # Its multiple can be changed.
    g = cmmpose.fit_sphere(pts, R, rule="e3125", reject=2.0)
    assert np.array_equal(g.inlier, np.abs(first.residuals) <= 2 * s)


def test_start_centre_and_determinism():
    rng = np.random.default_rng(8)
    pts = cap(rng, half_angle=40.0, n=1500, noise=0.002)
    plain = cmmpose.fit_sphere(pts, R)
    from_start = cmmpose.fit_sphere(pts, R, start=CENTRE + [1.0, -2.0, 0.5])
    assert np.allclose(from_start.centre, plain.centre, atol=1e-9, rtol=0)
    # (A 40 degree cap: a free radius is ill-conditioned, and says so.)
    with pytest.warns(IllConditionedFit):
        free = cmmpose.fit_sphere(pts, start=CENTRE + [1.0, -2.0, 0.5])
    with pytest.warns(IllConditionedFit):
        assert np.allclose(free.centre, cmmpose.fit_sphere(pts).centre, atol=1e-7, rtol=0)
    # The same seed gives the same fit; the input is never modified.
    before = pts.copy()
    a = cmmpose.fit_sphere(pts, R, start="lmeds", seed=3)
    b = cmmpose.fit_sphere(pts, R, start="lmeds", seed=3)
    assert np.array_equal(a.centre, b.centre) and np.array_equal(a.inlier, b.inlier)
    assert np.array_equal(pts, before)


def test_free_radius_on_a_20_degree_cap_warns_and_logs(caplog):
    rng = np.random.default_rng(9)
    pts = cap(rng, half_angle=20.0, n=2000)
    with caplog.at_level(logging.WARNING, logger="cmmpose"):
        with pytest.warns(IllConditionedFit, match=r"correlation 0\.99\d\d .*20\.\d deg cap.*radius fixed"):
            f = cmmpose.fit_sphere(pts)
    assert f.centre_radius_correlation > 0.999
    assert any("ill-determined" in r.message for r in caplog.records)
    # A fixed radius, or a hemisphere, does not warn.
    with warnings.catch_warnings():
        warnings.simplefilter("error", IllConditionedFit)
        g = cmmpose.fit_sphere(pts, R)
        assert np.isnan(g.centre_radius_correlation)
        h = cmmpose.fit_sphere(cap(rng, half_angle=90.0))
        assert 0.8 < h.centre_radius_correlation < 0.9  # sqrt(3) / 2 for a uniform hemisphere
    # Many spheres: one warning naming the ill-conditioned labels.
    both = np.vstack([pts, cap(rng, half_angle=90.0)])
    labels = np.repeat([1, 2], [len(pts), len(both) - len(pts)])
    with pytest.warns(IllConditionedFit, match=r"1 of 2 spheres \(1; worst 1\)"):
        fits = cmmpose.fit_spheres(both, labels)
    rho = fits.centre_radius_correlation
    assert rho[0] > 0.999 and rho[1] < 0.9
    assert rho[0] == pytest.approx(fits[1].centre_radius_correlation)


def test_robust_fit_of_many_spheres_matches_single_fits():
    rng = np.random.default_rng(10)
    a, _ = one_sided(rng, 0.3)
    b, _ = clutter(rng, 0.3)
    pts = np.vstack([a, b])
    labels = np.repeat([0, 1], [len(a), len(b)])
    fits = cmmpose.fit_spheres(pts, labels, R, start="lmeds", rule="mad")
    for k, p in enumerate((a, b)):
        one = cmmpose.fit_sphere(p, R, start="lmeds", rule="mad")
        assert np.array_equal(fits.centre[k], one.centre)
        assert np.linalg.norm(one.centre - CENTRE) < 2e-3


@pytest.mark.parametrize("kwargs, match", [
    ({"rule": "bogus"}, "rule: "),
    ({"rule": "none", "reject": 3.0}, "reject: "),
    ({"reject": -1.0}, "reject: "),
    ({"start": "ransac"}, "start: "),
    ({"start": (np.nan, 0.0, 0.0)}, "start: "),
    ({"start": (1.0, 2.0)}, "start: "),
    ({"start": "lmeds", "samples": 0}, "samples: "),
    ({"seed": -1}, "seed: "),
])
def test_bad_robust_options_name_the_argument(kwargs, match):
    pts = cap(np.random.default_rng(11), n=100)
    with pytest.raises(InputError, match=match):
        cmmpose.fit_sphere(pts, R, **kwargs)


def test_bad_segmentation_options_name_the_argument():
    pts = cap(np.random.default_rng(12), n=200)
    for kwargs, match in [({"radius": -1.0}, "radius: "), ({"scanner_origin": (0, 0)}, "scanner_origin: "),
                          ({"half_angle": 120.0}, "half_angle: "), ({"rule": "x"}, "rule: "),
                          ({"max_rounds": 0}, "max_rounds: "), ({"start": (np.inf, 0, 0)}, "start: ")]:
        args = {"radius": R, "scanner_origin": (0.0, 0.0, 0.0), **kwargs}
        with pytest.raises(InputError, match=match):
            cmmpose.segment_sphere(pts, **args)
    with pytest.raises(InputError, match="start: "):
        cmmpose.fit_spheres(pts, np.zeros(len(pts)), start=(0.0, 0.0, 0.0))
    # The scanner sitting on a point.
    with pytest.raises(InputError, match="scanner_origin: coincides with point 3"):
        cmmpose.segment_sphere(pts, R, pts[3])
