"""ISO 230-2 positioning evaluation: a hand-worked example, an independent
implementation (pandas groupby), interferometer runs, edge cases, the CLI."""

import json

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

import cmmpose
from cmmpose.calibration.interferometer import process_run, write_run
from cmmpose.cli import main
from cmmpose.sim.interferometer import simulate_interferometer_run
from cmmpose.standards.iso230_2 import (
    AXIS_KEYS,
    PositioningData,
    PositioningError,
    evaluate_iso230_2,
    load_positioning,
    read_positioning_csv,
)

# Four targets, three cycles, deviations in um (target_mm: up cycles, down cycles).
HAND = {
    0.0: ((1, 2, 3), (-3, -2, -1)),
    100.0: ((4, 4, 4), (2, 3, 4)),
    200.0: ((1, 2, 3), (1, 2, 3)),
    300.0: ((0, 0, 0), (0, 0, 0)),
}


def hand_data(source="hand") -> PositioningData:
    t, d, c, x = [], [], [], []
    for target, (up, down) in HAND.items():
        for direction, values in ((1, up), (-1, down)):
            for cycle, v in enumerate(values, start=1):
                t.append(target), d.append(direction), c.append(cycle), x.append(float(v))
    return PositioningData(np.array(t), np.array(d), np.array(c), np.array(x), source)


def write_csv(path, data: PositioningData) -> None:
    lines = ["# a positioning test", "target_mm,direction,cycle,deviation_um"]
    lines += [f"{t},{d:+d},{c},{x}" for t, d, c, x in zip(data.target_mm, data.direction, data.cycle, data.deviation_um)]
    path.write_text("\n".join(lines) + "\n")


def test_hand_worked_example():
    r = evaluate_iso230_2(hand_data())
    # Means over the 3 cycles (not over the 4 targets):
    #   up: 2, 4, 2, 0     down: -2, 3, 2, 0
    # s (n - 1 = 2): up 1, 0, 1, 0; down 1, 1, 1, 0
    # B_i = up - down: 4, 1, 0, 0; bidirectional means: 0, 3.5, 2, 0
    assert [t.mean_up for t in r.targets] == pytest.approx([2, 4, 2, 0])
    assert [t.mean_down for t in r.targets] == pytest.approx([-2, 3, 2, 0])
    assert [t.s_up for t in r.targets] == pytest.approx([1, 0, 1, 0])
    assert [t.s_down for t in r.targets] == pytest.approx([1, 1, 1, 0])
    assert [t.reversal for t in r.targets] == pytest.approx([4, 1, 0, 0])
    assert [t.mean for t in r.targets] == pytest.approx([0, 3.5, 2, 0])
    # R_up_i = 4 s: 4, 0, 4, 0; R_down_i: 4, 4, 4, 0
    # R_i = max(2 s_up + 2 s_down + |B_i|, R_up_i, R_down_i):
    #   target 0: max(2 + 2 + 4 = 8, 4, 4) = 8 (the bidirectional term decides)
    #   target 100: max(0 + 2 + 1 = 3, 0, 4) = 4; target 200: max(4, 4, 4) = 4; target 300: 0
    assert [t.R_up for t in r.targets] == pytest.approx([4, 0, 4, 0])
    assert [t.R_down for t in r.targets] == pytest.approx([4, 4, 4, 0])
    assert [t.R for t in r.targets] == pytest.approx([8, 4, 4, 0])
    # Axis:
    #   B = max |B_i| = 4; B_mean = (4 + 1 + 0 + 0) / 4 = 1.25
    #   E_up = 4 - 0 = 4; E_down = 3 - (-2) = 5;
    #   E = max(all means) - min(all means) = 4 - (-2) = 6 (more than either direction alone)
    #   M = 3.5 - 0 = 3.5
    #   R_up = 4, R_down = 4, R = 8
    #   A_up: max(x + 2s) = max(4, 4, 4, 0) = 4, min(x - 2s) = min(0, 4, 0, 0) = 0 -> 4
    #   A_down: max(0, 5, 4, 0) = 5, min(-4, 1, 0, 0) = -4 -> 9
    #   A = max(4, 5) - min(0, -4) = 9
    expected = {"A": 9, "A_up": 4, "A_down": 9, "B": 4, "B_mean": 1.25, "E": 6, "E_up": 4, "E_down": 5,
                "M": 3.5, "R": 8, "R_up": 4, "R_down": 4}
    assert r.axis_values == pytest.approx(expected)
    assert r.cycles == 3
    assert any("3 cycles" in n for n in r.notes)


