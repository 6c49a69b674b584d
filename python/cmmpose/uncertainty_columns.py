"""Each compensated point's uncertainty as columns of a point file, and the
budget a compensation states for it (docs/formats.md, "Uncertainty columns";
docs/uncertainty.md, "Per point").

Every output path (:func:`cmmpose.compensate_file`, ``cmmpose compensate
--uncertainty``, the Dask path in :mod:`cmmpose.scale`) writes the same
columns, named like the other per-axis uncertainties the project writes
(``u_x_um`` in an artefact's deviations): the axis in lower case, the unit
last. They are mm (mm^2) in every format, E57's included (whose coordinates
are metres): only the coordinates are converted.

``detail='standard'``
    ``u_x_mm, u_y_mm, u_z_mm``: the standard uncertainty (k = 1) of X, Y, Z, mm.
``detail='covariance'``
    and ``cov_xx_mm2, cov_yy_mm2, cov_zz_mm2, cov_xy_mm2, cov_xz_mm2,
    cov_yz_mm2``: the full covariance of (X, Y, Z), mm^2.
``detail='split'``
    and ``cov_common_xx_mm2`` ... ``cov_common_yz_mm2``: its part common to
    nearby points (maps, temperature, pose, scanner scale, model), mm^2; the
    rest (``cov_* - cov_common_*``) is independent from point to point (the
    scanner's noise).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np

from .errormap import ErrorMapSet
from .errors import InputError
from .point_uncertainty import DETAILS, MapUncertainty, UncertainPoints, UncertaintySources

__all__ = ["U_COLUMNS", "COVARIANCE_COLUMNS", "COMMON_COLUMNS", "uncertainty_columns", "columns_of",
           "check_detail", "check_no_collision", "stated_sources", "require_stated", "budget_rows",
           "UncertaintyTally", "log_budget"]

_log = logging.getLogger("cmmpose.uncertainty")

_PAIRS = ("xx", "yy", "zz", "xy", "xz", "yz")
#: The standard uncertainty (k = 1) of X, Y, Z, mm.
U_COLUMNS = ("u_x_mm", "u_y_mm", "u_z_mm")
#: The covariance of (X, Y, Z), entries xx, yy, zz, xy, xz, yz, mm^2.
COVARIANCE_COLUMNS = tuple(f"cov_{p}_mm2" for p in _PAIRS)
#: The covariance's part common to nearby points, mm^2.
COMMON_COLUMNS = tuple(f"cov_common_{p}_mm2" for p in _PAIRS)


def check_detail(detail: str) -> str:
    """``detail`` if it is one of ``DETAILS``, else ``InputError`` listing them."""
    if detail not in DETAILS:
        raise InputError(f"uncertainty_detail: {detail!r} is not one of {', '.join(DETAILS)}")
    return detail


def uncertainty_columns(detail: str = "standard") -> tuple[str, ...]:
    """The column names written for ``detail`` (one of ``DETAILS``), in order."""
    check_detail(detail)
    return U_COLUMNS + (COVARIANCE_COLUMNS if detail != "standard" else ()) + (
        COMMON_COLUMNS if detail == "split" else ())


def columns_of(points: UncertainPoints) -> dict[str, np.ndarray]:
    """The uncertainty columns of ``points`` by name (views of its arrays:
    u mm, covariance and common part mm^2), in the order of :func:`uncertainty_columns`."""
    out = {n: points.u[:, k] for k, n in enumerate(U_COLUMNS)}
    if points.covariance is not None:
        out |= {n: points.covariance[:, k] for k, n in enumerate(COVARIANCE_COLUMNS)}
    if points.common is not None:
        out |= {n: points.common[:, k] for k, n in enumerate(COMMON_COLUMNS)}
    return out


def check_no_collision(where, names, detail: str) -> None:
    """``InputError`` naming ``where`` when an input column (``names``) has
    the name of an uncertainty column the output writes: it would be written twice."""
    clash = [n for n in names if n in uncertainty_columns(detail)]
    if clash:
        raise InputError(f"{where}: has a column {clash[0]!r}, which the uncertainty output (uncertainty=, "
                         f"--uncertainty) writes; drop or rename it (an output compensated before?)")


def _model_stated(maps) -> bool:
    """A model with at least one effect whose parameters have a stated uncertainty."""
    effects = getattr(maps, "effects", None)
    if not effects:
        return False
    stated = getattr(maps, "uncertainty", {}) or {}
    return any(np.any(np.isfinite(np.ravel(stated.get(spec.name, np.nan)))) for spec, _ in effects)


@dataclass(frozen=True)
class StatedMaps:
    """What a machine model (maps or a found model) states for the
    uncertainty budget, read once: the map uncertainty in force (None: none
    stated, or the source switched off), whether the temperature acts
    through the maps (a set at several temperatures), and whether a model
    states its parameters' covariance."""

    map: MapUncertainty | None
    thermal: bool
    model: bool

    @classmethod
    def of(cls, sources: UncertaintySources, maps) -> "StatedMaps":
        thermal = isinstance(maps.error_maps, ErrorMapSet)
        model = _model_stated(maps)
        return cls(sources.stated_map(maps), thermal, model)


