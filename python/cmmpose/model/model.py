"""A machine model with physical effects: the thesis model (error maps,
pose, machine-mean temperature) plus named effects with their values, as a
diagnosis found them or a user set them. Immutable: :meth:`Model.with_values`
returns a new model; fitting an effect to a run is the diagnosis's
(:func:`cmmpose.diagnosis.fit_effect`). Applying a model to a run or to
points is :meth:`Model.compensate_run` and :meth:`Model.compensate_points`,
the same calls :class:`cmmpose.ErrorMap` and :class:`cmmpose.ErrorMapSet`
answer (:class:`cmmpose.model.MachineModel`)."""

from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from .. import _core
from ..errormap import ErrorMap, ErrorMapSet
from ..errors import InputError, InputTypeError, ModelDomainWarning, warn_clamped
from ..fitting import fit_spheres
from ..pose import digitizer
from ..run import Run
from ..schemas.model import MODEL_SCHEMA  # ``schema`` of a saved model file, defined with the file's schema
from ..temperature import LOG_HOLD, TEMPERATURE_TOLERANCE, TemperaturePolicy, check_policy
from ..kernel_report import KernelReport
from ..point_uncertainty import DETAILS, UncertainPoints, UncertaintySources
from .alternatives import check_alternatives
from .domain import Domain, correction_uncertainty, domain_notes, parameter_jacobian, uncertainty_notes
from .inputs import RunInputs, incidence_angles
from .modelfile import model_document, read_model, write_model
from .names import resolve
from .point_inputs import check_inputs, point_inputs, single_map_warning
from .spec import LIBRARY, EffectSpec, effect_spec

__all__ = ["Model", "MODEL_SCHEMA", "as_model", "check_kinematics", "run_kinematics"]

_log = logging.getLogger(__name__)



