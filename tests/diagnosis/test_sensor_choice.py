"""Which sensor a thermal term follows is a candidate choice that the data
decide (issue 16).

The maps' squareness changes with temperature (Table 7: up to 8 arc-seconds
per K between 25 and 30 C). When the axes sit at different temperatures,
the library's assumption (squareness at the machine mean) may be wrong: the
real squareness may follow one axis's thermocouples. The diagnosis tries one
candidate per thermocouple role, 'squareness-temperature@<role>'.

Blind tests: the simulator's truth follows one role; the diagnosis is not
told which. Three runs at 25.5-27 C, each with a different axis 3 K warm,
make the roles move differently, so the data can choose; one run with one
warm axis cannot (every role then departs from the mean in proportion), and
the diagnosis must not claim a choice there.
"""

from __future__ import annotations

import functools
import importlib
import json

import numpy as np
import pytest

import cmmpose
from cmmpose.model import Model
from cmmpose.diagnosis.diagnose import select_effects
from cmmpose.diagnosis.result import Step
from cmmpose.model.names import resolve
from cmmpose.model.spec import LIBRARY
from cmmpose.diagnosis.identify import INDISTINGUISHABLE_LR, Candidate
from cmmpose.diagnosis.joint import diagnose_jointly
from cmmpose.effects import parse
from cmmpose.effects.squareness_temperature import SquarenessTemperature
from cmmpose.errors import InputError
from cmmpose.sim import effects as E
from cmmpose.sim.machine import TruthMachine
from cmmpose.sim.runs import simulate_ballbar_run
from cmmpose.sim.scanner import Scanner

MAPS = cmmpose.ErrorMapSet.thesis()
SCALES = ("x_scale", "y_scale", "z_scale")
#: (machine temperature C, which axis is 3 K warm, seed) of each run.
PLAN = ((26.0, 2, 1), (27.0, 0, 2), (25.5, 1, 3))


def simulate(sensor: str, temperature: float, warm_axis: int, seed: int, kelvin: float = 3.0):
    offsets = [0.0, 0.0, 0.0]
    offsets[warm_axis] = kelvin
    truth = [E.AxisTemperature(*offsets), SquarenessTemperature(sensor=sensor)]
    return simulate_ballbar_run(MAPS, temperature, truth, jitter=0.0015, seed=seed,
                                scanner=Scanner(points_per_profile=256))[0]


@functools.lru_cache(maxsize=None)
def runs(sensor: str):
    return tuple(simulate(sensor, t, a, s) for t, a, s in PLAN)


def decisions(d) -> dict:
    return {x["name"]: x for x in d.decisions()}


@pytest.mark.parametrize("sensor", SCALES)
def test_the_data_choose_the_sensor_squareness_follows(sensor):
    d = diagnose_jointly(list(runs(sensor)), max_effects=3)
    chosen = f"squareness-temperature@{sensor}"
    # Both hidden effects found: the carriages at their own temperatures and
    # squareness at the warm sensor's.
    assert sorted(d.added) == ["axis-temperature", chosen]
    x = decisions(d)
    gain = x[chosen]["values"]["gain"]
    u = x[chosen]["uncertainty"]["gain"]
    # Tolerance: 4 standard uncertainties of the fit (the truth's gain is 1).
    assert abs(gain - 1.0) < 4 * u < 0.4
    others = [n for n in x if n.startswith("squareness-temperature@") and n != chosen]
    assert len(others) == 4  # the other two scales and the granite's top and bottom
    for n in others:
        assert x[n]["decision"] == "not chosen", (n, x[n])
        assert f"the data prefer {chosen}" in x[n]["reason"]
    # Each rejected alternative is worse by far more than the margin at which
    # two candidates count as indistinguishable.
    last = d.steps[-1].ranking
    assert all(c.lr < -INDISTINGUISHABLE_LR for c in last if c.name in others)
    assert not d.ambiguous or all(chosen not in g for g in d.ambiguous)


