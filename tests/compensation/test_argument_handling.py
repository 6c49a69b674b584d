"""Argument handling of cmmpose.compensate, cmmpose.uncompensated,
ErrorMap.position_error / rotation_error and Pose: shapes, dtypes, layouts,
NaN and out-of-range rows, options, temperatures."""

import functools
import re
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import cmmpose
from cmmpose import ErrorMap, ErrorMapSet, Pose

OFFSET = cmmpose.MountOffset.thesis()
POSE = Pose(30.0, 40.0, 20.0)
CHUNK = 4096  # rows per parallel work item in the Rust kernel
N_BIG = 3 * CHUNK + 123  # spans four chunks


@pytest.fixture(scope="module")
def thesis():
    return ErrorMapSet.thesis()


@pytest.fixture(scope="module")
def map20(thesis):
    return thesis.maps[0]


def points(n, seed=0):
    """``n`` points inside the thesis volume: uv (n, 2) and scales (n, 3), mm."""
    rng = np.random.default_rng(seed)
    uv = rng.uniform(-40.0, 40.0, (n, 2))
    scales = np.column_stack([rng.uniform(0, 900, n), rng.uniform(0, 550, n), rng.uniform(-500, 0, n)])
    return uv, scales


def temperatures(n, seed=1):
    return np.random.default_rng(seed).uniform(20.0, 30.0, n)


def message(exc_class, fn, *args, **kwargs):
    with pytest.raises(exc_class) as exc:
        fn(*args, **kwargs)
    return str(exc.value)


def has_row(msg, k):
    return re.search(rf"\brow {k}\b", msg) is not None


# -- shapes, lengths, non-numbers -----------------------------------------------------


@pytest.mark.parametrize("shape", [(5, 3), (10,), (5, 2, 1), (5, 1)])
def test_uv_of_wrong_shape(map20, shape):
    _, scales = points(5)
    uv = np.zeros(shape)
    for call in (
        lambda: cmmpose.compensate(uv, scales, map20, POSE, OFFSET),
        lambda: cmmpose.uncompensated(uv, scales, POSE, OFFSET),
    ):
        msg = message(cmmpose.InputError, call)
        assert msg.startswith("uv:") and str(shape) in msg


@pytest.mark.parametrize("shape", [(5, 2), (15,), (5, 3, 1), (5, 4)])
def test_scales_of_wrong_shape(map20, shape):
    uv, _ = points(5)
    scales = np.zeros(shape)
    for call in (
        lambda: cmmpose.compensate(uv, scales, map20, POSE, OFFSET),
        lambda: cmmpose.uncompensated(uv, scales, POSE, OFFSET),
        lambda: map20.position_error(scales),
        lambda: map20.rotation_error(scales),
    ):
        msg = message(cmmpose.InputError, call)
        assert msg.startswith("scales:") and str(shape) in msg


def test_mismatched_lengths_name_both_arguments(map20):
    uv, _ = points(5)
    _, scales = points(4)
    for call in (
        lambda: cmmpose.compensate(uv, scales, map20, POSE, OFFSET),
        lambda: cmmpose.uncompensated(uv, scales, POSE, OFFSET),
    ):
        msg = message(cmmpose.InputError, call)
        assert "uv" in msg and "scales" in msg and "5" in msg and "4" in msg


def test_strings_that_are_not_numbers(map20, thesis):
    uv, scales = points(2)
    cases = {
        "uv": lambda: cmmpose.compensate([["a", "b"], ["1", "2"]], scales, map20, POSE, OFFSET),
        "scales": lambda: cmmpose.compensate(uv, [["1", "2", "x"], ["1", "2", "3"]], map20, POSE, OFFSET),
        "temperature": lambda: cmmpose.compensate(uv, scales, thesis, POSE, OFFSET, temperature="warm"),
        "pose": lambda: cmmpose.compensate(uv, scales, map20, ("ninety", 0, 0), OFFSET),
        "offset": lambda: cmmpose.compensate(uv, scales, map20, POSE, ("1", "two", "3")),
    }
    for name, call in cases.items():
        assert message(cmmpose.InputError, call).startswith(f"{name}:")
    assert message(cmmpose.InputError, map20.position_error, [["1", "2", "x"]]).startswith("scales:")


# -- dtypes and memory layouts -------------------------------------------------------


