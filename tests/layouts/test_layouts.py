"""Ballbar layouts (cmmpose.layouts): the B89 positions of thesis Appendix C,
the crossed-ballbar squareness test of section 6.2, and digitizer poses."""

import numpy as np
import pytest

from cmmpose import InputError, Pose
from cmmpose import layouts as lay

R = lay.BALL_RADIUS_MM
LO = np.array([r[0] for r in lay.TRAVEL_MM])
HI = np.array([r[1] for r in lay.TRAVEL_MM])


@pytest.fixture(scope="module")
def b89():
    return lay.b89_positions()


@pytest.fixture(scope="module")
def appendix():
    return lay.appendix_c_centres("compensated")


def all_balls(positions):
    return np.array([p.balls for p in positions]).reshape(-1, 3)


# -- Appendix C access -----------------------------------------------------------------------


def test_appendix_c_centres_and_lengths_shapes():
    for state in ("compensated", "uncompensated"):
        c = lay.appendix_c_centres(state)
        assert c.shape == (20, 2, 3) and np.all(np.isfinite(c))
        L = lay.appendix_c_lengths(state)
        assert L.shape == (20,) and np.all(np.isfinite(L))
    assert lay.appendix_c_centres("compensated")[0, 0].tolist() == [-496.5355, -134.2546, 27.7874]
    assert lay.appendix_c_lengths("uncompensated")[1] == 404.3593
    with pytest.raises(InputError):
        lay.appendix_c_centres("raw")


# -- B89 layout ------------------------------------------------------------------------------


def test_twenty_positions_numbered_as_in_the_thesis(b89):
    assert [p.position for p in b89] == list(range(1, 21))


def test_constant_length(b89):
    for p in b89:
        assert abs(p.length - lay.B89_LENGTH_MM) < 1e-10
    assert lay.B89_LENGTH_MM == 404.2357
    for p in lay.b89_positions(length=300.0):
        assert abs(p.length - 300.0) < 1e-10


def test_directions_match_appendix_c(b89, appendix):
    for p, (b1, b2) in zip(b89, appendix):
        d = (b2 - b1) / np.linalg.norm(b2 - b1)
        np.testing.assert_allclose(p.direction, d, rtol=0, atol=1e-9)


def test_midpoints_are_appendix_c_midpoints_plus_translation(b89, appendix):
    shift = np.array(lay.B89_CENTRE_MM) - lay.appendix_c_bbox_centre()
    for p, (b1, b2) in zip(b89, appendix):
        np.testing.assert_allclose(p.midpoint, (b1 + b2) / 2 + shift, rtol=0, atol=1e-9)
    # a different length leaves the midpoints where they are
    for p, q in zip(b89, lay.b89_positions(length=350.0)):
        np.testing.assert_allclose(p.midpoint, q.midpoint, rtol=0, atol=1e-9)


def test_bounding_box_centre_maps_to_centre(appendix):
    c = (1.0, 2.0, 3.0)
    shift = np.array(c) - lay.appendix_c_bbox_centre()
    flat = appendix.reshape(-1, 3) + shift
    np.testing.assert_allclose((flat.min(0) + flat.max(0)) / 2, c, atol=1e-9)
    for p, (b1, b2) in zip(lay.b89_positions(centre=c), appendix):
        np.testing.assert_allclose(p.midpoint, (b1 + b2) / 2 + shift, atol=1e-9)


def test_balls_inside_the_travel(b89):
    balls = all_balls(b89)
    # X and Z: a full ball radius inside the scale ranges
    for ax in (0, 2):
        assert balls[:, ax].min() >= LO[ax] + R and balls[:, ax].max() <= HI[ax] - R
    # Y: the layout is 476.5 mm wide, so two radii (76.25 mm) cannot fit in 550 mm;
    # the default centres it, leaving the same margin (36.7 mm) on both sides.
    span_y = np.ptp(lay.appendix_c_centres().reshape(-1, 3)[:, 1])
    assert span_y + 2 * R > HI[1] - LO[1]
    lo_margin, hi_margin = balls[:, 1].min() - LO[1], HI[1] - balls[:, 1].max()
    assert min(lo_margin, hi_margin) > 36.7
    assert abs(lo_margin - hi_margin) < 0.01


def test_reachable_centre_keeps_every_sweep_inside_the_travel():
    positions = lay.b89_positions(centre=lay.B89_REACHABLE_CENTRE_MM)
    readings = np.array([lay.sweep_readings(b, (90.0, 90.0, 0.0)) for p in positions for b in p.balls])
    assert readings.shape == (40, 2, 3)
    assert np.all(readings >= LO + 35.0) and np.all(readings <= HI - 35.0)


