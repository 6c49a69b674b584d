"""A broken user effect (docs/user-effects.md) is an error in the user's code,
said in one line naming the effect, its file (and line) and what went wrong:
not a Python traceback on the command line, and not a physics verdict ('not
observable') in a diagnosis. Two files defining the same effect name are
refused (the verdict would depend on their order), and a saved model's user
effect missing on the command line names the flag, not the Python argument."""

from __future__ import annotations

import functools
import textwrap

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner

import cmmpose
from cmmpose.cli import main
from cmmpose.model import Model, UserEffect
from cmmpose.model.spec import load_user_effect, load_user_effects
from cmmpose.diagnosis.identify import Problem
from cmmpose.errors import InputError, UserEffectError
from cmmpose.sim.runs import simulate_ballbar_run
from cmmpose.sim.scanner import Scanner

MAPS = cmmpose.ErrorMapSet.thesis()

#: A user-effect file; BODY is the function's body (its first line is line 5 of the file).
EFFECT_FILE = """\
import numpy as np
from cmmpose.model import UserEffect

def correction(inputs, a_um):
{body}

EFFECT = UserEffect.create({name!r}, correction, {{"a_um": ("um", 1.0)}}, physics="p", reveal="r")
"""


@functools.cache
def small_run():
    run, _ = simulate_ballbar_run(MAPS, 22.5, [], jitter=0.0015, seed=3, scanner=Scanner(points_per_profile=64))
    return run


def write_effect(path, body, name="my-effect"):
    path.write_text(EFFECT_FILE.format(body=textwrap.indent(textwrap.dedent(body).strip("\n"), "    "), name=name))
    return path


def inputs(n=6):
    return {k: np.linspace(100.0, 200.0, n) for k in ("u", "v", "D", "E", "F")}


# --- 2. a user function that raises ------------------------------------------------------------------------------

def test_a_raising_user_function_is_a_user_effect_error_naming_file_line_and_exception(tmp_path):
    path = write_effect(tmp_path / "raises.py", 'x = 1\nraise KeyError("nope")')
    effect = load_user_effect(path)
    with pytest.raises(UserEffectError) as err:
        effect.correction(inputs(), [1.0])
    msg = str(err.value)
    assert "'my-effect'" in msg and "raises.py" in msg and "line 6" in msg and "KeyError: 'nope'" in msg, msg
    assert err.value.file == str(path) and err.value.row == 6 and err.value.what == "my-effect"
    assert isinstance(err.value, InputError)  # bad input to cmmpose, as before: `except InputError` still holds


def test_an_effect_made_in_python_names_the_file_of_its_function():
    def broken(inputs, a):
        return inputs["nothing"]

    effect = UserEffect.create("inline", broken, {"a": ("mm", 1.0)})
    with pytest.raises(UserEffectError, match=r"'inline' \(.*test_user_effect_errors\.py, line \d+\): .*KeyError"):
        effect.correction(inputs(), [1.0])


def test_a_cmmpose_error_from_the_users_code_passes_as_is():
    def refuses(inputs, a):
        raise InputError("outside what this effect models")

    effect = UserEffect.create("refuses", refuses, {"a": ("mm", 1.0)})
    with pytest.raises(InputError, match="^outside what this effect models$") as err:
        effect.correction(inputs(), [1.0])
    assert not isinstance(err.value, UserEffectError)


def test_diagnose_cli_says_a_raising_user_effect_in_one_line(tmp_path):
    run_dir = tmp_path / "run"
    small_run().save(run_dir)
    path = write_effect(tmp_path / "raises.py", 'raise KeyError("nope")')
    res = CliRunner().invoke(main, ["diagnose", str(run_dir), "--user-effect", str(path), "--json"])
    assert res.exit_code == 1, res.output
    assert "Traceback" not in res.output and not isinstance(res.exception, KeyError)
    assert "raises.py, line 5" in res.output and "KeyError: 'nope'" in res.output and "'my-effect'" in res.output