def stated_sources(sources: UncertaintySources, stated: StatedMaps) -> list[str]:
    """The names of the sources that are on and give the points some
    uncertainty (a non-zero value; the temperature only through a map set)."""
    on = []
    m = stated.map
    if m is not None and any(v > 0 for v in (*np.ravel(m.position_um), *np.ravel(m.rotation_arcsec),
                                             *m.squareness_arcsec, *m.positioning_ppm)):
        on.append("map")
    if sources.on("temperature") and sources.temperature_k > 0 and stated.thermal:
        on.append("temperature")
    if sources.on("scanner_scale") and sources.scanner_scale_ppm > 0:
        on.append("scanner_scale")
    if sources.on("scanner_noise") and max(sources.scanner_noise_um) > 0:
        on.append("scanner_noise")
    if sources.on("pose") and sources.pose and any(
            np.any(np.asarray(p.offset_covariance_mm2)) or np.any(np.asarray(p.angle_covariance_deg2))
            for p in sources.pose):
        on.append("pose")
    if sources.model and sources.on("model") and stated.model:
        on.append("model")
    return on


def require_stated(sources: UncertaintySources, maps, where: str = "uncertainty") -> StatedMaps:
    """What ``maps`` (an ErrorMap, ErrorMapSet or Model) state
    (:class:`StatedMaps`), or ``InputError`` when no source is stated:
    every point's uncertainty would be written as 0, a silent wrong answer."""
    stated = StatedMaps.of(sources, maps)
    if not stated_sources(sources, stated):
        off = f"; switched off: {', '.join(sources.off)}" if sources.off else ""
        raise InputError(
            f"{where}: no source of uncertainty is stated (the maps state none, and no temperature, scanner or "
            f"pose uncertainty is given{off}): every u would be 0. State one (a map file's uncertainty, "
            f"--temperature-uncertainty / temperature_k, --scanner-noise / scanner_noise_um, "
            f"--scanner-scale-ppm / scanner_scale_ppm, an alignment's covariance) or leave out --uncertainty")
    return stated


def _map_text(m) -> str:
    pos, rot = max(np.ravel(m.position_um)), max(np.ravel(m.rotation_arcsec))
    return (f"position up to {pos:.3g} um, rotation up to {rot:.3g} arc-second, squareness up to "
            f"{max(m.squareness_arcsec):.3g} arc-second, positioning up to {max(m.positioning_ppm):.3g} ppm")


def _pose_text(poses) -> str:
    texts = []
    for p in poses:
        so = np.sqrt(np.clip(np.diag(np.asarray(p.offset_covariance_mm2)), 0, None)) * 1e3
        sa = np.sqrt(np.clip(np.diag(np.asarray(p.angle_covariance_deg2)), 0, None)) * 3600.0
        texts.append("offset sd " + ", ".join(f"{v:.3g}" for v in so) + " um; angles sd "
                     + ", ".join(f"{v:.3g}" for v in sa) + " arc-second")
    return "; ".join(texts)


