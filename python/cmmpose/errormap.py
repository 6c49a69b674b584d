"""Error maps: the 21 geometric component errors of a CMM (thesis Table 6) at
one temperature (``ErrorMap``) or several (``ErrorMapSet``).

Tables are in the thesis's units: position mm, deltas um, angles arc-second.
The Rust core converts them to mm and rad once, when the map is built.
"""

from __future__ import annotations

from importlib import resources
from os import PathLike

import math
from numbers import Real

import numpy as np

import warnings

from . import _core
from .formats import mapformats
from ._arrays import as_rows, as_triple
from .temperature import TEMPERATURE_TOLERANCE, TemperaturePolicy
from .errors import InputError, InputTypeError, MapTemperatureWarning, warn_clamped
from .kernel_report import KernelReport
from .point_uncertainty import DETAILS, MapUncertainty, UncertainPoints, UncertaintySources
from .pose import digitizer


#: Carriages in kinematic order.
CARRIAGES = ("X", "Y", "Z")
#: Columns of a carriage table.
TABLE_COLUMNS = ("position_mm", "dx_um", "dy_um", "dz_um", "ex_arcsec", "ey_arcsec", "ez_arcsec")


def _checked_uncertainty(uncertainty):
    if uncertainty is not None and not isinstance(uncertainty, MapUncertainty):
        raise InputTypeError(f"uncertainty: expected a MapUncertainty, got {type(uncertainty).__name__}")
    return uncertainty


def scalar_temperature(value, name: str = "temperature", *, finite: bool = True) -> float:
    """``value`` as one temperature (degrees C, float).

    Raises ``InputTypeError`` naming ``name`` for anything but a real number
    (text, booleans, None: ``True`` is not 1 C) and, with ``finite``,
    ``InputError`` for NaN or infinity (without, they are returned for the
    caller's NaN policy).
    """
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (Real, np.floating, np.integer)):
        raise InputTypeError(f"{name}: expected a temperature in degrees C (a number), "
                             f"got {type(value).__name__} {value!r}")
    t = float(value)
    if finite and not math.isfinite(t):
        raise InputError(f"{name}: {t} C is not finite; give the temperature in degrees C")
    return t


def data_path(*parts: str):
    """Path of a file bundled in the installed package's ``data`` folder."""
    return resources.files("cmmpose").joinpath("data", *parts)


def _detail(detail: str) -> str:
    if detail not in DETAILS:
        raise InputError(f"detail: {detail!r} is not one of {', '.join(DETAILS)}")
    return detail