def test_positions_14_and_18_are_the_same_bar(b89):
    assert np.array_equal(b89[13].balls, b89[17].balls)
    assert b89[13] != b89[17]  # different position numbers


def test_bad_arguments():
    with pytest.raises(InputError):
        lay.b89_positions(length=-1.0)
    with pytest.raises(InputError):
        lay.b89_positions(centre=(1.0, 2.0))
    with pytest.raises(InputError):
        lay.crossed_ballbar_positions(centres=[(0.0, 0.0, 0.0)])


# -- BallbarPosition -------------------------------------------------------------------------


def test_ballbar_position_value_semantics():
    p = lay.BallbarPosition(3, [0, 0, 0], [3, 4, 0])
    assert p.length == 5.0
    np.testing.assert_array_equal(p.direction, [0.6, 0.8, 0.0])
    np.testing.assert_array_equal(p.midpoint, [1.5, 2.0, 0.0])
    assert p == lay.BallbarPosition(3, (0.0, 0.0, 0.0), (3.0, 4.0, 0.0))
    assert hash(p) == hash(lay.BallbarPosition(3, (0.0, 0.0, 0.0), (3.0, 4.0, 0.0)))
    assert p.ball1.dtype == np.float64 and not p.ball1.flags.writeable
    with pytest.raises(AttributeError):
        p.position = 4
    with pytest.raises(InputError):
        lay.BallbarPosition(1, [1, 2, 3], [1, 2, 3])
    with pytest.raises(InputError):
        lay.BallbarPosition(1, [1, 2, np.nan], [1, 2, 3])


# -- crossed ballbars ------------------------------------------------------------------------


@pytest.fixture(scope="module")
def crossed():
    return lay.crossed_ballbar_positions()


def test_crossed_layout_has_eight_positions(crossed):
    assert [p.position for p in crossed] == list(range(1, 9))
    assert lay.CROSSED_W_AXES == ("X",) * 4 + ("Y",) * 4
    for p in crossed:
        assert abs(p.length - lay.B89_LENGTH_MM) < 1e-10
        assert abs(p.direction[2]) < 1e-15  # horizontal


def test_crossed_geometry(crossed):
    # 5-8 repeat 1-4 (same bars, other digitizer orientation)
    for k in range(4):
        assert np.array_equal(crossed[k].balls, crossed[k + 4].balls)
    # each pair crosses at right angles at a common midpoint
    for a, b in ((0, 1), (2, 3)):
        np.testing.assert_allclose(crossed[a].midpoint, crossed[b].midpoint, atol=1e-12)
        assert abs(crossed[a].direction @ crossed[b].direction) < 1e-15
    # 1 and 3 (long in the thesis) share a diagonal, as do 2 and 4 (short)
    np.testing.assert_allclose(crossed[0].direction, [np.sqrt(0.5), np.sqrt(0.5), 0], atol=1e-15)
    np.testing.assert_allclose(crossed[0].direction, crossed[2].direction, atol=1e-15)
    np.testing.assert_allclose(crossed[1].direction, crossed[3].direction, atol=1e-15)
    # position 1 near home: its ball 1 is the ball nearest the origin of X, Y
    near = np.linalg.norm(all_balls(crossed)[:, :2], axis=1).min()
    assert np.linalg.norm(crossed[0].ball1[:2]) == near


def test_crossed_balls_inside_the_travel_and_reachable(crossed):
    balls = all_balls(crossed)
    assert np.all(balls >= LO + R) and np.all(balls <= HI - R)
    for p, w in zip(crossed, lay.CROSSED_W_AXES):
        pose = lay.digitizer_pose_for(p, w)
        assert pose == ((90.0, 90.0, 0.0) if w == "X" else (180.0, 90.0, 0.0))  # thesis: gamma = 0
        for b in p.balls:
            s = lay.sweep_readings(b, pose)
            assert np.all(s >= LO) and np.all(s <= HI)


# -- digitizer poses -------------------------------------------------------------------------


def test_e313_is_the_package_pose_matrix():
    for angles in [(90, 90, 0), (90, 90, -60), (180, 90, 45), (0, -90, 0), (12.5, 33.0, -71.0)]:
        np.testing.assert_allclose(lay._e313(*angles), Pose(*angles).matrix(), atol=1e-15)


