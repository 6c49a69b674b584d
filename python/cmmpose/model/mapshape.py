"""A correction of one map component by a smooth function of its axis's
position, as a term of a machine model (the shapes, their names and how a
model applies them); the search for such corrections in a run is the
diagnosis's (:mod:`cmmpose.diagnosis.mapfamily`, whose docstring gives the
shapes and the statistics).

Names read ``map:<component>:<shape>[lo,hi]``, e.g. ``map:dx(X):sine170.2[-120,780]``
or ``map:ez(X):poly[0,900]`` (:func:`parse`); an angle on a machine
configured other than the thesis's X-Y-Z bridge carries the configuration
(``map:ez(X):poly[0,900]@moving-bridge``), since its arms depend on it. A
model file records the correction by its name and parameters (um or
arc-seconds), so ``Model.load`` rebuilds it with no code from the user,
and :func:`corrected_maps` writes it into the maps themselves.

Units: positions mm, translational corrections um, angles and squareness
arc-seconds (parameters), priors in the same units.
"""

from __future__ import annotations

import functools
import math
import re
from dataclasses import dataclass, field

import numpy as np

from ..errormap import ErrorMap, ErrorMapSet
from ..errors import InputError
from ..machine import configurations
from .spec import EffectSpec

__all__ = ["ARCSEC", "COMPONENTS", "PERIOD_MIN", "PRIOR_AS", "PRIOR_UM", "ROTATIONAL", "SQUARENESS", "TRANSLATIONAL",
           "MapCorrection", "arms", "corrected_maps", "is_map", "kind_of", "make", "parse", "reading_axis"]

#: Translational components: name -> (axis index whose reading it follows,
#: direction index it moves the point along).
TRANSLATIONAL = {f"d{d}({a})": ("XYZ".index(a), "xyz".index(d)) for a in "XYZ" for d in "xyz"}
#: Rotational components: name -> (axis index whose reading it follows,
#: index of the machine axis it turns about).
ROTATIONAL = {f"e{d}({a})": ("XYZ".index(a), "xyz".index(d)) for a in "XYZ" for d in "xyz"}
#: The 18 per-axis map components a correction can act on.
COMPONENTS = {**TRANSLATIONAL, **ROTATIONAL}
#: Squarenesses: name -> (index of the reading the shear grows with, direction
#: it moves the point along): e_x holds -E S_xy - F S_zx, e_y holds -F S_yz.
SQUARENESS = {"sq(xy)": (1, 0), "sq(yz)": (2, 1), "sq(zx)": (2, 0)}
#: Shortest period searched, mm.
PERIOD_MIN = 10.0
#: Typical size of a translational correction's coefficient, um (a map
#: calibrated to a few um leaves errors of this size).
PRIOR_UM = 3.0
#: Typical size of an angle's or squareness's coefficient, arc-seconds.
PRIOR_AS = 2.0
#: One arc-second in radians.
ARCSEC = math.pi / 648000.0
_NAME = re.compile(r"^map:([de][xyz]\([XYZ]\)|sq\((?:xy|yz|zx)\)):(poly|hat|sine|const)([0-9.]*)"
                   r"\[(-?[0-9.]+),(-?[0-9.]+)\](?:@([a-z-]+))?$")
_ANGLE_WORDS = {"ex(X)": "roll of X", "ey(X)": "pitch of X", "ez(X)": "yaw of X",
                "ex(Y)": "pitch of Y", "ey(Y)": "roll of Y", "ez(Y)": "yaw of Y",
                "ex(Z)": "tilt of Z about x", "ey(Z)": "tilt of Z about y", "ez(Z)": "roll of Z"}


def kind_of(component: str) -> str:
    """'translational', 'rotational' or 'squareness'."""
    return "squareness" if component in SQUARENESS else "rotational" if component in ROTATIONAL else "translational"


def reading_axis(component: str) -> int:
    """Index of the scale reading a component's shape follows."""
    return SQUARENESS[component][0] if component in SQUARENESS else COMPONENTS[component][0]


