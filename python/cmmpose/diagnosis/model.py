"""A compensation model with physical effects: the thesis model (error maps,
pose, machine-mean temperature) plus named effects with fitted parameters.
Immutable: :meth:`Model.add` returns a new model."""

from __future__ import annotations

import json
import math
import tempfile
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from .. import _core
from .._json import dumps as strict_json
from ..atomicfile import write_text
from ..errormap import ErrorMap, ErrorMapSet
from ..errors import Error, InputError, InputTypeError, MapError
from ..policy import LOG_HOLD, TEMPERATURE_TOLERANCE, check_policy
from ..pose import digitizer
from ..run import Run
from ..temperature import TemperaturePolicy
from .effects import LIBRARY, EffectSpec, UserEffect, effect_spec, resolve
from .inputs import RunInputs

__all__ = ["Model", "MODEL_SCHEMA", "check_kinematics", "run_kinematics"]

#: ``schema`` of a saved model file.
MODEL_SCHEMA = "cmmpose-model"


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
    #: holds (:class:`cmmpose.diagnosis.aliases.Alternative`): saved, and
    #: applying the model warns where they predict differently.
    alternatives: tuple = field(default=(), compare=False, repr=False)
    _inputs_cache: dict = field(default_factory=dict, compare=False, repr=False)

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
        return replace(self, effects=tuple(effects), alternatives=alternatives, _inputs_cache=self._inputs_cache)

    def without(self, name: str) -> Model:
        """A model without effect ``name``."""
        self.values(name)
        return replace(self, effects=tuple((s, v) for s, v in self.effects if s.name != name),
                       _inputs_cache=self._inputs_cache)

    def add(self, effect, run: Run | None = None, *, values=None) -> Model:
        """A new model with ``effect`` added: its parameters given as
        ``values``, or fitted to ``run`` (jointly with the effects already in
        the model, by Gauss-Newton through the Rust kernel).

        Parameters
        ----------
        effect : str or EffectSpec
            A library name (see ``cmmpose.diagnosis.LIBRARY``) or a spec
            (e.g. a :class:`UserEffect`).
        run : Run, optional
            The run to fit the parameters to.
        values : array_like, optional
            Parameter values in the effect's units, instead of fitting.
        """
        spec = effect_spec(effect, _known(self, effect))
        if spec.name in self.names:
            raise InputError(f"effect {spec.name!r} is already in the model; use with_values to change it")
        if values is not None:
            return self.with_values(spec, values)
        if run is None:
            raise InputError(f"add({spec.name!r}): give a run to fit it to, or values=")
        from .identify import fit_model

        return fit_model(self.with_values(spec, np.zeros(spec.size)), run)

    # -- compensation -------------------------------------------------------

    def inputs(self, run: Run) -> RunInputs:
        """Per-point inputs of ``run`` (cached per run object)."""
        key = id(run)
        cached = self._inputs_cache.get(key)
        if cached is None or cached[0] is not run:
            self._inputs_cache.clear()
            cached = (run, inputs_with_incidence(self, RunInputs.from_run(run, self.temperature, temperature_policy=self.policy)))
            self._inputs_cache[key] = cached
        return cached[1]

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
        inputs = run if isinstance(run, RunInputs) else self.inputs(run)
        # Incidence angles come from a first pass through the model (the points' surface normals): computed only
        # when an effect declares it needs them (``needs``) and is switched on.
        needs_incidence = any("incidence" in s.needs and np.any(v != 0) for s, v in self.effects)
        if needs_incidence and inputs.incidence is None:
            inputs = inputs_with_incidence(self, inputs)
        digitizers = [digitizer(p[:3], p[3:]) for p in self.poses(inputs)]
        named = inputs.named()
        # An effect following a chosen thermocouple group reads that group's temperature.
        named |= {s.sensor_input: inputs.sensor(s.sensor) for s, _ in self.effects if s.sensor_input}
        xyz, report = _core.compensate_model(
            inputs.uv, inputs.scales, self.maps._core, digitizers, pose_index=inputs.pose_index,
            inputs=named, effects=self.kernel_terms(), out_of_range=self.out_of_range,
            temperature_tolerance=float(self.temperature_tolerance))
        clamped = report["clamped_points"]
        users = [(s, v) for s, v in self.effects if s.kind == "python"]
        if users:
            pts = _user_inputs(inputs, xyz)
            for spec, v in users:
                xyz = xyz + spec.correction(pts, v)
        if return_report:
            return xyz, report
        return (xyz, clamped) if return_clamped else xyz

    def evaluate(self, run: Run):
        """Ballbar figures of ``run`` under this model (see ``ModelFigures``);
        a run on another machine configuration (:func:`check_kinematics`) or
        whose calibrated bar length is far from the lengths it measures, or
        an artefact's ball far from its calibrated place
        (:func:`cmmpose.diagnosis.observables.check_first_observation`) is
        refused."""
        from .observables import ObservationLayout, check_first_observation, figures, observe

        check_kinematics(self, run)
        inputs = self.inputs(run)
        layout = ObservationLayout.from_run(run, inputs)
        observed = observe(layout, self.compensate(inputs), self.expansion_ppm_per_kelvin, inputs.scan_id)
        check_first_observation(layout, observed, run_label(run))
        return figures(layout, None, self, observed=observed)

    # -- pickling (sent to a worker process: cmmpose.scale) -----------------

    def __getstate__(self) -> dict:
        """The model without its per-run inputs cache (which holds a run)."""
        return {**self.__dict__, "_inputs_cache": {}}

    # -- files --------------------------------------------------------------

    def to_dict(self) -> dict:
        maps = self.maps.maps if isinstance(self.maps, ErrorMapSet) else [self.maps]
        texts = []
        with tempfile.TemporaryDirectory() as d:
            for i, m in enumerate(maps):
                p = Path(d) / f"map{i}.csv"
                m.write(p)
                texts.append(p.read_text())
        return {
            "schema": MODEL_SCHEMA,
            "schema_version": 1,
            "maps": {"kind": "set" if isinstance(self.maps, ErrorMapSet) else "map", "csv": texts,
                     "kinematics": self.maps.kinematics},
            "temperature": self.temperature,
            "out_of_range": self.out_of_range,
            "temperature_tolerance_K": self.temperature_tolerance,
            "log_hold_s": self.log_hold,
            "temperature_policy": self.policy.to_dict(),
            **({"temperature_log": self.thermal} if self.thermal else {}),
            "effects": [{"name": s.name, "kind": s.kind, "params": dict(zip(s.params, map(float, v))),
                         "units": dict(zip(s.params, s.units))} | _uncertainty_entry(self, s) for s, v in self.effects],
            **({"alternatives": [a.to_dict() for a in self.alternatives if a.chosen in self.names]}
               if self.alternatives else {}),
        }

    def save(self, path) -> Path:
        """Write the model (maps included) as JSON to ``path``, atomically
        (:mod:`cmmpose.atomicfile`: ``OutputError`` on a full disk, the earlier
        file left whole)."""
        path = Path(path)
        doc = self.to_dict()
        if _holds_nan(doc):
            raise InputError(f"{path}: the model holds a value that is not a number (NaN): not written")
        try:
            # Standard JSON only (cmmpose._json): an undetermined uncertainty (inf) is written null and named
            # in the top-level "non_finite" list; load reads null back as inf.
            text = strict_json(doc, indent=1)
        except ValueError:
            raise InputError(f"{path}: the model holds a value that is not finite (inf): not written") from None
        write_text(path, text)
        return path

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
        path = Path(path)
        try:
            doc = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError, RecursionError) as e:
            raise InputError(f"{path}: not a readable model file ({e})") from None
        if not isinstance(doc, dict) or doc.get("schema") != MODEL_SCHEMA or doc.get("schema_version") != 1:
            raise InputError(f"{path}: not a {MODEL_SCHEMA} version 1 file")
        try:
            with tempfile.TemporaryDirectory() as d:
                maps = []
                for i, text in enumerate(doc["maps"]["csv"]):
                    p = Path(d) / f"map{i}.csv"
                    p.write_text(text)
                    try:
                        maps.append(ErrorMap.read(p))
                    except MapError as exc:  # name the user's file, not the temporary one
                        raise MapError(str(exc).replace(str(p), f"{path} (maps.csv[{i}])")) from None
            kind = doc["maps"]["kind"]
            if kind not in ("set", "map"):
                raise InputError(f"{path}: maps.kind must be 'set' or 'map', got {kind!r}")
            if not maps:
                raise InputError(f"{path}: maps.csv lists no map")
            if kind == "map" and len(maps) != 1:
                raise InputError(f"{path}: maps.kind 'map' needs exactly one map, got {len(maps)}")
            model_maps = ErrorMapSet(maps) if kind == "set" else maps[0]
            kinematics = doc["maps"].get("kinematics", "thesis")  # files before machine configurations: thesis
            if not isinstance(kinematics, str):
                raise InputError(f"{path}: maps.kinematics must be a configuration name, got {kinematics!r}")
            model_maps = model_maps.with_kinematics(kinematics)
            users = {}
            for u in user_effects:
                if users.get(u.name, u) is not u:  # which one the file means would depend on their order
                    raise InputError(f"user_effects: two effects are named {u.name!r}: give each effect once",
                                     what=u.name)
                users[u.name] = u
            effects, unc = [], {}
            for e in doc["effects"]:
                name = e["name"]
                if name.startswith("map:"):  # a map correction: rebuilt from its name
                    from .mapfamily import parse as parse_map

                    spec = parse_map(name)
                elif e.get("kind") == "python":
                    if name not in users:
                        raise InputError(f"{path}: effect {name!r} is user-defined", remedy="user_effects")
                    spec = users[name]
                else:
                    spec = resolve(name)
                if set(e["params"]) != set(spec.params):
                    raise InputError(f"{path}: effect {name!r} has parameters {sorted(e['params'])}, "
                                     f"expected {list(spec.params)}")
                values = [e["params"][p] for p in spec.params]
                bad = [p for p, v in zip(spec.params, values) if isinstance(v, bool) or not isinstance(v, (int, float))]
                if bad:
                    raise InputError(f"{path}: effect {name!r}: parameter {bad[0]!r} = {e['params'][bad[0]]!r} "
                                     f"is not a number")
                effects.append((spec, np.array([float(v) for v in values])))
                if "uncertainty" in e:  # optional: null is a parameter the data did not determine
                    unc[name] = _saved_uncertainty(e["uncertainty"], spec, path)
            alternatives = _saved_alternatives(doc.get("alternatives") or [], users, [s.name for s, _ in effects],
                                               path)
            return cls(model_maps, tuple(effects), doc.get("temperature"), doc.get("out_of_range", "raise"),
                       doc.get("temperature_tolerance_K", TEMPERATURE_TOLERANCE), doc.get("log_hold_s", LOG_HOLD),
                       unc, _saved_policy(doc.get("temperature_policy"), path), doc.get("temperature_log") or {},
                       alternatives)
        except Error:  # already names the file and what is wrong in it
            raise
        except (KeyError, TypeError, ValueError) as e:
            raise InputError(f"{path}: malformed model file ({type(e).__name__}: {e})") from None

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