def test_inputs_are_not_modified_and_row_order_does_not_matter():
    d = hand_data()
    before = [a.copy() for a in (d.target_mm, d.direction, d.cycle, d.deviation_um)]
    perm = np.random.default_rng(3).permutation(len(d.target_mm))
    shuffled = PositioningData(d.target_mm[perm], d.direction[perm], d.cycle[perm], d.deviation_um[perm])
    assert evaluate_iso230_2(shuffled).axis_values == pytest.approx(evaluate_iso230_2(d).axis_values)
    for a, b in zip(before, (d.target_mm, d.direction, d.cycle, d.deviation_um)):
        np.testing.assert_array_equal(a, b)


def independent(df: pd.DataFrame) -> dict:
    """The ISO 230-2 axis figures written out again with pandas."""
    g = df.groupby(["target_mm", "direction"])["deviation_um"]
    stats = pd.DataFrame({"mean": g.mean(), "s": g.std(ddof=1)}).unstack("direction")
    up_m, dn_m = stats[("mean", 1)], stats[("mean", -1)]
    up_s, dn_s = stats[("s", 1)], stats[("s", -1)]
    rev = up_m - dn_m
    r_i = pd.concat([2 * up_s + 2 * dn_s + rev.abs(), 4 * up_s, 4 * dn_s], axis=1).max(axis=1)
    both_m = pd.concat([up_m, dn_m])
    return {
        "A": max((up_m + 2 * up_s).max(), (dn_m + 2 * dn_s).max()) - min((up_m - 2 * up_s).min(), (dn_m - 2 * dn_s).min()),
        "A_up": (up_m + 2 * up_s).max() - (up_m - 2 * up_s).min(),
        "A_down": (dn_m + 2 * dn_s).max() - (dn_m - 2 * dn_s).min(),
        "B": rev.abs().max(), "B_mean": rev.mean(),
        "E": both_m.max() - both_m.min(), "E_up": up_m.max() - up_m.min(), "E_down": dn_m.max() - dn_m.min(),
        "M": ((up_m + dn_m) / 2).max() - ((up_m + dn_m) / 2).min(),
        "R": r_i.max(), "R_up": (4 * up_s).max(), "R_down": (4 * dn_s).max(),
    }


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_against_an_independent_implementation(seed):
    rng = np.random.default_rng(seed)
    targets = np.sort(rng.uniform(0, 900, 11))
    rows = []
    for t in targets:
        slope, rev = 0.05 * t, rng.normal(0, 2)
        for d in (1, -1):
            for c in range(1, 6):
                rows.append((t, d, c, slope + d * rev / 2 + rng.normal(0, 1.5)))
    df = pd.DataFrame(rows, columns=["target_mm", "direction", "cycle", "deviation_um"])
    data = PositioningData(*(df[c].to_numpy() for c in df.columns))
    r = evaluate_iso230_2(data)
    assert r.axis_values == pytest.approx(independent(df), rel=1e-12, abs=1e-12)
    assert set(r.axis_values) == set(AXIS_KEYS)


def test_csv_round_trip_and_cli_json(tmp_path):
    path = tmp_path / "pos.csv"
    write_csv(path, hand_data())
    d = read_positioning_csv(path)
    assert d.rows[0] == 3  # after a comment and the header
    out = CliRunner().invoke(main, ["standards", "iso230-2", str(path), "--json", "--plot", str(tmp_path / "p.png")])
    assert out.exit_code == 0, out.output
    doc = json.loads(out.stdout)
    assert {k: doc[k] for k in AXIS_KEYS} == pytest.approx(evaluate_iso230_2(hand_data()).axis_values)
    assert doc["unit"] == "um" and "ISO 230-2:2014" in doc["standard"]
    assert (tmp_path / "p.png").stat().st_size > 0
    table = CliRunner().invoke(main, ["standards", "iso230-2", str(path)])
    assert table.exit_code == 0 and "ISO 230-2" in table.stdout
    rep = CliRunner().invoke(main, ["standards", "iso230-2", str(path), "--report", str(tmp_path / "rep")])
    assert rep.exit_code == 0, rep.output
    md = (tmp_path / "rep" / "iso230-2.md").read_text()
    assert "| A | A_up |" in md and "| 9.00 | 4.00 | 9.00 |" in md  # the hand-worked A, A_up, A_down
    assert json.loads((tmp_path / "rep" / "iso230-2.json").read_text())["E"] == 6
    assert (tmp_path / "rep" / "iso230-2.png").is_file()


