"""Diagnosis: compare the model with measurements, see where it fails, find
the missing physical effect, add it and watch the error fall (issue 6). It
produces models (:class:`cmmpose.model.Model`: error maps plus physical
effects, ``cmmpose.model.LIBRARY`` or a :class:`cmmpose.model.UserEffect`);
what applies them never imports it.

- :func:`diagnose`: ranks the candidate effects, adds the significant ones
  one by one and keeps the history;
- :func:`find_patterns`: residuals at every level against what could
  explain them;
- :func:`verify`: does a found model hold on a run it never saw
  (:mod:`cmmpose.diagnosis.cv`, which also cross-validates every choice);
- :class:`AmbiguitySet`: explanations the data cannot choose between,
  side by side, with where over the travel they disagree
  (:mod:`cmmpose.diagnosis.ambiguity`; ``Diagnosis.ambiguity``), and what
  tells them apart (:func:`cmmpose.diagnosis.plan.plan` with ``rivals``);
- :func:`jacobian`: the named sensitivities of a run's observables to every
  candidate parameter, map corrections (:mod:`cmmpose.diagnosis.mapfamily`)
  included.
"""

from .ambiguity import AmbiguitySet
from .cv import verify
from .diagnose import diagnose
from .identify import Candidate, Problem, fit_effect, fit_model, rank_candidates
from .result import Diagnosis, Step
from .sensitivity import jacobian
from .spheres import SphereFitDiagnosis, diagnose_sphere_fits

__all__ = ["diagnose", "Diagnosis", "Step", "Candidate", "Problem", "fit_effect", "fit_model", "rank_candidates",
           "SphereFitDiagnosis", "diagnose_sphere_fits", "verify", "jacobian", "AmbiguitySet"]