# --- 3. a user function returning NaN or the wrong shape ---------------------------------------------------------

@pytest.mark.parametrize("body, words", [
    ("out = np.zeros((len(inputs['u']), 3)); out[3:5, 1] = np.nan\nreturn out",
     r"non-finite value \(nan\) at row 3, column y; 2 of 6 rows are not finite"),
    ("return np.zeros((len(inputs['u']), 2))", r"array of shape \(6, 3\) .*returned shape \(6, 2\)"),
    ("return 'not numbers'", r"array of shape|returned str"),
])
def test_a_bad_return_value_names_what_is_wrong(tmp_path, body, words):
    effect = load_user_effect(write_effect(tmp_path / "bad.py", body))
    with pytest.raises(UserEffectError, match=r"'my-effect' \(.*bad\.py\): .*" + words):
        effect.correction(inputs(), [1.0])


@pytest.mark.parametrize("body", [
    "out = np.zeros((len(inputs['u']), 3)); out[0, 0] = np.nan * a_um\nreturn out",
    "return np.zeros((len(inputs['u']), 2))",
    "raise ZeroDivisionError('by hand')",
])
def test_a_broken_user_effect_stops_the_diagnosis_instead_of_being_skipped(tmp_path, body):
    effect = load_user_effect(write_effect(tmp_path / "broken.py", body))
    with pytest.raises(UserEffectError, match="'my-effect'.*broken.py"):
        Problem(Model(MAPS), small_run(), extra=[effect])


def test_a_user_effect_the_run_cannot_evaluate_is_still_skipped():
    """A cmmpose error from the user's code (it cannot model these inputs) is a verdict: skipped, as before."""
    def refuses(inputs, k):
        if k != 0:
            raise InputError("outside what this user effect can model")
        return np.zeros((len(inputs["u"]), 3))

    p = Problem(Model(MAPS), small_run(), extra=[UserEffect.create("refuses", refuses, {"k": ("1", 1.0)})])
    assert "refuses" not in p.candidates and "cannot be evaluated" in p.skipped["refuses"]
    assert p.candidates  # the library's effects are still there


def test_diagnose_cli_refuses_a_nan_user_effect(tmp_path):
    run_dir = tmp_path / "run"
    small_run().save(run_dir)
    path = write_effect(tmp_path / "nan.py", "out = np.zeros((len(inputs['u']), 3)); out[0, 0] = np.nan\nreturn out")
    res = CliRunner().invoke(main, ["diagnose", str(run_dir), "--user-effect", str(path), "--json"])
    assert res.exit_code == 1 and "Traceback" not in res.output, res.output
    assert "nan.py" in res.output and "non-finite value (nan) at row 0, column x" in res.output
    assert "not observable" not in res.output


# --- 1. two files defining the same effect name ------------------------------------------------------------------

def test_two_files_defining_one_effect_name_are_refused_naming_both(tmp_path):
    a = write_effect(tmp_path / "a.py", "return np.zeros((len(inputs['u']), 3))", name="x-scale-ripple")
    b = write_effect(tmp_path / "b.py", "return np.ones((len(inputs['u']), 3)) * a_um", name="x-scale-ripple")
    with pytest.raises(InputError, match=r"b\.py: defines the user effect 'x-scale-ripple', as .*a\.py does"):
        load_user_effects([a, b])
    assert [e.name for e in load_user_effects([a, a])] == ["x-scale-ripple"]  # one file twice: one effect
    run_dir = tmp_path / "run"
    small_run().save(run_dir)
    for order in ((a, b), (b, a)):
        res = CliRunner().invoke(main, ["diagnose", str(run_dir), "--user-effect", str(order[0]),
                                        "--user-effect", str(order[1]), "--json"])
        assert res.exit_code == 1 and "Traceback" not in res.output, res.output
        assert "a.py" in res.output and "b.py" in res.output and "x-scale-ripple" in res.output


