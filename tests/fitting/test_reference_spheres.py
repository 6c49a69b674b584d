"""Geometric sphere fits against reference data with exactly known answers
(ISO 10360-6 style, tests/support/reference_spheres.py), thesis Appendix A through the
Python API, and the reported centre uncertainty against Monte Carlo scatter."""

import itertools

import numpy as np
import pytest

import cmmpose

try:
    from .reference_spheres import (cap_directions, data_extent, null_space_deviations, random_unit,
                                    reference_sphere_data, sphere_jacobian)
except ImportError:
    from reference_spheres import (cap_directions, data_extent, null_space_deviations, random_unit,
                                   reference_sphere_data, sphere_jacobian)

# The reference caps go down to 30 degrees and Appendix A's to 5: free-radius
# fits there are ill-conditioned by design (these tests check the arithmetic on
# exact data) and rightly warn IllConditionedFit; tests/fitting/test_robust_fits.py
# tests the warning.
pytestmark = pytest.mark.filterwarnings("ignore::cmmpose.IllConditionedFit")

#: Largest centre-coordinate and radius error accepted (mm): 0.1 um.
TOLERANCE = 1e-4

HALF_ANGLES = (90.0, 60.0, 45.0, 30.0)
FORM_FRACTIONS = (1e-3, 1e-4)
CENTRES = ((0.0, 0.0, 0.0), (1200.0, -800.0, 300.0), (-7000.0, 5000.0, 4000.0))  # up to 9.9 m from the origin
SIZES = ((5.0, 300), (38.125, 2000), (100.0, 20_000), (5.0, 20_000), (100.0, 300))  # (radius mm, points)

CASES = list(itertools.product(HALF_ANGLES, FORM_FRACTIONS, CENTRES, SIZES))


def _case_id(case):
    half, frac, centre, (radius, n) = case
    return f"cap{half:g}-form{frac:g}-c{int(np.linalg.norm(centre))}-r{radius:g}-n{n}"


def _data(index, case):
    half, frac, centre, (radius, n) = case
    return reference_sphere_data(np.random.default_rng(1000 + index), n, half, frac, centre, radius)


# --- the generator -----------------------------------------------------------------------------


@pytest.mark.parametrize("half, frac", [(90.0, 1e-3), (30.0, 1e-4)])
def test_null_space_deviations_are_orthogonal_to_the_jacobian(half, frac):
    rng = np.random.default_rng(5)
    for n in (300, 20_000):
        normals = cap_directions(rng, n, half, random_unit(rng))
        amplitude = frac * data_extent(38.125, half)
        d = null_space_deviations(rng, normals, amplitude)
        g = sphere_jacobian(normals).T @ d
        # J^T d is a sum of n terms of size <= amplitude: zero to rounding.
        assert np.abs(g).max() <= 1e-13 * n * amplitude, g
        assert np.abs(d).max() == pytest.approx(amplitude, rel=1e-15)
        # Not a trivial solution: the deviations fill the amplitude range.
        assert np.std(d) > 0.2 * amplitude


@pytest.mark.parametrize("index", range(0, len(CASES), 7))
def test_generated_points_satisfy_the_normal_equations(index):
    """From the stored points (coordinates rounded): the residuals at the
    reference sphere have max |r| = the amplitude, and the Gauss-Newton step
    there, (J^T J)^-1 J^T r, is zero to rounding."""
    case = CASES[index]
    half, frac, _, (radius, n) = case
    points, centre, r0 = _data(index, case)
    assert points.shape == (n, 3) and r0 == radius
    v = points - centre
    dist = np.linalg.norm(v, axis=1)
    r = dist - r0
    jac = sphere_jacobian(v / dist[:, None])
    step = np.linalg.solve(jac.T @ jac, jac.T @ r)
    assert np.abs(step).max() < 1e-11, step
    assert abs(np.abs(r).max() - frac * data_extent(radius, half)) < 1e-11
    # The points cover the cap about the generator's axis (its first draw from the rng).
    axis = random_unit(np.random.default_rng(1000 + index))
    polar = np.degrees(np.arccos(np.clip((v / dist[:, None]) @ axis, -1.0, 1.0)))
    assert polar.max() <= half + 1e-9 and polar.max() > half - (3.0 if n < 1000 else 0.5)