def test_thesis_printed_w_along_y_pose_looks_up():
    # line 1615 prints (0, -90, 0) for W along Y: W is +Y, but v (part -> sensor) is -Z.
    m = lay._e313(0, -90, 0)
    np.testing.assert_allclose(m[:, 2], [0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(m[:, 1], [0, 0, -1], atol=1e-15)
    np.testing.assert_allclose(lay._e313(180, 90, 0)[:, 1], [0, 0, 1], atol=1e-15)


AXES = {"X": [1, 0, 0], "Y": [0, 1, 0], "-X": [-1, 0, 0], "-Y": [0, -1, 0]}


@pytest.mark.parametrize("w_axis", list(AXES))
@pytest.mark.parametrize("rule", ["view_across_bar", "scan_across_bar"])
def test_poses_are_valid_rotations_following_the_rule(b89, crossed, w_axis, rule):
    for p in b89 + crossed:
        alpha, beta, gamma = lay.digitizer_pose_for(p, w_axis, rule=rule)
        m = Pose(alpha, beta, gamma).matrix()
        np.testing.assert_allclose(m.T @ m, np.eye(3), atol=1e-12)
        assert abs(np.linalg.det(m) - 1.0) < 1e-12
        np.testing.assert_allclose(m[:, 2], AXES[w_axis], atol=1e-12)
        assert gamma % 15 == 0 and -90 <= gamma <= 90
        assert m[2, 1] >= -1e-12  # v never points down
        d = p.direction
        proj = np.hypot(m[:, 0] @ d, m[:, 1] @ d)
        if proj > np.sin(np.radians(15)):
            along = m[:, 1] if rule == "view_across_bar" else m[:, 0]
            # perpendicular to the projected bar up to the 15 degree index (7.5 deg)
            assert abs(along @ d) <= proj * np.sin(np.radians(7.5)) + 1e-12
        else:
            assert gamma == 0


def test_pose_rule_examples(b89):
    gammas = [lay.digitizer_pose_for(p)[2] for p in b89]
    # horizontal bars (1, 2, 11-18) are scanned from above, vertical ones (19, 20)
    # from the side, the diagonals in between
    for k in (1, 2, 11, 12, 13, 14, 15, 16, 17, 18):
        assert gammas[k - 1] == 0
    for k in (5, 6, 19, 20):
        assert abs(gammas[k - 1]) == 90
    for k in (3, 4, 7, 8, 9, 10):
        assert abs(gammas[k - 1]) == 45
    # exact angles without indexing
    p = lay.BallbarPosition(1, [0, 0, 0], [0, np.cos(np.radians(30)), -np.sin(np.radians(30))])
    assert lay.digitizer_pose_for(p, step=None)[2] == pytest.approx(-30.0, abs=1e-12)
    assert lay.digitizer_pose_for(p)[2] == -30.0
    assert lay.digitizer_pose_for(p, rule="scan_across_bar", step=None)[2] == pytest.approx(60.0, abs=1e-12)


def test_side_view_faces_the_travel_centre():
    vertical = lay.BallbarPosition(1, [450, 100, -400], [450, 100, -100])
    g = lay.digitizer_pose_for(vertical)[2]
    v = Pose(90, 90, g).matrix()[:, 1]
    np.testing.assert_allclose(v, [0, 1, 0], atol=1e-12)  # sensor on the +Y side, towards Y = 275
    g = lay.digitizer_pose_for(vertical, travel_centre=(450, 0, -250))[2]
    np.testing.assert_allclose(Pose(90, 90, g).matrix()[:, 1], [0, -1, 0], atol=1e-12)


def test_pose_bad_arguments(b89):
    with pytest.raises(InputError):
        lay.digitizer_pose_for(b89[0], "Z")
    with pytest.raises(InputError):
        lay.digitizer_pose_for(b89[0], rule="best")
    with pytest.raises(InputError):
        lay.digitizer_pose_for((0, 0, 0))


def test_sweep_readings_put_the_ball_top_at_the_laser_origin():
    ball = np.array([400.0, 275.0, -350.0])
    s = lay.sweep_readings(ball, (90, 90, 0))
    # pose (90, 90, 0): X_H = (D - W1, E + u - U1, F + v - V1), sweep along X
    np.testing.assert_allclose(s[:, 1], 275.0 + 1.001)
    np.testing.assert_allclose(s[:, 2], -350.0 + R + 264.505)
    np.testing.assert_allclose(sorted(s[:, 0]), [400 + 129.575 - R, 400 + 129.575 + R])
