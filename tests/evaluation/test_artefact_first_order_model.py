"""An independent first-order model of ball-plate deviations (issue 24).

Written here from the published small-angle equations, not from the
simulator: with only a squareness error S (thesis eqs. 11-12, Table 7
signs, docs/conventions.md) a machine errs at scale reading (D, E, F) by

    e = (-E S_xy - F S_zx, -F S_yz, 0)

and the uncompensated coordinates are the true ones minus e. Each profile
of a sweep moves by -e at its own readings, an affine shear of the ball whose
fitted centre moves by -e at the readings where the scan plane passes the
centre: along the sweep axis (the scanner's w) the centre's coordinate plus
that of E313 . l1 (docs/conventions.md: X_H = S + E313 ((u, v, 0) - l1)),
the other two readings fixed during the sweep. The best-fit rigid transform of a placement
then takes away the part of those shifts that a small translation t and
rotation w explain, t + w x p_i: what is left is each ball's deviation. The
simulator (exact rigid-body truth machine, ray-traced scanner, sphere fits)
and the evaluation (Kabsch fit) must agree with this to well under 0.01 um.
The same holds on every machine configuration (the stackings of
docs/conventions.md) for constant angular map errors, which act through
each configuration's own arms: another stacking's arms miss by micrometres.
"""

from __future__ import annotations

import numpy as np
import pytest

from cmmpose import _core, artefacts
from cmmpose.evaluation.artefact import evaluate_artefact
from cmmpose.errormap import ErrorMap, data_path
from cmmpose.machine import load_machine
from cmmpose.sim import Scanner, Squareness
from cmmpose.sim.artefact_runs import simulate_artefact_run

ARCSEC = np.pi / 648000


def first_order_deviations(centres: np.ndarray, shifts: np.ndarray) -> np.ndarray:
    """Residuals of ``shifts`` (n, 3) after the least-squares small rigid
    motion t + w x p at ``centres`` (n, 3)."""
    p = centres - centres.mean(axis=0)
    rows = []
    for x, y, z in p:  # w x p = (wy z - wz y, wz x - wx z, wx y - wy x)
        rows += [[1, 0, 0, 0, z, -y], [0, 1, 0, -z, 0, x], [0, 0, 1, y, -x, 0]]
    a = np.array(rows, float)
    b = shifts.ravel()
    solution, *_ = np.linalg.lstsq(a, b, rcond=None)
    return (b - a @ solution).reshape(-1, 3)


def squareness_shift(d, e, f, xy, yz, zx):
    """-e(S) of eqs. 11-12 at readings D, E, F (mm), squareness in arc-seconds."""
    return np.array([e * xy * ARCSEC + f * zx * ARCSEC, f * yz * ARCSEC, 0.0])


CASES = [  # (artefact, placements, squareness xy, yz, zx in arc-seconds)
    ("koba-0620", ["xy@z=-525", "xy@z=-525,rot=30"], (5.0, 0.0, 0.0)),
    ("koba-0420", ["yz@x=150"], (0.0, 4.0, 0.0)),
    ("koba-0420", ["xz@y=560", "yz@x=150"], (0.0, 0.0, 3.0)),
    ("step-gauge-31x20", ["xy@z=-525,rot=20"], (6.0, 0.0, 0.0)),
]


@pytest.mark.parametrize("name, where, squareness", CASES)
def test_first_order_model_agrees_with_the_simulated_plate(name, where, squareness):
    artefact = artefacts.load_artefact(name)
    effect = Squareness(*squareness)
    run, truth = simulate_artefact_run(artefact, where, ErrorMap.zero(temperature=20.0), 20.0, [effect],
                                       scanner=Scanner(noise=0.0), seed=0)
    ev = evaluate_artefact(run, None, 20.0)
    sid = run.points["scan_id"]
    largest = 0.0
    for p in ev.uncompensated.placements:
        scans = [b.scans[0] for b in p.balls]
        centres = truth[0]["ball_centres"][scans]
        readings = []
        for s, c in zip(scans, centres):  # the readings where the scan plane passes the ball's centre
            row = int(np.flatnonzero(run.scans["scan_id"] == s)[0])
            pose, offset = run.pose(int(run.scans["pose_id"][row]))
            r = np.array([run.points[k][sid == s][0] for k in "DEF"])
            a = "XYZ".index(run.scans["sweep_axis"][row])
            r[a] = c[a] + (_core.euler313(*pose) @ np.asarray(offset))[a]
            readings.append(r)
        shifts = np.array([squareness_shift(*r, *squareness) for r in readings])
        model = first_order_deviations(centres, shifts)
        simulated = np.array([b.deviation for b in p.balls])
        worst = float(np.max(np.abs(simulated - model)))
        print(f"{name} {p.label}: model vs simulation {worst * 1e6:.3f} nm")
        assert worst < 2e-6  # mm: 0.002 um
        largest = max(largest, float(np.max(np.abs(model))))
        # a wrong model (the shear on the wrong axis) misses by micrometres
        wrong = first_order_deviations(centres, shifts[:, [1, 0, 2]])
        assert np.max(np.abs(simulated - wrong)) > 0.5e-3
    assert largest > 1e-3  # the error shows: deviations of more than 1 um


