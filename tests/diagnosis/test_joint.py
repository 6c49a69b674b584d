"""Several runs together (issue 16): one model with shared effect parameters
and per-run noise; runs at two temperatures of the same artefact pin its
expansion, which neither run alone can, and a shared effect is determined
better than by either run."""

from __future__ import annotations

import functools
import json

import pytest
from click.testing import CliRunner

import cmmpose
from cmmpose.cli import main
from cmmpose.diagnosis.joint import diagnose_jointly
from cmmpose.errors import InputError
from cmmpose.sim import effects as E
from cmmpose.sim.runs import simulate_ballbar_run
from cmmpose.sim.scanner import Scanner

TRUTH = [E.ArtefactExpansion(ppm_per_kelvin=11.5), E.Squareness(yz=12.0)]


@functools.lru_cache(maxsize=None)
def runs():
    return tuple(simulate_ballbar_run(cmmpose.ErrorMapSet.thesis(), t, TRUTH, jitter=0.0015, seed=s,
                                      scanner=Scanner(points_per_profile=256))[0] for t, s in ((21.0, 1), (27.0, 2)))


def decision(d, name):
    return next(x for x in d.decisions() if x["name"] == name)


def test_two_temperatures_pin_the_artefact_expansion_and_share_the_squareness():
    alone = [cmmpose.diagnose(r, max_effects=3, patterns=False) for r in runs()]
    for d in alone:
        assert decision(d, "artefact-expansion")["decision"] == "not observable"
        assert "squareness" in d.added
    joint = diagnose_jointly(list(runs()), max_effects=3)
    assert sorted(joint.added) == ["artefact-expansion", "squareness"]
    e = decision(joint, "artefact-expansion")
    assert abs(e["values"]["ppm_per_kelvin"] - 11.5) < 4 * e["uncertainty"]["ppm_per_kelvin"] < 2.0
    sq = decision(joint, "squareness")
    assert abs(sq["values"]["yz"] - 12.0) < 4 * sq["uncertainty"]["yz"]
    assert sq["uncertainty"]["yz"] < min(decision(d, "squareness")["uncertainty"]["yz"] for d in alone)
    assert len(joint.run_figures) == len(joint.steps) and all(len(f) == 2 for f in joint.run_figures)
    doc = json.loads(joint.to_json())
    assert doc["runs"] == ["run 1", "run 2"] and len(doc["run_figures"][0]) == 2


def test_separate_artefacts_cannot_pin_the_expansion():
    joint = diagnose_jointly(list(runs()), max_effects=3, same_artefact=False)
    assert "artefact-expansion" not in joint.added


def test_joint_from_the_command_line(tmp_path):
    dirs = []
    for i, r in enumerate(runs()):
        r.save(tmp_path / f"run{i}")
        dirs.append(str(tmp_path / f"run{i}"))
    res = CliRunner().invoke(main, ["diagnose", *dirs, "--joint", "--max-effects", "3", "--json",
                                    "--save-model", str(tmp_path / "m.json"), "--corrected-maps",
                                    str(tmp_path / "corrected.csv")], catch_exceptions=False)
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout)
    assert doc["runs"] == dirs and {x["name"] for x in doc["decisions"] if x["decision"] == "added"} == {
        "artefact-expansion", "squareness"}
    assert (tmp_path / "m.json").is_file()
    # --corrected-maps works jointly too (one CSV, or one per temperature of a set beside it)
    assert list(tmp_path.glob("corrected*.csv"))
    res = CliRunner().invoke(main, ["diagnose", dirs[0], "--joint"])
    assert res.exit_code != 0 and "two or more runs" in res.output
    # --reproducibility takes one value, or one per run (tests/diagnosis/test_noise_floor.py); a count that is
    # neither is refused, naming the option
    res = CliRunner().invoke(main, ["diagnose", *dirs, "--joint", "--reproducibility", "1.0,2.0,3.0"])
    assert res.exit_code == 2 and "--reproducibility" in res.output and "3 values for 2 runs" in res.output


def test_bad_inputs():
    with pytest.raises(InputError, match="two or more"):
        diagnose_jointly([runs()[0]])
    with pytest.raises(InputError, match=r"runs\[1\]"):
        diagnose_jointly([runs()[0], "run"])
    with pytest.raises(InputError, match="nonsense"):
        diagnose_jointly(list(runs()), add=["nonsense"])
