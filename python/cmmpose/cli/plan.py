"""``cmmpose plan``: the next placements that best separate what the runs
leave aliased or invisible (:mod:`cmmpose.diagnosis.plan`; docs/plan.md),
and, with ``--simulate``, a simulated run of them."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from pathlib import Path

import click
from rich.console import Console
from rich.markup import escape

from .._json import dumps as strict_json
from ..errors import Error, InputError
from .common import SEED, Positive, check_outputs, console, fail, load_maps, machine_option, map_specs, parse_effects
from .common import TEMPERATURE


@click.command("plan")
@click.argument("run_dirs", metavar="RUN_DIR...", nargs=-1, required=True,
                type=click.Path(exists=True, file_okay=False))
@machine_option
@click.option("--maps", "maps", multiple=True, callback=map_specs,
              help="The model's maps ('thesis' or files); default: the machine's.")
@click.option("--model", "model_file", type=click.Path(exists=True, dir_okay=False), default=None,
              help="The current model (`cmmpose diagnose --save-model`): its maps, and its effects planned for too.")
@click.option("--artefact", "artefact", default=None, metavar="FILE|NAME",
              help="What to place next (an artefact file or bundled example); default the runs' artefact, else "
                   "the thesis ballbar.")
@click.option("--budget", type=click.IntRange(min=1), default=3, show_default=True,
              help="How many placements to propose.")
@click.option("--plan-for", "plan_for", multiple=True, metavar="EFFECT",
              help="An effect whose parameters the placements should determine (repeatable; default squareness, "
                   "scale, roll).")
@click.option("--sigma", "sigma_um", type=Positive("um"), default=None,
              help="Noise per ball-centre coordinate, um (default: from the runs' residuals).")
@click.option("--simulate", "simulate", is_flag=True,
              help="Simulate the proposed placements on the machine (with --effect physics) into -o RUN_DIR.")
@click.option("--effect", "effects", multiple=True, metavar="NAME:param=value,...",
              help="With --simulate: the physics the simulated machine has beyond its maps (as `cmmpose simulate`).")
@click.option("--temperature", type=TEMPERATURE, default=20.0, show_default=True, help="With --simulate: machine temperature, C.")
@click.option("--jitter", type=float, default=0.0, show_default=True,
              help="With --simulate: per-scan reproducibility, um per axis.")
@click.option("--seed", type=SEED, default=0, show_default=True, help="With --simulate: noise seed.")
@click.option("-o", "--output", "run_out", type=click.Path(file_okay=False), default=None,
              help="With --simulate: the run directory to write.")
@click.option("--overwrite", is_flag=True, help="With --simulate: replace an existing run in -o.")
@click.option("--separate", "separate", is_flag=True,
              help="Diagnose the runs first and propose the placements that best tell apart the competing "
                   "explanations it cannot choose between (T-optimal), instead of sharpening parameters.")
@click.option("--user-effect", "user_files", multiple=True, type=click.Path(exists=True, dir_okay=False),
              help="With --separate: a Python file of user effects, candidates of the diagnosis (repeatable).")
@click.option("--json", "as_json", is_flag=True, help="Print JSON instead of the table.")
def plan_cmd(**flags) -> None:
    """Propose the next placements of an artefact (ballbar positions, plate placements, step-gauge lines) that
    best determine what RUN_DIR... leave aliased or invisible (D-optimal on the centre-level sensitivities,
    greedy over the placements the machine reaches), with the parameters' predicted uncertainties before and
    after each; --simulate measures them on a virtual machine."""
    from ..artefacts import load_artefact
    from ..model.model import Model
    from ..diagnosis.plan import DEFAULT_EFFECTS, plan
    from ..machine import load_machine
    from ..run import Run

    o = PlanOptions.from_flags(flags)
    _check_flags(o)
    parsed = parse_effects(o.effects)  # before any work
    try:
        if o.simulate:
            check_outputs({"-o": o.run_out}, o.run_dirs, [o.model_file])
        machine = load_machine(o.machine_file)
        runs = [Run.load(d) for d in o.run_dirs]
        model = Model.load(o.model_file) if o.model_file is not None else Model(load_maps(o.maps, machine))
        art = load_artefact(o.artefact) if o.artefact is not None else None
        rivals = None
        if o.separate:
            from ..model import load_user_effects

            rivals = _open_rivals(runs, model, load_user_effects(o.user_files) if o.user_files else (), machine)
        try:
            result = plan(runs, art, o.budget, machine=machine, model=model, effects=o.plan_for or DEFAULT_EFFECTS,
                          sigma_um=o.sigma_um, rivals=rivals)
        except InputError as exc:
            _usage(exc)
        written = None
        if o.simulate:
            written = _simulate(result, runs, art, machine, parsed, o)
    except Error as exc:
        raise fail(exc) from None
    if o.as_json:
        click.echo(strict_json({**result.to_dict(), "simulated": written}, indent=2))
    else:
        Console(width=max(Console().width, 140)).print(result)
    if written:
        console.print(f"wrote {escape(written)}: the {len(result.proposals)} proposed placements, simulated")


@dataclass(frozen=True)
class PlanOptions:
    """What ``cmmpose plan`` was asked, from its flags (each field the click parameter of its name): one
    object for the command and its helpers."""

    run_dirs: tuple[str, ...]
    machine_file: str | None
    maps: tuple[str, ...]
    model_file: str | None
    artefact: str | None
    budget: int
    plan_for: tuple[str, ...]
    sigma_um: float | None
    simulate: bool
    effects: tuple[str, ...]
    temperature: float
    jitter: float
    seed: int
    run_out: str | None
    overwrite: bool
    separate: bool
    user_files: tuple[str, ...]
    as_json: bool

    @classmethod
    def from_flags(cls, flags: dict) -> PlanOptions:
        """The options from the command's click parameters (by their names)."""
        return cls(**{f.name: flags[f.name] for f in fields(cls)})