def _saved_spec(name: str, kind, users: dict, path) -> EffectSpec:
    """The spec of a saved effect named ``name`` (a map correction is rebuilt from its name)."""
    if name.startswith("map:"):
        from .mapfamily import parse as parse_map

        return parse_map(name)
    if kind == "python":
        if name not in users:
            raise InputError(f"{path}: effect {name!r} is user-defined", remedy="user_effects")
        return users[name]
    return resolve(name)


def _saved_alternatives(entries, users: dict, names, path) -> tuple:
    """The ``alternatives`` of a model file (files before them: none). An
    alternative to an effect the model lacks is refused; a user-defined one
    whose spec was not passed is left out, with a log line (the model still
    applies; only the check of that alternative is lost)."""
    from .aliases import Alternative

    out = []
    for i, e in enumerate(entries):
        name, chosen = e["name"], e["chosen"]
        if chosen not in names:
            raise InputError(f"{path}: alternatives[{i}] ({name}) is an alternative to {chosen!r}, "
                             f"which the model does not hold")
        # A map correction (kind "python", name "map:...") is a library shape rebuilt from its name
        # (_saved_spec): only a user-defined effect needs its spec passed again.
        if e.get("kind") == "python" and not name.startswith("map:") and name not in users:
            import logging

            logging.getLogger("cmmpose.diagnosis.aliases").warning(
                "%s: the alternative %s to %s is user-defined and was not passed: it is not checked", path, name,
                chosen)
            continue
        spec = _saved_spec(name, e.get("kind"), users, path)
        values = [e["params"][p] for p in spec.params]
        if any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in values):
            raise InputError(f"{path}: alternatives[{i}] ({name}): a parameter is not a number")
        out.append(Alternative(chosen, spec, np.array(values, float), float(e.get("in_sample_difference_um") or 0.0),
                               str(e.get("reason", ""))))
    return tuple(out)


