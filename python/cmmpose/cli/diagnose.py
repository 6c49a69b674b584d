"""``cmmpose diagnose`` and ``diagnose-fits``: which effect the model misses."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import click
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, Progress, TextColumn
from rich.table import Table

from .._json import dumps as strict_json
from ..atomicfile import check_outputs_free, ensure_folder, write_text
from ..errors import Error
from ..temperature import TemperaturePolicy, log_notes
from .artefact import diagnose_plate_fits_cli
from .common import (TEMPERATURE, check_free, check_outputs, check_report_file, command_inputs, console, fail,
                     load_maps, machine_option, map_specs, overwrite_option, policy_options, report_folder_html,
                     scheduler_options, writing)


@click.command("diagnose")
@click.argument("run_dirs", metavar="RUN_DIR...", nargs=-1, required=True, type=click.Path(exists=True, file_okay=False))
@machine_option
@click.option("--maps", "maps", multiple=True, callback=map_specs,
              help="Model maps ('thesis' or files); default: the machine's, or as run.json says.")
@click.option("--model", "model_file", type=click.Path(exists=True, dir_okay=False), default=None,
              help="Start from a model saved by an earlier diagnosis (its maps and effects).")
@click.option("--temperature", type=TEMPERATURE, default=None, help="Machine temperature, C (default: the run's thermocouple log).")
@policy_options()
@click.option("--add", "add", multiple=True, help="Add this effect first, whether significant or not (repeatable).")
@click.option("--no-auto", is_flag=True, help="Only rank the candidates (and add --add ones); add nothing automatically.")
@click.option("--max-effects", type=int, default=4, show_default=True, help="Most effects added automatically.")
@click.option("--report", "report_file", type=click.Path(), default=None, callback=report_folder_html,
              help="Folder for the report: a self-contained diagnose.html (made if missing).")
@click.option("--save-model", "model_out", type=click.Path(dir_okay=False), default=None, help="Write the final model (JSON) here.")
@click.option("--user-effect", "user_files", multiple=True, type=click.Path(exists=True, dir_okay=False),
              help="A Python file defining EFFECT (a cmmpose.UserEffect), added to the candidates "
                   "(repeatable; docs/user-effects.md).")
@click.option("--user-effect-skeleton", "skeleton_out", type=click.Path(dir_okay=False), default=None,
              help="Write a user-effect draft (Python) built on the first unexplained finding here.")
@click.option("--joint", is_flag=True,
              help="With several runs: one model for all (shared effect parameters, per-run noise levels; the same "
                   "artefact: one bar length), instead of one diagnosis per run.")
@click.option("--separate-artefacts", is_flag=True, help="With --joint: each run measured its own artefact.")
@scheduler_options("With several runs: where each run's diagnosis runs (threads, processes or tcp://host:port; "
                   "the [dask] extra; docs/scale-out.md).")
@click.option("--json", "as_json", is_flag=True, help="Print JSON instead of the tables.")
@click.option("--verbose", "-v", is_flag=True,
              help="After the verdict, the final model and the error's history, also print the candidate tables, "
                   "every finding and what each candidate would need (by default only the verdict: about 40 lines).")
@click.option("--reproducibility", "reproducibility_um", default=None, metavar="UM[,UM...]",
              callback=lambda ctx, param, value: _reproducibility_values(value),
              help="Per-scan centre reproducibility, um per axis: the noise floor of a run that repeats no scan "
                   "(default: the --machine file's [reproducibility]; a run that repeats scans measures its own). "
                   "With --joint: one value, or one per run, comma-separated.")
@click.option("--no-map-corrections", is_flag=True,
              help="Offer only the library's named effects (no corrections of the map components).")
@click.option("--corrected-maps", "corrected_out", type=click.Path(dir_okay=False), default=None,
              help="Write the maps with the found map corrections in them (CSV; a set: one file per temperature).")
@overwrite_option("Replace existing --save-model, --report, --corrected-maps and --user-effect-skeleton files "
                  "(never an input).")
def diagnose_cmd(**flags) -> None:
    """Find which physical effect the model misses on RUN_DIR, add it, and show the error fall.
    Several RUN_DIRs are diagnosed one by one on a Dask scheduler, with one table across them."""
    o = DiagnoseOptions.from_flags(flags)
    if o.joint:
        if len(o.run_dirs) < 2 or o.scheduler:
            raise click.UsageError("--joint takes two or more runs and runs in this process (no --scheduler)")
        if o.skeleton_out:
            raise click.UsageError("--user-effect-skeleton takes one run: diagnose the run of interest on its own")
        if o.reproducibility_um is not None and len(o.reproducibility_um) not in (1, len(o.run_dirs)):
            raise click.BadParameter(f"{len(o.reproducibility_um)} values for {len(o.run_dirs)} runs: give one value, "
                                     "or one per run (comma-separated, in the runs' order)",
                                     param_hint="--reproducibility")
        return _diagnose_joint(o)
    if o.reproducibility_um is not None and len(o.reproducibility_um) > 1:
        raise click.BadParameter("one value per run is for --joint; without it every run takes the one value",
                                 param_hint="--reproducibility")
    if len(o.run_dirs) > 1 or o.scheduler:
        for flag, given in (("--report", o.report_file), ("--save-model", o.model_out), ("--user-effect", o.user_files),
                            ("--user-effect-skeleton", o.skeleton_out)):
            if given:
                raise click.UsageError(f"{flag} takes one run: diagnose the run of interest on its own")
        return _diagnose_fleet(o)
    _diagnose_one(o)


@dataclass(frozen=True)
class DiagnoseOptions:
    """What ``cmmpose diagnose`` was asked, from its flags: one object for the command and its helpers.

    The temperature policy's flags arrive as ``temperature_policy`` (built by
    :func:`~cmmpose.cli.temperature_options.temperature_options`); its ``out_of_range``,
    ``temperature_tolerance`` and ``log_hold`` are what the model and the scale-out are given."""

    run_dirs: tuple[str, ...]
    machine_file: str | None
    maps: tuple[str, ...]
    model_file: str | None
    temperature: float | None
    temperature_policy: TemperaturePolicy
    add: tuple[str, ...]
    auto: bool
    max_effects: int
    report_file: str | None
    model_out: str | None
    user_files: tuple[str, ...]
    skeleton_out: str | None
    joint: bool
    same_artefact: bool
    scheduler: str | None
    scheduler_timeout: float
    as_json: bool
    verbose: bool
    #: --reproducibility: one value, or with --joint one per run (um); None when not given.
    reproducibility_um: tuple[float, ...] | None
    map_corrections: bool
    corrected_out: str | None
    #: --overwrite: replace existing output files (never an input).
    overwrite: bool = False

    @classmethod
    def from_flags(cls, flags: dict) -> DiagnoseOptions:
        """The options from the command's click parameters (by their names)."""
        return cls(run_dirs=tuple(flags["run_dirs"]), machine_file=flags["machine_file"], maps=flags["maps"],
                   model_file=flags["model_file"], temperature=flags["temperature"],
                   temperature_policy=flags["temperature_policy"], add=flags["add"], auto=not flags["no_auto"],
                   max_effects=flags["max_effects"], report_file=flags["report_file"], model_out=flags["model_out"],
                   user_files=flags["user_files"], skeleton_out=flags["skeleton_out"], joint=flags["joint"],
                   same_artefact=not flags["separate_artefacts"], scheduler=flags["scheduler"],
                   scheduler_timeout=flags["scheduler_timeout"], as_json=flags["as_json"], verbose=flags["verbose"],
                   reproducibility_um=flags["reproducibility_um"], map_corrections=not flags["no_map_corrections"],
                   corrected_out=flags["corrected_out"], overwrite=flags["overwrite"])

    @property
    def one_reproducibility_um(self) -> float | None:
        """--reproducibility's one value (one run, or each run of a fleet), None when not given."""
        return None if self.reproducibility_um is None else self.reproducibility_um[0]

    @property
    def inputs(self) -> list:
        """The files the diagnosis reads besides the runs and the maps: model, machine, user effects."""
        return [self.model_file, self.machine_file, *self.user_files]

    @property
    def outputs(self) -> dict:
        """The files asked for, by flag (None: not asked; --corrected-maps' own names come from the maps)."""
        return {"--save-model": self.model_out, "--report": self.report_file,
                "--user-effect-skeleton": self.skeleton_out}

    def check_targets(self) -> None:
        """Before any work: no output is an input (the runs' files, model, machine, user effects), through links,
        nor (without --overwrite) an existing file; the --report file's folder is made if missing."""
        files = {k: v for k, v in self.outputs.items() if k != "--report"}
        check_outputs({**files, "--report": self.report_file, "--corrected-maps": self.corrected_out},
                      self.run_dirs, self.inputs)
        check_report_file(self.report_file)  # after: an input given as --report is named as such
        inputs = command_inputs(self.inputs, self.run_dirs)
        check_free(files, inputs, overwrite=self.overwrite)
        check_free({"--report": self.report_file}, inputs, overwrite=self.overwrite, folders_made=True)

    def writing(self, inputs, corrected=()):
        """The group every output is written in (cmmpose.cli.common.writing): exclusive without --overwrite,
        never over one of ``inputs``, all the files asked for (``corrected``: the --corrected-maps files) or
        none."""
        given = [flag for flag, path in {**self.outputs, "--corrected-maps": self.corrected_out}.items() if path]
        return writing(" and ".join(given) or "output", [*self.outputs.values(), *corrected], inputs,
                       overwrite=self.overwrite)

    def model_policy(self) -> dict:
        """The starting model's temperature keywords: --temperature and the policy (its fields and itself)."""
        policy = self.temperature_policy
        return {"temperature": self.temperature, "out_of_range": policy.out_of_range,
                "temperature_tolerance": policy.temperature_tolerance, "log_hold": policy.log_hold,
                "temperature_policy": policy}


