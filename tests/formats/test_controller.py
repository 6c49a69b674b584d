"""The controller error file of thesis Appendix B (errors_1102.txt):
ErrorMap.appendix_b() and ErrorMap.read_controller_file."""

import numpy as np
import pytest

import cmmpose
from cmmpose import ErrorMap

BUNDLED = cmmpose.data_path("errors_1102.txt")


# -- helpers ---------------------------------------------------------------------


@pytest.fixture(scope="module")
def appendix_b():
    return ErrorMap.appendix_b()


@pytest.fixture
def lines():
    """The bundled controller file as a list of lines, ready to be edited."""
    return BUNDLED.read_text(encoding="utf-8").splitlines()


def write_lines(tmp_path, lines, name="errors_edited.txt"):
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def index_of(lines, prefix, after=0):
    """0-based index of the first line at or after ``after`` starting with ``prefix``."""
    return next(i for i in range(after, len(lines)) if lines[i].startswith(prefix))


def block_start(lines, axis):
    return index_of(lines, f"Map Data: {axis} Axis")


def data_row(lines, axis, position):
    """Index of the data row at ``position`` inside the ``axis`` block."""
    return index_of(lines, f"{position}\t", after=block_start(lines, axis))


def read_error(path):
    with pytest.raises(cmmpose.MapError) as exc:
        ErrorMap.read_controller_file(path)
    return str(exc.value)


# -- the bundled appendix ----------------------------------------------------------


def test_appendix_b_loads_with_temperature_grids_and_negated_squareness(appendix_b):
    assert appendix_b.temperature == 22.0
    # The file says XY 169.397, YZ 33.979, ZX -25.984; the controller's sign
    # convention is opposite to Table 7's, so the reader negates them.
    assert appendix_b.squareness == (-169.397, -33.979, 25.984)
    assert appendix_b.ranges == [(0.0, 900.0), (0.0, 550.0), (-500.0, 0.0)]
    for c, grid in (("X", np.arange(0, 901, 25)), ("Y", np.arange(0, 551, 25)), ("Z", np.arange(-500, 1, 25))):
        np.testing.assert_array_equal(appendix_b.table(c)[:, 0], grid)


# (carriage, position): (dx, dy, dz, ex, ey, ez) read off thesis Appendix B.
# X block order: X Linear, Y Straight, Z Straight, Y Rotation, Z Rotation, X Rotation.
# Y block order: Y Linear, Z Straight, X Straight, X Rotation, Z Rotation, Y Rotation.
# Z block order: Z Linear, X Straight, Y Straight, X Rotation, Y Rotation, Z Rotation.
APPENDIX_B_ROWS = {
    ("X", 0): (0.0, 0.0, 0.0, 0.0, -0.60, -0.10),
    ("X", 50): (3.0, 0.0, 0.0, 0.0, -0.90, 0.15),
    ("X", 525): (11.0, 2.0, 1.0, 0.0, 0.65, 0.80),
    ("X", 550): (14.0, 2.0, 1.0, 0.0, 0.35, 0.80),  # first row after a repeated header
    ("X", 625): (13.0, -1.0, 1.0, 0.0, 0.80, 1.25),
    ("X", 900): (12.0, 0.0, 0.0, 0.0, 1.40, 2.00),
    ("Y", 0): (0.0, 0.0, 0.0, -0.35, 0.0, -0.20),
    ("Y", 175): (-7.0, 15.0, 0.0, -0.85, 0.0, -0.15),
    ("Y", 200): (-7.0, 16.0, 1.0, -0.70, 0.0, 0.05),
    ("Y", 525): (6.0, 39.0, 0.0, -1.75, 0.0, 1.20),
    ("Y", 550): (0.0, 41.0, 0.0, -2.20, 0.0, 1.00),
    ("Z", -500): (0.0, 0.0, 0.0, -1.50, -0.15, 0.0),
    ("Z", -300): (0.0, 0.0, -4.0, -1.05, 0.40, 0.0),
    ("Z", -175): (0.0, -1.0, -2.0, -3.55, -0.65, 0.0),
    ("Z", -100): (0.0, -2.0, -2.0, -3.70, -1.60, 0.0),
    ("Z", -25): (0.0, 0.0, -5.0, -3.65, -2.55, 0.0),
    ("Z", 0): (0.0, 0.0, -5.0, -3.80, -3.20, 0.0),
}


