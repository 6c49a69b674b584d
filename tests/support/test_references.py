"""Self-checks of the independent references numpy_reference.py and rigid_body.py.

No cmmpose import: these modules are what the Rust kernel is checked against.
Run with ``python -m pytest tests/support/test_references.py -q`` (add -s to see the deviations).
"""

import numpy as np
import pytest

import numpy_reference as nr
import rigid_body as rb

GRIDS = {"X": np.arange(0.0, 901.0, 25.0), "Y": np.arange(0.0, 551.0, 25.0),
         "Z": np.arange(-500.0, 1.0, 25.0)}
OFFSET = (1.001, 264.505, 129.575)
POSES = [(0, 0, 0), (90, 90, 0), (90, 90, 90), (180, 90, 0), (30, 40, 20), (-120, 135, -60)]
A = nr.ARCSEC_TO_RAD


def random_map(rng, ang=20.0, dl=50.0, sq=200.0, temperature=20.0):
    m = {"temperature": temperature, "squareness": tuple(rng.uniform(-sq, sq, 3))}
    for axis, g in GRIDS.items():
        t = np.empty((len(g), 7))
        t[:, 0] = g
        t[:, 1:4] = rng.uniform(-dl, dl, (len(g), 3))
        t[:, 4:] = rng.uniform(-ang, ang, (len(g), 3))
        m[axis] = t
    return m


def scaled(m, k):
    out = {"temperature": m["temperature"], "squareness": tuple(k * np.asarray(m["squareness"]))}
    for axis in "XYZ":
        out[axis] = m[axis].copy()
        out[axis][:, 1:] *= k
    return out


def random_points(rng, n=4000):
    scales = np.column_stack([rng.uniform(0, 900, n), rng.uniform(0, 550, n), rng.uniform(-500, 0, n)])
    scales[:4] = [[0, 0, -500], [900, 550, 0], [900, 550, -500], [0, 0, 0]]  # grid corners
    return rng.uniform(-40, 40, (n, 2)), scales


def deviation(m, uv, scales, pose):
    return np.linalg.norm(rb.true_points(uv, scales, m, pose, OFFSET)
                          - nr.compensate(uv, scales, m, pose, OFFSET), axis=1)


def rotation_printed_eq30(m, scales):
    """R(S) with X_p as printed in eq. 30: (1, -tan eZ, -(tan eX tan eZ + tan eY)) / norm."""
    eps = sum(nr.interpolate_carriage(m[a], scales[:, k])[:, 3:] for k, a in enumerate("XYZ"))
    tx, ty, tz = np.tan(eps).T
    zp = np.stack([ty, -tx, np.ones_like(tx)], axis=1)
    xp = np.stack([np.ones_like(tx), -tz, -(tx * tz + ty)], axis=1)
    zp /= np.linalg.norm(zp, axis=1, keepdims=True)
    xp /= np.linalg.norm(xp, axis=1, keepdims=True)
    return np.stack([xp, np.cross(zp, xp), zp], axis=2)


# --- Euler 3-1-3 ---------------------------------------------------------------------

def test_euler313_orthonormal_right_handed():
    rng = np.random.default_rng(0)
    for alpha, beta, gamma in rng.uniform(-360, 360, (200, 3)):
        e = nr.euler313(alpha, beta, gamma)
        np.testing.assert_allclose(e.T @ e, np.eye(3), atol=1e-14)
        np.testing.assert_allclose(np.cross(e[:, 0], e[:, 1]), e[:, 2], atol=1e-14)


def test_euler313_named_poses():
    np.testing.assert_allclose(nr.euler313(90, 90, 0)[:, 2], [1, 0, 0], atol=1e-15)
    np.testing.assert_allclose(nr.euler313(90, 90, 37)[:, 2], [1, 0, 0], atol=1e-15)
    np.testing.assert_allclose(nr.euler313(180, 90, 0)[:, 2], [0, 1, 0], atol=1e-15)
    np.testing.assert_array_equal(nr.euler313(0, 0, 0), np.eye(3))


# --- map evaluation ------------------------------------------------------------------