@dataclass(frozen=True)
class Model:
    """Error maps plus physical effects with parameter values.

    Parameters
    ----------
    maps : ErrorMap or ErrorMapSet
        The machine's component errors (a set is interpolated at each point's
        machine temperature, C).
    effects : tuple of (EffectSpec, ndarray)
        Effects in the order added, each with its parameter values in the
        units of ``EffectSpec.units``.
    temperature : float, optional
        Machine temperature for every point, C; default the run's
        thermocouple log (mean of the axis-scale channels, thesis 6.4).
    out_of_range : {'raise', 'clamp', 'extrapolate'}
        Readings or temperatures beyond the tolerance outside the maps
        (cmmpose.policy).
    temperature_tolerance : float
        K: temperatures this close outside the maps are held at the edge.
    log_hold : float
        s: points this far outside the thermocouple log take its nearest reading.
    temperature_policy : TemperaturePolicy, optional
        The rest of the temperature policy (gaps, broken channels, which
        sensor each role reads; cmmpose.temperature). Its ``out_of_range``,
        ``temperature_tolerance`` and ``log_hold`` are taken when the three
        fields above are left at their defaults; the fields win otherwise.
        :attr:`policy` is the whole policy in force.
    thermal : dict
        How the temperatures of the run the model was diagnosed on were read
        (channels dropped and why, points held and how long, the channels
        each role read); saved with the model, empty when unknown.
    """

    maps: ErrorMap | ErrorMapSet
    effects: tuple[tuple[EffectSpec, np.ndarray], ...] = ()
    temperature: float | None = None
    out_of_range: str = "raise"
    temperature_tolerance: float = TEMPERATURE_TOLERANCE
    log_hold: float = LOG_HOLD
    #: Standard uncertainty of each effect's parameters (name -> array in its
    #: units) as the diagnosis found them; empty when unknown (saved, loaded).
    uncertainty: dict = field(default_factory=dict, compare=False, repr=False)
    temperature_policy: TemperaturePolicy | None = field(default=None, compare=False, repr=False)
    thermal: dict = field(default_factory=dict, compare=False, repr=False)
    #: Effects the data the model was found on could not tell from one it
    #: holds (:class:`cmmpose.model.alternatives.Alternative`): saved, and
    #: applying the model warns where they predict differently.
    alternatives: tuple = field(default=(), compare=False, repr=False)
    #: Where the model was fitted (:class:`cmmpose.model.domain.Domain`): saved, and applying the model
    #: says where data leave it. None: not recorded (a model made by hand).
    domain: Domain | None = field(default=None, compare=False, repr=False)
    #: The covariance of the effects' parameters as the diagnosis found it: ``{"parameters": ["effect.param",
    #: ...], "matrix": (k, k) in the parameters' units}``; empty: the standard uncertainties, independent.
    covariance: dict = field(default_factory=dict, compare=False, repr=False)

    def __post_init__(self):
        if not isinstance(self.maps, (ErrorMap, ErrorMapSet)):
            raise InputTypeError(f"maps: expected an ErrorMap or ErrorMapSet, got {type(self.maps).__name__}")
        check_policy(self.out_of_range, self.temperature_tolerance, self.log_hold)
        _keep_policy(self)
        names = [s.name for s, _ in self.effects]
        if len(set(names)) != len(names):
            raise InputError(f"effects: each effect once, got {names}")
        keys = [s.key for s, _ in self.effects if s.kind == "kernel"]
        for k in set(keys):
            if keys.count(k) > 1:
                alts = [s.name for s, _ in self.effects if s.key == k]
                raise InputError(f"effects {', '.join(alts)} are alternatives of one effect: a model holds one")
        for spec, _ in self.effects:
            if spec.sensor_input and spec.sensor is None:
                raise InputError(f"effect {spec.name}: name the thermocouple role it follows, e.g. "
                                 f"'{spec.name}@z_scale'")
        for spec, values in self.effects:
            v = np.asarray(values, dtype=float)
            if v.shape != (spec.size,) or not np.all(np.isfinite(v)):
                raise InputError(f"effect {spec.name}: expected {spec.size} finite values "
                                 f"({', '.join(spec.params)}), got {values!r}")

    def __eq__(self, other: object) -> bool:
        # Effects compare by spec and values (arrays), not by array identity.
        if not isinstance(other, Model):
            return NotImplemented
        return (self.maps == other.maps and self.temperature == other.temperature
                and self.policy == other.policy
                and len(self.effects) == len(other.effects)
                and all(s == t and np.array_equal(v, w) for (s, v), (t, w) in zip(self.effects, other.effects)))

    # -- parameters ---------------------------------------------------------

    @property
    def names(self) -> tuple[str, ...]:
        """Names of the effects in the model, in the order added."""
        return tuple(s.name for s, _ in self.effects)

    def values(self, name: str) -> np.ndarray:
        """Parameter values of effect ``name`` (zeros if absent is an error)."""
        for s, v in self.effects:
            if s.name == name:
                return np.array(v, dtype=float)
        raise InputError(f"effect {name!r} is not in the model (has: {', '.join(self.names) or 'none'})")

    def with_values(self, spec: EffectSpec | str, values) -> Model:
        """A model with effect ``spec`` set to ``values`` (added if absent)."""
        spec = effect_spec(spec, _known(self, spec))
        values = np.array(values, dtype=float).reshape(-1)
        effects = [(s, v) for s, v in self.effects if s.name != spec.name]
        at = next((i for i, (s, _) in enumerate(self.effects) if s.name == spec.name), len(effects))
        effects.insert(at, (spec, values))
        # Alternatives were fitted in place of the effect's values: a changed value leaves them behind.
        alternatives = tuple(a for a in self.alternatives if a.chosen != spec.name)
        return replace(self, effects=tuple(effects), alternatives=alternatives)

    def without(self, name: str) -> Model:
        """A model without effect ``name``."""
        self.values(name)
        return replace(self, effects=tuple((s, v) for s, v in self.effects if s.name != name))

    def add(self, effect, values) -> Model:
        """A new model with ``effect`` added at ``values`` (its units); to
        fit it to a run, :func:`cmmpose.diagnosis.fit_effect`.

        Parameters
        ----------
        effect : str or EffectSpec
            A library name (see ``cmmpose.model.LIBRARY``) or a spec
            (e.g. a :class:`UserEffect`).
        values : array_like
            Parameter values in the effect's units.
        """
        spec = effect_spec(effect, _known(self, effect))
        if spec.name in self.names:
            raise InputError(f"effect {spec.name!r} is already in the model; use with_values to change it")
        return self.with_values(spec, values)

    # -- compensation -------------------------------------------------------

    def inputs(self, run: Run) -> RunInputs:
        """Per-point inputs of ``run`` its effects read (computed afresh: a
        caller that applies the model to one run several times keeps them)."""
        return inputs_with_incidence(self, RunInputs.from_run(run, self.temperature, temperature_policy=self.policy))

    @property
    def policy(self) -> TemperaturePolicy:
        """The temperature policy in force (cmmpose.temperature)."""
        return replace(self.temperature_policy or TemperaturePolicy(), out_of_range=self.out_of_range,
                       temperature_tolerance=self.temperature_tolerance, log_hold=self.log_hold)

    def kernel_terms(self) -> dict[str, list[float]]:
        """The per-point effects' parameters by name, as the Rust terms of
        rust/core/src/effects.rs take them."""
        return {spec.key: [float(x) for x in v] for spec, v in self.effects if spec.kind == "kernel"}

    def poses(self, inputs: RunInputs) -> np.ndarray:
        """Each pose (P, 6: alpha, beta, gamma deg, U1, V1, W1 mm) with the
        pose-level effects applied (each effect's ``adjust_poses``)."""
        poses = inputs.poses.copy()
        for spec, v in self.effects:
            if spec.kind != "pose":
                continue
            if spec.pose_id is None:
                spec.effect.adjust_poses(v, poses, slice(None))
            elif spec.pose_id in inputs.pose_ids:
                spec.effect.adjust_poses(v, poses, inputs.pose_ids.index(spec.pose_id))
        return poses

    @property
    def expansion_ppm_per_kelvin(self) -> float:
        """The artefact expansion coefficient in the model, ppm/K (0 if absent)."""
        for spec, v in self.effects:
            if spec.kind == "length":
                return float(v[0])
        return 0.0

    def _kernel_inputs(self, run: Run | RunInputs):
        """What the kernel reads of ``run`` under this model: its inputs (with incidence angles from a first pass
        through the model, only when an effect that needs them is switched on), one digitizer per pose (the
        pose-level effects applied) and the named per-point inputs (an effect following a chosen thermocouple
        group reads that group's temperature)."""
        inputs = run if isinstance(run, RunInputs) else self.inputs(run)
        needs_incidence = any("incidence" in s.needs and np.any(v != 0) for s, v in self.effects)
        if needs_incidence and inputs.incidence is None:
            inputs = inputs_with_incidence(self, inputs)
        digitizers = [digitizer(p[:3], p[3:]) for p in self.poses(inputs)]
        named = inputs.named()
        named |= {s.sensor_input: inputs.sensor(s.sensor) for s, _ in self.effects if s.sensor_input}
        return inputs, digitizers, named

    def _user_corrections(self, inputs: RunInputs, xyz: np.ndarray) -> np.ndarray:
        """``xyz`` with the user effects' (Python) corrections added."""
        users = [(s, v) for s, v in self.effects if s.kind == "python"]
        if users:
            pts = _user_inputs(inputs, xyz)
            for spec, v in users:
                xyz = xyz + spec.correction(pts, v)
        return xyz

    def compensate(self, run: Run | RunInputs, *, return_clamped: bool = False, return_report: bool = False):
        """Compensated machine coordinates of every point of ``run``, mm.

        Parameters
        ----------
        run : Run or RunInputs
            The run (or its prepared inputs).
        return_clamped : bool
            Also return how many points were clamped into the maps.
        return_report : bool
            Also return the kernel's report (a dict of ``cmmpose.KernelReport`` fields).

        Returns
        -------
        ndarray, shape (N, 3)
            X, Y, Z in mm, machine frame.
        """
        inputs, digitizers, named = self._kernel_inputs(run)
        xyz, report = _core.compensate_model(
            inputs.uv, inputs.scales, self.maps._core, digitizers, self.policy, pose_index=inputs.pose_index,
            inputs=named, effects=self.kernel_terms())
        clamped = report["clamped_points"]
        xyz = self._user_corrections(inputs, xyz)
        if return_report:
            return xyz, report
        return (xyz, clamped) if return_clamped else xyz

    # -- the machine-model calls (cmmpose.model.MachineModel) ---------------

    #: A model reads a run's own inputs (thermocouple log, time stamps, sweeps) itself.
    reads_run = True

    @property
    def reads_sweeps(self) -> bool:
        """Whether the model reads each sweep's velocity (latency): then a
        point file is compensated sweep by sweep."""
        return any("velocity" in s.needs for s, _ in self.effects)

    @property
    def error_maps(self) -> ErrorMap | ErrorMapSet:
        """The maps under the model."""
        return self.maps

    def provenance(self) -> dict:
        """What compensated, for an evaluation's JSON."""
        return {"kind": "model", "maps": "set" if isinstance(self.maps, ErrorMapSet) else "map",
                "effects": [{"name": s.name, "params": dict(zip(s.params, map(float, v))),
                             "units": dict(zip(s.params, s.units))} for s, v in self.effects]}

    def without_effects(self) -> Model:
        """The plain maps as a model: the same maps, policy and reading of a
        run's log, without the effects (what a found model is judged against)."""
        return replace(self, effects=(), alternatives=(), uncertainty={}, domain=None, covariance={})

    def with_policy(self, *, out_of_range=None, temperature_tolerance=None, log_hold=None,
                    temperature=None) -> Model:
        """The model with the caller's policy (each None: the model's own)
        and machine temperature (C; None: the model's, else the data's)."""
        changes = {k: v for k, v in (("out_of_range", out_of_range), ("temperature_tolerance", temperature_tolerance),
                                     ("log_hold", log_hold), ("temperature", temperature)) if v is not None}
        return replace(self, **changes) if changes else self

    def compensate_points(self, uv, scales, pose, offset, temperature=None, *, policy: TemperaturePolicy | None = None,
                          nan_policy: str = "raise", out=None, columns=None, where: str = "points",
                          once: set | None = None) -> tuple[np.ndarray, dict]:
        """Compensated X, Y, Z (mm) of points taken at one pose, and the
        kernel's report (a dict).

        Parameters
        ----------
        uv, scales : ndarray (N, 2), (N, 3)
            Scan-plane u, v and scale readings D, E, F, mm (checked float64 rows).
        pose, offset : sequence of 3 float
            Euler 3-1-3 angles (degrees) and mount offset (mm).
        temperature : float or ndarray (N,), optional
            Machine temperature, C, for every point or per point (the T column).
        policy : TemperaturePolicy, optional
            The caller's map side of the policy (``out_of_range``,
            ``temperature_tolerance``); None: the model's.
        nan_policy, out
            For maps only: a model refuses anything but the defaults.
        columns : dict of str -> ndarray, optional
            The points' other columns its effects read (:mod:`cmmpose.model.point_inputs`).
        where : str
            The data's name, for messages (a file's path).
        once : set, optional
            The checks already said for these data (a file's earlier chunks):
            each warning is given once.
        """
        if out is not None or nan_policy != "raise":
            raise InputError("compensate with a model: out= and nan_policy='propagate' are for maps only")
        temps = None
        if temperature is not None and np.ndim(temperature) > 0:
            temps, temperature = temperature, None
        model = self._map_policy(policy)
        inputs = point_inputs(model, uv, scales, pose, offset, temperature, temps, dict(columns or {}), where)
        xyz, raw = model.compensate(inputs, return_report=True)
        model._check_application(inputs, xyz, str(where), once, compare=None, every_call=False)
        return xyz, raw

    def compensate_points_uncertainty(self, uv, scales, pose, offset, temperature=None, *,
                                      sources: UncertaintySources, detail: str = "standard",
                                      policy: TemperaturePolicy | None = None, nan_policy: str = "raise",
                                      columns=None, where: str = "points", once: set | None = None):
        """As :meth:`compensate_points`, and each point's uncertainty
        (:meth:`compensate_uncertainty`): ``(UncertainPoints, report)``."""
        if nan_policy != "raise":
            raise InputError("compensate with a model: nan_policy='propagate' is for maps only")
        temps = None
        if temperature is not None and np.ndim(temperature) > 0:
            temps, temperature = temperature, None
        model = self._map_policy(policy)
        inputs = point_inputs(model, uv, scales, pose, offset, temperature, temps, dict(columns or {}), where)
        points, raw = model.compensate_uncertainty(inputs, sources, detail)
        model._check_application(inputs, points.xyz, str(where), once, compare=None, every_call=False)
        return points, raw

    def compensate_uncertainty(self, run: Run | RunInputs, sources: UncertaintySources, detail: str = "standard"):
        """Compensated points of ``run`` with each point's uncertainty
        (k = 1): the kernel propagates the maps', temperature's, scanner's and
        pose's sources in its pass; the model's parameter covariance is added
        as J C J^T, J from one kernel pass per determined parameter
        (:func:`cmmpose.model.domain.parameter_jacobian`). Returns
        ``(UncertainPoints, report)``; ``detail`` one of ``DETAILS``."""
        if detail not in DETAILS:
            raise InputError(f"detail: {detail!r} is not one of {', '.join(DETAILS)}")
        inputs, digitizers, named = self._kernel_inputs(run)
        xyz, rows, report = _core.compensate_uncertainty(
            inputs.uv, inputs.scales, self.maps._core, digitizers, self.policy,
            sources.kernel_sources(self, len(digitizers)), pose_index=inputs.pose_index, inputs=named,
            effects=self.kernel_terms(), detail=detail)
        xyz = self._user_corrections(inputs, xyz)
        if sources.model and sources.on("model") and self.effects:
            names, J, _ = parameter_jacobian(self, inputs, xyz)
            if names:
                C = self.parameter_covariance(names)
                full = np.einsum("mik,kl,mjl->mij", J, C, J)
                sym = full[:, [0, 1, 2, 0, 0, 1], [0, 1, 2, 1, 2, 2]]
                rows[:, :3] = np.sqrt(np.square(rows[:, :3]) + sym[:, :3])
                if rows.shape[1] >= 9:
                    rows[:, 3:9] += sym
                if rows.shape[1] >= 15:
                    rows[:, 9:15] += sym
        return UncertainPoints.from_kernel(xyz, rows, sources), report

    def compensate_run(self, run: Run, temperature=None, *, policy: TemperaturePolicy | None = None,
                       reports: list | None = None, compare=None, once: set | None = None) -> np.ndarray:
        """All points of ``run`` in machine coordinates (N, 3 mm): its maps
        and effects, with the inputs its effects read from the run (a
        lacking one is an ``InputError`` naming it).

        Parameters
        ----------
        run : Run
            The run (a run of another machine configuration is refused).
        temperature : float or ndarray (N,), optional
            C, one or per point, in place of the run's thermocouple log.
        policy : TemperaturePolicy, optional
            The caller's map side of the policy (None: the model's).
        reports : list, optional
            The kernel's report (:class:`cmmpose.KernelReport`) is appended.
        compare : callable, optional
            ``compare(model, other, inputs, xyz) -> um``: how the run's
            figures differ under an alternative (the evaluation's lengths or
            deviations; default: the points, less a rigid motion).
        once : set, optional
            The checks already said for this run (an uncertainty budget
            applies perturbed models to one run): each is said once.
        """
        scalar = temperature is not None and np.ndim(temperature) == 0
        model = self._map_policy(policy).with_policy(temperature=float(temperature) if scalar else None)
        inputs = RunInputs.from_run(run, model.temperature, temperature_policy=model.policy)
        check_inputs(model, inputs, "run")
        check_kinematics(model, run)
        where = "run"  # a command names the run before the message
        if once is None or ("single map", where) not in once:
            single_map_warning(model, inputs.temperature)
        if temperature is not None and not scalar:
            inputs = replace(inputs, temperature=np.ascontiguousarray(temperature, dtype=float))
        xyz, raw = model.compensate(inputs, return_report=True)
        model._check_application(inputs, xyz, where, once, compare=compare, every_call=True)
        report = KernelReport(**raw)
        warn_clamped(report)
        if reports is not None:
            reports.append(report)
        return xyz

    def domain_notes(self, data, xyz: np.ndarray | None = None) -> list[str]:
        """Where ``data`` (a Run, or the inputs of a run or point file) lie
        outside the domain the model was fitted on, and where its correction
        is not determined there, one sentence each
        (:mod:`cmmpose.model.domain`); empty for a model without effects.
        ``xyz``: the model's compensation of the data when the caller has it (mm)."""
        return self.where_it_holds(data, xyz)["notes"]

    def where_it_holds(self, data, xyz: np.ndarray | None = None) -> dict:
        """The model applied to ``data`` (a Run, or the inputs of a run or
        point file): ``notes`` (:meth:`domain_notes`), and its correction
        beyond the plain maps there with the correction's predicted standard
        uncertainty (``correction_um``, ``correction_u_um``: rms over a
        sample of the points, k = 1; :func:`cmmpose.model.domain.correction_uncertainty`)."""
        if not self.effects:
            return {"notes": [], "correction_um": 0.0, "correction_u_um": 0.0}
        inputs = RunInputs.from_run(data, self.temperature, temperature_policy=self.policy) \
            if isinstance(data, Run) else data
        found = correction_uncertainty(self, inputs, xyz)
        return {"notes": domain_notes(self.domain, inputs) + uncertainty_notes(found),
                "correction_um": found["correction_um"], "correction_u_um": found["uncertainty_um"]}

    def parameter_covariance(self, names) -> np.ndarray:
        """The covariance of the parameters ``names`` ('effect.param'), in
        their units: the diagnosis's where it kept it, else the standard
        uncertainties as independent (NaN: none stated, taken as 0)."""
        index = {n: i for i, n in enumerate(self.covariance.get("parameters", ()))}
        if names and all(n in index for n in names):
            at = [index[n] for n in names]
            return np.asarray(self.covariance["matrix"], float)[np.ix_(at, at)]
        sd = []
        for n in names:
            effect, _, param = n.rpartition(".")
            spec = next(s for s, _ in self.effects if s.name == effect)
            u = np.ravel(self.uncertainty.get(effect, np.full(spec.size, np.nan)))[spec.params.index(param)]
            sd.append(0.0 if not np.isfinite(u) else float(u))
        return np.diag(np.square(sd))

    def _map_policy(self, policy: TemperaturePolicy | None) -> Model:
        """The model under the caller's map side of ``policy`` (None: its own)."""
        if policy is None:
            return self
        return self.with_policy(out_of_range=policy.out_of_range, temperature_tolerance=policy.temperature_tolerance)

    def _check_application(self, inputs: RunInputs, xyz: np.ndarray, where: str, once: set | None, *, compare,
                           every_call: bool) -> None:
        """The checks of a model applied to data: where they leave its domain
        or its correction is not determined (:mod:`cmmpose.model.domain`:
        ``ModelDomainWarning``), where an aliased choice matters
        (:mod:`cmmpose.model.alternatives`). With ``once``, each is
        made once for ``where``: after its first check (``every_call``: a
        run) or its first warning (a file's chunks)."""
        if once is not None:
            once.add(("single map", where))
        if self.effects and (once is None or ("domain", where) not in once):
            notes = self.domain_notes(inputs, xyz)
            for note in notes:
                _log.warning("%s: %s", where, note)
                warnings.warn(f"{where}: {note}", ModelDomainWarning, stacklevel=4)
            if once is not None and (every_call or notes):
                once.add(("domain", where))
        if not self.alternatives or (once is not None and ("alternatives", where) in once):
            return
        found = check_alternatives(self, inputs, where, xyz=xyz, compare=compare)
        if once is not None and (every_call or any(f["warned"] for f in found)):
            once.add(("alternatives", where))

    # -- files --------------------------------------------------------------

    def to_dict(self) -> dict:
        return model_document(self)

    def save(self, path) -> Path:
        """Write the model (maps included) as JSON to ``path``, atomically
        (:mod:`cmmpose.atomicfile`: ``OutputError`` on a full disk, the earlier
        file left whole)."""
        return write_model(self, path)

    @classmethod
    def load(cls, path, user_effects=()) -> Model:
        """Read a model written by :meth:`save`; user-defined effects must be
        passed again (their functions are code, not data).

        Parameters
        ----------
        path : path-like
            The JSON file.
        user_effects : sequence of UserEffect
            Specs of the user-defined effects the file names.
        """
        return cls(*read_model(path, user_effects))

    def __repr__(self) -> str:
        eff = "; ".join(f"{s.name}: {s.describe(v)}" for s, v in self.effects) or "thesis model, no effects"
        return f"Model({eff})"


