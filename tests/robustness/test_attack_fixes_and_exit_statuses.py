"""Issue 35, the rest of the doors: each fix behind an attack of scripts/hostile_inputs.py, tested in the library
and on the command line (a test for each, failing before its fix), and one exit status per kind of failure: a
missing input is a usage error, exit 2, in every command."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys

import numpy as np
import pytest
from click.testing import CliRunner

import cmmpose
from cmmpose.cli import main
from cmmpose.errors import InputError, RunError, UserEffectError

SCAN = cmmpose.data_path("examples", "sphere_scan.csv")


def invoke(*args, **kw):
    return CliRunner().invoke(main, [str(a) for a in args], **kw)


# -- simulate: a speed or a jitter that measures nothing -----------------------------------------------------------

@pytest.mark.parametrize("options, words", [
    ({"speed": 1e-320}, r"speed: .* too slow"),
    ({"speed": 1e308}, r"speed: 1e\+308 mm/s lets fewer than 3 profiles cross a ball"),
    ({"speed": 1000.0}, r"at most 168 mm/s"),
    ({"jitter": 1e305}, r"jitter: 1e\+305 mm is beyond 1 mm per axis"),
])
def test_simulate_refuses_a_speed_or_jitter_that_measures_nothing(options, words):
    from cmmpose.sim import simulate_ballbar_run

    with pytest.raises(InputError, match=words):
        simulate_ballbar_run(None, 20.0, (), **options)


def test_an_artefact_run_refuses_a_sweep_of_a_million_profiles_and_a_metre_of_jitter():
    from cmmpose import artefacts
    from cmmpose.sim.artefact_runs import simulate_artefact_run

    plate = artefacts.load_artefact("koba-0320")
    with pytest.raises(InputError, match="too slow"):
        simulate_artefact_run(plate, ["xy"], speed=1e-320)
    with pytest.raises(InputError, match="jitter"):
        simulate_artefact_run(plate, ["xy"], jitter=1e3)


def test_simulate_cli_writes_no_empty_run(tmp_path):
    for option in (("--speed", "1e308"), ("--speed", "1e-320"), ("--jitter", "1e308")):
        r = invoke("simulate", *option, "-o", tmp_path / "r")
        assert r.exit_code == 1 and "Traceback" not in r.output and not (tmp_path / "r").exists(), r.output


# -- user effects ---------------------------------------------------------------------------------------------------

def _inputs(n=5):
    z = np.zeros(n)
    return {k: z for k in ("u", "v", "D", "E", "F", "t", "temperature", "x", "y", "z", "scan_id", "pose_id",
                           "incidence")}


def test_a_user_effect_returning_complex_values_is_refused_not_truncated():
    from cmmpose.model import UserEffect

    effect = UserEffect.create("ripple", lambda inputs, a_um: np.full((len(inputs["u"]), 3), 1 + 1j) * a_um,
                               {"a_um": ("um", 1.0)})
    with pytest.raises(UserEffectError, match="returned complex values"):
        effect.correction(_inputs(), [1.0])


@pytest.mark.parametrize("name", ["rip\x1b[2Jple", "a\nb", "x\x7f"])
def test_a_user_effect_name_with_a_control_character_is_refused(name):
    from cmmpose.model import UserEffect

    with pytest.raises(InputError, match="a name is printable text") as info:
        UserEffect.create(name, lambda inputs, a_um: np.zeros((len(inputs["u"]), 3)), {"a_um": ("um", 1.0)})
    assert "\x1b" not in str(info.value) and "\n" not in str(info.value)


# -- names and numbers typed in other scripts ---------------------------------------------------------------------

def test_arabic_indic_digits_are_not_numbers_in_a_placement_or_a_pose(tmp_path):
    from cmmpose.placement import parse

    with pytest.raises(InputError, match="is not a number of mm"):
        parse("xy@z=-٥٢٥")
    r = invoke("compensate", SCAN, tmp_path / "o.csv", "--maps", "thesis", "--pose", "٩٠,90,0", "--offset",
               "1.001,264.505,129.575")
    assert r.exit_code == 2 and "--pose" in r.output and not (tmp_path / "o.csv").exists()


def test_an_artefact_radius_of_5e_324_is_refused():
    from cmmpose import artefacts
    from cmmpose.schemas.artefact import MIN_RADIUS_MM

    doc = artefacts.load_artefact("reference-sphere").to_dict()
    doc["radius"].update(nominal_mm=5e-324, calibrated_mm=5e-324)
    with pytest.raises(InputError, match=rf"radius\.nominal_mm: must be finite and >= {MIN_RADIUS_MM:g} mm"):
        artefacts.parse_artefact(doc, "s.toml")


def test_a_400_digit_number_in_a_triple_is_refused_by_its_size():
    from cmmpose._validate import triple

    with pytest.raises(InputError, match=r"^r: expected three finite numbers, got \[<400 digits>, 1, 2\]$"):
        triple("r", [10**399, 1, 2])


# -- plan: --sigma, the plan file's integers --------------------------------------------------------------------

def test_plan_sigma_is_a_noise_a_cmm_can_have(tmp_path, simulated_run):
    simulated_run.save(tmp_path / "r")
    for sigma in ("1e-320", "1e9"):
        r = invoke("plan", tmp_path / "r", "--sigma", sigma)
        assert r.exit_code == 2 and "--sigma" in r.output and "0" * 40 not in r.output, r.output


def test_plan_for_an_unknown_effect_is_a_usage_error_listing_the_known_ones(tmp_path, simulated_run):
    simulated_run.save(tmp_path / "r")
    r = invoke("plan", tmp_path / "r", "--plan-for", "squarenes")
    assert r.exit_code == 2 and "--plan-for" in r.output and "squareness" in r.output, r.output


def test_a_plan_id_beyond_int32_is_refused_when_read(tmp_path):
    from cmmpose.acquire.plan import Plan, artefact_plan
    from cmmpose.errors import AcquisitionError

    doc = artefact_plan("koba-0320", ["xy"]).to_dict()
    doc["scans"][0]["scan_id"] = 2**31
    (tmp_path / "p.json").write_text(json.dumps(doc))
    with pytest.raises(AcquisitionError, match=r"scans\[0\]: scan_id = 2147483648 is not an integer that fits its "
                                               r"int32 column"):
        Plan.read(tmp_path / "p.json")


# -- compensate --model of another machine configuration -----------------------------------------------------------

def test_compensate_model_stacked_for_another_configuration_is_refused(tmp_path):
    from cmmpose.model import Model

    Model(cmmpose.ErrorMapSet.thesis().with_kinematics("gantry")).save(tmp_path / "mg.json")
    r = invoke("compensate", SCAN, tmp_path / "o.csv", "--model", tmp_path / "mg.json", "--pose", "90,90,0")
    assert r.exit_code == 1 and "stacked as 'gantry'" in r.output and "'thesis'" in r.output, r.output
    assert not (tmp_path / "o.csv").exists()


# -- evaluate: a duplicated scan before the declared repeats ----------------------------------------------------------

def test_a_duplicated_scan_before_the_declared_repeats_is_ambiguous():
    """A run declaring 6 repeated scans at its end: scan 5 relabelled as scan 4's ball is a duplicate, not a
    repeat (before, the repeats' count hid it and evaluate answered in silence)."""
    from cmmpose.evaluation.ballbar import ballbar_scans
    from cmmpose.scanner import Scanner
    from cmmpose.sim import simulate_ballbar_run

    run, _ = simulate_ballbar_run(None, 20.0, (), repeat_scans=6, scanner=Scanner(points_per_profile=64))
    positions, skipped = ballbar_scans(run)  # the declared repeats alone: complete
    assert not skipped and len(positions) == 20
    scans = {k: np.array(v, copy=True) for k, v in run.scans.items()}
    scans["position"][5], scans["ball"][5] = scans["position"][4], scans["ball"][4]
    with pytest.raises(RunError, match=r"scans 4, 5.*duplicated"):
        ballbar_scans(dataclasses.replace(run, scans=scans))


# -- RAYON_NUM_THREADS ---------------------------------------------------------------------------------------------

def test_the_thread_count_from_the_environment_is_bounded():
    from cmmpose._threads import thread_limit

    code = "import os, cmmpose; print(os.environ['RAYON_NUM_THREADS'], cmmpose.thread_count())"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                         env={**os.environ, "RAYON_NUM_THREADS": "100000"})
    assert out.returncode == 0, out.stderr
    told, used = map(int, out.stdout.split())
    assert told == thread_limit() and used <= thread_limit()
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                         env={**os.environ, "RAYON_NUM_THREADS": "2"})
    assert out.stdout.split()[0] == "2"


