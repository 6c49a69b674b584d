"""Each compensated point's standard uncertainty (k = 1): the sources, where
their values come from, and the compensation that returns them
(docs/uncertainty.md, section 5 "Per point").

The kernel propagates every source by the linear law (GUM eq. 10) in the
same pass as the correction (``cmmpose._core.compensate_uncertainty``);
this module states the sources in the package's units (um, arc-seconds,
ppm, K, degrees) and converts them to the core's (mm, rad, relative) in
one place, :meth:`UncertaintySources.kernel_sources`.

Sources, each switchable off by name for a budget (:meth:`UncertaintySources.without`):

``map``
    The maps' stated uncertainty per component (:class:`MapUncertainty`):
    common to nearby points.
``temperature``
    The machine temperature's standard uncertainty, K, through the map
    set's thermal sensitivity: common.
``scanner_scale``
    The scanner's relative scale uncertainty, ppm of (u, v): common.
``scanner_noise``
    The scanner's noise in u and v, um: independent from point to point.
``pose``
    The pose angles' and mount offset's covariance from the calibration
    solvers (:class:`PoseUncertainty`): common.
``model``
    A found model's parameter covariance (J C J^T, one kernel pass per
    determined parameter): common.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from .errors import InputError

__all__ = ["MapUncertainty", "PoseUncertainty", "UncertaintySources", "UncertainPoints", "SOURCES",
           "DETAILS", "covariance_matrices"]

#: The sources by name, in the order a budget lists them.
SOURCES = ("map", "temperature", "scanner_scale", "scanner_noise", "pose", "model")
#: What a compensation with uncertainty returns per point (see :class:`UncertainPoints`).
DETAILS = ("standard", "covariance", "split")

ARCSEC = math.pi / (180.0 * 3600.0)
_AXES = ("x", "y", "z")
# Bounds beyond which a stated uncertainty is not a measurement's (a typing slip, a unit mix-up).
_MAX = {"um": 1000.0, "arcsec": 3600.0, "ppm": 1000.0, "K": 50.0, "mm^2": 100.0, "degree^2": 100.0}


def _standard(where: str, value, unit: str) -> float:
    """A standard uncertainty: a finite number, >= 0, within the bound for ``unit``."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise InputError(f"{where}: expected a number ({unit}), got {type(value).__name__}")
    v = float(value)
    if not math.isfinite(v) or v < 0:
        raise InputError(f"{where}: {v:g} {unit} is not a standard uncertainty (finite, >= 0)")
    if v > _MAX[unit]:
        raise InputError(f"{where}: {v:g} {unit} is beyond any stated uncertainty of this kind "
                         f"(at most {_MAX[unit]:g} {unit}); check the unit")
    return v


def _triple(where: str, value, unit: str) -> tuple[float, float, float]:
    a = list(value) if isinstance(value, (list, tuple, np.ndarray)) else None
    if a is None or len(a) != 3:
        raise InputError(f"{where}: expected 3 values ({unit}) for X, Y, Z, got {value!r}")
    return tuple(_standard(f"{where}[{i}]", v, unit) for i, v in enumerate(a))


def _covariance(where: str, value, unit: str) -> tuple:
    """A 3 x 3 covariance: finite, symmetric, positive semi-definite."""
    try:
        m = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{where}: expected a 3 x 3 covariance ({unit}), got {value!r}") from None
    if m.shape != (3, 3):
        raise InputError(f"{where}: expected a 3 x 3 covariance ({unit}), got shape {m.shape}")
    if not np.all(np.isfinite(m)):
        raise InputError(f"{where}: has a value that is not finite")
    scale = float(np.max(np.abs(m))) if m.size else 0.0
    if scale > _MAX[unit]:
        raise InputError(f"{where}: entries up to {scale:g} {unit} are beyond any calibration's covariance")
    if np.max(np.abs(m - m.T)) > 1e-12 * max(scale, 1e-300):
        raise InputError(f"{where}: is not symmetric")
    low = float(np.linalg.eigvalsh(m).min())
    if low < -1e-12 * scale:
        raise InputError(f"{where}: is not positive semi-definite (eigenvalue {low:.3g} {unit})")
    return tuple(tuple(float(x) for x in row) for row in m)


