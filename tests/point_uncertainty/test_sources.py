"""Each compensated point's uncertainty through the Python API
(cmmpose.point_uncertainty): the same points as plain compensation, the
standard uncertainties against an independent reference (each source moved
alone through the plain kernel), the sources switched off one by one, and
bad sources refused by name."""

import pickle
from dataclasses import replace

import numpy as np
import pytest

import cmmpose
from cmmpose import ErrorMap, ErrorMapSet, InputError
from cmmpose.model import Model
from cmmpose.point_uncertainty import (SOURCES, MapUncertainty, PoseUncertainty, UncertainPoints,
                                       UncertaintySources, covariance_matrices)

POSE = (90.0, 90.0, 0.0)
OFFSET = (1.001, 264.505, 129.575)


@pytest.fixture(scope="module")
def points():
    rng = np.random.default_rng(3)
    n = 400
    uv = np.c_[rng.uniform(-30, 30, n), rng.uniform(110, 170, n)]
    scales = np.c_[rng.uniform(300, 500, n), rng.uniform(100, 400, n), rng.uniform(-400, -100, n)]
    t = rng.uniform(20.5, 29.5, n)
    return uv, scales, t


def close(got, ref, rel=1e-4):
    """Each point's u within ``rel`` of its largest component: the model is linear but for the angles, whose
    second-order terms (the map's own angles, ~1e-5 rad, times the change) are ~1e-5 of a point's largest
    sensitivity, whatever the CPU."""
    scale = np.max(np.abs(ref), axis=1, keepdims=True)
    assert np.all(np.abs(got - ref) <= rel * scale), float(np.max(np.abs(got - ref) / scale))


def moved_set(maps, f):
    """The set with every map's tables changed by ``f(tables)`` in place."""
    out = []
    for one in maps.maps:
        tables = [one.table(c).copy() for c in "XYZ"]
        f(tables)
        out.append(ErrorMap(*tables, one.squareness, one.temperature))
    return ErrorMapSet(out)


def test_points_are_the_plain_compensations_bits(points):
    uv, scales, t = points
    maps = ErrorMapSet.thesis()
    plain = cmmpose.compensate(uv, scales, maps, POSE, OFFSET, t)
    got = cmmpose.compensate(uv, scales, maps, POSE, OFFSET, t, uncertainty=True, uncertainty_detail="split")
    assert isinstance(got, UncertainPoints)
    np.testing.assert_array_equal(got.xyz, plain)
    # The standard uncertainties are the covariance's diagonal; the common part is all of it without noise.
    np.testing.assert_allclose(got.u ** 2, got.covariance[:, :3], rtol=1e-13)
    np.testing.assert_array_equal(got.common, got.covariance)
    assert np.all(np.linalg.eigvalsh(covariance_matrices(got.covariance)) >= -1e-20)


def test_map_sources_match_each_source_moved_alone_through_the_kernel(points):
    """Reference: one plain kernel pass per stated map source (a component moved by one table unit, each axis's
    positioning by 1 ppm from its start), the changes times the stated uncertainties summed in quadrature. The
    model is linear in positions; the angles' second-order terms are ~1e-5 relative, so 1e-4 holds on any CPU."""
    uv, scales, t = points
    maps = ErrorMapSet.thesis()
    m = MapUncertainty(position_um=((0.5, 0.2, 0.3), (0.1, 0.4, 0.2), (0.3, 0.3, 0.6)),
                       rotation_arcsec=((0.2, 0.3, 0.1), (0.1, 0.5, 0.2), (0.4, 0.1, 0.3)),
                       squareness_arcsec=(0.5, 0.7, 0.9), positioning_ppm=(2.5, 1.0, 3.0))
    got = cmmpose.compensate(uv, scales, maps, POSE, OFFSET, t, uncertainty=UncertaintySources(map=m))
    base = cmmpose.compensate(uv, scales, maps, POSE, OFFSET, t)
    var = np.zeros_like(base)
    for k in range(3):
        for j in range(6):
            u = m.position_um[k][j] if j < 3 else m.rotation_arcsec[k][j - 3]

            def bump(tables, k=k, j=j):
                tables[k][:, 1 + j] += 1.0
            var += np.square((cmmpose.compensate(uv, scales, moved_set(maps, bump), POSE, OFFSET, t) - base) * u)

        def ppm(tables, k=k):
            tables[k][:, 1 + k] += (tables[k][:, 0] - tables[k][0, 0]) * 1e-3
        var += np.square((cmmpose.compensate(uv, scales, moved_set(maps, ppm), POSE, OFFSET, t) - base)
                         * m.positioning_ppm[k])
    for j in range(3):
        sq = []
        for one in maps.maps:
            s = list(one.squareness)
            s[j] += 1.0
            sq.append(ErrorMap(*[one.table(c) for c in "XYZ"], s, one.temperature))
        var += np.square((cmmpose.compensate(uv, scales, ErrorMapSet(sq), POSE, OFFSET, t) - base)
                         * m.squareness_arcsec[j])
    close(got.u, np.sqrt(var))