# -- one exit status per kind of failure: a missing input exits 2 in every command ---------------------------------

MISSING = [
    ("compensate", "nothing.csv", "o.csv", "--maps", "thesis"),
    ("compensate", "a.csv", "o.csv", "--machine", "nothing.toml"),
    ("compensate", "a.csv", "o.csv", "--model", "nothing.json", "--pose", "90,90,0"),
    ("evaluate", "nothing"),
    ("standards", "iso230-2", "nothing.csv"),
    ("standards", "acceptance", "nothing", "--mpe-form", "1", "--mpe-size", "1", "--mpe-length", "1"),
    ("diagnose", "nothing"),
    ("diagnose-fits", "nothing.csv"),
    ("fit", "nothing.csv"),
    ("plan", "nothing"),
    ("simulate", "--machine", "nothing.toml", "-o", "r"),
    ("calibrate", "offset", "A", "B", "C", "--library", "nothing.json"),
    ("calibrate", "alignment", "--vernier", "nothing.csv", "--plane-scan", "p.csv", "--plane-normal", "0,0,1",
     "--reference-scan", "s.csv", "--name", "A", "--library", "lib.json"),
    ("map", "import", "iso230-2", "nothing.csv", "-o", "x.csv"),
    ("map", "import", "linuxcnc", "X=nothing.comp", "-o", "x.csv"),
    ("map", "export", "nothing.csv", "--format", "iso230-2", "-o", "y.csv"),
    ("map", "table-motion", "nothing.csv", "-o", "t.csv", "--carriage", "X", "--measured-at", "0,0,0",
     "--part-point", "0,0,0"),
    ("map", "plot", "nothing.csv", "-o", "p.png"),
    ("machine", "check", "nothing.toml"),
    ("artefact", "check", "nothing.toml"),
    ("artefact", "show", "nothing.toml"),
    ("acquire", "--recover", "-o", "nothing"),
]


