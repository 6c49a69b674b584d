"""Errors carry their fields where they are raised (issue 34, item 3): an
error that names a Python argument carries it as a remedy (a key of
cmmpose.errors.REMEDIES), and the command line words it from that field
(the running command's flag, or that the command has none), never by
rewriting the text. Each case below is one the command line used to
rewrite by a table of hints and regular expressions (cmmpose.policy): the
Python wording and the command line's are the same as before, to the
character, and an error with its fields survives pickling."""

import pickle
import socket

import numpy as np
import pytest

from cmmpose import errors
from cmmpose.errors import REMEDIES, InputError, OutOfRangeError, RunError, SchedulerError, quoting
from cmmpose.policy import cli_wording

NONE = {"--maps"}  # a command with none of the flags below


class _Ctx:
    """A click context's stand-in: a command with these flags."""

    def __init__(self, flags):
        self.command = type("C", (), {"params": [type("P", (), {"opts": list(flags)})()]})()


def _said(exc, python, cli, missing, *, without=NONE):
    """``exc`` says ``python`` in Python, ``cli`` on a command with every flag, ``missing`` on one without."""
    assert str(exc) == python
    assert exc.render("cli") == cli and cli_wording(exc) == cli
    assert exc.render("cli", without) == missing and cli_wording(exc, _Ctx(without)) == missing
    back = pickle.loads(pickle.dumps(exc))
    assert type(back) is type(exc) and back.fields == exc.fields and str(back) == python
    assert back.render("cli", without) == missing


# -- the thermocouple log ---------------------------------------------------------------
LOG = {"t": np.arange(0.0, 101.0), "X1": np.full(101, 20.0)}
CHANNELS = [("X1", "x_scale")]


def _log_error(func, *args, **kwargs):
    with pytest.raises(InputError) as info:
        func(*args, **kwargs)
    return info.value


def test_a_point_beyond_the_log_hold():
    from cmmpose.temperature import check_log_coverage

    run = type("R", (), {"temperatures": LOG})()
    exc = _log_error(check_log_coverage, run, [300.0], 120.0)
    head = "point row 0: t = 300 s is 200.0 s outside the temperature log (0..100 s), more than the 120 s held at its ends"
    assert (exc.remedy, exc.option, exc.row) == ("log_hold", "log_hold", 0)
    _said(exc, head + " (pass log_hold= (s) to hold the nearest reading that far, or give the temperature)",
          head + " (use --log-hold S to hold the nearest reading that far, or give the temperature)",
          head + " (this command has no option to hold the log's readings, or give the temperature)")


def test_a_point_in_a_gap_of_the_log():
    from cmmpose.temperature import temperatures_at

    keep = (LOG["t"] < 40) | (LOG["t"] > 80)
    log = {k: v[keep] for k, v in LOG.items()}
    exc = _log_error(temperatures_at, [60.0], log, CHANNELS)
    head = "point row 0 (t = 60 s) falls in a gap of the temperature log: no samples from 39 s to 81 s (42 s > max_gap 5 s)"
    assert exc.remedy == "on_gap"
    _said(exc, head + "; pass on_gap='interpolate' to interpolate across it",
          head + "; use --on-gap interpolate to interpolate across it",
          head + "; the command line has no option to interpolate across it")
    # a command with --temperature but no --on-gap says what it can do instead
    assert exc.render("cli", {"--temperature"}) == (head + "; the command line has no option to interpolate across "
                                                    "it (give the machine temperature with --temperature instead)")


def test_a_point_in_a_bad_stretch_of_a_channel():
    from cmmpose.temperature import temperatures_at

    log = {"t": LOG["t"], "X1": np.where((LOG["t"] > 40) & (LOG["t"] < 80), np.nan, 20.0)}
    exc = _log_error(temperatures_at, [60.0], log, CHANNELS)
    assert exc.remedy == "on_gap_stretch" and exc.message.startswith("point row 0 (t = 60 s): no clean axis-scale")
    head = exc.message
    assert head.endswith("]") and "pass" not in head
    _said(exc, head + "; pass on_gap='interpolate' to interpolate across the bad stretch",
          head + "; use --on-gap interpolate to interpolate across the bad stretch",
          head + "; the command line has no option to interpolate across the bad stretch")