def strided(a):
    """A non-contiguous view holding the values of ``a``."""
    big = np.full((2 * a.shape[0], a.shape[1] + 3), -1.0e9, dtype=a.dtype)
    big[::2, 1 : 1 + a.shape[1]] = a
    view = big[::2, 1 : 1 + a.shape[1]]
    assert not view.flags.c_contiguous and not view.flags.f_contiguous
    return view


LAYOUTS = {
    # name: (make the variant from float64 values, the float64 values it holds)
    "int64": (lambda a: np.round(a).astype(np.int64), lambda a: np.round(a)),
    "int32": (lambda a: np.round(a).astype(np.int32), lambda a: np.round(a)),
    "float32": (lambda a: a.astype(np.float32), lambda a: a.astype(np.float32).astype(np.float64)),
    "fortran": (np.asfortranarray, lambda a: a),
    "strided": (strided, lambda a: a),
    "list": (lambda a: a.tolist(), lambda a: a),
}


@pytest.mark.parametrize("layout", list(LAYOUTS))
def test_other_dtypes_and_layouts_give_the_float64_result(thesis, map20, layout):
    make, values = LAYOUTS[layout]
    uv, scales = points(500)
    temps = np.round(temperatures(500), 0) if "int" in layout else temperatures(500)
    uv64, scales64 = values(uv), values(scales)
    temps64 = values(temps[:, None])[:, 0]
    uv_v, scales_v = make(uv), make(scales)
    temps_v = make(temps[:, None])
    temps_v = temps_v[:, 0] if isinstance(temps_v, np.ndarray) else [t[0] for t in temps_v]

    def same(f):
        np.testing.assert_array_equal(f(uv_v, scales_v, temps_v), f(uv64, scales64, temps64))

    same(lambda u, s, t: cmmpose.compensate(u, s, map20, POSE, OFFSET))
    same(lambda u, s, t: cmmpose.compensate(u, s, thesis, POSE, OFFSET, temperature=t))
    same(lambda u, s, t: cmmpose.uncompensated(u, s, POSE, OFFSET))
    same(lambda u, s, t: map20.position_error(s))
    same(lambda u, s, t: map20.rotation_error(s))


def test_inputs_are_not_modified_nor_aliased(thesis, map20):
    uv, scales = points(1000)
    temps = temperatures(1000)
    before = [uv.copy(), scales.copy(), temps.copy()]
    outputs = [
        cmmpose.compensate(uv, scales, map20, POSE, OFFSET),
        cmmpose.compensate(uv, scales, thesis, POSE, OFFSET, temperature=temps),
        cmmpose.compensate(uv, scales, thesis, POSE, OFFSET, temperature=24.0),
        cmmpose.uncompensated(uv, scales, POSE, OFFSET),
        map20.position_error(scales),
        map20.rotation_error(scales),
    ]
    for a, b in zip((uv, scales, temps), before):
        np.testing.assert_array_equal(a, b)
    for out in outputs:
        for a in (uv, scales, temps):
            assert not np.shares_memory(out, a)
    # and an output is the caller's to change without touching the inputs
    outputs[0][:] = 0.0
    np.testing.assert_array_equal(scales, before[1])


# -- NaN rows --------------------------------------------------------------------------


def big_inputs():
    uv, scales = points(N_BIG)
    return uv, scales, temperatures(N_BIG)


def poison(arrays, argument, rows):
    uv, scales, temps = arrays
    for r in rows:
        if argument == "uv":
            uv[r, 1] = np.nan
        elif argument == "scales":
            scales[r, 2] = np.nan
        else:
            temps[r] = np.nan


@pytest.mark.parametrize("argument", ["uv", "scales", "temperature"])
@pytest.mark.parametrize("rows", [(5001, 9000), (9000, 5001), (5001, 5002), (8191, 8192), (12000, 6000)])
def test_nan_row_is_reported_by_argument_and_first_row(thesis, argument, rows):
    arrays = big_inputs()
    poison(arrays, argument, rows)
    uv, scales, temps = arrays
    first, second = min(rows), max(rows)
    msg = message(cmmpose.InputError, cmmpose.compensate, uv, scales, thesis, POSE, OFFSET, temperature=temps)
    assert msg.startswith(f"{argument}:") and has_row(msg, first) and not has_row(msg, second), msg


