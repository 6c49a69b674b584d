"""cmmpose._validate: each helper's good and bad inputs; messages name the
argument and the exception class is the caller's choice."""

import math

import numpy as np
import pytest

import cmmpose
from cmmpose import _validate as v
from cmmpose.errors import CalibrationError, InputError, MapError


# -- finite, nonnegative, positive -------------------------------------------------


@pytest.mark.parametrize("value, expected", [(1, 1.0), (-2.5, -2.5), ("3.25", 3.25), (np.float32(0.5), 0.5),
                                             (np.int64(7), 7.0), (np.array(4.0), 4.0), (0, 0.0)])
def test_finite_accepts_numbers(value, expected):
    out = v.finite("k", value)
    assert out == expected and type(out) is float


@pytest.mark.parametrize("value, message", [
    (True, "k: expected a number, got True"),  # a JSON true is not 1.0 (issue 11)
    ("abc", "k: expected a number, got 'abc'"),
    (None, "k: expected a number, got None"),
    ([1.0, 2.0], "k: expected a number"),
    (np.array([1.0]), "k: expected a number"),
    (math.nan, "k: must be finite, got nan"),
    (-math.inf, "k: must be finite, got -inf"),
])
def test_finite_rejects_non_numbers_and_non_finite(value, message):
    with pytest.raises(InputError) as exc:
        v.finite("k", value)
    assert str(exc.value).startswith(message)


def test_finite_raises_the_callers_class():
    with pytest.raises(CalibrationError, match="^temperature: must be finite"):
        v.finite("temperature", "inf", error=CalibrationError)


@pytest.mark.parametrize("value", [0, 0.0, 2, "1e-3"])
def test_nonnegative_accepts_zero_and_up(value):
    assert v.nonnegative("u", value) == float(value)


@pytest.mark.parametrize("value, message", [(-1e-300, "u: must be finite and >= 0, got -1e-300"),
                                            (math.nan, "u: must be finite and >= 0, got nan"),
                                            (math.inf, "u: must be finite and >= 0, got inf"),
                                            ("x", "u: expected a number, got 'x'")])
def test_nonnegative_rejects(value, message):
    with pytest.raises(InputError, match=f"^{message}$"):
        v.nonnegative("u", value)


def test_positive():
    assert v.positive("lam", 632.99) == 632.99
    with pytest.raises(InputError, match="^lam: must be > 0, got 0$"):
        v.positive("lam", 0)
    with pytest.raises(InputError, match="^lam: must be finite and >= 0, got -1.0$"):
        v.positive("lam", -1)
    with pytest.raises(MapError, match="^lam: expected a number"):
        v.positive("lam", None, error=MapError)


# -- triple, vector3 ---------------------------------------------------------------


@pytest.mark.parametrize("value", [(1, 2, 3), [1.0, 2.0, 3.0], np.array([1, 2, 3]), ("1", "2", "3"), range(1, 4)])
def test_triple_accepts_three_numbers(value):
    out = v.triple("offset", value)
    assert out == (1.0, 2.0, 3.0) and type(out) is tuple and all(type(x) is float for x in out)


@pytest.mark.parametrize("value, message", [
    (5, "offset: expected three numbers, got 5"),
    (None, "offset: expected three numbers, got None"),
    (["a", 1, 2], "offset: expected three numbers, got ['a', 1, 2]"),
    ((1, 2), "offset: expected three finite numbers, got (1, 2)"),
    ((1, 2, 3, 4), "offset: expected three finite numbers, got (1, 2, 3, 4)"),
    ((1, math.nan, 3), "offset: expected three finite numbers, got (1, nan, 3)"),
])
def test_triple_rejects(value, message):
    with pytest.raises(InputError) as exc:
        v.triple("offset", value)
    assert str(exc.value) == message