def test_a_scan_across_a_gap_of_the_log():
    from cmmpose.temperature import per_scan_temperature

    keep = (LOG["t"] < 40) | (LOG["t"] > 80)
    log = {k: v[keep] for k, v in LOG.items()}
    exc = _log_error(per_scan_temperature, [30.0, 90.0], [1, 1], log, CHANNELS)
    head = ("scan 1 (30 s to 90 s) spans a gap of the temperature log: no samples from 39 s to 81 s "
            "(42 s > max_gap 5 s)")
    _said(exc, head + "; pass on_gap='interpolate' to interpolate across it",
          head + "; use --on-gap interpolate to interpolate across it",
          head + "; the command line has no option to interpolate across it")


def test_a_point_outside_the_log_without_a_hold():
    from cmmpose.temperature import temperatures_at

    exc = _log_error(temperatures_at, [200.0], LOG, CHANNELS)
    head = "point row 0 (t = 200 s) is outside the temperature log (0 s to 100 s)"
    # no command has the option: the command line always says so
    _said(exc, head + "; pass out_of_range='hold' to use the log's end values",
          head + "; the command line has no option to hold the log's end values this far",
          head + "; the command line has no option to hold the log's end values this far")


def test_a_broken_thermocouple():
    exc = InputError("thermocouple X1: broken (X1: NaN at 3 s, 1 samples (reads nan))", option="broken_channels",
                     remedy="broken_channels")
    head = exc.message
    _said(exc, head + "; pass broken_channels='drop' to leave its bad samples out",
          head + "; use --broken-channels drop to leave its bad samples out",
          head + "; this command has no option to leave a broken thermocouple out")


@pytest.mark.parametrize("remedy, python", [("temperature", "run has no temperature log: pass temperature= (C)"),
                                            ("temperature_explicit",
                                             "run has no temperature log: pass temperature= explicitly")])
def test_a_run_without_a_log(remedy, python):
    exc = InputError("run has no temperature log", option="temperature", remedy=remedy)
    _said(exc, python, "run has no temperature log: give --temperature (C)",
          "run has no temperature log: record a temperature log with the run")


def test_a_run_without_a_log_from_the_library(simulated_run):
    import dataclasses

    from cmmpose.temperature import run_temperatures

    run = dataclasses.replace(simulated_run, temperatures=None, temperature_channels=[])
    exc = _log_error(run_temperatures, run, [0.0])
    assert exc.remedy == "temperature_explicit" and str(exc) == "run has no temperature log: pass temperature= explicitly"


# -- the maps' temperature range --------------------------------------------------------
def test_a_temperature_outside_the_maps_clamp_instead():
    from cmmpose.calibration.thermal import select_map_temperature
    from cmmpose.errormap import ErrorMapSet

    with pytest.raises(OutOfRangeError) as info:
        select_map_temperature(45.0, ErrorMapSet.thesis())
    exc = info.value
    head = exc.message
    assert head.startswith("the temperature: temperature 45 C is outside the maps' range") and "pass" not in head
    assert (exc.value, exc.unit, exc.remedy) == (45.0, "C", "clamp_temperature")
    _said(exc, head + "; pass out_of_range='clamp' to clamp instead", head + "; use --out-of-range clamp to clamp instead",
          head + "; this command has no option to clamp it")


# -- a ballbar run's positions ----------------------------------------------------------
def test_incomplete_positions():
    exc = RunError("run: 1 incomplete or ambiguous ballbar position(s) or scan(s): position 3: no ball B",
                   option="skip_incomplete", remedy="skip_incomplete")
    head = exc.message
    _said(exc, head + " (fix the scans' position and ball labels, or pass skip_incomplete=True to evaluate the "
          "complete positions only and list the others)",
          head + " (fix the scans' position and ball labels, or use --skip-incomplete to evaluate the complete "
          "positions only and list the others)",
          head + " (fix the scans' position and ball labels, or complete or relabel the positions)")


