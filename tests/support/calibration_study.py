"""The command-line calibration chain on simulated data, for its coverage study
(tests/calibration/test_uncertainty_coverage.py, benches/calibration_coverage.py).

One trial simulates a machine that is not the thesis's (the bundled
moving-bridge example: Y-X-Z stacking, the thesis maps, 21 C) with a pose error
and a mount-offset error, measures three vernier points, a plane scan and a
reference-sphere scan at each of the three standard poses, and runs
``cmmpose calibrate alignment`` (with the machine's maps and the stated vernier
uncertainty) three times and ``cmmpose calibrate offset`` once, as a user
would. It returns each estimate's error divided by the standard uncertainty
the CLI states for it: about 95 % should fall within 2.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from click.testing import CliRunner

from cmmpose import sim
from cmmpose.calibration import STANDARD_POSES, AlignmentLibrary
from cmmpose.cli import main
from cmmpose.machine import Machine, example_text
from cmmpose.sim.calibration_data import VERNIER_NOISE, plane_scan, reference_sphere_scans, vernier_points

MACHINE = "moving-bridge"
TEMPERATURE = 21.0  # C, between the 20 and 25 C maps
POSE_ERROR = sim.Alignment(0.03, -0.02, 0.04)  # deg: what the alignment must find
OFFSET_ERROR = sim.MountOffset(0.03, -0.02, 0.04)  # mm
VERNIER_POINTS = 3  # the thesis's procedure
PLANE_SCANNER = sim.Scanner(points_per_profile=64)  # fewer points: a quick trial
SPHERE_SCANNER = sim.Scanner(points_per_profile=256)
GROUPS = ("pose", "reading", "offset")


def _uvdef(path: Path, uv, scales) -> None:
    np.savetxt(path, np.column_stack([uv, scales]), delimiter=",", header="u,v,D,E,F", comments="", fmt="%.9f")


def _cli(args: list[str]) -> str:
    res = CliRunner().invoke(main, args, catch_exceptions=False)
    if res.exit_code != 0:
        raise RuntimeError(f"cmmpose {' '.join(args)} failed:\n{res.output}")
    return res.output


def cli_trial(seed: int, folder: Path) -> dict[str, np.ndarray]:
    """One calibration through the CLI; the standardised errors of its results.

    Parameters
    ----------
    seed : int
        Noise seed of the trial.
    folder : Path
        Where the trial's files go (an empty folder).

    Returns
    -------
    dict
        ``pose``: (3 poses x 3 angles), ``reading``: (3 x 3), ``offset``: (3,),
        each (estimate - truth) / stated standard uncertainty, 1; and
        ``true_offset`` (3,), mm.
    """
    folder.mkdir(parents=True, exist_ok=True)
    machine_file = folder / "machine.toml"
    machine_file.write_text(example_text(MACHINE), encoding="utf-8")
    machine = Machine.example(MACHINE)
    maps = machine.maps()
    offset = tuple(machine.offset)
    effects = [POSE_ERROR, OFFSET_ERROR]
    rng = np.random.default_rng(seed)
    library = folder / "alignments.json"
    truth, normals = {}, []
    for k, nominal in enumerate(STANDARD_POSES):
        common = dict(maps=maps, temperature=TEMPERATURE, effects=effects)
        v = vernier_points(nominal, offset, n=VERNIER_POINTS, seed=rng, **common)
        np.savetxt(folder / f"vernier{k}.csv", v.points, delimiter=",", header="x,y,z", comments="", fmt="%.9f")
        p = plane_scan(nominal, offset, scanner=PLANE_SCANNER, seed=rng, **common)
        _uvdef(folder / f"plane{k}.csv", p.uv, p.scales)
        normals.append([float(c) for c in p.plane.normal])
        x = reference_sphere_scans([nominal], offset, scanner=SPHERE_SCANNER, seed=int(rng.integers(1 << 30)),
                                   **common)[0]
        _uvdef(folder / f"sphere{k}.csv", x.data.uv, x.data.scales)
        truth[f"P{k}"] = x
        _cli(["calibrate", "alignment", "--machine", str(machine_file), "--temperature", str(TEMPERATURE),
              "--vernier", str(folder / f"vernier{k}.csv"), "--vernier-uncertainty", str(VERNIER_NOISE * 1e3),
              "--plane-scan", str(folder / f"plane{k}.csv"), "--plane-normal", ",".join(map(repr, normals[-1])),
              "--reference-scan", str(folder / f"sphere{k}.csv"), "--name", f"P{k}", "--library", str(library),
              "--json"])
    (folder / "trial.json").write_text(json.dumps({"plane_normals": normals}), encoding="utf-8")
    fit = json.loads(_cli(["calibrate", "offset", *truth, "--library", str(library), "--json"]))
    lib = AlignmentLibrary(library)
    pose_z, reading_z = [], []
    for name, x in truth.items():
        rec = lib.load(name)
        d_angle = (np.subtract(rec.pose, x.true_pose) + 180.0) % 360.0 - 180.0
        pose_z.append(d_angle / np.asarray(rec.pose_uncertainty))
        # The reading's error holds the pose's: judge it by the total uncertainty.
        reading_z.append((np.asarray(rec.reading) - x.true_reading) / rec.reference_reading().uncertainty)
    true_offset = next(iter(truth.values())).true_offset
    offset_z = (np.asarray(fit["offset"]) - true_offset) / np.asarray(fit["uncertainty"])
    return {"pose": np.array(pose_z), "reading": np.array(reading_z), "offset": offset_z,
            "true_offset": np.asarray(true_offset, dtype=float)}


def coverage(trials: list[dict[str, np.ndarray]], k: float = 2.0) -> dict[str, float]:
    """Fraction of standardised errors within ``k`` per group and over all, 1."""
    out = {g: float(np.mean(np.abs(np.concatenate([t[g].ravel() for t in trials])) <= k)) for g in GROUPS}
    every = np.concatenate([t[g].ravel() for t in trials for g in GROUPS])
    out["all"] = float(np.mean(np.abs(every) <= k))
    return out


__all__ = ["cli_trial", "coverage"]
