"""The ``cmmpose`` command line: a front end over the library, one module
per command group (docs/architecture.md). ``main`` is the console script.

A command's module is imported only when that command runs (or when help
lists them all): ``cmmpose fit`` pays for the sphere fit's imports, not for
the diagnosis, the Dask scale-out or the acquisition (issue 27, start-up).
"""

from __future__ import annotations

import importlib

import click

from ..atomicfile import raise_on_termination
from ..policy import shorten_numbers

__all__ = ["main"]

#: Command name -> (module of this package, attribute): the commands, in the order help lists them.
COMMANDS = {
    "compensate": ("compensate", "compensate_cmd"),
    "effects": ("effects", "effects_cmd"),
    "simulate": ("simulate", "simulate_cmd"),
    "fit": ("fit", "fit_cmd"),
    "evaluate": ("evaluate", "evaluate_cmd"),
    "diagnose": ("diagnose", "diagnose_cmd"),
    "diagnose-fits": ("diagnose", "diagnose_fits_cmd"),
    "demo": ("demo", "demo_cmd"),
    "acquire": ("acquire", "acquire_cmd"),
    "calibrate": ("calibrate", "calibrate"),
    "machine": ("machine", "machine_group"),
    "map": ("map", "map_group"),
    "standards": ("standards", "standards_group"),
    "artefact": ("artefact", "artefact_group"),
    "plan": ("plan", "plan_cmd"),
}

#: Where users look for them: the alignment simulation beside `calibrate alignment` that reads its files, the map
#: plot under `map`, the standards under `standards`. Group -> (name in the group, module, attribute).
NESTED = {
    "calibrate": ("simulate-alignment", "simulate", "simulate_alignment_cmd"),
    "map": ("plot", "map", "plot_map_cmd"),
}


def _load(module: str, attribute: str) -> click.Command:
    return getattr(importlib.import_module(f".{module}", __name__), attribute)


def command(name: str) -> click.Command | None:
    """The command ``name`` of ``cmmpose`` (its module imported now), or None."""
    if name in COMMANDS:
        found = _load(*COMMANDS[name])
        if name in NESTED and NESTED[name][0] not in getattr(found, "commands", {}):
            sub, module, attribute = NESTED[name]
            found.add_command(_load(module, attribute), sub)
        return found
    return None


class _Commands(click.Group):
    """The command group: commands loaded on first use (``COMMANDS``), and
    click's own messages (a bad option value echoed back) with numbers of
    more than 20 digits shortened (cmmpose.policy), and cmmpose's warnings
    said as one line each (cmmpose.cli.common.cli_warnings)."""

    def list_commands(self, ctx):
        return list(COMMANDS)

    def get_command(self, ctx, name):
        if name not in self.commands:
            found = command(name)
            if found is None:
                return None
            self.add_command(found, name)
        return self.commands[name]

    def invoke(self, ctx):
        from .common import cli_warnings  # here: the shared options' imports once a command runs

        try:
            with cli_warnings():  # cmmpose's warnings as `warning: <message>`, one line each, once
                return super().invoke(ctx)
        except click.ClickException as exc:
            exc.message = shorten_numbers(exc.message)
            raise


@click.group(cls=_Commands)
@click.version_option(package_name="cmmpose")
def main() -> None:
    """Error compensation of a laser line scanner on a CMM."""
    raise_on_termination()  # SIGTERM, SIGHUP: clean up temporary files as on Ctrl-C