def _saved_uncertainty(entry, spec: EffectSpec, path) -> np.ndarray:
    """The standard uncertainty of a saved effect's parameters, in its units:
    null (or absent) is a parameter the data did not determine (inf); a NaN,
    a negative value or one that is not a number is refused, naming the file,
    the effect and the parameter (an evaluation's budget would otherwise drop
    its row without a word)."""
    if not isinstance(entry, dict):
        raise InputError(f"{path}: effect {spec.name!r}: uncertainty must map each parameter to a number, "
                         f"got {entry!r}")
    out = []
    for p in spec.params:
        v = entry.get(p)
        if v is None:
            out.append(np.inf)
            continue
        if isinstance(v, bool) or not isinstance(v, (int, float)) or math.isnan(v) or v < 0:
            raise InputError(f"{path}: effect {spec.name!r}: the uncertainty of parameter {p!r} is {v!r}; expected "
                             f"a standard uncertainty >= 0 in {spec.units[spec.params.index(p)]}, or null for a "
                             f"parameter the data did not determine")
        out.append(float(v))
    return np.array(out)


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


def _saved_policy(doc, path) -> TemperaturePolicy | None:
    if doc is None:  # files before the policy was saved whole
        return None
    try:
        return TemperaturePolicy.from_dict(doc)
    except InputError as exc:
        raise InputError(f"{path}: temperature_policy: {exc}") from None