@dataclass(frozen=True)
class MapUncertainty:
    """Stated standard uncertainties (k = 1) of a map's components, taken as
    independent and the same along each axis, plus a part of each axis's
    positioning error that grows with the distance from where it was zeroed
    (an interferometer's ppm).

    Parameters
    ----------
    position_um : 3 x 3 nested sequence of float
        [carriage X, Y, Z][dx, dy, dz], um.
    rotation_arcsec : 3 x 3 nested sequence of float
        [carriage X, Y, Z][ex, ey, ez], arc-seconds.
    squareness_arcsec : sequence of 3 float
        S_xy, S_yz, S_zx, arc-seconds.
    positioning_ppm : sequence of 3 float
        Relative uncertainty of X's dx, Y's dy, Z's dz, ppm of the distance
        from ``reference_mm``.
    reference_mm : sequence of 3 float, optional
        Where each axis's positioning error was zeroed, mm; None: the first
        position of each map table.
    source : str
        Where the values come from (a citation, a certificate).
    """

    position_um: tuple = ((0.0,) * 3,) * 3
    rotation_arcsec: tuple = ((0.0,) * 3,) * 3
    squareness_arcsec: tuple = (0.0, 0.0, 0.0)
    positioning_ppm: tuple = (0.0, 0.0, 0.0)
    reference_mm: tuple | None = None
    source: str = ""

    def __post_init__(self):
        for name, unit in (("position_um", "um"), ("rotation_arcsec", "arcsec")):
            rows = getattr(self, name)
            if not isinstance(rows, (list, tuple, np.ndarray)) or len(rows) != 3:
                raise InputError(f"{name}: expected 3 rows (carriages X, Y, Z) of 3 values ({unit})")
            object.__setattr__(self, name, tuple(_triple(f"{name}[{a}]", r, unit) for a, r in zip(_AXES, rows)))
        object.__setattr__(self, "squareness_arcsec", _triple("squareness_arcsec", self.squareness_arcsec, "arcsec"))
        object.__setattr__(self, "positioning_ppm", _triple("positioning_ppm", self.positioning_ppm, "ppm"))
        if self.reference_mm is not None:
            ref = [float(x) for x in self.reference_mm]
            if len(ref) != 3 or not all(math.isfinite(x) and abs(x) <= 1e5 for x in ref):
                raise InputError(f"reference_mm: expected 3 finite positions within 100 m, got {self.reference_mm!r}")
            object.__setattr__(self, "reference_mm", tuple(ref))

    @classmethod
    def from_dict(cls, d: dict, where: str = "uncertainty") -> MapUncertainty:
        """From a document's table (a machine file's ``[uncertainty]``, a map
        file's ``uncertainty`` header): the fields above by name, each
        optional; an unknown key or a bad value is an ``InputError`` naming
        ``where`` and the key."""
        if not isinstance(d, dict):
            raise InputError(f"{where}: expected a table of the map's uncertainties, got {type(d).__name__}")
        known = {f for f in cls.__dataclass_fields__}
        unknown = sorted(set(d) - known)
        if unknown:
            raise InputError(f"{where}: unknown key(s) {', '.join(unknown)} (known: {', '.join(sorted(known))})")
        try:
            return cls(**d)
        except InputError as e:
            raise InputError(f"{where}.{e}") from None

    def to_dict(self) -> dict:
        """JSON/TOML-ready: the fields by name."""
        out = {"position_um": [list(r) for r in self.position_um],
               "rotation_arcsec": [list(r) for r in self.rotation_arcsec],
               "squareness_arcsec": list(self.squareness_arcsec), "positioning_ppm": list(self.positioning_ppm),
               "source": self.source}
        if self.reference_mm is not None:
            out["reference_mm"] = list(self.reference_mm)
        return out

    @classmethod
    def thesis(cls) -> MapUncertainty:
        """What the thesis states for its map measurements (thesis.txt):
        the laser interferometer's calibration, 2.5 ppm of the length
        (line 772), on each axis's positioning error; the linear (straightness
        and positioning) and angular readings' resolution, 0.1 um and 0.1
        arc-second (lines 756, 774), as rectangular distributions (0.1/sqrt(12)).
        The thesis states no uncertainty for its squareness values (Table 7):
        they are given none here."""
        r = 0.1 / math.sqrt(12.0)
        return cls(position_um=((r,) * 3,) * 3, rotation_arcsec=((r,) * 3,) * 3,
                   positioning_ppm=(2.5, 2.5, 2.5),
                   source="Harris thesis: interferometer 2.5 ppm (line 772); resolution 0.1 um, 0.1 arc-second "
                          "(lines 756, 774), rectangular; squareness not stated")

    def combined(self, other: MapUncertainty) -> MapUncertainty:
        """The larger of the two per component (a map set's maps at several
        temperatures state one uncertainty for the blend)."""
        big = lambda a, b: tuple(max(x, y) for x, y in zip(a, b))  # noqa: E731
        return MapUncertainty(tuple(big(a, b) for a, b in zip(self.position_um, other.position_um)),
                              tuple(big(a, b) for a, b in zip(self.rotation_arcsec, other.rotation_arcsec)),
                              big(self.squareness_arcsec, other.squareness_arcsec),
                              big(self.positioning_ppm, other.positioning_ppm),
                              self.reference_mm if self.reference_mm is not None else other.reference_mm,
                              "; ".join(dict.fromkeys(s for s in (self.source, other.source) if s)))


