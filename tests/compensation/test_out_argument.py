"""``out=``: compensate into the caller's buffer, with the same bits as a
fresh result, and refuse a buffer that cannot take the result safely."""

import numpy as np
import pytest

import cmmpose
from cmmpose.errors import InputError

POSE = (90.0, 90.0, 0.0)
OFFSET = (1.001, 264.505, 129.575)


@pytest.fixture(scope="module")
def points():
    rng = np.random.default_rng(7)
    n = 5000
    scales = np.column_stack([rng.uniform(0, 900, n), rng.uniform(0, 550, n), rng.uniform(-500, 0, n)])
    uv = np.column_stack([rng.uniform(-30, 30, n), rng.uniform(110, 170, n)])
    return uv, scales, cmmpose.ErrorMapSet.thesis()


def test_out_gets_the_same_bits_and_is_returned(points):
    uv, scales, maps = points
    fresh = cmmpose.compensate(uv, scales, maps, POSE, OFFSET, 22.5)
    out = np.full_like(fresh, np.nan)
    got = cmmpose.compensate(uv, scales, maps, POSE, OFFSET, 22.5, out=out)
    assert got is out
    assert np.array_equal(out.view(np.int64), fresh.view(np.int64))
    again = cmmpose.uncompensated(uv, scales, POSE, OFFSET, out=out)
    assert again is out and np.array_equal(out, cmmpose.uncompensated(uv, scales, POSE, OFFSET))


def test_out_is_reused_call_after_call(points):
    uv, scales, maps = points
    out = np.empty((len(uv), 3))
    for t in (20.0, 22.5, 25.0):
        cmmpose.compensate(uv, scales, maps, POSE, OFFSET, t, out=out)
        assert np.array_equal(out, cmmpose.compensate(uv, scales, maps, POSE, OFFSET, t))


@pytest.mark.parametrize(
    "make, words",
    [
        (lambda n: np.empty((n + 1, 3)), "shape"),
        (lambda n: np.empty((n, 2)), "shape"),
        (lambda n: np.empty((n, 3), dtype=np.float32), "float64"),
        (lambda n: np.empty((n, 3), order="F"), "C-contiguous"),
        (lambda n: np.empty((n, 6))[:, ::2], "C-contiguous"),
        (lambda n: "not an array", "float64"),
    ],
)
def test_out_of_the_wrong_kind_is_refused_naming_it(points, make, words):
    uv, scales, maps = points
    with pytest.raises(InputError, match=rf"out: .*{words}"):
        cmmpose.compensate(uv, scales, maps, POSE, OFFSET, 22.5, out=make(len(uv)))


def test_read_only_out_is_refused(points):
    uv, scales, maps = points
    out = np.empty((len(uv), 3))
    out.flags.writeable = False
    with pytest.raises(InputError, match="out: cannot be written"):
        cmmpose.compensate(uv, scales, maps, POSE, OFFSET, 22.5, out=out)


def test_out_overlapping_an_input_is_refused_and_the_input_kept(points):
    uv, scales, maps = points
    n = len(uv)
    buffer = np.empty(6 * n)
    buffer[: 3 * n] = scales.ravel()
    inside = buffer[: 3 * n].reshape(n, 3)
    overlapping = buffer[3 * n - 3 : 6 * n - 3].reshape(n, 3)
    before = inside.copy()
    with pytest.raises(InputError, match="share no memory"):
        cmmpose.compensate(uv, inside, maps, POSE, OFFSET, 22.5, out=overlapping)
    assert np.array_equal(inside, before)
    with pytest.raises(InputError, match="share no memory"):
        cmmpose.compensate(uv, inside, maps, POSE, OFFSET, 22.5, out=inside)


def test_the_binding_refuses_fortran_ordered_rows(points):
    """A Fortran-ordered (N, 3) array is contiguous but not row by row: the
    binding refuses it rather than read columns as rows."""
    uv, scales, maps = points
    from cmmpose import _core
    from cmmpose.pose import digitizer

    with pytest.raises(InputError, match="scales: array must be C-contiguous"):
        _core.compensate(uv, np.asfortranarray(scales), maps._core, digitizer(POSE, OFFSET), cmmpose.TemperaturePolicy(),
                         22.5)