def _diagnose_one(o: DiagnoseOptions) -> None:
    """`diagnose RUN_DIR`: one run's diagnosis, the files it writes, printed."""
    from ..diagnosis import diagnose
    from ..machine import load_machine
    from ..run import Run

    run_dir = o.run_dirs[0]
    reproducibility_um = o.one_reproducibility_um
    try:
        o.check_targets()  # before any work
        machine = load_machine(o.machine_file)
        run = Run.load(run_dir)
        from ..model import load_user_effects

        user = load_user_effects(o.user_files)
        model = _starting_model(run, machine, user, o)
        map_inputs = _map_inputs(o, machine)
        _check_corrected_maps(model, o.corrected_out, map_inputs, o.overwrite)
        with console.status("diagnosing ..."):
            known = set(model.names)
            diag = diagnose(run, model, add=o.add, auto=o.auto, max_effects=o.max_effects,
                            user_effects=[u for u in user if u.name not in known],
                            map_corrections=o.map_corrections, reproducibility_um=reproducibility_um,
                            machine=machine, **machine_floor(machine, o.machine_file, reproducibility_um))
        files = []
        corrected = _corrected_maps(diag.model, o.corrected_out)
        with o.writing(map_inputs, corrected):  # every output or none
            if o.skeleton_out:
                from ..diagnosis.unexplained import user_effect_skeleton

                if diag.unexplained:
                    write_text(o.skeleton_out, user_effect_skeleton(diag.unexplained[0]))
                    files.append(o.skeleton_out)
                else:
                    console.print("no unexplained structure: no user-effect draft written")
            if o.model_out:
                files.append(diag.model.save(o.model_out))
            files += _write_corrected_maps(corrected)
            if o.report_file:
                try:
                    ensure_folder(Path(o.report_file).parent)
                    files.append(diag.write_report(o.report_file, run, run_dir=run_dir, model_file=o.model_out))
                except ImportError as exc:  # the diagnosis is still printed and the model saved
                    console.print(f"[yellow]no HTML report:[/] {escape(str(exc))}")
    except Error as exc:
        raise _fail_or_usage(exc) from None
    _print_diagnosis(diag, files, o.as_json, o.verbose)


