"""docs/user-effects.md runs as written: an effect outside the library is
flagged under `unexplained` with the input it follows, then explained by a
ten-line user effect, and the error falls."""

from __future__ import annotations

import json
import re
import shutil
import subprocess

import pytest
from repo import REPO

DOC = REPO / "docs" / "user-effects.md"


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("cmmpose") is None, reason="needs the installed cmmpose command")
def test_user_effect_tutorial_runs(tmp_path):
    blocks = re.findall(r"```bash\n(.*?)```", DOC.read_text(encoding="utf-8"), flags=re.S)
    assert len(blocks) == 3
    res = subprocess.run(["bash", "-c", "set -euo pipefail\n" + "\n".join(blocks)], cwd=tmp_path,
                         capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    before = json.loads((tmp_path / "before.json").read_text())
    after = json.loads((tmp_path / "after.json").read_text())
    # the flag: one periodic finding along x, on the D reading, at the period put in
    (finding,) = before["unexplained"]
    assert finding["kind"] == "periodic" and finding["input"] == "D" and finding["axis"] == "x"
    assert finding["period_mm"] == pytest.approx(12.0, abs=0.05)
    assert finding["size_um"] == pytest.approx(2.0, abs=0.3) and finding["p_value"] < finding["threshold"]
    assert (tmp_path / "draft.py").read_text().count("UserEffect.create") == 1
    # the user effect: added, fitted to the truth within its uncertainty, the error falls, nothing left over
    added = [d for d in after["decisions"] if d["decision"] == "added"]
    assert [d["name"] for d in added] == ["x-scale-ripple"]
    v, u = added[0]["values"], added[0]["uncertainty"]
    assert abs(v["sin_um"] - 2.0) < 4 * u["sin_um"] and abs(v["cos_um"]) < 4 * u["cos_um"], (v, u)
    first, last = after["steps"][0], after["steps"][-1]
    assert last["rms_accuracy_error_um"] < 0.75 * first["rms_accuracy_error_um"]
    assert after["unexplained"] == []
    # the draft written from the finding explains it as well
    res = subprocess.run(["cmmpose", "diagnose", "rippled-run", "--user-effect", "draft.py", "--json"], cwd=tmp_path,
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    assert [d["name"] for d in json.loads(res.stdout)["decisions"] if d["decision"] == "added"] == ["my-effect"]
    # the saved model with its user effect starts the next diagnosis
    res = subprocess.run(["cmmpose", "diagnose", "rippled-run", "--model", "rippled-model.json", "--user-effect",
                          "x_scale_ripple.py", "--no-auto", "--json"], cwd=tmp_path, capture_output=True, text=True,
                         timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    doc = json.loads(res.stdout)
    assert doc["steps"][0]["effects"][0]["name"] == "x-scale-ripple" and doc["unexplained"] == []
    res = subprocess.run(["cmmpose", "diagnose", "rippled-run", "--model", "rippled-model.json"], cwd=tmp_path,
                         capture_output=True, text=True, timeout=300)
    assert res.returncode != 0 and "--user-effect" in res.stderr + res.stdout and "Traceback" not in res.stderr
