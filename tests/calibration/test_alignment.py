"""Alignment calibration (thesis chapter 4, section 5.3): every solver against
the simulator's truth at the thesis's noise (8 um scanner, 9 um vernier), the
stated uncertainties against Monte Carlo scatter, the closed form of eqs. 19-21
against least squares, the alignment library, and every bad input."""

import json
import math

import numpy as np
import pytest

import cmmpose
from cmmpose import sim
from cmmpose.calibration.alignment import (
    STANDARD_POSES,
    CalibrationError,
    ReferenceReading,
    alpha_beta_from_vernier,
    calibrated_pose,
    gamma_from_plane_scan,
    mount_offset,
    mount_offset_closed_form,
    reference_centre_reading,
)
from cmmpose.calibration.library import AlignmentLibrary, AlignmentRecord
from cmmpose.sim.calibration_data import (
    VERNIER_NOISE,
    plane_scan,
    reference_sphere_scans,
    true_alignment_reading,
    vernier_points,
)

MAPS = cmmpose.ErrorMapSet.thesis()
T = 21.0  # between the 20 and 25 C maps
OFFSET = np.array(cmmpose.MountOffset.thesis())
ALIGN_ERR = sim.Alignment(0.03, -0.02, 0.04)  # deg: the pose to recover
OFFSET_ERR = sim.MountOffset(0.03, -0.02, 0.04)  # mm: the offset to recover
FAST = sim.Scanner(points_per_profile=256)  # 8 um noise, fewer points: quick Monte Carlo
SMALL = sim.Scanner(points_per_profile=64)


def angle_diff(a, b):
    """a - b in degrees, wrapped to (-180, 180]."""
    return (np.asarray(a) - np.asarray(b) + 180.0) % 360.0 - 180.0


def rms(z):
    return np.sqrt(np.mean(np.square(z), axis=0))


def tilted_plane(pose):
    """A plane the scanner sees at an angle: normal mostly along v, tilted towards u and w,
    through the laser origin at mid-sweep (plane_scan's default centre)."""
    e = cmmpose.Pose(*pose).matrix()
    centre = np.array([450.0, 275.0, -250.0]) - e @ OFFSET
    n = e[:, 1] + 0.3 * e[:, 0] + 0.4 * e[:, 2]
    return sim.Plane(centre, n / np.linalg.norm(n), 300.0)


# ---------------------------------------------------------------------------
# 1. alpha, beta from the optical vernier
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("pose", [*STANDARD_POSES, (90.0, 90.0, -60.0)])
def test_vernier_recovers_alpha_beta_within_3u(pose):
    v = vernier_points(pose, maps=MAPS, temperature=T, effects=[ALIGN_ERR], seed=3)
    r = alpha_beta_from_vernier(v.points, point_uncertainty=VERNIER_NOISE, maps=MAPS, temperature=T)
    err = np.array([angle_diff(r.alpha, v.true_pose[0]), r.beta - v.true_pose[1]])
    assert np.all(np.abs(err) < 3 * r.uncertainty), (err, r.uncertainty)
    assert 0.005 < r.uncertainty[0] < 0.03  # the thesis's 0.01-0.05 deg class
    # The same convention as Pose.from_normal (beta = acos n_z, alpha = atan2(n_x, -n_y)).
    p = cmmpose.Pose.from_normal(r.normal)
    assert angle_diff(p.alpha, r.alpha) == pytest.approx(0, abs=1e-9) and p.beta == pytest.approx(r.beta, abs=1e-9)
    assert np.allclose(r.pose(12.0).normal, r.normal, atol=1e-12)


def test_vernier_uncertainty_matches_monte_carlo():
    z_b, z_a = [], []
    for seed in range(300):
        v = vernier_points((90.0, 90.0, 0.0), maps=MAPS, temperature=T, effects=[ALIGN_ERR], seed=seed)
        r = alpha_beta_from_vernier(v.points, point_uncertainty=VERNIER_NOISE, maps=MAPS, temperature=T)
        z_b.append(np.array([angle_diff(r.alpha, v.true_pose[0]), r.beta - v.true_pose[1]]) / r.uncertainty)
        # Type A (sigma from the fit's residuals) with enough points to be a fair estimate.
        v = vernier_points((180.0, 90.0, 0.0), n=30, maps=MAPS, temperature=T, effects=[ALIGN_ERR], seed=1000 + seed)
        r = alpha_beta_from_vernier(v.points, maps=MAPS, temperature=T)
        z_a.append(np.array([angle_diff(r.alpha, v.true_pose[0]), r.beta - v.true_pose[1]]) / r.uncertainty)
    assert np.all(np.abs(rms(z_b) - 1) < 0.15), rms(z_b)
    # Student t with 27 degrees of freedom: sd sqrt(27/25) = 1.04.
    assert np.all(np.abs(rms(z_a) - 1.04) < 0.15), rms(z_a)


def test_vernier_without_the_map_sees_the_squareness():
    """Uncompensated vernier readings lie on a plane sheared by the machine's
    squareness: alpha comes out off by S_xy (-174 a-s at 21 C), beta by S_zx."""
    v = vernier_points((90.0, 90.0, 0.0), noise=0.0, maps=MAPS, temperature=T)
    comp = alpha_beta_from_vernier(v.points, point_uncertainty=VERNIER_NOISE, maps=MAPS, temperature=T)
    raw = alpha_beta_from_vernier(v.points, point_uncertainty=VERNIER_NOISE)
    s_xy, _, s_zx = np.array(MAPS.at(T).squareness) / 3600.0
    # compensated: a few arc-seconds (the ram's rotation changes between the vernier points, acting on the
    # 300 mm lever), against an uncertainty of 0.013 deg = 47 a-s
    assert abs(comp.alpha - 90.0) < 0.002 and abs(comp.beta - 90.0) < 0.002
    assert raw.alpha - comp.alpha == pytest.approx(-s_xy, abs=0.003)
    assert raw.beta - comp.beta == pytest.approx(s_zx, abs=0.003)