class AppliedMaps:
    """Maps alone as a machine model (:class:`cmmpose.model.MachineModel`):
    what compensation and evaluation call on an :class:`ErrorMap`, an
    :class:`ErrorMapSet` or a found :class:`cmmpose.Model` alike. Maps hold
    no effects, no parameter uncertainties, no temperature policy of their
    own and no training domain."""

    __slots__ = ()
    #: Effects beyond the maps (a found model's), with their values: none.
    effects: tuple = ()
    #: Alternatives a diagnosis could not tell from a held effect: none.
    alternatives: tuple = ()
    #: Where the model was fitted (:class:`cmmpose.model.Domain`): maps are measured, not fitted.
    domain = None
    #: Whether the model reads a run's own inputs (its thermocouple log) itself: maps are given a temperature.
    reads_run = False
    #: Whether the model reads each sweep's velocity (latency): then a point file is compensated sweep by sweep.
    reads_sweeps = False

    @property
    def error_maps(self):
        """The maps under the model: these maps."""
        return self

    @property
    def uncertainty(self) -> dict:
        """Standard uncertainty of each effect's parameters: none."""
        return {}

    @property
    def expansion_ppm_per_kelvin(self) -> float:
        """The artefact expansion the model holds, ppm/K: none."""
        return 0.0

    def with_policy(self, **policy):
        """Maps hold no temperature policy: the caller's is passed to each call."""
        return self

    def without_effects(self):
        """The plain maps: these maps."""
        return self

    def compensate_points(self, uv, scales, pose, offset, temperature=None, *, policy: TemperaturePolicy | None = None,
                          nan_policy: str = "raise", out=None, columns=None, where: str = "points",
                          once: set | None = None):
        """Compensated X, Y, Z (mm) of points taken at one pose, and the
        kernel's report (a dict); arguments as :func:`cmmpose.compensate`
        takes them once checked (float64 rows; ``temperature`` C, one value,
        one per point, or None for a single map; ``policy`` the
        :class:`cmmpose.TemperaturePolicy`, None its defaults, handed to the
        kernel whole). ``columns``, ``where`` and ``once`` are a model's (its
        effects' inputs, the data's name, the warnings already given): maps
        read none of them."""
        return _core.compensate(uv, scales, self._core, digitizer(pose, offset), policy or TemperaturePolicy(),
                                temperature, nan_policy, out)

    def compensate_points_uncertainty(self, uv, scales, pose, offset, temperature=None, *,
                                      sources: UncertaintySources, detail: str = "standard",
                                      policy: TemperaturePolicy | None = None, nan_policy: str = "raise",
                                      columns=None, where: str = "points", once: set | None = None):
        """As :meth:`compensate_points`, and each point's uncertainty from
        ``sources`` in the same kernel pass: ``(UncertainPoints, report)``.
        ``detail`` is one of ``DETAILS`` (cmmpose.point_uncertainty)."""
        n = len(scales)
        inputs = None
        if isinstance(self, ErrorMap):
            if temperature is not None:
                raise InputError("temperature: only meaningful with an ErrorMapSet; an ErrorMap has one temperature")
        elif temperature is None:
            raise InputError("temperature: required with an ErrorMapSet (a float or an (N,) array, C)")
        else:
            t = np.full(n, float(temperature)) if np.ndim(temperature) == 0 else temperature
            inputs = {"temperature": t}
        kernel = sources.kernel_sources(self, 1)
        xyz, rows, report = _core.compensate_uncertainty(
            uv, scales, self._core, [digitizer(pose, offset)], policy or TemperaturePolicy(), kernel,
            inputs=inputs, nan_policy=nan_policy, detail=_detail(detail))
        return UncertainPoints.from_kernel(xyz, rows, sources), report

    def compensate_run(self, run, temperature=None, *, policy: TemperaturePolicy | None = None,
                       reports: list | None = None, compare=None, once: set | None = None):
        """All points of ``run`` in machine coordinates (N, 3 mm), pose by
        pose, at ``temperature`` (C: one value, one per point, or None for a
        single map); each pose's kernel report (:class:`KernelReport`) is
        appended to ``reports``, and what it says is warned
        (``ClampWarning``). ``compare`` and ``once`` are a model's."""
        out = np.empty((run.n_points, 3))
        for rows, pose, offset in run.points_by_pose():
            t = temperature if temperature is None or np.ndim(temperature) == 0 else \
                np.ascontiguousarray(temperature[rows], dtype=float)
            out[rows], raw = self.compensate_points(np.ascontiguousarray(run.uv[rows]),
                                                    np.ascontiguousarray(run.scales[rows]), pose, offset, t,
                                                    policy=policy)
            report = KernelReport(**raw)
            warn_clamped(report)
            if reports is not None:
                reports.append(report)
        return out




