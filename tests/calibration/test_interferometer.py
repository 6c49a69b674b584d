"""Error maps from laser-interferometer runs (cmmpose.calibration.interferometer)
and simulated runs (cmmpose.sim.interferometer): the refractive index of air of
thesis section 3.3 and its GUM uncertainty, the run file, processing of a run,
assembly of a map, comparison of maps.

Thesis line numbers refer to the plain-text thesis of data/SOURCES.md."""

import math
import warnings

import numpy as np
import pytest

import cmmpose
from cmmpose.calibration.interferometer import (
    STANDARD_AIR,
    THESIS_AIR_UNCERTAINTY,
    THESIS_SENSITIVITIES_PPM,
    THESIS_TOTAL_UNCERTAINTY_PPM,
    InterferometerRun,
    InterferometerRunError,
    InterferometerWarning,
    build_map,
    compare_maps,
    correct_reading,
    correction_factor,
    map_from_runs,
    process_run,
    read_run,
    refractive_index,
    refractive_index_budget,
    refractivity,
    refractivity_partials,
    refractivity_uncertainty,
    wavelength_in_air_nm,
)
from cmmpose.sim.interferometer import (
    DEFAULT_NOISE,
    DEFAULT_REVERSAL,
    simulate_interferometer_run,
    simulate_interferometer_runs,
)

REPEATS = 3
#: Tolerance of a recovered component: its value at a target is the mean of
#: 2 * REPEATS readings minus the same at home, standard deviation
#: sigma / sqrt(REPEATS); 5 of those.
K = 5.0


def tolerance(optics):
    return K * DEFAULT_NOISE[optics] / math.sqrt(REPEATS)


def optics_of(carriage, component):
    if component[0] == "e":
        return "angular"
    return "linear" if component[1].upper() == carriage else "straightness"


@pytest.fixture(scope="module")
def thesis_maps():
    return cmmpose.ErrorMapSet.thesis().maps


@pytest.fixture(scope="module")
def truth(thesis_maps):
    return thesis_maps[0]  # 20 C


@pytest.fixture(scope="module")
def simulated(truth):
    return simulate_interferometer_runs(truth, repeats=REPEATS, seed=7)


def run_of(runs, carriage, component):
    return next(r for r in runs if r.axis == carriage and r.component == component)


# -- 1. refractive index of air (thesis lines 762-772) -------------------------------------


def test_refractivity_of_standard_air_is_the_accepted_633nm_value():
    # Line 762 with the 1e-6 of the Edlen form (the printed 10^6 would give N ~ 1e11).
    n = refractivity(20.0, 760.0, 50.0)
    assert 271.0 < n < 271.6
    assert refractive_index(20.0, 760.0, 50.0) == pytest.approx(1.0 + n * 1e-6, abs=1e-15)
    # Dry air at 15 C, 760 mmHg: Edlen's 633 nm value is about 276.5 ppm.
    assert refractivity(15.0, 760.0, 0.0) == pytest.approx(276.5, abs=0.3)


def test_about_one_ppm_per_degree_of_air_temperature_and_n_falls_as_it_warms():
    # Line 770: "a 1 PPM error ... will result from a 1 C change in air temperature".
    dn = refractivity(21.0, 760.0, 50.0) - refractivity(20.0, 760.0, 50.0)
    assert dn < 0
    assert -1.05 < dn < -0.9


def test_about_one_ppm_per_2_5_mmHg_and_n_rises_with_pressure():
    # Line 770: "... a 2.5 mm Hg change in air pressure".
    dn = refractivity(20.0, 762.5, 50.0) - refractivity(20.0, 760.0, 50.0)
    assert dn > 0
    assert 0.85 < dn < 1.05