def _reproducibility_values(text) -> tuple[float, ...] | None:
    """--reproducibility: one number of um, or several comma-separated (one per run of --joint); the
    diagnosis checks each (finite, > 0, plausible) and names this option."""
    if text is None:
        return None
    values = []
    for item in str(text).split(","):
        try:
            values.append(float(item))
        except ValueError:
            raise click.BadParameter(f"{item.strip()!r} is not a number of um", param_hint="--reproducibility") \
                from None
    return tuple(values)


def machine_floor(machine, machine_file, reproducibility_um=None) -> dict:
    """The keywords that give the diagnosis its floor's source: --reproducibility when given (it wins);
    else the --machine file's stated per-scan reproducibility, the floor of each run that repeats no scan (a
    run that repeats scans measures its own); none for the default machine (without --machine the runs' maps
    are as run.json says, and a machine the run may not come from states nothing of its noise)."""
    if reproducibility_um is not None:
        return {"reproducibility_source": "stated (--reproducibility)"}
    if machine_file is None or machine.reproducibility_um is None:
        return {}
    return {"default_reproducibility_um": machine.reproducibility_um,
            "reproducibility_source": f"stated in the machine file {machine.source}"}


def _corrected_map_paths(maps, path) -> list[Path]:
    """Where --corrected-maps writes ``maps``: ``path``, or for a set one file per temperature beside it
    (``NAME_<T>C.csv``)."""
    from ..errormap import ErrorMapSet

    path = Path(path)
    if not isinstance(maps, ErrorMapSet):
        return [path]
    return [path.with_name(f"{path.stem}_{m.temperature:g}C{path.suffix or '.csv'}") for m in maps.maps]