# -- outputs that exist -----------------------------------------------------------------
def test_an_output_that_exists(tmp_path):
    from cmmpose.atomicfile import exists_error

    exc = exists_error(tmp_path / "out.csv")
    head = f"{tmp_path / 'out.csv'}: exists; the output is never written over an existing file without being told"
    _said(exc, head + " (pass overwrite=True to replace it)", head + " (use --overwrite to replace it)",
          head + " (remove it first to replace it)")
    exc = exists_error(tmp_path / "out.csv", meanwhile=True)
    assert str(exc).endswith("was not written over it (pass overwrite=True to replace it)")
    assert exc.render("cli").endswith("was not written over it (use --overwrite to replace it)")


def test_a_run_folder_that_is_not_empty(tmp_path):
    from cmmpose.run import check_run_target

    (tmp_path / "x").write_text("")
    with pytest.raises(RunError) as info:
        check_run_target(tmp_path)
    head = f"{tmp_path}: directory is not empty"
    _said(info.value, head + " (pass overwrite=True to replace the run in it)",
          head + " (use --overwrite to replace the run in it)", head + " (remove it first to replace the run in it)")


def test_a_folder_that_holds_a_recording():
    exc = errors.AcquisitionError("rec: already holds a recording", option="overwrite", remedy="overwrite_recording")
    _said(exc, "rec: already holds a recording (pass overwrite=True / --overwrite to replace it)",
          "rec: already holds a recording (use --overwrite to replace it)",
          "rec: already holds a recording (choose another folder)")


def test_an_output_group_quotes_its_member_with_the_remedy_a_field(tmp_path):
    from cmmpose.atomicfile import exists_error

    inner = exists_error(tmp_path / "a.csv")
    message, fields = quoting(inner, after="; nothing of the outputs was written")
    exc = errors.OutputError(message, **fields)
    assert str(exc) == str(inner) + "; nothing of the outputs was written"
    assert exc.render("cli") == inner.render("cli") + "; nothing of the outputs was written"
    assert exc.render("cli", NONE) == inner.render("cli", NONE) + "; nothing of the outputs was written"
    back = pickle.loads(pickle.dumps(exc))
    assert back.fields == exc.fields and back.render("cli") == exc.render("cli")


# -- a scheduler that does not answer ---------------------------------------------------
def test_a_scheduler_that_does_not_greet():
    from cmmpose.scale.scheduler import _probe_scheduler

    with socket.socket() as server:  # accepts (the kernel's backlog) and says nothing
        server.bind(("127.0.0.1", 0))
        server.listen(1)
        port = server.getsockname()[1]
        with pytest.raises(SchedulerError) as info:
            _probe_scheduler(f"tcp://127.0.0.1:{port}", 0.2)
    exc = info.value
    head = f"scheduler tcp://127.0.0.1:{port}: accepted the connection but sent no Dask handshake within 0.2 s"
    tail = ": is a Dask scheduler listening there (its port, usually 8786)?"
    assert exc.remedy == "scheduler_handshake" and exc.value == 0.2
    _said(exc, head + " (scheduler_timeout= sets the limit)" + tail,
          head + " (--scheduler-timeout SECONDS sets the limit)" + tail,
          head + " (no option of this command sets the limit)" + tail)


def test_a_scheduler_that_accepts_nothing():
    exc = SchedulerError("scheduler tcp://10.0.0.1:8786: nothing accepted the connection within 10 s",
                         option="scheduler_timeout", remedy="scheduler_timeout")
    head = exc.message
    _said(exc, head + " (scheduler_timeout= sets the limit)", head + " (--scheduler-timeout SECONDS sets the limit)",
          head + " (no option of this command sets the limit)")


