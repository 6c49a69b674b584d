"""An error of one direction that varies with two axes' positions together,
as a term of a machine model: outside every rigid-body map component, each
of which follows one axis.

Two low-order shapes, in the normalised positions ``t = (2 q - lo - hi) /
(hi - lo)`` of the two axes A and B over the travel the training runs used
(readings clipped to it: the correction is held beyond, never extrapolated):

- ``twist``: ``c t_A t_B`` (one parameter, um at the corners of the
  travel): a twisted table, a warped guide, a bridge whose two legs sit at
  different heights;
- ``sag``: ``s_A P2(t_A) t_B + s_B t_A P2(t_B)`` (two parameters, um;
  ``P2(t) = (3 t^2 - 1) / 2``): a bow along one axis whose depth grows
  along the other, the sag of a beam with the carriage on it.

Names read ``cross:<direction>(<A><B>):<shape>[loA,hiA][loB,hiB]``, e.g.
``cross:z(XY):twist[170,730][40,515]``: a model file records the term by
its name and parameters, so ``Model.load`` rebuilds it. The diagnosis offers
them as candidates where a run moves along both axes
(:mod:`cmmpose.diagnosis.mapfamily`: they share the map corrections'
centre-level sensitivities). Units: positions mm, parameters um.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from .spec import EffectSpec

__all__ = ["CROSS_PRIOR_UM", "CrossAxisCorrection", "is_cross", "make_cross", "parse_cross"]

#: Typical size of a cross-axis coefficient at the corners of the travel, um.
CROSS_PRIOR_UM = 3.0
_NAME = re.compile(r"^cross:([xyz])\(([XYZ])([XYZ])\):(twist|sag)\[(-?[0-9.]+),(-?[0-9.]+)\]"
                   r"\[(-?[0-9.]+),(-?[0-9.]+)\]$")
_WORDS = {"twist": "a twisted table or warped guide", "sag": "a bow that deepens along the other axis (a sag)"}


@dataclass(frozen=True)
class CrossAxisCorrection(EffectSpec):
    """A ``python`` effect: one direction's error as a low-order function of
    two axes' positions (module docstring).

    Attributes (beyond :class:`EffectSpec`)
    ---------------------------------------
    direction : int
        0, 1, 2: the error along x, y or z.
    axes : tuple of int
        The two axes (0 = X, 1 = Y, 2 = Z) whose readings it follows.
    shape : {'twist', 'sag'}
    travel : tuple of 2 (lo, hi)
        The two axes' travel it spans, mm.
    """

    direction: int = 2
    axes: tuple = (0, 1)
    shape: str = "twist"
    travel: tuple = ((0.0, 1.0), (0.0, 1.0))
    family: str = field(default="cross", compare=False)

    def basis(self, q: np.ndarray) -> np.ndarray:
        """(N, k) shape functions at readings ``q`` (N, 3 mm), unitless."""
        t = []
        for a, (lo, hi) in zip(self.axes, self.travel):
            x = np.clip(np.asarray(q, float)[:, a], lo, hi)
            t.append((2 * x - lo - hi) / (hi - lo))
        ta, tb = t
        if self.shape == "twist":
            return (ta * tb)[:, None]
        return np.column_stack([(1.5 * ta * ta - 0.5) * tb, ta * (1.5 * tb * tb - 0.5)])

    def correction(self, inputs: dict, values) -> np.ndarray:
        """(N, 3) mm added to the compensated points (the UserEffect interface)."""
        q = np.column_stack([inputs["D"], inputs["E"], inputs["F"]])
        out = np.zeros((len(q), 3))
        out[:, self.direction] = self.basis(q) @ np.asarray(values, float) * 1e-3
        return out

    def describe(self, values) -> str:
        v = np.asarray(values, float)
        a, b = ("XYZ"[i] for i in self.axes)
        what = f"{'xyz'[self.direction]} error varying with {a} and {b} together ({_WORDS[self.shape]})"
        return f"{what}: " + ", ".join(f"{p}={x:+.3g} um" for p, x in zip(self.params, v))


def is_cross(spec) -> bool:
    return getattr(spec, "family", None) == "cross"


def make_cross(direction: int, axes, shape: str, travel) -> CrossAxisCorrection:
    """The cross-axis correction of ``direction`` (0-2) over ``axes`` (two of
    0-2) with ``shape`` ('twist' or 'sag'), normalised over ``travel`` ((lo,
    hi) mm of each of the two axes)."""
    axes = tuple(int(a) for a in axes)
    if direction not in (0, 1, 2) or len(axes) != 2 or axes[0] == axes[1] or any(a not in (0, 1, 2) for a in axes):
        raise InputError(f"cross-axis correction: direction {direction!r} and two different axes expected, got {axes}")
    if shape not in _WORDS:
        raise InputError(f"cross-axis correction: shape {shape!r} is not 'twist' or 'sag'")
    travel = tuple((float(lo), float(hi)) for lo, hi in travel)
    if len(travel) != 2 or any(not hi > lo for lo, hi in travel):
        raise InputError(f"cross-axis correction: each axis's travel must be a range lo < hi, got {travel}")
    a, b = ("XYZ"[i] for i in axes)
    d = "xyz"[direction]
    params = ("c_um",) if shape == "twist" else (f"bow_{a.lower()}_um", f"bow_{b.lower()}_um")
    span = "".join(f"[{lo:.6g},{hi:.6g}]" for lo, hi in travel)
    physics = (f"the {d} error varies with {a} and {b} together: {_WORDS[shape]}, outside every one-axis map "
               f"component")
    reveal = (f"placements spread over {a} and {b} together (the corners of the {a}{b} plane), at more than one "
              f"height")
    return CrossAxisCorrection(name=f"cross:{d}({a}{b}):{shape}{span}", params=params, units=("um",) * len(params),
                               prior=(CROSS_PRIOR_UM,) * len(params), kind="python", key="cross", physics=physics,
                               reveal=reveal, direction=direction, axes=axes, shape=shape, travel=travel)


def parse_cross(name: str) -> CrossAxisCorrection:
    """The spec of a cross-axis correction's name ('cross:z(XY):twist[170,730][40,515]')."""
    m = _NAME.match(name)
    if not m:
        raise InputError(f"effect {name!r}: not a cross-axis correction name (cross:<d>(<A><B>):twist|sag"
                         f"[loA,hiA][loB,hiB], e.g. 'cross:z(XY):twist[170,730][40,515]')")
    d, a, b, shape, *span = m.groups()
    v = [float(x) for x in span]
    return make_cross("xyz".index(d), ("XYZ".index(a), "XYZ".index(b)), shape, ((v[0], v[1]), (v[2], v[3])))