def test_humidity_examples_of_the_text():
    # Line 770-772: "an 80 % change in relative humidity" ~ 1 ppm (Kneppers, rounded);
    # the formula gives 0.0096 ppm per % RH: 0.77 ppm for 80 points, 0.38 ppm for
    # the printed example 50 -> 10 % RH, 0.05 ppm for 50 -> 45 % RH.
    per_point = refractivity(20.0, 760.0, 51.0) - refractivity(20.0, 760.0, 50.0)
    assert per_point == pytest.approx(-0.0096, abs=0.0002)
    assert refractivity(20.0, 760.0, 10.0) - refractivity(20.0, 760.0, 90.0) == pytest.approx(0.77, abs=0.02)
    assert refractivity(20.0, 760.0, 10.0) - refractivity(20.0, 760.0, 50.0) == pytest.approx(0.38, abs=0.02)
    assert refractivity(20.0, 760.0, 45.0) - refractivity(20.0, 760.0, 50.0) == pytest.approx(0.048, abs=0.003)


def test_analytic_partials_match_finite_differences_and_the_printed_coefficients():
    p = refractivity_partials(20.0, 760.0, 50.0)
    h = 1e-4
    fd = {
        "air_temperature_C": (refractivity(20 + h, 760, 50) - refractivity(20 - h, 760, 50)) / (2 * h),
        "pressure_mmHg": (refractivity(20, 760 + h, 50) - refractivity(20, 760 - h, 50)) / (2 * h),
        "humidity_percent": (refractivity(20, 760, 50 + h) - refractivity(20, 760, 50 - h)) / (2 * h),
    }
    for k in p:
        assert p[k] == pytest.approx(fd[k], rel=1e-6)
    # Printed in line 768 (magnitudes; the printed signs of T and P are swapped).
    assert abs(p["air_temperature_C"]) == pytest.approx(abs(THESIS_SENSITIVITIES_PPM["air_temperature_C"]), abs=0.015)
    assert abs(p["pressure_mmHg"]) == pytest.approx(abs(THESIS_SENSITIVITIES_PPM["pressure_mmHg"]), abs=0.025)
    assert abs(p["humidity_percent"]) == pytest.approx(abs(THESIS_SENSITIVITIES_PPM["humidity_percent"]), abs=0.001)
    assert p["air_temperature_C"] < 0 < p["pressure_mmHg"] and p["humidity_percent"] < 0


def test_gum_uncertainty_of_line_768_and_the_thesis_estimate_of_2_5_ppm():
    # The air changes the thesis deems possible (1 C, 2.5 mmHg, 10 % RH):
    u = refractivity_uncertainty(*THESIS_AIR_UNCERTAINTY)
    assert u == pytest.approx(math.sqrt(0.97**2 + (0.38 * 2.5) ** 2 + 0.1**2), rel=1e-12)
    assert u == pytest.approx(1.36, abs=0.005)
    plain_sum = 0.97 * 1 + 0.38 * 2.5 + 0.01 * 10
    assert u < plain_sum < THESIS_TOTAL_UNCERTAINTY_PPM  # 2.5 ppm is a rounded-up bound
    # With the analytic derivatives at standard air instead of the printed ones:
    assert refractivity_uncertainty(*THESIS_AIR_UNCERTAINTY, at=STANDARD_AIR) == pytest.approx(1.31, abs=0.01)
    budget = refractive_index_budget(0.1, 0.3, 2.0)
    assert budget.unit == "ppm"
    assert [i.unit for i in budget.inputs] == ["C", "mmHg", "%RH"]
    assert budget.combined_standard_uncertainty == pytest.approx(math.sqrt(0.097**2 + 0.114**2 + 0.02**2), rel=1e-9)
    assert "line" in budget.source
    with pytest.raises(cmmpose.InputError, match="u_pressure_mmHg"):
        refractivity_uncertainty(1.0, -1.0, 1.0)


def test_wavelength_correction_of_a_reading():
    # Warm thin air: n below standard, the uncorrected reading is short; the
    # correction lengthens it by (N_std - N_air) ppm.
    air = (23.0, 750.0, 40.0)
    f = correction_factor(*air)
    ppm = refractivity(*STANDARD_AIR) - refractivity(*air)
    assert (f - 1) * 1e6 == pytest.approx(ppm, rel=1e-3)
    assert 6.0 < ppm < 6.5
    assert correct_reading(900.0, *air) == pytest.approx(900.0 * f, rel=1e-15)
    assert correction_factor(*STANDARD_AIR) == 1.0
    assert correction_factor(*air, basis="vacuum") == pytest.approx(1 / refractive_index(*air), rel=1e-15)
    assert correction_factor(*air, basis="compensated") == 1.0
    lam = wavelength_in_air_nm(632.991, *STANDARD_AIR)
    assert lam == pytest.approx(632.991 / refractive_index(*STANDARD_AIR))
    arr = correct_reading(np.array([0.0, 100.0]), [20.0, 23.0], 760.0, 50.0)
    assert arr.shape == (2,) and arr[0] == 0.0
    with pytest.raises(cmmpose.InputError, match="reading_basis"):
        correction_factor(*air, basis="laser")