@dataclass(frozen=True)
class PoseUncertainty:
    """One pose's calibration uncertainty and its scanner's noise.

    Parameters
    ----------
    offset_covariance_mm2 : 3 x 3 nested sequence of float
        Covariance of the mount offset (U1, V1, W1), mm^2.
    angle_covariance_deg2 : 3 x 3 nested sequence of float
        Covariance of the pose angles (alpha, beta, gamma), degree^2.
    source : str
        Where the values come from (a calibration record).
    """

    offset_covariance_mm2: tuple = ((0.0,) * 3,) * 3
    angle_covariance_deg2: tuple = ((0.0,) * 3,) * 3
    source: str = ""

    def __post_init__(self):
        object.__setattr__(self, "offset_covariance_mm2",
                           _covariance("offset_covariance_mm2", self.offset_covariance_mm2, "mm^2"))
        object.__setattr__(self, "angle_covariance_deg2",
                           _covariance("angle_covariance_deg2", self.angle_covariance_deg2, "degree^2"))

    @classmethod
    def from_record(cls, record) -> PoseUncertainty:
        """From a stored alignment (:class:`cmmpose.calibration.library.AlignmentRecord`):
        its pose covariance (else its pose uncertainties as independent) and
        its offset covariance (stored by ``calibrate offset --store``; else
        its offset uncertainty, independent per component)."""
        ac = record.pose_covariance
        if ac is None and record.pose_uncertainty is not None:
            ac = np.diag(np.square(record.pose_uncertainty))
        oc = getattr(record, "offset_covariance", None)
        if oc is None and record.offset_uncertainty is not None:
            oc = np.diag(np.square(record.offset_uncertainty))
        zero = ((0.0,) * 3,) * 3
        return cls(zero if oc is None else oc, zero if ac is None else ac, source=f"alignment of {record.date}")


@dataclass(frozen=True)
class _KernelPose:
    """One digitizer's sources in the core's units (mm^2, rad^2, mm)."""
    offset_covariance: tuple
    angle_covariance: tuple
    noise: tuple


@dataclass(frozen=True)
class KernelSources:
    """The sources as the kernel takes them (mm, rad, K, relative): the
    named structure ``cmmpose._core.compensate_uncertainty`` reads."""
    map_position: tuple
    map_rotation: tuple
    map_squareness: tuple
    map_positioning: tuple
    map_reference: tuple
    temperature: float
    scanner_scale: float
    poses: list


