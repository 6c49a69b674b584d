"""Usage errors and warnings on the command line: a usage error, not a traceback, for a plot name matplotlib cannot
save or a negative seed; cmmpose's warnings as one clean line each, once; no pass/fail from an ill-conditioned probing
fit; an effect that would simulate nothing or names a parameter twice refused; an expansion coefficient in the machine
file's range on every command that takes one."""

import re
import subprocess
import sys
import warnings
from pathlib import Path

import click
import numpy as np
import pytest
from click.testing import CliRunner

import cmmpose
from cmmpose import effects as effects_registry
from cmmpose.cli import main
from cmmpose.cli.common import check_plot_path, cli_warnings, expansion_ppm, parse_effects
from cmmpose.errors import ClampWarning, IllConditionedFit
from cmmpose.machine import EXPANSION_RANGE_PPM
from cmmpose.sim.effects import inert
from cmmpose.standards.acceptance import NO_DECISION, probing_test

INTERFEROMETER = Path(cmmpose.data_path("examples", "interferometer"))
RAW_WARNING = re.compile(r"\.py:\d+: \w+")  # Python's `file.py:123: Category: message`


def invoke(args):
    return CliRunner().invoke(main, [str(a) for a in args])


def cli(args, cwd):
    """The installed command line in a process of its own (Python's warning machinery as a user meets it)."""
    return subprocess.run([sys.executable, "-m", "cmmpose.cli", *map(str, args)], cwd=cwd, capture_output=True,
                          text=True, timeout=300)


def cap_points(half_angle_deg, n=3000, radius=12.5, noise=0.002, seed=0):
    """Points on a spherical cap about +z of ``half_angle_deg``, mm, with normal noise of ``noise`` mm."""
    rng = np.random.default_rng(seed)
    theta = np.arccos(rng.uniform(np.cos(np.radians(half_angle_deg)), 1, n))
    phi = rng.uniform(0, 2 * np.pi, n)
    p = radius * np.c_[np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)]
    return p + rng.normal(0, noise, p.shape)


# -- 1. plot names and seeds: usage errors before any work --------------------------------------------------------


def _no_traceback(r, flag):
    assert r.exit_code == 2, r.output  # a usage error
    assert r.exception is None or isinstance(r.exception, SystemExit), repr(r.exception)
    assert "Traceback" not in r.output and flag in r.output, r.output


@pytest.mark.parametrize("command", ["map plot", "iso230-2", "acceptance", "e3125-distances", "calibrate map"])
def test_a_plot_name_matplotlib_cannot_save_is_a_usage_error_before_any_work(tmp_path, command):
    pytest.importorskip("matplotlib")
    pairs = tmp_path / "pairs.csv"
    pairs.write_text("a,b,reference_mm\nA,B,100\n")
    out_map = tmp_path / "map.csv"
    args = {
        "map plot": ["map", "plot", "thesis", "-o", tmp_path / "maps.txt"],
        "iso230-2": ["standards", "iso230-2", INTERFEROMETER / "x_dx.csv", "--plot", tmp_path / "x.txt"],
        "acceptance": ["standards", "acceptance", tmp_path, "--mpe-form", "12", "--mpe-size", "10", "--mpe-length",
                       "8+L/300", "--plot", tmp_path / "a.txt"],
        "e3125-distances": ["standards", "e3125-distances", f"A={pairs}", f"B={pairs}", "--pairs", pairs,
                            "--radius", "50", "--plot", tmp_path / "d.txt"],
        "calibrate map": ["calibrate", "map", *sorted(INTERFEROMETER.glob("*.csv")), "--squareness", "-173,-19,21",
                          "-o", out_map, "--compare", "thesis@20", "--plot", tmp_path / "diff.txt"],
    }[command]
    r = invoke(args)
    _no_traceback(r, "'.txt' is not an image format")
    assert ".png" in r.output and ".pdf" in r.output  # what it can be
    assert not out_map.exists()  # calibrate map: nothing written before the refusal
    assert not list(tmp_path.glob("*.txt"))


def test_the_plot_check_takes_what_matplotlib_saves():
    pytest.importorskip("matplotlib")
    for name in ("a.png", "a.PDF", "b.svg", "c", "dir.v2/plot.png", None):
        check_plot_path(name, "--plot")
    with pytest.raises(click.BadParameter, match="'.csv' is not an image format"):
        check_plot_path("plot.csv", "--plot")