# -- 2. the run file -----------------------------------------------------------------------


@pytest.mark.parametrize("component", ["dx", "dy", "ez"])
def test_run_file_round_trip(tmp_path, truth, component):
    run, _ = simulate_interferometer_run(truth, "X", component, repeats=2, seed=3)
    path = tmp_path / f"{component}.csv"
    run.write(path)
    back = InterferometerRun.read(path)
    assert back == run
    for name, col in run.columns().items():
        np.testing.assert_array_equal(back.columns()[name], col)
    assert back.component == component and back.axis == "X"
    assert back.metadata == run.metadata
    # writing the read run gives the same text
    path2 = tmp_path / "again.csv"
    back.write(path2)
    assert path2.read_text() == path.read_text()


def test_hand_written_run_file(tmp_path):
    path = tmp_path / "y_pitch.csv"
    path.write_text(
        "# cmmpose-interferometer-run: 1\n"
        "# axis: Y\n"
        "# optics: angular\n"
        "# rotation_axis: X\n"
        "# date: 2004-03-02\n"
        "# a plain comment\n"
        "target_mm,reading_arcsec,repeat,direction,air_temperature_C,pressure_mmHg,humidity_percent,material_temperature_C\n"
        "0,0.0,1,+1,22.1,748.2,41,22.0\n"
        "25,-0.6,1,+1,22.1,748.2,41,22.0\n"
        "25,-0.5,1,-1,22.1,748.2,41,22.0\n"
        "# comments after the header row are ignored\n"
        "0,0.1,1,-1,22.1,748.2,41,22.0\n",
        encoding="utf-8",
    )
    run = read_run(path)
    assert run.component == "ex" and run.column == "ex_arcsec" and run.reading_unit == "arcsec"
    assert run.metadata == {"date": "2004-03-02"}
    assert run.home_mm == 0.0 and len(run) == 4
    p = process_run(run)
    np.testing.assert_allclose(p.values, [0.0, -0.6])
    np.testing.assert_allclose(p.reversal, [-0.1, -0.1])
    assert p.temperature == pytest.approx(22.0)


@pytest.fixture
def run_file(tmp_path, truth):
    run, _ = simulate_interferometer_run(truth, "X", "dx", repeats=2, seed=5, targets=[0, 25, 50, 75])
    path = tmp_path / "x_linear.csv"
    run.write(path)
    return path


def edit(path, fn):
    lines = path.read_text(encoding="utf-8").splitlines()
    lines = fn(lines)
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def header_index(lines):
    return next(i for i, ln in enumerate(lines) if ln.startswith("target_mm"))


def read_error(path):
    with pytest.raises(InterferometerRunError) as exc:
        read_run(path)
    assert isinstance(exc.value, cmmpose.MapError) and isinstance(exc.value, cmmpose.Error)
    return str(exc.value)


def test_missing_magic_header(run_file):
    msg = read_error(edit(run_file, lambda ls: ls[1:]))
    assert f"{run_file}:1:" in msg and "not a cmmpose interferometer run" in msg


def test_missing_header_key(run_file):
    msg = read_error(edit(run_file, lambda ls: [ln for ln in ls if not ln.startswith("# axis")]))
    assert str(run_file) in msg and "'# axis: <value>' is missing" in msg


def test_missing_column_header(run_file):
    msg = read_error(edit(run_file, lambda ls: [ln for ln in ls if not ln.startswith("target_mm")]))
    assert str(run_file) in msg and "column header must be" in msg