def test_temperature_and_pose_sources_match_the_kernel_moved_by_them(points):
    uv, scales, t = points
    maps = ErrorMapSet.thesis()
    base = cmmpose.compensate(uv, scales, maps, POSE, OFFSET, t)
    got = cmmpose.compensate(uv, scales, maps, POSE, OFFSET, t,
                             uncertainty=UncertaintySources(temperature_k=0.3).without("map"))
    ref = np.abs(cmmpose.compensate(uv, scales, maps, POSE, OFFSET, t + 0.01) - base) / 0.01 * 0.3
    close(got.u, ref)
    cov = np.diag([0.04, 0.03, 0.05]) ** 2
    got = cmmpose.compensate(uv, scales, maps, POSE, OFFSET, t,
                             uncertainty=UncertaintySources(pose=PoseUncertainty(offset_covariance_mm2=cov)).without("map"))
    var = sum(np.square((cmmpose.compensate(uv, scales, maps, POSE, np.add(OFFSET, np.eye(3)[k] * 1e-3), t) - base)
                        / 1e-3 * np.sqrt(cov[k, k])) for k in range(3))
    close(got.u, np.sqrt(var))


def test_each_source_switched_off_lowers_the_budget_and_noise_is_independent(points):
    uv, scales, t = points
    maps = ErrorMapSet.thesis()
    src = UncertaintySources(temperature_k=0.2, scanner_scale_ppm=50, scanner_noise_um=(9, 4),
                             pose=PoseUncertainty(np.eye(3) * 0.04 ** 2, np.eye(3) * 1e-4))
    full = cmmpose.compensate(uv, scales, maps, POSE, OFFSET, t, uncertainty=src, uncertainty_detail="split")
    total = np.sum(full.covariance[:, :3])
    for name in ("map", "temperature", "scanner_scale", "scanner_noise", "pose"):
        less = cmmpose.compensate(uv, scales, maps, POSE, OFFSET, t, uncertainty=src.without(name),
                                  uncertainty_detail="split")
        assert np.sum(less.covariance[:, :3]) < total, name
        np.testing.assert_array_equal(less.xyz, full.xyz)
    # The independent part is the noise alone, the same at every point of the pose: E diag(su^2, sv^2, 0) E^T.
    ind = full.independent
    np.testing.assert_allclose(ind, np.broadcast_to(ind[0], ind.shape), rtol=1e-9, atol=1e-18)
    assert np.isclose(ind[0, :3].sum(), (0.009 ** 2 + 0.004 ** 2), rtol=1e-9)
    with pytest.raises(InputError, match="no source of uncertainty is stated.*switched off: map"):
        cmmpose.compensate(uv, scales, maps, POSE, OFFSET, t, uncertainty=src.without(*SOURCES))


def test_a_single_map_has_no_thermal_sensitivity_and_states_nothing_by_default(points):
    uv, scales, _ = points
    m = ErrorMap.appendix_b()
    assert m.stated_uncertainty is None
    with pytest.raises(InputError, match="every u would be 0"):  # a temperature moves nothing through one map
        cmmpose.compensate(uv, scales, m, POSE, OFFSET, uncertainty=UncertaintySources(temperature_k=1.0))
    stated = m.with_uncertainty(MapUncertainty.thesis())
    got = cmmpose.compensate(uv, scales, stated, POSE, OFFSET, uncertainty=True)
    assert np.all(got.u > 0)
    with pytest.raises(InputError, match="temperature: only meaningful"):
        cmmpose.compensate(uv, scales, stated, POSE, OFFSET, 20.0, uncertainty=True)


def test_nan_rows_propagate_to_their_uncertainty(points):
    uv, scales, t = points
    uv = uv.copy()
    uv[5] = np.nan
    got = cmmpose.compensate(uv, scales, ErrorMapSet.thesis(), POSE, OFFSET, t, uncertainty=True,
                             nan_policy="propagate")
    assert np.isnan(got.u[5]).all() and np.isfinite(np.delete(got.u, 5, axis=0)).all()
    with pytest.raises(InputError, match="row 5"):
        cmmpose.compensate(uv, scales, ErrorMapSet.thesis(), POSE, OFFSET, t, uncertainty=True)


