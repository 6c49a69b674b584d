"""docs/appendix-c.md: every figure of the write-up, recomputed from the
bundled Appendix C by the sphere-fit-level diagnosis, and the statements it
makes about them."""

import numpy as np
import pytest

from cmmpose.diagnosis.spheres import NOMINAL_RADIUS_MM, appendix_c_sphere_fits, diagnose_sphere_fits
from cmmpose.errors import InputError
from repo import REPO

DOC = (REPO / "docs" / "appendix-c.md").read_text(encoding="utf-8")


def diagnosis(state):
    f = appendix_c_sphere_fits(state)
    return diagnose_sphere_fits(f["centres"], f["radii"], nominal_radius=NOMINAL_RADIUS_MM, points=f["points"],
                                fit_rms=f["fit_rms"])


@pytest.mark.parametrize("state, rms, radius, excess, u, sd", [
    ("uncompensated", "73.2", "38.1630", "38.0", "2.3", "14.4"),
    ("compensated", "12.8", "38.1661", "41.1", "2.2", "14.1"),
])
def test_the_figures_of_the_write_up(state, rms, radius, excess, u, sd):
    d = diagnosis(state)
    assert f"{d.rms_um:.1f}" == rms and f"{d.radius_mean:.4f}" == radius
    assert f"{d.radius_excess_um:.1f}" == excess and f"{d.radius_excess_u_um:.1f}" == u
    assert f"{d.radius_sd_um:.1f}" == sd
    row = f"| {state} | {radius} | {excess} +- {u} | {sd} |"
    assert row in DOC, row
    assert f"| {state} | {rms} |" in DOC
    assert len(d.patterns) == 17 and "17 patterns" in DOC


def test_the_statements_of_the_write_up():
    unc, comp = diagnosis("uncompensated"), diagnosis("compensated")
    # uncompensated: the xy squareness, significant
    lead = [p for p in unc.significant if p.level == "length"]
    assert [p.quantity for p in lead] == ["dx*dy"] and f"{lead[0].amplitude_um:.0f} um" in DOC
    assert f"R^2 {lead[0].r2:.2f}" in DOC and f"p {lead[0].p_value:.1e}" in DOC
    # compensated: no length pattern significant; the strongest is the one the doc names
    lengths = [p for p in comp.patterns if p.level == "length"]
    assert not any(p.significant for p in lengths)
    strongest = min(lengths, key=lambda p: p.p_value)
    assert strongest.quantity == "dz*dx" and f"p {strongest.p_value:.2f}" in DOC
    # the radius: a significant constant excess, following nothing else
    radius = [p for p in comp.patterns if p.level == "sphere"]
    assert [p.quantity for p in radius if p.significant] == ["(all scans)"]
    assert f"p {next(p for p in radius if p.quantity == '(all scans)').p_value:.0e}".replace("e-", "e-") in DOC
    # the tolerance and the ppm figure
    assert comp.radius_excess_um > 3 * 12.5
    assert round(comp.radius_excess_um / NOMINAL_RADIUS_MM * 1e3, -2) == 1100


def test_sphere_fit_diagnosis_bad_inputs():
    f = appendix_c_sphere_fits("compensated")
    with pytest.raises(InputError, match="centres"):
        diagnose_sphere_fits(f["centres"][:, 0], f["radii"])
    with pytest.raises(InputError, match="radii"):
        diagnose_sphere_fits(f["centres"], f["radii"][:, :1])
    with pytest.raises(InputError, match="at least 3"):
        diagnose_sphere_fits(f["centres"][:2], f["radii"][:2])
    bad = f["radii"].copy()
    bad[0, 0] = np.nan
    with pytest.raises(InputError, match="finite"):
        diagnose_sphere_fits(f["centres"], bad)
    with pytest.raises(InputError, match="points"):
        diagnose_sphere_fits(f["centres"], f["radii"], points=np.ones(3))
    with pytest.raises(InputError, match="state"):
        appendix_c_sphere_fits("raw")


def test_the_command_line_and_a_users_file(tmp_path):
    import json

    from click.testing import CliRunner

    from cmmpose.cli import main

    res = CliRunner().invoke(main, ["diagnose-fits", "appendix-c", "--json"], catch_exceptions=False)
    assert res.exit_code == 0, res.output
    assert json.loads(res.output)["rms_um"] == pytest.approx(diagnosis("compensated").rms_um)
    f = appendix_c_sphere_fits("uncompensated")
    rows = ["position,ball,x_mm,y_mm,z_mm,radius_mm"]
    for p in range(20):
        for b in range(2):
            rows.append(",".join(map(str, [p + 1, b + 1, *f["centres"][p, b], f["radii"][p, b]])))
    (tmp_path / "fits.csv").write_text("\n".join(rows) + "\n")
    res = CliRunner().invoke(main, ["diagnose-fits", str(tmp_path / "fits.csv"), "--nominal-radius", "38.125",
                                    "--json"], catch_exceptions=False)
    assert res.exit_code == 0, res.output
    assert json.loads(res.output)["rms_um"] == pytest.approx(diagnosis("uncompensated").rms_um)
    (tmp_path / "bad.csv").write_text("\n".join(rows[:5] + ["3,1,a,b,c,d"]) + "\n")
    res = CliRunner().invoke(main, ["diagnose-fits", str(tmp_path / "bad.csv")])
    assert res.exit_code != 0 and "bad.csv:6" in res.output and "Traceback" not in res.output, res.output
    (tmp_path / "lonely.csv").write_text("\n".join(rows[:4]) + "\n")
    res = CliRunner().invoke(main, ["diagnose-fits", str(tmp_path / "lonely.csv")])
    assert res.exit_code != 0 and "lack ball" in res.output