def test_vernier_w_side_from_point_order_or_hint():
    v = vernier_points((90.0, 90.0, 0.0), noise=0.0, maps=MAPS, temperature=T)
    ccw = alpha_beta_from_vernier(v.points, point_uncertainty=0.009)
    assert ccw.normal[0] > 0.999  # W along +X: the points go counter-clockwise about +w
    cw = alpha_beta_from_vernier(v.points[::-1], point_uncertainty=0.009)
    assert np.allclose(cw.normal, -ccw.normal)
    hinted = alpha_beta_from_vernier(v.points[::-1], w_hint=(1, 0, 0), point_uncertainty=0.009)
    assert np.allclose(hinted.normal, ccw.normal) and hinted.alpha == pytest.approx(ccw.alpha)


def test_vernier_bad_inputs():
    v = vernier_points((90.0, 90.0, 0.0), maps=MAPS, temperature=T, seed=1)
    pts = v.points.copy()
    with pytest.raises(cmmpose.InputError, match="at least 3 points"):
        alpha_beta_from_vernier(pts[:2])
    line = np.array([[0.0, 0.0, 0.0], [10.0, 5.0, 1.0], [20.0, 10.0, 2.0], [30.0, 15.0, 3.0]])
    with pytest.raises(cmmpose.GeometryError, match="collinear"):
        alpha_beta_from_vernier(line)
    rng = np.random.default_rng(0)
    with pytest.raises(cmmpose.GeometryError, match="collinear"):
        alpha_beta_from_vernier(line + rng.normal(0, 0.009, line.shape))  # noise does not make it a plane
    bad = pts.copy()
    bad[1, 2] = np.nan
    with pytest.raises(cmmpose.InputError, match="row 1"):
        alpha_beta_from_vernier(bad)
    with pytest.raises(cmmpose.InputError, match="w_hint"):
        alpha_beta_from_vernier(pts, w_hint=(0, 0, 1))  # in the scan plane of W along X
    bowtie = np.array([[0.0, 0.0, 0.0], [0.0, 20.0, 20.0], [0.0, 20.0, 0.0], [0.0, 0.0, 20.0]])
    with pytest.raises(cmmpose.GeometryError, match="w_hint"):
        alpha_beta_from_vernier(bowtie)
    with pytest.raises(cmmpose.InputError, match="temperature"):
        alpha_beta_from_vernier(pts, maps=MAPS)
    assert np.array_equal(pts, v.points)  # inputs never modified
    three = alpha_beta_from_vernier(pts[:3])  # 3 points: a plane, but no Type A uncertainty
    assert np.all(np.isnan(three.uncertainty))


# ---------------------------------------------------------------------------
# 2. gamma from a plane scanned while the machine moves
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("pose", [*STANDARD_POSES, (90.0, 90.0, -60.0)])
def test_gamma_known_normal_recovers_truth(pose):
    d = plane_scan(pose, maps=MAPS, temperature=T, effects=[ALIGN_ERR], seed=5, scanner=FAST)
    g = gamma_from_plane_scan(d.uv, d.scales, d.true_pose[0], d.true_pose[1], normal=d.plane.normal,
                              offset=OFFSET, maps=MAPS, temperature=T)
    assert g.method == "known normal" and g.rms < 0.01
    assert abs(angle_diff(g.gamma, d.true_pose[2])) < 3 * g.uncertainty, (g.gamma, d.true_pose[2], g.uncertainty)
    # Without gamma0 the whole circle is searched; the facing condition picks the branch.
    assert np.dot(g.normal, cmmpose.Pose(d.true_pose[0], d.true_pose[1], g.gamma).matrix()[:, 1]) > 0


@pytest.mark.parametrize("pose, axes", [((90.0, 90.0, 0.0), ("X", "Y")), ((90.0, 90.0, 90.0), ("X", "Z")),
                                        ((180.0, 90.0, 0.0), ("X", "Y", "Z"))])
def test_gamma_fitted_plane_from_two_sweeps_recovers_truth(pose, axes):
    d = plane_scan(pose, plane=tilted_plane(pose), axes=axes, maps=MAPS, temperature=T, effects=[ALIGN_ERR],
                   seed=2, scanner=FAST)
    g = gamma_from_plane_scan(d.uv, d.scales, d.true_pose[0], d.true_pose[1], offset=OFFSET, maps=MAPS,
                              temperature=T)
    assert g.method == "fitted plane"
    assert abs(angle_diff(g.gamma, d.true_pose[2])) < 3 * g.uncertainty
    assert np.degrees(np.arccos(min(1.0, abs(g.normal @ d.plane.normal)))) < 0.01


def test_gamma_uncertainty_matches_monte_carlo():
    pose = (90.0, 90.0, 30.0)
    z_known, z_free = [], []
    for seed in range(120):
        d = plane_scan(pose, maps=MAPS, temperature=T, effects=[ALIGN_ERR], seed=seed, scanner=SMALL)
        g = gamma_from_plane_scan(d.uv, d.scales, d.true_pose[0], d.true_pose[1], normal=d.plane.normal,
                                  gamma0=30.0, offset=OFFSET, maps=MAPS, temperature=T)
        z_known.append(angle_diff(g.gamma, d.true_pose[2]) / g.uncertainty)
    for seed in range(80):
        d = plane_scan(pose, plane=tilted_plane(pose), axes=("X", "Y"), maps=MAPS, temperature=T,
                       effects=[ALIGN_ERR], seed=500 + seed, scanner=SMALL)
        g = gamma_from_plane_scan(d.uv, d.scales, d.true_pose[0], d.true_pose[1], gamma0=30.0, offset=OFFSET,
                                  maps=MAPS, temperature=T)
        z_free.append(angle_diff(g.gamma, d.true_pose[2]) / g.uncertainty)
    assert abs(rms(z_known) - 1) < 0.2, rms(z_known)
    assert abs(rms(z_free) - 1) < 0.2, rms(z_free)