# --- 4 (and 2). compensate --model ---------------------------------------------------------------------------------

def model_with_user_effect(tmp_path):
    """A saved model holding the user effect of ok.py, points to compensate, and a raising copy of ok.py."""
    ok = write_effect(tmp_path / "ok.py", "return np.zeros((len(inputs['u']), 3)) + a_um * 1e-3", name="shift")
    bad = write_effect(tmp_path / "bad.py", "raise RuntimeError('boom')", name="shift")
    model = Model(MAPS).with_values(load_user_effect(ok), [0.5])
    model.save(tmp_path / "model.json")
    rng = np.random.default_rng(0)
    n = 20
    pq.write_table(pa.table({"u": rng.uniform(-5, 5, n), "v": rng.uniform(-5, 5, n), "D": rng.uniform(100, 800, n),
                             "E": rng.uniform(50, 500, n), "F": rng.uniform(-450, -50, n), "T": np.full(n, 22.0),
                             "t": np.arange(n) * 0.01, "scan_id": np.zeros(n, int)}), tmp_path / "pts.parquet")
    return ok, bad


def test_compensate_model_without_its_user_effect_names_the_flag(tmp_path):
    ok, _ = model_with_user_effect(tmp_path)
    res = CliRunner().invoke(main, ["compensate", str(tmp_path / "pts.parquet"), str(tmp_path / "o.csv"),
                                    "--model", str(tmp_path / "model.json")])
    assert res.exit_code == 1, res.output
    assert "--user-effect FILE.py" in res.output and "user_effects" not in res.output, res.output
    small_run().save(tmp_path / "run")
    res = CliRunner().invoke(main, ["diagnose", str(tmp_path / "run"), "--model", str(tmp_path / "model.json")])
    assert res.exit_code == 1 and "--user-effect FILE.py" in res.output and "user_effects" not in res.output
    with pytest.raises(InputError, match=r"'shift' is user-defined: pass its UserEffect in user_effects=$"):
        Model.load(tmp_path / "model.json")
    assert Model.load(tmp_path / "model.json", [load_user_effect(ok)]).names == ("shift",)


def test_compensate_model_with_a_raising_user_effect_says_it_in_one_line(tmp_path):
    ok, bad = model_with_user_effect(tmp_path)
    args = ["compensate", str(tmp_path / "pts.parquet"), str(tmp_path / "o.csv"), "--model", str(tmp_path / "model.json")]
    res = CliRunner().invoke(main, [*args, "--user-effect", str(ok)])
    assert res.exit_code == 0, res.output
    res = CliRunner().invoke(main, [*args, "--user-effect", str(bad), "--overwrite"])  # o.csv exists: replaced
    assert res.exit_code == 1 and "Traceback" not in res.output and not isinstance(res.exception, RuntimeError)
    assert "bad.py, line 5" in res.output and "RuntimeError: boom" in res.output and "'shift'" in res.output


def test_two_user_effects_of_one_name_are_refused_in_python_too(tmp_path):
    import cmmpose
    from cmmpose.diagnosis.diagnose import user_specs
    from cmmpose.model.spec import UserEffect
    from cmmpose.model.model import Model

    def ripple(ctx, a_um):
        return np.zeros((len(ctx.scales), 3))

    a = UserEffect.create("my-ripple", ripple, params={"a_um": ("um", 1.0)})
    b = UserEffect.create("my-ripple", ripple, params={"a_um": ("um", 1.0)})
    assert user_specs([a, a]) == (a,)  # the same object twice: one effect
    with pytest.raises(cmmpose.InputError, match="two effects are named 'my-ripple'"):
        user_specs([a, b])
    path = tmp_path / "m.json"
    Model(cmmpose.ErrorMapSet.thesis()).save(path)
    with pytest.raises(cmmpose.InputError, match="two effects are named 'my-ripple'"):
        Model.load(path, user_effects=[a, b])
