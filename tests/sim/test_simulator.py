"""The simulator: noise-free round trips through the truth machine and the
compensation, the eq. 30 sign, and each effect alone doing what it should."""

import numpy as np
import pytest

import cmmpose
from cmmpose import sim

import numpy_reference as nr

MAPS = cmmpose.ErrorMapSet.thesis()
OFFSET = np.array(cmmpose.MountOffset.thesis())
QUIET = sim.Scanner(noise=0.0, points_per_profile=256)
POSE_X = (90.0, 90.0, 0.0)  # W along +X: v = +Z, u = +Y


def ball_sweep(centre, pose=POSE_X, direction=1, axis="X", speed=10.0):
    """A sweep along ``axis`` that carries the scan plane across the ball at ``centre``:
    mid-sweep the laser origin sits on the ball where +v leaves it."""
    e = cmmpose.Pose(*pose).matrix()
    laser_origin = np.asarray(centre, float) + e[:, 1] * sim.BALL_RADIUS
    start = laser_origin + e @ OFFSET  # P = L + E313 l1 on a perfect machine
    start["XYZ".index(axis)] -= direction * 45.0
    return sim.Sweep(start=tuple(start), axis=axis, length=90.0, speed=speed, direction=direction)


def scan(machine, centre=(400, 275, -350), pose=POSE_X, temperature=22.5, scanner=QUIET, **kw):
    return sim.simulate_sweep(machine, sim.Sphere(centre), pose, OFFSET, ball_sweep(centre, pose, **kw), temperature,
                              scanner=scanner, rng=7)


@pytest.mark.parametrize("temperature", [20.0, 22.5, 25.0, 28.1, 30.0])
@pytest.mark.parametrize("centre", [(150, 80, -450), (400, 275, -350), (700, 480, -320)])
def test_noise_free_round_trip_within_0_05_um(temperature, centre):
    d = scan(sim.TruthMachine(MAPS), centre=centre, temperature=temperature)
    assert len(d.t) > 1000
    xyz = cmmpose.compensate(d.uv, d.scales, MAPS, POSE_X, OFFSET, temperature)
    assert np.abs(xyz - d.true_xyz).max() < 5e-5
    # uncompensated is off by tens to hundreds of micrometres
    assert np.abs(cmmpose.uncompensated(d.uv, d.scales, POSE_X, OFFSET) - d.true_xyz).max() > 0.02


@pytest.mark.parametrize("pose", [(90.0, 90.0, 30.0), (90.0, 80.0, -20.0)])
def test_round_trip_other_poses_and_a_temperature_drift(pose):
    drift = sim.temperature_series([0.0, 20.0], [21.0, 23.5])
    d = sim.simulate_sweep(sim.TruthMachine(MAPS), sim.Sphere((400, 275, -350)), pose, OFFSET,
                           ball_sweep((400, 275, -350), pose), drift, scanner=QUIET, rng=1)
    assert len(d.t) > 200
    xyz = cmmpose.compensate(d.uv, d.scales, MAPS, pose, OFFSET, d.temperatures["temperature"])
    assert np.abs(xyz - d.true_xyz).max() < 5e-5


def printed_eq30_compensation(dmap, uv, scales, pose):
    """Compensation with X_p as printed in eq. 30: (1, -tan eZ, -(tan eX tan eZ + tan eY)) / norm."""
    eps = sum(nr.interpolate_carriage(dmap[a], scales[:, k])[:, 3:] for k, a in enumerate("XYZ"))
    tx, ty, tz = np.tan(eps).T
    zp = np.stack([ty, -tx, np.ones_like(tx)], 1)
    xp = np.stack([np.ones_like(tx), -tz, -(tx * tz + ty)], 1)
    zp /= np.linalg.norm(zp, axis=1, keepdims=True)
    xp /= np.linalg.norm(xp, axis=1, keepdims=True)
    r = np.stack([xp, np.cross(zp, xp), zp], 2)
    lever = (np.column_stack([uv, np.zeros(len(uv))]) - OFFSET) @ nr.euler313(*pose).T
    return scales + nr.position_error(dmap, scales) + np.einsum("nij,nj->ni", r, lever)


def test_eq30_printed_sign_fails_the_round_trip_by_micrometres():
    m = MAPS.maps[0]
    dmap = {"temperature": 20.0, "squareness": m.squareness, **{c: m.table(c) for c in "XYZ"}}
    ours, theirs = [], []
    for centre in [(150, 480, -320), (400, 275, -350), (700, 80, -450), (700, 480, -320)]:
        d = scan(sim.TruthMachine(MAPS), centre=centre, temperature=20.0)
        ours.append(np.abs(cmmpose.compensate(d.uv, d.scales, m, POSE_X, OFFSET) - d.true_xyz).max())
        theirs.append(np.abs(printed_eq30_compensation(dmap, d.uv, d.scales, POSE_X) - d.true_xyz).max())
    # Right-handed X_p: second-order remainder only. Printed: 2 eps_Z x lever, micrometres
    # where the thesis map's total yaw is largest.
    assert max(ours) < 5e-5 and max(theirs) > 2e-3, (ours, theirs)