@functools.cache
def arms(kinematics: str) -> np.ndarray:
    """(3, 3): ``arms[A, B]`` = 1 when carriage B's travel is in carriage A's
    arm (docs/conventions.md, Machine configurations), from the stacking the
    kernel reports for ``kinematics``."""
    conf = next((c for c in configurations() if c["name"] == kinematics), None)
    if conf is None:
        raise InputError(f"map correction: machine configuration {kinematics!r} is unknown")
    probe = ["XYZ".index(a) for a, side in conf["stack"] if side == "probe"]
    part = ["XYZ".index(a) for a, side in conf["stack"] if side == "part"]
    out = np.zeros((3, 3))
    for k, a in enumerate(probe):
        out[a, probe[k + 1:]] = 1.0
    for k, a in enumerate(part):
        out[a, probe + part[:k]] = 1.0
    out.setflags(write=False)
    return out


@dataclass(frozen=True)
class MapCorrection(EffectSpec):
    """A correction of one map component by a smooth function of its axis's
    reading (a ``python`` effect whose sensitivities are analytic at the
    centre level).

    Attributes (beyond :class:`EffectSpec`)
    ---------------------------------------
    component : str
        'dx(X)', ..., 'ez(Z)' (:data:`COMPONENTS`) or 'sq(xy)', 'sq(yz)',
        'sq(zx)' (:data:`SQUARENESS`).
    shape : {'poly', 'hat', 'sine', 'const'}
    scale_mm : float
        Knot spacing (hat) or period (sine), mm; 0 for poly and const.
    lo, hi : float
        Travel the shape spans, mm (the readings are clipped to it, except a
        sine's: a periodic error runs on along its scale).
    scale_u_mm : float
        Standard uncertainty of the period found by the search, mm (sine).
    trials : int
        Independent alternatives the search chose among (the p-value's
        Bonferroni factor).
    kinematics : str
        The machine configuration whose arms an angle acts over.
    """

    component: str = ""
    shape: str = "poly"
    scale_mm: float = 0.0
    lo: float = 0.0
    hi: float = 1.0
    scale_u_mm: float = float("nan")
    trials: int = 1
    kinematics: str = "thesis"
    family: str = field(default="map", compare=False)

    # -- the shape ---------------------------------------------------------

    @property
    def kind_of_component(self) -> str:
        return kind_of(self.component)

    def basis(self, q: np.ndarray) -> np.ndarray:
        """(N, k) basis functions at readings ``q`` (mm), unitless (x the parameters' unit)."""
        q = self._reading(q)
        if self.shape == "const":
            return np.ones((len(q), 1))
        if self.shape == "poly":
            t = (2 * q - self.lo - self.hi) / (self.hi - self.lo)
            cols = [(3 * t ** 2 - 1) / 2, (5 * t ** 3 - 3 * t) / 2]
            return np.column_stack(([t] if self.kind_of_component == "rotational" else []) + cols)
        if self.shape == "sine":
            w = 2 * np.pi * q / self.scale_mm
            return np.column_stack([np.sin(w), np.cos(w)])
        knots = self.knots()
        return np.clip(1 - np.abs(q[:, None] - knots[None, :]) / self.scale_mm, 0.0, None)

    def _reading(self, q) -> np.ndarray:
        """Readings ``q`` (mm) as the shape takes them: a sine runs on beyond its travel (a periodic error of a
        scale or a screw repeats along it: a run that reaches past the training travel gets the same period
        and phase, not the end value held), every other shape holds its end values there."""
        q = np.asarray(q, float)
        return q if self.shape == "sine" else np.clip(q, self.lo, self.hi)

    def knots(self) -> np.ndarray:
        n = max(int(math.ceil((self.hi - self.lo) / self.scale_mm - 1e-9)), 1)
        return self.lo + self.scale_mm * np.arange(n + 1)

    def function_um(self, q: np.ndarray, values) -> np.ndarray:
        """The correction of the component at readings ``q`` (mm), in the
        parameters' unit (um, or arc-seconds for an angle or a squareness).
        O(N) for every shape (a hat sum is the linear interpolation of its
        knot values), so a model applies it to every point of a run cheaply."""
        v = np.asarray(values, float)
        q = self._reading(q)
        if self.shape == "hat":
            return np.interp(q, self.knots(), v)
        if self.shape == "const":
            return np.full(len(q), v[0])
        if self.shape == "sine":
            w = (2 * np.pi / self.scale_mm) * q
            return v[0] * np.sin(w) + v[1] * np.cos(w)
        t = (2 * q - self.lo - self.hi) / (self.hi - self.lo)
        t2 = t * t
        out = v[-2] * (1.5 * t2 - 0.5) + v[-1] * ((2.5 * t2 - 1.5) * t)
        return out + v[0] * t if len(v) == 3 else out

    def correction(self, inputs: dict, values) -> np.ndarray:
        """(N, 3) mm added to the compensated points (the UserEffect interface)."""
        reading = [inputs["D"], inputs["E"], inputs["F"]]
        out = np.zeros((len(reading[0]), 3))
        kind = self.kind_of_component
        if kind == "squareness":
            r, d = SQUARENESS[self.component]
            out[:, d] = reading[r] * (-float(np.asarray(values, float)[0]) * ARCSEC)
            return out
        axis, d = COMPONENTS[self.component]
        f = self.function_um(reading[axis], values)
        if kind == "translational":
            out[:, d] = f * 1e-3
            return out
        # e_d x lever, lever = arm + (point - reading): only the two components across the turning axis count.
        f *= ARCSEC
        a, b = (d + 1) % 3, (d + 2) % 3
        arm = arms(self.kinematics)[axis]
        lev = [inputs["xyz"[c]] + (arm[c] - 1.0) * reading[c] if arm[c] != 1.0 else inputs["xyz"[c]] for c in (a, b)]
        out[:, b] = lev[0] * f
        out[:, a] = -lev[1] * f
        return out

    def describe(self, values) -> str:
        v = np.asarray(values, float)
        unit = "um" if self.kind_of_component == "translational" else "arc-second"
        if self.shape == "sine":
            amp = float(np.hypot(*v))
            per = f"{self.scale_mm:.1f}" + (f" ± {self.scale_u_mm:.1g}" if math.isfinite(self.scale_u_mm) else "")
            return f"{self.component}: {amp:.3g} {unit} amplitude at a period of {per} mm"
        return f"{self.component}: " + ", ".join(f"{p}={x:+.3g} {unit}" for p, x in zip(self.params, v))

    # -- sensitivities -----------------------------------------------------


