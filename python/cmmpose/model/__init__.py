"""The machine model: what compensates a scanner's points. Measured error
maps (:class:`~cmmpose.ErrorMap`, :class:`~cmmpose.ErrorMapSet`) and a
found :class:`Model` (maps plus physical effects with their values,
uncertainties and the domain they were fitted on) answer the same calls
(:class:`MachineModel`), which compensation and evaluation use; the
diagnosis produces models and is never imported by what applies them.

- :mod:`.spec`: an effect as a model term (:class:`EffectSpec`, the library,
  :class:`UserEffect`); :mod:`.names`: any effect name to its spec;
- :mod:`.mapshape`: a correction of one map component by a smooth shape;
- :mod:`.inputs`: what a model reads from a run (:class:`RunInputs`);
  :mod:`.point_inputs`: from a point file;
- :mod:`.alternatives`: aliased choices, checked where a model is applied;
- :mod:`.model`: :class:`Model`, saved and loaded as JSON.
"""

from .._lazy import lazy_attributes
from .protocol import MachineModel

# The model's modules load on first use (they need the run format and the sphere fits): what applies maps
# alone (``cmmpose compensate`` with maps) imports only the protocol.
__getattr__, __dir__ = lazy_attributes(__name__, {
    "Alternative": ("alternatives", "Alternative"),
    "RunInputs": ("inputs", "RunInputs"),
    "Model": ("model", "Model"),
    **{name: ("spec", name) for name in ("LIBRARY", "EffectSpec", "UserEffect", "library", "load_user_effect",
                                         "load_user_effects")},
}, globals())

__all__ = ["Alternative", "EffectSpec", "LIBRARY", "MachineModel", "Model", "RunInputs", "UserEffect", "library",
           "load_user_effect", "load_user_effects"]
