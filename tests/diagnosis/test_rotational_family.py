"""Issue 25 section 2: the map-correction family covers all 18 per-axis
components (each axis's three angles beside its position error and
straightnesses) and the squarenesses, with analytic centre-level
sensitivities, a component report that names what the run determines, and
corrected map files.

The references are independent of the family's code: the Rust kernel
compensating with maps edited by the correction (an angle acts over the
configuration's arms, docs/conventions.md), finite differences through the
kernel and the sphere fits, and a plate simulated on a machine whose yaw of
X is bowed (the truth machine of the simulator), judged on a placement that
no step of the diagnosis used.
"""

from __future__ import annotations

import functools
import json

import cmmpose
import numpy as np
import pytest
from click.testing import CliRunner
from cmmpose.artefacts import load_artefact
from cmmpose.cli import main
from cmmpose.model import Model
from cmmpose.diagnosis import cv as cvmod
from cmmpose.diagnosis import mapfamily as mf
from cmmpose.diagnosis.identify import Problem
from cmmpose.diagnosis.joint import diagnose_jointly
from cmmpose.errormap import ErrorMap, ErrorMapSet, data_path
from cmmpose.errors import InputError
from cmmpose.sim.artefact_runs import simulate_artefact_run
from cmmpose.sim.runs import simulate_ballbar_run
from cmmpose.sim.scanner import Scanner

PLATE = load_artefact(data_path("artefacts", "koba-0420.toml"))
PLACEMENTS = ("xy@x=300,y=250,z=-400", "xy@x=560,y=300,z=-400", "xy@x=430,y=270,z=-400")
JITTER = 0.0015  # mm per axis per scan
#: The hidden yaw of X: a bow of this many arc-seconds at mid-travel, zero at the ends (0 and 900 mm).
YAW_BOW_AS = 6.0


def _bowed(maps: ErrorMapSet, column: int = 6, amp: float = YAW_BOW_AS) -> ErrorMapSet:
    """The maps with a bow added to one column of the X table (6: eps_z, the yaw of X)."""
    out = []
    for m in maps.maps:
        tx = m.table("X").copy()
        tx[:, column] += amp * (1 - ((tx[:, 0] - 450.0) / 450.0) ** 2)
        out.append(ErrorMap(tx, m.table("Y"), m.table("Z"), m.squareness, m.temperature))
    return ErrorMapSet(out)


@functools.cache
def b89(seed=1):
    return simulate_ballbar_run(temperature=22.5, jitter=JITTER, seed=seed, scanner=Scanner(points_per_profile=128))[0]


@functools.cache
def yaw_plates():
    truth = _bowed(ErrorMapSet.thesis())
    runs = tuple(simulate_artefact_run(PLATE, [p], truth, jitter=JITTER, seed=40 + i,
                                       scanner=Scanner(points_per_profile=96))[0] for i, p in enumerate(PLACEMENTS))
    return truth, runs


def test_the_family_names_all_18_components_and_the_squarenesses():
    assert len(mf.COMPONENTS) == 18 and set(mf.ROTATIONAL) == {f"e{d}({a})" for a in "XYZ" for d in "xyz"}
    spec = mf.make("ez(X)", "poly", 0.0, 900.0)
    assert spec.params == ("p1_as", "p2_as", "p3_as") and set(spec.units) == {"arc-second"}
    assert "yaw of X" in spec.physics
    assert mf.parse(spec.name) == spec
    other = mf.make("ey(Y)", "sine", 0.0, 550.0, 120.0, kinematics="moving-bridge")
    assert other.name.endswith("@moving-bridge") and mf.parse(other.name).kinematics == "moving-bridge"
    sq = mf.make("sq(xy)", "const", 0.0, 550.0)
    assert sq.params == ("s_as",) and mf.parse(sq.name) == sq
    with pytest.raises(InputError, match="const"):
        mf.make("sq(xy)", "poly", 0.0, 550.0)
    with pytest.raises(InputError, match="configuration"):
        mf.make("ez(X)", "poly", 0.0, 900.0, kinematics="tripod")


