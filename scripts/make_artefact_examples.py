"""Write the bundled example artefact files (python/cmmpose/data/artefacts/).

The geometries are the nominal ones (ball count and pitch, data/SOURCES.md);
the "calibrated" centres and radii are SYNTHETIC: the nominal values plus a
seeded deviation of a few tenths of a micrometre, with plausible standard
uncertainties. No real certificate is copied. Run from the repository root:

    python scripts/make_artefact_examples.py
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

OUT = Path(__file__).resolve().parents[1] / "python" / "cmmpose" / "data" / "artefacts"

HEADER = """# cmmpose artefact file (docs/artefacts.md): a calibration certificate.
# Units: mm (centres, radius), um (standard uncertainties), ppm/K, degrees C.
# Ball centres are in the artefact's own frame: a plate's balls in its xy
# plane on its +z side, a bar's and a step gauge's along +x.
"""


def grid(n: int, pitch: float) -> np.ndarray:
    return np.array([[i * pitch, j * pitch, 0.0] for j in range(n) for i in range(n)])


def row(n: int, pitch: float) -> np.ndarray:
    return np.array([[i * pitch, 0.0, 0.0] for i in range(n)])


def write(name, kind, title, note, centres, u_um, radius, u_radius_um, alpha, seed, dev_um=(0.3, 0.3, 0.5)):
    rng = np.random.default_rng(seed)
    cal = centres + rng.normal(0.0, 1.0, centres.shape) * np.array(dev_um) * 1e-3
    cal -= cal[0] - centres[0]  # ball 1 stays at its nominal place (the frame's origin)
    r_cal = radius + float(rng.normal(0.0, 0.3e-3))
    lines = [HEADER, f"# {note}", "", f'kind = "{kind}"', f'name = "{title}"',
             'certificate = "synthetic: nominal geometry plus seeded deviations '
             f'(scripts/make_artefact_examples.py, seed {seed}); not a real calibration"',
             "reference_temperature_C = 20.0", f"expansion_ppm_per_K = {alpha}", "",
             "balls = ["]
    for k, (c, u) in enumerate(zip(cal, u_um), start=1):
        xyz = ", ".join(f"{x:.4f}" for x in c)
        uu = ", ".join(f"{x:g}" for x in u)
        lines.append(f"  {{ id = {k}, xyz_mm = [{xyz}], u_um = [{uu}] }},")
    lines += ["]", "", "[radius]", f"nominal_mm = {radius}", f"calibrated_mm = {r_cal:.4f}", f"u_um = {u_radius_um}"]
    (OUT / f"{name}.toml").write_text("\n".join(lines) + "\n", encoding="utf-8")


def main() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    for name, n, pitch, seed in (("koba-0620", 5, 133.0, 620), ("koba-0420", 5, 83.0, 420), ("koba-0320", 5, 60.0, 320)):
        c = grid(n, pitch)
        write(name, "ball-plate", f"KOBA {name[-4:]} ball plate, {n} x {n} balls at {pitch:g} mm",
              f"Nominal KOBA {name[-4:]} geometry: {n} x {n} balls at {pitch:g} mm; 22 mm balls and steel assumed.",
              c, [(0.4, 0.4, 0.6)] * len(c), 11.0, 0.2, 11.5, seed)
    c = grid(8, 50.0)
    write("apmp-plate", "ball-plate", "APMP comparison ball plate, 8 x 8 balls at 50 mm",
          "Nominal APMP comparison plate geometry: 8 x 8 balls at 50 mm; 20 mm balls and steel assumed.",
          c, [(0.3, 0.3, 0.5)] * len(c), 10.0, 0.2, 11.5, 64)
    c = row(31, 20.0)
    write("step-gauge-31x20", "step-gauge", "Ball step gauge, 31 balls at 20 mm",
          "Nominal step gauge: 31 balls at 20 mm (600 mm); 10 mm balls and steel assumed.",
          c, [(round(0.2 + 0.5 * x / 1000, 3), 0.5, 0.5) for x in c[:, 0]], 5.0, 0.2, 11.5, 31, (0.2, 0.5, 0.5))
    L = 404.2357  # cmmpose.layouts.B89_LENGTH_MM: the thesis's mean compensated length at 20 C (Appendix C)
    write("thesis-ballbar", "ballbar", "The thesis's optical ballbar (76.25 mm balls)",
          "Thesis ballbar: 76.25 mm balls (section 6.1.1), length 404.2357 mm (Appendix C mean), steel 12 ppm/K.",
          np.array([[0.0, 0.0, 0.0], [L, 0.0, 0.0]]), [(0.5, 0.5, 0.5)] * 2, 38.125, 0.5, 12.0, 404, (0.5, 0.0, 0.0))
    write("reference-sphere", "sphere", "Reference sphere, 25.4 mm (the alignment's, thesis Figure 4-7)",
          "Reference sphere: 25.4 mm ball, as cmmpose.sim.reference_sphere().",
          np.zeros((1, 3)), [(0.2, 0.2, 0.2)], 12.7, 0.1, 11.5, 1)


if __name__ == "__main__":
    main()