def test_interferometer_run_agrees_with_process_run(tmp_path):
    truth = cmmpose.ErrorMapSet.thesis().maps[0]
    run, _ = simulate_interferometer_run(truth, "X", "dx", repeats=5, seed=4)
    path = tmp_path / "x.run"
    write_run(run, path)
    data, u, note = load_positioning(path)
    assert data.source == str(path) and u > 0 and "refractive index" in note
    r = evaluate_iso230_2(data, test_uncertainty_um=u)
    p = process_run(run)
    home = int(np.searchsorted(p.positions_mm, p.home_mm))
    zero = r.targets[home].mean
    np.testing.assert_allclose([t.target_mm for t in r.targets], p.positions_mm)
    np.testing.assert_allclose([t.mean_up - zero for t in r.targets], p.forward, atol=1e-9)
    np.testing.assert_allclose([t.mean_down - zero for t in r.targets], p.backward, atol=1e-9)
    np.testing.assert_allclose([t.reversal for t in r.targets], p.reversal, atol=1e-9)
    # The simulated reversal (0.8 um) and noise (0.1 um) show in B and R_up.
    assert 0.4 < r.B_mean < 1.2
    assert 0.1 < r.R_up < 1.5
    out = CliRunner().invoke(main, ["standards", "iso230-2", str(path), "--json"])
    assert out.exit_code == 0, out.output
    assert json.loads(out.stdout)["E"] == pytest.approx(r.E, abs=1e-4)


def test_non_linear_run_is_refused(tmp_path):
    truth = cmmpose.ErrorMapSet.thesis().maps[0]
    run, _ = simulate_interferometer_run(truth, "X", "ez", repeats=2, seed=1)
    path = tmp_path / "ez.run"
    write_run(run, path)
    with pytest.raises(cmmpose.Error, match="linear optics"):
        load_positioning(path)


def _rows(keep):
    d = hand_data("pos.csv")
    return PositioningData(d.target_mm[keep], d.direction[keep], d.cycle[keep], d.deviation_um[keep], "pos.csv")


def test_one_cycle_is_a_clear_error():
    d = hand_data("pos.csv")
    with pytest.raises(PositioningError, match=r"pos.csv: target 0 mm is approached once in direction \+1"):
        evaluate_iso230_2(_rows(d.cycle == 1))


def test_one_target_is_a_clear_error():
    d = hand_data("pos.csv")
    with pytest.raises(PositioningError, match=r"pos.csv: .*at least 2 target positions, found 1 \(100 mm\)"):
        evaluate_iso230_2(_rows(d.target_mm == 100))


def test_missing_direction_names_the_file_and_target(tmp_path):
    d = hand_data()
    keep = ~((d.target_mm == 200) & (d.direction == -1))
    path = tmp_path / "pos.csv"
    write_csv(path, PositioningData(d.target_mm[keep], d.direction[keep], d.cycle[keep], d.deviation_um[keep]))
    with pytest.raises(PositioningError, match=r"pos.csv: target 200 mm has no approach in direction -1"):
        evaluate_iso230_2(read_positioning_csv(path))
    out = CliRunner().invoke(main, ["standards", "iso230-2", str(path)])
    assert out.exit_code != 0 and "target 200 mm" in out.output


def test_repeated_cycle_and_bad_direction_name_the_line(tmp_path):
    path = tmp_path / "pos.csv"
    d = hand_data()
    cyc = d.cycle.copy()
    cyc[1] = 1  # the second row repeats cycle 1 of target 0, up
    write_csv(path, PositioningData(d.target_mm, d.direction, cyc, d.deviation_um))
    with pytest.raises(PositioningError, match=r"pos.csv: line 4: target 0 mm, direction \+1, cycle 1 is given twice"):
        evaluate_iso230_2(read_positioning_csv(path))
    direction = d.direction.copy()
    direction[2] = 0
    write_csv(path, PositioningData(d.target_mm, direction, d.cycle, d.deviation_um))
    with pytest.raises(PositioningError, match=r"pos.csv: line 5: direction must be \+1 or -1"):
        evaluate_iso230_2(read_positioning_csv(path))


def test_csv_errors_name_file_and_line(tmp_path):
    path = tmp_path / "pos.csv"
    path.write_text("target_mm,direction,deviation_um\n0,1,2\n")
    with pytest.raises(PositioningError, match=r"pos.csv:1: missing column\(s\) cycle"):
        read_positioning_csv(path)
    path.write_text("target_mm,direction,cycle,deviation_um\n0,1,1,abc\n")
    with pytest.raises(PositioningError, match=r"pos.csv:2: deviation_um = 'abc' is not a number"):
        read_positioning_csv(path)
    assert issubclass(PositioningError, cmmpose.Error)
