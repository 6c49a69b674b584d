"""The truth machine: exact rigid-body kinematics of the CMM with its error
maps and extra effects (the physics is in rust/core/src/truth.rs)."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from .. import _core
from .._arrays import as_rows
from ..errormap import ErrorMap, ErrorMapSet
from ..errors import InputError, InputTypeError
from ..effects import Effect, channel_roles

#: Thermocouple roles of the standard channels (cmmpose.sim.thermocouples.CHANNELS).
STANDARD_ROLES = ("x_scale", "y_scale", "z_scale", "granite_top", "granite_bottom")

#: Machine temperature: one value (C), or a function of time (s) -> C.
Temperature = float | Callable[[np.ndarray], np.ndarray]


def temperature_series(times, values) -> Callable[[np.ndarray], np.ndarray]:
    """A temperature that follows a logged series, linear in time.

    Parameters
    ----------
    times : array_like, shape (K,)
        Strictly increasing times in s.
    values : array_like, shape (K,)
        Temperatures in degrees C.
    """
    times = np.asarray(times, dtype=float)
    values = np.asarray(values, dtype=float)
    if times.ndim != 1 or times.shape != values.shape or len(times) < 2 or np.any(np.diff(times) <= 0):
        raise InputError("temperature_series: times must be strictly increasing, same length as values, at least 2")

    def at(t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        if np.any(t < times[0]) or np.any(t > times[-1]):
            raise InputError(f"temperature_series: times {t.min():g}..{t.max():g} s outside the series {times[0]:g}..{times[-1]:g} s")
        return np.interp(t, times, values)

    return at


class TruthMachine:
    """A CMM whose errors are exactly its maps plus the given effects.

    Parameters
    ----------
    maps : ErrorMap or ErrorMapSet
        The machine's real component errors. A single map applies at its own
        temperature only.
    effects : sequence of Effect
        Extra physics (see :mod:`cmmpose.effects`); their Rust terms act
        here, forward, in exact rigid-body kinematics.
    """

    def __init__(self, maps: ErrorMap | ErrorMapSet, effects: Sequence[Effect] = ()):
        if isinstance(maps, ErrorMap):
            if maps.temperature is None:
                raise InputError("maps: a single ErrorMap needs a temperature to act as a truth machine")
            maps = ErrorMapSet([maps])
        if not isinstance(maps, ErrorMapSet):
            raise InputTypeError(f"maps: expected ErrorMap or ErrorMapSet, got {type(maps).__name__}")
        self.maps = maps
        self.effects = tuple(effects)
        roles = set(STANDARD_ROLES) | set(channel_roles())
        for e in self.effects:
            if e.sensor_input and e.sensor not in roles:
                raise InputError(f"effect {e.name}: sensor {e.sensor!r} is not a thermocouple role "
                                 f"({', '.join(sorted(roles))})")
        terms: dict[str, np.ndarray] = {}
        for e in self.effects:
            if e.on_scanner:
                continue  # acts on each profile (cmmpose.sim.scanner), not on the machine
            for name, values in e.truth_terms().items():
                terms[name] = terms.get(name, 0.0) + np.asarray(values, dtype=float)
        self._terms = {k: [float(x) for x in v] for k, v in terms.items()}

    def role_offsets(self, times: np.ndarray) -> dict[str, np.ndarray]:
        """How far each thermocouple role reads above the machine mean (K) at ``times`` (s)."""
        times = np.asarray(times, dtype=float)
        out: dict[str, np.ndarray] = {}
        for e in self.effects:
            for role, k in e.role_offsets(times).items():
                out[role] = out.get(role, 0.0) + np.broadcast_to(np.asarray(k, dtype=float), times.shape)
        return out

    def states(self, times: np.ndarray, temperature: Temperature) -> dict[str, np.ndarray]:
        """The machine's real temperatures at ``times`` (s), as the truth
        machine's named inputs: ``temperature`` (C, the machine mean as the
        scale thermocouples see it), ``axis_temperature`` (K, 3) C,
        ``gradient`` (granite top minus bottom, K) and ``<role>_temperature``
        (C) for every other thermocouple role an effect warms."""
        times = np.asarray(times, dtype=float)
        mean = temperature(times) if callable(temperature) else np.full(times.shape, float(temperature))
        mean = np.asarray(mean, dtype=float)
        off = self.role_offsets(times)
        zero = np.zeros(times.shape)
        axes = [off.get(r, zero) for r in ("x_scale", "y_scale", "z_scale")]
        states = {
            # Squareness follows the machine mean as the scale thermocouples
            # see it (thesis 6.4), which includes the carriages' offsets.
            "temperature": np.ascontiguousarray(mean + (axes[0] + axes[1] + axes[2]) / 3.0),
            "axis_temperature": np.ascontiguousarray(np.column_stack([mean + a for a in axes])),
            "gradient": np.ascontiguousarray(off.get("granite_top", zero) - off.get("granite_bottom", zero)),
        }
        for role, k in off.items():
            if role not in STANDARD_ROLES:
                states[f"{role}_temperature"] = np.ascontiguousarray(mean + k)
        for e in self.effects:
            # A thermocouple role's channels read the room mean plus the role's offset.
            states |= {k: np.ascontiguousarray(v, dtype=float) for k, v in
                       e.truth_inputs(lambda role: mean + off.get(role, zero)).items()}
        return states

    def frames(self, scales, states) -> dict[str, np.ndarray]:
        """True mount points ``p`` (K, 3) mm, ram orientations ``r`` (K, 3, 3)
        and factors on the mount offset ``mount_scale`` (K,).

        Parameters
        ----------
        scales : array_like, shape (K, 3)
            Where the carriages really are, as scale readings D, E, F in mm.
        states : dict
            From :meth:`states`.
        """
        return _core.true_frames(as_rows("scales", scales, 3), self.maps._core, inputs=states,
                                 effects=self._terms)
