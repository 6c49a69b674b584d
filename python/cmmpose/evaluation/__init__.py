"""Evaluation of measurement runs and its uncertainty (docs/uncertainty.md).

- ``ballbar``: the ballbar evaluation of thesis chapter 6 (:func:`evaluate`).
- ``artefact``: ball plates, step gauges and spheres at placements
  (:func:`evaluate_artefact`, docs/artefacts.md).
- ``metrics``: the figures of merit (rms accuracy error, B89 value).
- ``uncertainty``: the GUM toolkit (budgets, inputs, coverage); ``point_monte_carlo``:
  the Monte Carlo of compensated points (each point's uncertainty checked);
  ``ballbar_uncertainty``: every ballbar figure's budget.
- ``files``: the files an evaluation writes; ``plots``: its figures and those of
  fits and maps (extra ``plot``).

Names load their module on first use: ``import cmmpose`` needs only the
metrics, not the run format and pyarrow behind the evaluations.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from .._lazy import lazy_attributes

_MODULES = ("ballbar", "artefact", "metrics", "uncertainty", "ballbar_uncertainty", "point_monte_carlo", "files", "plots")

__getattr__, __dir__ = lazy_attributes(__name__, {
    **{name: (name, None) for name in _MODULES},
    "evaluate": ("ballbar", "evaluate"),
    "Evaluation": ("ballbar", "Evaluation"),
    "BallbarResult": ("ballbar", "BallbarResult"),
    "SphereResult": ("ballbar", "SphereResult"),
    "evaluate_artefact": ("artefact", "evaluate_artefact"),
    "ArtefactEvaluation": ("artefact", "ArtefactEvaluation"),
    "evaluation_uncertainty": ("ballbar_uncertainty", "evaluation_uncertainty"),
    "write_evaluation_files": ("files", "write_evaluation_files"),
}, globals())

if TYPE_CHECKING:
    from .artefact import ArtefactEvaluation, evaluate_artefact
    from .ballbar import BallbarResult, Evaluation, SphereResult, evaluate
    from .ballbar_uncertainty import evaluation_uncertainty
    from .files import write_evaluation_files

del annotations, lazy_attributes, TYPE_CHECKING
__all__ = [*_MODULES, "evaluate", "Evaluation", "BallbarResult", "SphereResult", "evaluate_artefact",
           "ArtefactEvaluation", "evaluation_uncertainty", "write_evaluation_files"]