def test_nan_scalar_temperature(thesis):
    """A scalar temperature is every row's temperature: NaN raises naming the
    argument, and under nan_policy='propagate' gives NaN rows like a NaN
    per-point temperature does."""
    uv, scales = points(4)
    msg = message(cmmpose.InputError, cmmpose.compensate, uv, scales, thesis, POSE, OFFSET, temperature=np.nan)
    assert msg.startswith("temperature:")
    out = cmmpose.compensate(uv, scales, thesis, POSE, OFFSET, temperature=np.nan, nan_policy="propagate")
    assert out.shape == (4, 3) and np.isnan(out).all()


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_scales_in_error_functions(map20, bad):
    _, scales = points(N_BIG)
    scales[7777, 0] = bad
    scales[10000, 1] = bad
    for fn in (map20.position_error, map20.rotation_error):
        msg = message(cmmpose.InputError, fn, scales)
        assert msg.startswith("scales:") and has_row(msg, 7777) and not has_row(msg, 10000)


@pytest.mark.parametrize("argument", ["uv", "scales", "temperature"])
def test_nan_policy_propagate_gives_nan_in_exactly_those_rows(thesis, argument):
    arrays = big_inputs()
    bad = [5001, 9000]
    poison(arrays, argument, bad)
    uv, scales, temps = arrays
    out, report = cmmpose.compensate(
        uv, scales, thesis, POSE, OFFSET, temperature=temps, nan_policy="propagate", return_report=True
    )
    good = np.setdiff1d(np.arange(N_BIG), bad)
    assert np.isnan(out[bad]).all()
    assert np.isfinite(out[good]).all()
    assert report.nan_rows == 2 and report.points == N_BIG
    # the other rows are what they would be without the bad ones
    np.testing.assert_array_equal(
        out[good], cmmpose.compensate(uv[good], scales[good], thesis, POSE, OFFSET, temperature=temps[good])
    )


def test_nan_policy_propagate_in_other_functions(map20):
    uv, scales = points(N_BIG)
    scales[[5001, 9000], 1] = np.nan
    for out in (
        cmmpose.uncompensated(uv, scales, POSE, OFFSET, nan_policy="propagate"),
        map20.position_error(scales, nan_policy="propagate"),
        map20.rotation_error(scales, nan_policy="propagate").reshape(N_BIG, 9),
    ):
        assert np.isnan(out[[5001, 9000]]).all()
        assert np.isfinite(np.delete(out, [5001, 9000], axis=0)).all()


@pytest.mark.parametrize(("option", "value"), [("out_of_range", "extend"), ("nan_policy", "omit"),
                                               ("out_of_range", "Raise"), ("nan_policy", "")])
def test_bad_option_strings(thesis, map20, option, value):
    uv, scales = points(4)
    calls = [
        lambda: cmmpose.compensate(uv, scales, map20, POSE, OFFSET, **{option: value}),
        lambda: cmmpose.compensate(uv, scales, thesis, POSE, OFFSET, temperature=22.0, **{option: value}),
        lambda: map20.position_error(scales, **{option: value}),
        lambda: map20.rotation_error(scales, **{option: value}),
    ]
    if option == "nan_policy":
        calls.append(lambda: cmmpose.uncompensated(uv, scales, POSE, OFFSET, nan_policy=value))
    else:
        calls.append(lambda: thesis.at(22.0, out_of_range=value))
    for call in calls:
        msg = message(cmmpose.InputError, call)
        assert option in msg and repr(value)[1:-1] in msg


# -- scale readings outside the maps ----------------------------------------------------


@pytest.mark.parametrize(
    ("axis", "value", "span"),
    [(0, 900.5, "[0, 900]"), (0, -0.25, "[0, 900]"), (1, 550.125, "[0, 550]"), (1, -3.0, "[0, 550]"),
     (2, 0.5, "[-500, 0]"), (2, -512.0, "[-500, 0]")],
)
def test_scale_reading_outside_the_map_raises(thesis, map20, axis, value, span):
    uv, scales = points(N_BIG)
    scales[6000, axis] = value
    scales[9500, axis] = value
    letter = "XYZ"[axis]
    temps = temperatures(N_BIG)
    for call in (
        lambda: cmmpose.compensate(uv, scales, map20, POSE, OFFSET),
        lambda: cmmpose.compensate(uv, scales, thesis, POSE, OFFSET, temperature=temps),
        lambda: cmmpose.compensate(uv, scales, thesis, POSE, OFFSET, temperature=21.0),
        lambda: map20.position_error(scales),
        lambda: map20.rotation_error(scales),
    ):
        msg = message(cmmpose.OutOfRangeError, call)
        assert has_row(msg, 6000) and not has_row(msg, 9500), msg
        assert f"{letter} scale reading {value:g} mm" in msg and span in msg, msg


