"""The truth machine: exact rigid-body kinematics of the CMM with its error
maps and extra effects (the physics is in rust/core/src/truth.rs)."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from .. import _core
from .._arrays import as_rows
from ..errormap import ErrorMap, ErrorMapSet
from ..errors import InputError
from .effects import Effect

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
        Extra physics (see ``cmmpose.sim.effects``); machine-side hooks act here.
    """

    def __init__(self, maps: ErrorMap | ErrorMapSet, effects: Sequence[Effect] = ()):
        if isinstance(maps, ErrorMap):
            if maps.temperature is None:
                raise InputError("maps: a single ErrorMap needs a temperature to act as a truth machine")
            maps = ErrorMapSet([maps])
        if not isinstance(maps, ErrorMapSet):
            raise InputError(f"maps: expected ErrorMap or ErrorMapSet, got {type(maps).__name__}")
        self.maps = maps
        self.effects = tuple(effects)
        fx = {k: np.zeros(3) for k in ("squareness_offset", "scale_error_ppm", "roll_slope", "granite_squareness")}
        for e in self.effects:
            e.machine(fx)
        self._fx = tuple(tuple(float(x) for x in fx[k]) for k in ("squareness_offset", "scale_error_ppm", "roll_slope", "granite_squareness"))

    def states(self, times: np.ndarray, temperature: Temperature) -> np.ndarray:
        """(K, 5) real temperatures at ``times`` (s): carriage X, Y, Z, squareness (C), granite gradient (K)."""
        times = np.asarray(times, dtype=float)
        mean = temperature(times) if callable(temperature) else np.full(times.shape, float(temperature))
        states = np.zeros((len(times), 5))
        states[:, 0:4] = mean[:, None]
        for e in self.effects:
            states = e.states(states, times)
        return states

    def frames(self, scales, states) -> tuple[np.ndarray, np.ndarray]:
        """True mount points P (K, 3) mm and ram orientations R (K, 3, 3).

        Parameters
        ----------
        scales : array_like, shape (K, 3)
            Where the carriages really are, as scale readings D, E, F in mm.
        states : array_like, shape (K, 5)
            From :meth:`states`.
        """
        return _core.true_frames(as_rows("scales", scales, 3), as_rows("states", states, 5), self.maps._core, self._fx)