def test_the_map_is_compared_before_it_is_written(tmp_path):
    # a --compare that cannot be read or is not one map is refused before map.csv is written, not after
    for compare in ("thesis@abc", "thesis", str(tmp_path / "missing.csv")):
        out = tmp_path / "map.csv"
        r = invoke(["calibrate", "map", *sorted(INTERFEROMETER.glob("*.csv")), "--squareness", "-173,-19,21",
                    "-o", out, "--compare", compare])
        assert r.exit_code != 0 and "Traceback" not in r.output, r.output
        assert r.exception is None or isinstance(r.exception, SystemExit), repr(r.exception)
        assert not out.exists(), compare
    r = invoke(["calibrate", "map", *sorted(INTERFEROMETER.glob("*.csv")), "--squareness", "-173,-19,21",
                "-o", tmp_path / "m.csv", "--plot", tmp_path / "d.png"])
    _no_traceback(r, "--compare")  # a difference plot needs the map it is the difference from


@pytest.mark.parametrize("args", [["simulate", "--layout", "crossed"], ["calibrate", "simulate-alignment", "--pose",
                                                                        "90,90,0", "--name", "A"],
                                  ["plan", "RUN", "--simulate"], ["demo"]])
def test_a_negative_seed_is_a_usage_error(tmp_path, args):
    args = [str(tmp_path) if a == "RUN" else a for a in args]
    out = "--report" if args[0] == "demo" else "-o"
    r = invoke([*args, "--seed", "-1", out, tmp_path / "out"])
    _no_traceback(r, "--seed")
    assert not (tmp_path / "out").exists()


# -- 2. warnings: one clean line each, once; the library warns as before -------------------------------------------


def test_cli_warnings_format_cmmposes_own_once_and_leave_the_rest():
    with cli_warnings():
        first = warnings.formatwarning("clamped into the maps: 1 X", ClampWarning, "/x/compensation.py", 134)
        again = warnings.formatwarning("clamped into the maps: 1 X", ClampWarning, "/y/other.py", 9)
        cli_own = warnings.formatwarning("--x ignored with --y", UserWarning, "cmmpose", 0)  # the command line's own
        theirs = warnings.formatwarning("divide by zero", RuntimeWarning, "/numpy/x.py", 5)
    assert first == "warning: clamped into the maps: 1 X\n" and again == ""
    assert cli_own == "warning: --x ignored with --y\n"
    assert "RuntimeWarning" in theirs and "x.py:5" in theirs  # another package's: Python's form
    assert warnings.formatwarning("m", ClampWarning, "f.py", 1).startswith("f.py:1: ClampWarning")  # restored


def test_compensate_and_calibrate_map_warn_in_one_clean_line(tmp_path):
    (tmp_path / "p.csv").write_text("u,v,D,E,F\n0,0,450,275,-250\n")
    r = cli(["compensate", "p.csv", "o.csv", "--temperature", "35", "--out-of-range", "extrapolate"], tmp_path)
    assert r.returncode == 0, r.stderr
    assert not RAW_WARNING.search(r.stderr), r.stderr
    lines = [line for line in r.stderr.splitlines() if "extrapolated" in line]
    assert lines == ["warning: 1 of 1 temperatures extrapolated beyond the maps, up to 5.00 K"], r.stderr
    r = cli(["calibrate", "map", *sorted(INTERFEROMETER.glob("*.csv")), "--squareness", "-173,-19,21", "-o",
             "map.csv"], tmp_path)
    assert r.returncode == 0, r.stderr
    assert not RAW_WARNING.search(r.stderr) and "InterferometerWarning" not in r.stderr, r.stderr
    assert r.stderr.count("not measured, stored as zero") == 1, r.stderr  # its note, not the warning again


def test_acceptance_sphere_makes_no_decision_from_an_ill_conditioned_fit(tmp_path):
    np.savetxt(tmp_path / "cap.csv", cap_points(8), fmt="%.5f", delimiter=",", header="X,Y,Z", comments="")
    r = cli(["standards", "acceptance-sphere", "cap.csv", "--radius", "12.5", "--mpe-form", "20", "--mpe-size", "10",
             "--json"], tmp_path)
    assert r.returncode == 1, r.stderr  # no conformance shown
    assert not RAW_WARNING.search(r.stderr), r.stderr
    assert r.stderr.count("ill-determined") == 1, r.stderr  # the warning and its log line are one line
    import json

    doc = json.loads(r.stdout)
    assert doc["decision"] == NO_DECISION
    size = doc["tests"]["probing size, single view"]
    assert size["decision"] == NO_DECISION and size["U_um"] == 0.0
    assert any("no decision" in n and "8.1 deg cap" in n for n in doc["notes"]), doc["notes"]


