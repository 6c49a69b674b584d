"""The ``cmmpose`` command line: a front end over the library, one module
per command group (docs/architecture.md). ``main`` is the console script.

A command's module is imported only when that command runs (or when help
lists them all): ``cmmpose fit`` pays for the sphere fit's imports, not for
the diagnosis, the Dask scale-out or the acquisition (issue 27, start-up).
"""

from __future__ import annotations

import copy
import importlib
import warnings

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

#: Old top-level spellings that still work (hidden, with a FutureWarning): old name -> new spelling.
OLD_SPELLINGS = {
    "simulate-alignment": "calibrate simulate-alignment",
    "plot-map": "map plot",
    **{name: f"standards {name}" for name in
       ("iso230-2", "acceptance", "acceptance-sphere", "interim-check", "e3125-distances")},
}


def _load(module: str, attribute: str) -> click.Command:
    return getattr(importlib.import_module(f".{module}", __name__), attribute)


def _deprecated(command: click.Command, old: str, new: str) -> click.Command:
    """``command`` under its old top-level name ``old``: hidden from the
    list, working as before, with a FutureWarning (on stderr, which a --json
    reader of stdout never sees) that ``cmmpose new`` is its name now."""
    alias = copy.copy(command)
    alias.name, alias.hidden = old, True
    alias.help = f"(Old spelling of `cmmpose {new}`.) " + (command.help or "")
    parse = alias.parse_args

    def parse_args(ctx, args):  # said first, before the options are read (also for --help or a usage error)
        warnings.warn_explicit(f"`cmmpose {old}` is now `cmmpose {new}`; the old spelling still works for now",
                               FutureWarning, "cmmpose", 0)
        return parse(ctx, args)

    alias.parse_args = parse_args
    return alias


def command(name: str) -> click.Command | None:
    """The command ``name`` of ``cmmpose`` (its module imported now), or None."""
    if name in COMMANDS:
        found = _load(*COMMANDS[name])
        if name in NESTED and NESTED[name][0] not in getattr(found, "commands", {}):
            sub, module, attribute = NESTED[name]
            found.add_command(_load(module, attribute), sub)
        return found
    if name in OLD_SPELLINGS:
        group, _, sub = OLD_SPELLINGS[name].partition(" ")
        target = command(group).commands[sub]
        return _deprecated(target, name, OLD_SPELLINGS[name])
    return None


class _Commands(click.Group):
    """The command group: commands loaded on first use (``COMMANDS``), and
    click's own messages (a bad option value echoed back) with numbers of
    more than 20 digits shortened (cmmpose.policy), and cmmpose's warnings
    said as one line each (cmmpose.cli.common.cli_warnings)."""

    def list_commands(self, ctx):
        return list(COMMANDS)  # the old spellings are hidden

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
