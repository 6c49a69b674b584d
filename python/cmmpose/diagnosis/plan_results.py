"""What :func:`cmmpose.diagnosis.plan.plan` proposes: each placement (:class:`Proposal`) with the
parameters' predicted uncertainties after it (or the rival explanations it separates), and the plan as a whole
(:class:`Plan`: its criterion, noise, the parameters' status before and after; a table, JSON, text).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from .._json import dumps as strict_json, finite_or_none
from ..placement import Placement

__all__ = ["Plan", "Proposal", "separation_text"]


@dataclass(frozen=True)
class Proposal:
    """One proposed placement.

    Attributes
    ----------
    placement : str
        Its shorthand (``cmmpose.placement``), centre given in full (mm);
        a space diagonal by its ISO 10360-2 name.
    where : Placement
        The placement itself (what ``--simulate`` measures).
    balls : int
        Balls it measures.
    gain : float
        Increase of ``log det`` of the information it brings (D-optimal);
        of a T-optimal plan (``rivals``), the smallest pairwise separation
        after it (noise units).
    uncertainty : dict of str -> float
        Every parameter's predicted standard uncertainty after it (and the
        proposals before it), in the parameter's unit.
    de_aliases : list of str
        Parameters it turns from invisible or aliased into determined, or
        whose uncertainty it at least halves.
    """

    placement: str
    where: Placement
    balls: int
    gain: float
    uncertainty: dict
    de_aliases: list
    status: dict = field(default_factory=dict)
    #: T-optimal plans: for each pair of rival explanations, ``pair``, ``difference_um`` (the largest
    #: predicted difference of this placement's observables, the second explanation refitted to every run and
    #: the placements before, um) and ``separation`` (the sum of squared differences over every observable
    #: over the noise variance: the non-centrality a test between the two would have).
    separates: list = field(default_factory=list)

    def to_dict(self) -> dict:
        return {"placement": self.placement, "where": self.where.to_dict(), "balls": self.balls,
                "gain": round(self.gain, 4), "separates": [dict(x) for x in self.separates],
                "uncertainty": {k: finite_or_none(float(v)) for k, v in self.uncertainty.items()},
                "de_aliases": list(self.de_aliases), "status": dict(self.status)}


@dataclass(frozen=True)
class Plan:
    """What :func:`plan` proposes.

    Attributes
    ----------
    artefact : str
        The artefact's name and kind.
    criterion : str
        How the proposals were chosen.
    parameters : list of (str, str, float)
        Each candidate parameter: 'effect.param', unit, prior.
    sigma_um : float
        The noise per centre coordinate used, um; ``sigma_source`` says where from.
    before : dict of str -> float
        Each parameter's standard uncertainty from the runs (and the prior).
    status : dict of str -> str
        'determined', 'invisible' or 'aliased with X' from the runs.
    proposals : list of Proposal
        In the order chosen.
    candidates : int
        Candidate placements the machine reaches (and ``unreachable`` not).
    """

    artefact: str
    criterion: str
    parameters: list
    sigma_um: float
    sigma_source: str
    before: dict
    status: dict
    proposals: list
    candidates: int
    unreachable: int
    notes: list = field(default_factory=list)

    @property
    def placements(self) -> list[str]:
        """The proposed placements' shorthands, in order."""
        return [p.placement for p in self.proposals]

    @property
    def after(self) -> dict:
        """Each parameter's predicted uncertainty after every proposal."""
        return self.proposals[-1].uncertainty if self.proposals else dict(self.before)

    def to_dict(self) -> dict:
        return {"artefact": self.artefact, "criterion": self.criterion,
                "parameters": [{"name": n, "unit": u, "prior": p} for n, u, p in self.parameters],
                "sigma_um": round(self.sigma_um, 4), "sigma_source": self.sigma_source,
                "before": {k: finite_or_none(float(v)) for k, v in self.before.items()}, "status": dict(self.status),
                "after": {k: finite_or_none(float(v)) for k, v in self.after.items()},
                "proposals": [p.to_dict() for p in self.proposals], "candidates": self.candidates,
                "unreachable": self.unreachable, "notes": list(self.notes)}

    def to_json(self, **kw) -> str:
        return strict_json(self.to_dict(), **kw)

    def __rich__(self):
        from rich.console import Group
        from rich.markup import escape
        from rich.table import Table
        from rich.text import Text

        # The artefact's name comes from its file: shown as text, never as Rich markup.
        t = Table(title=f"Next placements: {escape(str(self.artefact))} ({self.criterion})")
        t.add_column("parameter")
        t.add_column("unit")
        t.add_column("now (u)", justify="right")
        t.add_column("status")
        for k, p in enumerate(self.proposals, start=1):
            t.add_column(f"+{k}", justify="right")
        for name, unit, _ in self.parameters:
            cells = [escape(name), escape(unit), f"{self.before[name]:.3g}", escape(self.status[name])]
            cells += [f"{p.uncertainty[name]:.3g}" for p in self.proposals]
            t.add_row(*cells)
        lines = [f"{k}. {p.placement} ({p.balls} balls): " + (separation_text(p.separates) if p.separates else
                 f"de-aliases {', '.join(p.de_aliases)}" if p.de_aliases else "sharpens what is determined")
                 for k, p in enumerate(self.proposals, start=1)]
        lines.append(f"noise {self.sigma_um:.3g} um per centre coordinate ({self.sigma_source}); "
                     f"{self.candidates} candidate placements reachable, {self.unreachable} not")
        lines += self.notes
        return Group(t, Text("\n".join(lines)))

    def __str__(self) -> str:
        from rich.console import Console

        console = Console(width=140, record=True, file=open("/dev/null", "w"))  # noqa: SIM115 - render to text only
        console.print(self)
        return console.export_text()


def separation_text(separates) -> str:
    """A proposal's separations in words."""
    return "; ".join(f"separates {a} from {b} by {x['difference_um']:.2g} um ({x['separation']:.3g} in noise units, "
                     f"sum of squared differences over the noise variance)" for x in separates
                     for a, b in [x["pair"]])
