"""The mount-expansion effect (added in one commit: one Python file, one Rust
term): the mount offset l1 scales by 1 + alpha (T_mount - 20 C), with T_mount
from a thermocouple of role 'mount'. The simulator switches it on, the model
inverts it, and the diagnosis finds it on a run at several poses while the
mount warms."""

from __future__ import annotations

import numpy as np
import pytest

import cmmpose
from cmmpose import effects
from cmmpose.calibration import STANDARD_POSES
from cmmpose.model import LIBRARY, Model
from cmmpose.run import CHANNEL_ROLES, Run
from cmmpose.sim.runs import simulate_ballbar_run
from cmmpose.sim.scanner import Scanner

MAPS = cmmpose.ErrorMapSet.thesis()
SCANNER = Scanner(points_per_profile=256)
TRUTH = 23.0  # ppm/K, an aluminium bracket
WARM = "mount-expansion:ppm_per_kelvin=23,kelvin=3,kelvin_per_hour=60"
# The reference sphere twice at each standard pose: scans minutes apart, so
# the warming mount shifts each pose's points differently over the run
# (a constant mount-offset error cannot do that).
POSES = list(STANDARD_POSES) * 2


def simulate(effect_list, seed=11, poses=POSES):
    return simulate_ballbar_run(temperature=22.5, effects=effect_list, jitter=0.0015, seed=seed, scanner=SCANNER,
                                reference_poses=poses)


@pytest.fixture(scope="module")
def warm():
    return simulate([effects.parse(WARM)])


def test_registered_everywhere():
    cls = effects.get("mount-expansion")
    assert cls.acts == "kernel" and "mount" in CHANNEL_ROLES
    assert "mount-expansion" in LIBRARY and LIBRARY["mount-expansion"].needs == ("mount_temperature",)
    assert "mount-expansion" in [t["name"] for t in cmmpose._core.effect_terms()]


def test_simulator_logs_the_mount_and_moves_the_points(warm, tmp_path):
    run, truth = warm
    mt = [c for c in run.temperature_channels if c["role"] == "mount"]
    assert [c["name"] for c in mt] == ["MT"]
    t = np.asarray(run.temperatures["t"])
    # Machine mean 22.5 C + 3 K + 60 K/h, read with 0.02 K of noise.
    np.testing.assert_allclose(run.temperatures["MT"], 25.5 + 60 * t / 3600, atol=0.1)
    clean, clean_truth = simulate([])
    assert "MT" not in clean.temperatures
    # Same seed, same sweeps: only the laser origin moved, by l1 alpha dT
    # (264.5 mm x 23e-6 x 5.5..19 K = 33..116 um).
    shift = np.linalg.norm(truth[0]["true_xyz"][:1000] - clean_truth[0]["true_xyz"][:1000], axis=1)
    assert np.all(shift > 0)
    run.save(tmp_path / "r")
    back = Run.load(tmp_path / "r")
    assert [c["role"] for c in back.temperature_channels][-1] == "mount"


def test_model_inverts_the_simulated_expansion(warm):
    run, truth = warm
    base = Model(MAPS)
    with_it = base.with_values("mount-expansion", [TRUTH])
    err0 = np.linalg.norm(base.compensate(run) - truth[0]["true_xyz"], axis=1)
    err1 = np.linalg.norm(with_it.compensate(run) - truth[0]["true_xyz"], axis=1)
    # What is left is the scanner noise (8 um in v) and the per-scan jitter.
    assert np.sqrt(np.mean(err1 ** 2)) < 0.012 < np.sqrt(np.mean(err0 ** 2))


def test_diagnosis_finds_it_on_a_run_at_several_poses_with_the_mount_warm(warm):
    run, _ = warm
    d = cmmpose.diagnose(run, MAPS, patterns=False, max_effects=2)
    assert d.added[0] == "mount-expansion"
    fitted = d.steps[1].model.values("mount-expansion")[0]
    assert abs(fitted - TRUTH) < 0.1 * TRUTH, fitted
    # Once it is in the model the constant mount-offset error explains nothing more.
    assert "mount-offset" not in d.added


def test_a_run_without_a_mount_thermocouple_says_what_to_add():
    run, _ = simulate([], poses=STANDARD_POSES[:2])
    d = cmmpose.diagnose(run, MAPS, patterns=False, max_effects=0)
    assert "mount-expansion" in d.unobservable
    assert "role 'mount'" in d.unobservable["mount-expansion"]
