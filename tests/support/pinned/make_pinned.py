"""Compute today's numerical outputs and write them to ``tests/support/pinned/``
(``outputs.npz``, ``diagnosis.json``), so that a refactor of the effects and
kernel code can prove that nothing moved (``tests/compensation/test_pinned_outputs.py``
recomputes every case with the functions below and compares).

Run from the repository root::

    PYTHONPATH=python python tests/support/pinned/make_pinned.py

Cases (keys of ``outputs.npz`` are ``<case>__<name>``):

a. ``demo``: the run ``cmmpose demo`` simulates (thesis maps, 22.5 C, seed 0,
   default B89 layout, per-scan reproducibility ``sim.REALISTIC_JITTER``) and its evaluation at 22.5 C: every 97th point's
   u, v, D, E, F, t; per-position lengths uncompensated and compensated; rms.
b. ``scan``: ``data/examples/sphere_scan.csv`` compensated as the CI line
   ``cmmpose compensate ... --maps thesis --pose 90,90,0 --offset 1.001,264.505,129.575``
   (per-point temperatures from its T column): all rows.
c. ``model``: ``cmmpose.Model`` on a small simulated run that has
   every input the library effects need (axis-temperature offsets, a changing
   granite gradient, bidirectional sweeps, reference sphere at three poses):
   every 50th compensated row for the thesis model and for each library
   effect of kind kernel/pose/length alone at its prior; plus the figures
   (lengths at 20 C) of each model, which is where the length effect acts.
d. ``simfx``: simulator truth of a small crossed-ballbar run with every
   simulator effect switched on at a typical value: every 97th point's
   u, v, D, E, F, t and true X, Y, Z; ball centres and true lengths.
e. ``diagnosis.json``: ``cmmpose.diagnose`` of a small run with a hidden
   squareness offset (yz = 25 arc-second): the effects added, fitted values,
   rms accuracy error of every step.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

import cmmpose
from cmmpose import sim
from cmmpose.calibration import STANDARD_POSES
from cmmpose.model import LIBRARY, Model
from cmmpose.evaluation.observables import model_figures
from cmmpose.formats.pointfiles import read_points
from cmmpose.sim import effects as E
from cmmpose.sim.scanner import Scanner

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[2]  # the repository (this file is tests/support/pinned/make_pinned.py)
OUTPUTS = HERE / "outputs.npz"
DIAGNOSIS = HERE / "diagnosis.json"

#: A coarse scanner (256 points per profile) keeps the small runs small.
COARSE = Scanner(points_per_profile=256)

DEMO_TEMPERATURE = 22.5  # cmmpose demo defaults
DEMO_SEED = 0
SCAN_FILE = ROOT / "data" / "examples" / "sphere_scan.csv"
SCAN_POSE = (90.0, 90.0, 0.0)
SCAN_OFFSET = (1.001, 264.505, 129.575)

#: Simulator effects that give the model-effect run the inputs the library needs.
MODEL_RUN_EFFECTS = (E.AxisTemperature(x=1.0, y=-0.5, z=0.3),
                     E.GraniteGradient(kelvin=-1.0, kelvin_per_hour=2.0, xy=0.0, yz=10.0, zx=10.0))

#: Every simulator effect at a typical value (case d).
ALL_SIM_EFFECTS = (
    E.Squareness(xy=8.0, yz=-5.0, zx=6.0),
    E.Scale(x=5.0, y=-3.0, z=4.0),
    E.Roll(x=3.0, y=-2.0, z=4.0),
    E.AxisTemperature(x=0.8, y=-0.4, z=0.5),
    E.GraniteGradient(kelvin=1.0, kelvin_per_hour=1.5, xy=2.0, yz=10.0, zx=8.0),
    E.Latency(seconds=0.005),
    E.ScannerScale(lateral=5e-4, depth=-4e-4),
    E.Incidence(per_degree=2e-4, per_degree_mm=2e-5),
    E.Alignment(alpha=0.02, beta=-0.015, gamma=0.01),
    E.MountOffset(u1=0.03, v1=-0.02, w1=0.04),
    E.ArtefactExpansion(ppm_per_kelvin=11.5),
)


def _points_subset(run, step, prefix):
    p = run.points
    return {f"{prefix}__{k}": np.asarray(p[k][::step], dtype=float) for k in ("u", "v", "D", "E", "F", "t")}


def case_demo() -> dict[str, np.ndarray]:
    """(a) What ``cmmpose demo`` simulates and evaluates."""
    maps = cmmpose.ErrorMapSet.thesis()
    run, _ = sim.simulate_ballbar_run(maps, DEMO_TEMPERATURE, seed=DEMO_SEED, jitter=sim.REALISTIC_JITTER)
    ev = cmmpose.evaluate(run, maps, DEMO_TEMPERATURE)
    out = _points_subset(run, 97, "demo")
    out["demo__n_points"] = np.array(run.n_points, dtype=float)
    out["demo__positions"] = np.asarray(ev.compensated.positions, dtype=float)
    out["demo__lengths_uncompensated"] = np.asarray(ev.uncompensated.lengths, dtype=float)
    out["demo__lengths_compensated"] = np.asarray(ev.compensated.lengths, dtype=float)
    out["demo__rms"] = np.array([ev.uncompensated.rms_accuracy_error, ev.compensated.rms_accuracy_error,
                                 ev.uncompensated.b89, ev.compensated.b89])
    return out


def case_example_scan() -> dict[str, np.ndarray]:
    """(b) The example scan as the CI's ``cmmpose compensate`` line compensates it."""
    uv, scales, temps = read_points(SCAN_FILE)
    xyz = cmmpose.compensate(uv, scales, cmmpose.ErrorMapSet.thesis(), SCAN_POSE, SCAN_OFFSET, temps)
    return {"scan__xyz": np.asarray(xyz, dtype=float)}