# --- each effect alone ---------------------------------------------------------------------

def residual(effect, temperature=22.5, **kw):
    """Compensated minus true points with the effect on; the model knows only the maps."""
    d = scan(sim.TruthMachine(MAPS, [effect]), temperature=temperature, **kw)
    return d, cmmpose.compensate(d.uv, d.scales, MAPS, POSE_X, OFFSET, temperature) - d.true_xyz


def test_no_effect_no_residual():
    _, res = residual(sim.Scale())
    assert np.abs(res).max() < 5e-5


def test_latency_shifts_along_the_sweep_and_flips_with_direction():
    tau, speed = 0.01, 10.0
    d, fwd = residual(sim.Latency(seconds=tau), direction=1, speed=speed)
    _, rev = residual(sim.Latency(seconds=tau), direction=-1, speed=speed)
    # The recorded reading lags the profile by speed*tau along X: points shift by
    # -dir*speed*tau. The map is also read 0.1 mm off, which changes its errors by
    # about 1e-5 mm (slope of the map times 0.1 mm): hence 2e-5.
    np.testing.assert_allclose(fwd[:, 0], -speed * tau, atol=2e-5)
    np.testing.assert_allclose(rev[:, 0], speed * tau, atol=2e-5)
    assert np.abs(fwd[:, 1:]).max() < 2e-5 and np.abs(rev[:, 1:]).max() < 2e-5


def test_scale_error_grows_with_the_reading_on_its_axis_only():
    d, res = residual(sim.Scale(y=10.0))
    np.testing.assert_allclose(res[:, 1], -10e-6 * d.scales[:, 1], atol=1e-6)
    assert np.abs(res[:, [0, 2]]).max() < 1e-6


def test_squareness_offset_is_a_shear():
    d, res = residual(sim.Squareness(xy=5.0))
    s = 5.0 * np.pi / 648000
    np.testing.assert_allclose(res[:, 0], s * d.scales[:, 1], atol=1e-6)  # model lacks -E dS: comp - true = +E dS
    assert np.abs(res[:, 1:]).max() < 1e-6


def test_unmeasured_z_roll_turns_the_digitizer_lever():
    d, res = residual(sim.Roll(z=20.0))
    angle = 20.0 * np.pi / 648000 * d.scales[:, 2] / 1000
    lever = (np.column_stack([d.uv, np.zeros(len(d.uv))]) - OFFSET) @ cmmpose.Pose(*POSE_X).matrix().T
    # true point rotated by +angle about Z; the model misses it: comp - true = -(Rz - I) lever
    expect = -np.column_stack([-angle * lever[:, 1], angle * lever[:, 0], np.zeros(len(angle))])
    np.testing.assert_allclose(res, expect, atol=2e-6)


def test_axis_temperature_equals_maps_at_the_other_temperature():
    d, res = residual(sim.AxisTemperature(x=1.0, y=1.0, z=1.0), temperature=22.5)
    # Every carriage's table at 23.5 C, and squareness at the thermocouples'
    # machine mean, which the offsets raise to 23.5 C too.
    hot, mean = MAPS.at(23.5), MAPS.at(22.5)
    truth_model = cmmpose.ErrorMap(*(hot.table(c) for c in "XYZ"), hot.squareness)
    want = cmmpose.compensate(d.uv, d.scales, mean, POSE_X, OFFSET) - cmmpose.compensate(d.uv, d.scales, truth_model, POSE_X, OFFSET)
    # res - want is the noise-free round-trip remainder of the truth machine (< 0.05 um).
    np.testing.assert_allclose(res, want, atol=5e-5)
    assert np.abs(res).max() > 1e-3


def test_granite_gradient_changes_yz_and_zx_squareness():
    d, res = residual(sim.GraniteGradient(kelvin=1.0, xy=0.0, yz=10.0, zx=0.0))
    s = 10.0 * np.pi / 648000
    np.testing.assert_allclose(res[:, 1], s * d.scales[:, 2], atol=1e-6)
    assert np.abs(res[:, [0, 2]]).max() < 1e-6


def test_scanner_scale_scales_u_and_v():
    d, res = residual(sim.ScannerScale(depth=1e-3))
    # v is +Z for this pose: reported v too large by 1e-3 v
    # (R - I) turns the 1e-3 v error by the map angles (~5e-5 rad): a few nm off-axis.
    np.testing.assert_allclose(res[:, 2], 1e-3 * d.uv[:, 1] / (1 + 1e-3), atol=5e-6)
    assert np.abs(res[:, :2]).max() < 5e-6