def _map_inputs(o: DiagnoseOptions, machine) -> list:
    """Every file a diagnosis reads: the runs' files, the model, machine and user-effect files, the map files
    named by --maps and the machine file's own maps."""
    from ..run import RUN_FILES

    return ([Path(r) / n for r in o.run_dirs for n in RUN_FILES] + [f for f in o.inputs if f]
            + [Path(s) for s in o.maps if Path(s).exists()] + list(machine.map_files))


def _check_corrected_maps(model, path, inputs, overwrite: bool = False) -> None:
    """Before any work: every name --corrected-maps derives from ``path`` (the maps' temperatures are the
    starting model's) is checked against every input, through links, and (without ``overwrite``) refused if it
    exists (cmmpose.atomicfile.check_outputs_free)."""
    if path:
        check_outputs_free(_corrected_map_paths(model.maps, path), inputs, overwrite=overwrite,
                           what="--corrected-maps")


def _corrected_maps(model, path) -> dict:
    """--corrected-maps: the model's maps with its map corrections in them
    (cmmpose.diagnosis.mapfamily.corrected_maps), by where each goes: ``path``, or for a set one file per
    temperature beside it (``NAME_<T>C.csv``); empty without ``path``."""
    from ..errormap import ErrorMapSet
    from ..model.mapshape import corrected_maps

    if not path:
        return {}
    maps = corrected_maps(model)
    return dict(zip(_corrected_map_paths(maps, path), maps.maps if isinstance(maps, ErrorMapSet) else [maps],
                    strict=True))


def _write_corrected_maps(corrected: dict) -> list:
    """Write the --corrected-maps (:func:`_corrected_maps`), in the command's group
    (:meth:`DiagnoseOptions.writing`, a cmmpose.atomicfile.FileGroup): all of them or, on a failure, none."""
    for p, m in corrected.items():
        m.write(p)
    return list(corrected)


def _fail_or_usage(exc: Error) -> click.ClickException:
    """A library error as the command says it; a name given to --add that names no effect is a usage error
    (exit 2), as a wrong name is in every command."""
    if getattr(exc, "cli_option", None) == "--add":
        return click.BadParameter(str(exc).removeprefix("effect "), param_hint="--add")
    return fail(exc)


def _print_diagnosis(diag, files, as_json: bool, verbose: bool = False) -> None:
    """A diagnosis (or a joint one) on stdout: JSON, or its view at the terminal's width (the verdict first;
    ``verbose``: every table), then the thermocouple notes and the files written."""
    if as_json:
        click.echo(diag.to_json(indent=1))
    else:
        Console().print(diag.view(verbose))
        for note in log_notes(diag.thermal or {}):  # the thermocouples dropped, held, read
            console.print(f"note: {escape(note)}")
    for f in files:
        console.print(f"wrote {f}")


def _starting_model(run, machine, user, o: DiagnoseOptions):
    """The model a diagnosis starts from: a saved one (with its user effects),
    or the maps (--maps, the machine's, or the run's) with the temperature policy."""
    from ..model import Model

    if o.model_file:
        return Model.load(o.model_file, user_effects=user)
    maps_ = machine.maps_for_run(run, o.maps)
    if maps_ is None:
        raise click.BadParameter("the model needs maps ('none' is not a model)", param_hint="--maps")
    return Model(maps_, **o.model_policy())


