"""Sanity checks that keep a fixed-radius sphere fit, the E3125 distances and
diagnose-fits from answering nonsense silently: a scan in metres read as mm,
a wrong radius, an unsegmented raw scan, a distance off its reference by a
unit factor, a reference length in metres, a radius column of diameters."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
from click.testing import CliRunner
import cmmpose
from cmmpose.cli import main
from cmmpose.diagnosis.spheres import (
    RADIUS_FRACTION,
    REFERENCE_LENGTH_FRACTION,
    appendix_c_sphere_fits,
    diagnose_sphere_fits,
)
from cmmpose.errors import GeometryError, ImplausibleFit, InputError
from cmmpose.fitting import (
    MAX_RMS_FRACTION,
    RADIUS_MISFIT_FRACTION,
    RADIUS_MISFIT_RMS_RATIO,
    e3125,
    fit_sphere,
    segment_sphere,
)
from cmmpose.formats.pointclouds import read_point_cloud
from cmmpose.standards.e3125_distances import (
    GROSS_ERROR_FRACTION,
    SphereTarget,
    distance_errors,
    sphere_targets,
)
from repo import REPO

NIST = REPO / "data" / "nist_dmg"
R = 50.0  # the NIST spheres' calibrated radius, mm


@pytest.fixture(scope="module")
def scan_mm():
    return read_point_cloud(NIST / "SPH101.xyz", units="m").xyz


@pytest.fixture(scope="module")
def scan_as_read():
    """The same scan with its metres taken for mm (the forgotten --units m)."""
    return read_point_cloud(NIST / "SPH101.xyz").xyz


def _cap(n=4000, radius=R, half_angle=60.0, noise=0.0, seed=1):
    rng = np.random.default_rng(seed)
    cos_t = rng.uniform(np.cos(np.radians(half_angle)), 1.0, n)
    phi = rng.uniform(0, 2 * np.pi, n)
    sin_t = np.sqrt(1 - cos_t**2)
    u = np.column_stack([sin_t * np.cos(phi), sin_t * np.sin(phi), cos_t])
    return np.array([10.0, -20.0, 300.0]) + (radius + rng.normal(0, noise, n))[:, None] * u


def _implausible(caught):
    return [str(w.message) for w in caught if issubclass(w.category, ImplausibleFit)]


# -- defect 06: fixed-radius fits --------------------------------------------------------------------------------


def test_segmentation_of_a_scan_in_metres_is_refused_naming_the_unit(scan_as_read):
    with pytest.raises(GeometryError, match=r"polar coverage .* below .*2 deg.*look like metres") as info:
        e3125(scan_as_read, R)
    assert info.value.what == "units" and info.value.value == "m"


def test_fixed_radius_fit_of_a_scan_in_metres_names_the_unit(scan_as_read):
    with pytest.raises(GeometryError, match="look like metres") as info:
        fit_sphere(scan_as_read, R)
    assert info.value.value == "m"


def test_right_radius_on_every_nist_scan_gives_no_warning():
    for k in range(101, 106):
        pts = read_point_cloud(NIST / f"SPH{k}.xyz", units="m").xyz
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            res = e3125(pts, R)
        assert not _implausible(caught), k
        assert res.polar_coverage > 50


def test_wrong_radius_warns_with_the_free_radius(scan_mm):
    with pytest.warns(ImplausibleFit, match=r"fixed radius 25 mm misfits.*free-radius fit .* gives 50\.\d"):
        e3125(scan_mm, 25.0)


def test_diameter_for_radius_is_named():
    pts = _cap(noise=0.02)
    with pytest.warns(ImplausibleFit, match="a diameter"):
        fit_sphere(pts, 2 * R)


def test_unsegmented_raw_scan_warns(scan_mm):
    with pytest.warns(ImplausibleFit, match=r"% of the 50 mm radius .*do not lie on one sphere"):
        fit_sphere(scan_mm, R)


def test_thresholds_follow_their_definitions():
    """A radius error just inside the 2 % gives no warning even though it
    inflates the rms; one well beyond both thresholds does (noise 0.1 mm)."""
    pts = _cap(noise=0.1)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        f = fit_sphere(pts, R * (1 + 0.5 * RADIUS_MISFIT_FRACTION))
    assert not _implausible(caught)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        f = fit_sphere(pts, R * 1.1)
    free = fit_sphere(pts[f.inlier])
    assert f.rms > RADIUS_MISFIT_RMS_RATIO * free.rms  # what the rule measures, from its own pieces
    assert _implausible(caught)
    with warnings.catch_warnings(record=True) as caught:  # scatter of 12 % of the radius, right radius
        warnings.simplefilter("always")
        fit_sphere(_cap(noise=1.2 * MAX_RMS_FRACTION * R, seed=3), R)
    assert any("do not lie on one sphere" in m for m in _implausible(caught))


def test_segment_sphere_keeps_min_coverage_option(scan_as_read):
    # min_coverage below the sliver's cap lets it through (with whatever warnings it earns).
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        s = segment_sphere(scan_as_read, R, min_coverage=0.0)
    assert s.fit.polar_coverage < 2


def test_cli_fit_puts_the_warning_in_the_json():
    r = CliRunner().invoke(main, ["fit", str(NIST / "SPH101.xyz"), "--units", "m", "--radius", "25", "--segment",
                                  "e3125", "--json"])
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout[r.stdout.index("{"):])
    assert any("misfits" in w for w in out["warnings"])


def test_cli_fit_in_metres_names_units_flag():
    r = CliRunner().invoke(main, ["fit", str(NIST / "SPH101.xyz"), "--radius", "50", "--segment", "e3125"])
    assert r.exit_code != 0
    assert "--units m" in r.output


def test_e3125_distances_refuse_a_unit_mix_up():
    t = {"a": SphereTarget("a", np.zeros(3), np.eye(3) * 1e-6, 100),
         "b": SphereTarget("b", np.array([3.2714, 0, 0]), np.eye(3) * 1e-6, 100)}  # centres in metres
    with pytest.raises(InputError, match=r"pairs\[0\] \(a - b\).*% off .*metres read as mm"):
        distance_errors(t, [("a", "b", 3271.43, 0.0)])
    # within GROSS_ERROR_FRACTION: judged as before
    t["b"] = SphereTarget("b", np.array([3271.43 * (1 + 0.5 * GROSS_ERROR_FRACTION), 0, 0]), np.eye(3) * 1e-6, 100)
    assert distance_errors(t, [("a", "b", 3271.43, 0.0)]).errors[0].error_um > 0


def test_e3125_distances_name_the_target(scan_as_read):
    with pytest.raises(GeometryError, match=r"target 'a': .*metres"):
        sphere_targets({"a": scan_as_read}, R)


# -- defect 10: diagnose-fits -------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def fits():
    return appendix_c_sphere_fits("compensated")


def test_reference_length_in_metres_is_refused(fits):
    with pytest.raises(InputError, match=r"reference_length: .*in m, not mm") as info:
        diagnose_sphere_fits(fits["centres"], fits["radii"], reference_length=0.4042)
    assert info.value.cli_option == "--reference-length"
    with pytest.raises(InputError, match="reference_length"):
        diagnose_sphere_fits(fits["centres"], fits["radii"], reference_length=500.0)


def test_reference_length_within_tolerance_is_used_and_reported(fits):
    d = diagnose_sphere_fits(fits["centres"], fits["radii"], reference_length=404.2)
    mean = float(np.mean(d.lengths))
    assert abs(404.2 - mean) < REFERENCE_LENGTH_FRACTION * mean
    assert d.mean_deviation_um == pytest.approx((mean - 404.2) * 1e3, abs=1e-6)
    assert d.to_dict()["mean_length_deviation_um"] == pytest.approx(d.mean_deviation_um)


def test_radius_column_of_diameters_is_refused(fits):
    with pytest.raises(InputError, match="diameters") as info:
        diagnose_sphere_fits(fits["centres"], 2 * fits["radii"], nominal_radius=38.125)
    assert info.value.column == "radius_mm"
    with pytest.raises(InputError, match="nominal radius a diameter"):
        diagnose_sphere_fits(fits["centres"], fits["radii"], nominal_radius=76.25)
    with pytest.raises(InputError, match=r"over 5 %"):
        diagnose_sphere_fits(fits["centres"], fits["radii"] * (1 + 2 * RADIUS_FRACTION), nominal_radius=38.125)
    diagnose_sphere_fits(fits["centres"], fits["radii"], nominal_radius=38.125)  # the thesis's own: accepted


def test_cli_diagnose_fits_summary_and_json_agree():
    run = CliRunner()
    table = run.invoke(main, ["diagnose-fits", "appendix-c", "--reference-length", "404.2"])
    js = run.invoke(main, ["diagnose-fits", "appendix-c", "--reference-length", "404.2", "--json"])
    assert table.exit_code == 0 and js.exit_code == 0
    d = json.loads(js.stdout)
    assert f"{d['mean_length_deviation_um']:+.2f} um" in table.stdout
    bad = run.invoke(main, ["diagnose-fits", "appendix-c", "--reference-length", "0.4042", "--json"])
    assert bad.exit_code != 0 and "--reference-length" in bad.output


def test_fit_spheres_refuses_labels_that_are_not_finite():
    # NaN != NaN: every NaN-labelled point became a "sphere" of its own (300 groups of one point).
    rng = np.random.default_rng(1)
    u = rng.normal(size=(600, 3))
    u /= np.linalg.norm(u, axis=1)[:, None]
    u[:, 2] = abs(u[:, 2])
    pts = 12.7 * u + np.repeat([[0.0, 0, 0], [100.0, 0, 0]], 300, axis=0)
    labels = np.r_[np.full(300, np.nan), np.ones(300)]
    for on_error in ("raise", "return"):
        with pytest.raises(cmmpose.InputError, match=r"labels: row 0 is nan; every point needs a finite label "
                                                     r"\(300 of 600 are not\)"):
            cmmpose.fit_spheres(pts, labels, on_error=on_error)
    assert len(cmmpose.fit_spheres(pts, np.r_[np.zeros(300), np.ones(300)]).labels) == 2
