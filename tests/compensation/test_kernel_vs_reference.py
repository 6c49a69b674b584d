"""The Rust kernel against two independent references:

* ``numpy_reference``: the same equations in vectorised NumPy, written without
  looking at the Rust code. Agreement to 1e-9 mm: both evaluate identical
  formulas in float64, so they differ only by rounding (~1e-13 mm at 1000 mm).
* ``rigid_body``: an exact rigid-body chain with full rotation matrices. The
  first-order model must reproduce it to second order in the angles; this is
  what decides the sign of eq. 30 (docs/conventions.md, Sign of eps_Z in X_p).
"""

import numpy as np
import pytest

import cmmpose

import numpy_reference as nr
import rigid_body as rb

OFFSET = cmmpose.MountOffset.thesis()
POSES = [(90.0, 90.0, 0.0), (90.0, 90.0, 90.0), (180.0, 90.0, 0.0), (37.0, 121.0, -64.0)]
TOL_MM = 1e-9


def as_dict(m: cmmpose.ErrorMap) -> dict:
    return {"temperature": m.temperature, "squareness": m.squareness, **{c: m.table(c) for c in "XYZ"}}


@pytest.fixture(scope="module")
def thesis():
    return cmmpose.ErrorMapSet.thesis()


def volume_points(rng, n):
    """Random points over the whole thesis volume, grid nodes and corners included."""
    scales = np.column_stack([rng.uniform(0, 900, n), rng.uniform(0, 550, n), rng.uniform(-500, 0, n)])
    scales[:8] = [[x, y, z] for x in (0, 900) for y in (0, 550) for z in (-500, 0)]
    scales[8:40] = np.round(scales[8:40] / 25.0) * 25.0  # exactly on map nodes
    uv = np.column_stack([rng.uniform(-30, 30, n), rng.uniform(110, 170, n)])
    return uv, scales


def test_million_points_per_point_temperature(thesis):
    rng = np.random.default_rng(1)
    n = 1_000_000
    uv, scales = volume_points(rng, n)
    temps = rng.uniform(20.0, 30.0, n)
    temps[:3000] = rng.choice([20.0, 25.0, 30.0], 3000)  # exactly at map temperatures
    maps = [as_dict(m) for m in thesis.maps]
    for pose in POSES[::2]:
        got = cmmpose.compensate(uv, scales, thesis, pose, OFFSET, temps)
        want = nr.compensate(uv, scales, maps, pose, OFFSET, temps)
        assert np.abs(got - want).max() < TOL_MM, pose


@pytest.mark.parametrize("temperature", [20.0, 21.7, 22.5, 25.0, 27.3, 30.0])
@pytest.mark.parametrize("pose", POSES)
def test_scalar_temperature(thesis, temperature, pose):
    rng = np.random.default_rng(2)
    uv, scales = volume_points(rng, 100_000)
    got = cmmpose.compensate(uv, scales, thesis, pose, OFFSET, temperature)
    want = nr.compensate(uv, scales, [as_dict(m) for m in thesis.maps], pose, OFFSET, temperature)
    assert np.abs(got - want).max() < TOL_MM


def test_single_maps_and_model_parts(thesis):
    rng = np.random.default_rng(3)
    uv, scales = volume_points(rng, 200_000)
    for m in [*thesis.maps, cmmpose.ErrorMap.appendix_b()]:
        d = as_dict(m)
        assert np.abs(cmmpose.compensate(uv, scales, m, POSES[3], OFFSET) - nr.compensate(uv, scales, d, POSES[3], OFFSET)).max() < TOL_MM
        assert np.abs(m.position_error(scales) - nr.position_error(d, scales)).max() < TOL_MM
        assert np.abs(m.rotation_error(scales) - nr.rotation_error(d, scales)).max() < 1e-14
    assert np.abs(cmmpose.uncompensated(uv, scales, POSES[1], OFFSET) - nr.uncompensated(uv, scales, POSES[1], OFFSET)).max() < TOL_MM


def test_blended_map_equals_reference_blend(thesis):
    rng = np.random.default_rng(4)
    _, scales = volume_points(rng, 50_000)
    blended = thesis.at(26.2)
    want = nr.position_error([as_dict(m) for m in thesis.maps], scales, 26.2)
    assert np.abs(blended.position_error(scales) - want).max() < 1e-12


# --- eq. 30: which sign of eps_Z in X_p --------------------------------------------------

def exaggerated_map(eps_z_arcsec=50.0):
    """Thesis 20 C map with a large constant yaw on X so the eq. 30 sign shows clearly."""
    m = cmmpose.ErrorMapSet.thesis().maps[0]
    tables = [m.table(c) for c in "XYZ"]
    tables[0] = tables[0].copy()
    tables[0][:, 6] += eps_z_arcsec
    return cmmpose.ErrorMap(*tables, m.squareness, m.temperature)


def printed_eq30(d, uv, scales, pose):
    """Compensation with X_p as printed: (1, -tan eZ, -(tan eX tan eZ + tan eY))/norm."""
    eps = sum(nr.interpolate_carriage(d[a], scales[:, k])[:, 3:] for k, a in enumerate("XYZ"))
    tx, ty, tz = np.tan(eps).T
    zp = np.stack([ty, -tx, np.ones_like(tx)], 1)
    xp = np.stack([np.ones_like(tx), -tz, -(tx * tz + ty)], 1)
    zp /= np.linalg.norm(zp, axis=1, keepdims=True)
    xp /= np.linalg.norm(xp, axis=1, keepdims=True)
    r = np.stack([xp, np.cross(zp, xp), zp], 2)
    lever = (np.column_stack([uv, np.zeros(len(uv))]) - np.asarray(OFFSET)) @ nr.euler313(*pose).T
    return scales + nr.position_error(d, scales) + np.einsum("nij,nj->ni", r, lever)


@pytest.mark.parametrize("pose", POSES)
def test_right_handed_eq30_inverts_the_rigid_body_machine(pose):
    m = exaggerated_map()
    d = as_dict(m)
    rng = np.random.default_rng(5)
    uv, scales = volume_points(rng, 20_000)
    truth = rb.true_points(uv, scales, d, pose, OFFSET)
    ours = np.linalg.norm(cmmpose.compensate(uv, scales, m, pose, OFFSET) - truth, axis=1)
    bound = rb.second_order_bound(uv, scales, d, pose, OFFSET)
    # Second order: (angles + squareness)^2 x lever ~ (1e-3)^2 x 1000 mm ~ 1 um here.
    assert np.all(ours <= bound) and ours.max() < 2e-3
    printed = np.linalg.norm(printed_eq30(d, uv, scales, pose) - truth, axis=1)
    # The printed sign rotates by -eps_Z: a first-order error of 2 eps_Z |lever_xy|
    # (50 a-s = 2.4e-4 rad over a ~130-265 mm lever) - tens of micrometres.
    assert np.median(printed) > 10 * np.median(ours) and printed.max() > 0.03
