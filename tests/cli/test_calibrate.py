"""CLI: building a map from interferometer runs, and plotting maps."""

import json

import numpy as np
import pytest
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
    res = CliRunner().invoke(main, ["map", "plot", "thesis", "-o", str(tmp_path / "m.png")])
    assert res.exit_code == 0 and (tmp_path / "m.png").is_file()
    bad = tmp_path / "bad.csv"
    bad.write_text("not a run\n")
    res = CliRunner().invoke(main, ["calibrate", "map", str(bad), "--squareness", "0,0,0", "-o", str(tmp_path / "x.csv")])
    assert res.exit_code != 0 and "bad.csv" in res.output
    res = CliRunner().invoke(main, ["calibrate", "map", str(bad), "--squareness", "0,0", "-o", str(tmp_path / "x.csv")])
    assert res.exit_code != 0 and "three comma-separated numbers" in res.output


def _write_uvdef(path, uv, scales):
    np.savetxt(path, np.column_stack([uv, scales]), delimiter=",", header="u,v,D,E,F", comments="", fmt="%.9f")


def test_calibrate_alignment_and_offset_from_simulated_data(tmp_path):
    from cmmpose import sim
    from cmmpose.calibration import STANDARD_POSES

    maps = cmmpose.ErrorMap.zero()  # an error-free machine keeps the check about the solvers and the CLI
    maps = cmmpose.ErrorMapSet([maps.with_temperature(20.0)])
    lib = tmp_path / "alignments.json"
    refs = sim.reference_sphere_scans(STANDARD_POSES, maps=maps, seed=3)
    for k, (pose, ref) in enumerate(zip(STANDARD_POSES, refs)):
        vern = sim.vernier_points(pose, maps=maps, seed=k)
        np.savetxt(tmp_path / f"vernier{k}.csv", vern.points, delimiter=",", header="x,y,z", comments="")
        plane = sim.plane_scan(pose, maps=maps, seed=k)
        _write_uvdef(tmp_path / f"plane{k}.csv", plane.uv, plane.scales)
        _write_uvdef(tmp_path / f"ref{k}.csv", ref.data.uv, ref.data.scales)
        normal = ",".join(str(x) for x in plane.plane.normal) if hasattr(plane, "plane") else None
        args = ["calibrate", "alignment", "--vernier", str(tmp_path / f"vernier{k}.csv"), "--reference-scan",
                str(tmp_path / f"ref{k}.csv"), "--name", f"P{k}", "--library", str(lib), "--temperature", "20"]
        if normal:
            args += ["--plane-scan", str(tmp_path / f"plane{k}.csv"), "--plane-normal", normal]
        res = CliRunner().invoke(main, args, catch_exceptions=False)
        assert res.exit_code == 0, res.output
        rec = cmmpose.calibration.AlignmentLibrary(lib).load(f"P{k}")
        assert np.abs(np.subtract(rec.reading, ref.true_reading)).max() < 0.01  # mm: a fitted sphere centre
    res = CliRunner().invoke(main, ["calibrate", "offset", "P0", "P1", "P2", "--library", str(lib)], catch_exceptions=False)
    assert res.exit_code == 0, res.output
    assert "U1" in res.output and "chi-square" in res.output
    res = CliRunner().invoke(main, ["calibrate", "offset", "P0", "P1", "P2", "--library", str(lib), "--json"],
                             catch_exceptions=False)
    assert res.exit_code == 0, res.output
    fit = json.loads(res.output)
    assert set(fit["residuals"]) == {"P0", "P1", "P2"} and np.shape(fit["covariance"]) == (3, 3)
    assert 0 <= fit["p_value"] <= 1 and np.allclose(np.sqrt(np.diag(fit["covariance"])), fit["uncertainty"])
    res = CliRunner().invoke(main, ["calibrate", "offset", "P0", "P9", "--library", str(lib)])
    assert res.exit_code != 0 and "P9" in res.output and "never aligned" in res.output