# -- points in another unit (cmmpose.fitting) -------------------------------------------
def test_points_in_metres_name_the_unit_to_read_them_in():
    import cmmpose
    from cmmpose.errors import GeometryError

    rng = np.random.default_rng(1)
    v = rng.normal(size=(400, 3))
    v[:, 2] = np.abs(v[:, 2])
    with pytest.raises(GeometryError) as info:
        cmmpose.fit_sphere(v / np.linalg.norm(v, axis=1)[:, None] * 0.0125, 12.5)  # a 25 mm sphere in metres
    exc = info.value
    assert (exc.what, exc.value, exc.remedy) == ("units", "m", "units")
    head = exc.message
    assert head.endswith("the coordinates look like metres (24.92 mm if they are): convert them to mm")
    # a command without --units (and the Python API) says the call that reads them in metres
    _said(exc, head + " (read_point_cloud(path, units='m'))", head + " (give --units m)",
          head + " (read_point_cloud(path, units='m'))")


# -- runs too few to estimate their noise from (cmmpose.diagnosis.plan) --------------------
def test_runs_without_degrees_of_freedom_ask_for_the_noise():
    exc = InputError("the runs leave no degrees of freedom to estimate their noise from", what="sigma_um",
                     option="sigma_um", cli_option="--sigma", remedy="sigma")
    head = exc.message
    _said(exc, head + ": give sigma_um", head + ": give --sigma UM (noise per ball-centre coordinate, um)",
          head + ": give sigma_um")


# -- an argument's name leading the message ----------------------------------------------
def test_reproducibility_per_run():
    from cmmpose.diagnosis.floor import per_run

    with pytest.raises(InputError) as info:
        per_run([1.0, 2.0], 3)
    text = " one value, or one per run (3), got 2"
    _said(info.value, "reproducibility_um:" + text, "--reproducibility:" + text, "reproducibility:" + text)


def test_repeat_scans():
    from cmmpose.placement import check_repeat_scans

    with pytest.raises(InputError) as info:
        check_repeat_scans(9, 4)
    text = " expected a whole number of sweeps from 0 to 4 (each scan once more at most), got 9"
    _said(info.value, "repeat_scans:" + text, "--repeat-scans:" + text, "repeat_scans:" + text)


def test_a_leading_name_quoted_inside_another_message_is_left_as_it_is():
    from cmmpose.placement import check_repeat_scans

    with pytest.raises(InputError) as info:
        check_repeat_scans(9, 4)
    message, fields = quoting(info.value, "run r: ")
    exc = InputError(message, **fields)
    assert str(exc) == exc.render("cli") == "run r: " + str(info.value)


# -- the mechanism ----------------------------------------------------------------------
@pytest.mark.parametrize("key", sorted(REMEDIES))
def test_every_remedy_pickles_with_its_fields(key):
    lead = REMEDIES[key].python if REMEDIES[key].lead else ""
    exc = errors.InputError(lead + " bad", what="x", value=2.0, allowed=(0.0, 1.0), unit="s", file="f.csv", row=4,
                            column="t", option="x", cli_option="--x", remedy=key, after="; and more")
    back = pickle.loads(pickle.dumps(exc))
    assert type(back) is errors.InputError and back.fields == exc.fields and back.args == exc.args
    assert str(back) == str(exc) and back.render("cli") == exc.render("cli")
    assert back.render("cli", NONE) == exc.render("cli", NONE)
    assert str(exc).endswith("; and more") and exc.render("cli").endswith("; and more")


def test_the_command_line_rewrites_no_text():
    """A plain message (or an error without a remedy) is said as it is, numbers shortened only."""
    text = "x: pass log_hold= (s) to hold the nearest reading that far; pass overwrite=True to replace it"
    assert cli_wording(text) == text and cli_wording(InputError(text)) == text
    assert cli_wording("n = " + "9" * 30) == "n = 1e+30"


def test_the_hint_table_is_gone():
    import cmmpose.policy as policy

    assert not hasattr(policy, "_HINTS") and not hasattr(policy, "SKIP_INCOMPLETE_HINT")
    assert not hasattr(policy, "SCHEDULER_TIMEOUT_HINT")
    import cmmpose.cli.fit as fit
    import cmmpose.fitting as fitting

    assert not hasattr(fit, "units_flag") and not hasattr(fitting, "unit_remedy")