def test_data_extent():
    assert data_extent(10.0, 90.0) == pytest.approx(20.0)
    assert data_extent(10.0, 30.0) == pytest.approx(10.0)
    assert data_extent(10.0, 120.0) == pytest.approx(20.0)


# --- cmmpose against the reference results ----------------------------------------------------


@pytest.mark.parametrize("index", range(len(CASES)), ids=[_case_id(c) for c in CASES])
def test_fit_sphere_recovers_the_reference_sphere(index):
    points, centre, radius = _data(index, CASES[index])
    f = cmmpose.fit_sphere(points)
    assert f.converged and f.n_points == len(points) and f.rejected == 0
    centre_error = np.abs(f.centre - centre).max()
    radius_error = abs(f.radius - radius)
    assert centre_error < TOLERANCE, f"centre off by {centre_error:.3e} mm"
    assert radius_error < TOLERANCE, f"radius off by {radius_error:.3e} mm"
    # Residuals are the constructed deviations; form and rms follow from them.
    r = np.linalg.norm(points - centre, axis=1) - radius
    np.testing.assert_allclose(f.residuals, r, rtol=0, atol=1e-6)
    assert f.form == pytest.approx(r.max() - r.min(), abs=2e-6)


def test_fit_spheres_batch_recovers_the_reference_spheres():
    chosen = list(range(0, len(CASES), 11))
    data = {k: _data(k, CASES[k]) for k in chosen}
    points = np.vstack([d[0] for d in data.values()])
    labels = np.concatenate([np.full(len(d[0]), k) for k, d in data.items()])
    fits = cmmpose.fit_spheres(points, labels)
    assert list(fits) == chosen
    for k, (_, centre, radius) in data.items():
        assert np.abs(fits[k].centre - centre).max() < TOLERANCE
        assert abs(fits[k].radius - radius) < TOLERANCE


# --- thesis Appendix A: spheroids seen on caps about the pole ---------------------------------


def spheroid_cap(a: float, c: float, cap_deg: float, step: float = 0.1) -> np.ndarray:
    """Points on the spheroid (equatorial semi-axis ``a``, polar ``c``, centre
    at the origin, pole on +Z) from the pole down to polar angle ``cap_deg``:
    rings every ``step`` mm of arc (thesis: 0.1 mm increments), each ring with
    points every ``step`` mm around it."""
    rings = int(np.floor(np.radians(cap_deg) * a / step))
    out = [np.array([[0.0, 0.0, c]])]
    for k in range(1, rings + 1):
        t = k * step / a
        st, ct = np.sin(t), np.cos(t)
        r = 1.0 / np.sqrt((st / a) ** 2 + (ct / c) ** 2)
        m = int(round(2 * np.pi * r * st / step))
        phi = 2 * np.pi * np.arange(m) / m
        out.append(np.column_stack([r * st * np.cos(phi), r * st * np.sin(phi), np.full(m, r * ct)]))
    return np.vstack(out)


# (polar semi-axis, polar coverage deg, centre z, radius) as the thesis prints them (Appendix A,
# NIST ATS fits, 1 um resolution). The prolate 60 degree case is not printed ("similar effects are
# seen"): its values are the mirror image of the oblate one, as docs/conventions.md (Spheroid
# fits of Appendix A) summarises (+-0.004 mm); the prolate 5 degree radius is "smaller by 0.003 mm" than 38.125.
APPENDIX_A = [
    (38.1225, 5.0, -0.005, 38.128),
    (38.1225, 60.0, -0.004, 38.126),
    (38.1225, 85.0, -0.003, 38.126),
    (38.1275, 5.0, 0.005, 38.122),
    (38.1275, 60.0, 0.004, 38.124),
    (38.1275, 85.0, 0.003, 38.124),
]