def test_interpolation_units_and_linearity():
    table = np.array([[0.0, 1, 2, 3, 4, 5, 6], [10.0, 3, 4, 5, 6, 7, 8]])
    got = nr.interpolate_carriage(table, [0.0, 2.5, 10.0])
    want = np.array([[1, 2, 3, 4, 5, 6], [1.5, 2.5, 3.5, 4.5, 5.5, 6.5], [3, 4, 5, 6, 7, 8]])
    np.testing.assert_allclose(got, want * ([1e-3] * 3 + [np.pi / 648000] * 3), rtol=1e-15)


def test_zero_map_is_uncompensated_exactly():
    rng = np.random.default_rng(1)
    m = random_map(rng, ang=0, dl=0, sq=0)
    uv, s = random_points(rng)
    for pose in POSES:
        np.testing.assert_array_equal(nr.compensate(uv, s, m, pose, OFFSET),
                                      nr.uncompensated(uv, s, pose, OFFSET))


def test_pure_squareness_xy():
    rng = np.random.default_rng(2)
    m = random_map(rng, ang=0, dl=0, sq=0)
    m["squareness"] = (100.0, 0.0, 0.0)
    _, s = random_points(rng)
    e = nr.position_error(m, s)
    np.testing.assert_allclose(e[:, 0], -s[:, 1] * 100 * np.pi / 648000, rtol=1e-14, atol=0)
    np.testing.assert_array_equal(e[:, 1:], 0.0)


def test_temperature_blending():
    rng = np.random.default_rng(3)
    maps = [random_map(rng, temperature=t) for t in (30.0, 20.0, 25.0)]   # unsorted on purpose
    by_t = {m["temperature"]: m for m in maps}
    _, s = random_points(rng)
    pe = {t: nr.position_error(m, s) for t, m in by_t.items()}
    np.testing.assert_allclose(nr.position_error(maps, s, 22.5), (pe[20.0] + pe[25.0]) / 2,
                               rtol=1e-12, atol=1e-15)
    for t in (20.0, 25.0, 30.0):  # at a map temperature: that map, exactly
        np.testing.assert_array_equal(nr.position_error(maps, s, t), pe[t])
    # per-point temperatures: each point uses its own bracketing pair
    t = rng.uniform(20, 30, len(s))
    w_lo = np.where(t < 25, (25 - t) / 5, 0.0)
    w_mid = np.where(t < 25, (t - 20) / 5, (30 - t) / 5)
    w_hi = np.where(t < 25, 0.0, (t - 25) / 5)
    want = w_lo[:, None] * pe[20.0] + w_mid[:, None] * pe[25.0] + w_hi[:, None] * pe[30.0]
    np.testing.assert_allclose(nr.position_error(maps, s, t), want, rtol=1e-12, atol=1e-14)
    # squareness is blended too
    R = nr.rotation_error(maps, s, t)
    assert R.shape == (len(s), 3, 3)


def test_out_of_range_raises():
    rng = np.random.default_rng(4)
    m = random_map(rng)
    for bad in ([900.001, 10, -10], [-0.001, 10, -10], [10, 550.5, -10], [10, 10, 0.001],
                [10, 10, -500.01], [np.nan, 10, -10]):
        with pytest.raises(ValueError):
            nr.position_error(m, np.array([[10.0, 10, -10], bad]))
    with pytest.raises(ValueError):
        nr.interpolate_carriage(m["X"], [450.0, 1e4])
    maps = [random_map(rng, temperature=t) for t in (20.0, 25.0, 30.0)]
    s = np.array([[10.0, 10, -10], [20, 20, -20]])
    for bad_t in (19.99, 30.01, np.array([25.0, 31.0])):
        with pytest.raises(ValueError):
            nr.compensate([[0, 0], [1, 1]], s, maps, (0, 0, 0), OFFSET, bad_t)
    with pytest.raises(ValueError):
        nr.position_error(maps, s)  # several maps, no temperature


def test_rotation_error_is_a_rotation():
    rng = np.random.default_rng(5)
    _, s = random_points(rng)
    for ang in (20.0, 5000.0):
        R = nr.rotation_error(random_map(rng, ang=ang), s)
        np.testing.assert_allclose(np.einsum("nki,nkj->nij", R, R), np.broadcast_to(np.eye(3), R.shape),
                                   atol=1e-15)
        np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-15)