def _check_flags(o: PlanOptions) -> None:
    """The usage errors of ``cmmpose plan``, before any work: flags for --simulate or --separate without it,
    --maps with --model, a temperature or jitter that is no number, an -o that is a run read or not empty."""
    if o.simulate and o.run_out is None:
        raise click.UsageError("--simulate needs -o RUN_DIR (where the simulated run goes)")
    if not o.simulate:
        for flag, given in (("-o", o.run_out is not None), ("--effect", bool(o.effects)), ("--overwrite", o.overwrite)):
            if given:
                raise click.UsageError(f"{flag} is for --simulate")
    if o.user_files and not o.separate:
        raise click.UsageError("--user-effect is for --separate")
    if o.separate and o.plan_for:
        raise click.UsageError("--plan-for sharpens parameters; --separate tells explanations apart: give one")
    if o.model_file is not None and o.maps:
        raise click.UsageError("give --maps or --model (whose maps it holds), not both")
    if not math.isfinite(o.temperature):
        raise click.BadParameter(f"{o.temperature!r} is not a temperature in C", param_hint="--temperature")
    if not (math.isfinite(o.jitter) and o.jitter >= 0):
        raise click.BadParameter(f"{o.jitter!r} is not a reproducibility >= 0 um", param_hint="--jitter")
    if o.simulate and any(Path(o.run_out).resolve() == Path(r).resolve() for r in o.run_dirs):
        raise click.UsageError(f"-o {o.run_out}: is one of the runs read; the simulated run goes elsewhere")
    if o.simulate and Path(o.run_out).exists() and not o.overwrite and (not Path(o.run_out).is_dir()
                                                                        or any(Path(o.run_out).iterdir())):
        raise click.UsageError(f"{o.run_out}: exists and is not empty (use --overwrite to replace the run in it)")


def _open_rivals(runs, model, user_effects, machine):
    """The first open ambiguity set of the runs' diagnosis (one run: cmmpose.diagnose; several: jointly)."""
    from ..diagnosis.diagnose import diagnose
    from ..diagnosis.joint import diagnose_jointly

    if len(runs) == 1:
        d = diagnose(runs[0], model, user_effects=user_effects, patterns=False, machine=machine)
    else:
        d = diagnose_jointly(runs, model, user_effects=user_effects, machine=machine)
    if not d.open_ambiguity:
        raise click.UsageError("--separate: the diagnosis of the runs leaves no competing explanations to tell "
                               "apart (no open ambiguity set); plan without it to sharpen parameters")
    return d.open_ambiguity[0]


def _usage(exc: InputError) -> None:
    """The library's error about an argument this command takes as an option (--sigma, --budget, an unknown
    --plan-for effect listing the known ones; the options' types check their values first) as a usage error naming the option (exit 2), not the Python argument,
    from its fields (``cli_option``; a remedy worded for the command line); any other error raised on as it is."""
    if exc.message.startswith("effect ") and ": unknown; available: " in exc.message:  # a --plan-for name
        raise click.BadParameter(exc.message, param_hint="--plan-for") from None
    if exc.cli_option not in ("--sigma", "--budget"):
        raise exc
    if exc.remedy is not None:  # runs without the degrees of freedom to estimate the noise from: give --sigma
        raise click.UsageError(exc.render("cli")) from None
    raise click.BadParameter(exc.message.removeprefix(f"{exc.option}: "), param_hint=exc.cli_option) from None


def _simulate(result, runs, art, machine, effects, o: PlanOptions) -> str:
    """The proposals measured on the virtual machine (``effects``: --effect parsed), saved as a run (-o); its
    directory."""
    import dataclasses

    from .. import artefacts
    from ..evaluation.artefact_balls import is_artefact_run
    from ..sim.artefact_runs import simulate_artefact_run

    if art is None:
        first = next((r for r in runs if is_artefact_run(r)), None)
        art = (artefacts.from_dict(first.artefact["definition"]) if first is not None
               else artefacts.load_artefact("thesis-ballbar"))
    run, truth = simulate_artefact_run(art, [p.where for p in result.proposals], load_maps(o.maps, machine),
                                       o.temperature, effects, machine=machine, jitter=o.jitter * 1e-3, seed=o.seed)
    run = dataclasses.replace(run, maps=machine.maps_record(o.maps))  # as `cmmpose simulate` records them
    run.save(o.run_out, truth=truth, overwrite=o.overwrite)
    return str(o.run_out)