def clamp_case():
    """Points inside the volume except X out at 3 rows, Y at 2, Z at 4 (row 30 on X and Z)."""
    uv, scales = points(200)
    scales[[10, 20, 30], 0] = [905.0, -1.0, 1000.0]
    scales[[40, 50], 1] = [551.0, -0.5]
    scales[[30, 60, 70, 80], 2] = [0.25, -600.0, 3.0, -500.01]
    return uv, scales, (3, 2, 4)


def test_clamp_warns_and_counts_per_axis(thesis, map20):
    uv, scales, counts = clamp_case()
    temps = temperatures(len(scales))
    for kwargs, error_map in (({}, map20), ({"temperature": temps}, thesis), ({"temperature": 27.0}, thesis)):
        with pytest.warns(cmmpose.ClampWarning, match="3 X, 2 Y, 4 Z scale readings"):
            out, report = cmmpose.compensate(
                uv, scales, error_map, POSE, OFFSET, out_of_range="clamp", return_report=True, **kwargs
            )
        assert report.clamped_position == counts
        assert report.clamped_temperature == 0 and report.points == len(scales)
        assert np.isfinite(out).all()
    for fn in (map20.position_error, map20.rotation_error):
        with pytest.warns(cmmpose.ClampWarning, match="3 X, 2 Y, 4 Z scale readings"):
            fn(scales, out_of_range="clamp")


def test_no_clamp_warning_when_nothing_is_clamped(map20):
    uv, scales = points(200)
    with warnings.catch_warnings():
        warnings.simplefilter("error", cmmpose.ClampWarning)
        _, report = cmmpose.compensate(uv, scales, map20, POSE, OFFSET, out_of_range="clamp", return_report=True)
    assert report.clamped_position == (0, 0, 0) and report.clamped == 0


def clipped(scales):
    return np.column_stack([np.clip(scales[:, 0], 0, 900), np.clip(scales[:, 1], 0, 550), np.clip(scales[:, 2], -500, 0)])


def test_clamped_values_are_the_table_end_values(map20):
    _, scales, _ = clamp_case()
    # R(S) depends on the scale readings only through the tables.
    with pytest.warns(cmmpose.ClampWarning):
        rot = map20.rotation_error(scales, out_of_range="clamp")
    np.testing.assert_array_equal(rot, map20.rotation_error(clipped(scales)))
    # e(S) also has terms linear in E and F (squareness, Abbe offsets, eqs. 11-13);
    # without them (X and Y angles and squareness zero) it depends on the tables only.
    x, y = map20.table("X"), map20.table("Y")
    x[:, 4:] = 0.0
    y[:, 4:] = 0.0
    deltas_only = ErrorMap(x, y, map20.table("Z"), (0.0, 0.0, 0.0))
    with pytest.warns(cmmpose.ClampWarning):
        e = deltas_only.position_error(scales, out_of_range="clamp")
    np.testing.assert_array_equal(e, deltas_only.position_error(clipped(scales)))
    assert np.abs(e[[10, 20, 30, 40, 50]]).max() > 1e-3  # the end values are not zero


# -- temperatures ----------------------------------------------------------------------


def test_temperature_is_required_with_a_map_set(thesis):
    uv, scales = points(5)
    msg = message(cmmpose.InputError, cmmpose.compensate, uv, scales, thesis, POSE, OFFSET)
    assert msg.startswith("temperature:") and "required" in msg


@pytest.mark.parametrize("temperature", [22.0, np.full(5, 22.0)])
def test_temperature_with_a_single_map_is_refused(map20, temperature):
    uv, scales = points(5)
    msg = message(cmmpose.InputError, cmmpose.compensate, uv, scales, map20, POSE, OFFSET, temperature=temperature)
    assert msg.startswith("temperature:") and "ErrorMapSet" in msg


