"""NIST's DMG sphere scans (data/nist_dmg, shipped in the repository and the
wheel; source and citation in data/SOURCES.md) for the tests: the folder, and
NIST's own E3125 results per file. A missing folder is a broken checkout, not
a reason to skip."""

from __future__ import annotations

import csv
import pytest

from repo import REPO

NIST = REPO / "data" / "nist_dmg"
FILES = [f"SPH10{k}" for k in range(1, 6)]


def reference_rows() -> dict[str, dict[str, str]]:
    """NIST's reference_centres.csv, one row per file (metres, counts)."""
    if not (NIST / "reference_centres.csv").is_file():
        pytest.fail(f"NIST reference scans missing: expected {NIST} (a broken checkout)")
    with open(NIST / "reference_centres.csv", newline="") as f:
        return {row["file"]: row for row in csv.DictReader(f)}