def test_reading_column_must_carry_the_unit_of_the_optics(run_file):
    def fn(ls):
        i = header_index(ls)
        ls[i] = ls[i].replace("reading_mm", "reading_um")
        return ls

    msg = read_error(edit(run_file, fn))
    lines = run_file.read_text().splitlines()
    assert f"{run_file}:{header_index(lines) + 1}:" in msg and "reading_mm" in msg


def test_ragged_row(run_file):
    lines = run_file.read_text().splitlines()
    i = header_index(lines) + 3

    def fn(ls):
        ls[i] = ",".join(ls[i].split(",")[:-1])
        return ls

    msg = read_error(edit(run_file, fn))
    assert f"{run_file}:{i + 1}: expected 8 fields, got 7" in msg


def test_non_numeric_field(run_file):
    lines = run_file.read_text().splitlines()
    i = header_index(lines) + 2

    def fn(ls):
        f = ls[i].split(",")
        f[1] = "12.3.4"
        ls[i] = ",".join(f)
        return ls

    msg = read_error(edit(run_file, fn))
    assert f"{run_file}:{i + 1}: reading_mm '12.3.4' is not a number" in msg


def test_unknown_optics(run_file):
    lines = run_file.read_text().splitlines()
    i = next(k for k, ln in enumerate(lines) if ln.startswith("# optics"))
    msg = read_error(edit(run_file, lambda ls: [("# optics: laser" if k == i else ln) for k, ln in enumerate(ls)]))
    assert f"{run_file}:{i + 1}: unknown optics 'laser'" in msg and "linear, straightness, angular" in msg


def test_a_missing_direction(run_file):
    lines = run_file.read_text().splitlines()
    h = header_index(lines)
    # drop every -1 reading of target 50 mm
    keep = [ln for k, ln in enumerate(lines) if not (k > h and ln.split(",")[0] == "50" and ln.split(",")[3] == "-1")]
    first_50 = next(k for k, ln in enumerate(keep) if k > h and ln.split(",")[0] == "50")
    msg = read_error(edit(run_file, lambda ls: keep))
    assert f"{run_file}:{first_50 + 1}: target 50 mm has no reading in direction -1" in msg


@pytest.mark.parametrize(
    "column, value, expect",
    [
        (3, "2", "direction must be +1 or -1"),
        (3, "+1.0", "direction '+1.0' is not +1 or -1"),
        (2, "0", "repeat must be an integer >= 1"),
        (5, "1013.2", "hPa"),
        (4, "293.15", "Kelvin"),
        (6, "0.45e3", "relative humidity"),
        (1, "nan", "not finite"),
    ],
)
def test_bad_values_name_the_line(run_file, column, value, expect):
    lines = run_file.read_text().splitlines()
    i = header_index(lines) + 4

    def fn(ls):
        f = ls[i].split(",")
        f[column] = value
        ls[i] = ",".join(f)
        return ls

    msg = read_error(edit(run_file, fn))
    assert f"{run_file}:{i + 1}" in msg and expect in msg


def test_duplicate_reading(run_file):
    lines = run_file.read_text().splitlines()
    i = header_index(lines) + 2
    msg = read_error(edit(run_file, lambda ls: ls[: i + 1] + [ls[i]] + ls[i + 1:]))
    assert f"{run_file}:{i + 2}: duplicate reading" in msg and f"{run_file}:{i + 1}" in msg


def test_straightness_needs_an_error_axis_across_the_axis(tmp_path, truth):
    run, _ = simulate_interferometer_run(truth, "X", "dy", repeats=1, seed=1, targets=[0, 25])
    path = tmp_path / "s.csv"
    run.write(path)
    msg = read_error(edit(path, lambda ls: [ln for ln in ls if not ln.startswith("# error_axis")]))
    assert "straightness needs error_axis" in msg
    msg = read_error(edit(path, lambda ls: ls[:3] + ["# error_axis: X"] + ls[3:]))
    assert "error_axis must differ from X" in msg


def test_linear_needs_wavelength_and_basis(run_file):
    msg = read_error(edit(run_file, lambda ls: [ln for ln in ls if not ln.startswith("# wavelength")]))
    assert "vacuum wavelength" in msg
    # (the edit above removed the line; add it back twice)
    msg = read_error(edit(run_file, lambda ls: ls[:2] + ["# wavelength_vacuum_nm: 632.991"] * 2 + ls[2:]))
    assert f"{run_file}:4: header key 'wavelength_vacuum_nm' repeats line 3" in msg