def budget_rows(sources: UncertaintySources, stated: StatedMaps, origins: dict | None = None) -> list[dict]:
    """One row per source: ``source``, ``on`` (bool), ``value`` (text with
    units) and ``from`` (where the value comes from; ``origins`` by source
    name overrides the default wording, e.g. a machine file's key).
    ``stated`` is what the maps state (:func:`require_stated`)."""
    origins = dict(origins or {})
    m = stated.map
    u_n = sources.scanner_noise_um
    thermal = stated.thermal
    model_on = bool(sources.model and sources.on("model"))
    rows = [
        ("map", sources.on("map"), "none stated" if m is None else _map_text(m),
         "" if m is None else (m.source or "the maps' stated uncertainty")),
        ("temperature", sources.on("temperature"),
         f"{sources.temperature_k:g} K" + ("" if thermal or not sources.temperature_k
                                           else " (no effect: one map, no thermal sensitivity)"), "stated"),
        ("scanner_scale", sources.on("scanner_scale"), f"{sources.scanner_scale_ppm:g} ppm of u, v", "stated"),
        ("scanner_noise", sources.on("scanner_noise"), f"u {u_n[0]:g} um, v {u_n[1]:g} um (independent)", "stated"),
        ("pose", sources.on("pose"), "none stated" if not sources.pose else _pose_text(sources.pose),
         "; ".join(p.source for p in sources.pose or ()) or ""),
        ("model", model_on, "parameter covariance" if stated.model else "no model effects",
         "the model's parameter covariance" if stated.model else ""),
    ]
    return [{"source": s, "on": bool(on), "value": v, "from": origins.get(s, f)} for s, on, v, f in rows]


def _squares_and_largest(u: np.ndarray) -> tuple[np.ndarray, list]:
    """Sum of squares and largest value of each of the 3 columns of ``u``
    (a column at a time: numpy's max along axis 0 of an (N, 3) array is 5x slower)."""
    return np.einsum("ij,ij->j", u, u), [u[:, k].max() for k in range(u.shape[1])]


@dataclass
class UncertaintyTally:
    """The rms and largest u per axis over the points, gathered chunk by
    chunk (NaN rows, ``nan_policy='propagate'``, are not counted).

    Attributes
    ----------
    points : int
        Points counted.
    sum_sq : list of 3 float
        Sum of u^2 per axis, mm^2.
    largest : list of 3 float
        Largest u per axis, mm.
    budget : list of dict
        :func:`budget_rows` of the sources propagated.
    """

    points: int = 0
    sum_sq: list = field(default_factory=lambda: [0.0, 0.0, 0.0])
    largest: list = field(default_factory=lambda: [0.0, 0.0, 0.0])
    budget: list = field(default_factory=list)

    def add(self, u: np.ndarray) -> None:
        """Count a chunk's (n, 3) u, mm."""
        u = np.asarray(u)
        if not len(u):
            return
        sq, top = _squares_and_largest(u)
        if not (np.all(np.isfinite(sq)) and np.all(np.isfinite(top))):  # NaN rows: counted without them
            u = u[np.all(np.isfinite(u), axis=1)]
            if not len(u):
                return
            sq, top = _squares_and_largest(u)
        self.points += len(u)
        self.sum_sq = [a + float(b) for a, b in zip(self.sum_sq, sq)]
        self.largest = [max(a, float(b)) for a, b in zip(self.largest, top)]

    def merge(self, other: UncertaintyTally) -> UncertaintyTally:
        """Both tallies' points (the budget: this one's)."""
        return UncertaintyTally(self.points + other.points, [a + b for a, b in zip(self.sum_sq, other.sum_sq)],
                                [max(a, b) for a, b in zip(self.largest, other.largest)],
                                self.budget or other.budget)

    @property
    def rms_um(self) -> tuple[float, float, float]:
        """rms u of X, Y, Z over the points, um."""
        return tuple(math.sqrt(s / self.points) * 1e3 if self.points else 0.0 for s in self.sum_sq)

    @property
    def max_um(self) -> tuple[float, float, float]:
        """Largest u of X, Y, Z, um."""
        return tuple(v * 1e3 for v in self.largest)

    def to_dict(self) -> dict:
        """JSON-ready: the budget, the points and the rms and largest u (um) per axis."""
        return {"budget": self.budget, "points": self.points, "rms_um": list(self.rms_um),
                "max_um": list(self.max_um)}


def log_budget(tally: UncertaintyTally, where: str) -> None:
    """The budget and the u over the points, one line each in the log (info)."""
    for row in tally.budget:
        _log.info("%s: uncertainty source %s %s: %s%s", where, row["source"], "on" if row["on"] else "off",
                  row["value"], f" ({row['from']})" if row["from"] else "")
    _log.info("%s: u (k = 1) over %d points: rms %s um, max %s um", where, tally.points,
              ", ".join(f"{v:.3g}" for v in tally.rms_um), ", ".join(f"{v:.3g}" for v in tally.max_um))
