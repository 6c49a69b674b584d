"""The canonical error-map CSV (cmmpose.formats.mapfiles): exact round trips and one
test per kind of malformed file, each naming the file and line at fault."""

import numpy as np
import pytest

import cmmpose
from cmmpose import ErrorMap

BUNDLED = cmmpose.data_path("maps", "thesis_20C.csv")


# -- helpers ---------------------------------------------------------------------


@pytest.fixture
def lines():
    """The bundled 20 C map as a list of lines, ready to be edited."""
    return BUNDLED.read_text(encoding="utf-8").splitlines()


def write_lines(tmp_path, lines, name="edited.csv"):
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def index_of(lines, prefix):
    """0-based index of the first line starting with ``prefix``."""
    return next(i for i, line in enumerate(lines) if line.startswith(prefix))


def read_error(path):
    with pytest.raises(cmmpose.MapError) as exc:
        ErrorMap.read(path)
    return str(exc.value)


def assert_same_map(a, b):
    """Field by field, so that a broken ``==`` cannot hide a difference."""
    assert a == b
    for c in cmmpose.CARRIAGES:
        np.testing.assert_array_equal(a.table(c), b.table(c))
    assert a.squareness == b.squareness
    assert a.temperature == b.temperature


# -- round trips -----------------------------------------------------------------


@pytest.mark.parametrize("temperature", [20, 25, 30])
def test_bundled_thesis_map_round_trips_exactly(tmp_path, temperature):
    original = ErrorMap.read(cmmpose.data_path("maps", f"thesis_{temperature}C.csv"))
    out = tmp_path / "copy.csv"
    original.write(out)
    assert_same_map(ErrorMap.read(out), original)


def random_map(rng, temperature):
    tables = []
    for lo, hi, n in ((0.0, 900.0, 29), (0.0, 550.0, 17), (-500.0, 0.0, 11)):
        inner = np.sort(rng.uniform(lo, hi, n - 2))
        positions = np.concatenate([[lo], inner, [hi]])  # non-uniform, non-integer inside
        assert np.all(np.diff(positions) > 0)
        values = np.column_stack([rng.normal(0.0, 30.0, (n, 3)), rng.normal(0.0, 5.0, (n, 3))])
        tables.append(np.column_stack([positions, values]))
    squareness = tuple(rng.normal(0.0, 100.0, 3))
    return ErrorMap(*tables, squareness, temperature)


@pytest.mark.parametrize("temperature", [23.456789012345, None])
def test_random_map_round_trips_exactly(tmp_path, temperature):
    rng = np.random.default_rng(7)
    original = random_map(rng, temperature)
    out = tmp_path / "random.csv"
    original.write(out)
    back = ErrorMap.read(out)
    assert_same_map(back, original)
    # The comparison is able to fail: a map differing in one digit is not equal.
    x = original.table("X")
    x[3, 5] = np.nextafter(x[3, 5], np.inf)
    assert ErrorMap(x, original.table("Y"), original.table("Z"), original.squareness, temperature) != back


# -- malformed files: one per defect, each naming file and line ------------------


def test_row_with_too_few_fields(tmp_path, lines):
    i = index_of(lines, "X,100,")
    lines[i] = lines[i].rsplit(",", 1)[0]
    path = write_lines(tmp_path, lines)
    msg = read_error(path)
    assert f"{path.name}:{i + 1}:" in msg and "expected 8 fields, got 7" in msg


def test_row_with_too_many_fields(tmp_path, lines):
    i = index_of(lines, "Y,250,")
    lines[i] += ",0"
    path = write_lines(tmp_path, lines)
    msg = read_error(path)
    assert f"{path.name}:{i + 1}:" in msg and "expected 8 fields, got 9" in msg


def test_non_numeric_cell(tmp_path, lines):
    i = index_of(lines, "X,100,")
    lines[i] = lines[i].replace("8.9", "8.9um")
    path = write_lines(tmp_path, lines)
    msg = read_error(path)
    assert f"{path.name}:{i + 1}:" in msg and "dx_um '8.9um' is not a number" in msg


def test_duplicate_position(tmp_path, lines):
    i = index_of(lines, "X,125,")
    lines[i] = lines[i].replace("X,125,", "X,100,")
    path = write_lines(tmp_path, lines)
    msg = read_error(path)
    assert f"{path.name}:{i + 1}:" in msg and "duplicates" in msg


def test_decreasing_position(tmp_path, lines):
    i = index_of(lines, "Z,-300,")
    lines[i] = lines[i].replace("Z,-300,", "Z,-330,")
    path = write_lines(tmp_path, lines)
    msg = read_error(path)
    assert f"{path.name}:{i + 1}:" in msg and "is less than" in msg and "-330" in msg


def test_missing_carriage(tmp_path, lines):
    kept = [line for line in lines if not line.startswith("Z,")]
    path = write_lines(tmp_path, kept)
    msg = read_error(path)
    assert path.name in msg and "no rows for the Z carriage" in msg


def test_carriage_with_one_row(tmp_path, lines):
    first_y = index_of(lines, "Y,")
    kept = [line for i, line in enumerate(lines) if not line.startswith("Y,") or i == first_y]
    path = write_lines(tmp_path, kept)
    msg = read_error(path)
    assert path.name in msg and "the Y carriage has 1 row" in msg


@pytest.mark.parametrize("bad", ["nan", "NaN", "inf", "-inf"])
def test_non_finite_cell(tmp_path, lines, bad):
    i = index_of(lines, "Z,-175,")
    fields = lines[i].split(",")
    fields[6] = bad  # ey_arcsec
    lines[i] = ",".join(fields)
    path = write_lines(tmp_path, lines)
    msg = read_error(path)
    assert f"{path.name}:{i + 1}:" in msg and "ey_arcsec is not finite" in msg