@pytest.mark.parametrize("args", MISSING, ids=[" ".join(a[:2]) + (f" {a[2]}" if a[0] in ("map", "calibrate") else "")
                                               for a in MISSING])
def test_a_missing_input_is_a_usage_error_in_every_command(tmp_path, monkeypatch, args):
    """docs/formats.md, "Exit status": 2 for a usage error, a missing input among them, naming it."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "a.csv").write_bytes(SCAN.read_bytes())
    r = invoke(*args)
    assert r.exit_code == 2, (r.exit_code, r.output)
    assert "nothing" in r.output and "Traceback" not in r.output


# -- text from files shown as text, never as Rich markup ------------------------------------------------------------

def test_a_file_name_holding_rich_markup_is_printed_as_text(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    rows = ["target_mm,direction,cycle,deviation_um"] + [f"{t},{d},{c},{1.0 + 0.01 * t + 0.3 * c}"
                                                        for t in range(0, 500, 50) for d in (1, -1) for c in range(1, 6)]
    (tmp_path / "[").mkdir()
    (tmp_path / "[" / "b].csv").write_text("\n".join(rows) + "\n")
    r = invoke("standards", "iso230-2", "[/b].csv")
    assert r.exit_code == 0 and "ISO 230-2 positioning: [/b].csv" in r.output, r.output


def test_an_artefact_name_holding_rich_markup_is_shown_as_written():
    from cmmpose import artefacts
    from cmmpose.evaluation.artefact import evaluate_artefact
    from cmmpose.scanner import Scanner
    from cmmpose.sim.artefact_runs import simulate_artefact_run

    doc = artefacts.load_artefact("koba-0320").to_dict()
    doc["name"] = "[/bold][red]KOBA"
    plate = artefacts.parse_artefact(doc, "p.toml")
    run, _ = simulate_artefact_run(plate, ["xy"], scanner=Scanner(points_per_profile=128), seed=1, repeat_scans=0)
    assert "Artefact evaluation: [/bold][red]KOBA (ball-plate)" in str(evaluate_artefact(run, None))


# -- --temperature: within a CMM room's range, said in a sensible precision -------------------------------------------

@pytest.mark.parametrize("value, words", [
    ("-273.16", r"-273\.16 C \(below absolute zero, -273\.15 C\) is outside -50\.\.150 C"),
    ("1e6", r"1e\+06 C is outside -50\.\.150 C"),
    ("nan", r"nan C is outside"),
    ("٢٢", r"expected a temperature in degrees C"),
])
def test_a_temperature_option_out_of_a_rooms_range_is_a_usage_error(tmp_path, value, words):
    import re

    for command in (("compensate", SCAN, tmp_path / "o.csv", "--maps", "thesis", "--pose", "90,90,0",
                     "--out-of-range", "extrapolate"), ("simulate", "-o", tmp_path / "r")):
        r = invoke(*command, "--temperature", value)
        assert r.exit_code == 2 and "--temperature" in r.output and re.search(words, r.output), r.output
        assert not (tmp_path / "o.csv").exists() and not (tmp_path / "r").exists()


def test_a_long_decimal_is_said_in_six_significant_digits():
    from cmmpose.policy import shorten_numbers

    assert shorten_numbers("temperature 0." + "0" * 319 + "1 C is") == "temperature 9.99989e-321 C is"
    assert shorten_numbers("1.5 and 22.125 and 0.123456789") == "1.5 and 22.125 and 0.123456789"


# -- diagnose-fits --artefact: ids beyond a C long, centres in another unit -----------------------------------------

def _plate_rows():
    from cmmpose import artefacts

    plate = artefacts.load_artefact("koba-0420")
    rows = ["placement,ball,x_mm,y_mm,z_mm,radius_mm"]
    for p, (rot, shift) in enumerate(((np.eye(3), [300.0, 100.0, -500.0]),
                                      (np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]]), [600.0, 100.0, -400.0])), 1):
        for b, c in zip(plate.ids.tolist(), plate.centres @ rot.T + shift):
            rows.append(f"{p},{b},{float(c[0])!r},{float(c[1])!r},{float(c[2])!r},{float(plate.calibrated_radius)!r}")
    return plate, rows


def test_a_placement_beyond_a_c_long_is_refused_naming_the_line(tmp_path):
    from cmmpose.diagnosis.plate_fits import read_plate_fits

    _, rows = _plate_rows()
    rows[1] = "9" * 25 + rows[1][1:]
    (tmp_path / "f.csv").write_text("\n".join(rows) + "\n")
    with pytest.raises(InputError, match=r"f\.csv:2: placement and ball are numbers >= 1 that fit a C long .*"
                                         r"a 25-digit number") as info:
        read_plate_fits(tmp_path / "f.csv")
    assert "9" * 25 not in str(info.value)


@pytest.mark.parametrize("factor, unit", [(1000.0, "um"), (1 / 25.4, "inches"), (1e-3, "metres")])
def test_fitted_centres_in_another_unit_are_refused(tmp_path, factor, unit):
    from cmmpose.diagnosis.plate_fits import diagnose_plate_fits, read_plate_fits

    plate, rows = _plate_rows()
    diagnose_plate_fits(plate, _read(tmp_path, rows, read_plate_fits))  # in mm: diagnosed
    scaled = [rows[0]] + [",".join([*r.split(",")[:2], *(repr(float(v) * factor) for v in r.split(",")[2:5]),
                                    r.split(",")[5]]) for r in rows[1:]]
    with pytest.raises(InputError, match=rf"placement 1: the measured centres are .* times as far apart as the "
                                         rf"certificate's .*look like {unit}, not mm"):
        diagnose_plate_fits(plate, _read(tmp_path, scaled, read_plate_fits))


def _read(tmp_path, rows, reader):
    (tmp_path / "f.csv").write_text("\n".join(rows) + "\n")
    return reader(tmp_path / "f.csv")


# -- ErrorMap: a temperature label is a number ----------------------------------------------------------------------

@pytest.mark.parametrize("value, error", [("22", cmmpose.InputTypeError), (True, cmmpose.InputTypeError),
                                          (float("nan"), cmmpose.MapError)])
def test_an_error_map_temperature_is_a_finite_number_never_text(value, error):
    m = cmmpose.ErrorMapSet.thesis().maps[0]
    with pytest.raises(error, match="temperature"):
        cmmpose.ErrorMap(m.table("X"), m.table("Y"), m.table("Z"), m.squareness, temperature=value)
    with pytest.raises(error, match="temperature"):
        m.with_temperature(value)
    assert m.with_temperature(np.float64(21.5)).temperature == 21.5 and m.with_temperature(None).temperature is None


# -- a 400-digit number anywhere in the alignment library or the plan: refused by its size, never an OverflowError --

@pytest.mark.parametrize("key, value", [("temperature", 10**400), ("pose_covariance", [[10**400, 0, 0], [0, 1, 0],
                                                                                        [0, 0, 1]]),
                                        ("residuals", {"r": 10**400}), ("reading", [10**400, 1, 2])])
def test_a_400_digit_number_in_an_alignment_library_is_refused(tmp_path, key, value):
    from cmmpose.calibration import AlignmentLibrary, AlignmentRecord
    from cmmpose.errors import CalibrationError

    lib = AlignmentLibrary(tmp_path / "lib.json")
    lib.save("A", AlignmentRecord(pose=(1, 2, 3), reading=(1, 2, 3), offset=(0, 0, 0)))
    doc = json.loads(lib.path.read_text())
    doc["poses"]["A"][key] = value
    lib.path.write_text(json.dumps(doc))
    with pytest.raises(CalibrationError, match=rf"lib\.json: pose 'A': .*{key.split('_')[0].rstrip('s')}") as info:
        lib.load("A")
    assert "0" * 40 not in str(info.value)


@pytest.mark.parametrize("where, key", [("scans", "sweep_speed"), ("poses", "alpha")])
def test_a_400_digit_number_in_a_plan_float_column_is_refused(tmp_path, where, key):
    from cmmpose.acquire.plan import Plan, artefact_plan
    from cmmpose.errors import AcquisitionError

    doc = artefact_plan("koba-0320", ["xy"]).to_dict()
    doc[where][0][key] = 10**400
    (tmp_path / "p.json").write_text(json.dumps(doc))
    with pytest.raises(AcquisitionError, match=rf"{where}\[0\]: {key} = a 401-digit integer is not a finite number"):
        Plan.read(tmp_path / "p.json")


def test_diagnose_refuses_an_unknown_added_effect_and_an_unphysical_temperature_as_usage_errors(tmp_path,
                                                                                                simulated_run):
    run_dir = tmp_path / "run"
    simulated_run.save(run_dir)
    r = CliRunner().invoke(main, ["diagnose", str(run_dir), "--add", "bogus"])
    assert r.exit_code == 2 and "--add" in r.output and "'bogus': unknown; available:" in r.output, r.output
    for command in (["diagnose", str(run_dir)], ["diagnose-fits", str(tmp_path / "fits.csv")]):
        r = CliRunner().invoke(main, [*command, "--temperature", "500"])
        assert r.exit_code == 2 and "--temperature" in r.output, r.output
