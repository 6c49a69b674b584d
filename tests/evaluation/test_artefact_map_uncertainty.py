"""An artefact evaluation carries the maps' stated uncertainty per component as a move common to every ball
(issue 36, item 3): each pair's length u grows by exactly the change of that length when the maps are moved by the
component's u (evaluated independently, with the maps' tables edited by hand), and a constant offset of a carriage,
which moves every ball alike, adds nothing to a length."""

import numpy as np
import pytest

from cmmpose import ErrorMap, ErrorMapSet, artefacts
from cmmpose.evaluation.artefact import evaluate_artefact
from cmmpose.point_uncertainty import MapUncertainty
from cmmpose.sim.artefact_runs import simulate_artefact_run

MAPS = ErrorMapSet.thesis()
PPM = 10.0


@pytest.fixture(scope="module")
def run():
    run, _ = simulate_artefact_run(artefacts.load_artefact("koba-0320"), ["xy@z=-525"], MAPS, 21.0, seed=3)
    return run


def lengths(ev):
    return {(d.ball_a, d.ball_b): d for d in ev.compensated.placements[0].lengths}


def stretched_x(maps, ppm):
    """The maps with X's dx grown by ``ppm`` from each table's start (um = ppm x mm x 1e-3), by hand."""
    out = []
    for m in maps.maps:
        x = m.table("X").copy()
        x[:, 1] += ppm * 1e-3 * (x[:, 0] - maps.maps[0].table("X")[0, 0])
        out.append(ErrorMap(x, m.table("Y"), m.table("Z"), m.squareness, m.temperature))
    return ErrorMapSet(out)


def test_a_stated_component_adds_the_length_change_it_makes_and_a_constant_offset_adds_nothing(run):
    plain = evaluate_artefact(run, MAPS, 21.0)
    moved = evaluate_artefact(run, stretched_x(MAPS, PPM), 21.0)
    stated = MAPS.with_uncertainty(MapUncertainty(positioning_ppm=(PPM, 0.0, 0.0),
                                                  position_um=((5.0, 0, 0), (0, 0, 0), (0, 0, 0))))
    with_u = evaluate_artefact(run, stated, 21.0, map_uncertainty=True)
    assert any("maps' stated uncertainty (2 components" in n for n in with_u.provenance["notes"])
    for key, d in lengths(with_u).items():
        base = lengths(plain)[key]
        change = lengths(moved)[key].error - base.error  # what the stated u moves this length by, mm
        added = np.sqrt(max(d.u ** 2 - base.u ** 2, 0.0))
        # The compensation is linear in a table's values, the sphere fits are not: the evaluation moves the maps by
        # one unit and scales, the reference by the whole u. The fits' second-order term is the stretch itself
        # (10 ppm = 1e-5) relative; besides, a stretched cap's fit moves its centre sideways by up to ~0.1 um at
        # 10 ppm (scanned patch, not a whole sphere), not quite linearly: 1e-4 relative and 5e-6 mm bound both.
        assert added == pytest.approx(abs(change), rel=1e-4, abs=5e-6), key
    # Without the flag, or with maps stating nothing, the figures are the plain ones.
    again = evaluate_artefact(run, stated, 21.0)
    assert [d.u for d in lengths(again).values()] == [d.u for d in lengths(plain).values()]
    none = evaluate_artefact(run, MAPS.with_uncertainty(None), 21.0, map_uncertainty=True)
    assert any("the maps state no uncertainty" in n for n in none.provenance["notes"])
