"""docs/your-machine.md runs as written: its bash blocks, in order, in a
fresh folder, on a machine that is not the thesis's."""

from __future__ import annotations

import json
import re
import shutil
import subprocess

import numpy as np
import pytest
from repo import REPO

DOC = REPO / "docs" / "your-machine.md"


@pytest.mark.slow
@pytest.mark.skipif(not DOC.is_file() or shutil.which("cmmpose") is None,
                    reason="needs the docs and the installed cmmpose command")
def test_your_machine_walkthrough_runs(tmp_path):
    blocks = re.findall(r"```bash\n(.*?)```", DOC.read_text(encoding="utf-8"), flags=re.S)
    assert len(blocks) >= 5
    script = "set -euo pipefail\n" + "\n".join(blocks)
    res = subprocess.run(["bash", "-c", script], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    assert "moving-bridge" in res.stdout
    assert (tmp_path / "b89-report" / "evaluation.json").is_file()
    assert (tmp_path / "my-cmm-model.json").is_file()
    assert len((tmp_path / "scan-xyz.csv").read_text().splitlines()) == 3905
    assert len((tmp_path / "scan-aligned-xyz.csv").read_text().splitlines()) == 3905
    # the CLI calibration found the simulated offset error within its stated uncertainty (k = 3)
    fit = json.loads((tmp_path / "offset.json").read_text())
    truth = json.loads((tmp_path / "align" / "A90B90-truth.json").read_text())
    for est, true, u in zip(fit["offset"], truth["true_offset"], fit["uncertainty"]):
        assert abs(est - true) < 3 * u, (fit, truth)
    # ... and stored it where `compensate --alignment` takes it from: the aligned scan used the solved offset
    assert fit["stored_in"] == "align.json"
    library = json.loads((tmp_path / "align.json").read_text())
    assert library["poses"]["A90B90"]["offset"] == fit["offset"]
    # (the record keeps the covariance symmetrised: the last bit of an off-diagonal pair may differ)
    np.testing.assert_allclose(library["poses"]["A90B90"]["offset_covariance"], fit["covariance"], rtol=1e-14)