def test_gamma_propagates_alpha_beta_and_combines_into_a_pose():
    pose = (90.0, 90.0, -60.0)
    v = vernier_points(pose, maps=MAPS, temperature=T, effects=[ALIGN_ERR], seed=8)
    ab = alpha_beta_from_vernier(v.points, point_uncertainty=VERNIER_NOISE, maps=MAPS, temperature=T)
    d = plane_scan(pose, maps=MAPS, temperature=T, effects=[ALIGN_ERR], seed=8, scanner=FAST)
    g = gamma_from_plane_scan(d.uv, d.scales, ab.alpha, ab.beta, normal=d.plane.normal, gamma0=-60.0,
                              offset=OFFSET, maps=MAPS, temperature=T, alpha_beta_covariance=ab.covariance)
    assert g.uncertainty > g.noise_uncertainty  # alpha, beta add to it
    assert abs(angle_diff(g.gamma, d.true_pose[2])) < 3 * g.uncertainty
    cp = calibrated_pose(ab, g)
    assert cp.covariance.shape == (3, 3) and np.allclose(cp.covariance, cp.covariance.T)
    assert cp.uncertainty[2] == pytest.approx(g.uncertainty, rel=1e-9)
    assert np.all(np.abs(angle_diff(cp.pose.as_tuple(), d.true_pose)) < 3 * cp.uncertainty)
    other = gamma_from_plane_scan(d.uv, d.scales, ab.alpha + 0.1, ab.beta, normal=d.plane.normal, gamma0=-60.0,
                                  maps=MAPS, temperature=T)
    with pytest.raises(cmmpose.InputError, match="solve gamma with the vernier's angles"):
        calibrated_pose(ab, other)


def test_gamma_bad_inputs():
    d = plane_scan((90.0, 90.0, 0.0), maps=MAPS, temperature=T, seed=1, scanner=SMALL)
    a, b = 90.0, 90.0
    # no motion: the same profile's readings everywhere
    still = np.tile(d.scales[0], (len(d.scales), 1))
    with pytest.raises(CalibrationError, match="no motion"):
        gamma_from_plane_scan(d.uv, still, a, b, normal=(0, 0, 1))
    with pytest.raises(cmmpose.InputError, match="at least 10 points"):
        gamma_from_plane_scan(d.uv[:5], d.scales[:5], a, b, normal=(0, 0, 1))
    with pytest.raises(cmmpose.InputError, match="same number of rows"):
        gamma_from_plane_scan(d.uv, d.scales[:-1], a, b)
    bad = d.uv.copy()
    bad[7, 1] = np.inf
    with pytest.raises(cmmpose.InputError, match="row 7"):
        gamma_from_plane_scan(bad, d.scales, a, b, normal=(0, 0, 1))
    # one straight sweep over a plane of unknown orientation: flat for every gamma
    with pytest.raises(CalibrationError, match="does not determine gamma"):
        gamma_from_plane_scan(d.uv, d.scales, a, b, maps=MAPS, temperature=T)
    # moving only within the scan plane (W along X, sweeps along Y and Z)
    inplane = plane_scan((90.0, 90.0, 0.0), plane=tilted_plane((90.0, 90.0, 0.0)), axes=("Y", "Z"), maps=MAPS,
                         temperature=T, seed=1, scanner=SMALL)
    with pytest.raises(CalibrationError, match="scan plane"):
        gamma_from_plane_scan(inplane.uv, inplane.scales, a, b, maps=MAPS, temperature=T)
    # a normal pointing into the material: the scanner cannot face it near gamma0
    with pytest.raises(CalibrationError, match="outward normal"):
        gamma_from_plane_scan(d.uv, d.scales, a, b, normal=(0, 0, -1), gamma0=0.0, maps=MAPS, temperature=T)
    with pytest.raises(cmmpose.InputError, match="normal"):
        gamma_from_plane_scan(d.uv, d.scales, a, b, normal=(0, 0, 0))
    # a normal with a component along the sweep: no gamma puts the points on a plane with it (the least bad
    # one is 45 degrees off and 12 mm rms), refused rather than returned
    with pytest.raises(CalibrationError, match="45.0 deg from the given normal"):
        gamma_from_plane_scan(d.uv, d.scales, a, b, normal=(1, 0, 1), maps=MAPS, temperature=T)
    # the true normal tilted by 0.5 deg (a face not quite level) is taken
    tilt = np.radians(0.5)
    g = gamma_from_plane_scan(d.uv, d.scales, a, b, normal=(np.sin(tilt), 0, np.cos(tilt)), maps=MAPS,
                              temperature=T)
    assert g.method == "known normal"
    # a covariance that is not finite names itself and the usual cause
    with pytest.raises(cmmpose.InputError, match="alpha_beta_covariance: expected finite entries.*point_uncertainty"):
        gamma_from_plane_scan(d.uv, d.scales, a, b, normal=(0, 0, 1), maps=MAPS, temperature=T,
                              alpha_beta_covariance=np.full((2, 2), np.nan))
    with pytest.raises(cmmpose.InputError, match="temperature"):
        gamma_from_plane_scan(d.uv, d.scales, a, b, normal=(0, 0, 1), maps=MAPS)
    with pytest.raises(cmmpose.InputError, match="temperature"):
        gamma_from_plane_scan(d.uv, d.scales, a, b, normal=(0, 0, 1), maps=MAPS, temperature=[20.0, 21.0])


# ---------------------------------------------------------------------------
# 3. D0, E0, F0 from the reference sphere
# ---------------------------------------------------------------------------