@pytest.mark.parametrize("kwargs, match", [
    (dict(position_um=((-1, 0, 0), (0, 0, 0), (0, 0, 0))), r"position_um\[x\]\[0\]: -1 um is not"),
    (dict(rotation_arcsec=((0, float("nan"), 0), (0, 0, 0), (0, 0, 0))), r"rotation_arcsec\[x\]\[1\]"),
    (dict(squareness_arcsec=(0, 0, 1e30)), r"squareness_arcsec\[2\]: 1e\+30 arcsec is beyond"),
    (dict(positioning_ppm=(0, float("inf"), 0)), r"positioning_ppm\[1\]"),
    (dict(position_um=((0, 0), (0, 0, 0), (0, 0, 0))), r"position_um\[x\]: expected 3 values"),
])
def test_bad_map_uncertainties_are_refused_by_key(kwargs, match):
    with pytest.raises(InputError, match=match):
        MapUncertainty(**kwargs)


def test_from_dict_names_the_document_and_key():
    with pytest.raises(InputError, match=r"m\.toml: \[uncertainty\]\.squareness_arcsec\[0\]"):
        MapUncertainty.from_dict({"squareness_arcsec": [-2, 0, 0]}, "m.toml: [uncertainty]")
    with pytest.raises(InputError, match="unknown key.*rotations"):
        MapUncertainty.from_dict({"rotations": 1}, "m.toml: [uncertainty]")
    m = MapUncertainty.thesis()
    assert MapUncertainty.from_dict(m.to_dict()) == m


@pytest.mark.parametrize("cov, match", [
    ([[1e-4, 2e-4, 0], [2e-4, 1e-4, 0], [0, 0, 1e-4]], "not positive semi-definite"),
    ([[1e-4, 1e-5, 0], [0, 1e-4, 0], [0, 0, 1e-4]], "not symmetric"),
    ([[np.nan, 0, 0], [0, 1, 0], [0, 0, 1]], "not finite"),
    ([[1e9, 0, 0], [0, 1, 0], [0, 0, 1]], "beyond"),
    ([[1, 0], [0, 1]], "3 x 3"),
])
def test_bad_pose_covariances_are_refused(cov, match):
    with pytest.raises(InputError, match=match):
        PoseUncertainty(offset_covariance_mm2=cov)


@pytest.mark.parametrize("kwargs, match", [
    (dict(temperature_k=-0.1), "temperature_k"),
    (dict(temperature_k=1e9), "temperature_k.*beyond"),
    (dict(scanner_noise_um=(1, 2, 3)), "scanner_noise_um"),
    (dict(scanner_scale_ppm=float("nan")), "scanner_scale_ppm"),
    (dict(off=("maps",)), "unknown source.*maps"),
])
def test_bad_sources_are_refused(kwargs, match):
    with pytest.raises(InputError, match=match):
        UncertaintySources(**kwargs)


def test_sources_pickle_and_a_wrong_detail_or_pose_count_is_refused(points):
    uv, scales, t = points
    src = UncertaintySources(temperature_k=0.2, pose=[PoseUncertainty(), PoseUncertainty()])
    assert pickle.loads(pickle.dumps(src)) == src
    with pytest.raises(InputError, match="2 pose uncertainties for 1 poses"):
        cmmpose.compensate(uv, scales, ErrorMapSet.thesis(), POSE, OFFSET, t, uncertainty=src)
    with pytest.raises(InputError, match="detail"):
        cmmpose.compensate(uv, scales, ErrorMapSet.thesis(), POSE, OFFSET, t, uncertainty=True,
                           uncertainty_detail="full")
    with pytest.raises(InputError, match="out:"):
        cmmpose.compensate(uv, scales, ErrorMapSet.thesis(), POSE, OFFSET, t, uncertainty=True,
                           out=np.empty((len(uv), 3)))


