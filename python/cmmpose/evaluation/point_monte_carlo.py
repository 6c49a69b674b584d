"""Monte Carlo (GUM Supplement 1) of compensated points: the check of the
linear propagation ``compensate(..., uncertainty=...)`` performs in the
kernel (docs/uncertainty.md, section 5 "Per point").

Every source of an :class:`cmmpose.point_uncertainty.UncertaintySources` is
drawn from its stated distribution (normal, at its standard uncertainty) and
the points are compensated with the plain kernel, draw by draw:

- the maps: one constant per component (position um, rotation arc-second,
  squareness arc-second) added to every table row of every map of a set,
  and each axis's positioning error scaled by a relative error (ppm) times
  the distance from where it was zeroed (``MapUncertainty.reference_mm``,
  else each table's first position); the tables are rebuilt through
  :class:`cmmpose.ErrorMap`;
- the machine temperature: one shift for all points, K;
- the scanner's scale: (u, v) times (1 + e), e in ppm;
- the scanner's noise: independent normal draws on u and v of every point, um;
- the pose angles (degrees) and mount offset (mm) from their covariance;
- a model's determined parameters from their covariance.

Units: mm, degrees, degrees C in and out (as :func:`cmmpose.compensate`).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from ..compensation import compensate
from ..errormap import CARRIAGES, ErrorMap, ErrorMapSet
from ..errors import InputError, InputTypeError, ModelDomainWarning
from ..model.model import Model
from ..model.point_inputs import point_inputs
from ..point_uncertainty import MapUncertainty, UncertaintySources

__all__ = ["PointsMonteCarlo", "MapDraw", "draw_map_errors", "perturbed_maps", "monte_carlo_points"]

# (N, 6) symmetric entries xx, yy, zz, xy, xz, yz: the rows and columns they take.
_I = np.array([0, 1, 2, 0, 0, 1])
_J = np.array([0, 1, 2, 1, 2, 2])


@dataclass(frozen=True)
class MapDraw:
    """One draw of the maps' component errors (added to every map's tables).

    Attributes
    ----------
    position_um : ndarray (3, 3)
        [carriage X, Y, Z][dx, dy, dz], um.
    rotation_arcsec : ndarray (3, 3)
        [carriage X, Y, Z][ex, ey, ez], arc-seconds.
    squareness_arcsec : ndarray (3,)
        S_xy, S_yz, S_zx, arc-seconds.
    positioning_ppm : ndarray (3,)
        Relative error of X's dx, Y's dy, Z's dz from the reference, ppm.
    """

    position_um: np.ndarray
    rotation_arcsec: np.ndarray
    squareness_arcsec: np.ndarray
    positioning_ppm: np.ndarray


def draw_map_errors(stated: MapUncertainty, rng: np.random.Generator) -> MapDraw:
    """One normal draw of every component at its stated standard uncertainty."""
    return MapDraw(rng.normal(size=(3, 3)) * np.asarray(stated.position_um),
                   rng.normal(size=(3, 3)) * np.asarray(stated.rotation_arcsec),
                   rng.normal(size=3) * np.asarray(stated.squareness_arcsec),
                   rng.normal(size=3) * np.asarray(stated.positioning_ppm))


def _shifted_map(m: ErrorMap, draw: MapDraw, reference) -> ErrorMap:
    """``m`` with ``draw`` added to its tables (thesis units: um, arc-second)."""
    tables = []
    for k, carriage in enumerate(CARRIAGES):
        t = np.array(m.table(carriage), dtype=float)
        t[:, 1:4] += draw.position_um[k]
        t[:, 4:7] += draw.rotation_arcsec[k]
        ref = t[0, 0] if reference is None else reference[k]
        t[:, 1 + k] += draw.positioning_ppm[k] * 1e-3 * (t[:, 0] - ref)  # ppm x mm = 1e-3 um
        tables.append(t)
    out = ErrorMap(*tables, np.add(m.squareness, draw.squareness_arcsec), m.temperature, source=m.source)
    return out if m.kinematics == "thesis" else out.with_kinematics(m.kinematics)


def perturbed_maps(maps: ErrorMap | ErrorMapSet, draw: MapDraw, reference=None) -> ErrorMap | ErrorMapSet:
    """The maps with one draw of their component errors: the same draw on
    every map of a set (the stated uncertainty is the blend's, common to its
    temperatures), the positioning error from ``reference`` (mm per axis;
    None: the first map's table starts, as the kernel takes them)."""
    if isinstance(maps, ErrorMap):
        return _shifted_map(maps, draw, reference)
    if isinstance(maps, ErrorMapSet):
        first = maps.maps
        ref = reference if reference is not None else [lo for lo, _ in first[0].ranges]
        return ErrorMapSet([_shifted_map(m, draw, ref) for m in first])
    raise InputTypeError(f"maps: expected an ErrorMap or ErrorMapSet, got {type(maps).__name__}")


def _normal(cov, rng: np.random.Generator) -> np.ndarray:
    """One draw of N(0, cov) for a positive semi-definite ``cov`` (k, k)."""
    w, v = np.linalg.eigh(np.asarray(cov, dtype=float))
    return v @ (np.sqrt(np.clip(w, 0.0, None)) * rng.normal(size=len(w)))


def _model_parameters(model: Model):
    """The model's determined parameters: ``(spec, index)`` per column and their covariance."""
    cols, names = [], []
    for spec, _ in model.effects:
        u = np.ravel(model.uncertainty.get(spec.name, np.full(spec.size, np.nan)))
        for j, param in enumerate(spec.params):
            if np.isfinite(u[j]) and u[j] > 0:
                cols.append((spec, j))
                names.append(f"{spec.name}.{param}")
    return cols, (model.parameter_covariance(names) if names else np.zeros((0, 0)))


@dataclass(frozen=True)
class PointsMonteCarlo:
    """The spread of compensated points over Monte Carlo draws.

    Attributes
    ----------
    nominal : ndarray (N, 3)
        The points compensated with every input at its stated value, mm.
    mean : ndarray (N, 3)
        Mean of the draws, mm.
    covariance : ndarray (N, 6)
        Sample covariance over the draws (M - 1 degrees of freedom), entries
        xx, yy, zz, xy, xz, yz, mm^2.
    draws : int
        M.
    features : ndarray (M, ...) or None
        What ``feature`` returned for each draw (e.g. a fitted centre, mm).
    """

    nominal: np.ndarray
    mean: np.ndarray
    covariance: np.ndarray
    draws: int
    features: np.ndarray | None = None

    @property
    def u(self) -> np.ndarray:
        """Standard deviation of X, Y, Z over the draws, mm (N, 3)."""
        return np.sqrt(self.covariance[:, :3])

    @property
    def relative_scatter(self) -> float:
        """The Monte Carlo's own relative standard error of a standard
        deviation, 1 / sqrt(2 (M - 1)) (normal draws)."""
        return float(1.0 / np.sqrt(2.0 * (self.draws - 1)))


def monte_carlo_points(uv, scales, maps, pose, offset, temperature=None, *, sources: UncertaintySources,
                       draws: int = 2000, rng=None, feature: Callable | None = None,
                       columns: dict | None = None) -> PointsMonteCarlo:
    """Compensate the points ``draws`` times, each with one draw of every
    source switched on in ``sources``, and return the spread per point.

    Parameters
    ----------
    uv, scales, maps, pose, offset, temperature
        As :func:`cmmpose.compensate` (mm, degrees, C); ``maps`` an
        ErrorMap, ErrorMapSet or Model. The points are compensated without
        uncertainty, ``out_of_range='raise'``.
    sources : UncertaintySources
        What to draw (as ``compensate(..., uncertainty=sources)`` propagates
        it): the maps' stated uncertainty (``sources.map``, else the maps'
        own), temperature K, scanner scale ppm and noise um, one pose
        uncertainty, a model's parameter covariance.
    draws : int
        M, at least 2. The relative standard error of a standard deviation
        from M normal draws is about 1 / sqrt(2 (M - 1)): 1.6 % for 2000.
    rng : numpy Generator or int, optional
        The random source (a seed: reproducible).
    feature : callable, optional
        ``feature(xyz) -> array``, called on each draw's points (N, 3 mm):
        e.g. ``lambda x: cmmpose.fit_sphere(x, r).centre``.
    columns : dict, optional
        A model's point columns (as :func:`cmmpose.compensate`).

    Returns
    -------
    PointsMonteCarlo
    """
    if not isinstance(sources, UncertaintySources):
        raise InputTypeError(f"sources: expected an UncertaintySources, got {type(sources).__name__}")
    if isinstance(draws, bool) or not isinstance(draws, (int, np.integer)) or draws < 2:
        raise InputError(f"draws: expected an integer >= 2, got {draws!r}")
    if sources.pose is not None and len(sources.pose) != 1:
        raise InputError("sources.pose: one pose uncertainty (the points are taken at one pose)")
    rng = np.random.default_rng(rng)
    uv = np.asarray(uv, dtype=float)
    pose, offset = np.asarray(tuple(pose), dtype=float), np.asarray(tuple(offset), dtype=float)
    plain = maps.error_maps if isinstance(maps, Model) else maps
    stated = sources.stated_map(maps)
    params, pcov = _model_parameters(maps) if isinstance(maps, Model) and sources.model and sources.on("model") \
        else ([], np.zeros((0, 0)))
    p = sources.pose[0] if sources.pose is not None and sources.on("pose") else None
    noise = np.asarray(sources.scanner_noise_um) * 1e-3 if sources.on("scanner_noise") else np.zeros(2)
    scale = sources.scanner_scale_ppm * 1e-6 if sources.on("scanner_scale") else 0.0
    u_t = sources.temperature_k if sources.on("temperature") and temperature is not None else 0.0
    nominal = compensate(uv, scales, maps, pose, offset, temperature, columns=columns)
    run = lambda m, uv_, a, o, t: _compensate(m, uv_, scales, a, o, t, columns)  # noqa: E731
    s1, s2, feats = np.zeros_like(nominal), np.zeros((len(nominal), 6)), []
    with warnings.catch_warnings():  # a model's domain notes: said once, for the nominal points
        warnings.simplefilter("ignore", ModelDomainWarning)
        for _ in range(draws):
            m = plain if stated is None else perturbed_maps(plain, draw_map_errors(stated, rng), stated.reference_mm)
            if isinstance(maps, Model):
                m = _drawn_model(maps, m, params, pcov, rng)
            uv_m = uv * (1.0 + scale * rng.normal()) if scale else uv
            if noise.any():
                uv_m = uv_m + rng.normal(size=uv.shape) * noise
            a = pose if p is None else pose + _normal(p.angle_covariance_deg2, rng)
            o = offset if p is None else offset + _normal(p.offset_covariance_mm2, rng)
            t = temperature if not u_t else np.asarray(temperature, dtype=float) + u_t * rng.normal()
            x = run(m, uv_m, a, o, t)
            d = x - nominal
            s1 += d
            s2 += d[:, _I] * d[:, _J]
            if feature is not None:
                feats.append(np.asarray(feature(x), dtype=float))
    mean_d = s1 / draws
    cov = (s2 - draws * mean_d[:, _I] * mean_d[:, _J]) / (draws - 1)
    return PointsMonteCarlo(nominal, nominal + mean_d, cov, int(draws), np.array(feats) if feats else None)


def _compensate(m, uv, scales, pose, offset, temperature, columns) -> np.ndarray:
    """One draw's points: a model through its kernel without its domain checks
    (said once, for the nominal points), maps as :func:`compensate` does."""
    if not isinstance(m, Model):
        return compensate(uv, scales, m, pose, offset, temperature)
    temps, scalar = (temperature, None) if temperature is not None and np.ndim(temperature) > 0 else (None, temperature)
    inputs = point_inputs(m, np.ascontiguousarray(uv, dtype=float), np.ascontiguousarray(scales, dtype=float),
                          tuple(pose), tuple(offset), scalar, temps, dict(columns or {}), "points")
    return m.compensate(inputs)


def _drawn_model(model: Model, maps, params, pcov, rng: np.random.Generator) -> Model:
    """``model`` on ``maps`` with one draw of its determined parameters."""
    out = replace(model, maps=maps)
    if not params:
        return out
    delta = _normal(pcov, rng)
    values = {spec.name: np.array(v, dtype=float) for spec, v in model.effects}
    for (spec, j), d in zip(params, delta):
        values[spec.name][j] += d
    for spec, _ in model.effects:
        out = out.with_values(spec, values[spec.name])
    return out