def test_general_form_gives_eqs_16_to_18():
    """S = centre + E313 l1: for the three standard poses, the thesis's eqs. 16-18."""
    c = np.array([450.0, 380.0, -420.0])
    u1, v1, w1 = OFFSET
    s1, s2, s3 = (c + cmmpose.Pose(*p).matrix() @ OFFSET for p in STANDARD_POSES)
    assert np.allclose(c, [s1[0] - w1, s1[1] - u1, s1[2] - v1])  # eq. 16
    assert np.allclose(c, [s2[0] - w1, s2[1] + v1, s2[2] - u1])  # eq. 17
    assert np.allclose(c, [s3[0] + u1, s3[1] - w1, s3[2] - v1])  # eq. 18


@pytest.mark.parametrize("pose", [*STANDARD_POSES, (0.0, 90.0, 0.0)])
def test_reference_reading_recovers_truth(pose):
    x = reference_sphere_scans([pose], maps=MAPS, temperature=T, effects=[OFFSET_ERR], seed=4)[0]
    r = reference_centre_reading(x.data.uv, x.data.scales, pose, offset=OFFSET, maps=MAPS, temperature=T)
    err = r.reading - x.true_reading
    assert np.all(np.abs(err) < 3 * r.uncertainty), (err * 1e3, r.uncertainty * 1e3)
    assert np.all(r.uncertainty < 0.002)  # ~5000 points at 8 um: about 0.2-0.5 um
    # the centre, with the offset the scan was planned with (the true one is 40 um away)
    assert np.all(np.abs(r.centre - x.centre) < 0.1)
    # no offset: D0 within 0.5 um (the ram's rotation between the scan and D0, docs)
    r0 = reference_centre_reading(x.data.uv, x.data.scales, pose, maps=MAPS, temperature=T)
    assert np.abs(r0.reading - r.reading).max() < 0.0006
    assert np.allclose(r0.position, r.position) and np.allclose(r0.lever, r.lever)


def test_reference_reading_noise_free_is_exact():
    x = reference_sphere_scans([STANDARD_POSES[1]], maps=MAPS, temperature=T, effects=[OFFSET_ERR], seed=1,
                               scanner=sim.Scanner(noise=0.0, points_per_profile=256))[0]
    r = reference_centre_reading(x.data.uv, x.data.scales, x.pose, offset=x.true_offset, maps=MAPS, temperature=T)
    assert np.abs(r.reading - x.true_reading).max() < 2e-6  # mm
    assert np.abs(r.centre - x.centre).max() < 2e-6


def test_reference_reading_error_free_machine_needs_no_offset():
    zero = cmmpose.ErrorMap.zero(temperature=20.0)
    x = reference_sphere_scans([STANDARD_POSES[2]], maps=zero, temperature=20.0, seed=2, scanner=FAST)[0]
    r = reference_centre_reading(x.data.uv, x.data.scales, x.pose)
    assert np.all(np.abs(r.reading - x.true_reading) < 3 * r.uncertainty)
    assert np.allclose(r.lever, cmmpose.Pose(*x.pose).matrix()) and np.array_equal(r.reading, r.position)
    assert np.allclose(true_alignment_reading(x.centre, x.pose, OFFSET, maps=zero),
                       x.centre + cmmpose.Pose(*x.pose).matrix() @ OFFSET, atol=1e-9)


def test_reference_reading_bad_inputs():
    x = reference_sphere_scans([STANDARD_POSES[0]], maps=MAPS, temperature=T, seed=1, scanner=SMALL)[0]
    with pytest.raises(cmmpose.InputError, match="same number of rows"):
        reference_centre_reading(x.data.uv[:-1], x.data.scales, x.pose)
    with pytest.raises(cmmpose.InputError, match="at least 4 points"):
        reference_centre_reading(x.data.uv[:3], x.data.scales[:3], x.pose)
    with pytest.raises(cmmpose.InputError, match="covariance"):
        reference_centre_reading(x.data.uv, x.data.scales, x.pose, pose_covariance=np.eye(2))
    with pytest.raises(cmmpose.InputError, match="reading_uncertainty"):
        reference_centre_reading(x.data.uv, x.data.scales, x.pose, reading_uncertainty=-1.0)
    with pytest.raises(cmmpose.InputError, match="uncertainty"):
        ReferenceReading.from_reading(x.pose, (1.0, 2.0, 3.0))
    r = reference_centre_reading(x.data.uv, x.data.scales, x.pose, reading_uncertainty=(0.002, 0.0165, 0.001))
    assert np.all(r.uncertainty >= [0.002, 0.0165, 0.001])


# ---------------------------------------------------------------------------
# 4-5. the mount offset: least squares, closed form, uncertainty, Monte Carlo
# ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def monte_carlo_alignments():
    """200 repeats of the three standard alignments (8 um noise), with the truth."""
    runs = []
    for seed in range(200):
        scans = reference_sphere_scans(STANDARD_POSES, maps=MAPS, temperature=T, effects=[OFFSET_ERR], seed=seed,
                                       scanner=FAST)
        al = [reference_centre_reading(x.data.uv, x.data.scales, x.pose, offset=OFFSET, maps=MAPS,
                                       temperature=T) for x in scans]
        runs.append((scans, al))
    return runs


def test_reading_uncertainty_matches_monte_carlo(monte_carlo_alignments):
    z = np.array([[(a.reading - x.true_reading) / a.uncertainty for x, a in zip(scans, al)]
                  for scans, al in monte_carlo_alignments])  # (repeats, pose, axis)
    r = rms(z.reshape(-1, 3))
    assert np.all(np.abs(r - 1) < 0.15), r
    assert np.all(np.abs(z.reshape(-1, 3).mean(axis=0)) < 0.2)  # no bias