#: The effects that existed when these outputs were pinned (before the
#: effects redesign). Effects added since are checked by their own tests.
PINNED_EFFECTS = ("squareness", "scale", "roll", "axis-temperature", "granite-gradient", "latency", "scanner-scale",
                  "incidence", "alignment", "mount-offset", "artefact-expansion")


def model_effect_specs():
    """The pinned library effects of kind kernel, pose or length, in library order."""
    return [s for s in LIBRARY.values() if s.kind in ("kernel", "pose", "length") and s.name in PINNED_EFFECTS]


def model_run():
    """Small run with every input the library effects need."""
    run, _ = sim.simulate_ballbar_run(cmmpose.ErrorMapSet.thesis(), 22.5, MODEL_RUN_EFFECTS, layout="crossed",
                                      scanner=COARSE, bidirectional=True, reference_poses=STANDARD_POSES,
                                      calibrated=("length",), seed=5)
    return run


def case_model_effects() -> dict[str, np.ndarray]:
    """(c) Model compensation: thesis model, then each library effect alone at its prior."""
    maps = cmmpose.ErrorMapSet.thesis()
    run = model_run()
    out = {}
    models = {"thesis": Model(maps)}
    for spec in model_effect_specs():
        models[spec.name] = Model(maps).with_values(spec.name, spec.prior)
    for name, m in models.items():
        out[f"model__{name}__xyz"] = np.asarray(m.compensate(run)[::50], dtype=float)
        out[f"model__{name}__lengths_20c"] = np.asarray(model_figures(m, run).lengths_20c, dtype=float)
    return out


def case_sim_effects() -> dict[str, np.ndarray]:
    """(d) Simulator truth with every simulator effect on."""
    assert {e.name for e in ALL_SIM_EFFECTS} == set(PINNED_EFFECTS) <= set(sim.available_effects()), \
        "a pinned simulator effect is missing"
    run, (truth, _) = sim.simulate_ballbar_run(cmmpose.ErrorMapSet.thesis(), 22.5, ALL_SIM_EFFECTS, layout="crossed",
                                               scanner=COARSE, bidirectional=True, seed=7)
    out = _points_subset(run, 97, "simfx")
    out["simfx__n_points"] = np.array(run.n_points, dtype=float)
    out["simfx__true_xyz"] = np.asarray(truth["true_xyz"][::97], dtype=float)
    out["simfx__ball_centres"] = np.asarray(truth["ball_centres"], dtype=float)
    out["simfx__true_lengths"] = np.asarray(truth["true_lengths"], dtype=float)
    return out


def case_diagnosis() -> dict:
    """(e) One diagnosis: a hidden squareness offset, found and fitted."""
    run, _ = sim.simulate_ballbar_run(cmmpose.ErrorMapSet.thesis(), 22.5, [E.Squareness(yz=25.0)],
                                      scanner=COARSE, jitter=0.0015, seed=11)
    d = cmmpose.diagnose(run, patterns=False, max_effects=2)
    final = d.steps[-1].model
    return {
        "hidden": {"squareness": {"yz": 25.0}},
        "added": list(d.added),
        "steps": [s.label for s in d.steps],
        "effects": [{"name": s.name, "params": list(s.params), "values": [float(x) for x in v]}
                    for s, v in final.effects],
        "rms_accuracy_error_mm": [float(s.figures.rms_accuracy_error) for s in d.steps],
    }


ARRAY_CASES = (case_demo, case_example_scan, case_model_effects, case_sim_effects)


def main() -> None:
    arrays = {}
    for case in ARRAY_CASES:
        arrays.update(case())
    np.savez_compressed(OUTPUTS, **arrays)
    DIAGNOSIS.write_text(json.dumps(case_diagnosis(), indent=1) + "\n")
    print(f"wrote {OUTPUTS} ({OUTPUTS.stat().st_size / 1e3:.0f} kB, {len(arrays)} arrays) and {DIAGNOSIS}")


if __name__ == "__main__":
    main()