def _keep_policy(model: Model) -> None:
    """Model.__post_init__: a given temperature_policy's out_of_range,
    temperature_tolerance and log_hold are taken when the model's own three
    are at their defaults; the stored policy then keeps only the rest (its
    three at their defaults), so that ``replace(model, out_of_range=...)``
    means what it says."""
    pol = model.temperature_policy
    if pol is None:
        return
    if not isinstance(pol, TemperaturePolicy):
        raise InputTypeError(f"temperature_policy: expected a cmmpose.TemperaturePolicy, got {type(pol).__name__}")
    base = TemperaturePolicy()
    mine = (model.out_of_range, model.temperature_tolerance, model.log_hold)
    if mine == (base.out_of_range, base.temperature_tolerance, base.log_hold):
        object.__setattr__(model, "out_of_range", pol.out_of_range)
        object.__setattr__(model, "temperature_tolerance", pol.temperature_tolerance)
        object.__setattr__(model, "log_hold", pol.log_hold)
    object.__setattr__(model, "temperature_policy", replace(pol, out_of_range=base.out_of_range,
                                                            temperature_tolerance=base.temperature_tolerance,
                                                            log_hold=base.log_hold))



def run_kinematics(run: Run) -> str | None:
    """The machine configuration ``run.json`` says the run was measured on
    (its ``maps.kinematics``; a run naming the bundled thesis maps without
    one: ``'thesis'``); None when the run does not say (maps given apart)."""
    maps = run.maps or {}
    kin = maps.get("kinematics")
    if kin is None and maps.get("kind") == "bundled":
        return "thesis"
    return kin if isinstance(kin, str) else None