@pytest.mark.parametrize("sensor", ("granite_top", "granite_bottom"))
def test_the_granite_can_be_the_sensor_too(sensor):
    # The granite's top and bottom depart from the mean differently in each
    # run (a gradient of +4, -3 and +1 K that bends nothing by itself), and
    # an axis 2 K warm in each: the data pick the granite role.
    runs = []
    for (temperature, axis, seed), kelvin in zip(PLAN, (4.0, -3.0, 1.0)):
        offsets = [0.0, 0.0, 0.0]
        offsets[axis] = 2.0
        truth = [E.AxisTemperature(*offsets), E.GraniteGradient(kelvin=kelvin, xy=0.0, yz=0.0, zx=0.0),
                 SquarenessTemperature(sensor=sensor)]
        runs.append(simulate_ballbar_run(MAPS, temperature, truth, jitter=0.0015, seed=seed,
                                         scanner=Scanner(points_per_profile=256))[0])
    d = diagnose_jointly(runs, max_effects=4)
    chosen = f"squareness-temperature@{sensor}"
    assert sorted(d.added) == ["axis-temperature", chosen]
    x = decisions(d)
    assert abs(x[chosen]["values"]["gain"] - 1.0) < 4 * x[chosen]["uncertainty"]["gain"]
    assert all(x[n]["decision"] == "not chosen" for n in x if n.startswith("squareness-temperature@") and n != chosen)


@pytest.mark.parametrize("seed", (3, 4))
def test_one_warm_axis_cannot_choose_and_says_what_would(seed):
    # One axis warm: every role departs from the mean in proportion (z by
    # +2 K, the others by -1 K), so the roles' candidates differ only in
    # gain, and each equals a squareness offset. One of them is added for
    # the squareness change the run does show; the diagnosis must say that
    # it stands for the whole group, and what would separate them.
    run = simulate("z_scale", 26.0, 2, seed)
    d = cmmpose.diagnose(run, max_effects=3, patterns=False)
    x = decisions(d)
    variants = [n for n in x if n.startswith("squareness-temperature@")]
    assert len(variants) == 5
    group = [*variants, "squareness"]
    added = [n for n in group if x[n]["decision"].startswith("added")]
    assert len(added) == 1
    assert any(set(variants) <= set(g) for g in d.ambiguous), d.ambiguous
    if added[0] != "squareness":
        assert "the run cannot tell it from" in x[added[0]]["reason"]
        assert "the candidate sensors move differently" in x[added[0]]["reason"]
        # Its gain, in units of its own departure, carries the true change:
        # z is +2 K from the mean, the other roles -1 K, so gain -2 on them.
        want = 1.0 if added[0].endswith("z_scale") else -2.0
        u = x[added[0]]["uncertainty"]["gain"]
        assert abs(x[added[0]]["values"]["gain"] - want) < 4 * u
    for n in variants:
        if n not in added:
            assert x[n]["decision"] in ("aliased", "not chosen", "not observable", "not significant"), (n, x[n])
            assert x[n]["decision"] != "not chosen" or "cannot" in x[n]["reason"]


def test_a_forced_wrong_sensor_stays_and_the_better_one_is_named():
    d = diagnose_jointly(list(runs("z_scale")), add=["squareness-temperature@x_scale"], max_effects=2)
    x = decisions(d)
    assert x["squareness-temperature@x_scale"]["decision"] == "added on request"
    assert x["squareness-temperature@z_scale"]["decision"] == "preferred"
    assert "the data prefer it to squareness-temperature@x_scale" in x["squareness-temperature@z_scale"]["reason"]


def _candidate(name, lr, alternative_to=""):
    spec = resolve(name)
    return Candidate(name, spec, np.ones(spec.size), np.full(spec.size, 0.1), lr, 1, 1e-9 if not alternative_to else 1.0,
                     -lr, 0.5, 0.5, 0.1, "", 1.0, 100.0, significant=not alternative_to, alternative_to=alternative_to)


