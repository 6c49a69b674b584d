"""Coverage of the command-line calibration's stated uncertainties: how often
its errors fall within 2 (and 1, 3) stated standard uncertainties, over many
noise seeds, on the moving-bridge example machine with its maps and three
vernier points (tests/support/calibration_study.py runs one trial: three
``cmmpose calibrate alignment`` and one ``cmmpose calibrate offset``).

    python benches/calibration_coverage.py [--trials 200]

Beside it, in the same run, the offset's coverage when the pose's covariance
is cut to its diagonal and acts through the lever only (what ``calibrate
offset`` did before it read the full record back): the baseline.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from cmmpose.calibration import AlignmentLibrary, ReferenceReading, mount_offset

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "support"))
from calibration_study import GROUPS, cli_trial  # noqa: E402


def diagonal_readings(folder: Path) -> list[ReferenceReading]:
    """The baseline: each record as readings with uncorrelated uncertainties and
    a diagonal pose covariance acting through the lever."""
    lib = AlignmentLibrary(folder / "alignments.json")
    recs = [lib.load(n) for n in ("P0", "P1", "P2")]
    readings = [ReferenceReading.from_reading(r.pose, r.reading, r.reading_uncertainty,
                                              pose_covariance=np.diag(np.square(r.pose_uncertainty)))
                for r in recs]
    return readings


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--trials", type=int, default=200)
    args = ap.parse_args()
    t0 = time.perf_counter()
    trials, baseline = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(args.trials):
            folder = Path(tmp) / str(seed)
            z = cli_trial(seed, folder)
            trials.append(z)
            fit = mount_offset(diagonal_readings(folder), tolerance=None)
            baseline.append((np.asarray(fit.offset) - z["true_offset"]) / fit.uncertainty)
    wall = time.perf_counter() - t0
    print(f"{args.trials} trials of the CLI calibration (moving-bridge, maps, 3 vernier points) in {wall:.1f} s")
    print(f"{'group':8} {'n':>6} {'within 1':>9} {'within 2':>9} {'within 3':>9} {'sd of z':>8} {'max |z|':>8}")
    every = []
    for g in GROUPS:
        z = np.concatenate([t[g].ravel() for t in trials])
        every.append(z)
        print(f"{g:8} {z.size:6d} " + " ".join(f"{np.mean(np.abs(z) <= k):9.1%}" for k in (1, 2, 3))
              + f" {z.std():8.2f} {np.abs(z).max():8.2f}")
    z = np.concatenate(every)
    print(f"{'all':8} {z.size:6d} " + " ".join(f"{np.mean(np.abs(z) <= k):9.1%}" for k in (1, 2, 3))
          + f" {z.std():8.2f} {np.abs(z).max():8.2f}   (normal: 68.3 %, 95.4 %, 99.7 %)")
    zb = np.concatenate(baseline)
    print(f"baseline (diagonal pose covariance, through the lever only): offset within 2: "
          f"{np.mean(np.abs(zb) <= 2):.1%}, sd of z {zb.std():.2f}")


if __name__ == "__main__":
    main()
