"""``cmmpose effects``: the physical effects the registry knows."""

from __future__ import annotations

import click
from rich.table import Table

from .. import effects as effects_registry
from .common import json_option, show


@click.command("effects")
@json_option
def effects_cmd(as_json) -> None:
    """List the physical effects: name, where each acts, its parameters and what it is."""
    table = Table(title="Physical effects (cmmpose.effects)")
    for col in ("effect", "acts", "model parameters (prior)", "simulator fields", "what it is"):
        table.add_column(col, no_wrap=col == "effect")
    for name, cls in effects_registry.available().items():
        params = ", ".join(f"{p} {q.unit} ({q.prior:g})" for p, q in cls.params.items())
        fields_ = ", ".join(f"{k} {u}".strip() for k, u in cls.units().items())
        table.add_row(name, cls.acts, params, fields_, cls.summary)
    show(table, as_json)