def test_selection_replaces_a_sibling_the_data_come_to_prefer(monkeypatch):
    # Rankings scripted per model: after x_scale is in, z_scale is better by
    # LR 30 (say another effect added since changed the picture).
    x, z = "squareness-temperature@x_scale", "squareness-temperature@z_scale"

    class Problem:
        candidates = {n: resolve(n) for n in (x, z)}

    def step(label, model, forced):
        if not model.names:
            ranking = [_candidate(x, 50.0), _candidate(z, 45.0)]
        elif model.names == (x,):
            ranking = [_candidate(z, 30.0, alternative_to=x)]
        else:
            ranking = [_candidate(x, -30.0, alternative_to=z)]
        return Step(label, model, None, ranking, forced)

    module = importlib.import_module("cmmpose.diagnosis.diagnose")  # the package's 'diagnose' is the function
    monkeypatch.setattr(module, "fit_model", lambda model, run, problem=None, **kw: model)
    steps, model = select_effects(Problem(), Model(MAPS), [], True, 3, step)
    assert [s.label for s in steps] == ["base", f"+ {x}", f"+ {z} (instead of {x})"]
    assert steps[-1].replaces == x and steps[-1].effect == z and model.names == (z,)
    # The decisions say what happened to each.
    from cmmpose.diagnosis.result import Diagnosis

    decisions = Diagnosis(steps, {}, []).decisions()
    assert len({d["name"] for d in decisions}) == len(decisions)  # one decision per candidate
    found = {d["name"]: d for d in decisions}
    assert found[x]["decision"] == "replaced" and found[x]["reason"].startswith(f"replaced by {z}: the data prefer it")
    assert found[z]["decision"] == "added" and f"in place of {x}" in found[z]["reason"]
    assert f"against the final model: the data prefer {z}" in found[x]["reason"]


def test_model_files_keep_the_sensor_and_apply_it(tmp_path):
    run = runs("z_scale")[0]
    m = Model(MAPS).with_values("squareness-temperature@z_scale", [1.0])
    path = m.save(tmp_path / "m.json")
    back = Model.load(path)
    assert back.names == ("squareness-temperature@z_scale",) and back.effects[0][0].sensor == "z_scale"
    np.testing.assert_array_equal(back.compensate(run), m.compensate(run))
    # It matters: the z scale sits 2 K above the mean in this run.
    shift = np.linalg.norm(m.compensate(run) - Model(MAPS).compensate(run), axis=1)
    assert shift.max() > 0.005


def test_bad_sensor_choices_are_named():
    with pytest.raises(InputError, match="alternatives of one effect"):
        Model(MAPS).with_values("squareness-temperature@z_scale", [1.0]).with_values(
            "squareness-temperature@x_scale", [1.0])
    with pytest.raises(InputError, match="@z_scale"):
        Model(MAPS).with_values("squareness-temperature", [1.0])
    m = Model(MAPS).with_values("squareness-temperature@mount", [1.0])
    with pytest.raises(InputError, match="role 'mount'.*x_scale"):
        m.compensate(runs("z_scale")[0])
    with pytest.raises(InputError, match="not a thermocouple role"):
        TruthMachine(MAPS, [SquarenessTemperature(sensor="ram")])
    with pytest.raises(InputError, match="must be a name"):
        SquarenessTemperature(sensor="")
    with pytest.raises(InputError, match="must be finite"):
        SquarenessTemperature(gain="high")
    assert parse("squareness-temperature:sensor=granite_top,gain=0.5") == SquarenessTemperature(0.5, "granite_top")
    assert "squareness-temperature" in LIBRARY and LIBRARY["squareness-temperature"].sensor is None


