"""CLI: building a map from interferometer runs, and plotting maps."""

import numpy as np
from click.testing import CliRunner

import cmmpose
from cmmpose.calibration.interferometer import write_run
from cmmpose.cli import main
from cmmpose.sim.interferometer import simulate_interferometer_runs


def test_calibrate_map_from_simulated_runs(tmp_path):
    truth = cmmpose.ErrorMapSet.thesis().maps[0]
    runs, _ = simulate_interferometer_runs(truth, include_roll=False, seed=2)
    files = []
    for k, r in enumerate(runs):
        files.append(tmp_path / f"run{k}.csv")
        write_run(r, files[-1])
    out = tmp_path / "map.csv"
    res = CliRunner().invoke(main, ["calibrate", "map", *map(str, files), "--squareness", "-173,-19,21", "-o", str(out),
                                    "--compare", "thesis@20", "--plot", str(tmp_path / "diff.png")], catch_exceptions=False)
    assert res.exit_code == 0, res.output
    built = cmmpose.ErrorMap.read(out)
    assert built.squareness == (-173.0, -19.0, 21.0)
    for c in "XYZ":
        np.testing.assert_allclose(built.table(c)[:, 1:4], truth.table(c)[:, 1:4], atol=0.6)  # um, simulated noise
    assert (tmp_path / "diff.png").stat().st_size > 10_000
    assert "note:" in res.output  # the unmeasured rolls are reported


def test_plot_map_and_bad_inputs(tmp_path):
    res = CliRunner().invoke(main, ["plot-map", "thesis", "-o", str(tmp_path / "m.png")])
    assert res.exit_code == 0 and (tmp_path / "m.png").is_file()
    bad = tmp_path / "bad.csv"
    bad.write_text("not a run\n")
    res = CliRunner().invoke(main, ["calibrate", "map", str(bad), "--squareness", "0,0,0", "-o", str(tmp_path / "x.csv")])
    assert res.exit_code != 0 and "bad.csv" in res.output
    res = CliRunner().invoke(main, ["calibrate", "map", str(bad), "--squareness", "0,0", "-o", str(tmp_path / "x.csv")])
    assert res.exit_code != 0 and "three comma-separated numbers" in res.output
