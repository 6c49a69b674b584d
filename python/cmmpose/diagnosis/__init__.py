"""Diagnosis: compare the model with measurements, see where it fails, find
the missing physical effect, add it and watch the error fall (issue 6).

- :class:`Model`: error maps plus physical effects (``LIBRARY``, or a
  :class:`UserEffect`), evaluated in the Rust kernel;
- :func:`diagnose`: ranks the candidate effects, adds the significant ones
  one by one and keeps the history;
- :func:`find_patterns`: residuals at every level against what could
  explain them;
- :func:`verify`: does a found model hold on a run it never saw
  (:mod:`cmmpose.diagnosis.cv`, which also cross-validates every choice);
- :func:`jacobian`: the named sensitivities of a run's observables to every
  candidate parameter, map corrections (:mod:`cmmpose.diagnosis.mapfamily`)
  included.
"""

from .cv import verify
from .diagnose import Diagnosis, Step, diagnose
from .effects import LIBRARY, EffectSpec, UserEffect, library
from .identify import Candidate, Problem, fit_model, rank_candidates
from .inputs import RunInputs
from .model import Model
from .observables import ModelFigures, ObservationLayout
from .sensitivity import jacobian
from .spheres import SphereFitDiagnosis, diagnose_sphere_fits

__all__ = ["diagnose", "Diagnosis", "Step", "LIBRARY", "EffectSpec", "UserEffect", "library", "Candidate", "Problem", "fit_model",
           "rank_candidates", "RunInputs", "Model", "ModelFigures", "ObservationLayout", "SphereFitDiagnosis",
           "diagnose_sphere_fits", "verify", "jacobian"]