def test_calibrate_alignment_with_the_maps_and_a_stated_vernier_uncertainty(tmp_path):
    """With the machine's maps the readings are compensated before alpha and
    beta are fitted: the squareness shear no longer biases alpha. Three
    vernier points (the thesis's procedure) need a stated uncertainty."""
    import json

    from cmmpose import sim
    from cmmpose.calibration import STANDARD_POSES

    maps = cmmpose.ErrorMapSet.thesis()
    pose = STANDARD_POSES[0]
    ref = sim.reference_sphere_scans([pose], maps=maps, temperature=20.0, seed=5)[0]
    _write_uvdef(tmp_path / "ref.csv", ref.data.uv, ref.data.scales)
    plane = sim.plane_scan(pose, maps=maps, temperature=20.0, seed=1)
    _write_uvdef(tmp_path / "plane.csv", plane.uv, plane.scales)
    normal = ",".join(str(x) for x in plane.plane.normal)
    alphas = {}
    for n in (5, 3):
        vern = sim.vernier_points(pose, n=n, maps=maps, temperature=20.0, seed=n)
        np.savetxt(tmp_path / f"v{n}.csv", vern.points, delimiter=",", header="x,y,z", comments="")
    base = ["calibrate", "alignment", "--reference-scan", str(tmp_path / "ref.csv"), "--library",
            str(tmp_path / "lib.json"), "--temperature", "20", "--json", "--plane-scan", str(tmp_path / "plane.csv"),
            "--plane-normal", normal]
    for label, extra in (("no map", []), ("maps", ["--maps", "thesis"])):
        res = CliRunner().invoke(main, base + ["--vernier", str(tmp_path / "v5.csv"), "--name", label, *extra],
                                 catch_exceptions=False)
        assert res.exit_code == 0, res.output
        alphas[label] = json.loads(res.output[res.output.index("{"):])["pose"][0]
    true_alpha = pose.alpha if hasattr(pose, "alpha") else pose[0]
    assert abs(alphas["maps"] - true_alpha) < abs(alphas["no map"] - true_alpha) / 3, alphas
    res = CliRunner().invoke(main, ["calibrate", "alignment", "--vernier", str(tmp_path / "v5.csv"), "--reference-scan",
                                    str(tmp_path / "ref.csv"), "--library", str(tmp_path / "lib.json"), "--name", "n"])
    assert res.exit_code != 0 and "--plane-scan is needed" in res.output
    res = CliRunner().invoke(main, base + ["--vernier", str(tmp_path / "v3.csv"), "--name", "three", "--maps", "thesis"])
    assert res.exit_code != 0 and "Traceback" not in res.output
    res = CliRunner().invoke(main, base + ["--vernier", str(tmp_path / "v3.csv"), "--name", "three", "--maps", "thesis",
                                           "--vernier-uncertainty", "5"], catch_exceptions=False)
    assert res.exit_code == 0, res.output
    record = json.loads(res.output)
    assert np.isfinite(record["pose_uncertainty"][:2]).all()
    res = CliRunner().invoke(main, base + ["--vernier", str(tmp_path / "v3.csv"), "--name", "x", "--maps", "thesis",
                                           "--vernier-uncertainty", "-1"])
    assert res.exit_code != 0 and "--vernier-uncertainty" in res.output


def test_simulate_alignment_writes_what_calibrate_alignment_reads(tmp_path):
    res = CliRunner().invoke(main, ["calibrate", "simulate-alignment", "--pose", "90,90,0", "--name", "A90B90", "--temperature", "21",
                                    "--effect", "alignment:alpha=0.03", "-o", str(tmp_path / "m")],
                             catch_exceptions=False)
    assert res.exit_code == 0, res.output
    truth = json.loads((tmp_path / "m" / "A90B90-truth.json").read_text())
    assert truth["true_pose"] == pytest.approx([90.03, 90.0, 0.0])
    assert "cmmpose calibrate alignment --maps thesis --temperature 21" in res.output
    normal = ",".join(repr(c) for c in truth["plane_normal"])
    res = CliRunner().invoke(main, ["calibrate", "alignment", "--maps", "thesis", "--temperature", "21", "--vernier",
                                    str(tmp_path / "m" / "A90B90-vernier.csv"), "--vernier-uncertainty", "9",
                                    "--plane-scan", str(tmp_path / "m" / "A90B90-plane.csv"), "--plane-normal", normal,
                                    "--reference-scan", str(tmp_path / "m" / "A90B90-sphere.csv"), "--name", "A90B90",
                                    "--library", str(tmp_path / "lib.json"), "--json"], catch_exceptions=False)
    assert res.exit_code == 0, res.output
    rec = json.loads(res.output)
    assert abs(rec["pose"][0] - 90.03) < 3 * rec["pose_uncertainty"][0]
    assert np.shape(rec["pose_covariance"]) == (3, 3) and np.shape(rec["pose_jacobian"]) == (3, 3)
    # Three vernier points without a stated uncertainty, and a plane normal the sweep moved along: each refused
    # by name, the library not written.
    base = ["calibrate", "alignment", "--maps", "thesis", "--temperature", "21", "--vernier",
            str(tmp_path / "m" / "A90B90-vernier.csv"), "--plane-scan", str(tmp_path / "m" / "A90B90-plane.csv"),
            "--reference-scan", str(tmp_path / "m" / "A90B90-sphere.csv"), "--name", "A90B90",
            "--library", str(tmp_path / "refused.json")]
    for args, message in ((["--plane-normal", normal], "--vernier-uncertainty"),
                          (["--plane-normal", "1,0,1", "--vernier-uncertainty", "9"], "from the given normal")):
        res = CliRunner().invoke(main, [*base, *args])
        assert res.exit_code != 0 and message in res.output and "Traceback" not in res.output, res.output
        assert "A90B90" in res.output or "vernier.csv" in res.output
        assert not (tmp_path / "refused.json").exists()
    for args, message in ((["--pose", "90,90"], "--pose"), (["--pose", "90,90,0", "--effect", "nonsense:x=1"],
                                                            "nonsense"),
                          (["--pose", "90,90,0", "--vernier-points", "2"], "--vernier-points")):
        res = CliRunner().invoke(main, ["calibrate", "simulate-alignment", "--name", "X", "-o", str(tmp_path / "bad"), *args])
        assert res.exit_code != 0 and message in res.output and "Traceback" not in res.output, res.output
