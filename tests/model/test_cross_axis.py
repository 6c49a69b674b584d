"""Issue 33, section 6: errors that vary with two axes together, as model terms (cmmpose.model.crossaxis):
the shapes against a NumPy reference, the name round trip through a model file, held beyond the trained
travel, and bad names refused. (The diagnosis finding one: tests/diagnosis/test_out_of_sample.py.)"""

from __future__ import annotations

import numpy as np
import pytest

import cmmpose
from cmmpose.errors import InputError
from cmmpose.model import Model
from cmmpose.model.crossaxis import make_cross, parse_cross
from cmmpose.model.names import resolve

MAPS = cmmpose.ErrorMapSet.thesis()
POSE, OFFSET = (90.0, 90.0, 0.0), (1.001, 264.505, 129.575)


def _points(n=500, seed=2):
    rng = np.random.default_rng(seed)
    uv = np.column_stack([rng.uniform(-25, 25, n), rng.uniform(115, 165, n)])
    scales = np.column_stack([rng.uniform(10, 890, n), rng.uniform(10, 540, n), rng.uniform(-490, -10, n)])
    return uv, scales


def test_the_shapes_against_a_numpy_reference():
    uv, scales = _points()
    twist = make_cross(2, (0, 1), "twist", ((100.0, 800.0), (50.0, 500.0)))
    sag = make_cross(1, (0, 2), "sag", ((100.0, 800.0), (-450.0, -50.0)))
    model = Model(MAPS).with_values(twist, [12.0]).with_values(sag, [-4.0, 6.0])
    D, E, F = (np.clip(scales[:, 0], 100, 800), np.clip(scales[:, 1], 50, 500), np.clip(scales[:, 2], -450, -50))
    tx, ty, tz = (2 * D - 900) / 700, (2 * E - 550) / 450, (2 * F + 500) / 400
    p2 = lambda t: 1.5 * t * t - 0.5  # noqa: E731
    want = np.zeros((len(D), 3))
    want[:, 2] = 12.0 * tx * ty * 1e-3
    want[:, 1] = (-4.0 * p2(tx) * tz + 6.0 * tx * p2(tz)) * 1e-3
    got = cmmpose.compensate(uv, scales, model, POSE, OFFSET, 22.0) - cmmpose.compensate(uv, scales, MAPS, POSE,
                                                                                           OFFSET, 22.0)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)  # mm: added after the kernel, rounding only
    assert np.abs(want).max() > 5e-3  # the terms matter, so the check can fail


def test_a_model_with_a_cross_axis_term_round_trips_through_its_file(tmp_path):
    twist = make_cross(2, (0, 1), "twist", ((169.0, 729.0), (37.0, 515.0)))
    assert twist.name == "cross:z(XY):twist[169,729][37,515]"
    assert resolve(twist.name) == twist and parse_cross(twist.name) == twist
    model = Model(MAPS).with_values(twist, [-26.7])
    back = Model.load(model.save(tmp_path / "m.json"))
    assert back.names == model.names and np.array_equal(back.values(twist.name), [-26.7])
    uv, scales = _points()
    assert np.array_equal(cmmpose.compensate(uv, scales, back, POSE, OFFSET, 22.0),
                          cmmpose.compensate(uv, scales, model, POSE, OFFSET, 22.0))


@pytest.mark.parametrize("name", ["cross:w(XY):twist[0,1][0,1]", "cross:z(XX):twist[0,900][0,900]",
                                  "cross:z(XY):warp[0,900][0,500]", "cross:z(XY):twist[900,0][0,500]",
                                  "cross:z(XY):twist[0,900]"])
def test_a_bad_cross_axis_name_is_refused(name):
    with pytest.raises(InputError, match="cross-axis"):
        resolve(name)