@dataclass(frozen=True)
class UncertaintySources:
    """The sources of each compensated point's uncertainty (k = 1).

    Parameters
    ----------
    map : MapUncertainty, optional
        The maps' stated uncertainty; None: the maps' own
        (``ErrorMap.stated_uncertainty``), else none.
    temperature_k : float
        Standard uncertainty of the machine temperature, K (acts through a
        map set's thermal sensitivity; a single map has none).
    scanner_scale_ppm : float
        The scanner's relative scale uncertainty, ppm of (u, v).
    scanner_noise_um : float or sequence of 2 float
        The scanner's noise, um, in u and v (one value: both); independent
        from point to point.
    pose : PoseUncertainty or sequence of PoseUncertainty, optional
        The pose's calibration uncertainty, one for every pose or one per pose.
    model : bool
        Include a found model's parameter covariance.
    off : tuple of str
        Sources switched off (:meth:`without`).
    """

    map: MapUncertainty | None = None
    temperature_k: float = 0.0
    scanner_scale_ppm: float = 0.0
    scanner_noise_um: float | tuple = 0.0
    pose: PoseUncertainty | tuple | None = None
    model: bool = True
    off: tuple = field(default=())

    def __post_init__(self):
        if self.map is not None and not isinstance(self.map, MapUncertainty):
            raise InputError(f"map: expected a MapUncertainty, got {type(self.map).__name__}")
        object.__setattr__(self, "temperature_k", _standard("temperature_k", self.temperature_k, "K"))
        object.__setattr__(self, "scanner_scale_ppm", _standard("scanner_scale_ppm", self.scanner_scale_ppm, "ppm"))
        noise = self.scanner_noise_um
        noise = (noise, noise) if np.ndim(noise) == 0 else tuple(noise)
        if len(noise) != 2:
            raise InputError(f"scanner_noise_um: expected one value or two (u, v), got {self.scanner_noise_um!r}")
        object.__setattr__(self, "scanner_noise_um", tuple(_standard(f"scanner_noise_um[{i}]", v, "um")
                                                           for i, v in enumerate(noise)))
        poses = self.pose
        if poses is not None:
            poses = (poses,) if isinstance(poses, PoseUncertainty) else tuple(poses)
            if not all(isinstance(p, PoseUncertainty) for p in poses):
                raise InputError("pose: expected a PoseUncertainty or a sequence of them (one per pose)")
            object.__setattr__(self, "pose", poses)
        bad = sorted(set(self.off) - set(SOURCES))
        if bad:
            raise InputError(f"off: unknown source(s) {', '.join(bad)} (the sources: {', '.join(SOURCES)})")
        object.__setattr__(self, "off", tuple(dict.fromkeys(self.off)))

    def without(self, *names: str) -> UncertaintySources:
        """These sources with ``names`` switched off (a budget: what each source adds)."""
        return replace(self, off=tuple(self.off) + tuple(names))

    def on(self, name: str) -> bool:
        """Whether source ``name`` is switched on."""
        return name not in self.off

    def stated_map(self, maps) -> MapUncertainty | None:
        """The map uncertainty in force: this one, else the maps' own."""
        if not self.on("map"):
            return None
        return self.map if self.map is not None else getattr(maps.error_maps, "stated_uncertainty", None)

    def kernel_sources(self, maps, digitizers: int) -> KernelSources:
        """In the core's units, for ``digitizers`` poses: the one place that
        converts um, arc-seconds, ppm and degrees to mm, rad and relative."""
        m = self.stated_map(maps)
        zero3, zero33 = (0.0, 0.0, 0.0), ((0.0,) * 3,) * 3
        if m is None:
            pos, rot, sq, ppm, ref = zero33, zero33, zero3, zero3, zero3
        else:
            pos = tuple(tuple(x * 1e-3 for x in r) for r in m.position_um)
            rot = tuple(tuple(x * ARCSEC for x in r) for r in m.rotation_arcsec)
            sq = tuple(x * ARCSEC for x in m.squareness_arcsec)
            ppm = tuple(x * 1e-6 for x in m.positioning_ppm)
            ref = m.reference_mm if m.reference_mm is not None else _table_starts(maps.error_maps)
        poses = []
        noise = tuple(x * 1e-3 for x in self.scanner_noise_um) if self.on("scanner_noise") else (0.0, 0.0)
        given = self.pose if self.on("pose") and self.pose is not None else ()
        if given and len(given) not in (1, digitizers):
            raise InputError(f"pose: {len(given)} pose uncertainties for {digitizers} poses (give one, or one per pose)")
        for k in range(digitizers):
            p = given[0] if len(given) == 1 else (given[k] if given else None)
            oc = zero33 if p is None else p.offset_covariance_mm2
            ac = zero33 if p is None else tuple(tuple(x * (math.pi / 180.0) ** 2 for x in r)
                                                for r in p.angle_covariance_deg2)
            poses.append(_KernelPose(oc, ac, noise))
        return KernelSources(pos, rot, sq, ppm, tuple(ref),
                             self.temperature_k if self.on("temperature") else 0.0,
                             self.scanner_scale_ppm * 1e-6 if self.on("scanner_scale") else 0.0, poses)

    def describe(self, maps=None) -> list[dict]:
        """One row per source: name, whether on, value, unit, where it comes from."""
        m = self.stated_map(maps) if maps is not None else self.map
        return [
            {"source": "map", "on": self.on("map"), "value": None if m is None else m.to_dict(), "unit": "um, arc-second, ppm",
             "from": "" if m is None else m.source},
            {"source": "temperature", "on": self.on("temperature"), "value": self.temperature_k, "unit": "K", "from": "stated"},
            {"source": "scanner_scale", "on": self.on("scanner_scale"), "value": self.scanner_scale_ppm, "unit": "ppm",
             "from": "stated"},
            {"source": "scanner_noise", "on": self.on("scanner_noise"), "value": list(self.scanner_noise_um), "unit": "um",
             "from": "stated"},
            {"source": "pose", "on": self.on("pose"), "value": None if self.pose is None else len(self.pose),
             "unit": "poses", "from": "; ".join(p.source for p in self.pose or ())},
            {"source": "model", "on": self.on("model") and self.model, "value": None, "unit": "",
             "from": "the model's parameter covariance"},
        ]


