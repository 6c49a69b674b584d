"""Generate data/examples/interferometer/: the 15 raw laser-interferometer runs
(linear, straightness and the pitch and yaw angles of each carriage; the rolls
are not measured, as in the thesis) that ``cmmpose calibrate map`` builds a map
from and ``cmmpose standards iso230-2`` evaluates, simulated on the thesis's 20 C map
(cmmpose.sim.interferometer: air at 23 C / 750 mmHg / 40 %RH, seed 2). The
README's examples read them, so they run from a fresh clone.

Run: python scripts/make_example_interferometer.py
"""

from pathlib import Path

import cmmpose
from cmmpose.calibration.interferometer import write_run
from cmmpose.sim.interferometer import simulate_interferometer_runs

OUT = Path(__file__).resolve().parents[1] / "python" / "cmmpose" / "data" / "examples" / "interferometer"

truth = cmmpose.ErrorMapSet.thesis().maps[0]
runs, _ = simulate_interferometer_runs(truth, include_roll=False, seed=2)
OUT.mkdir(exist_ok=True)
for run in runs:
    write_run(run, OUT / f"{run.axis}_{run.component}.csv".lower())
print(f"wrote {len(runs)} runs to {OUT}")
