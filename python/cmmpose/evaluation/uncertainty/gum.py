"""The GUM toolkit: an input quantity with its standard uncertainty and sensitivity, a budget that combines them
(GUM eq. 10) and states the expanded uncertainty, the standard uncertainty of a mean.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..._validate import finite
from ...errors import InputError


@dataclass(frozen=True)
class Input:
    """One input quantity of an uncertainty budget (GUM 4.1).

    Parameters
    ----------
    name : str
        What the input is (e.g. "E1: digitizer probing").
    value : float
        Its estimate x_i, in ``unit`` (0 for an error term whose expectation is zero).
    standard_uncertainty : float
        Its standard uncertainty u(x_i) >= 0, in ``unit``.
    unit : str
        Unit of ``value`` and ``standard_uncertainty`` (e.g. "um", "deg", "mm", "K").
    sensitivity : float
        Sensitivity coefficient c_i = df/dx_i, in (budget unit) per ``unit``;
        its sign is kept for the record, only |c_i u_i| enters the budget.
    note : str
        Where the number comes from.
    """

    name: str
    value: float
    standard_uncertainty: float
    unit: str
    sensitivity: float = 1.0
    note: str = ""

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise InputError(f"Input.name: expected a non-empty string, got {self.name!r}")
        object.__setattr__(self, "value", finite(f"Input {self.name!r} value", self.value))
        u = finite(f"Input {self.name!r} standard_uncertainty", self.standard_uncertainty)
        if u < 0:
            raise InputError(f"Input {self.name!r}: standard_uncertainty must be >= 0, got {u}")
        object.__setattr__(self, "standard_uncertainty", u)
        object.__setattr__(self, "sensitivity", finite(f"Input {self.name!r} sensitivity", self.sensitivity))

    @property
    def contribution(self) -> float:
        """|c_i| u(x_i): this input's uncertainty contribution, in the budget's unit."""
        return abs(self.sensitivity) * self.standard_uncertainty

    def to_dict(self) -> dict:
        return {"name": self.name, "value": self.value, "standard_uncertainty": self.standard_uncertainty,
                "unit": self.unit, "sensitivity": self.sensitivity, "contribution": self.contribution,
                "note": self.note}


@dataclass(frozen=True)
class Budget:
    """An uncertainty budget for uncorrelated inputs (GUM eq. 10):
    u_c(y) = sqrt(sum_i (c_i u(x_i))^2).

    Parameters
    ----------
    name : str
        The measurand (e.g. "U1").
    inputs : sequence of Input
        The input quantities; each contribution c_i u(x_i) is in ``unit``.
    unit : str
        Unit of the measurand and of the combined uncertainty (e.g. "um", "mm").
    source : str
        Where the budget comes from (thesis section, equation, lines).
    printed : float, optional
        The combined standard uncertainty the source prints, in ``unit``, kept
        for comparison (shown by :meth:`table`; never used in a calculation).
    """

    name: str
    inputs: tuple[Input, ...]
    unit: str
    source: str = ""
    printed: float | None = None

    def __post_init__(self) -> None:
        inputs = tuple(self.inputs)
        if not inputs:
            raise InputError(f"Budget {self.name!r}: needs at least one Input")
        bad = [type(i).__name__ for i in inputs if not isinstance(i, Input)]
        if bad:
            raise InputError(f"Budget {self.name!r}: inputs must be Input objects, got {bad[0]}")
        object.__setattr__(self, "inputs", inputs)
        if self.printed is not None:
            object.__setattr__(self, "printed", finite(f"Budget {self.name!r} printed", self.printed))

    @property
    def variance(self) -> float:
        """u_c^2 = sum (c_i u_i)^2, in ``unit`` squared."""
        return float(sum(i.contribution ** 2 for i in self.inputs))

    @property
    def combined_standard_uncertainty(self) -> float:
        """u_c = sqrt(sum (c_i u_i)^2), in ``unit`` (GUM eq. 10, uncorrelated inputs)."""
        return math.sqrt(self.variance)

    def expanded_uncertainty(self, k: float = 2.0) -> float:
        """U = k u_c, in ``unit``; k = 2 gives about 95 % coverage for a normal distribution."""
        k = finite("k", k)
        if k <= 0:
            raise InputError(f"k: the coverage factor must be positive, got {k}")
        return k * self.combined_standard_uncertainty

    def shares(self) -> list[float]:
        """Each input's share of the variance, (c_i u_i)^2 / u_c^2 (0..1), in input order."""
        var = self.variance
        return [(i.contribution ** 2 / var if var > 0 else 0.0) for i in self.inputs]

    def table(self, digits: int = 3) -> str:
        """The budget as a plain-text table (one row per input, then u_c and U).

        Parameters
        ----------
        digits : int
            Significant digits of the numbers.
        """
        g = f"{{:.{int(digits)}g}}".format
        head = ["input", "value", "u(x_i)", "unit", "c_i", f"|c_i| u(x_i) [{self.unit}]", "share"]
        rows = [[i.name, f"{i.value:.6g}", g(i.standard_uncertainty), i.unit, g(i.sensitivity), g(i.contribution),
                 f"{100 * s:.1f} %"] for i, s in zip(self.inputs, self.shares())]
        widths = [max(len(r[j]) for r in [head, *rows]) for j in range(len(head))]
        left = {0, 3}

        def line(r):
            return "  ".join(c.ljust(w) if j in left else c.rjust(w) for j, (c, w) in enumerate(zip(r, widths)))

        out = [f"Uncertainty budget: {self.name}" + (f"  ({self.source})" if self.source else ""), line(head),
               "-" * len(line(head)), *map(line, rows), "-" * len(line(head)),
               f"combined standard uncertainty u_c = {g(self.combined_standard_uncertainty)} {self.unit}",
               f"expanded uncertainty U (k = 2)   = {g(self.expanded_uncertainty(2.0))} {self.unit}"]
        if self.printed is not None:
            out.append(f"source prints u_c = {self.printed:g} {self.unit}")
        return "\n".join(out)

    def __str__(self) -> str:
        return self.table()

    def to_dict(self) -> dict:
        """Plain dict (JSON-serialisable) with the inputs, u_c and U (k = 2)."""
        return {"name": self.name, "unit": self.unit, "source": self.source, "printed": self.printed,
                "inputs": [i.to_dict() for i in self.inputs],
                "combined_standard_uncertainty": self.combined_standard_uncertainty,
                "expanded_uncertainty_k2": self.expanded_uncertainty(2.0)}


def uncertainty_of_mean(uncertainties, correlation: float = 0.0) -> float:
    """Standard uncertainty of the plain mean of k determinations (GUM eq. 13).

    u^2(mean) = (1/k^2) sum_i sum_j r_ij u_i u_j with r_ii = 1 and r_ij = ``correlation``.

    Parameters
    ----------
    uncertainties : array_like, shape (k,)
        Standard uncertainty of each determination, any unit (the result has the same).
    correlation : float
        Correlation coefficient between any two determinations, 0 (independent:
        u/sqrt(k) for equal u) to 1 (fully correlated: the mean of the u_i).

    Returns
    -------
    float
    """
    u = np.asarray(uncertainties, dtype=float)
    if u.ndim != 1 or len(u) == 0 or not np.all(np.isfinite(u)) or np.any(u < 0):
        raise InputError(f"uncertainties: expected a non-empty 1-D array of finite values >= 0, got {uncertainties!r}")
    r = finite("correlation", correlation)
    if not 0.0 <= r <= 1.0:
        raise InputError(f"correlation: must be between 0 and 1, got {r}")
    var = (1 - r) * np.sum(u ** 2) + r * np.sum(u) ** 2
    return float(np.sqrt(var) / len(u))
