"""The error model (cmmpose.errors): classes that live in cmmpose.errors,
carry fields, pickle with their class and fields (also across a process-based
Dask cluster), follow the ecosystem (input errors are ValueErrors, type errors
TypeErrors), and are worded for each interface from the same fields."""

import pickle

import numpy as np
import pytest

import cmmpose
from cmmpose import errors
from cmmpose.errormap import ErrorMapSet
from cmmpose.policy import cli_wording

UV = np.array([[0.0, 140.0], [1.0, 141.0]])
SCALES = np.array([[100.0, 100.0, -100.0], [120.0, 90.0, -80.0]])
POSE, OFFSET = (90.0, 90.0, 0.0), (1.001, 264.505, 129.575)

CLASSES = [getattr(errors, n) for n in errors.__all__ if isinstance(getattr(errors, n), type)
           and issubclass(getattr(errors, n), errors.Error)]


def _kernel_error(temperature=45.0):
    with pytest.raises(cmmpose.Error) as info:
        cmmpose.compensate(UV, SCALES, ErrorMapSet.thesis(), POSE, OFFSET, temperature=temperature)
    return info.value


def test_every_class_lives_in_cmmpose_errors_and_is_public():
    assert {c.__name__ for c in CLASSES} >= {"Error", "MapError", "OutOfRangeError", "InputError", "InputTypeError",
                                              "GeometryError", "RunError", "CalibrationError", "AcquisitionError",
                                              "SchedulerError", "OutputError"}
    for cls in CLASSES:
        assert cls.__module__ == "cmmpose.errors", cls
        assert getattr(cmmpose, cls.__name__) is cls


@pytest.mark.parametrize("cls", CLASSES, ids=lambda c: c.__name__)
def test_each_class_pickles_with_its_fields(cls):
    exc = cls("row 3: bad", what="x", value=1.5, allowed=(0.0, 1.0), unit="mm", file="a.csv", row=3, column="u",
              option="x", cli_option="--x")
    back = pickle.loads(pickle.dumps(exc))
    assert type(back) is cls
    assert back.fields == exc.fields and str(back) == str(exc) and back.args == exc.args


def test_input_errors_are_value_errors_and_type_errors_type_errors():
    for cls in (errors.InputError, errors.MapError, errors.OutOfRangeError, errors.GeometryError, errors.RunError,
                errors.CalibrationError):
        assert issubclass(cls, ValueError) and issubclass(cls, cmmpose.Error)
    assert issubclass(errors.InputTypeError, TypeError) and issubclass(errors.InputTypeError, errors.InputError)
    for cls in (errors.AcquisitionError, errors.SchedulerError, errors.OutputError):
        assert not issubclass(cls, ValueError)


def test_a_kernel_error_has_fields_and_keeps_them_through_pickle():
    exc = _kernel_error(45.0)
    assert type(exc) is errors.OutOfRangeError
    assert (exc.what, exc.value, exc.allowed, exc.unit) == ("temperature", 45.0, (20.0, 30.0), "C")
    assert exc.option == "temperature" and exc.remedy == "temperature_out_of_range"
    back = pickle.loads(pickle.dumps(exc))
    assert type(back) is errors.OutOfRangeError and back.fields == exc.fields and str(back) == str(exc)


def test_a_non_finite_row_names_its_row_and_argument():
    scales = SCALES.copy()
    scales[1, 2] = np.nan
    with pytest.raises(errors.InputError) as info:
        cmmpose.compensate(UV, scales, ErrorMapSet.thesis().at(20.0), POSE, OFFSET)
    assert info.value.row == 1 and info.value.option == "scales" and info.value.remedy == "nan_policy"
    assert isinstance(info.value, ValueError)


def test_each_interface_is_worded_from_the_fields():
    exc = _kernel_error(45.0)
    python = str(exc)
    assert "out_of_range='clamp'" in python and "--out-of-range" not in python
    cli = exc.render("cli")
    assert cli.startswith(exc.message) and "--out-of-range clamp" in cli and "out_of_range=" not in cli
    assert "no option to clamp or extrapolate" in exc.render("cli", {"--maps"})
    assert cli_wording(exc) == cli  # the CLI's wording, with no command: every flag counts


def test_the_remedy_wording_is_not_in_the_core_text():
    """The message is the core's fact; the remedy text comes from one place (REMEDIES)."""
    exc = _kernel_error(45.0)
    assert "choices" not in exc.message and "out_of_range" not in exc.message
    assert str(exc) == exc.message + errors.REMEDIES["temperature_out_of_range"].python


def test_an_unknown_remedy_is_refused():
    with pytest.raises(KeyError, match="remedy"):
        errors.InputError("x", remedy="no-such-remedy")


def test_a_worker_error_arrives_as_its_class_on_a_process_cluster():
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(processes=True, n_workers=1, threads_per_worker=1, dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        future = client.submit(cmmpose.compensate, UV, SCALES, ErrorMapSet.thesis(), POSE, OFFSET, temperature=45.0,
                               pure=False)
        try:
            future.result(timeout=120)
        except cmmpose.Error as exc:
            caught = exc
        else:
            pytest.fail("the worker's error did not arrive")
    assert type(caught) is errors.OutOfRangeError
    assert (caught.value, caught.allowed, caught.remedy) == (45.0, (20.0, 30.0), "temperature_out_of_range")
    assert "--out-of-range clamp" in caught.render("cli")


def test_an_argument_of_the_wrong_type_is_a_type_error():
    with pytest.raises(TypeError) as info:
        cmmpose.compensate(UV, SCALES, "not a map", POSE, OFFSET)
    assert isinstance(info.value, errors.InputTypeError) and isinstance(info.value, errors.InputError)
    assert str(info.value).startswith("maps:")  # names the argument at fault


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_relabelling_a_map_checks_finiteness_as_making_it_does(bad):
    """ErrorMap.with_temperature refuses a non-finite temperature as ErrorMap(...) does (the core's one check)."""
    m = ErrorMapSet.thesis().at(25.0)
    with pytest.raises(errors.MapError, match="temperature: .* C is not finite"):
        m.with_temperature(bad)
    assert m.with_temperature(21.0).temperature == 21.0 and m.with_temperature(None).temperature is None