def test_probing_test_still_warns_and_decides_on_a_hemisphere():
    with pytest.warns(IllConditionedFit):  # the library's warning is unchanged
        r = probing_test(cap_points(8), 12.5, mpe_form=20, mpe_size=10)
    form, size = r.checks
    assert size.decision == NO_DECISION and r.decision == NO_DECISION
    assert form.decision == "pass"  # the residuals' range over the points given is still determined
    with warnings.catch_warnings():
        warnings.simplefilter("error", IllConditionedFit)  # a hemisphere: well conditioned, decided
        r = probing_test(cap_points(80, noise=0.0005), 12.5, mpe_form=20, mpe_size=10)
    assert r.decision == "pass" and not any("no decision" in n for n in r.notes)
    # the worst decision: a fail still outranks an undecided value; no decision outranks not proven
    from cmmpose.standards.acceptance import _worst

    assert _worst(["pass", NO_DECISION, "not proven"]) == NO_DECISION and _worst([NO_DECISION, "fail"]) == "fail"


# -- 3. effects: none that simulates nothing, no key given twice ---------------------------------------------------


def test_an_effect_parameter_given_twice_is_refused(tmp_path):
    with pytest.raises(cmmpose.InputError, match="seconds is given twice"):
        effects_registry.parse("latency:seconds=0.005,seconds=0.01")
    r = invoke(["simulate", "--layout", "crossed", "--effect", "latency:seconds=0.005,seconds=0.01",
                "-o", tmp_path / "r"])
    _no_traceback(r, "given twice")
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize("name", list(effects_registry.available()))
def test_an_effect_at_its_no_op_defaults_is_refused_naming_its_parameters(name):
    cls = effects_registry.get(name)
    reason = inert(cls())
    if name == "squareness-temperature":  # gain 1 by default: it acts when its sensor group runs warm
        assert reason is None
        return
    assert reason and name in reason and "simulates nothing" in reason
    example = reason.rsplit("e.g. ", 1)[1]
    assert inert(effects_registry.parse(example)) is None  # the example it gives acts
    for field in example.split(":")[1].split("=")[:1]:
        assert field in reason


def test_simulate_refuses_a_bare_effect_and_takes_one_that_acts(tmp_path):
    r = invoke(["simulate", "--layout", "crossed", "--effect", "latency", "-o", tmp_path / "r"])
    _no_traceback(r, "seconds")
    assert "latency:seconds=0.005" in r.output and not (tmp_path / "r").exists()
    r = invoke(["simulate", "--layout", "crossed", "--effect", "latency:seconds=0", "-o", tmp_path / "r"])
    _no_traceback(r, "simulates nothing")
    assert [type(e).__name__ for e in parse_effects(["latency:seconds=0.005", "granite-gradient:kelvin=2",
                                                     "squareness-temperature:sensor=y_scale"])] == \
        ["Latency", "GraniteGradient", "SquarenessTemperature"]


def test_plan_refuses_an_inert_effect_before_any_work(tmp_path):
    r = invoke(["plan", tmp_path, "--simulate", "--effect", "scale", "-o", tmp_path / "next"])
    _no_traceback(r, "scale simulates nothing")


# -- 4. expansion coefficients: the machine file's range on every option -------------------------------------------


@pytest.mark.parametrize("value", ["-1e9", "-1.5", "101", "nan", "inf"])
@pytest.mark.parametrize("command", [["evaluate"], ["standards", "acceptance", "--mpe-form", "1", "--mpe-size", "1",
                                                    "--mpe-length", "1"]])
def test_an_expansion_coefficient_outside_the_machine_files_range_is_refused(tmp_path, command, value):
    r = invoke([*command, tmp_path, "--expansion", value])
    _no_traceback(r, "--expansion")
    assert "ppm/K" in r.output and "-1..100" in r.output


def test_the_expansion_range_is_the_machine_files():
    lo, hi = EXPANSION_RANGE_PPM
    for ok in (lo, 0.0, 11.5, hi):
        assert expansion_ppm(None, None, ok) == ok
    assert expansion_ppm(None, None, None) is None
    with pytest.raises(Exception, match="outside"):
        parse_effects(["artefact-expansion:ppm_per_kelvin=-1e9"])  # an effect's expansion coefficient alike