@pytest.mark.parametrize(("carriage", "position"), list(APPENDIX_B_ROWS))
def test_appendix_b_values_in_canonical_column_order(appendix_b, carriage, position):
    table = appendix_b.table(carriage)
    (row,) = np.flatnonzero(table[:, 0] == position)
    np.testing.assert_array_equal(table[row, 1:], APPENDIX_B_ROWS[carriage, position])


def test_copy_of_bundled_file_reads_like_appendix_b(tmp_path, lines, appendix_b):
    path = write_lines(tmp_path, lines, "errors_1102.txt")
    assert ErrorMap.read_controller_file(path, temperature=22.0) == appendix_b
    assert ErrorMap.read_controller_file(path).temperature is None


# -- malformed controller files ------------------------------------------------------


def test_unknown_column_name(tmp_path, lines):
    i = index_of(lines, "Y Position", after=block_start(lines, "Y"))
    lines[i] = lines[i].replace("Z Rotation", "Z Roll")
    path = write_lines(tmp_path, lines)
    msg = read_error(path)
    assert f"{path.name}:{i + 1}:" in msg and "unknown column 'Z Roll'" in msg


def test_data_row_with_six_values(tmp_path, lines):
    i = data_row(lines, "Y", 100)
    lines[i] = lines[i].rsplit("\t", 1)[0]
    path = write_lines(tmp_path, lines)
    msg = read_error(path)
    assert f"{path.name}:{i + 1}:" in msg and "expected 7 values in a Y row, got 6" in msg


def test_non_numeric_value(tmp_path, lines):
    i = data_row(lines, "Z", -300)
    lines[i] = lines[i].replace("-4.00", "-4.O0")
    path = write_lines(tmp_path, lines)
    msg = read_error(path)
    assert f"{path.name}:{i + 1}:" in msg and "'-4.O0' is not a number" in msg


def test_missing_z_block(tmp_path, lines):
    path = write_lines(tmp_path, lines[: block_start(lines, "Z")])
    msg = read_error(path)
    assert path.name in msg and "no 'Map Data: Z Axis' block" in msg


def test_block_span_disagrees_with_axis_parameters(tmp_path, lines):
    i = index_of(lines, "Y 0 550 25 0")
    lines[i] = "Y 0 575 25 0"
    path = write_lines(tmp_path, lines)
    msg = read_error(path)
    assert path.name in msg and "Y block spans 0..550" in msg and "0..575" in msg


@pytest.mark.parametrize("key", ["XY", "YZ", "ZX"])
def test_missing_squareness_line(tmp_path, lines, key):
    del lines[index_of(lines, f"{key}:")]
    path = write_lines(tmp_path, lines)
    msg = read_error(path)
    assert path.name in msg and f"squareness parameter(s) {key} missing" in msg


def test_duplicate_position(tmp_path, lines):
    i = data_row(lines, "Y", 100)
    lines[i] = "75" + lines[i][len("100"):]
    path = write_lines(tmp_path, lines)
    msg = read_error(path)
    assert f"{path.name}:{i + 1}:" in msg and "Y position 75 duplicates the previous 75" in msg


def test_repeated_header_differs_from_first(tmp_path, lines):
    first = index_of(lines, "X Position")
    i = index_of(lines, "X Position", after=first + 1)
    lines[i] = lines[i].replace("Y Rotation\tZ Rotation", "Z Rotation\tY Rotation")
    path = write_lines(tmp_path, lines)
    msg = read_error(path)
    assert f"{path.name}:{i + 1}:" in msg and "repeated X header differs" in msg


# -- named columns in another order -------------------------------------------------


@pytest.mark.parametrize(
    ("axis", "order"),
    [("X", (0, 6, 3, 1, 5, 2, 4)), ("Y", (0, 2, 4, 6, 1, 3, 5)), ("Z", (0, 5, 6, 4, 3, 2, 1))],
)
def test_columns_in_another_named_order_read_to_the_same_map(tmp_path, lines, appendix_b, axis, order):
    start = block_start(lines, axis)
    end = next((i for i in range(start + 1, len(lines)) if lines[i].startswith("Map Data:")), len(lines))
    shuffled = 0
    for i in range(start + 1, end):
        fields = lines[i].split("\t")
        if len(fields) == 7 and not set(lines[i]) <= set("-\t "):  # header or data row, not the dashes
            lines[i] = "\t".join(fields[k] for k in order)
            shuffled += 1
    assert shuffled > 20
    path = write_lines(tmp_path, lines)
    assert ErrorMap.read_controller_file(path, temperature=22.0) == appendix_b
