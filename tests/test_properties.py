"""Property tests (hypothesis) of compensate and the readers: for any valid
input, the result is finite, agrees with the independent NumPy reference,
leaves the inputs unchanged, and files read back exactly what was written."""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

import cmmpose
import numpy_reference as ref
from cmmpose.pointfiles import read_points

MAPS = cmmpose.ErrorMapSet.thesis()
DICTS = [{"temperature": m.temperature, "squareness": m.squareness, **{a: m.table(a) for a in "XYZ"}}
         for m in MAPS.maps]
OFFSET = (1.001, 264.505, 129.575)
SETTINGS = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def floats(lo, hi):
    return st.floats(lo, hi, allow_nan=False, allow_infinity=False)


@st.composite
def point_sets(draw):
    n = draw(st.integers(0, 40))
    uv = draw(arrays(np.float64, (n, 2), elements=floats(-30, 30)))
    scales = np.column_stack([draw(arrays(np.float64, n, elements=floats(lo, hi)))
                              for lo, hi in ((0, 900), (0, 550), (-500, 0))]).reshape(n, 3)
    t = draw(arrays(np.float64, n, elements=floats(20, 30)))
    pose = (draw(floats(-180, 180)), draw(floats(0, 180)), draw(floats(-180, 180)))
    return uv, scales, t, pose


@SETTINGS
@given(point_sets())
def test_compensate_agrees_with_the_numpy_reference_and_leaves_inputs_alone(case):
    uv, scales, t, pose = case
    before = (uv.copy(), scales.copy(), t.copy())
    got = cmmpose.compensate(uv, scales, MAPS, pose, OFFSET, t)
    assert got.shape == (len(uv), 3) and np.all(np.isfinite(got))
    # Same equations, other summation order: rounding only (< 1e-9 mm).
    np.testing.assert_allclose(got, ref.compensate(uv, scales, DICTS, pose, OFFSET, t), rtol=0, atol=1e-9)
    for a, b in zip((uv, scales, t), before):
        np.testing.assert_array_equal(a, b)


@SETTINGS
@given(point_sets(), st.sampled_from([".csv", ".npy"]), st.booleans())
def test_point_files_read_back_what_was_written(tmp_path_factory, case, suffix, with_t):
    uv, scales, t, _ = case
    p = tmp_path_factory.mktemp("pts") / f"p{suffix}"
    data = np.column_stack([uv, scales] + ([t] if with_t else []))
    if suffix == ".npy":
        np.save(p, data)
    else:
        cols = ["u", "v", "D", "E", "F"] + (["T"] if with_t else [])
        p.write_text(",".join(cols) + "\n" + "".join(",".join(repr(float(x)) for x in row) + "\n" for row in data))
    uv2, s2, t2 = read_points(p)
    np.testing.assert_array_equal(uv2, uv)
    np.testing.assert_array_equal(s2, scales)
    assert (t2 is None) == (not with_t)
    if with_t:
        np.testing.assert_array_equal(t2, t)


@SETTINGS
@given(st.lists(floats(-50, 50), min_size=18, max_size=18), floats(-200, 200), floats(10, 40))
def test_maps_read_back_what_was_written(tmp_path_factory, values, sq, temperature):
    rows = []
    for a, (lo, hi) in enumerate(((0, 900), (0, 550), (-500, 0))):
        pos = np.linspace(lo, hi, 3)
        tab = np.column_stack([pos] + [np.array(values[6 * a:6 * a + 6][k:k + 1] * 3) for k in range(6)])
        rows.append(tab)
    m = cmmpose.ErrorMap(*rows, squareness=(sq, -sq / 2, sq / 3), temperature=temperature)
    p = tmp_path_factory.mktemp("maps") / "m.csv"
    m.write(p)
    back = cmmpose.ErrorMap.read(p)
    for a in "XYZ":
        np.testing.assert_array_equal(back.table(a), m.table(a))
    assert back.squareness == m.squareness and back.temperature == m.temperature