def test_in_memory_run_is_checked_too():
    ok = dict(axis="X", optics="angular", target_mm=[0, 25, 0, 25], reading=[0, 1, 0, 1], repeat=[1, 1, 1, 1],
              direction=[1, 1, -1, -1], air_temperature_C=[20] * 4, pressure_mmHg=[760] * 4,
              humidity_percent=[50] * 4, material_temperature_C=[20] * 4, rotation_axis="Y")
    assert InterferometerRun(**ok).component == "ey"
    with pytest.raises(InterferometerRunError, match="row 3: direction must be"):
        InterferometerRun(**{**ok, "direction": [1, 1, -1, 0]})
    with pytest.raises(InterferometerRunError, match="row 1: target 25 mm has no reading in direction -1"):
        InterferometerRun(**{**ok, "direction": [1, 1, -1, 1], "repeat": [1, 1, 1, 2]})
    with pytest.raises(InterferometerRunError, match="unknown optics"):
        InterferometerRun(**{**ok, "optics": "laser"})


def test_unreadable_file(tmp_path):
    with pytest.raises(InterferometerRunError, match="cannot read"):
        read_run(tmp_path / "nope.csv")


# -- 3. processing one run -----------------------------------------------------------------


@pytest.mark.parametrize("carriage, component", [("X", "dx"), ("Z", "dz"), ("Y", "dx"), ("X", "ey")])
def test_processing_recovers_the_truth_and_the_reversal(simulated, carriage, component):
    runs, truths = simulated
    info = truths[f"{component}({carriage})"]
    p = process_run(run_of(runs, carriage, component))
    optics = optics_of(carriage, component)
    assert p.optics == optics and p.component == component and p.axis == carriage
    np.testing.assert_array_equal(p.positions_mm, info["positions"])
    err = p.values - info["values"]
    assert np.max(np.abs(err)) < tolerance(optics)
    assert p.values[np.searchsorted(p.positions_mm, info["home"])] == 0.0
    # Reversal: (+1) - (-1), each a mean of REPEATS readings.
    sigma_rev = DEFAULT_NOISE[optics] * math.sqrt(2 / REPEATS)
    assert np.max(np.abs(p.reversal - DEFAULT_REVERSAL[optics])) < K * sigma_rev
    assert np.mean(p.reversal) == pytest.approx(DEFAULT_REVERSAL[optics], abs=4 * sigma_rev / math.sqrt(len(p.reversal)))
    # Repeatability estimates the simulated noise of one reading.
    assert np.sqrt(np.mean(p.repeatability**2)) == pytest.approx(DEFAULT_NOISE[optics], rel=0.2)
    assert np.all(p.repeats == REPEATS)
    assert p.temperature == pytest.approx(20.0, abs=0.01)


def test_linear_run_is_air_corrected_and_reports_its_uncertainty(simulated):
    runs, truths = simulated
    p = process_run(run_of(runs, "X", "dx"))
    assert p.air_corrected
    # the correction undoes the simulated index error
    assert p.index_correction_ppm == pytest.approx(-truths["dx(X)"]["index_error_ppm"], abs=0.01)
    assert p.u_index_ppm == pytest.approx(refractivity_uncertainty(*THESIS_AIR_UNCERTAINTY))
    # u_N of the distance from home: 1.36 ppm of 900 mm = 1.2 um
    assert p.wavelength_uncertainty[-1] == pytest.approx(900 * p.u_index_ppm * 1e-3)
    assert p.wavelength_uncertainty[0] == 0.0
    assert "air correction" in p.table()


def test_without_the_air_correction_linear_components_are_off_by_the_expected_ppm(simulated):
    runs, truths = simulated
    for c in cmmpose.CARRIAGES:
        comp = "d" + c.lower()
        run = run_of(runs, c, comp)
        info = truths[f"{comp}({c})"]
        good = process_run(run)
        bad = process_run(run, air_correction=False)
        assert not bad.air_corrected
        travel = bad.positions_mm - info["home"]  # mm, from home
        diff = bad.values - good.values  # um
        slope_ppm = np.polyfit(travel, diff, 1)[0] * 1e3  # um/mm -> ppm
        assert slope_ppm == pytest.approx(info["index_error_ppm"], abs=0.1)
        assert info["index_error_ppm"] < -6.0  # several ppm: the default air is 23 C, 750 mmHg, 40 % RH
        # ... which is far more than the noise: at the far end several um
        assert np.max(np.abs(bad.values - info["values"])) > 10 * tolerance("linear")