def _table_starts(maps) -> tuple:
    """Each axis's first table position, mm (a set: its first map's)."""
    first = maps.maps[0] if hasattr(maps, "maps") else maps
    return tuple(float(lo) for lo, _ in first.ranges)


def covariance_matrices(sym: np.ndarray) -> np.ndarray:
    """(N, 6) entries xx, yy, zz, xy, xz, yz as (N, 3, 3) matrices."""
    sym = np.asarray(sym)
    out = np.empty((len(sym), 3, 3))
    for (r, c), k in {(0, 0): 0, (1, 1): 1, (2, 2): 2, (0, 1): 3, (0, 2): 4, (1, 2): 5}.items():
        out[:, r, c] = sym[:, k]
        out[:, c, r] = sym[:, k]
    return out


@dataclass(frozen=True)
class UncertainPoints:
    """Compensated points with their uncertainty.

    Attributes
    ----------
    xyz : ndarray (N, 3)
        Compensated X, Y, Z, mm (the bits :func:`cmmpose.compensate` gives).
    u : ndarray (N, 3)
        Standard uncertainty (k = 1) of X, Y, Z, mm.
    covariance : ndarray (N, 6) or None
        The full covariance, entries xx, yy, zz, xy, xz, yz, mm^2
        (``detail='covariance'`` or ``'split'``; :func:`covariance_matrices`
        makes 3 x 3 matrices of it).
    common : ndarray (N, 6) or None
        Its part common to nearby points (maps, temperature, pose, scanner
        scale, model), mm^2 (``detail='split'``); the rest is independent
        (the scanner's noise).
    sources : UncertaintySources
        What was propagated.
    """

    xyz: np.ndarray
    u: np.ndarray
    covariance: np.ndarray | None
    common: np.ndarray | None
    sources: UncertaintySources

    def __len__(self) -> int:
        return len(self.xyz)

    @property
    def independent(self) -> np.ndarray | None:
        """The independent part of the covariance (N, 6), mm^2."""
        return None if self.covariance is None or self.common is None else self.covariance - self.common

    @classmethod
    def from_kernel(cls, xyz: np.ndarray, rows: np.ndarray, sources: UncertaintySources) -> UncertainPoints:
        """From the kernel's (N, 3 / 9 / 15) rows: views, no copy."""
        w = rows.shape[1]
        return cls(xyz, rows[:, :3], rows[:, 3:9] if w >= 9 else None, rows[:, 9:15] if w >= 15 else None, sources)
