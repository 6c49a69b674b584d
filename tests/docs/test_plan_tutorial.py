"""docs/plan.md runs as written (issue 25, section 4): diagnose, plan, measure
(simulated), diagnose jointly, verify on placements no step used."""

from __future__ import annotations

import json
import re
import shutil
import subprocess

import pytest
from repo import REPO

DOC = REPO / "docs" / "plan.md"


@pytest.mark.slow
@pytest.mark.skipif(not DOC.is_file() or shutil.which("cmmpose") is None,
                    reason="needs the docs and the installed cmmpose command")
def test_plan_tutorial_runs(tmp_path):
    blocks = re.findall(r"```bash\n(.*?)```", DOC.read_text(encoding="utf-8"), flags=re.DOTALL)
    assert len(blocks) == 4
    script = "set -euo pipefail\n" + "\n".join(blocks)
    res = subprocess.run(["bash", "-c", script], cwd=tmp_path, capture_output=True, text=True, timeout=1200)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    plan = json.loads((tmp_path / "plan.json").read_text())
    assert plan["status"]["squareness.yz"] == "invisible" and plan["status"]["squareness.zx"] == "invisible"
    assert {p["placement"][:2] for p in plan["proposals"]} == {"xz", "yz"}
    assert "yz@" in res.stdout and "de-aliases squareness.yz" in res.stdout
    model = {e["name"]: e for e in json.loads((tmp_path / "m2.json").read_text())["effects"]}
    for param, truth in (("xy", 8.0), ("yz", 6.0), ("zx", -5.0)):
        value, u = model["squareness"]["params"][param], model["squareness"]["uncertainty"][param]
        assert abs(value - truth) < max(3 * u, 0.6), (param, value, u)  # arc-seconds

    def rms(name):
        doc = json.loads((tmp_path / name).read_text())
        return next(r for r in doc["results"] if r["label"] == "compensated")["rms_deviation_um"]

    maps, m1, m2 = rms("check-maps.json"), rms("check-m1.json"), rms("check-m2.json")
    assert m2 < 0.6 * maps and m2 < 0.6 * m1, (maps, m1, m2)


def test_the_walkthrough_resolving_an_ambiguity_runs_as_written():
    """docs/plan.md, "Telling competing explanations apart" (issue 33, section 5): an ambiguous diagnosis,
    the T-optimal placement, the joint diagnosis that resolves it, the unseen placement's error falling."""
    blocks = re.findall(r"```python walkthrough\n(.*?)```", DOC.read_text(encoding="utf-8"), flags=re.DOTALL)
    assert len(blocks) == 2
    ns: dict = {"__name__": "walkthrough"}
    exec(compile(blocks[0], "plan.md walkthrough 1", "exec"), ns)
    rivals = ns["rivals"]
    assert ns["first"].added == [] and sorted(rivals.names) == ["roll-x", "twist"] and not rivals.agree
    # 50 um at the corners of a 900 x 550 travel; the roll's Y term adds up to 50 um x 500 / 275 more: tens of um.
    assert rivals.largest_difference_um > 20
    exec(compile(blocks[1], "plan.md walkthrough 2", "exec"), ns)
    first = ns["proposed"].proposals[0]
    assert not first.placement.startswith("xy@") or "z=-400" not in first.placement
    sep = first.separates[0]
    assert sep["separation"] > 25 and sep["difference_um"] > 1  # well beyond chi-square's 1-dof 5-sigma
    assert ns["second"].added == ["twist"] and ns["second"].open_ambiguity == []
    before, after = ns["before"].to_dict(), ns["after"].to_dict()
    # The first model added nothing: the plain maps' figure; the second removes more than half of it.
    assert after["model_rms_um"] < 0.5 * before["model_rms_um"], (before, after)