def test_straightness_and_angular_readings_are_not_air_corrected(simulated):
    runs, _ = simulated
    for comp, c in (("dy", "X"), ("ez", "Y")):
        run = run_of(runs, c, comp)
        a, b = process_run(run), process_run(run, air_correction=False)
        assert not a.air_corrected and a.u_index_ppm == 0.0
        np.testing.assert_array_equal(a.values, b.values)


def test_a_weather_station_error_of_one_degree_shows_as_one_ppm(truth):
    plain, info = simulate_interferometer_run(truth, "X", "dx", seed=11)
    biased, _ = simulate_interferometer_run(truth, "X", "dx", seed=11, station_error=(1.0, 0.0, 0.0))
    diff = process_run(biased).values - process_run(plain).values
    slope_ppm = np.polyfit(process_run(plain).positions_mm, diff, 1)[0] * 1e3
    assert slope_ppm == pytest.approx(-refractivity_partials(*info["air_mean"])["air_temperature_C"], abs=0.02)


@pytest.mark.parametrize("basis", ["vacuum", "compensated"])
def test_other_reading_bases(truth, basis):
    run, info = simulate_interferometer_run(truth, "Y", "dy", seed=2, reading_basis=basis)
    p = process_run(run)
    assert np.max(np.abs(p.values - info["values"])) < tolerance("linear")
    if basis == "vacuum":
        assert info["index_error_ppm"] > 260  # n - 1 of the air
    else:
        assert not p.air_corrected and p.index_correction_ppm == 0.0


def test_air_correction_refuses_a_laser_that_is_not_hene(truth):
    run, _ = simulate_interferometer_run(truth, "X", "dx", seed=2, wavelength_vacuum_nm=532.0, targets=[0, 25])
    with pytest.raises(cmmpose.InputError, match="HeNe"):
        process_run(run)
    process_run(run, air_correction=False)  # readings corrected elsewhere


def test_material_temperature_kept_or_normalised_to_20C(thesis_maps):
    truth25 = thesis_maps[1]
    run, info = simulate_interferometer_run(truth25, "X", "dx", seed=4)
    keep = process_run(run)
    assert keep.temperature == pytest.approx(25.0) and keep.material == "keep"
    assert np.max(np.abs(keep.values - info["values"])) < tolerance("linear")
    norm = process_run(run, material="normalise", expansion_ppm_per_C=12.0)
    assert norm.temperature == 20.0 and norm.material_temperature_C[0] == pytest.approx(25.0)
    # the 20 C error of a scale expanding 12 ppm/C: 5 C * 12 ppm less per mm of travel
    expected = keep.values - 12e-6 * 5.0 * (keep.positions_mm - keep.home_mm) * 1e3
    np.testing.assert_allclose(norm.values, expected, atol=0.01)
    assert norm.values[-1] - keep.values[-1] == pytest.approx(-54.0, abs=0.05)  # thesis line 822: 54 um at 900 mm
    with pytest.raises(cmmpose.InputError, match="expansion_ppm_per_C"):
        process_run(run, material="normalise")


def test_straightness_line_removal(truth):
    run, info = simulate_interferometer_run(truth, "Y", "dx", seed=8)
    cols = run.columns()
    tilted = InterferometerRun(
        run.axis, run.optics, run.target_mm, run.reading + 0.01 * run.target_mm + 3.0, run.repeat, run.direction,
        run.air_temperature_C, run.pressure_mmHg, run.humidity_percent, cols["material_temperature_C"],
        error_axis=run.error_axis)
    p = process_run(tilted, straightness_line="least_squares")
    x = info["positions"]
    ref = info["values"] - np.polyval(np.polyfit(x, info["values"], 1), x)
    ref -= ref[np.searchsorted(x, info["home"])]
    assert np.max(np.abs(p.values - ref)) < tolerance("straightness")
    pe = process_run(tilted, straightness_line="endpoint")
    assert pe.values[0] == pytest.approx(0.0) and pe.values[-1] == pytest.approx(0.0, abs=1e-9)
    with pytest.raises(cmmpose.InputError, match="only for straightness"):
        process_run(run_of(simulate_interferometer_runs(truth, seed=1)[0], "X", "dx"), straightness_line="endpoint")


