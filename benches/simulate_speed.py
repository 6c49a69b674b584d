"""Wall time of ``cmmpose simulate`` (the default B89 run, about 476,000
points, written as a run directory) as a user sees it: a fresh process from
start to exit, and of what that process spends importing ``cmmpose.cli``.

    python benches/simulate_speed.py [--repeats 5]

Each run is ``python -m cmmpose.cli simulate -o DIR --overwrite`` into one
temporary directory; figures are min-max over --repeats. The import figure is
``-X importtime``'s cumulative time of ``cmmpose.cli`` in a fresh process.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def import_seconds() -> float:
    """Cumulative import time of cmmpose.cli in a fresh interpreter, s."""
    err = subprocess.run([sys.executable, "-X", "importtime", "-c", "import cmmpose.cli"], check=True,
                         capture_output=True, text=True).stderr
    line = next(x for x in err.splitlines() if x.rstrip().endswith("| cmmpose.cli"))
    return int(line.split("|")[1]) * 1e-6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    walls = []
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "run"
        for _ in range(args.repeats):
            t = time.perf_counter()
            subprocess.run([sys.executable, "-m", "cmmpose.cli", "simulate", "-o", str(out), "--overwrite"],
                           check=True, capture_output=True)
            walls.append(time.perf_counter() - t)
    imports = [import_seconds() for _ in range(args.repeats)]
    print(f"cmmpose simulate (default run, fresh process), {args.repeats} runs: "
          f"{min(walls):.2f}-{max(walls):.2f} s wall; importing cmmpose.cli {min(imports):.2f}-{max(imports):.2f} s")


if __name__ == "__main__":
    main()