def test_rotation_error_signs_right_handed():
    """A pure eps_z of one carriage turns X_p towards +Y (rotation about +Z, eq. 11 -E*ez(X))."""
    rng = np.random.default_rng(6)
    m = random_map(rng, ang=0, dl=0, sq=0)
    m["Z"][:, 6] = 50.0
    _, s = random_points(rng, 10)
    R = nr.rotation_error(m, s)
    np.testing.assert_allclose(R[:, :, 0], np.broadcast_to([np.cos(50 * A), np.sin(50 * A), 0], (10, 3)),
                               atol=1e-16)


# --- truth machine vs compensation ---------------------------------------------------

def test_truth_machine_linearises_to_eqs_11_13():
    """With the errors scaled down 1000x the ram point P of the chain equals S + e(S) of
    eqs. 11-13 to ~1e-9 mm (second-order terms shrink 1e6x, first-order ones 1e3x)."""
    rng = np.random.default_rng(7)
    _, s = random_points(rng)
    m = scaled(random_map(rng), 1e-3)
    p = rb.true_points(np.zeros((len(s), 2)), s, m, (0, 0, 0), (0, 0, 0))  # zero lever: P itself
    e = nr.position_error(m, s)
    assert np.abs(e).max() > 1e-4
    np.testing.assert_allclose(p - s, e, rtol=0, atol=1e-9)


def test_truth_machine_agrees_to_second_order():
    rng = np.random.default_rng(8)
    worst, worst_bound_ratio = 0.0, np.inf
    for _ in range(4):
        m = random_map(rng)
        uv, s = random_points(rng)
        for pose in POSES:
            dev = deviation(m, uv, s, pose)
            bound = rb.second_order_bound(uv, s, m, pose, OFFSET)
            assert np.all(dev <= bound), (pose, dev.max(), bound[dev.argmax()])
            worst = max(worst, dev.max())
            worst_bound_ratio = min(worst_bound_ratio, (bound / dev).min())
    print(f"\ntruth vs compensate, |deviation| max {worst:.3e} mm, bound/deviation >= {worst_bound_ratio:.1f}")
    assert worst < 1e-3


def test_remainder_is_second_order():
    """Scaling every error by k scales the deviation by k^2 (first-order terms are exact)."""
    rng = np.random.default_rng(9)
    m = random_map(rng)
    uv, s = random_points(rng)
    for pose in POSES:
        d1 = deviation(m, uv, s, pose).max()
        for k in (0.5, 0.1):
            ratio = deviation(scaled(m, k), uv, s, pose).max() / d1
            assert abs(ratio / k**2 - 1) < 0.01, (pose, k, ratio)


def test_no_squareness_small_remainder():
    rng = np.random.default_rng(10)
    worst = 0.0
    for _ in range(4):
        m = random_map(rng, sq=0.0)
        uv, s = random_points(rng)
        worst = max(worst, max(deviation(m, uv, s, pose).max() for pose in POSES))
    print(f"\ntruth vs compensate without squareness, |deviation| max {worst:.3e} mm")
    assert worst < 5e-5


def test_printed_eq30_sign_is_detected():
    rng = np.random.default_rng(11)
    m = random_map(rng)
    m["X"][:, 6] = 0.0
    m["Y"][:, 6] = 0.0
    m["Z"][:, 6] = 50.0  # total eps_Z = 50 arc-seconds everywhere
    uv, s = random_points(rng)
    least = np.inf
    for pose in POSES:
        truth = rb.true_points(uv, s, m, pose, OFFSET)
        lever = nr.uncompensated(uv, s, pose, OFFSET) - s
        printed = s + nr.position_error(m, s) + np.einsum("nij,nj->ni", rotation_printed_eq30(m, s), lever)
        good = np.linalg.norm(truth - nr.compensate(uv, s, m, pose, OFFSET), axis=1)
        bad = np.linalg.norm(truth - printed, axis=1)
        assert np.all(good <= rb.second_order_bound(uv, s, m, pose, OFFSET))
        assert bad.min() > 1e-3, (pose, bad.min())
        least = min(least, bad.min())
    print(f"\nprinted eq. 30 with eps_Z = 50 a-s: |deviation| >= {least:.3e} mm")