# -- 4. the whole map ------------------------------------------------------------------------


@pytest.mark.parametrize("which", [0, 1, 2])
def test_a_map_built_from_simulated_runs_reproduces_the_truth(thesis_maps, which):
    truth = thesis_maps[which]
    runs, truths = simulate_interferometer_runs(truth, repeats=REPEATS, seed=100 + which)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # nothing missing, nothing truncated
        built = build_map(runs, truth.squareness)
    m = built.map
    assert isinstance(m, cmmpose.ErrorMap) and built.missing == ()
    assert m.temperature == pytest.approx(truth.temperature, abs=0.01)
    assert m.squareness == truth.squareness
    cmp = compare_maps(m, truth)
    for c in cmmpose.CARRIAGES:
        np.testing.assert_array_equal(m.table(c)[:, 0], truth.table(c)[:, 0])
        for col in cmmpose.TABLE_COLUMNS[1:]:
            comp = col.split("_")[0]
            tol = tolerance(optics_of(c, comp))
            assert cmp.max_difference[c][col] < tol, (c, col, cmp.max_difference[c][col], tol)
    # and the map works in the model
    scales = np.array([[450.0, 275.0, -250.0]])
    assert np.max(np.abs(m.position_error(scales) - truth.position_error(scales))) < 0.002  # mm


def test_without_air_correction_the_map_is_off_by_ppm_of_travel(truth, simulated):
    runs, truths = simulated
    bad = map_from_runs(runs, truth.squareness, air_correction=False)
    cmp = compare_maps(bad, truth)
    ppm = truths["dx(X)"]["index_error_ppm"]
    assert cmp.max_difference["X"]["dx_um"] == pytest.approx(abs(ppm) * 900e-3, abs=tolerance("linear"))
    assert cmp.max_difference["Y"]["dy_um"] == pytest.approx(abs(truths["dy(Y)"]["index_error_ppm"]) * 550e-3,
                                                              abs=tolerance("linear"))
    assert cmp.max_difference["X"]["ey_arcsec"] < tolerance("angular")  # angles unaffected


def test_unmeasured_rolls_are_zero_and_reported(truth):
    runs, _ = simulate_interferometer_runs(truth, include_roll=False, seed=3)
    assert len(runs) == 15
    with pytest.warns(InterferometerWarning, match=r"ex\(X\), ey\(Y\), ez\(Z\).*line 793"):
        built = build_map(runs, truth.squareness, temperature=20.0)
    assert built.missing == ("ex(X)", "ey(Y)", "ez(Z)")
    assert "ex(X)" in built.map.source
    for c, col in (("X", 4), ("Y", 5), ("Z", 6)):
        assert np.all(built.map.table(c)[:, col] == 0.0)


def test_assembly_errors(truth, simulated):
    runs, _ = simulated
    with pytest.raises(InterferometerRunError, match=r"two runs for dx\(X\)"):
        build_map(runs + [run_of(runs, "X", "dx")], truth.squareness)
    with pytest.raises(InterferometerRunError, match="no run for the Y carriage"):
        build_map([r for r in runs if r.axis != "Y"], truth.squareness)
    with pytest.raises(cmmpose.InputError, match="squareness"):
        build_map(runs, (1.0, 2.0))
    with pytest.raises(cmmpose.InputError, match="runs\\[0\\]"):
        build_map(["x.csv"], truth.squareness)
    keep = process_run(run_of(runs, "X", "dx"))
    norm = process_run(run_of(runs, "X", "dy"), material="normalise", expansion_ppm_per_C=12)
    with pytest.raises(InterferometerRunError, match="mix material"):
        build_map([keep, norm] + [r for r in runs if r.axis != "X"], truth.squareness)