@pytest.mark.parametrize("n_temps", [4, 6, 0])
def test_per_point_temperatures_of_wrong_length(thesis, n_temps):
    uv, scales = points(5)
    msg = message(cmmpose.InputError, cmmpose.compensate, uv, scales, thesis, POSE, OFFSET,
                  temperature=np.full(n_temps, 22.0))
    assert msg.startswith("temperature:") and "(5,)" in msg and f"({n_temps},)" in msg


def test_per_point_temperature_outside_the_set_names_the_row(thesis):
    uv, scales = points(N_BIG)
    temps = temperatures(N_BIG)
    # Beyond the default 0.5 K tolerance (closer is held at the edge: cmmpose.policy).
    temps[7000] = 30.8
    temps[9001] = 19.0
    msg = message(cmmpose.OutOfRangeError, cmmpose.compensate, uv, scales, thesis, POSE, OFFSET, temperature=temps)
    assert has_row(msg, 7000) and not has_row(msg, 9001) and "30.8" in msg and "[20, 30]" in msg
    assert "0.800 K outside" in msg and "0.5 K tolerance" in msg and "'extrapolate' extends the maps" in msg


@pytest.mark.parametrize("t", [19.25, 30.8])
def test_scalar_temperature_outside_the_set_names_the_value(thesis, t):
    uv, scales = points(5)
    msg = message(cmmpose.OutOfRangeError, cmmpose.compensate, uv, scales, thesis, POSE, OFFSET, temperature=t)
    assert f"temperature {t:g} C" in msg and "[20, 30]" in msg


def test_temperature_clamp_uses_the_end_map(thesis):
    uv, scales = points(300)
    with pytest.warns(cmmpose.ClampWarning, match="300 temperatures"):
        out, report = cmmpose.compensate(uv, scales, thesis, POSE, OFFSET, temperature=np.full(300, 35.0),
                                         out_of_range="clamp", return_report=True)
    assert report.clamped_temperature == 300
    np.testing.assert_allclose(out, cmmpose.compensate(uv, scales, thesis.maps[2], POSE, OFFSET), rtol=0, atol=1e-12)


@pytest.mark.parametrize("t", [20.0, 21.3, 22.5, 25.0, 27.9, 30.0])
def test_scalar_temperature_equals_array_of_it(thesis, t):
    uv, scales = points(2000)
    scalar = cmmpose.compensate(uv, scales, thesis, POSE, OFFSET, temperature=t)
    array = cmmpose.compensate(uv, scales, thesis, POSE, OFFSET, temperature=np.full(2000, t))
    np.testing.assert_allclose(scalar, array, rtol=0, atol=1e-12)


def test_temperature_25_is_the_25_C_map(thesis):
    uv, scales = points(2000)
    m25 = thesis.maps[1]
    assert m25.temperature == 25.0
    expected = cmmpose.compensate(uv, scales, m25, POSE, OFFSET)
    for t in (25.0, 25, np.full(2000, 25.0)):
        np.testing.assert_allclose(cmmpose.compensate(uv, scales, thesis, POSE, OFFSET, temperature=t),
                                   expected, rtol=0, atol=1e-12)
    # and the 25 C map is not the 20 C map at these points
    assert np.abs(expected - cmmpose.compensate(uv, scales, thesis.maps[0], POSE, OFFSET)).max() > 1e-3


# -- Pose -------------------------------------------------------------------------------