def _map_temperature(value) -> float | None:
    """A map's temperature label, C: None, or a real number (never text such as "22", converted in silence,
    nor a boolean); its finiteness is the core's check."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, Real):
        raise InputTypeError(f"temperature: expected a number of degrees C or None, got {type(value).__name__} "
                             f"{value!r}"[:200], what="temperature")
    return float(value)  # a non-finite one: the core's one check (MapError "temperature: nan C is not finite")

class ErrorMap(AppliedMaps):
    """The component errors of a CMM at one temperature.

    Parameters
    ----------
    x, y, z : array_like, shape (n, 7)
        Table of each carriage: position (mm, strictly increasing), delta_x,
        delta_y, delta_z (um), eps_x, eps_y, eps_z (arc-second).
    squareness : sequence of 3 float
        S_xy, S_yz, S_zx in arc-seconds, sign convention of thesis Table 7 and
        eq. 11 (e_x contains -E*S_xy).
    temperature : float, optional
        Temperature of the machine when the map was measured, degrees C.
    source : str, optional
        Where the map came from (file, table), kept for reports.
    uncertainty : MapUncertainty, optional
        The stated standard uncertainty of the map's components
        (:class:`cmmpose.point_uncertainty.MapUncertainty`), propagated to
        each compensated point (``compensate(..., uncertainty=True)``).
    """

    __slots__ = ("_core", "source", "stated_uncertainty")

    def __init__(self, x, y, z, squareness, temperature: float | None = None, source: str | None = None,
                 uncertainty: MapUncertainty | None = None):
        tables = [as_rows(f"{c.lower()} table", t, 7) for c, t in zip(CARRIAGES, (x, y, z))]
        sq = as_triple("squareness", squareness)
        self._core = _core.ErrorMap(*tables, sq, _map_temperature(temperature))
        self.source = source
        self.stated_uncertainty = _checked_uncertainty(uncertainty)

    @classmethod
    def _wrap(cls, core_map, source: str | None = None, uncertainty: MapUncertainty | None = None) -> ErrorMap:
        obj = cls.__new__(cls)
        obj._core = core_map
        obj.source = source
        obj.stated_uncertainty = uncertainty
        return obj

    def with_uncertainty(self, uncertainty: MapUncertainty | None) -> ErrorMap:
        """The same map stating ``uncertainty`` for its components."""
        return ErrorMap._wrap(self._core, self.source, _checked_uncertainty(uncertainty))

    # -- constructors from files -------------------------------------------------
    @classmethod
    def read(cls, path: str | PathLike, format: str = "csv", **options) -> ErrorMap:
        """Read a map file: by default the canonical CSV format (docs/formats.md).

        ``format`` names a registered map file format (:mod:`cmmpose.formats.mapformats`:
        ``'csv'``, ``'controller'``, ``'iso230-2'``, ``'linuxcnc'``), or ``'auto'`` for the one that
        recognises the file; ``options`` go to that format's reader. A format of one file per axis
        (``'linuxcnc'``) reads a mapping axis -> file, or the files of a folder.
        """
        return mapformats.read(path, format, **options)

    def write(self, path: str | PathLike, format: str = "csv") -> None:
        """Write the map, by default in the canonical CSV format (docs/formats.md); a format of one
        file per axis (``'linuxcnc'``) writes into the folder ``path``."""
        mapformats.write(self, path, format)

    @classmethod
    def read_controller_file(cls, path: str | PathLike, temperature: float | None = None) -> ErrorMap:
        """Read a controller error file in the layout of thesis Appendix B."""
        return mapformats.read(path, "controller", temperature=temperature)

    @classmethod
    def appendix_b(cls) -> ErrorMap:
        """The controller map of thesis Appendix B (``errors_1102.txt``), measured at 22 C."""
        with resources.as_file(data_path("errors_1102.txt")) as p:
            return cls.read_controller_file(p, temperature=22.0)

    @classmethod
    def zero(cls, ranges=((0.0, 900.0), (0.0, 550.0), (-500.0, 0.0)), temperature: float | None = None) -> ErrorMap:
        """A map with every error zero over ``ranges`` ((lo, hi) mm per carriage)."""
        tables = [np.array([[lo] + [0.0] * 6, [hi] + [0.0] * 6]) for lo, hi in ranges]
        return cls(*tables, (0.0, 0.0, 0.0), temperature, source="zero map")

    # -- contents ----------------------------------------------------------------
    def table(self, carriage: str) -> np.ndarray:
        """Table of ``carriage`` ('X', 'Y' or 'Z'), shape (n, 7), thesis units (see ``TABLE_COLUMNS``)."""
        return self._core.table(carriage)

    @property
    def squareness(self) -> tuple[float, float, float]:
        """(S_xy, S_yz, S_zx) in arc-seconds."""
        return self._core.squareness

    @property
    def temperature(self) -> float | None:
        """Map temperature in degrees C, or None."""
        return self._core.temperature

    @property
    def ranges(self) -> list[tuple[float, float]]:
        """Covered scale range (lo, hi) in mm for X, Y, Z."""
        return self._core.ranges

    @property
    def kinematics(self) -> str:
        """The machine configuration the map is for: how the carriages are
        stacked, which decides over which arms their angular errors act (a
        name of :func:`cmmpose.machine.configurations`; ``'thesis'``, the
        X-Y-Z moving bridge, unless set)."""
        return self._core.kinematics

    def with_kinematics(self, kinematics: str) -> ErrorMap:
        """The same map for a machine configured as ``kinematics`` (a name of
        :func:`cmmpose.machine.configurations`)."""
        if not isinstance(kinematics, str):
            raise InputError(f"kinematics: expected a configuration name, got {kinematics!r}")
        return ErrorMap._wrap(self._core.with_kinematics(kinematics), self.source, self.stated_uncertainty)

    def with_temperature(self, temperature: float | None) -> ErrorMap:
        """The same map labelled with another temperature (C)."""
        return ErrorMap._wrap(self._core.with_temperature(_map_temperature(temperature)), self.source,
                              self.stated_uncertainty)

    # -- the model ---------------------------------------------------------------
    def position_error(self, scales, *, out_of_range: str = "raise", nan_policy: str = "raise") -> np.ndarray:
        """Position error e(S) of eqs. 11-13.

        Parameters
        ----------
        scales : array_like, shape (N, 3)
            Scale readings D, E, F in mm.
        out_of_range : {'raise', 'clamp'}
            Readings outside the tables raise ``OutOfRangeError`` or are clamped
            to the table ends (with a ``ClampWarning`` giving the count).
        nan_policy : {'raise', 'propagate'}
            NaN rows raise ``InputError`` naming the first, or give NaN rows.

        Returns
        -------
        ndarray, shape (N, 3)
            e_x, e_y, e_z in mm.
        """
        out, report = self._core.position_error(as_rows("scales", scales, 3), out_of_range, nan_policy)
        warn_clamped(KernelReport(**report))
        return out

    def rotation_error(self, scales, *, out_of_range: str = "raise", nan_policy: str = "raise") -> np.ndarray:
        """Rotation R(S) of eqs. 29-32 (right-handed X_p, docs/conventions.md).

        Parameters
        ----------
        scales : array_like, shape (N, 3)
            Scale readings D, E, F in mm.
        out_of_range, nan_policy : str
            As in :meth:`position_error`.

        Returns
        -------
        ndarray, shape (N, 3, 3)
            Rotation matrices whose columns are X_p, Y_p, Z_p (dimensionless).
        """
        out, report = self._core.rotation_error(as_rows("scales", scales, 3), out_of_range, nan_policy)
        warn_clamped(KernelReport(**report))
        return out

    def provenance(self) -> dict:
        """What compensated, for an evaluation's JSON."""
        return {"kind": "map", "temperature_C": self.temperature}

    def __eq__(self, other: object) -> bool:
        return isinstance(other, ErrorMap) and self._core == other._core

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        t = "no temperature" if self.temperature is None else f"{self.temperature:g} C"
        rng = ", ".join(f"{c} {lo:g}..{hi:g}" for c, (lo, hi) in zip(CARRIAGES, self.ranges))
        sq = ", ".join(f"{v:g}" for v in self.squareness)
        src = f", source={self.source!r}" if self.source else ""
        kin = "" if self.kinematics == "thesis" else f"; {self.kinematics}"
        return f"ErrorMap({t}; {rng} mm; squareness {sq} a-s{kin}{src})"