def test_mount_offset_uncertainty_matches_monte_carlo(monte_carlo_alignments):
    z = []
    for scans, al in monte_carlo_alignments:
        m = mount_offset(al)
        z.append((np.array(m.offset) - scans[0].true_offset) / m.uncertainty)
    z = np.array(z)
    assert np.all(np.abs(rms(z) - 1) < 0.2), rms(z)  # 200 repeats: 5 % standard error
    assert np.all(np.abs(z.mean(axis=0)) < 0.25)


def test_mount_offset_recovers_truth_and_reports_residuals(monte_carlo_alignments):
    scans, al = monte_carlo_alignments[0]
    m = mount_offset(al)
    truth = scans[0].true_offset
    assert np.all(np.abs(np.array(m.offset) - truth) < 3 * m.uncertainty)
    assert np.all(m.uncertainty < 0.002)  # noise only: about 0.3-0.6 um
    assert np.all(np.abs(m.centre - scans[0].centre) < 3 * np.sqrt(np.diag(m.centre_covariance)))
    assert m.dof == 3 and m.residuals.shape == (3, 3) and np.abs(m.residuals).max() < 0.003
    assert 0.001 < m.p_value <= 1.0
    assert np.allclose(np.sqrt((m.contributions**2).sum(axis=0)), m.uncertainty)


def test_closed_form_and_least_squares_agree_on_consistent_data():
    # Exact readings of the three standard alignments (S_k = c + E313_k l1): the
    # closed form of eqs. 19, 20 and 21 (corrected) and least squares both give l1.
    c = np.array([450.0, 380.0, -420.0])
    s = [c + cmmpose.Pose(*p).matrix() @ OFFSET for p in STANDARD_POSES]
    cf = mount_offset_closed_form(*s)
    assert np.allclose(cf.offset, OFFSET, atol=1e-9) and np.allclose(cf.centre, c, atol=1e-9)
    assert all(abs(v) < 1e-9 for v in cf.checks.values())
    ls = mount_offset([ReferenceReading.from_reading(p, sk, 0.01) for p, sk in zip(STANDARD_POSES, s)])
    assert np.allclose(ls.offset, cf.offset, atol=1e-9) and ls.chi2 < 1e-12
    # eq. 21 as printed gives another W1: the misprint (docs/conventions.md, Misprints)
    (d1, e1, f1), (d2, e2, f2), (d3, e3, f3) = s
    printed = (d1 + 2 * d3 - e2 + f2 - f1) / 2
    assert abs(printed - OFFSET[2]) > 100.0


def test_closed_form_and_least_squares_agree_on_simulated_scans():
    zero = cmmpose.ErrorMap.zero(temperature=20.0)  # an error-free machine: the thesis's model exactly
    scans = reference_sphere_scans(STANDARD_POSES, maps=zero, temperature=20.0, effects=[OFFSET_ERR], seed=11)
    al = [reference_centre_reading(x.data.uv, x.data.scales, x.pose) for x in scans]
    cf = mount_offset_closed_form(*al)
    ls = mount_offset(al)
    truth = scans[0].true_offset
    assert np.all(np.abs(np.array(cf.offset) - truth) < 3 * cf.uncertainty)
    assert np.all(np.abs(np.array(cf.offset) - np.array(ls.offset)) < 3 * cf.uncertainty)
    assert np.all(ls.uncertainty <= cf.uncertainty * (1 + 1e-9))  # all nine equations, weighted
    assert all(abs(v) < 0.005 for v in cf.checks.values())


def test_closed_form_gum_budget_of_eqs_22_to_24():
    """Thesis inputs per reading: 9 um digitizer, 5.8 um sphere fit per axis and
    the scale errors 2, 16.5, 1 um. Eqs. 22-23 give 15.8 um (the thesis prints
    35.1), the corrected eq. 21 gives 22.1 um for W1."""
    per_axis = np.sqrt(9.0**2 + (10 / math.sqrt(3)) ** 2 + np.array([2.0, 16.5, 1.0]) ** 2) / 1000.0
    c = np.array([450.0, 380.0, -420.0])
    s = [c + cmmpose.Pose(*p).matrix() @ OFFSET for p in STANDARD_POSES]
    cf = mount_offset_closed_form(*s, uncertainties=per_axis)
    u = cf.uncertainty * 1000
    assert u[0] == pytest.approx(15.85, abs=0.01) and u[1] == pytest.approx(15.85, abs=0.01)
    assert u[2] == pytest.approx(math.sqrt(2 * per_axis[0] ** 2 * 1e6 + 15.85**2), abs=0.02)
    assert u[2] == pytest.approx(22.1, abs=0.05)
    names = {n: c for n, c, _, _ in cf.budget["U1"]}
    assert names == {"E1": 0.5, "F1": -0.5, "E2": -0.5, "F2": 0.5}
    assert math.sqrt(sum(x[3] ** 2 for x in cf.budget["W1"])) == pytest.approx(u[2] / 1000, rel=1e-9)
    # ReferenceReadings bring their own covariance, and must be at the standard poses
    rr = [ReferenceReading.from_reading(p, sk, per_axis) for p, sk in zip(STANDARD_POSES, s)]
    assert np.allclose(mount_offset_closed_form(*rr).covariance, cf.covariance)
    with pytest.raises(cmmpose.InputError, match="pose"):
        mount_offset_closed_form(rr[1], rr[0], rr[2])


