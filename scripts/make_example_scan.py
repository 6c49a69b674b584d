"""Generate data/examples/sphere_scan.csv: a small synthetic scan of a 76.25 mm
ball (thesis Appendix A) with the digitizer W along X (pose 90, 90, 0, thesis
mount offset), sweeping along X; 8 um Gaussian noise on u and v (thesis Table
17); a slowly rising machine temperature in column T. Geometry only: no
machine errors are added (the simulator of a later issue does that).

Run: python scripts/make_example_scan.py
"""

from pathlib import Path

import numpy as np

RADIUS = 76.25 / 2
CENTRE = np.array([400.0, 275.0, -350.0])  # mm, machine frame
U1, V1, W1 = 1.001, 264.505, 129.575
# The laser origin L is mid depth of view (140 mm in front of the sensor); put it at
# the top of the ball so the cap lies at v in [-RADIUS, 0].

rng = np.random.default_rng(20021114)
profiles, per_profile = 61, 64
slices = np.linspace(-30.0, 30.0, profiles)  # x - centre_x of each scan plane
F = CENTRE[2] + RADIUS + V1
E = CENTRE[1]
rows = []
for k, s in enumerate(slices):
    r = np.sqrt(RADIUS**2 - s**2)
    phi = np.radians(np.linspace(25.0, 155.0, per_profile))  # the upper cap faces the sensor (+v = +Z)
    y = CENTRE[1] + r * np.cos(phi)
    z = CENTRE[2] + r * np.sin(phi)
    D = CENTRE[0] + s + W1  # pose (90, 90, 0): X_H = (D - W1, E + u - U1, F + v - V1)
    u = y - E + U1 + rng.normal(0, 0.008, per_profile)
    v = z - F + V1 + rng.normal(0, 0.008, per_profile)
    T = 21.8 + 0.4 * k / (profiles - 1)
    rows.append(np.column_stack([u, v, np.full(per_profile, D), np.full(per_profile, E), np.full(per_profile, F), np.full(per_profile, T)]))
data = np.vstack(rows)
out = Path(__file__).resolve().parents[1] / "python" / "cmmpose" / "data" / "examples" / "sphere_scan.csv"
np.savetxt(out, data, delimiter=",", fmt=["%.4f", "%.4f", "%.4f", "%.4f", "%.4f", "%.3f"], header="u,v,D,E,F,T", comments="")
print(f"wrote {len(data)} rows to {out}")
