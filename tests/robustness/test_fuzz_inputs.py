"""The fuzz script (scripts/fuzz_inputs.py) on a small budget: every entry
point that reads user data gives clear errors, no tracebacks and no silent
results. The README's reliability figures come from a full run."""

from __future__ import annotations

from repo import REPO
from repo_scripts import load_script

SCRIPT = REPO / "scripts" / "fuzz_inputs.py"


def test_no_tracebacks_and_no_silent_results():
    fuzz = load_script(SCRIPT, register=True)  # its dataclasses look their module up
    results = fuzz.run_all(trials=150, seed=7)
    assert set(results) == {"read_points (CSV)", "read_points (NPY)", "ErrorMap.read (CSV)", "Model.load", "Run.load",
                            "compensate"}
    for name, c in results.items():
        assert c.tried > 0 and c.errors > 0 and c.accepted > 0, (name, c)  # both kinds of input were tried
        assert c.crashes == 0 and c.silent == 0, (name, c.examples)