def run_label(run: Run, name: str | None = None) -> str:
    """How a message names ``run``: ``name`` if given, else the directory it
    was loaded from, else 'the run'."""
    return name or getattr(run, "source", None) or "the run"


def check_kinematics(model: Model, run: Run, name: str | None = None) -> None:
    """Refuse to apply ``model`` to ``run`` (or diagnose the run from it) when
    the model's maps are stacked for another machine configuration than the
    one run.json names: every map error would act through the wrong lever
    arms (a moving-table model on a moving-bridge run: 1.1 um against 0.3 um).
    A run that names no configuration is not checked.

    Raises
    ------
    InputError
        Naming the run and both configurations.
    """
    kin = run_kinematics(run)
    if kin is None or kin == model.maps.kinematics:
        return
    raise InputError(f"{run_label(run, name)}: run.json says the machine is configured as {kin!r}, but the model's "
                     f"maps are stacked as {model.maps.kinematics!r}: the model was found on (or made for) another "
                     f"machine; diagnose this run from its own maps (a machine file with kinematics = {kin!r})")



def _known(model: Model, effect) -> dict[str, EffectSpec]:
    if isinstance(effect, EffectSpec):
        return {effect.name: effect}
    known = dict(LIBRARY)
    if isinstance(effect, str) and effect not in (s.name for s, _ in model.effects):
        known[effect] = resolve(effect)
    known |= {s.name: s for s, _ in model.effects}
    return known