def test_triple_unit_nonnegative_and_class():
    with pytest.raises(InputError, match=r"^squareness: expected three finite numbers \(arc-seconds\)"):
        v.triple("squareness", (1, 2), unit="arc-seconds")
    assert v.triple("u", (0, 1, 2), nonnegative=True) == (0.0, 1.0, 2.0)
    with pytest.raises(CalibrationError, match=r"^lib.json: u: must be >= 0, got \(1, -2, 3\)$"):
        v.triple("lib.json: u", (1, -2, 3), nonnegative=True, error=CalibrationError)
    assert v.triple("u", (1, -2, 3)) == (1.0, -2.0, 3.0)


@pytest.mark.parametrize("value", [(1, 2, 3), [1.0, 2.0, 3.0], np.array([1, 2, 3], dtype=np.int32)])
def test_vector3_gives_a_new_float64_array(value):
    out = v.vector3("centre", value)
    assert out.dtype == np.float64 and out.shape == (3,) and out.flags.writeable
    np.testing.assert_array_equal(out, [1.0, 2.0, 3.0])
    assert not np.shares_memory(out, value) if isinstance(value, np.ndarray) else True


def test_vector3_copies():
    a = np.array([1.0, 2.0, 3.0])
    out = v.vector3("centre", a)
    a[0] = 9.0
    assert out[0] == 1.0


@pytest.mark.parametrize("value, message", [
    ("abc", "centre: expected three numbers (mm), got 'abc'"),
    (None, "centre: expected three finite numbers (mm), got None"),
    ([[1, 2, 3]], "centre: expected three finite numbers (mm), got [[1, 2, 3]]"),
    ((1, 2), "centre: expected three finite numbers (mm), got (1, 2)"),
    ((1, 2, math.inf), "centre: expected three finite numbers (mm), got (1, 2, inf)"),
    ([[1, 2], [3]], "centre: expected three numbers (mm), got [[1, 2], [3]]"),
])
def test_vector3_rejects(value, message):
    with pytest.raises(InputError) as exc:
        v.vector3("centre", value, unit="mm")
    assert str(exc.value) == message


def test_vector3_is_a_drop_in_for_the_simulator_effects_triple():
    """sim/effects.py's ``_triple(name, value) -> ndarray (3,)``: same call, same
    result for three numbers, InputError naming the argument otherwise."""
    out = v.vector3("dx", [1, 2, 3])
    np.testing.assert_array_equal(out, np.asarray([1, 2, 3], dtype=float))
    with pytest.raises(InputError, match="^dx: "):
        v.vector3("dx", [1, 2])


# -- parse_number ------------------------------------------------------------------


@pytest.mark.parametrize("text, expected", [("1.5", 1.5), (" -2 ", -2.0), ("1e3", 1000.0), ("0", 0.0)])
def test_parse_number_reads_fields(text, expected):
    assert v.parse_number(text, "m.csv:3", "dx_um") == expected


@pytest.mark.parametrize("text, message", [
    ("8.9um", "m.csv:3: dx_um '8.9um' is not a number"),
    (" x ", "m.csv:3: dx_um 'x' is not a number"),
    ("", "m.csv:3: dx_um '' is not a number"),
    ("nan", "m.csv:3: dx_um is not finite (nan)"),
    ("-inf ", "m.csv:3: dx_um is not finite (-inf)"),
])
def test_parse_number_rejects(text, message):
    with pytest.raises(MapError) as exc:
        v.parse_number(text, "m.csv:3", "dx_um")
    assert str(exc.value) == message


def test_parse_number_raises_the_callers_class():
    with pytest.raises(InputError, match="is not a number"):
        v.parse_number("?", "f:1", "value", error=InputError)


def test_no_copies_left_in_the_package():
    """The helpers are defined here and nowhere else (sim/effects.py, being
    rewritten, excepted)."""
    import pathlib
    import re

    root = pathlib.Path(cmmpose.__file__).parent
    pattern = re.compile(r"^def (_finite|_finite_nonneg|_finite_positive|_float|_number|_vec)\(", re.M)
    found = [str(p.relative_to(root)) for p in root.rglob("*.py") if pattern.search(p.read_text(encoding="utf-8"))]
    assert found == []