def test_incidence_error_grows_with_angle():
    d, res = residual(sim.Incidence(per_degree=0.0005))
    centre = np.array([400, 275, -350.0])
    n = (d.true_xyz - centre) / np.linalg.norm(d.true_xyz - centre, axis=1, keepdims=True)
    theta = np.degrees(np.arccos(np.clip(n[:, 2], -1, 1)))
    np.testing.assert_allclose(res[:, 2], 0.0005 * theta, atol=5e-6)
    assert np.abs(res[:, 2]).max() > 0.02  # up to 70 degrees x 0.5 um


def test_alignment_and_mount_offset_errors():
    _, res = residual(sim.MountOffset(v1=0.04))
    # v1 is along +Z here; the model uses the old l1. (R - I) dl adds ~5e-5 x 0.04 mm.
    np.testing.assert_allclose(res[:, 2], 0.04, atol=5e-6)
    assert np.abs(res[:, :2]).max() < 5e-6
    d, res = residual(sim.Alignment(gamma=0.05))
    assert np.abs(res).max() > 1e-3  # a rotation about w = X of the lever


@pytest.mark.parametrize("text, cls", [("latency:seconds=0.01", sim.Latency), ("scale:x=3,y=4", sim.Scale),
                                       ("roll", sim.Roll)])
def test_parse_effect(text, cls):
    assert isinstance(sim.parse_effect(text), cls)


@pytest.mark.parametrize("text, fragment", [("nope", "unknown"), ("scale:w=3", "not one of"), ("scale:x=abc", "not a number")])
def test_parse_effect_errors(text, fragment):
    with pytest.raises(cmmpose.InputError, match=fragment):
        sim.parse_effect(text)


def test_bad_sim_inputs():
    with pytest.raises(cmmpose.InputError, match="axis"):
        sim.Sweep(start=(0, 0, 0), axis="W")
    with pytest.raises(cmmpose.InputError, match="direction"):
        sim.Sweep(start=(0, 0, 0), direction=2)
    with pytest.raises(cmmpose.InputError, match="radius"):
        sim.Sphere((0, 0, 0), radius=-1)
    with pytest.raises(cmmpose.InputError, match="finite"):
        sim.Scale(x=float("nan"))
    with pytest.raises(cmmpose.InputError, match="max_incidence_deg"):
        scan(sim.TruthMachine(MAPS), scanner=sim.Scanner(max_incidence=95))
    with pytest.raises(cmmpose.InputError, match="outside the maps"):
        scan(sim.TruthMachine(MAPS), temperature=35.0)


# --- thermocouple log ------------------------------------------------------------------------

def test_thermocouple_log_channels_offsets_and_faults():
    log = sim.thermocouple_log(600.0, 21.0, rate=2.0, axis_offsets=(0.5, 0.0, -0.3), granite_gradient=1.0,
                               noise=0.0, faults=(sim.Fault("Y2", "stuck", at=100.0), sim.Fault("GB", "open", at=300.0)), rng=3)
    assert set(log) == {"t"} | {c for c, _ in sim.CHANNELS} and len(log["t"]) == 1201
    np.testing.assert_allclose(log["X1"], 21.5)
    np.testing.assert_allclose(log["Z3"], 20.7)
    np.testing.assert_allclose(log["GT"], 21.5)
    assert np.all(log["GB"][log["t"] >= 300] == sim.OPEN_CIRCUIT_READING)
    assert np.all(log["GB"][log["t"] < 300] == 20.5)
    assert np.ptp(log["Y2"][log["t"] >= 100]) == 0.0


def test_thermocouple_log_follows_a_drifting_room_with_noise():
    room = sim.temperature_series([0.0, 3600.0], [20.0, 22.0])
    log = sim.thermocouple_log(3600.0, room, rate=1.0, noise=0.02, drift=0.1, rng=4)
    mean_scales = np.mean([log[c] for c, r in sim.CHANNELS if r.endswith("scale")], axis=0)
    assert abs(mean_scales[-1] - 22.0) < 0.15 and abs(mean_scales[0] - 20.0) < 0.05
    assert 0.01 < np.std(log["X1"] - room(log["t"])) < 0.1


def test_thermocouple_log_bad_arguments():
    with pytest.raises(cmmpose.InputError, match="channel"):
        sim.Fault("Q9", "open")
    with pytest.raises(cmmpose.InputError, match="kind"):
        sim.Fault("X1", "melted")
    with pytest.raises(cmmpose.InputError, match="positive"):
        sim.thermocouple_log(0.0, 20.0)