def _diagnose_joint(o: DiagnoseOptions) -> None:
    """`diagnose RUN_DIR... --joint`: one model for several runs (cmmpose.diagnosis.joint); the
    report shows the first run's plots and every run's error at each step."""
    from ..diagnosis.joint import diagnose_jointly
    from ..machine import load_machine
    from ..run import Run

    try:
        o.check_targets()  # before any work
        machine = load_machine(o.machine_file)
        runs = [Run.load(r) for r in o.run_dirs]
        from ..model import load_user_effects

        user = load_user_effects(o.user_files)
        model = _starting_model(runs[0], machine, user, o)
        map_inputs = _map_inputs(o, machine)
        _check_corrected_maps(model, o.corrected_out, map_inputs, o.overwrite)
        with console.status(f"diagnosing {len(runs)} runs together ..."):
            options = {"add": o.add, "auto": o.auto, "max_effects": o.max_effects, "same_artefact": o.same_artefact,
                       "map_corrections": o.map_corrections}
            repro = o.reproducibility_um
            if repro is not None:
                options["reproducibility_um"] = repro[0] if len(repro) == 1 else list(repro)
            diag = diagnose_jointly(runs, model, user_effects=[u for u in user if u.name not in set(model.names)],
                                    run_names=[str(r) for r in o.run_dirs], machine=machine, **options,
                                    **machine_floor(machine, o.machine_file, repro))
        corrected = _corrected_maps(diag.model, o.corrected_out)
        with o.writing(map_inputs, corrected):  # every output or none
            files = [diag.model.save(o.model_out)] if o.model_out else []
            files += _write_corrected_maps(corrected)
            if o.report_file:
                try:
                    ensure_folder(Path(o.report_file).parent)
                    files.append(diag.write_report(o.report_file, runs[0], run_dir=o.run_dirs[0],
                                                   model_file=o.model_out))
                except ImportError as exc:  # the diagnosis is still printed and the model saved
                    console.print(f"[yellow]no HTML report:[/] {escape(str(exc))}")
    except Error as exc:
        raise _fail_or_usage(exc) from None
    _print_diagnosis(diag, files, o.as_json, o.verbose)


def _diagnose_fleet(o: DiagnoseOptions) -> None:
    """`diagnose RUN_DIR...`: each run's diagnosis on a Dask scheduler (cmmpose.scale), one table across them."""
    from ..model import Model
    from ..machine import load_machine
    from ..scale import diagnose_runs

    scheduler = o.scheduler or "threads"
    policy = o.temperature_policy
    try:
        machine = load_machine(o.machine_file)
        options = {"add": o.add, "auto": o.auto, "max_effects": o.max_effects, "temperature_policy": policy,
                   "reproducibility_um": o.one_reproducibility_um}
        options.update(machine_floor(machine, o.machine_file, options.get("reproducibility_um")))
        model = "run"  # each run's bundled maps, on its worker
        if o.model_file:
            model = Model.load(o.model_file)
        elif o.maps == ("none",):
            raise click.BadParameter("the model needs maps ('none' is not a model)", param_hint="--maps")
        elif o.maps or o.machine_file:
            model = Model(load_maps(o.maps, machine))
        with Progress(TextColumn("diagnosing"), BarColumn(), TextColumn("{task.completed}/{task.total} runs"),
                      console=console) as bar:
            task = bar.add_task("", total=len(o.run_dirs))
            diags = diagnose_runs(o.run_dirs, model, scheduler=scheduler, scheduler_timeout=o.scheduler_timeout,
                                  progress=lambda done, total: bar.update(task, completed=done, total=total),
                                  temperature=o.temperature, out_of_range=policy.out_of_range,
                                  temperature_tolerance=policy.temperature_tolerance, log_hold=policy.log_hold,
                                  **options)
    except Error as exc:
        raise _fail_or_usage(exc) from None
    if o.as_json:
        click.echo(strict_json({str(r): json.loads(d.to_json()) for r, d in zip(o.run_dirs, diags)}, indent=1))
        return
    Console().print(fleet_table(o.run_dirs, diags, scheduler))
    if o.verbose:  # each run's own view after the table
        for r, d in zip(o.run_dirs, diags):
            Console().print(f"[bold]{escape(str(r))}[/]")
            Console().print(d.view(verbose=True))


def fleet_table(run_dirs, diags, scheduler: str) -> Table:
    """One row per run of a fleet's diagnoses: what was added (final values ± u), the headline before and after
    and what stays unexplained; every cell folds at the console's width."""
    table = Table(title=f"diagnosis of {len(run_dirs)} runs ({scheduler})")
    for col in ("run", "added (final values ± u)", "rms before (um)", "rms after (um)", "unexplained"):
        table.add_column(col, justify="left" if col in ("run", "added (final values ± u)", "unexplained") else "right",
                         overflow="fold")
    for r, d in zip(run_dirs, diags):
        added = "; ".join(f"{x['name']}: {x['reason'].split(' (final model)')[0]}" for x in d.decisions()
                          if x["decision"].startswith("added")) or "-"
        before, after = d.steps[0].figures, d.steps[-1].figures
        table.add_row(escape(str(r)), escape(added), f"{before.headline[1] * 1e3:.2f}",
                      f"{after.headline[1] * 1e3:.2f}",
                      escape("; ".join(f.input + ": " + f.description.split(":")[0] for f in d.unexplained) or "-"))
    return table