@pytest.mark.filterwarnings("ignore::cmmpose.errors.ModelDomainWarning")  # a correction as uncertain as itself
def test_a_models_parameter_covariance_adds_j_c_jt(points):
    """A found model's squareness with stated uncertainties: the points' added variance is J C J^T, J from the
    model moved by one arc-second per parameter (exactly linear in squareness: 1e-9 relative)."""
    uv, scales, t = points
    maps = ErrorMapSet.thesis()
    values = np.array([7.0, -4.0, 3.0])
    cov = np.array([[4.0, 1.0, 0.0], [1.0, 2.0, 0.5], [0.0, 0.5, 3.0]])  # arc-second^2
    model = Model(maps).with_values("squareness", values)
    names = [f"squareness.{p}" for p in model.effects[0][0].params]
    model = replace(model, uncertainty={"squareness": np.sqrt(np.diag(cov))},
                    covariance={"parameters": names, "matrix": cov.tolist()})
    base = cmmpose.compensate(uv, scales, model, POSE, OFFSET, t)
    J = np.stack([cmmpose.compensate(uv, scales, model.with_values("squareness", values + np.eye(3)[k]), POSE, OFFSET,
                                     t) - base for k in range(3)], axis=2)
    want = np.einsum("mik,kl,mil->mi", J, cov, J)
    only = UncertaintySources().without("map")
    got = cmmpose.compensate(uv, scales, model, POSE, OFFSET, t, uncertainty=only, uncertainty_detail="covariance")
    np.testing.assert_array_equal(got.xyz, base)
    np.testing.assert_allclose(got.u ** 2, want, rtol=1e-6, atol=1e-18)
    with pytest.raises(InputError, match="every u would be 0"):
        cmmpose.compensate(uv, scales, model, POSE, OFFSET, t, uncertainty=only.without("model"))


def test_a_map_file_states_its_uncertainty_and_reads_back(tmp_path):
    m = ErrorMap.appendix_b().with_uncertainty(MapUncertainty.thesis())
    m.write(tmp_path / "m.csv")
    back = ErrorMap.read(tmp_path / "m.csv")
    assert back.stated_uncertainty == m.stated_uncertainty and back == m
    text = (tmp_path / "m.csv").read_text()
    bad = text.replace('"positioning_ppm": [2.5', '"positioning_ppm": [-2.5')
    (tmp_path / "bad.csv").write_text(bad)
    with pytest.raises(cmmpose.MapError, match=r"bad\.csv:\d+: uncertainty\.positioning_ppm\[0\]"):
        ErrorMap.read(tmp_path / "bad.csv")
    line = next(ln for ln in text.splitlines() if ln.startswith("# uncertainty:"))
    repeated = text.replace(line, line[:-1] + ', "source": "again"}')
    (tmp_path / "rep.csv").write_text(repeated)
    with pytest.raises(cmmpose.MapError, match="source repeated"):
        ErrorMap.read(tmp_path / "rep.csv")


def _machine_text(extra: str) -> str:
    from cmmpose.machine import example_text
    return example_text("thesis") + "\n" + extra


def test_a_machine_file_states_its_maps_uncertainty(tmp_path):
    from cmmpose.machine import load_machine
    path = tmp_path / "m.toml"
    path.write_text(_machine_text('[uncertainty]\nposition_um = [[0.5, 0.5, 0.5], [0.5, 0.5, 0.5], [0.5, 0.5, 0.5]]\n'
                                  'positioning_ppm = [1.0, 1.0, 1.0]\nsource = "certificate 123"\n'))
    machine = load_machine(path)
    assert machine.map_uncertainty.source == "certificate 123"
    maps = machine.maps()
    assert maps.stated_uncertainty == machine.map_uncertainty
    assert all(m.stated_uncertainty == machine.map_uncertainty for m in maps.maps)
    # Maps named apart are taken as they state themselves.
    assert machine.maps(("appendix-b",)).stated_uncertainty is None


@pytest.mark.parametrize("table, match", [
    ("squareness_arcsec = [1.0, 1e30, 0.0]", r"uncertainty\.squareness_arcsec\[1\]"),
    ("positioning_ppm = [-1.0, 0.0, 0.0]", r"uncertainty\.positioning_ppm\[0\]"),
    ("rotation_arcsec = [[0.1, 0.1], [0.1, 0.1, 0.1], [0.1, 0.1, 0.1]]", r"uncertainty\.rotation_arcsec\[0\]"),
    ("position = 1.0", r"uncertainty.*position"),
])
def test_a_machine_files_bad_uncertainty_is_refused_by_key(tmp_path, table, match):
    from cmmpose.machine import load_machine
    path = tmp_path / "m.toml"
    path.write_text(_machine_text("[uncertainty]\n" + table + "\n"))
    with pytest.raises(InputError, match=match) as info:
        load_machine(path)
    assert "m.toml" in str(info.value)
