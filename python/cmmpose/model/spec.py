"""The library of candidate physical effects a diagnosis model can hold:
the diagnosis's view of the effects registry (:mod:`cmmpose.effects`, one
file per effect), so a value fitted from data compares directly with the
truth of a simulated run. An effect acts at one of four places:

- ``kernel``: inside the Rust compensation kernel (its term in
  rust/core/src/effects.rs, of the same name);
- ``pose``: on the digitizer pose or mount offset handed to that kernel;
- ``length``: on the predicted artefact length (expansion);
- ``python``: a user-defined function of the points (:class:`UserEffect`).

``prior`` is a typical magnitude of each parameter: the step of the
finite-difference sensitivities and the scale at which an effect counts as
observable. ``reveal`` says what measurement shows the effect when a run
cannot.
"""

from __future__ import annotations

import importlib.util
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from .. import effects as effects_registry
from ..effects import Effect
from ..errors import Error, InputError, UserEffectError, read_input

__all__ = ["EffectSpec", "UserEffect", "load_user_effect", "load_user_effects", "LIBRARY", "library", "run_library", "effect_spec", "USER_INPUTS"]


@dataclass(frozen=True)
class EffectSpec:
    """One candidate physical effect.

    Attributes
    ----------
    name : str
        CLI and model name (e.g. 'squareness').
    params : tuple of str
        Parameter names.
    units : tuple of str
        Unit of each parameter (e.g. 'arc-second').
    prior : tuple of float
        Typical magnitude of each parameter, in its unit.
    kind : {'kernel', 'pose', 'length', 'python'}
        Where the effect acts.
    key : str
        Kernel term (kind 'kernel'), or 'alignment' / 'mount-offset' (kind
        'pose'), or 'expansion' (kind 'length').
    physics : str
        What the effect is, in a sentence.
    reveal : str
        The extra measurement that shows it when a run cannot.
    needs : tuple of str
        Run inputs it requires: 'axis_temperature', 'gradient', 'velocity',
        'incidence', 'poses>1'.
    pose_id : int or None
        For a per-pose alignment: the pose it belongs to.
    step : tuple of float or None
        Finite-difference step of each parameter, if not ``prior`` (where a
        step of one typical magnitude would leave the maps' range).
    effect : type or None
        The effect class of :mod:`cmmpose.effects` it comes from.
    sensor : str or None
        For an effect that follows a thermocouple group the data choose
        (``effect.sensor_input``): the role it follows in this candidate.
    """

    name: str
    params: tuple[str, ...]
    units: tuple[str, ...]
    prior: tuple[float, ...]
    kind: str
    key: str
    physics: str
    reveal: str
    needs: tuple[str, ...] = ()
    pose_id: int | None = None
    step: tuple[float, ...] | None = None
    effect: type | None = field(default=None, compare=False, repr=False)
    sensor: str | None = None

    @classmethod
    def from_effect(cls, effect: type[Effect], **changes) -> EffectSpec:
        """The spec of an effect class of :mod:`cmmpose.effects`."""
        ps = effect.params
        steps = tuple(p.step if p.step is not None else p.prior for p in ps.values())
        spec = cls(name=effect.name, params=tuple(ps), units=tuple(p.unit for p in ps.values()),
                   prior=tuple(p.prior for p in ps.values()), kind=effect.acts, key=effect.name,
                   physics=effect.summary, reveal=effect.reveal, needs=effect.needs,
                   step=None if steps == tuple(p.prior for p in ps.values()) else steps, effect=effect)
        return replace(spec, **changes) if changes else spec

    @property
    def sensor_input(self) -> str | None:
        """The kernel input carrying the followed sensor's temperature, if any."""
        return getattr(self.effect, "sensor_input", None)

    @property
    def steps(self) -> tuple[float, ...]:
        return self.prior if self.step is None else self.step

    @property
    def size(self) -> int:
        return len(self.params)

    def difference_columns(self, current, change: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
        """Sensitivity columns (one per parameter, scaled by its prior) by
        one-sided differences: ``change(values)`` is the residual change at
        ``values``; a forward step, or backward where the forward one cannot be
        evaluated (it leaves the maps' range)."""
        cols = []
        for j in range(self.size):
            for sign in (1.0, -1.0):
                v = np.array(current, dtype=float)
                v[j] += sign * self.steps[j]
                try:
                    moved = change(v)
                except UserEffectError:  # the user's code failed: no other step can mend it
                    raise
                except Error:
                    if sign < 0:
                        raise
                    continue
                cols.append(moved * sign * self.prior[j] / self.steps[j])
                break
        return np.column_stack(cols)

    def describe(self, values) -> str:
        """'xy=+5.2 arc-second, ...' for parameter ``values`` (dimensionless ones without a unit)."""
        return ", ".join(f"{p}={v:+.4g}" + ("" if u in ("1", "") else f" {u}")
                         for p, v, u in zip(self.params, np.ravel(values), self.units))


@dataclass(frozen=True)
class UserEffect(EffectSpec):
    """A user-defined effect: a Python function of the points.

    ``function(inputs, **params)`` returns an (N, 3) correction in mm, added to
    the compensated coordinates; ``inputs`` is a dict of (N,) arrays named in
    ``USER_INPUTS`` (u, v, D, E, F in mm, t in s, temperature in C, x, y, z the
    compensated coordinates in mm, scan_id, pose_id, incidence in degrees).
    The slower path (Python, not the Rust kernel), the same workflow.

    Parameters
    ----------
    name : str
        Name of the effect.
    function : callable
        ``function(inputs: dict, **params) -> ndarray (N, 3)`` in mm; must be
        zero when every parameter is zero.
    params : dict of str -> (unit, prior)
        Parameter names with their unit and typical magnitude.
    physics : str
        What the effect is.
    reveal : str
        What measurement shows it.

    A function that raises (other than a :class:`cmmpose.Error`, which
    passes as is: the effect cannot be evaluated on these inputs), or returns
    anything but a finite (N, 3) array, is a :class:`UserEffectError` naming
    the effect, its file and line and the exception: an error in the user's
    code stops a diagnosis, it is not filed as 'not observable'.
    """

    function: Callable | None = field(default=None, compare=False)
    #: The file that defines it (set by :func:`load_user_effect`); None: the function's own file.
    source: str | None = field(default=None, compare=False)

    @classmethod
    def create(cls, name: str, function: Callable, params: dict, physics: str = "user-defined",
               reveal: str = "") -> UserEffect:
        if not callable(function):
            raise InputError(f"user effect {name!r}: function must be callable")
        if not params:
            raise InputError(f"user effect {name!r}: give at least one parameter as name -> (unit, prior)")
        names, units, priors = [], [], []
        for p, spec in params.items():
            try:
                unit, prior = spec
                prior = float(prior)
            except (TypeError, ValueError):
                raise InputError(f"user effect {name!r}: parameter {p!r} must map to (unit, prior)") from None
            if not (np.isfinite(prior) and prior > 0):
                raise InputError(f"user effect {name!r}: prior of {p!r} must be a positive magnitude, got {prior}")
            names.append(str(p))
            units.append(str(unit))
            priors.append(prior)
        if name in LIBRARY:
            raise InputError(f"user effect {name!r}: the library already has an effect of that name")
        if not isinstance(name, str) or not name or not name.isprintable():
            raise InputError(f"user effect {name!r}: a name is printable text (no control character, no line "
                             "break: it is shown in a terminal and saved in the model)", what="name", value=repr(name))
        return cls(name=name, params=tuple(names), units=tuple(units), prior=tuple(priors), kind="python",
                   key="user", physics=physics, reveal=reveal or "a measurement that exercises its inputs",
                   function=function)

    @property
    def file(self) -> str | None:
        """The file of the user's code: ``source``, or the file its function was defined in."""
        if self.source is not None:
            return str(self.source)
        code = getattr(self.function, "__code__", None)
        return None if code is None else code.co_filename

    def _failed(self, what: str, values, exc: BaseException | None = None) -> UserEffectError:
        """The error of a failed call: the effect, its file (and the line of it the exception left), ``what``."""
        file, line = self.file, None
        if exc is not None and file is not None:
            try:
                here = Path(file).resolve()
                lines = [f.lineno for f in traceback.extract_tb(exc.__traceback__) if Path(f.filename).resolve() == here]
            except (OSError, ValueError):
                lines = []
            line = lines[-1] if lines else None
        where = "" if file is None else f" ({file}" + ("" if line is None else f", line {line}") + ")"
        return UserEffectError(f"user effect {self.name!r}{where}: {what} (at {self.describe(values)})",
                               what=self.name, file=file, row=line)

    def correction(self, inputs: dict, values) -> np.ndarray:
        """The (N, 3) correction in mm at parameter ``values``; the user's
        function failing is a :class:`UserEffectError` (a cmmpose error it
        raises passes as is)."""
        values = [float(v) for v in values]
        try:
            out = self.function(dict(inputs), **dict(zip(self.params, values)))
        except Error:
            raise
        except Exception as exc:  # the user's code: say where and how it failed
            raise self._failed(f"its function raised {type(exc).__name__}: {exc}", values, exc) from exc
        if np.iscomplexobj(out):  # never cast to real in silence (the imaginary part discarded with a warning)
            raise self._failed("its function returned complex values; a correction is real, in mm", values)
        try:
            out = np.asarray(out, dtype=float)
        except (TypeError, ValueError) as exc:
            raise self._failed(f"its function must return an (N, 3) array in mm, returned "
                               f"{type(out).__name__} ({exc})", values) from None
        n = len(inputs["u"])
        if out.shape != (n, 3):
            raise self._failed(f"its function must return an array of shape ({n}, 3) in mm (a row per point), returned "
                               f"shape {out.shape}", values)
        bad = ~np.isfinite(out)
        if bad.any():
            rows = np.flatnonzero(bad.any(axis=1))
            row, col = rows[0], int(np.argmax(bad[rows[0]]))
            raise self._failed(f"its function returned a non-finite value ({out[row, col]}) at row {row}, "
                               f"column {'xyz'[col]}; {len(rows)} of {n} rows are not finite", values)
        return out


#: Names of the per-point inputs a user effect receives.
USER_INPUTS = ("u", "v", "D", "E", "F", "t", "temperature", "x", "y", "z", "scan_id", "pose_id", "incidence")

#: The library: every effect of the registry (:mod:`cmmpose.effects`).
LIBRARY: dict[str, EffectSpec] = {name: EffectSpec.from_effect(e) for name, e in effects_registry.available().items()}


def library(pose_ids=(), sensors=()) -> dict[str, EffectSpec]:
    """The candidate library for a run: ``LIBRARY`` plus, when the run has
    more than one pose, an alignment error per pose ('alignment@<pose_id>'),
    and, for each effect that follows a thermocouple group the data choose,
    one candidate per role in ``sensors`` ('squareness-temperature@z_scale')
    in place of the effect itself."""
    out = {}
    for name, spec in LIBRARY.items():
        if spec.sensor_input is None:
            out[name] = spec
            continue
        for role in sensors:
            out[f"{name}@{role}"] = replace(spec, name=f"{name}@{role}", sensor=str(role),
                                            physics=f"{spec.physics}; here the '{role}' thermocouples")
    pose_ids = [int(p) for p in pose_ids]
    if len(pose_ids) > 1:
        base = LIBRARY["alignment"]
        for p in pose_ids:
            out[f"alignment@{p}"] = replace(base, name=f"alignment@{p}", pose_id=p,
                                            physics=f"the Euler angles of pose {p} differ from its calibrated ones")
    return out


def run_library(inputs) -> dict[str, EffectSpec]:
    """The candidate library for a run's inputs (:class:`RunInputs`): its
    poses and thermocouple roles."""
    return library(inputs.pose_ids, inputs.sensor_roles)


def effect_spec(name, candidates: dict[str, EffectSpec] | None = None) -> EffectSpec:
    """The spec named ``name`` (or ``name`` itself if it is a spec)."""
    if isinstance(name, EffectSpec):
        return name
    candidates = LIBRARY if candidates is None else candidates
    if name not in candidates:
        raise InputError(f"effect {name!r}: unknown; available: {', '.join(sorted(candidates))}")
    return candidates[name]


def load_user_effect(path) -> UserEffect:
    """The ``EFFECT`` a user-effect file defines (docs/user-effects.md). The
    file is the user's own code and runs as such; an exception it raises
    becomes an ``InputError`` naming the file (a cmmpose error passes as is).

    Parameters
    ----------
    path : str or Path
        A Python file that sets ``EFFECT = UserEffect.create(...)``.
    """
    read_input(path, "user-effect file")  # a FIFO or /dev/zero refused as such before Python reads it
    spec = importlib.util.spec_from_file_location(f"cmmpose_user_effect_{Path(path).stem}", path)
    if spec is None or spec.loader is None:
        raise InputError(f"{path}: not a Python file")
    module = importlib.util.module_from_spec(spec)
    try:
        spec.loader.exec_module(module)
    except Error:
        raise
    except Exception as exc:  # the user's file: say where it failed
        raise InputError(f"{path}: the user effect file failed to run: {type(exc).__name__}: {exc}") from None
    effect = getattr(module, "EFFECT", None)
    if not isinstance(effect, UserEffect):
        raise InputError(f"{path}: must define EFFECT = UserEffect.create(...) (see docs/user-effects.md)")
    return replace(effect, source=str(path))


def load_user_effects(paths) -> list[UserEffect]:
    """The effects of several user-effect files (:func:`load_user_effect`);
    two files defining effects of the same name are an ``InputError`` naming
    both (which one to fit would otherwise depend on their order); a file
    given twice counts once."""
    out: dict[str, UserEffect] = {}
    seen = set()
    for path in paths:
        if Path(path).resolve() in seen:  # the same file given twice: the same effect, nothing to choose
            continue
        seen.add(Path(path).resolve())
        effect = load_user_effect(path)
        first = out.get(effect.name)
        if first is not None:
            raise InputError(f"{path}: defines the user effect {effect.name!r}, as {first.source} does: give each "
                             f"effect once, under its own name", what=effect.name, file=str(path))
        out[effect.name] = effect
    return list(out.values())