@pytest.mark.parametrize("kinematics", ["thesis", "moving-bridge", "horizontal-arm"])
def test_angles_and_squareness_written_into_the_maps_compensate_as_the_model_does(kinematics, tmp_path):
    """The kernel with the edited maps is the reference for the correction's
    lever arms and signs, configuration by configuration."""
    run = b89()
    base = Model(ErrorMapSet.thesis().with_kinematics(kinematics))
    lo, hi = run.scales.min(axis=0) - 1, run.scales.max(axis=0) + 1
    x0 = base.compensate(run)
    for comp in ("ez(X)", "ex(X)", "ey(Y)", "ex(Z)", "sq(xy)", "sq(zx)"):
        a = mf.reading_axis(comp)
        shape = "const" if comp.startswith("sq") else "poly"
        spec = mf.make(comp, shape, float(lo[a]), float(hi[a]), kinematics=kinematics)
        values = [4.0] if shape == "const" else [3.0, -4.0, 2.0]
        m = base.with_values(spec, values)
        x1 = m.compensate(run)
        x2 = Model(mf.corrected_maps(m)).compensate(run)
        assert np.abs(x1 - x0).max() > 1e-3, comp  # arc-seconds over hundreds of mm: micrometres
        d = np.abs(x2 - x1).max(axis=1)
        # One map node (25 mm) inside the travel the shape spans, the maps interpolate the shape
        # linearly between their nodes: at most h^2 / 8 max|f''| (arc-seconds) over the lever.
        inside = (run.scales[:, a] > lo[a] + 25) & (run.scales[:, a] < hi[a] - 25)
        nodes = base.maps.maps[0].table("XYZ"[a])[:, 0]
        h = float(np.diff(nodes).max())
        q = np.linspace(lo[a], hi[a], 2001)
        f2 = np.abs(np.diff(spec.function_um(q, values), 2)).max() / (q[1] - q[0]) ** 2
        lever = np.linalg.norm(x0 - run.scales + run.scales * mf.arms(kinematics)[a], axis=1).max()
        bound = h ** 2 / 8 * f2 * mf.ARCSEC * lever + 2e-5
        # Over an end interval the maps go linearly to the value held beyond: at most h max|f'|.
        f1 = np.abs(np.diff(spec.function_um(q, values))).max() / (q[1] - q[0])
        assert d[inside].max() < bound, (comp, kinematics, d[inside].max(), bound)
        assert d.max() < bound + h * f1 * mf.ARCSEC * lever, (comp, kinematics, d.max())
    # A model file keeps an angle with its configuration and a squareness (rebuilt from their names).
    m = base.with_values(mf.make("ez(X)", "sine", float(lo[0]), float(hi[0]), 150.0, kinematics=kinematics),
                         [2.0, -1.0]).with_values(mf.make("sq(xy)", "const", float(lo[1]), float(hi[1])), [3.0])
    m.save(tmp_path / "m.json")
    back = Model.load(tmp_path / "m.json")
    assert back.names == m.names and np.allclose(back.compensate(run), m.compensate(run), rtol=0, atol=1e-12)
    # A correction found for one configuration is not written into another's maps.
    wrong = Model(ErrorMapSet.thesis().with_kinematics("gantry" if kinematics == "thesis" else "thesis"))
    spec = mf.make("ez(X)", "poly", float(lo[0]), float(hi[0]), kinematics=kinematics)
    with pytest.raises(InputError, match="configuration|machine"):
        mf.corrected_maps(wrong.with_values(spec, [1.0, 0.0, 0.0]))


@pytest.mark.parametrize("case", ["ballbar", "plate"])
def test_centre_level_sensitivities_of_an_angle_agree_with_finite_differences(case):
    run = b89() if case == "ballbar" else yaw_plates()[1][0]
    model = Model(ErrorMapSet.thesis())
    lo, hi = run.scales[:, 0].min(), run.scales[:, 0].max()
    for comp in ("ez(X)", "ey(X)"):
        spec = mf.make(comp, "poly", float(lo), float(hi))
        problem = Problem(model, run, {spec.name: spec})
        analytic = problem.columns[spec.name]
        for j in range(3):
            v = np.zeros(3)
            v[j] = spec.prior[j]  # one prior magnitude
            fd = problem.observe(model.with_values(spec, v)).residual - problem.base_obs.residual
            L = problem.classes == 0  # lengths, or the plate's deviations after each placement's rigid fit
            assert np.abs(fd[L]).max() > 1e-4, (comp, j)
            assert np.abs(fd[L] - analytic[L, j]).max() < 0.05 * np.abs(fd[L]).max() + 2e-5, (case, comp, j)