class ErrorMapSet(AppliedMaps):
    """Error maps at several temperatures, blended linearly in temperature for
    all 21 components (thesis section 6.4).

    Parameters
    ----------
    maps : sequence of ErrorMap
        Maps with distinct temperatures (C), in any order. Grids may differ;
        blending uses the union of the grids over their common range.
    """

    __slots__ = ("_core", "_sources", "_uncertainty")

    def __init__(self, maps):
        maps = list(maps)
        if not all(isinstance(m, ErrorMap) for m in maps):
            raise InputError("maps: expected a sequence of ErrorMap")
        kinds = list(dict.fromkeys(m.kinematics for m in maps))
        if len(kinds) > 1:
            which = "; ".join(f"{k!r}: " + ", ".join("no temperature" if m.temperature is None
                                                    else f"{m.temperature:g} C" for m in maps if m.kinematics == k)
                              for k in kinds)
            raise InputError(f"maps: the maps are for differently configured machines ({which}); give maps of one "
                             "configuration (ErrorMap.with_kinematics)")
        self._core = _core.ErrorMapSet([m._core for m in maps])
        by_t = {m.temperature: (m.source, m.stated_uncertainty) for m in maps}
        self._sources = [by_t[t][0] for t in self._core.temperatures]
        self._uncertainty = [by_t[t][1] for t in self._core.temperatures]

    @property
    def stated_uncertainty(self) -> MapUncertainty | None:
        """The maps' stated uncertainty for the blend: the larger per
        component over the maps that state one (None if none does)."""
        stated = [u for u in self._uncertainty if u is not None]
        out = stated[0] if stated else None
        for u in stated[1:]:
            out = out.combined(u)
        return out

    @classmethod
    def thesis(cls) -> ErrorMapSet:
        """The thesis maps at 20, 25 and 30 C (Tables 8-16, squareness Table 7),
        stating the thesis's measurement uncertainty (:meth:`MapUncertainty.thesis`)."""
        maps = []
        for t in (20, 25, 30):
            with resources.as_file(data_path("maps", f"thesis_{t}C.csv")) as p:
                maps.append(ErrorMap.read(p).with_uncertainty(MapUncertainty.thesis()))
        return cls(maps)

    @property
    def temperatures(self) -> list[float]:
        """Map temperatures in degrees C, ascending."""
        return self._core.temperatures

    @property
    def maps(self) -> list[ErrorMap]:
        """The maps, sorted by temperature."""
        return [ErrorMap._wrap(m, s, u) for m, s, u in zip(self._core.maps, self._sources, self._uncertainty)]

    @property
    def kinematics(self) -> str:
        """The machine configuration of the set's maps (see ``ErrorMap.kinematics``)."""
        return self._core.kinematics

    def with_uncertainty(self, uncertainty: MapUncertainty | None) -> ErrorMapSet:
        """The same set, every map stating ``uncertainty`` for its components."""
        return ErrorMapSet([m.with_uncertainty(uncertainty) for m in self.maps])

    def with_kinematics(self, kinematics: str) -> ErrorMapSet:
        """The same set for a machine configured as ``kinematics``."""
        if not isinstance(kinematics, str):
            raise InputError(f"kinematics: expected a configuration name, got {kinematics!r}")
        out = object.__new__(ErrorMapSet)
        out._core = self._core.with_kinematics(kinematics)
        out._sources = list(self._sources)
        out._uncertainty = list(self._uncertainty)
        return out

    def at(self, temperature: float, *, out_of_range: str = "raise",
           temperature_tolerance: float = TEMPERATURE_TOLERANCE) -> ErrorMap:
        """The map at ``temperature`` (C), linear between the two closest maps.

        Within ``temperature_tolerance`` (K) outside the set's range: the end
        map. Beyond it: ``OutOfRangeError``, the end map with
        ``out_of_range='clamp'``, or the end maps' slope carried on with
        ``'extrapolate'`` (cmmpose.policy).
        """
        t = scalar_temperature(temperature)
        policy = TemperaturePolicy(out_of_range=out_of_range, temperature_tolerance=temperature_tolerance)
        return ErrorMap._wrap(self._core.at(t, policy), source=f"blend at {t:g} C", uncertainty=self.stated_uncertainty)

    def __len__(self) -> int:
        return len(self.temperatures)

    def provenance(self) -> dict:
        """What compensated, for an evaluation's JSON."""
        return {"kind": "set", "temperatures_C": [float(x) for x in self.temperatures]}

    def __eq__(self, other: object) -> bool:
        # Equal maps at equal temperatures, the same machine configuration.
        return (isinstance(other, ErrorMapSet) and self.kinematics == other.kinematics
                and self.temperatures == other.temperatures
                and all(a._core == b._core for a, b in zip(self.maps, other.maps)))

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        kin = "" if self.kinematics == "thesis" else f", kinematics={self.kinematics!r}"
        return f"ErrorMapSet(temperatures={[float(t) for t in self.temperatures]}{kin})"


def warn_single_map(error_map: ErrorMap, temperature, tolerance: float = TEMPERATURE_TOLERANCE) -> str | None:
    """One map holds at one temperature: say so (a ``MapTemperatureWarning``,
    whose text is also returned) when the given temperatures (C) are not its
    own within ``tolerance`` (K), instead of ignoring them silently."""
    t = np.asarray(temperature, dtype=float)
    if t.size == 0 or not np.all(np.isfinite(t)):
        return None
    lo, hi = float(t.min()), float(t.max())
    span = f"{lo:.2f} C" if hi - lo < 0.005 else f"{lo:.2f}..{hi:.2f} C"
    own = error_map.temperature
    if own is None:
        msg = f"a single map of unstated temperature was used for points at {span}: its errors are taken as they are"
    elif max(abs(lo - own), abs(hi - own)) > tolerance:
        msg = (f"a single map at {own:g} C was used for points at {span}: its errors are taken at {own:g} C "
               f"(give maps at several temperatures to follow the machine)")
    else:
        return None
    warnings.warn(msg, MapTemperatureWarning, stacklevel=3)
    return msg
