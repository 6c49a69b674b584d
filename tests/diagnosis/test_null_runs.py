"""Null machines (issue 33, "Done when": "on null machines at most 1 % of runs carry any claim"): a handful of
runs of every layout benches/diagnosis_false_alarms.py measures (200 seeds each there) carry no claim, and the
arithmetic behind the promise holds."""

import pytest

import cmmpose
from cmmpose.diagnosis.floor import FLOOR_ALPHA
from cmmpose.diagnosis.statistics import ALPHA, CLAIM_FAMILIES
from repo_scripts import bench



def _bench():
    return bench("diagnosis_false_alarms")


def test_the_claim_families_together_stay_within_the_promise():
    """Every family of tests whose rejection is a claim runs at ALPHA (the floor's too): by the union bound a
    null run carries a claim with probability at most CLAIM_FAMILIES * ALPHA, within issue 33's 1 %."""
    bench = _bench()
    assert FLOOR_ALPHA == ALPHA
    assert CLAIM_FAMILIES * ALPHA <= bench.PROMISE == 0.01


@pytest.mark.parametrize("layout", ["b89", "crossed", "plate", "plate-joint"])
def test_null_runs_carry_no_claim(layout):
    bench = _bench()
    maps = cmmpose.ErrorMapSet.thesis()
    for seed in (0, 1):
        d, _ = bench.diagnose_null(layout, seed, maps, 3.0, 256, True)
        claims = d.claims
        assert set(claims) == set(bench.KINDS)
        assert not any(claims.values()), (layout, seed, claims, d.added, (d.noise or {}).get("verdict"))
        assert d.noise["floor_stated_or_measured"] and d.noise["noise"] is True