@click.command("diagnose-fits")
@click.argument("fits_file", metavar="FITS")
@click.option("--state", default=None, help="Rows of this state only (a 'state' column, e.g. compensated).")
@click.option("--nominal-radius", type=float, default=None, help="Calibrated ball radius, mm.")
@click.option("--reference-length", type=float, default=None, help="Calibrated bar length, mm (default: the mean).")
@click.option("--artefact", "artefact_spec", default=None, metavar="FILE|NAME",
              help="FITS holds measured centres of this artefact (ball plate, step gauge): columns placement, ball, "
                   "x_mm, y_mm, z_mm, radius_mm (docs/artefacts.md).")
@click.option("--temperature", type=TEMPERATURE, default=None,
              help="With --artefact: the artefact's temperature while measured, C (default 20).")
@click.option("--json", "as_json", is_flag=True, help="Print JSON instead of the tables.")
def diagnose_fits_cmd(fits_file, state, nominal_radius, reference_length, artefact_spec, temperature,
                      as_json) -> None:
    """Diagnose a ballbar run from its sphere fits alone (centres, radii, points, fit rms per ball): FITS is a
    CSV (docs/appendix-c.md) or 'appendix-c' (thesis Appendix C, 20 C, nominal radius 38.125 mm). With
    --artefact, FITS holds the measured ball centres of a ball plate or step gauge at its placements."""
    if artefact_spec is not None or temperature is not None:
        return diagnose_plate_fits_cli(fits_file, artefact_spec, state, temperature, nominal_radius,
                                       reference_length, as_json)
    from ..diagnosis.spheres import NOMINAL_RADIUS_MM, appendix_c_sphere_fits, diagnose_sphere_fits, read_sphere_fits

    try:
        if fits_file == "appendix-c":
            fits = appendix_c_sphere_fits(state or "compensated")
            nominal_radius = NOMINAL_RADIUS_MM if nominal_radius is None else nominal_radius
        else:
            if not Path(fits_file).exists():  # a FIFO or a device: the reader says what it is
                raise click.BadParameter(f"{fits_file}: no such file", param_hint="FITS")
            fits = read_sphere_fits(fits_file, state)
        d = diagnose_sphere_fits(fits["centres"], fits["radii"], nominal_radius=nominal_radius,
                                 reference_length=reference_length, points=fits.get("points"),
                                 fit_rms=fits.get("fit_rms"))
    except Error as exc:
        if exc.cli_option and ": " in exc.message:
            # An implausible --reference-length or --nominal-radius (or radius column): named as the flag.
            what, text = exc.message.split(": ", 1)
            column = f" (column {exc.column} of {fits_file})" if exc.column else ""
            raise click.BadParameter((text if what == exc.option else exc.message) + column,
                                     param_hint=exc.cli_option) from None
        raise fail(exc) from None
    if as_json:
        click.echo(strict_json(d.to_dict(), indent=1))
        return
    table = Table(title=f"sphere fits of {fits_file}" + (f" ({state})" if state else ""), show_header=False)
    table.add_row("positions", str(len(d.lengths)))
    if d.reference_length is not None:
        table.add_row("mean length (mm)", f"{d.mean_length:.4f} ({d.mean_deviation_um:+.2f} um from the reference "
                      f"{d.reference_length:g})")
    table.add_row("rms accuracy error (um)", f"{d.rms_um:.2f}" + (" (about the mean deviation)"
                                                                  if d.reference_length is not None else ""))
    table.add_row("mean radius (mm)", f"{d.radius_mean:.4f}" + ("" if d.nominal_radius is None else
                  f" ({d.radius_excess_um:+.1f} ± {d.radius_excess_u_um:.1f} um over {d.nominal_radius:g})"))
    table.add_row("radius scatter between balls (um)", f"{d.radius_sd_um:.1f}")
    Console().print(table)
    Console().print(d.patterns)
