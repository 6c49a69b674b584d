"""Digitizer alignment calibration (thesis chapter 4 and section 5.3).

Solvers, each returning its result with a standard uncertainty:

- :func:`alpha_beta_from_vernier`: alpha, beta from optical-vernier points on
  the scan plane (eqs. 5-6, quadrant-safe form of docs/conventions.md, Frames);
- :func:`gamma_from_plane_scan`: gamma from a flat plane scanned while the
  machine moves (section 4.3: "scanning a planar surface while moving the CMM,
  and fitting the data");
- :func:`calibrated_pose`: the two combined into one pose with its 3 x 3
  covariance (these three in :mod:`.orientation`);
- :func:`reference_centre_reading`: D0, E0, F0, the scale reading at which the
  laser origin sits at the reference-sphere centre (section 4.4, eq. 14;
  :mod:`.reference`);
- :func:`mount_offset`: U1, V1, W1 from two or more alignments by generalised
  least squares, with residuals and a chi-square consistency check;
- :func:`mount_offset_closed_form`: eqs. 19-20 and the corrected eq. 21 for the
  thesis's three standard alignments, with the GUM budget of eqs. 22-24
  (these two in :mod:`.offset`).

What the solvers share (the standard poses, E313, the checks of their inputs)
is in :mod:`.common`.

Units: mm for lengths, degrees for angles (radians only inside), degrees C
for temperatures; covariances in the square of those units. Conventions,
methods and their uncertainties: docs/calibration.md ("Alignment").
"""

from ...errors import CalibrationError
from .common import STANDARD_POSES
from .offset import ClosedFormOffset, MountOffsetFit, mount_offset, mount_offset_closed_form
from .orientation import (CalibratedPose, GammaAlignment, VernierAlignment, alpha_beta_from_vernier, calibrated_pose,
                          gamma_from_plane_scan)
from .reference import ReferenceReading, reference_centre_reading

__all__ = [
    "CalibrationError",
    "STANDARD_POSES",
    "VernierAlignment",
    "alpha_beta_from_vernier",
    "GammaAlignment",
    "gamma_from_plane_scan",
    "CalibratedPose",
    "calibrated_pose",
    "ReferenceReading",
    "reference_centre_reading",
    "MountOffsetFit",
    "mount_offset",
    "ClosedFormOffset",
    "mount_offset_closed_form",
]