def test_assembly_on_different_grids_truncates_and_warns(truth):
    lin, _ = simulate_interferometer_run(truth, "X", "dx", seed=1)  # 0..900 every 25
    yaw, _ = simulate_interferometer_run(truth, "X", "ez", seed=2, targets=np.arange(0, 851, 50.0))
    others = [r for r in simulate_interferometer_runs(truth, seed=3)[0] if r.axis != "X"]
    with pytest.warns(InterferometerWarning) as record:
        m = map_from_runs([lin, yaw] + others, truth.squareness)
    messages = [str(w.message) for w in record]
    assert any("truncated to the common range 0..850 mm" in t for t in messages)
    assert any("dy(X), dz(X), ex(X), ey(X)" in t for t in messages)
    x = m.table("X")
    assert x[-1, 0] == 850.0 and len(x) == 35  # the 25 mm grid up to 850


def test_temperature_spread_warns(truth, thesis_maps):
    runs = simulate_interferometer_runs(truth, seed=3)[0]
    warm, _ = simulate_interferometer_run(truth, "X", "dx", seed=1, material_temperature=22.0)
    runs = [warm if (r.axis, r.component) == ("X", "dx") else r for r in runs]
    with pytest.warns(InterferometerWarning, match="spread 2.00 C"):
        built = build_map(runs, truth.squareness)
    assert built.temperature == pytest.approx(20.0 + 2.0 / 18, abs=0.001)


def test_compare_identical_maps_is_zero(truth):
    cmp = compare_maps(truth, truth)
    for c in cmmpose.CARRIAGES:
        assert np.all(cmp.differences[c] == 0.0)
        assert all(v == 0.0 for v in cmp.max_difference[c].values())
    assert cmp.squareness_difference == (0.0, 0.0, 0.0) and cmp.temperature_difference == 0.0
    assert cmp.max_um == 0.0 and cmp.max_arcsec == 0.0
    assert "max |a - b|" in str(cmp)


def test_compare_maps_on_a_common_grid(truth):
    # b: X on a coarser grid (every 50 mm), Y shorter (0..500 mm) with 1 um added
    # to dz(Y), and 2 arc-seconds added to S_xy.
    tx, ty, tz = (truth.table(c).copy() for c in cmmpose.CARRIAGES)
    bx = tx[::2]
    by = ty[ty[:, 0] <= 500.0]
    by[:, 3] += 1.0
    sq = np.array(truth.squareness) + [2.0, 0.0, 0.0]
    b = cmmpose.ErrorMap(bx, by, tz, sq, 25.0)
    cmp = compare_maps(b, truth)
    np.testing.assert_array_equal(cmp.positions["X"], tx[:, 0])  # union of the grids
    np.testing.assert_array_equal(cmp.positions["Y"], by[:, 0])  # common range
    shared = np.isin(cmp.positions["X"], bx[:, 0])
    assert np.all(cmp.differences["X"][shared] == 0.0)
    assert np.any(cmp.differences["X"][~shared] != 0.0)  # b is linear between its 50 mm nodes
    assert cmp.max_difference["Y"]["dz_um"] == pytest.approx(1.0)
    assert cmp.max_difference["Y"]["dy_um"] == 0.0
    assert all(v == 0.0 for v in cmp.max_difference["Z"].values())
    assert cmp.squareness_difference == (2.0, 0.0, 0.0) and cmp.temperature_difference == 5.0
    assert cmp.max_arcsec >= 2.0


def test_plot_map_difference(tmp_path, truth, simulated):
    pytest.importorskip("matplotlib")
    from matplotlib.figure import Figure

    from cmmpose.calibration.interferometer import plot_map_difference

    built = map_from_runs(simulated[0], truth.squareness)
    path = tmp_path / "difference.png"
    fig = plot_map_difference(built, truth, path, labels=("interferometer", "truth"))
    assert isinstance(fig, Figure) and len(fig.axes) == 6
    assert path.stat().st_size > 10_000
    assert all(len(ax.lines) == 4 for ax in fig.axes)  # 3 components + zero line
    with pytest.raises(cmmpose.InputError, match="ErrorMap"):
        plot_map_difference(built, "truth.csv")
