"""The alignment library: one alignment record per indexed trunnion pose, in a
JSON file. The trunnion repositions the scanner repeatably at each index stop
(thesis section 4.4: "any coordinate frame transformation that is computed can
be stored in an alignment file to be recalled later"), so a pose is aligned
once and recalled by name.

File format (UTF-8 JSON, docs/calibration.md)::

    {"format": "cmmpose-alignment-library", "version": 1,
     "units": {...},
     "poses": {"A90B90": {"pose": [90, 90, 0], "reading": [...], ...}, ...}}
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from ..atomicfile import ensure_folder, locked_update, write_text
from ..errors import InputError, InputTypeError, read_input_text
from ..pose import MountOffset, Pose, pose_tuple
from ..errors import CalibrationError
from .._validate import digits_cut, finite, triple
from ..schemas import validate
from ..schemas import no_repeats
from ..schemas.alignments import FIELDS as _FIELDS, LIBRARY_FORMAT, LIBRARY_VERSION
from .alignment import CalibratedPose, MountOffsetFit, ReferenceReading

__all__ = ["AlignmentRecord", "AlignmentLibrary", "LIBRARY_FORMAT", "LIBRARY_VERSION"]

UNITS = {
    "pose": "degree (alpha, beta, gamma, Euler 3-1-3)",
    "pose_uncertainty": "degree",
    "pose_covariance": "degree^2",
    "reading": "mm (D0, E0, F0)",
    "reading_uncertainty": "mm (the reading's own: sphere fit and stated terms, not the pose's)",
    "reading_covariance": "mm^2 (the reading's own, as reading_uncertainty)",
    "pose_jacobian": "mm/degree (d reading / d alpha, beta, gamma; columns)",
    "position": "mm (the mount point's position with the laser origin at the sphere centre)",
    "lever": "1 (d sphere centre / d(-offset))",
    "offset": "mm (U1, V1, W1)",
    "offset_uncertainty": "mm",
    "offset_covariance": "mm^2 (U1, V1, W1: the mount-offset fit's, stored by `calibrate offset --store`)",
    "temperature": "degree C",
    "residuals": "mm",
    "date": "ISO 8601",
}


def _now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


#: The top-level keys of a library file.
_DOC_KEYS = ("format", "version", "units", "poses")


def _unit(text) -> str:
    """The unit of a ``units`` entry: its first word (``'degree (alpha, ...)'`` -> ``'degree'``)."""
    return text.split()[0] if isinstance(text, str) and text.split() else repr(text)


def _check_units(path, units) -> None:
    """The file's ``units`` block names the units this module writes (``UNITS``),
    or is absent: values in radians or metres would otherwise be read as
    degrees or mm in silence. An unknown entry is refused (a typo)."""
    if units is None:
        return
    if not isinstance(units, dict):
        raise CalibrationError(f"{path}: \"units\" must be an object of field -> unit, got {units!r}")
    for key, text in units.items():
        if key not in UNITS:
            raise CalibrationError(f"{path}: units: unknown field {key!r} (known: {', '.join(UNITS)})")
        if _unit(text) != _unit(UNITS[key]):
            raise CalibrationError(f"{path}: units.{key} is {text!r}; an alignment library holds {key} in "
                                   f"{_unit(UNITS[key])} only ({UNITS[key]}): convert the values and the unit")


def _is_finite_number(x) -> bool:
    """Whether ``x`` is a finite number (not a boolean; an integer beyond any float is not finite)."""
    try:
        finite("x", x, error=CalibrationError)
    except CalibrationError:
        return False
    return True


def _no_text(where: str, name: str, value) -> None:
    """Refuse text where numbers belong (``"90"`` would otherwise read as 90)."""
    if isinstance(value, (str, bytes)) or any(isinstance(x, (str, bytes)) for x in np.ravel(
            np.asarray(value, dtype=object))):
        raise CalibrationError(f"{where}: {name} must be numbers, not text, got {digits_cut(repr(value))}")


def _triple(where: str, name: str, value, *, optional: bool = False, nonnegative: bool = False):
    if value is None and optional:
        return None
    _no_text(where, name, value)
    return triple(f"{where}: {name}", value, nonnegative=nonnegative, error=CalibrationError)


def _matrix(where: str, name: str, value, *, covariance: bool = False):
    """A 3 x 3 matrix as a tuple of row tuples (None stays None); a covariance
    must be symmetric positive semi-definite."""
    if value is None:
        return None
    _no_text(where, name, value)
    try:
        m = np.array(value, dtype=float)
    except (TypeError, ValueError, OverflowError):  # an integer beyond any float too
        raise CalibrationError(f"{where}: {name} must be a 3 x 3 matrix of numbers, got {digits_cut(repr(value))}") from None
    if m.shape != (3, 3) or not np.isfinite(m).all():
        raise CalibrationError(f"{where}: {name} must be a finite 3 x 3 matrix, got {digits_cut(repr(value))}")
    if covariance:
        scale = max(float(np.abs(m).max()), 1e-300)
        if np.abs(m - m.T).max() > 1e-9 * scale or np.linalg.eigvalsh((m + m.T) / 2).min() < -1e-9 * scale:
            raise CalibrationError(f"{where}: {name} must be symmetric positive semi-definite, got {m.tolist()}")
        m = (m + m.T) / 2
    return tuple(tuple(float(x) for x in row) for row in m)


def _agree(where: str, name: str, uncertainty, covariance):
    """The standard uncertainties implied by ``covariance`` (if given), checked
    against ``uncertainty`` (if also given): one number, one meaning."""
    if covariance is None:
        return uncertainty
    implied = tuple(math.sqrt(max(covariance[i][i], 0.0)) for i in range(3))
    if uncertainty is not None and not np.allclose(uncertainty, implied, rtol=1e-6, atol=1e-15):
        raise CalibrationError(f"{where}: {name}_uncertainty {list(uncertainty)} disagrees with the square roots "
                               f"of the diagonal of {name}_covariance {list(implied)}")
    return implied


@dataclass(frozen=True)
class AlignmentRecord:
    """The stored alignment of one trunnion pose.

    Parameters
    ----------
    pose : sequence of 3 float
        alpha, beta, gamma, degrees.
    reading : sequence of 3 float
        D0, E0, F0: the scale reading at which the laser origin sits at the
        reference-sphere centre, mm.
    offset : sequence of 3 float
        Mount offset U1, V1, W1, mm.
    pose_uncertainty, reading_uncertainty, offset_uncertainty : sequence of 3 float, optional
        Standard uncertainties, degrees and mm. ``reading_uncertainty`` is
        the reading's own (the sphere fit's and any stated terms): the pose's
        share is not in it but in ``pose_covariance`` acting through
        ``pose_jacobian``, so that the mount-offset fit counts it once, with
        its correlations.
    pose_covariance : 3 x 3 nested sequence of float, optional
        Covariance of (alpha, beta, gamma), degree^2 (gamma is correlated with
        alpha and beta through the plane scan).
    reading_covariance : 3 x 3 nested sequence of float, optional
        Covariance of D0, E0, F0 without the pose term, mm^2.
    pose_jacobian : 3 x 3 nested sequence of float, optional
        d (D0, E0, F0) / d (alpha, beta, gamma), mm/degree.
    offset_covariance : 3 x 3 nested sequence of float, optional
        Covariance of the mount offset, mm^2 (the mount-offset fit's:
        :meth:`AlignmentLibrary.store_offset`).
    position : sequence of 3 float, optional
        The mount point's position with the laser origin at the sphere centre,
        mm (``ReferenceReading.position``; equals ``reading`` without a map).
    lever : 3 x 3 nested sequence of float, optional
        d sphere centre / d(-offset) (``ReferenceReading.lever``), 1.
    temperature : float, optional
        Machine temperature during the alignment, C.
    date : str
        When it was aligned, ISO 8601 (default: now, UTC).
    residuals : dict of str to float
        Fit residuals worth keeping, mm (e.g. ``vernier_rms``, ``plane_rms``,
        ``sphere_rms``, ``offset_max_residual``).
    note : str
        Free text.
    """

    pose: tuple
    reading: tuple
    offset: tuple
    pose_uncertainty: tuple | None = None
    reading_uncertainty: tuple | None = None
    offset_uncertainty: tuple | None = None
    temperature: float | None = None
    date: str = field(default_factory=_now)
    residuals: dict = field(default_factory=dict)
    note: str = ""
    pose_covariance: tuple | None = None
    reading_covariance: tuple | None = None
    pose_jacobian: tuple | None = None
    position: tuple | None = None
    lever: tuple | None = None
    offset_covariance: tuple | None = None

    def __post_init__(self):
        raw = {f: getattr(self, f) for f in _FIELDS}
        checked = AlignmentRecord._checked(raw, "record")
        for k, v in checked.items():
            object.__setattr__(self, k, v)

    # -- conversion --------------------------------------------------------------
    def to_dict(self) -> dict:
        """Plain JSON-ready dict."""
        lst = lambda t: None if t is None else [float(x) for x in t]  # noqa: E731
        mat = lambda m: None if m is None else [lst(row) for row in m]  # noqa: E731
        return {
            "pose": lst(self.pose), "reading": lst(self.reading), "offset": lst(self.offset),
            "pose_uncertainty": lst(self.pose_uncertainty), "reading_uncertainty": lst(self.reading_uncertainty),
            "offset_uncertainty": lst(self.offset_uncertainty),
            "temperature": self.temperature, "date": self.date, "residuals": dict(self.residuals),
            "note": self.note,
            "pose_covariance": mat(self.pose_covariance), "reading_covariance": mat(self.reading_covariance),
            "pose_jacobian": mat(self.pose_jacobian), "position": lst(self.position), "lever": mat(self.lever),
            "offset_covariance": mat(self.offset_covariance),
        }

    @staticmethod
    def _checked(d, where: str) -> dict:
        if not isinstance(d, dict):
            raise CalibrationError(f"{where}: expected an object, got {type(d).__name__}")
        missing = [k for k in ("pose", "reading", "offset") if k not in d]
        if missing:
            raise CalibrationError(f"{where}: missing field(s) {', '.join(missing)}")
        unknown = sorted(set(d) - set(_FIELDS))
        if unknown:
            raise CalibrationError(f"{where}: unknown field(s) {', '.join(unknown)}")
        out = {
            "pose": _triple(where, "pose", d["pose"]),
            "reading": _triple(where, "reading", d["reading"]),
            "offset": _triple(where, "offset", d["offset"]),
        }
        for k in ("pose_uncertainty", "reading_uncertainty", "offset_uncertainty"):
            out[k] = _triple(where, k, d.get(k), optional=True, nonnegative=True)
        for k in ("pose", "reading", "offset"):
            out[f"{k}_covariance"] = _matrix(where, f"{k}_covariance", d.get(f"{k}_covariance"), covariance=True)
            out[f"{k}_uncertainty"] = _agree(where, k, out[f"{k}_uncertainty"], out[f"{k}_covariance"])
        out["pose_jacobian"] = _matrix(where, "pose_jacobian", d.get("pose_jacobian"))
        out["lever"] = _matrix(where, "lever", d.get("lever"))
        out["position"] = _triple(where, "position", d.get("position"), optional=True)
        t = d.get("temperature")
        if t is not None:
            if isinstance(t, bool) or not isinstance(t, (int, float)) or not _is_finite_number(t):
                raise CalibrationError(f"{where}: temperature must be a finite number (C) or null, got {digits_cut(repr(t))}")
            t = float(t)
        out["temperature"] = t
        date = d.get("date", _now())
        if not isinstance(date, str):
            raise CalibrationError(f"{where}: date must be an ISO 8601 string, got {date!r}")
        try:
            datetime.fromisoformat(date)
        except ValueError:
            raise CalibrationError(f"{where}: date {date!r} is not ISO 8601 (e.g. 2024-05-01T14:30:00+00:00)") from None
        out["date"] = date
        res = d.get("residuals", {}) or {}
        if not isinstance(res, dict) or not all(isinstance(k, str) for k in res):
            raise CalibrationError(f"{where}: residuals must be an object of named values (mm)")
        clean = {}
        for k, v in res.items():
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not _is_finite_number(v):
                raise CalibrationError(f"{where}: residual {k!r} must be a finite number (mm), got {digits_cut(repr(v))}")
            clean[k] = float(v)
        out["residuals"] = clean
        note = d.get("note", "")
        if not isinstance(note, str):
            raise CalibrationError(f"{where}: note must be text")
        out["note"] = note
        return out

    @classmethod
    def from_dict(cls, d, where: str = "record") -> AlignmentRecord:
        """Build from a dict (as read from the file); bad content raises CalibrationError naming ``where``."""
        return cls(**cls._checked(d, where))

    @classmethod
    def from_calibration(cls, pose, reading: ReferenceReading, offset, *, temperature: float | None = None,
                         date: str | None = None, residuals: dict | None = None, note: str = "") -> AlignmentRecord:
        """A record from the solvers' results.

        Parameters
        ----------
        pose : CalibratedPose, Pose or sequence of 3 float
            The calibrated pose, degrees (a CalibratedPose brings its uncertainty).
        reading : ReferenceReading
            From :func:`reference_centre_reading` at that pose.
        offset : MountOffsetFit, MountOffset or sequence of 3 float
            The mount offset, mm (a MountOffsetFit brings its uncertainty).
        temperature : float, optional
            C; default the reading's temperature.
        date : str, optional
            ISO 8601; default now (UTC).
        residuals : dict, optional
            Extra named residuals, mm; the sphere fit's rms is added as ``sphere_rms``.
        note : str
            Free text.
        """
        if isinstance(pose, CalibratedPose):
            p, pc = pose.pose.as_tuple(), pose.covariance
        else:
            p, pc = pose_tuple(pose), None
        if not isinstance(reading, ReferenceReading):
            raise InputTypeError(f"reading: expected a ReferenceReading, got {type(reading).__name__}")
        if pc is None and np.any(reading.pose_covariance != 0):
            pc = reading.pose_covariance
        oc = None
        if isinstance(offset, MountOffsetFit):
            o, ou = tuple(offset.offset), tuple(float(x) for x in offset.uncertainty)
            oc = np.asarray(offset.covariance).tolist()
        else:
            o, ou = tuple(float(x) for x in offset), None
        res = {} if reading.fit is None else {"sphere_rms": float(reading.fit.rms)}
        res.update(residuals or {})
        return cls(pose=p, reading=tuple(float(x) for x in reading.reading), offset=o,
                   pose_covariance=None if pc is None else np.asarray(pc).tolist(),
                   reading_covariance=np.asarray(reading.fit_covariance).tolist(), offset_uncertainty=ou,
                   pose_jacobian=np.asarray(reading.pose_jacobian).tolist(),
                   position=tuple(float(x) for x in reading.position), lever=np.asarray(reading.lever).tolist(),
                   temperature=reading.temperature if temperature is None else float(temperature),
                   date=_now() if date is None else date, residuals=res, note=note, offset_covariance=oc)

    def reference_reading(self) -> ReferenceReading:
        """The alignment as :func:`cmmpose.calibration.mount_offset` takes it.

        A record written by the solvers (``from_calibration``, ``cmmpose
        calibrate alignment``) gives back the solver's reading exactly: its
        position, lever, own covariance, and the pose's full covariance acting
        through the pose Jacobian. A record written by hand (readings and
        standard uncertainties only) is taken as ``ReferenceReading.from_reading``
        takes it: uncorrelated uncertainties, the pose acting through the lever.

        Raises
        ------
        CalibrationError
            The record states no reading uncertainty.
        """
        if self.reading_uncertainty is None:
            raise CalibrationError("the record states no reading uncertainty (mm): the mount-offset fit weighs "
                                   "each alignment by it")
        pc = self.pose_covariance
        if pc is None:
            pc = np.diag(np.square(self.pose_uncertainty or (0.0, 0.0, 0.0)))
        pc = np.array(pc, dtype=float)
        if self.reading_covariance is None or self.position is None or self.lever is None or self.pose_jacobian is None:
            cov = None if self.reading_covariance is None else np.array(self.reading_covariance)
            return ReferenceReading.from_reading(self.pose, self.reading,
                                                 None if cov is not None else self.reading_uncertainty,
                                                 covariance=cov, pose_covariance=pc, temperature=self.temperature)
        fit_cov = np.array(self.reading_covariance, dtype=float)
        jac = np.array(self.pose_jacobian, dtype=float)
        return ReferenceReading(pose=self.pose, reading=np.array(self.reading, dtype=float),
                                covariance=fit_cov + jac @ pc @ jac.T, fit_covariance=fit_cov, pose_covariance=pc,
                                pose_jacobian=jac, position=np.array(self.position, dtype=float),
                                lever=np.array(self.lever, dtype=float), temperature=self.temperature)

    # -- use --------------------------------------------------------------------
    def as_pose(self) -> Pose:
        """The pose, for ``cmmpose.compensate``."""
        return Pose(*self.pose)

    def as_offset(self) -> MountOffset:
        """The mount offset, for ``cmmpose.compensate``."""
        return MountOffset(*self.offset)


class AlignmentLibrary:
    """Alignments stored by trunnion pose name in one JSON file.

    Parameters
    ----------
    path : str or PathLike
        The library file. It need not exist yet: it is created by the first
        :meth:`save`.

    Examples
    --------
    >>> lib = AlignmentLibrary("alignments.json")            # doctest: +SKIP
    >>> lib.save("A90B90", record)                           # doctest: +SKIP
    >>> rec = lib.load("A90B90")                             # doctest: +SKIP
    >>> xyz = cmmpose.compensate(uv, scales, maps, rec.as_pose(), rec.as_offset(), 22.5)  # doctest: +SKIP
    """

    def __init__(self, path):
        self.path = Path(path)

    def __repr__(self) -> str:
        return f"AlignmentLibrary({str(self.path)!r})"

    # -- file --------------------------------------------------------------------
    def _read(self) -> dict:
        """name -> raw dict; raises CalibrationError for a malformed file.

        The one door in (issue 35): the file is read as a regular file only
        (a FIFO or a device is refused at once, its size bounded), a key
        repeated in one object is refused, every record is checked, and the
        whole document is validated against its schema
        (:mod:`cmmpose.schemas.alignments`, ranges and types naming the key)
        before any record is used."""
        if not self.path.exists():
            return {}
        text = read_input_text(self.path, "alignment library", error=CalibrationError)
        try:
            doc = json.loads(text, object_pairs_hook=no_repeats(self.path, CalibrationError))
        except json.JSONDecodeError as exc:
            raise CalibrationError(
                f"{self.path}:{exc.lineno}:{exc.colno}: not an alignment library (bad JSON: {exc.msg})") from None
        except RecursionError:
            raise CalibrationError(f"{self.path}: not an alignment library (JSON nested too deeply)") from None
        except CalibrationError:  # a repeated key, named
            raise
        except ValueError as exc:  # an integer of more than 4,300 digits
            raise CalibrationError(f"{self.path}: not an alignment library (bad JSON: {exc})") from None
        if not isinstance(doc, dict) or doc.get("format") != LIBRARY_FORMAT:
            raise CalibrationError(f"{self.path}: not an alignment library (expected \"format\": \"{LIBRARY_FORMAT}\")")
        if doc.get("version") != LIBRARY_VERSION:
            raise CalibrationError(f"{self.path}: alignment library version {doc.get('version')!r} is not supported "
                                   f"(this cmmpose reads version {LIBRARY_VERSION})")
        unknown = sorted(set(doc) - set(_DOC_KEYS))
        if unknown:
            raise CalibrationError(f"{self.path}: unknown key(s) {', '.join(map(repr, unknown))} "
                                   f"(known: {', '.join(_DOC_KEYS)})")
        _check_units(self.path, doc.get("units"))
        poses = doc.get("poses")
        if not isinstance(poses, dict):
            raise CalibrationError(f"{self.path}: \"poses\" must be an object of pose name -> record")
        for name, rec in poses.items():  # each record in the library's own words first
            AlignmentRecord._checked(rec, f"{self.path}: pose {name!r}")
        validate(doc, "alignments", self.path, error=CalibrationError)  # then every range, every key typed
        return poses

    def _write(self, poses: dict) -> None:
        doc = {"format": LIBRARY_FORMAT, "version": LIBRARY_VERSION, "units": UNITS,
               "poses": {k: poses[k] for k in sorted(poses)}}
        ensure_folder(self.path.parent)
        write_text(self.path, json.dumps(doc, indent=2, allow_nan=False) + "\n")  # atomic: a crash never leaves half a library

    # -- API ---------------------------------------------------------------------
    def names(self) -> list[str]:
        """Pose names stored, sorted."""
        return sorted(self._read())

    def __contains__(self, name) -> bool:
        return name in self._read()

    def __len__(self) -> int:
        return len(self._read())

    def save(self, name: str, record: AlignmentRecord, *, overwrite: bool = True) -> None:
        """Store ``record`` under ``name`` (e.g. "A90B90"), replacing an older
        alignment of that pose unless ``overwrite`` is False."""
        if not isinstance(name, str) or not name.strip():
            raise InputError(f"name: expected a non-empty pose name, got {name!r}")
        if not isinstance(record, AlignmentRecord):
            raise InputTypeError(f"record: expected an AlignmentRecord, got {type(record).__name__}")
        with locked_update(self.path):  # two saves into one library take turns: neither pose is lost
            poses = self._read()
            if name in poses and not overwrite:
                raise CalibrationError(
                    f"pose {name!r} is already aligned in {self.path}", file=str(self.path), option="overwrite",
                    remedy="overwrite")
            poses[name] = record.to_dict()
            self._write(poses)

    def load(self, name: str) -> AlignmentRecord:
        """The record of pose ``name``; CalibrationError if it was never aligned."""
        poses = self._read()
        if name not in poses:
            known = ", ".join(repr(k) for k in sorted(poses)) if poses else "none; the library is empty"
            raise CalibrationError(f"pose {name!r} was never aligned (known: {known}) in {self.path}")
        return AlignmentRecord.from_dict(poses[name], where=f"{self.path}: pose {name!r}")

    def store_offset(self, names, fit: MountOffsetFit) -> None:
        """Store the mount offset solved from the alignments ``names``
        (:func:`cmmpose.calibration.mount_offset`) in each of their records,
        with its uncertainty and covariance, where compensation takes it from
        (``AlignmentRecord.as_offset``, ``compensate --alignment NAME``). The
        records' readings are not touched: solving again gives the same fit.
        All records change together or none does."""
        if not isinstance(fit, MountOffsetFit):
            raise InputTypeError(f"fit: expected a MountOffsetFit, got {type(fit).__name__}")
        names = [str(n) for n in names]
        note = f"offset solved from {', '.join(names)} on {_now()}"
        with locked_update(self.path):
            poses = self._read()
            missing = [n for n in names if n not in poses]
            if missing:
                raise CalibrationError(f"pose(s) {', '.join(map(repr, missing))} never aligned in {self.path}")
            for n in names:
                rec = AlignmentRecord.from_dict(poses[n], where=f"{self.path}: pose {n!r}")
                rec = dataclasses.replace(rec, offset=tuple(float(x) for x in fit.offset),
                                          offset_uncertainty=tuple(float(x) for x in fit.uncertainty),
                                          offset_covariance=np.asarray(fit.covariance).tolist(),
                                          note=f"{rec.note}; {note}" if rec.note else note)
                poses[n] = rec.to_dict()
            self._write(poses)

    def remove(self, name: str) -> None:
        """Forget pose ``name`` (CalibrationError if it is not stored)."""
        with locked_update(self.path):
            poses = self._read()
            if name not in poses:
                raise CalibrationError(f"pose {name!r} was never aligned in {self.path}")
            del poses[name]
            self._write(poses)

    def records(self) -> dict[str, AlignmentRecord]:
        """Every record, by name."""
        return {k: AlignmentRecord.from_dict(v, where=f"{self.path}: pose {k!r}")
                for k, v in sorted(self._read().items())}

