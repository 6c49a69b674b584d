"""Sphere and plane fits through the Python API: against the independent NumPy
geometric fit, batch against single, and every bad input."""

import numpy as np
import pytest

import cmmpose
from cmmpose import sim

from numpy_sphere_fit import fit_sphere_reference


def cap(rng, n=5000, half_angle=70.0, centre=(10.0, -20.0, 30.0), radius=38.125, noise=0.008):
    d = rng.normal(size=(4 * n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d = d[d[:, 2] >= np.cos(np.radians(half_angle))][:n]
    return np.asarray(centre) + (radius + rng.normal(0, noise, len(d)))[:, None] * d


def test_matches_the_numpy_reference_on_a_simulated_scan():
    d = sim.simulate_reference_scan(temperature=20.0, seed=2, sphere=sim.Sphere((450, 380, -420), 38.125))
    xyz = cmmpose.compensate(d.uv, d.scales, cmmpose.ErrorMapSet.thesis(), (90, 90, 0), cmmpose.MountOffset.thesis(), 20.0)
    f = cmmpose.fit_sphere(xyz)
    c, r = fit_sphere_reference(xyz)
    # Both find the same least-squares minimum: they differ by rounding only.
    assert np.abs(f.centre - c).max() < 1e-9 and abs(f.radius - r) < 1e-9
    assert f.converged and f.n_points == len(xyz) and f.rejected == 0
    assert 0.006 < f.rms < 0.010  # 8 um noise on v
    np.testing.assert_allclose(f.residuals, np.linalg.norm(xyz - f.centre, axis=1) - f.radius, atol=1e-12)


def test_batch_equals_single_fits_and_keeps_labels():
    rng = np.random.default_rng(1)
    sets = {7: cap(rng, centre=(0, 0, 0)), 3: cap(rng, centre=(100, 0, 0)), 5: cap(rng, centre=(0, 200, 0))}
    labels = np.concatenate([np.full(len(p), k) for k, p in sets.items()])
    pts = np.vstack(list(sets.values()))
    perm = rng.permutation(len(pts))
    fits = cmmpose.fit_spheres(pts[perm], labels[perm])
    assert list(fits) == [3, 5, 7]
    for k, p in sets.items():
        mask = labels[perm] == k
        single = cmmpose.fit_sphere(pts[perm][mask])
        assert np.abs(fits[k].centre - single.centre).max() < 1e-12
        np.testing.assert_array_equal(fits[k].residuals, single.residuals)


def test_covariance_predicts_the_scatter():
    rng = np.random.default_rng(2)
    centres = np.array([cmmpose.fit_sphere(cap(rng, n=2000, half_angle=60)).centre for _ in range(60)])
    predicted = cmmpose.fit_sphere(cap(rng, n=2000, half_angle=60)).centre_uncertainty
    np.testing.assert_allclose(centres.std(axis=0, ddof=1), predicted, rtol=0.3)


def test_fixed_radius_and_robust_rejection():
    rng = np.random.default_rng(3)
    ball = cap(rng, centre=(0, 0, 0))
    stand = np.column_stack([rng.uniform(-5, 5, 300), rng.uniform(-5, 5, 300), rng.uniform(-60, -40, 300)])
    f = cmmpose.fit_sphere(np.vstack([ball, stand]), reject=3.5)
    assert f.rejected >= 300 and np.abs(f.centre).max() < 0.003 and not f.inlier[-300:].any()
    g = cmmpose.fit_sphere(ball, radius=38.125)
    assert g.radius == 38.125 and g.radius_uncertainty == 0.0 and np.abs(g.centre).max() < 0.003


def test_plane_fit():
    rng = np.random.default_rng(4)
    n = np.array([0.1, -0.2, 1.0]) / np.linalg.norm([0.1, -0.2, 1.0])
    a = np.cross(n, [1, 0, 0]); a /= np.linalg.norm(a)
    b = np.cross(n, a)
    p = np.array([5.0, 6.0, 7.0]) + rng.uniform(-50, 50, (500, 1)) * a + rng.uniform(-50, 50, (500, 1)) * b
    f = cmmpose.fit_plane(p + rng.normal(0, 0.001, (500, 1)) * n)
    assert np.abs(f.normal - n).max() < 1e-4 and f.normal[2] > 0 and abs(f.rms - 0.001) < 0.0002
    assert np.linalg.det(np.vstack([f.axes, f.normal])) == pytest.approx(1.0)


@pytest.mark.parametrize(
    "points, kw, exc, fragment",
    [
        (np.eye(3), {}, cmmpose.InputError, "at least 4 points"),
        (np.c_[np.ones((10, 2)), np.arange(10.0)], {}, cmmpose.GeometryError, "collinear"),
        (np.c_[np.random.default_rng(0).uniform(size=(50, 2)), np.zeros(50)], {}, cmmpose.GeometryError, "coplanar"),
        (np.ones((10, 2)), {}, cmmpose.InputError, "expected shape (N, 3)"),
        (np.eye(4, 3), {"radius": -1.0}, cmmpose.InputError, "radius"),
        (np.eye(4, 3), {"reject": 0.0}, cmmpose.InputError, "reject"),
    ],
)
def test_bad_sphere_inputs(points, kw, exc, fragment):
    with pytest.raises(exc, match=fragment.replace("(", r"\(").replace(")", r"\)")):
        cmmpose.fit_sphere(points, **kw)


def test_nan_names_the_row_and_tiny_caps_are_refused():
    rng = np.random.default_rng(5)
    p = cap(rng)
    p[123, 1] = np.nan
    with pytest.raises(cmmpose.InputError, match="row 123"):
        cmmpose.fit_sphere(p)
    th, ph = np.meshgrid(np.radians(np.linspace(0.05, 0.5, 10)), np.linspace(0, 2 * np.pi, 36))
    tiny = 38.125 * np.column_stack([np.sin(th).ravel() * np.cos(ph).ravel(), np.sin(th).ravel() * np.sin(ph).ravel(), np.cos(th).ravel()])
    with pytest.raises(cmmpose.GeometryError, match="coverage"):
        cmmpose.fit_sphere(tiny)


def test_batch_errors_name_the_label_or_are_returned():
    rng = np.random.default_rng(6)
    good = cap(rng)
    bad = np.c_[rng.uniform(size=(20, 2)), np.zeros(20)]
    pts, labels = np.vstack([good, bad]), np.r_[np.full(len(good), 1), np.full(20, 2)]
    with pytest.raises(cmmpose.GeometryError, match="sphere 2: points are coplanar"):
        cmmpose.fit_spheres(pts, labels)
    out = cmmpose.fit_spheres(pts, labels, on_error="return")
    assert isinstance(out[1], cmmpose.SphereFit) and isinstance(out[2], cmmpose.GeometryError)


def test_batch_arrays_equal_single_fits_with_labels_unsorted():
    # Every column entry is what fit_sphere gives that label's points (the
    # same serial path in Rust: equal to the last bit), and the per-point
    # arrays follow the input's order, whatever the order of the labels.
    rng = np.random.default_rng(7)
    sets = {12: cap(rng, n=400, centre=(0, 0, 0)), -4: cap(rng, n=90, centre=(100, 0, 0), half_angle=40),
            3: cap(rng, n=1000, centre=(0, 200, 0), radius=12.5)}
    sets[-4][5] += 0.5  # an outlier for the rejection
    labels = np.concatenate([np.full(len(p), k) for k, p in sets.items()])
    perm = rng.permutation(len(labels))
    pts, labels = np.vstack(list(sets.values()))[perm], labels[perm]
    fits = cmmpose.fit_spheres(pts, labels, reject=3.5)
    assert isinstance(fits, cmmpose.SphereFits)
    np.testing.assert_array_equal(fits.labels, [-4, 3, 12])
    assert fits.centre.shape == (3, 3) and fits.covariance.shape == (3, 4, 4)
    assert fits.residuals.shape == fits.inlier.shape == (len(pts),)
    assert list(fits) == [-4, 3, 12] and fits.ok.all() and all(e is None for e in fits.error)
    for k, label in enumerate(fits.labels.tolist()):
        mask = labels == label
        single = cmmpose.fit_sphere(pts[mask], reject=3.5)
        np.testing.assert_array_equal(fits.centre[k], single.centre)
        np.testing.assert_array_equal(fits.covariance[k], single.covariance)
        for name in ("radius", "rms", "form", "n_points", "polar_coverage", "iterations", "converged", "rejected"):
            assert getattr(fits, name)[k] == getattr(single, name), name
        np.testing.assert_array_equal(fits.residuals[mask], single.residuals)
        np.testing.assert_array_equal(fits.inlier[mask], single.inlier)
        np.testing.assert_array_equal(fits.centre_uncertainty[k], single.centre_uncertainty)
        assert fits.radius_uncertainty[k] == single.radius_uncertainty
        # The mapping builds the same SphereFit; a NumPy integer finds it too.
        assert fits[label].radius == single.radius and np.int32(label) in fits
        np.testing.assert_array_equal(fits[np.int64(label)].residuals, single.residuals)
        np.testing.assert_array_equal(np.flatnonzero(mask), fits.rows(label))
    # The outlier, row 400 + 5 before the shuffle.
    assert fits.rejected[0] >= 1 and not fits.inlier[np.flatnonzero(perm == 405)[0]]


def test_batch_arrays_in_label_order_give_slices():
    rng = np.random.default_rng(8)
    pts = np.vstack([cap(rng, n=50, centre=(0, 0, 0)), cap(rng, n=60, centre=(90, 0, 0))])
    labels = np.r_[np.full(50, "ball 1"), np.full(60, "ball 2")]
    fits = cmmpose.fit_spheres(pts, labels)
    assert fits.rows("ball 2") == slice(50, 110)
    np.testing.assert_array_equal(fits["ball 2"].residuals, cmmpose.fit_sphere(pts[50:]).residuals)
    assert "ball 3" not in fits and [] not in fits
    with pytest.raises(KeyError):
        fits["ball 3"]
    np.testing.assert_array_equal(fits.positions(["ball 2", "ball 1", "ball 2"]), [1, 0, 1])
    with pytest.raises(KeyError, match="ball 0"):
        fits.positions(["ball 1", "ball 0"])


def test_batch_arrays_return_errors_with_nan_fields():
    rng = np.random.default_rng(9)
    good = cap(rng, n=300)
    coplanar = np.c_[rng.uniform(size=(20, 2)), np.zeros(20)]
    pts = np.vstack([coplanar[:10], good, coplanar[10:], good[:3] + 100.0])
    labels = np.r_[np.full(10, 5), np.full(len(good), 1), np.full(10, 5), np.full(3, 9)]
    with pytest.raises(cmmpose.GeometryError, match="sphere 5: points are coplanar"):
        cmmpose.fit_spheres(pts, labels)
    fits = cmmpose.fit_spheres(pts, labels, on_error="return")
    np.testing.assert_array_equal(fits.labels, [1, 5, 9])
    np.testing.assert_array_equal(fits.ok, [True, False, False])
    assert fits.error[0] is None
    assert isinstance(fits.error[1], cmmpose.GeometryError) and "coplanar" in str(fits.error[1])
    assert isinstance(fits.error[2], cmmpose.InputError) and "at least 4 points" in str(fits.error[2])
    assert fits[5] is fits.error[1] and isinstance(fits[1], cmmpose.SphereFit)
    for k in (1, 2):
        assert np.isnan(fits.centre[k]).all() and np.isnan(fits.radius[k]) and np.isnan(fits.rms[k])
        assert np.isnan(fits.covariance[k]).all() and np.isnan(fits.polar_coverage[k])
        assert fits.n_points[k] == fits.iterations[k] == fits.rejected[k] == 0 and not fits.converged[k]
    failed = labels != 1
    assert np.isnan(fits.residuals[failed]).all() and not fits.inlier[failed].any()
    np.testing.assert_array_equal(fits.residuals[~failed], cmmpose.fit_sphere(good).residuals)


def test_batch_arrays_of_no_points():
    fits = cmmpose.fit_spheres(np.empty((0, 3)), np.empty(0, dtype=int))
    assert len(fits) == 0 and list(fits) == [] and fits.labels.shape == (0,)
    assert fits.centre.shape == (0, 3) and fits.covariance.shape == (0, 4, 4)
    assert fits.radius.shape == fits.error.shape == fits.residuals.shape == (0,)


def test_bad_plane_inputs():
    with pytest.raises(cmmpose.InputError, match="at least 3"):
        cmmpose.fit_plane(np.eye(2, 3))
    with pytest.raises(cmmpose.GeometryError, match="collinear"):
        cmmpose.fit_plane(np.c_[np.arange(5.0), np.zeros(5), np.zeros(5)])
