"""What each map component does to a ball plate at three placements
(docs/artefacts.md, "Signatures"): a machine whose only error is one of the
21 components of its map (the 18 of the three carriages and the three
squarenesses), a KOBA 0420 plate in the XY, XZ and YZ planes of the thesis
machine, a noiseless scanner, and the deviations after each placement's
best-fit rigid transform (uncompensated: the map is the machine's error).

Each carriage component varies linearly over its axis's travel, from -A to
+A (A = 5 um for a displacement, 5 arc-seconds for a rotation): a constant
would be a rigid motion, which no plate sees. A squareness is 5 arc-seconds.

    python scripts/artefact_signatures.py                 # table (markdown) on stdout
    python scripts/artefact_signatures.py --images docs/img/signatures   # and one PNG per component

Units: um, arc-seconds, mm.
"""

from __future__ import annotations

import argparse
import io
import sys
from pathlib import Path


from cmmpose import artefacts
from cmmpose.evaluation.artefact import evaluate_artefact
from cmmpose.errormap import ErrorMap
from cmmpose.sim import Scanner
from cmmpose.sim.artefact_runs import simulate_artefact_run

#: Size of each component: um for a displacement, arc-seconds for a rotation or squareness.
AMPLITUDE = 5.0
ARTEFACT = "koba-0420"
PLACEMENTS = ("planes",)
_COLUMN = {"delta_x": 1, "delta_y": 2, "delta_z": 3, "eps_x": 4, "eps_y": 5, "eps_z": 6}
_WHAT = {("delta", 0): "positioning", ("delta", 1): "straightness", ("eps", 0): "roll", ("eps", 1): "pitch",
         ("eps", 2): "yaw"}


def components() -> list[tuple[str, str]]:
    """(name, description) of the 21 components, e.g. ('X delta_y', 'X straightness in y')."""
    out = []
    for a, axis in enumerate("XYZ"):
        for c in ("delta_x", "delta_y", "delta_z", "eps_x", "eps_y", "eps_z"):
            k = "xyz".index(c[-1])
            if c.startswith("delta"):
                what = "positioning" if k == a else f"straightness in {'xyz'[k]}"
            else:
                # About its own axis a roll; about the others pitch and yaw (by the usual naming of each axis).
                what = "roll" if k == a else f"rotation about {'xyz'[k]}"
            out.append((f"{axis} {c}", f"{axis} {what}"))
    out += [("squareness xy", "squareness S_xy"), ("squareness yz", "squareness S_yz"),
            ("squareness zx", "squareness S_zx")]
    return out


def component_map(name: str, amplitude: float = AMPLITUDE) -> ErrorMap:
    """An error map whose only error is component ``name`` (see :func:`components`)."""
    zero = ErrorMap.zero(temperature=20.0)
    if name.startswith("squareness"):
        s = [0.0, 0.0, 0.0]
        s[("xy", "yz", "zx").index(name.split()[1])] = amplitude
        return ErrorMap(zero.table("x"), zero.table("y"), zero.table("z"), s, temperature=20.0,
                        source=f"only {name}")
    axis, column = name.split()
    tables = {a: zero.table(a).copy() for a in "xyz"}
    t = tables[axis.lower()]
    lo, hi = t[0, 0], t[-1, 0]
    t[:, _COLUMN[column]] = amplitude * (2 * (t[:, 0] - lo) / (hi - lo) - 1)
    return ErrorMap(tables["x"], tables["y"], tables["z"], [0.0, 0.0, 0.0], temperature=20.0,
                    source=f"only {name}")


def signature(name: str, artefact=None, amplitude: float = AMPLITUDE):
    """The evaluation (uncompensated result) of the plate on a machine with only ``name``."""
    artefact = artefacts.load_artefact(ARTEFACT) if artefact is None else artefact
    run, _ = simulate_artefact_run(artefact, list(PLACEMENTS), component_map(name, amplitude), 20.0, [],
                                   scanner=Scanner(noise=0.0), seed=0)
    return evaluate_artefact(run, None, 20.0).uncompensated


def table(names=None) -> list[dict]:
    """Per component: rms and largest deviation per placement, um."""
    artefact = artefacts.load_artefact(ARTEFACT)
    rows = []
    for name, what in components():
        if names and name not in names:
            continue
        r = signature(name, artefact)
        rows.append({"component": name, "what": what,
                     "rms_um": [p.rms * 1e3 for p in r.placements],
                     "largest_um": [p.largest.magnitude * 1e3 for p in r.placements],
                     "result": r})
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--images", type=Path, default=None, help="Write one PNG per component in this folder.")
    ap.add_argument("--dpi", type=int, default=45, help="Resolution of the PNGs (small: they go into the docs).")
    args = ap.parse_args(argv)
    rows = table()
    print("| component | what | rms deviation XY / XZ / YZ (um) | largest XY / XZ / YZ (um) | figure |")
    print("|---|---|---|---|---|")
    for row in rows:
        slug = row["component"].replace(" ", "_")
        fig = f"[png](img/signatures/{slug}.png)" if args.images else "-"
        print(f"| {row['component']} | {row['what']} | " + " / ".join(f"{x:.2f}" for x in row["rms_um"]) + " | "
              + " / ".join(f"{x:.2f}" for x in row["largest_um"]) + f" | {fig} |")
    if args.images:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        from PIL import Image

        from cmmpose.atomicfile import ensure_folder, write_bytes
        from cmmpose.evaluation.plots import plot_artefact_deviations

        ensure_folder(args.images)
        artefact = artefacts.load_artefact(ARTEFACT)
        for row in rows:
            unit = "um" if "delta" in row["component"] else "arc-seconds"
            fig = plot_artefact_deviations(artefact, row["result"], None,
                                           title=f"only {row['what']} ({row['component']}, {AMPLITUDE:g} {unit})")
            buffer = io.BytesIO()
            fig.savefig(buffer, format="png", dpi=args.dpi)
            plt.close(fig)
            # A palette of 48 colours: a third of the bytes, the same picture.
            small = io.BytesIO()
            Image.open(buffer).convert("RGB").quantize(48).save(small, format="png", optimize=True)
            write_bytes(args.images / f"{row['component'].replace(' ', '_')}.png", small.getvalue())
    return 0


if __name__ == "__main__":
    sys.exit(main())