def test_a_candidate_name_stands_for_all_its_sensors():
    run = runs("z_scale")[0]
    d = cmmpose.diagnose(run, candidates=["squareness-temperature", "axis-temperature"], auto=False, patterns=False)
    names = {c.name for c in d.steps[0].ranking}
    assert names == {"axis-temperature"} | {f"squareness-temperature@{r}" for r in
                                            (*SCALES, "granite_top", "granite_bottom")}


def test_a_step_beyond_the_maps_is_taken_backwards_and_an_unevaluable_candidate_is_skipped():
    # The granite top 4 K above a mean of 29.7 C: a forward step of the gain
    # (a quarter) reads squareness at 30.7 C, beyond the maps (20-30 C) and
    # their 0.5 K tolerance; the backward step reads it at 28.7 C.
    run = simulate_ballbar_run(MAPS, 29.7, [E.GraniteGradient(kelvin=8.0, xy=0.0, yz=0.0, zx=0.0)], jitter=0.0015,
                               seed=5, scanner=Scanner(points_per_profile=256))[0]
    from cmmpose.model.spec import UserEffect
    from cmmpose.diagnosis.identify import Problem

    def refuses(inputs, k):
        if k != 0:
            raise InputError("outside what this user effect can model")
        return np.zeros((len(inputs["u"]), 3))

    user = UserEffect.create("refuses", refuses, {"k": ("1", 1.0)})
    p = Problem(Model(MAPS), run, extra=[user])
    top = "squareness-temperature@granite_top"
    assert top in p.candidates and np.all(np.isfinite(p.columns[top])) and np.any(p.columns[top] != 0)
    assert "refuses" not in p.candidates and "cannot be evaluated" in p.skipped["refuses"]
    # The bottom sits 4 K below the mean: its forward step reads squareness
    # at 28.7 C, where the top's backward one does, so the two columns are
    # opposite, up to the two channels' noise (0.02 K each, so up to 0.05 K
    # apart at the steps, against the 1 K each step moves: 5 %).
    bottom = p.columns["squareness-temperature@granite_bottom"]
    np.testing.assert_allclose(p.columns[top], -bottom, atol=0.05 * np.abs(bottom).max())


@pytest.mark.slow
def test_from_the_command_line_with_the_truth_in_the_report(tmp_path):
    from click.testing import CliRunner

    from cmmpose.cli import main

    dirs = []
    for (temperature, axis, seed) in PLAN:
        d = tmp_path / f"run{seed}"
        res = CliRunner().invoke(main, ["simulate", "-o", str(d), "--temperature", str(temperature), "--jitter", "0.0015",
                                        "--seed", str(seed), "--effect", f"axis-temperature:{'xyz'[axis]}=3",
                                        "--effect", "squareness-temperature:sensor=y_scale"])
        assert res.exit_code == 0, res.output
        dirs.append(str(d))
    res = CliRunner().invoke(main, ["diagnose", *dirs, "--joint", "--json", "--max-effects", "3", "--report",
                                    str(tmp_path / "joint")])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout)
    joint = (tmp_path / "joint" / "diagnose.html").read_text()
    assert "Every run under the one model" in joint and all(d in joint for d in dirs)
    found = {x["name"]: x["decision"] for x in doc["decisions"]}
    assert found["squareness-temperature@y_scale"] == "added" and found["axis-temperature"] == "added"
    assert found["squareness-temperature@z_scale"] == "not chosen"
    # One run alone: the truth's sensor is named in the report's truth table.
    res = CliRunner().invoke(main, ["diagnose", dirs[0], "--report", str(tmp_path / "r"), "--json"])
    assert res.exit_code == 0, res.output
    page = (tmp_path / "r" / "diagnose.html").read_text()
    row = page[page.index("the simulator&#x27;s truth") if "the simulator&#x27;s truth" in page
                else page.index("the simulator's truth"):]
    assert "squareness-temperature@y_scale" in row and "not a candidate" not in row