def test_expansion_to_20c_is_undone():
    """At 23 C the plate really expands by its own coefficient; evaluated
    at 23 C its deviations at 20 C are the certificate's (zero)."""
    artefact = artefacts.load_artefact("koba-0620")
    run, _ = simulate_artefact_run(artefact, ["xy@z=-525"], ErrorMap.zero(temperature=23.0), 23.0,
                                   scanner=Scanner(noise=0.0))
    good = evaluate_artefact(run, None, 23.0).uncompensated
    assert good.rms < 2e-6
    # evaluated as if at 20 C: 3 K x 11.5 ppm/K over 532 mm is a 18 um length error
    wrong = evaluate_artefact(run, None, 20.0).uncompensated
    assert wrong.largest_length_error.error == pytest.approx(np.hypot(532, 532) * 3 * 11.5e-6, rel=1e-3)


def test_a_plate_in_the_xz_plane_does_not_see_s_yz():
    """S_yz moves Y by F S_yz: over a plate in the XZ plane that is a tilt
    about X, which the rigid fit takes away; in the YZ plane it is a shear."""
    artefact = artefacts.load_artefact("koba-0420")
    run, _ = simulate_artefact_run(artefact, ["xz@y=560", "yz@x=150"], ErrorMap.zero(temperature=20.0), 20.0,
                                   [Squareness(0.0, 4.0, 0.0)], scanner=Scanner(noise=0.0))
    xz, yz = evaluate_artefact(run, None, 20.0).uncompensated.placements
    assert xz.rms < 2e-6 and yz.rms > 0.5e-3


# -- every machine configuration ----------------------------------------------------------
#
# docs/conventions.md, "Machine configurations": the position error for any
# stacking is e = sum_A eps(A) x arm(A) (+ the straightnesses and the shear,
# zero here), arm(A) the travel of the carriages the carriage A carries on the
# probe side, and the probe turns by the sum of every carriage's angles. With
# constant angles, a ball's fitted centre moves by
#
#     -(sum_A eps(A) x arm(A)(S) + eps_total x (C - S))
#
# at the readings S where the scan plane passes its centre C (the same
# argument as for the squareness above: each profile moves by an amount
# affine along the sweep, and the rotation about C itself does not move C).

#: Constant angular errors of each carriage (eps_x, eps_y, eps_z), arc-seconds.
ANGLES = {"X": (3.0, -6.0, 9.0), "Y": (6.0, 4.5, -9.0), "Z": (-3.0, 6.0, 3.0)}
#: arm(A) at readings (D, E, F), by stacking (the table of docs/conventions.md).
ARMS = {
    "X-Y-Z": lambda d, e, f: {"X": (0, e, f), "Y": (0, 0, f), "Z": (0, 0, 0)},
    "Y-X-Z": lambda d, e, f: {"X": (0, 0, f), "Y": (d, 0, f), "Z": (0, 0, 0)},
    "X-Z-Y": lambda d, e, f: {"X": (0, e, f), "Y": (0, 0, 0), "Z": (0, e, 0)},
}
STACKING = {"thesis": "X-Y-Z", "moving-bridge": "Y-X-Z", "gantry": "Y-X-Z", "fixed-bridge": "Y-X-Z",
            "horizontal-arm": "X-Z-Y"}


def angular_shift(readings, centre, arms) -> np.ndarray:
    eps = {k: np.array(v) * ARCSEC for k, v in ANGLES.items()}
    arm = arms(*readings)
    e = sum(np.cross(eps[k], np.array(arm[k], float)) for k in "XYZ")
    return -(e + np.cross(sum(eps.values()), centre - readings))


@pytest.mark.parametrize("configuration", list(STACKING))
def test_first_order_model_agrees_on_every_configuration(configuration):
    """A KOBA 0420 in the three planes of each bundled machine whose map holds
    only constant angles: the model with that configuration's arms agrees
    with the simulator to well under 0.01 um; another stacking's arms miss by
    micrometres."""
    machine = load_machine(str(data_path("machines", f"{configuration}.toml")))
    tables = [np.array([[lo, 0, 0, 0, *ANGLES[k]], [hi, 0, 0, 0, *ANGLES[k]]])
              for (lo, hi), k in zip(machine.travel, "XYZ")]
    maps = ErrorMap(*tables, (0.0, 0.0, 0.0), 20.0).with_kinematics(machine.kinematics)
    run, truth = simulate_artefact_run(artefacts.load_artefact("koba-0420"), ["xy", "xz", "yz"], maps, 20.0,
                                       machine=machine, scanner=Scanner(noise=0.0), seed=0)
    ev = evaluate_artefact(run, None, 20.0)
    sid = run.points["scan_id"]
    miss = {name: 0.0 for name in ARMS}
    for p in ev.uncompensated.placements:
        scans = [b.scans[0] for b in p.balls]
        centres = truth[0]["ball_centres"][scans]
        readings = []
        for s, c in zip(scans, centres):
            row = int(np.flatnonzero(run.scans["scan_id"] == s)[0])
            pose, offset = run.pose(int(run.scans["pose_id"][row]))
            r = np.array([run.points[k][sid == s][0] for k in "DEF"])
            a = "XYZ".index(run.scans["sweep_axis"][row])
            r[a] = c[a] + (_core.euler313(*pose) @ np.asarray(offset))[a]
            readings.append(r)
        simulated = np.array([b.deviation for b in p.balls])
        for name, arms in ARMS.items():
            shifts = np.array([angular_shift(r, c, arms) for r, c in zip(readings, centres)])
            miss[name] = max(miss[name], float(np.max(np.abs(simulated - first_order_deviations(centres, shifts)))))
    print(configuration, {k: f"{v * 1e6:.2f} nm" for k, v in miss.items()})
    right = STACKING[configuration]
    assert miss[right] < 2e-6  # mm: 0.002 um
    assert all(v > 1e-3 for k, v in miss.items() if k != right)  # another stacking: more than 1 um off