def _uncertainty_entry(model: Model, spec: EffectSpec) -> dict:
    """``{"uncertainty": {param: u}}`` of an effect whose uncertainty the model knows (inf: undetermined,
    which :meth:`Model.save` writes null and names in ``non_finite``)."""
    u = model.uncertainty.get(spec.name)
    if u is None:
        return {}
    return {"uncertainty": {p: (float(x) if np.isfinite(x) else math.inf) for p, x in zip(spec.params, np.ravel(u))}}


def _holds_nan(obj) -> bool:
    if isinstance(obj, dict):
        return any(_holds_nan(v) for v in obj.values())
    if isinstance(obj, (list, tuple)):
        return any(_holds_nan(v) for v in obj)
    return isinstance(obj, float) and math.isnan(obj)


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
    from ..fitting import fit_spheres
    from .inputs import incidence_angles

    base = replace(model, effects=(), _inputs_cache={})
    xyz = base.compensate(inputs)
    fits = fit_spheres(xyz, inputs.scan_id, on_error="return")
    centres = {k: c for k, c, e in zip(fits.labels.tolist(), fits.centre, fits.error) if e is None}
    theta = np.zeros(len(xyz))
    ok = np.isin(inputs.scan_id, list(centres))
    if ok.any():
        theta[ok] = incidence_angles(xyz[ok], inputs.scan_id[ok], centres, replace(inputs, pose_index=inputs.pose_index[ok]))
    return inputs.with_incidence(theta)