def test_an_axis_can_warm_during_the_run():
    # The simulator's scenario for sensors that move differently within one
    # run: the z scale warms at 6 K/h from the mean, x sits 2 K above it.
    e = E.AxisTemperature(x=2.0, z_per_hour=6.0)
    off = e.role_offsets(np.array([0.0, 1800.0]))
    np.testing.assert_allclose(off["z_scale"], [0.0, 3.0])
    np.testing.assert_allclose(off["x_scale"], [2.0, 2.0])
    run = simulate_ballbar_run(MAPS, 24.0, [e], seed=6, scanner=Scanner(points_per_profile=64))[0]
    inputs = Model(MAPS).inputs(run)
    z = inputs.sensor("z_scale") - inputs.temperature
    t = inputs.t
    # The run lasts 800 s: z rises 1.33 K against the scales' mean, which
    # itself rises a third of that. The departure is averaged over 300 s,
    # which flattens it within half a window of the log's ends: judge inside.
    inside = (t > t.min() + 150.0) & (t < t.max() - 150.0)
    rise = np.polyfit(t[inside], z[inside], 1)[0] * 3600.0
    assert abs(rise - 6.0 * 2 / 3) < 0.2


def test_a_joint_candidate_must_act_on_every_run():
    # A mount thermocouple in one run only: the mount's candidates cannot be
    # shared, and the reason names the run that lacks it.
    plain = runs("z_scale")[0]
    mounted = simulate_ballbar_run(MAPS, 26.0, [E.AxisTemperature(z=3.0), parse("mount-expansion:kelvin=2")],
                                   jitter=0.0015, seed=7, scanner=Scanner(points_per_profile=256))[0]
    from cmmpose.diagnosis.joint import JointProblem

    p = JointProblem(Model(MAPS), [plain, mounted])
    assert "mount-expansion" not in p.candidates and p.skipped["mount-expansion"].startswith("run 1: the run lacks")
    assert "squareness-temperature@mount" not in p.candidates
    assert p.skipped["squareness-temperature@mount"] == "not every run can show it: run 1 lacks its inputs"
    assert "squareness-temperature@z_scale" in p.candidates


def test_broken_thermocouples_leave_their_role_out_not_the_run():
    # X2 open-circuit from the start, the only granite-top channel too, and
    # (in the second log) Z1 stuck half way: x_scale and z_scale come from
    # their clean channels, granite_top is not offered, the diagnosis runs.
    from cmmpose.run import Run

    run = runs("z_scale")[0]

    def with_log(change):
        log = {k: np.array(v, dtype=float) for k, v in run.temperatures.items()}
        change(log)
        return Run(dict(run.points), dict(run.scans), dict(run.poses), log, run.temperature_channels, run.artefact,
                   run.maps, run.metadata, run.created)

    def open_circuits(log):
        log["X2"][:] = 999.9
        log["GT"][:] = 999.9

    def and_stuck(log):
        open_circuits(log)
        half = len(log["t"]) // 2
        log["Z1"][half:] = log["Z1"][half]

    clean = Model(MAPS).inputs(run)
    inputs = Model(MAPS).inputs(with_log(open_circuits))
    assert set(inputs.sensors) == {"x_scale", "y_scale", "z_scale", "granite_bottom"}
    # The roles' temperatures agree with the clean log's to the channels'
    # noise (0.02 K each) though the machine mean moved (X2 is out of it).
    for role in ("x_scale", "z_scale"):
        np.testing.assert_allclose(inputs.sensor(role), clean.sensor(role), atol=0.03)
    broken = with_log(and_stuck)
    assert set(Model(MAPS).inputs(broken).sensors) == {"x_scale", "y_scale", "z_scale", "granite_bottom"}
    d = cmmpose.diagnose(broken, max_effects=2, patterns=False)
    x = decisions(d)
    assert "squareness-temperature@granite_top" not in x and "granite-gradient" in d.skipped