def test_pose_normals_of_the_thesis_alignments():
    np.testing.assert_allclose(Pose(90, 90, 0).normal, [1.0, 0.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(Pose(180, 90, 0).normal, [0.0, 1.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(Pose(0, 0, 0).normal, [0.0, 0.0, 1.0], atol=1e-15)


def angle_difference(a, b):
    return abs((a - b + 180.0) % 360.0 - 180.0)


@settings(max_examples=300, deadline=None)
@given(
    alpha=st.floats(-180.0, 180.0),
    beta=st.floats(0.5, 179.5),
    gamma=st.floats(-360.0, 360.0),
    length=st.floats(1e-3, 1e3),
)
def test_from_normal_recovers_alpha_and_beta(alpha, beta, gamma, length):
    a, b = np.radians(alpha), np.radians(beta)
    normal = length * np.array([np.sin(a) * np.sin(b), -np.cos(a) * np.sin(b), np.cos(b)])
    pose = Pose.from_normal(normal, gamma)
    assert angle_difference(pose.alpha, alpha) < 1e-8
    assert pose.beta == pytest.approx(beta, abs=1e-8)
    assert pose.gamma == gamma
    np.testing.assert_allclose(pose.normal, normal / length, atol=1e-12)


@pytest.mark.parametrize("signs", [(sx, sy, sz) for sx in (1, -1) for sy in (1, -1) for sz in (1, -1)])
def test_from_normal_in_every_octant(signs):
    normal = np.array(signs, dtype=float) * [0.3, 0.5, 0.8]
    pose = Pose.from_normal(normal)
    np.testing.assert_allclose(pose.normal, normal / np.linalg.norm(normal), atol=1e-14)


def test_from_zero_normal_is_a_geometry_error():
    with pytest.raises(cmmpose.GeometryError, match="normal"):
        Pose.from_normal((0.0, 0.0, 0.0))


@pytest.mark.parametrize("angles", [(np.nan, 0, 0), (0, np.inf, 0), (0, 0, -np.inf)])
def test_non_finite_pose_is_an_input_error(angles):
    with pytest.raises(cmmpose.InputError, match="pose"):
        Pose(*angles)


# -- no points ----------------------------------------------------------------------------


def test_zero_points(thesis, map20):
    uv, scales = np.zeros((0, 2)), np.zeros((0, 3))
    assert cmmpose.compensate(uv, scales, map20, POSE, OFFSET).shape == (0, 3)
    assert cmmpose.compensate(uv, scales, thesis, POSE, OFFSET, temperature=22.0).shape == (0, 3)
    assert cmmpose.compensate(uv, scales, thesis, POSE, OFFSET, temperature=np.zeros(0)).shape == (0, 3)
    assert cmmpose.uncompensated(uv, scales, POSE, OFFSET).shape == (0, 3)
    assert map20.position_error(scales).shape == (0, 3)
    assert map20.rotation_error(scales).shape == (0, 3, 3)
    _, report = cmmpose.compensate(uv, scales, map20, POSE, OFFSET, return_report=True)
    assert report.points == 0


# -- properties -----------------------------------------------------------------------------

point = st.tuples(
    st.floats(-60.0, 60.0), st.floats(-60.0, 60.0),  # u, v
    st.floats(0.0, 900.0), st.floats(0.0, 550.0), st.floats(-500.0, 0.0),  # D, E, F
)
angle = st.floats(-180.0, 180.0)


@settings(max_examples=200, deadline=None)
@given(rows=st.lists(point, min_size=1, max_size=50), pose=st.tuples(angle, angle, angle))
def test_zero_map_compensation_is_uncompensated(rows, pose):
    data = np.array(rows)
    uv, scales = data[:, :2], data[:, 2:]
    np.testing.assert_array_equal(
        cmmpose.compensate(uv, scales, ErrorMap.zero(), pose, OFFSET), cmmpose.uncompensated(uv, scales, pose, OFFSET)
    )


# Largest correction the thesis maps can make in the volume, term by term (eqs. 11-13):
# E * S_xy <= 550 mm * 178 a-s = 0.475 mm, dx(X) <= 0.141 mm (30 C), F * S_zx <= 500 mm * 42 a-s
# = 0.102 mm, F * (ey(X) + ey(Y)) <= 0.084 mm, rotation of the ~300 mm lever <= 0.07 mm.
# The largest found over all grid nodes, 20..30 C, random poses and u, v = +-60 mm is
# about 0.64 mm (near (900, 550, 0) at 30 C), so 0.5 mm would be too tight.
MAX_CORRECTION_MM = 0.75


@functools.cache
def cached_thesis():
    return ErrorMapSet.thesis()


@settings(max_examples=200, deadline=None)
@given(rows=st.lists(point, min_size=1, max_size=50), pose=st.tuples(angle, angle, angle),
       t=st.floats(20.0, 30.0))
def test_thesis_correction_is_small(rows, pose, t):
    s = cached_thesis()
    data = np.array(rows)
    uv, scales = data[:, :2], data[:, 2:]
    plain = cmmpose.uncompensated(uv, scales, pose, OFFSET)
    for temperature in (t, np.full(len(rows), t)):
        shift = np.linalg.norm(cmmpose.compensate(uv, scales, s, pose, OFFSET, temperature=temperature) - plain, axis=1)
        assert shift.max() < MAX_CORRECTION_MM