def test_fourth_noisy_alignment_degrades_gracefully(monte_carlo_alignments):
    scans, al = monte_carlo_alignments[3]
    noisy = sim.Scanner(points_per_profile=64, noise=0.03)
    x4 = reference_sphere_scans([(0.0, 90.0, 0.0)], maps=MAPS, temperature=T, effects=[OFFSET_ERR], seed=77,
                                scanner=noisy)[0]
    a4 = reference_centre_reading(x4.data.uv, x4.data.scales, x4.pose, maps=MAPS, temperature=T)
    assert a4.uncertainty.min() > 2 * max(a.uncertainty.max() for a in al)
    m3, m4 = mount_offset(al), mount_offset([*al, a4])
    change = np.array(m4.offset) - np.array(m3.offset)
    assert m4.dof == 6
    assert np.all(np.abs(change) < m3.uncertainty)  # within the stated uncertainty
    assert np.all(m4.uncertainty <= m3.uncertainty)  # more data never hurts when weighted
    # nested least squares: var(change) = var(3) - var(4)
    assert np.all(np.abs(change) < 3 * np.sqrt(m3.uncertainty**2 - m4.uncertainty**2) + 1e-6)
    assert np.all(np.abs(np.array(m4.offset) - scans[0].true_offset) < 3 * m4.uncertainty)
    # the noisy alignment carries little weight
    assert np.all(m4.contributions[3] < m4.uncertainty)


@pytest.mark.parametrize("dof", [1, 2, 3, 4, 5, 6, 9, 12, 25, 60])
def test_chi_square_p_value_is_scipys(dof):
    """mount_offset's p-value, P(chi^2_dof > chi2), equals scipy.stats.chi2.sf."""
    from scipy.stats import chi2 as chi2_dist

    from cmmpose.calibration.alignment.common import chi2_sf

    for x in np.geomspace(1e-6, 400.0, 60):
        assert chi2_sf(float(x), dof) == pytest.approx(chi2_dist.sf(x, dof), rel=1e-12, abs=1e-300)
    assert chi2_sf(0.0, dof) == 1.0 and chi2_sf(-1.0, dof) == 1.0
    assert chi2_sf(3.0, 0) == 1.0


def test_alignments_that_disagree_raise(monte_carlo_alignments):
    _, al = monte_carlo_alignments[5]
    # A fourth alignment 0.2 mm off (trunnion not seated): named, in standard deviations.
    x4 = reference_sphere_scans([(0.0, 90.0, 0.0)], maps=MAPS, temperature=T, seed=78, scanner=FAST)[0]
    a4 = reference_centre_reading(x4.data.uv, x4.data.scales + [0.0, 0.2, 0.0], x4.pose, maps=MAPS,
                                  temperature=T)
    with pytest.raises(CalibrationError, match=r"alignments disagree: alignment \d .*standard deviations"):
        mount_offset([*al, a4])
    loose = mount_offset([*al, a4], tolerance=None)  # reported, not raised
    assert loose.p_value < 1e-6 and np.abs(loose.residuals).max() > 0.05
    # Thesis-style readings with 20 um uncertainties, one 0.3 mm off.
    c = np.array([450.0, 380.0, -420.0])
    s = [c + cmmpose.Pose(*p).matrix() @ OFFSET for p in STANDARD_POSES]
    s[2] = s[2] + [0.3, 0.0, 0.0]
    rr = [ReferenceReading.from_reading(p, sk, 0.02) for p, sk in zip(STANDARD_POSES, s)]
    with pytest.raises(CalibrationError, match="disagree"):
        mount_offset(rr)
    with pytest.raises(CalibrationError, match="max_residual"):
        mount_offset(rr, tolerance=None, max_residual=0.05)
    with pytest.raises(CalibrationError, match="chi-square test"):
        mount_offset(rr, tolerance=None, significance=0.001)
    assert mount_offset(rr, tolerance=None).dof == 3


def test_mount_offset_bad_inputs():
    c = np.array([450.0, 380.0, -420.0])
    rr = [ReferenceReading.from_reading(p, c + cmmpose.Pose(*p).matrix() @ OFFSET, 0.01) for p in STANDARD_POSES]
    with pytest.raises(cmmpose.InputError, match="at least 2"):
        mount_offset(rr[:1])
    with pytest.raises(cmmpose.GeometryError, match="do not determine the mount offset"):
        mount_offset(rr[:2])  # both with W along X: W1 is free
    with pytest.raises(cmmpose.InputError, match="ReferenceReading"):
        mount_offset([*rr[:2], (1.0, 2.0, 3.0)])
    with pytest.raises(cmmpose.InputError, match="tolerance"):
        mount_offset(rr, tolerance=-1)
    with pytest.raises(cmmpose.InputError, match="significance"):
        mount_offset(rr, significance=2.0)


def test_full_calibration_recovers_pose_readings_and_offset():
    """Vernier -> alpha, beta; plane scan -> gamma; sphere -> D0 E0 F0 with the
    pose's uncertainty; three alignments -> U1 V1 W1, at the thesis's noise, on
    a machine with the thesis maps, a pose error and an offset error; repeated
    to check the propagated uncertainties (pose dominated, tens of um: the
    thesis's 40 um class) against the scatter."""

    def calibrate(rng):
        out = []
        for nominal in STANDARD_POSES:
            eff = [ALIGN_ERR, OFFSET_ERR]
            v = vernier_points(nominal, maps=MAPS, temperature=T, effects=eff, seed=rng)
            ab = alpha_beta_from_vernier(v.points, w_hint=cmmpose.Pose(*nominal).normal,
                                         point_uncertainty=VERNIER_NOISE, maps=MAPS, temperature=T)
            d = plane_scan(nominal, maps=MAPS, temperature=T, effects=eff, seed=rng, scanner=SMALL)
            g = gamma_from_plane_scan(d.uv, d.scales, ab.alpha, ab.beta, normal=d.plane.normal, gamma0=nominal[2],
                                      offset=OFFSET, maps=MAPS, temperature=T,
                                      alpha_beta_covariance=ab.covariance)
            cp = calibrated_pose(ab, g)
            x = reference_sphere_scans([nominal], maps=MAPS, temperature=T, effects=eff,
                                       seed=int(rng.integers(1 << 30)), scanner=FAST)[0]
            r = reference_centre_reading(x.data.uv, x.data.scales, cp.pose, offset=OFFSET, maps=MAPS,
                                         temperature=T, pose_covariance=cp.covariance)
            out.append((x, cp, r))
        return out

    z = []
    for seed in range(30):
        res = calibrate(np.random.default_rng(seed))
        m = mount_offset([r for _, _, r in res])
        truth = res[0][0].true_offset
        z.append((np.array(m.offset) - truth) / m.uncertainty)
        if seed == 0:
            for x, cp, r in res:
                assert np.all(np.abs(angle_diff(cp.pose.as_tuple(), x.true_pose)) < 3 * cp.uncertainty)
                assert np.all(np.abs(r.reading - x.true_reading) < 3 * r.uncertainty)
            assert np.all(np.abs(np.array(m.offset) - truth) < 3 * m.uncertainty)
            assert np.all((0.005 < m.uncertainty) & (m.uncertainty < 0.08))
    z = np.array(z)
    assert np.all(np.abs(z) < 4)
    assert 0.75 < rms(z.ravel()) < 1.25, rms(z)


