"""The ``cmmpose`` command line: a front end over the library, one module
per command group (docs/architecture.md). ``main`` is the console script."""

from __future__ import annotations

import copy
import warnings

import click

from ..atomicfile import raise_on_termination
from ..policy import shorten_numbers
from .acquire import acquire_cmd
from .artefact import artefact_group
from .calibrate import calibrate
from .compensate import compensate_cmd
from .demo import demo_cmd
from .diagnose import diagnose_cmd, diagnose_fits_cmd
from .effects import effects_cmd
from .evaluate import evaluate_cmd
from .fit import fit_cmd
from .machine import machine_group
from .map import map_group, plot_map_cmd
from .plan import plan_cmd
from .simulate import simulate_alignment_cmd, simulate_cmd
from .standards import standards_group

__all__ = ["main"]


class _Commands(click.Group):
    """The command group: click's own messages (a bad option value echoed
    back) with numbers of more than 20 digits shortened (cmmpose.policy)."""

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except click.ClickException as exc:
            exc.message = shorten_numbers(exc.message)
            raise


@click.group(cls=_Commands)
@click.version_option(package_name="cmmpose")
def main() -> None:
    """Error compensation of a laser line scanner on a CMM."""
    raise_on_termination()  # SIGTERM, SIGHUP: clean up temporary files as on Ctrl-C


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


for _command in (compensate_cmd, effects_cmd, simulate_cmd, fit_cmd, evaluate_cmd, diagnose_cmd, diagnose_fits_cmd,
                 demo_cmd, acquire_cmd, calibrate, machine_group, map_group, standards_group, artefact_group, plan_cmd):
    main.add_command(_command)

# Where users look for them: the standards under `standards`, the alignment simulation beside `calibrate
# alignment` that reads its files, the map plot under `map`; the old top-level spellings still work.
calibrate.add_command(simulate_alignment_cmd, "simulate-alignment")
map_group.add_command(plot_map_cmd, "plot")
for _command, _new in ((simulate_alignment_cmd, "calibrate simulate-alignment"), (plot_map_cmd, "map plot"),
                       *((c, f"standards {c.name}") for c in standards_group.commands.values())):
    main.add_command(_deprecated(_command, _command.name, _new))