def _user_inputs(inputs: RunInputs, xyz: np.ndarray) -> dict[str, np.ndarray]:
    out = {"u": inputs.uv[:, 0], "v": inputs.uv[:, 1], "D": inputs.scales[:, 0], "E": inputs.scales[:, 1],
           "F": inputs.scales[:, 2], "temperature": inputs.temperature, "x": xyz[:, 0], "y": xyz[:, 1],
           "z": xyz[:, 2], "pose_id": np.asarray(inputs.pose_ids)[inputs.pose_index],
           "incidence": inputs.incidence if inputs.incidence is not None else np.full(len(xyz), np.nan)}
    out |= {"t": inputs.t, "scan_id": inputs.scan_id}
    return out


def inputs_with_incidence(model: Model, inputs: RunInputs) -> RunInputs:
    """Incidence angles from sphere fits of the points compensated by the
    thesis model (the angle barely depends on the effects); points of scans
    that cannot be fitted get 0."""
    base = replace(model, effects=())
    xyz = base.compensate(inputs)
    fits = fit_spheres(xyz, inputs.scan_id, on_error="return")
    centres = {k: c for k, c, e in zip(fits.labels.tolist(), fits.centre, fits.error) if e is None}
    theta = np.zeros(len(xyz))
    ok = np.isin(inputs.scan_id, list(centres))
    if ok.any():
        theta[ok] = incidence_angles(xyz[ok], inputs.scan_id[ok], centres, replace(inputs, pose_index=inputs.pose_index[ok]))
    return inputs.with_incidence(theta)


def as_model(model, kinematics: str | None = None) -> Model:
    """The starting model of a diagnosis: a Model as given, maps as the thesis
    model, None as the thesis maps (stacked as ``kinematics``, the
    configuration the runs name; None: the thesis machine's)."""
    if model is None:
        return Model(ErrorMapSet.thesis().with_kinematics(kinematics or "thesis"))
    if isinstance(model, (ErrorMap, ErrorMapSet)):
        return Model(model)
    if not isinstance(model, Model):
        raise InputTypeError(f"model: expected a Model, ErrorMap or ErrorMapSet, got {type(model).__name__}")
    return model