# ---------------------------------------------------------------------------
# 6. the alignment library
# ---------------------------------------------------------------------------


def record(**kw):
    base = dict(pose=(90.0, 90.0, 0.0), reading=(579.575, 381.001, -155.495), offset=tuple(OFFSET),
                pose_uncertainty=(0.013, 0.013, 0.0003), reading_uncertainty=(0.0002, 0.0002, 0.0005),
                offset_uncertainty=(0.018, 0.025, 0.04), temperature=21.0, date="2024-05-01T14:30:00+00:00",
                residuals={"sphere_rms": 0.0079, "plane_rms": 0.0081}, note="test")
    base.update(kw)
    return AlignmentRecord(**base)


def test_library_round_trip(tmp_path):
    lib = AlignmentLibrary(tmp_path / "sub" / "alignments.json")
    assert len(lib) == 0 and lib.names() == []
    a = record()
    b = record(pose=(180.0, 90.0, 0.0), reading=(448.999, 509.575, -155.495), temperature=None, residuals={})
    lib.save("A90B90", a)
    lib.save("A180B90", b)
    again = AlignmentLibrary(tmp_path / "sub" / "alignments.json")
    assert again.names() == ["A180B90", "A90B90"] and "A90B90" in again and len(again) == 2
    assert again.load("A90B90") == a and again.load("A180B90") == b
    assert again.load("A90B90").as_pose() == cmmpose.Pose(90.0, 90.0, 0.0)
    assert again.load("A90B90").as_offset() == cmmpose.MountOffset(*OFFSET)
    doc = json.loads((tmp_path / "sub" / "alignments.json").read_text())
    assert doc["format"] == "cmmpose-alignment-library" and doc["units"]["reading"].startswith("mm")
    with pytest.raises(CalibrationError, match="already aligned"):
        lib.save("A90B90", b, overwrite=False)
    lib.save("A90B90", b)  # the trunnion was re-aligned
    assert lib.load("A90B90") == b
    lib.remove("A180B90")
    assert lib.names() == ["A90B90"]
    assert set(lib.records()) == {"A90B90"}


def test_library_unknown_pose_is_a_clear_error(tmp_path):
    lib = AlignmentLibrary(tmp_path / "lib.json")
    empty = r"pose 'A90B90' was never aligned \(known: none; the library is empty\)"
    with pytest.raises(CalibrationError, match=empty):
        lib.load("A90B90")
    lib.save("A180B90", record())
    lib.save("A90B90G90", record())
    with pytest.raises(CalibrationError, match=r"pose 'A90B90' was never aligned \(known: 'A180B90', 'A90B90G90'\)"):
        lib.load("A90B90")
    with pytest.raises(CalibrationError, match="never aligned"):
        lib.remove("A0B0")
    with pytest.raises(cmmpose.InputError, match="name"):
        lib.save("", record())


@pytest.mark.parametrize("content, message", [
    ("{not json", "bad JSON"),
    ('{"format": "something else", "version": 1, "poses": {}}', "not an alignment library"),
    ('{"format": "cmmpose-alignment-library", "version": 99, "poses": {}}', "version 99"),
    ('{"format": "cmmpose-alignment-library", "version": 1, "poses": []}', '"poses" must be an object'),
    ('{"format": "cmmpose-alignment-library", "version": 1, "poses": {"A": {"pose": [1, 2, 3]}}}',
     "pose 'A': missing field"),
    ('{"format": "cmmpose-alignment-library", "version": 1, "poses": {"A": {"pose": [1, 2], "reading": [1, 2, 3], '
     '"offset": [1, 2, 3]}}}', "pose: expected three finite numbers"),
    ('{"format": "cmmpose-alignment-library", "version": 1, "poses": {"A": {"pose": [1, 2, 3], "reading": [1, 2, 3], '
     '"offset": [1, 2, 3], "date": "yesterday"}}}', "not ISO 8601"),
    ('{"format": "cmmpose-alignment-library", "version": 1, "poses": {"A": {"pose": [1, 2, 3], "reading": [1, 2, 3], '
     '"offset": [1, 2, 3], "reading_uncertainty": [1, -2, 3]}}}', "must be >= 0"),
    ('{"format": "cmmpose-alignment-library", "version": 1, "poses": {"A": {"pose": [1, 2, 3], "reading": [1, 2, 3], '
     '"offset": [1, 2, 3], "pose_covariance": [[1, 0], [0, 1]]}}}', "pose_covariance must be a finite 3 x 3"),
    ('{"format": "cmmpose-alignment-library", "version": 1, "poses": {"A": {"pose": [1, 2, 3], "reading": [1, 2, 3], '
     '"offset": [1, 2, 3], "pose_covariance": [[1, 0, 0], [0.5, 1, 0], [0, 0, 1]]}}}', "symmetric positive"),
    ('{"format": "cmmpose-alignment-library", "version": 1, "poses": {"A": {"pose": [1, 2, 3], "reading": [1, 2, 3], '
     '"offset": [1, 2, 3], "reading_covariance": [[1, 0, 0], [0, -1, 0], [0, 0, 1]]}}}', "symmetric positive"),
    ('{"format": "cmmpose-alignment-library", "version": 1, "poses": {"A": {"pose": [1, 2, 3], "reading": [1, 2, 3], '
     '"offset": [1, 2, 3], "reading_covariance": [[4, 0, 0], [0, 4, 0], [0, 0, 4]], '
     '"reading_uncertainty": [1, 1, 1]}}}', "reading_uncertainty .* disagrees"),
    ('{"format": "cmmpose-alignment-library", "version": 1, "poses": {"A": {"pose": [1, 2, 3], "reading": [1, 2, 3], '
     '"offset": [1, 2, 3], "lever": [[1, 0, "x"], [0, 1, 0], [0, 0, 1]]}}}', "lever must be"),
])
def test_library_malformed_file(tmp_path, content, message):
    path = tmp_path / "lib.json"
    path.write_text(content)
    with pytest.raises(CalibrationError, match=message):
        AlignmentLibrary(path).load("A")
    assert path.read_text() == content  # never rewritten by a read