@pytest.mark.parametrize("c, cap_deg, z_thesis, r_thesis", APPENDIX_A)
def test_thesis_appendix_a_spheroids(c, cap_deg, z_thesis, r_thesis):
    a = 38.125
    points = spheroid_cap(a, c, cap_deg)
    f = cmmpose.fit_sphere(points)
    assert f.converged
    assert np.abs(f.centre[:2]).max() < 1e-9
    assert f.polar_coverage == pytest.approx(cap_deg, abs=0.2)
    # To the micrometre the thesis prints: within its 0.5 um rounding, plus 0.1 um for the point
    # layout (at 5 degrees the fitted radius, 38.12749 / 38.12251 mm, sits 0.01 um from the
    # rounding boundary the thesis's fit crossed).
    assert abs(f.centre[2] - z_thesis) <= 0.0006, f.centre[2]
    assert abs(f.radius - r_thesis) <= 0.0006, f.radius
    if cap_deg == 5.0:
        # A small cap about the pole sees the osculating sphere: radius a^2/c, centre z c - a^2/c.
        assert f.radius == pytest.approx(a * a / c, abs=1e-4)
        assert f.centre[2] == pytest.approx(c - a * a / c, abs=1e-4)


def test_appendix_a_shifts_are_mirror_images():
    """Oblate and prolate by the same 2.5 um give equal and opposite centre shifts and radius
    changes (to first order in the flattening: within 0.05 um)."""
    for cap_deg in (5.0, 60.0, 85.0):
        ob = cmmpose.fit_sphere(spheroid_cap(38.125, 38.1225, cap_deg, step=0.2))
        pr = cmmpose.fit_sphere(spheroid_cap(38.125, 38.1275, cap_deg, step=0.2))
        assert ob.centre[2] + pr.centre[2] == pytest.approx(0.0, abs=5e-5)
        assert (ob.radius - 38.125) + (pr.radius - 38.125) == pytest.approx(0.0, abs=5e-5)
        assert ob.centre[2] < 0 < ob.radius - 38.125


# --- reported uncertainty against Monte Carlo scatter ------------------------------------------


def test_centre_uncertainty_matches_monte_carlo_scatter():
    """1000 fits of 2000 points on a 60 degree cap (random axis) with 8 um Gaussian noise along
    the normals: the standard deviation of the fitted centre coordinates (and radius) agrees with
    the mean reported SphereFit.centre_uncertainty (radius_uncertainty) within 10 %. The sampling
    error of a standard deviation from 1000 samples is 1/sqrt(2 x 999) = 2.2 %."""
    rng = np.random.default_rng(20240607)
    repeats, n, half, sigma = 1000, 2000, 60.0, 0.008
    centre, radius = np.array([120.0, -45.0, 310.0]), 38.125
    axis = random_unit(rng)
    fitted = np.empty((repeats, 4))
    reported = np.empty((repeats, 4))
    for k in range(repeats):
        u = cap_directions(rng, n, half, axis)
        f = cmmpose.fit_sphere(centre + (radius + rng.normal(0.0, sigma, n))[:, None] * u)
        fitted[k] = [*f.centre, f.radius]
        reported[k] = [*f.centre_uncertainty, f.radius_uncertainty]
    scatter = fitted.std(axis=0, ddof=1)
    predicted = reported.mean(axis=0)
    np.testing.assert_allclose(scatter, predicted, rtol=0.10)
    # The reported values vary little from fit to fit, and the fit is unbiased.
    assert (reported.std(axis=0) < 0.05 * predicted).all()
    assert (np.abs(fitted.mean(axis=0) - [*centre, radius]) < 4 * scatter / np.sqrt(repeats)).all()


def test_covariance_is_s2_inverse_jtj():
    """The reported covariance equals s^2 (J^T J)^-1 at the fitted sphere, s^2 = SSR / (N - 4)."""
    rng = np.random.default_rng(3)
    u = cap_directions(rng, 2000, 60.0, random_unit(rng))
    points = np.array([5.0, 6.0, 7.0]) + (38.125 + rng.normal(0, 0.008, 2000))[:, None] * u
    f = cmmpose.fit_sphere(points)
    v = points - f.centre
    dist = np.linalg.norm(v, axis=1)
    jac = sphere_jacobian(v / dist[:, None])
    r = dist - f.radius
    expected = (r @ r) / (len(r) - 4) * np.linalg.inv(jac.T @ jac)
    np.testing.assert_allclose(f.covariance, expected, rtol=1e-8, atol=0)
