"""The README's command blocks run as written, in order, in a fresh folder
that sees the clone's ``data/`` as a user at the root of a fresh clone does.

Two kinds of block are not run here, and their fence says so: ``bash setup``
(the two install commands, which CI runs itself in .ci/run) and ``bash
hardware`` (acquisition from serial ports: tests/acquire/ drives the
same code through simulated instruments on ptys)."""

from __future__ import annotations

import re
import shutil
import subprocess

import pytest
from repo import REPO

ROOT = REPO
README = ROOT / "README.md"
FENCE = re.compile(r"^```bash([^\n]*)\n(.*?)^```", flags=re.S | re.M)


def blocks(text: str) -> list[tuple[str, str]]:
    """(info after ``bash``, body) of every bash block, in order."""
    return [(m.group(1).strip(), m.group(2)) for m in FENCE.finditer(text)]


def test_every_bash_block_is_run_or_says_why_not():
    kinds = [info for info, _ in blocks(README.read_text(encoding="utf-8"))]
    assert set(kinds) <= {"", "setup", "hardware"}, kinds
    assert kinds.count("") >= 2 and kinds.count("setup") == 1


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("cmmpose") is None, reason="needs the installed cmmpose command")
def test_readme_commands_run_as_written(tmp_path):
    run = [body for info, body in blocks(README.read_text(encoding="utf-8")) if info == ""]
    (tmp_path / "data").symlink_to(ROOT / "data", target_is_directory=True)
    script = "set -euo pipefail\n" + "\n".join(run)
    res = subprocess.run(["bash", "-c", script], cwd=tmp_path, capture_output=True, text=True, timeout=900)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    # what the commands promise is there
    assert (tmp_path / "cmmpose-demo" / "evaluation.json").is_file()
    assert (tmp_path / "report1" / "evaluation.json").is_file()
    assert len((tmp_path / "compensated.csv").read_text().splitlines()) == 3905
    assert {p.name for p in (tmp_path / "comp").iterdir()} >= {"x.comp", "y.comp", "z.comp"}
    assert (tmp_path / "imported.csv").is_file() and (tmp_path / "model3.json").is_file()
    assert (tmp_path / "report3" / "diagnose.html").stat().st_size > 10_000
