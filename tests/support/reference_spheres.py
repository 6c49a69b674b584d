"""Reference data for geometric least-squares sphere fits, with exactly known
answers (no cmmpose import).

ISO 10360-6:2001 (Geometrical Product Specifications - Acceptance and
reverification tests for coordinate measuring machines - Part 6: Estimation of
errors in computing Gaussian associated features) tests the software that
computes least-squares ("Gaussian") associated features, the sphere among
them, by comparing its results on reference data sets with reference results;
PTB and the other institutes of the TraCIM service (Traceability for
Computationally-Intensive Metrology) offer such tests on line, comparing a
user's results with the reference results within the maximum permissible
errors the user states.

The reference results are known exactly because the data are built from them,
with the null-space method of Cox and Forbes (M. G. Cox and A. B. Forbes,
"Strategies for testing form assessment software", NPL Report DITC 211/92,
1992; A. B. Forbes and H. D. Minh, "Generation of numerical artefacts for
geometric form and tolerance assessment", Int. J. Metrol. Qual. Eng. 3 (2012)
145-150): the deviations from the reference surface are chosen orthogonal to
the columns of the Jacobian of the residuals at the reference parameters, so
those parameters satisfy the least-squares normal equations.
"""

from __future__ import annotations

import numpy as np


def random_unit(rng: np.random.Generator) -> np.ndarray:
    """A direction uniform on the unit sphere."""
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def cap_directions(rng: np.random.Generator, n: int, half_angle_deg: float, axis) -> np.ndarray:
    """``n`` unit vectors uniform in area on the cap of half-angle
    ``half_angle_deg`` about ``axis``."""
    axis = np.asarray(axis, dtype=float)
    axis = axis / np.linalg.norm(axis)
    # Orthonormal (e1, e2, axis).
    e1 = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    cos_t = rng.uniform(np.cos(np.radians(half_angle_deg)), 1.0, n)
    sin_t = np.sqrt(np.maximum(0.0, 1.0 - cos_t**2))
    phi = rng.uniform(0.0, 2.0 * np.pi, n)
    return (sin_t * np.cos(phi))[:, None] * e1 + (sin_t * np.sin(phi))[:, None] * e2 + cos_t[:, None] * axis


def data_extent(radius: float, half_angle_deg: float) -> float:
    """Extent (largest chord) of a cap of the sphere: 2 R sin(theta) for a
    half-angle theta up to 90 degrees, the diameter 2 R beyond."""
    return 2.0 * radius * (np.sin(np.radians(half_angle_deg)) if half_angle_deg < 90.0 else 1.0)


def sphere_jacobian(normals: np.ndarray) -> np.ndarray:
    """Jacobian (N, 4) of the residuals r_i = |p_i - c| - R with respect to
    (c_x, c_y, c_z, R) at the reference sphere: rows (-n_i, -1)."""
    return np.column_stack([-normals, -np.ones(len(normals))])


def null_space_deviations(rng: np.random.Generator, normals: np.ndarray, amplitude: float) -> np.ndarray:
    """Deviations d (N,) along the normals with J^T d = 0 (to rounding) and
    max |d| = ``amplitude``.

    Random d, uniform in [-1, 1], less its projection on the range of J:
    d <- d - J (J^T J)^-1 J^T d, computed with an orthonormal basis Q of that
    range (thin QR, J = Q R) as d - Q (Q^T d) and applied twice (the second
    pass removes what rounding left of the first); then scaled to the
    amplitude, which keeps J^T d = 0.
    """
    jac = sphere_jacobian(normals)
    q, _ = np.linalg.qr(jac)
    d = rng.uniform(-1.0, 1.0, len(normals))
    for _ in range(2):
        d = d - q @ (q.T @ d)
    return d * (amplitude / np.abs(d).max())


def reference_sphere_data(rng: np.random.Generator, n_points: int, half_angle_deg: float, form_fraction: float,
                          centre, radius: float):
    """Points on a partial cap of the sphere (``centre``, ``radius``) with form
    error, whose geometric least-squares sphere is exactly (``centre``,
    ``radius``).

    Construction (the null-space method, module docstring):

    1. ``n_points`` unit normals n_i uniform in area on a cap of half-angle
       ``half_angle_deg`` about a random axis (``random_unit(rng)``, the
       first draw from ``rng``).
    2. Deviations d_i along the normals: random, then made orthogonal to the
       columns of the Jacobian J of the residuals r_i = |p_i - c| - R at the
       reference solution (columns -n_i, three of them, and -1):
       d <- d - J (J^T J)^-1 J^T d, so J^T d = 0.
    3. Scaled so that max |d_i| = ``form_fraction`` x the extent of the data
       (:func:`data_extent`, the cap's largest chord); J^T d stays 0.
    4. p_i = c + (R + d_i) n_i.

    At the reference parameters the residuals are exactly d_i and the unit
    directions exactly n_i, so J^T r = J^T d = 0: the reference sphere
    satisfies the normal equations of the geometric fit. Its Hessian
    J^T J + sum d_i (I - n_i n_i^T) / (R + d_i) (centre block) differs from
    J^T J by a term of relative size max|d| / R, so for form errors small
    against the radius it is positive definite and the stationary point is
    the least-squares minimum. Only the rounding of the coordinates
    (~1e-16 of |p_i|, ~2e-12 mm at 10 m) separates the stored data from the
    construction.

    Parameters
    ----------
    rng : numpy.random.Generator
    n_points : int
    half_angle_deg : float
        Half-angle of the cap (0 < theta <= 180 degrees).
    form_fraction : float
        Form error amplitude (max |d|) as a fraction of the data extent, e.g. 1e-3.
    centre : array_like (3,)
        Reference centre, mm.
    radius : float
        Reference radius, mm.

    Returns
    -------
    points : ndarray (n_points, 3)
    centre : ndarray (3,)
    radius : float
    """
    centre = np.asarray(centre, dtype=float)
    radius = float(radius)
    normals = cap_directions(rng, n_points, half_angle_deg, random_unit(rng))
    amplitude = form_fraction * data_extent(radius, half_angle_deg)
    d = null_space_deviations(rng, normals, amplitude)
    points = centre + (radius + d)[:, None] * normals
    return points, centre, radius
