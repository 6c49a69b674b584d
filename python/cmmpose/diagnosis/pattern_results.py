"""What the residual-pattern search found (:func:`cmmpose.diagnosis.patterns.find_patterns`):
one :class:`Pattern` per (observable, quantity) pair tested, with its strength (R^2, F-test p-value), its
amplitude (um) and the physics that could make it, and a run's :class:`Patterns`, ranked significant first.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError

__all__ = ["Pattern", "Patterns", "LEVELS"]

#: Levels of observables, coarse to fine.
LEVELS = ("length", "scan", "point")


@dataclass(frozen=True, eq=False)
class Pattern:
    """One residual pattern: an observable against a quantity that could explain it.

    Attributes
    ----------
    level : {'length', 'scan', 'point'}
        Where the observable lives: one value per ballbar position, per scan, per point.
    observable : str
        E.g. 'ballbar length deviation', 'sphere radius deviation', 'point fit residual'.
    quantity : str
        The explanatory quantity, e.g. 'dx*dy' (direction cosine product,
        dimensionless), 'v' (mm), 'incidence' (degrees), 'pose'.
    quantity_unit : str
        Unit of ``quantity`` ('1' for dimensionless, '' for categories).
    model : str
        'linear', 'quadratic', 'group means' or 'mean' (a constant offset).
    r2 : float
        Fraction of the observable's variance explained by the model
        (dimensionless, 0..1; for 'mean', the fraction of its mean square).
    p_value : float
        F-test p-value of the model against no pattern (dimensionless).
    df : tuple of int
        F-test degrees of freedom (model terms, residual).
    n : int
        Observations (positions, scans or points).
    amplitude_um : float
        Peak-to-peak of the fitted pattern over the data, um (for 'mean': |mean|).
    hint : str
        Physical effects that could produce the pattern.
    significant : bool
        p_value below the Bonferroni threshold of the :class:`Patterns` it belongs to.
    x : ndarray
        The quantity per observation, or per quantile bin at the point level
        (bin mean), in ``quantity_unit``; category labels (str) for group means.
    y : ndarray
        The observable per observation, or the bin mean, um.
    fitted : ndarray
        The model at ``x``, um.
    y_err : ndarray or None
        Standard error of each bin mean, um (point level only).
    counts : ndarray or None
        Points per bin (point level) or observations per group (group means).
    """

    level: str
    observable: str
    quantity: str
    quantity_unit: str
    model: str
    r2: float
    p_value: float
    df: tuple[int, int]
    n: int
    amplitude_um: float
    hint: str
    significant: bool = False
    x: np.ndarray = field(default=None, repr=False)
    y: np.ndarray = field(default=None, repr=False)
    fitted: np.ndarray = field(default=None, repr=False)
    y_err: np.ndarray | None = field(default=None, repr=False)
    counts: np.ndarray | None = field(default=None, repr=False)

    @property
    def categorical(self) -> bool:
        """True for group means over categories (``x`` holds labels)."""
        return self.model == "group means"

    @property
    def score(self) -> float:
        """R^2 x amplitude, um: the ranking key among significant patterns."""
        return self.r2 * self.amplitude_um

    @property
    def title(self) -> str:
        """'ballbar length deviation vs dx*dy'."""
        return f"{self.observable} vs {self.quantity}"

    @property
    def description(self) -> str:
        """One line: what, how strong (R^2, amplitude in um, p), which physics."""
        return (f"{self.title} (R^2 {self.r2:.2f}, {self.amplitude_um:.1f} um, p {self.p_value:.1e}): "
                f"consistent with {self.hint}")

    def to_dict(self) -> dict:
        """JSON-safe dict (NaN and inf as None, arrays as lists)."""
        def num(v):
            v = float(v)
            return v if math.isfinite(v) else None

        def arr(a):
            if a is None:
                return None
            a = np.asarray(a)
            if a.dtype.kind in "OUS":
                return [str(v) for v in a.tolist()]
            return [num(v) for v in a.ravel().tolist()]

        return {
            "level": self.level, "observable": self.observable, "quantity": self.quantity,
            "quantity_unit": self.quantity_unit, "model": self.model, "r2": num(self.r2),
            "p_value": num(self.p_value), "df": [int(self.df[0]), int(self.df[1])], "n": int(self.n),
            "amplitude_um": num(self.amplitude_um), "score_um": num(self.score), "hint": self.hint,
            "significant": bool(self.significant),
            "data": {"x": arr(self.x), "y_um": arr(self.y), "fitted_um": arr(self.fitted),
                     "y_err_um": arr(self.y_err), "counts": arr(self.counts)},
        }


@dataclass(frozen=True, eq=False)
class Patterns:
    """All residual patterns of a run, ranked (see :func:`find_patterns`).

    Attributes
    ----------
    patterns : tuple of Pattern
        Significant patterns first, then by R^2 x amplitude (um), decreasing.
    alpha : float
        Family-wise significance level (dimensionless).
    threshold : float
        Per-pattern p-value threshold, alpha / number of patterns tested (Bonferroni).
    lengths : dict or None
        The ballbar lengths behind the length level: ``position`` (P,),
        ``length_mm`` (P,), ``deviation_um`` (P,), ``direction`` (P, 3) unit
        vectors ball 1 -> ball 2 (dimensionless), ``midpoint`` (P, 3) mm,
        ``time_s`` (P,), ``temperature_C`` (P,) (NaN without temperatures).
        None when the run has fewer than 3 complete ballbar positions.
    residual_rms_um : float
        Rms of the point fit residuals used (inliers), um: the noise floor.
    """

    patterns: tuple[Pattern, ...]
    alpha: float
    threshold: float
    lengths: dict | None = field(default=None, repr=False)
    residual_rms_um: float = float("nan")

    def __len__(self) -> int:
        return len(self.patterns)

    def __iter__(self):
        return iter(self.patterns)

    def __getitem__(self, i):
        return self.patterns[i]

    @property
    def tested(self) -> int:
        """Number of patterns tested (the Bonferroni m)."""
        return len(self.patterns)

    @property
    def significant(self) -> tuple[Pattern, ...]:
        """The significant patterns, ranked."""
        return tuple(p for p in self.patterns if p.significant)

    @property
    def strongest(self) -> Pattern | None:
        """The top-ranked pattern if it is significant, else None (nothing to explain)."""
        return self.patterns[0] if self.patterns and self.patterns[0].significant else None

    def level(self, level: str) -> tuple[Pattern, ...]:
        """The patterns of one level ('length', 'scan', 'point'), ranked."""
        if level not in LEVELS:
            raise InputError(f"level: expected one of {LEVELS}, got {level!r}")
        return tuple(p for p in self.patterns if p.level == level)

    def find(self, observable: str, quantity: str) -> Pattern | None:
        """The pattern of ``observable`` (prefix match) vs ``quantity``, or None."""
        for p in self.patterns:
            if p.observable.startswith(observable) and p.quantity == quantity:
                return p
        return None

    def summary(self) -> str:
        """One sentence pointing at the strongest pattern (or saying there is none)."""
        s = self.strongest
        if s is None:
            return (f"no significant pattern: none of {self.tested} patterns has p < {self.threshold:.1e} "
                    f"(alpha {self.alpha:g}, Bonferroni): no pattern stands out (whether the scatter is noise: the "
                    f"diagnosis's noise floor)")
        return (f"strongest pattern: {s.title} (R^2 {s.r2:.2f}, {s.amplitude_um:.1f} um): "
                f"consistent with {s.hint}")

    def to_dict(self) -> dict:
        """JSON-safe dict: settings, the summary sentence, every pattern."""
        lengths = None if self.lengths is None else {k: _json_list(v) for k, v in self.lengths.items()}
        rms = self.residual_rms_um
        return {
            "alpha": self.alpha, "tested": self.tested, "threshold": self.threshold,
            "residual_rms_um": rms if math.isfinite(rms) else None,
            "summary": self.summary(),
            "strongest": None if self.strongest is None else self.strongest.to_dict(),
            "patterns": [p.to_dict() for p in self.patterns],
            "lengths": lengths,
        }

    def __rich__(self):
        from rich.console import Group
        from rich.table import Table
        from rich.text import Text

        t = Table(title="Residual patterns (ranked)", title_justify="left")
        for name, just in (("#", "right"), ("level", "left"), ("observable vs quantity", "left"), ("R^2", "right"),
                           ("p", "right"), ("n", "right"), ("ampl. (um)", "right"), ("could be", "left")):
            t.add_column(name, justify=just, overflow="fold")
        shown = list(self.patterns[:12])
        for i, p in enumerate(shown, start=1):
            style = "bold" if p.significant else "dim"
            t.add_row(str(i), p.level, p.title, f"{p.r2:.2f}", f"{p.p_value:.1e}", str(p.n),
                      f"{p.amplitude_um:.1f}", p.hint, style=style)
        rest = len(self.patterns) - len(shown)
        t.caption = (f"{len(self.significant)} of {self.tested} significant (p < {self.threshold:.1e}); dim: not significant"
                     + (f"; {rest} more not shown" if rest > 0 else ""))
        return Group(Text(self.summary(), style="bold" if self.strongest else ""), t)

    def __str__(self) -> str:
        from rich.console import Console

        console = Console(width=140, record=True, file=open("/dev/null", "w"))  # noqa: SIM115 - render to text only
        console.print(self)
        return console.export_text()


def _json_list(a) -> list:
    """An array as (nested) lists of plain numbers, NaN and inf as None."""
    a = np.asarray(a)
    if a.dtype.kind in "iub":
        return a.tolist()
    return np.where(np.isfinite(a), a, None).astype(object).tolist()