def test_library_record_from_calibration(tmp_path):
    x = reference_sphere_scans([STANDARD_POSES[0]], maps=MAPS, temperature=T, seed=3, scanner=FAST)[0]
    r = reference_centre_reading(x.data.uv, x.data.scales, x.pose, offset=OFFSET, maps=MAPS, temperature=T)
    rec = AlignmentRecord.from_calibration(x.pose, r, OFFSET, residuals={"plane_rms": 0.008})
    assert rec.temperature == pytest.approx(T) and rec.reading == pytest.approx(tuple(r.reading))
    assert rec.residuals["sphere_rms"] == pytest.approx(r.fit.rms) and rec.pose_uncertainty is None
    lib = AlignmentLibrary(tmp_path / "lib.json")
    lib.save("A90B90", rec)
    assert lib.load("A90B90") == rec
    with pytest.raises(CalibrationError, match="pose"):
        record(pose=(1.0, 2.0))
    with pytest.raises(CalibrationError, match="temperature"):
        record(temperature=float("nan"))


def test_library_record_keeps_the_solvers_reading_whole(tmp_path):
    """A record from the solvers gives mount_offset the very reading it was made
    from (pose covariance in full, pose Jacobian, lever, position), through the
    library file; reading_uncertainty is the reading's own, the pose's share apart."""
    readings, records = [], []
    lib = AlignmentLibrary(tmp_path / "lib.json")
    for k, nominal in enumerate(STANDARD_POSES):
        x = reference_sphere_scans([nominal], maps=MAPS, temperature=T, seed=10 + k, scanner=FAST)[0]
        pc = np.array([[2.8e-4, 1e-5, 3e-7], [1e-5, 2.8e-4, -2e-7], [3e-7, -2e-7, 1e-8]])  # deg^2, correlated
        r = reference_centre_reading(x.data.uv, x.data.scales, x.pose, offset=OFFSET, maps=MAPS,
                                     temperature=T, pose_covariance=pc)
        rec = AlignmentRecord.from_calibration(x.pose, r, OFFSET)
        np.testing.assert_allclose(rec.pose_covariance, pc)
        np.testing.assert_allclose(rec.reading_uncertainty, np.sqrt(np.diag(r.fit_covariance)))
        assert np.all(np.asarray(rec.reading_uncertainty) < r.uncertainty)  # the pose's share is apart
        lib.save(f"P{k}", rec)
        readings.append(r)
        records.append(lib.load(f"P{k}"))
    for r, rec in zip(readings, records):
        back = rec.reference_reading()
        for f in ("reading", "covariance", "fit_covariance", "pose_covariance", "pose_jacobian", "position", "lever"):
            np.testing.assert_allclose(getattr(back, f), getattr(r, f), rtol=1e-12, atol=1e-18, err_msg=f)
    a, b = mount_offset(readings), mount_offset([rec.reference_reading() for rec in records])
    np.testing.assert_allclose(b.offset, a.offset, rtol=0, atol=1e-9)  # mm: rounding (the file symmetrises covariances)
    np.testing.assert_allclose(b.covariance, a.covariance, rtol=1e-10)
    # a hand-written record (standard uncertainties only) is read as from_reading reads it
    hand = record()
    back = hand.reference_reading()
    np.testing.assert_allclose(back.fit_covariance, np.diag(np.square(hand.reading_uncertainty)))
    np.testing.assert_allclose(back.pose_covariance, np.diag(np.square(hand.pose_uncertainty)))
    with pytest.raises(CalibrationError, match="no reading uncertainty"):
        record(reading_uncertainty=None).reference_reading()


def test_the_alignment_solvers_take_the_temperature_policy():
    # Issue 26: every function that turns readings into temperatures takes the one TemperaturePolicy. 35 C is beyond
    # the thesis maps (20-30 C): an error by default, the 30 C map with out_of_range='clamp' (as at 30 C exactly).
    x = reference_sphere_scans([STANDARD_POSES[1]], maps=MAPS, temperature=30.0, seed=1, scanner=FAST)[0]
    args = (x.data.uv, x.data.scales, x.pose)
    with pytest.raises(cmmpose.OutOfRangeError):
        reference_centre_reading(*args, offset=OFFSET, maps=MAPS, temperature=35.0)
    clamp = cmmpose.TemperaturePolicy(out_of_range="clamp")
    with pytest.warns(cmmpose.ClampWarning):
        held = reference_centre_reading(*args, offset=OFFSET, maps=MAPS, temperature=35.0, temperature_policy=clamp)
    at_edge = reference_centre_reading(*args, offset=OFFSET, maps=MAPS, temperature=30.0)
    np.testing.assert_array_equal(held.reading, at_edge.reading)