def test_a_bowed_yaw_found_on_two_placements_holds_on_the_third():
    truth, runs = yaw_plates()
    joint = diagnose_jointly(list(runs[:2]), max_effects=3)
    assert joint.added and joint.added[0].startswith("map:ez(X):"), joint.added
    # The joint diagnosis reports what the two placements together determine, in its JSON too.
    rep = json.loads(joint.to_json())["components"]
    assert set(rep) == set(mf.COMPONENTS) | set(mf.SQUARENESS) and rep["ez(X)"]["kind"] == "rotational"
    assert rep["dz(Z)"]["status"] == "invisible"  # two XY placements at one height: no Z travel
    held = runs[2]
    v = cvmod.verify(joint.model, held)
    best = cvmod.verify(Model(truth), held)["model_rms_um"]
    plain, model = v["plain_rms_um"], v["model_rms_um"]
    assert plain - best > 0.3, (plain, best)  # the bow shows on the held-out placement
    assert plain - model >= 0.5 * (plain - best), (plain, model, best)
    # The found yaw, written into the maps, is the model's correction.
    maps = cmmpose.diagnosis.mapfamily.corrected_maps(joint.model)
    spec = next(s for s, _ in joint.model.effects if s.name == joint.added[0])
    assert not isinstance(maps, ErrorMap) and len(maps.maps) == len(ErrorMapSet.thesis().maps)
    t = maps.maps[0].table("X")
    mid = (t[:, 0] > spec.lo + 50) & (t[:, 0] < spec.hi - 50)
    found = t[mid, 6] - ErrorMapSet.thesis().maps[0].table("X")[mid, 6]
    want = YAW_BOW_AS * (1 - ((t[mid, 0] - 450.0) / 450.0) ** 2)
    # The shape over the travel used, up to a constant and a slope (a squareness and a tilt of the placements).
    A = np.column_stack([np.ones(mid.sum()), t[mid, 0]])
    resid = (found - want) - A @ np.linalg.lstsq(A, found - want, rcond=None)[0]
    assert np.abs(resid).max() < 0.5 * YAW_BOW_AS, (found, want)


def test_the_component_report_is_in_the_diagnosis_and_its_json():
    d = cmmpose.diagnose(b89(), patterns=False)
    rep = d.components
    assert set(rep) == set(mf.COMPONENTS) | set(mf.SQUARENESS)
    for comp, r in rep.items():
        assert r["kind"] == mf.kind_of(comp)
        assert r["status"] in ("determined", "aliased", "invisible")
        assert (r["status"] == "aliased") == bool(r["aliased_with"])
        assert r["shapes_determined"] <= r["shapes_tried"] and r["why"]
        for other in r["aliased_with"]:
            assert comp in rep[other]["aliased_with"]  # aliasing is mutual
        sv = r["singular_values"]
        assert sv == sorted(sv, reverse=True)
        assert r["shapes_determined"] == sum(x > 2.0 for x in sv)
    # A ballbar in the XY plane and up the Z travel determines the yaw of X (its length
    # changes with the bar's Y lever); it cannot see the roll of Z (one probe pose).
    assert rep["ez(X)"]["shapes_determined"] > 0
    assert rep["ez(Z)"]["status"] == "invisible"
    doc = json.loads(d.to_json())
    assert doc["components"] == json.loads(json.dumps(rep))


def test_cli_diagnose_json_carries_the_component_report(tmp_path):
    run = b89()
    run.save(tmp_path / "run")
    r = CliRunner().invoke(main, ["diagnose", str(tmp_path / "run"), "--json", "--no-auto"])
    assert r.exit_code == 0, r.output
    doc = json.loads(r.output)
    assert set(doc["components"]) == set(mf.COMPONENTS) | set(mf.SQUARENESS)
    assert doc["components"]["ez(X)"]["kind"] == "rotational"