def is_map(spec) -> bool:
    return getattr(spec, "family", None) == "map"


def make(component: str, shape: str, lo: float, hi: float, scale_mm: float = 0.0, *, kinematics: str = "thesis",
         **changes) -> MapCorrection:
    """A map correction spec (see the module docstring for the shapes)."""
    if component not in COMPONENTS and component not in SQUARENESS:
        raise InputError(f"map correction: component {component!r} is not one of "
                         f"{', '.join([*COMPONENTS, *SQUARENESS])}")
    if not (hi > lo):
        raise InputError(f"map correction {component}: travel [{lo}, {hi}] mm is empty")
    kind = kind_of(component)
    if (shape == "const") != (kind == "squareness"):
        raise InputError(f"map correction {component}: shape {shape!r} does not apply (a squareness is 'const', "
                         f"a component poly, hat or sine)")
    u = "um" if kind == "translational" else "as"
    if shape == "poly":
        params = (f"p2_{u}", f"p3_{u}") if kind == "translational" else (f"p1_{u}", f"p2_{u}", f"p3_{u}")
        tag = ""
    elif shape == "const":
        params = (f"s_{u}",)
        tag = ""
    elif shape == "sine":
        if not scale_mm > 0:
            raise InputError(f"map correction {component}: period must be > 0 mm, got {scale_mm}")
        params = (f"sin_{u}", f"cos_{u}")
        tag = f"{scale_mm:.6g}"
    elif shape == "hat":
        if not scale_mm > 0:
            raise InputError(f"map correction {component}: knot spacing must be > 0 mm, got {scale_mm}")
        n = max(int(math.ceil((hi - lo) / scale_mm - 1e-9)), 1) + 1
        params = tuple(f"k{i}_{u}" for i in range(n))
        tag = f"{scale_mm:.6g}"
    else:
        raise InputError(f"map correction {component}: shape {shape!r} is not poly, hat, sine or const")
    if kind == "rotational":
        arms(kinematics)  # a known configuration
    else:
        kinematics = "thesis"  # only an angle's action depends on the stacking
    axis = reading_axis(component)
    deg = "1-3" if kind == "rotational" else "2-3"
    what = {"poly": f"a smooth bow (Legendre degrees {deg})", "hat": f"local bumps (knots every {scale_mm:.4g} mm)",
            "sine": f"a periodic error of period {scale_mm:.4g} mm" if hi - lo >= 2 * scale_mm else  # issue 33 s. 7
            f"a sinusoidal error of period {scale_mm:.4g} mm (too few cycles over the travel to call it periodic)",
            "const": "a constant"}[shape]
    if kind == "squareness":
        physics = f"the map's squareness {component[3:5].upper()} is off by {what}"
        reveal = "ballbar positions or plate placements on the face diagonals of that plane"
    else:
        label = {"translational": "position error" if axis == COMPONENTS[component][1] else "straightness",
                 "rotational": _ANGLE_WORDS.get(component, "angle")}[kind]
        physics = f"the map's {label} {component} is off by {what} along {'XYZ'[axis]}"
        reveal = f"scans spread along {'XYZ'[axis]} (bar positions or plate placements along it)"
        if kind == "rotational":
            reveal += ", with different levers (heights, offsets across the axis, probe poses)"
    name = f"map:{component}:{shape}{tag}[{lo:.6g},{hi:.6g}]" + (f"@{kinematics}" if kinematics != "thesis" else "")
    unit = "um" if kind == "translational" else "arc-second"
    prior = PRIOR_UM if kind == "translational" else PRIOR_AS
    return MapCorrection(name=name, params=params, units=(unit,) * len(params), prior=(prior,) * len(params),
                         kind="python", key="map", physics=physics, reveal=reveal,
                         component=component, shape=shape, scale_mm=float(scale_mm), lo=float(lo), hi=float(hi),
                         kinematics=kinematics, **changes)


