"""What every physical effect declares: its one name, a one-line summary
(CLI help, diagnosis table, HTML report), its model parameters with units
and priors, where it acts, the run inputs it needs, and its simulator hooks.

An effect is a frozen dataclass; its fields are what the simulator needs to
produce it (often the model parameters themselves, sometimes a scenario
such as a temperature rise). Class attributes describe it once for every
layer. Effects that act per point (``acts = 'kernel'``) have a Rust term of
the same name in rust/core/src/effects.rs, which the truth machine applies
forward and the compensation kernel inverts.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import ClassVar

import numpy as np

from ..errors import InputError

__all__ = ["Effect", "Param"]


@dataclass(frozen=True)
class Param:
    """One model parameter of an effect.

    Parameters
    ----------
    unit : str
        Its unit ('arc-second', 'ppm', 's', 'mm', '1', ...).
    prior : float
        Typical magnitude, in ``unit``: the diagnosis's finite-difference
        step and the scale at which the effect counts as observable.
    step : float, optional
        Finite-difference step, in ``unit``, when one typical magnitude
        would leave the maps' range.
    """

    unit: str
    prior: float
    step: float | None = None


@dataclass(frozen=True)
class Effect:
    """Base class of the physical effects; every hook does nothing.

    Class attributes (set by each effect)
    -------------------------------------
    name : str
        The one name everywhere: Python, Rust term, CLI, JSON, docs.
    summary : str
        One line: what the effect is.
    reveal : str
        The measurement that shows it when a run cannot.
    params : dict of str -> Param
        The model's parameters, in order.
    acts : {'kernel', 'pose', 'length'}
        Per point (a Rust term), on the digitizer pose handed to the
        kernel, or on an artefact's predicted length.
    needs : tuple of str
        Run inputs the model needs: 'axis_temperature', 'gradient',
        'velocity', 'incidence', '<role>_temperature' (the channels of a
        thermocouple role), 'poses>1'.
    channels : tuple of (str, str)
        Thermocouple channels (name, role) the effect brings to a run.
    hints : dict of str -> dict of str -> str
        How the effect shows in the residual patterns the diagnosis draws
        (diagnosis/patterns.py): ``{"length": {quantity: phrase}, "point":
        {quantity: phrase}}``, quantities such as ``'dx^2'``, ``'dx*dy'``,
        ``'mid x'``, ``'time'`` (ballbar lengths) or ``'u'``, ``'incidence'``,
        ``'D in scan'`` (point residuals). The pattern's hint names every
        effect that declares its quantity.
    on_scanner : bool
        Whether its term acts on what the scanner reports (u, v): the
        simulator applies it to each profile rather than in the machine.
    sensor_input : str or None
        For an effect that follows one group of thermocouples the data
        choose (a field ``sensor`` names its role): the kernel input that
        carries that group's temperature. The diagnosis tries one candidate
        per role of the run, named '<name>@<role>'.
    """

    name: ClassVar[str] = ""
    summary: ClassVar[str] = ""
    reveal: ClassVar[str] = ""
    params: ClassVar[dict[str, Param]] = {}
    acts: ClassVar[str] = "kernel"
    needs: ClassVar[tuple[str, ...]] = ()
    channels: ClassVar[tuple[tuple[str, str], ...]] = ()
    on_scanner: ClassVar[bool] = False
    sensor_input: ClassVar[str | None] = None
    hints: ClassVar[dict[str, dict[str, str]]] = {}

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(f.default, str):  # a choice by name (a thermocouple role)
                if not (isinstance(value, str) and value.strip()):
                    raise InputError(f"effect {self.name}: {f.name} must be a name, got {value!r}")
                continue
            try:
                finite = np.all(np.isfinite(np.asarray(value, dtype=float)))
            except (TypeError, ValueError):
                finite = False
            if not finite:
                raise InputError(f"effect {self.name}: {f.name} must be finite, got {value!r}")

    @classmethod
    def text_fields(cls) -> tuple[str, ...]:
        """Fields that hold a name rather than a number (e.g. ``sensor``)."""
        return tuple(f.name for f in fields(cls) if isinstance(f.default, str))

    @classmethod
    def units(cls) -> dict[str, str]:
        """Unit of each simulator field (model parameters and scenario)."""
        out = {p: cls.params[p].unit for p in cls.params}
        out.update(getattr(cls, "scenario_units", {}))
        return {f.name: out.get(f.name, "") for f in fields(cls)}

    # -- simulator hooks ------------------------------------------------------

    def truth_terms(self) -> dict[str, list[float]]:
        """Rust terms the truth machine applies forward, name -> values."""
        if self.acts != "kernel":
            return {}
        return {self.name: [float(getattr(self, p)) for p in self.params]}

    def role_offsets(self, times: np.ndarray) -> dict[str, np.ndarray | float]:
        """How far each thermocouple role reads above the machine mean at
        ``times`` (s), K; the truth machine's temperatures follow."""
        return {}

    def truth_inputs(self, role_temperature) -> dict[str, np.ndarray]:
        """Extra named inputs of the truth machine's term, from
        ``role_temperature(role) -> ndarray`` (C at the states' times)."""
        return {}

    def pose(self, pose: np.ndarray, offset: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The true pose (degrees) and mount offset (mm) of a calibrated one."""
        return pose, offset

    def latency(self) -> float:
        """Seconds between the scale latch and the profile."""
        return 0.0

    def artefact_scale(self, temperature: float) -> float:
        """Factor on the artefact's length at machine temperature (C)."""
        return 1.0

    # -- model hooks (acts 'pose' and 'length'; 'kernel' effects are Rust) -----

    @classmethod
    def adjust_poses(cls, values: np.ndarray, poses: np.ndarray, rows: slice | int) -> None:
        """Apply ``values`` to ``poses`` (P, 6: alpha, beta, gamma deg,
        U1, V1, W1 mm) in place at ``rows``."""
        raise NotImplementedError(f"effect {cls.name} does not act on the pose")