@pytest.mark.parametrize(
    "header",
    [
        "carriage,position_mm,dx_um,dy_um,dz_um,ex_arcsec,ey_arcsec",  # a column short
        "carriage,position_mm,dx_mm,dy_mm,dz_mm,ex_arcsec,ey_arcsec,ez_arcsec",  # wrong units
        "carriage,position_mm,dy_um,dx_um,dz_um,ex_arcsec,ey_arcsec,ez_arcsec",  # reordered
    ],
)
def test_wrong_header_row(tmp_path, lines, header):
    i = index_of(lines, "carriage,")
    lines[i] = header
    path = write_lines(tmp_path, lines)
    msg = read_error(path)
    assert f"{path.name}:{i + 1}:" in msg and "header must be" in msg


@pytest.mark.parametrize("key", ["squareness_xy_arcsec", "squareness_yz_arcsec", "squareness_zx_arcsec"])
def test_missing_squareness_line(tmp_path, lines, key):
    del lines[index_of(lines, f"# {key}:")]
    path = write_lines(tmp_path, lines)
    msg = read_error(path)
    assert path.name in msg and key in msg and "missing" in msg


def test_missing_temperature_line(tmp_path, lines):
    del lines[index_of(lines, "# temperature_C:")]
    path = write_lines(tmp_path, lines)
    msg = read_error(path)
    assert path.name in msg and "temperature_C" in msg and "missing" in msg


def test_non_numeric_temperature(tmp_path, lines):
    i = index_of(lines, "# temperature_C:")
    lines[i] = "# temperature_C: warm"
    path = write_lines(tmp_path, lines)
    msg = read_error(path)
    assert f"{path.name}:{i + 1}:" in msg and "temperature_C 'warm' is not a number" in msg


@pytest.mark.parametrize("first", ["# cmmpose-error-map: 2", "# error map", "carriage,position_mm"])
def test_bad_first_line(tmp_path, lines, first):
    lines[0] = first
    path = write_lines(tmp_path, lines)
    msg = read_error(path)
    assert f"{path.name}:1:" in msg and "not a cmmpose error map" in msg


def test_unknown_carriage_letter(tmp_path, lines):
    i = index_of(lines, "Y,300,")
    lines[i] = "W" + lines[i][1:]
    path = write_lines(tmp_path, lines)
    msg = read_error(path)
    assert f"{path.name}:{i + 1}:" in msg and "carriage 'W' is not X, Y or Z" in msg


def test_empty_file(tmp_path):
    path = tmp_path / "empty.csv"
    path.write_bytes(b"")
    msg = read_error(path)
    assert f"{path.name}:1:" in msg and "not a cmmpose error map" in msg


def test_non_utf8_bytes(tmp_path, lines):
    """A Latin-1 byte in one row: the message names the file and that row's line."""
    i = index_of(lines, "X,550,")
    data = "\n".join(lines).encode("utf-8").split(b"\n")
    data[i] = data[i].replace(b"X,550,", b"X,550,\xb5")
    path = tmp_path / "latin1.csv"
    path.write_bytes(b"\n".join(data) + b"\n")
    msg = read_error(path)
    assert path.name in msg
    assert f"{path.name}:{i + 1}" in msg, f"line {i + 1} not named: {msg}"


# -- maps built directly ---------------------------------------------------------


def thesis_tables():
    m = ErrorMap.read(BUNDLED)
    return {c: m.table(c) for c in cmmpose.CARRIAGES}, m.squareness


@pytest.mark.parametrize("carriage", ["X", "Y", "Z"])
@pytest.mark.parametrize("reshape", [lambda t: t[:, :6], lambda t: np.column_stack([t, t[:, :1]]), lambda t: t.ravel()])
def test_table_of_wrong_shape_is_an_input_error_naming_the_table(carriage, reshape):
    tables, sq = thesis_tables()
    tables[carriage] = reshape(tables[carriage])
    with pytest.raises(cmmpose.InputError) as exc:
        ErrorMap(tables["X"], tables["Y"], tables["Z"], sq)
    msg = str(exc.value)
    assert f"{carriage.lower()} table" in msg and str(tables[carriage].shape) in msg


@pytest.mark.parametrize("squareness", [(1.0, 2.0), (1.0, 2.0, 3.0, 4.0)])
def test_squareness_of_wrong_length_is_an_input_error(squareness):
    tables, _ = thesis_tables()
    with pytest.raises(cmmpose.InputError, match="squareness"):
        ErrorMap(tables["X"], tables["Y"], tables["Z"], squareness)


@pytest.mark.parametrize(
    ("carriage", "row", "column", "name"),
    [("X", 0, 1, "dx"), ("Y", 3, 2, "dy"), ("Y", 22, 5, "ey"), ("Z", 12, 6, "ez")],
)
def test_nan_in_a_table_is_a_map_error_naming_carriage_and_row(carriage, row, column, name):
    tables, sq = thesis_tables()
    tables[carriage][row, column] = np.nan
    with pytest.raises(cmmpose.MapError) as exc:
        ErrorMap(tables["X"], tables["Y"], tables["Z"], sq)
    msg = str(exc.value)
    assert f"{carriage} carriage table, row {row}" in msg and f"component {name} is not finite" in msg


def test_nan_position_is_a_map_error_naming_carriage_and_row():
    tables, sq = thesis_tables()
    tables["Z"][4, 0] = np.nan
    with pytest.raises(cmmpose.MapError) as exc:
        ErrorMap(tables["X"], tables["Y"], tables["Z"], sq)
    assert "Z carriage table, row 4" in str(exc.value) and "position" in str(exc.value)