def parse(name: str) -> MapCorrection:
    """The spec of a map-correction name ('map:dx(X):sine170.2[-120,780]',
    'map:ez(X):poly[0,900]@moving-bridge')."""
    m = _NAME.match(name)
    if not m:
        raise InputError(f"effect {name!r}: not a map correction name (map:<component>:<shape>[lo,hi], e.g. "
                         f"'map:dy(X):poly[0,900]' or 'map:ez(X):hat90[0,900]')")
    comp, shape, scale, lo, hi, kin = m.groups()
    return make(comp, shape, float(lo), float(hi), float(scale) if scale else 0.0, kinematics=kin or "thesis")


# -- the corrected maps ---------------------------------------------------

#: Sign of a map table's entry against the correction added to the
#: compensated point (a map error adds to the compensated coordinate; checked by tests).
_TABLE_SIGN = 1.0


def corrected_maps(model):
    """``model``'s maps with its map corrections written into the component
    tables (translational components in um, angles in arc-seconds) and the
    squareness (the other effects are not maps: they stay in the model). The
    tables keep their nodes: within the travel a correction spans, one node
    in from its ends, the maps correct as the model does; over the end
    intervals they interpolate linearly towards the value held beyond it.

    Returns
    -------
    ErrorMap or ErrorMapSet
        Write it with ``.write(path, format)`` (:mod:`cmmpose.formats.mapfiles`).

    Raises
    ------
    InputError
        An angle's correction was found for another machine configuration
        than the maps'.
    """
    maps = model.maps.maps if isinstance(model.maps, ErrorMapSet) else [model.maps]
    corr = [(spec, v) for spec, v in model.effects if is_map(spec)]
    new = []
    for m in maps:
        tables = {c: m.table(c).copy() for c in "XYZ"}
        sq = list(m.squareness)
        for spec, v in corr:
            kind = spec.kind_of_component
            if kind == "squareness":
                sq[list(SQUARENESS).index(spec.component)] += _TABLE_SIGN * float(np.asarray(v, float)[0])
                continue
            if kind == "rotational" and spec.kinematics != m.kinematics:
                raise InputError(f"map correction {spec.name}: found for a {spec.kinematics} machine, the maps "
                                 f"are for {m.kinematics}")
            axis, d = COMPONENTS[spec.component]
            t = tables["XYZ"[axis]]
            t[:, (1 if kind == "translational" else 4) + d] += _TABLE_SIGN * spec.function_um(t[:, 0], v)
        out = ErrorMap(tables["X"], tables["Y"], tables["Z"], tuple(sq), m.temperature,
                       source=f"{getattr(m, 'source', None) or 'maps'} + map corrections")
        new.append(out.with_kinematics(m.kinematics) if hasattr(out, "with_kinematics") else out)
    return ErrorMapSet(new) if isinstance(model.maps, ErrorMapSet) else new[0]
