"""How fast the recorder takes the scanner + scales stream, against the
Hyscan 45C's own rate (1024 points per profile, 3.3 Hz mirror, both
directions: 6.6 profiles/s, about 6,760 points/s).

Two runs over a real pty with the simulated instruments (scanner and
thermocouple logger together, journal synced to disk every 0.2 s):

1. paced at 10x the Hyscan rate (66 profiles/s) for a few seconds: no loss;
2. a burst, the scanner sending as fast as the recorder takes it: the
   sustained rate, printed as a multiple of the Hyscan rate.

"No loss" is checked, not assumed: every frame in the journal equals the
frame sent, in order, with no rejection and no sequence gap.

    python benches/acquire_rate.py [--profiles 3000] [--paced-seconds 5]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from cmmpose.acquire import Recorder, read_journal
from cmmpose.sim.instruments import SimClock, SimLogger, SimScanner, synthetic_profiles

HYSCAN_RATE = 6.6  # profiles/s: 3.3 Hz mirror, bidirectional
POINTS = 1024


def record(profiles, *, burst: bool, workdir: Path, name: str):
    clock = SimClock(1.0)
    scanner = SimScanner(profiles, clock, burst=burst)
    logger = SimLogger({"t": np.array([0.0, 1e6]), **{f"C{k}": np.array([20.0, 21.0]) for k in range(11)}}, clock)
    rec = Recorder(workdir / name, scanner.port, logger.port, thermo_interval=0.1, flush_interval=0.2)
    with scanner, logger:
        rec.start()
        scanner.finished.wait()
        while rec.stats.scanner.records < len(scanner.sent):
            time.sleep(0.01)
        run = rec.finish()
    contents = read_journal(workdir / name / "journal.cmmj")
    frames = [f for _, f in contents.scanner]
    hosts = np.array([h for h, _ in contents.scanner])
    a = run.metadata["acquisition"]["scanner"]
    lossless = frames == [s["frame"] for s in scanner.sent] and not a["rejected"] and a["missing"] == 0 \
        and len(frames) == len(profiles)
    span = hosts[-1] - hosts[0]
    rate = (len(frames) - 1) / span if span > 0 else float("inf")
    return rate, lossless, run.n_points, contents.good_bytes


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--profiles", type=int, default=3000, help="profiles in the burst")
    ap.add_argument("--paced-seconds", type=float, default=5.0, help="length of the paced 10x run, s")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        n = int(args.paced_seconds * 10 * HYSCAN_RATE)
        rate, ok, pts, nbytes = record(synthetic_profiles(n, POINTS, 10 * HYSCAN_RATE), burst=False, workdir=tmp, name="paced")
        print(f"paced at 10x Hyscan: {n} profiles, {rate:.1f} profiles/s received "
              f"({rate / HYSCAN_RATE:.1f}x), {pts:,} points, lossless: {ok}")
        t0 = time.perf_counter()
        rate, ok2, pts, nbytes = record(synthetic_profiles(args.profiles, POINTS, HYSCAN_RATE, seed=1), burst=True,
                                        workdir=tmp, name="burst")
        wall = time.perf_counter() - t0
        print(f"burst: {args.profiles} profiles of {POINTS} points ({nbytes / 1e6:.1f} MB journal) in {wall:.1f} s; "
              f"sustained {rate:.0f} profiles/s = {rate * POINTS / 1e6:.2f} M points/s, lossless: {ok2}")
        print(f"ratio to the Hyscan data rate ({HYSCAN_RATE} profiles/s x {POINTS} points): {rate / HYSCAN_RATE:.0f}x")
        if not (ok and ok2 and rate >= 10 * HYSCAN_RATE):
            raise SystemExit("FAILED: loss, or below 10x the Hyscan rate")


if __name__ == "__main__":
    main()
