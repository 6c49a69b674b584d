"""``cmmpose evaluate``: ballbar (and artefact) runs evaluated, one or a fleet."""

from __future__ import annotations

import math
import os
import warnings
from dataclasses import dataclass
from pathlib import Path

import click
from rich.console import Console, Group
from rich.markup import escape
from rich.progress import BarColumn, Progress, TextColumn
from rich.table import Table
from rich.text import Text

from .._json import dumps as strict_json
from ..atomicfile import ensure_folder, write_text
from ..errors import (AliasedChoiceWarning, ClampWarning, Error, ExtrapolationWarning, InputError,
                      MapTemperatureWarning, ModelDomainWarning)
from ..evaluation.ballbar import evaluate
from ..evaluation.model_check import check_model
from ..evaluation.files import FLEET_FILES, REPORT_FILES, write_evaluation_files
from ..evaluation.metrics import STEEL_EXPANSION
from ..temperature import TemperaturePolicy
from .artefact import ARTEFACT_REPORT_FILES, evaluate_artefact_run, write_artefact_report
from .common import (aliased_choices_once, check_free, check_model_or_maps, command_inputs, console, console_log,
                     expansion_ppm, fail, load_maps, load_model, machine_option, map_specs, model_doubts, model_options,
                     overwrite_option, policy_options, print_model_check, scheduler_options, say_caught,
                     skip_incomplete_option, strict_model_exit, warn, writing)
from .common import TEMPERATURE


def report_folder_names(run_dirs, report_dir) -> list[str]:
    """The folder of each run's report under ``--report`` (the run folder's name), the same with --model and on
    the --scheduler: ``InputError`` naming both runs when two share a name (day1/run, day2/run), before any
    work - one report would replace the other while the summary lists both."""
    names = [Path(r).name if Path(r).name not in ("", ".", "..") else Path(os.path.abspath(r)).name or "root"
             for r in run_dirs]
    if report_dir:
        first: dict[str, str] = {}
        for r, name in zip(run_dirs, names):
            if name in first:
                raise InputError(f"--report: two runs share a folder name: {first[name]} and {r} would both write "
                                 f"{Path(report_dir) / name}, one report overwriting the other; report them in "
                                 "separate --report folders (or rename one run folder)")
            if name in FLEET_FILES:
                raise InputError(f"--report: the run {r}'s report folder {Path(report_dir) / name} would be the "
                                 f"file the summary across runs is written to; report it in another --report folder "
                                 "(or rename the run folder)")
            first[name] = str(r)
        check_report_paths(report_dir, [Path(n) / f for n in names for f in (*REPORT_FILES, *UNCERTAINTY_FILES)]
                           + list(FLEET_FILES))
    return names


def report_targets(folder) -> list[Path]:
    """Every file one run's --report may write in ``folder`` (a ballbar run's report and budgets, an artefact
    run's report and the deviation plots an earlier one left there): checked before any work, so that without
    --overwrite no earlier report is replaced, not even in part."""
    folder = Path(folder)
    earlier = sorted(folder.glob("deviations_*.png")) if folder.is_dir() else []
    return [folder / f for f in dict.fromkeys((*REPORT_FILES, *UNCERTAINTY_FILES, *ARTEFACT_REPORT_FILES))] + earlier


def check_report_free(o: EvaluateOptions, names=None) -> None:
    """Before any work: no file --report would write exists (unless --overwrite) or is an input, through links
    (cmmpose.cli.common.check_free); ``names``: the runs' report folders in a report across runs."""
    if not o.report_dir:
        return
    folders = [Path(o.report_dir)] if names is None else [Path(o.report_dir) / n for n in names]
    targets = [t for f in folders for t in report_targets(f)]
    if names is not None:
        targets += [Path(o.report_dir) / f for f in FLEET_FILES]
    check_free({"--report": targets}, o.inputs, overwrite=o.overwrite, folders_made=True)


#: The files of one ballbar run's report beside evaluation/files.py's (the uncertainty budgets).
UNCERTAINTY_FILES = ("uncertainty.json", "uncertainty.md")


def check_report_paths(report_dir, names) -> None:
    """Before any work: every file --report will write (``names``, relative to ``report_dir``) can be
    written - no folder where a file goes and no file where a folder goes (cmmpose.atomicfile.check_output)
    - so that no report is left half written."""
    report_dir = Path(report_dir)
    for name in names:
        path = report_dir / name
        for parent in [*reversed(Path(name).parents)][1:]:  # the folders on the way
            where = report_dir / parent
            if where.exists() and not where.is_dir():
                raise InputError(f"--report: {where} is a file, where the report needs a folder; give another "
                                 "--report folder")
        if path.is_dir():
            raise InputError(f"--report: {path} is a folder, where the report writes a file; give another "
                             "--report folder")


def write_report(evaluation, directory: Path, maps=None) -> list[Path]:
    """The evaluation's files (:func:`cmmpose.evaluation.files.write_evaluation_files`), the library's notes
    (no matplotlib: no plots) printed; the files written."""
    with console_log():
        return write_evaluation_files(evaluation, directory, maps)


@click.command("evaluate")
@click.argument("run_dir", metavar="RUN_DIR...", nargs=-1, required=True, type=click.Path(exists=True, file_okay=False))
@machine_option
@click.option("--maps", "maps", multiple=True, callback=map_specs,
              help="Compensation maps ('thesis', files, or 'none'); default: the machine's, or as run.json says.")
@click.option("--temperature", type=TEMPERATURE, default=None, help="Machine temperature, C (default: the run's thermocouple log).")
@policy_options()
@click.option("--expansion", type=float, default=None, callback=expansion_ppm,
              help=f"Artefact expansion coefficient for lengths at 20 C, ppm/K (default: the machine's, "
                   f"{STEEL_EXPANSION * 1e6:g} for the thesis machine).")
@click.option("--reject", type=float, default=None, help="Robust sphere fits: reject beyond this many robust sigmas.")
@click.option("--report", "report_dir", type=click.Path(file_okay=False), default=None, help="Write JSON, CSV and plots here.")
@click.option("--u-temperature", type=float, default=None,
              help="Standard uncertainty of the machine temperature reading, K (default 0.2).")
@click.option("--u-map", type=float, default=None,
              help="Standard uncertainty of each axis's map scale, ppm (default: the interferometer's air, ~1.4).")
@click.option("--u-model", type=float, default=0.0, show_default=True,
              help="Standard uncertainty of the residual model error, ppm of the length (0: left out of the budget).")
@click.option("--json", "as_json", is_flag=True, help="Print JSON instead of the table.")
@click.option("--verbose", "-v", is_flag=True,
              help="After the summary (each figure with U, k = 2, and what the compensation did), also print every "
                   "length and the uncertainty budgets.")
@skip_incomplete_option
@scheduler_options("Evaluate the runs on Dask: 'threads', 'processes' or a scheduler address tcp://host:port "
                   "(default with several runs: threads; needs the dask extra).")
@model_options(" (inputs the run lacks are an error naming them); its parameters' uncertainties enter the "
               "budgets. Several runs: each evaluated in turn with the model, with its budgets; --json prints a "
               "list, --report a folder per run.")
@overwrite_option("Replace the files of an earlier --report (never an input).")
def evaluate_cmd(**flags) -> None:
    """Ballbar evaluation of RUN_DIR: lengths per position, uncompensated and compensated.

    With several runs (a fleet, or a day's runs), each is evaluated on the
    --scheduler and a summary table across them is printed; --report writes
    the summary (CSV), each run's report and a plot of the trend. One run:
    every figure with its uncertainty (k = 2) and budget (docs/uncertainty.md)."""
    from ..machine import load_machine
    from ..run import Run

    o = EvaluateOptions.from_flags(flags)
    check_model_or_maps(o.model_file, o.user_files, o.maps, o.strict_model)
    if o.model_file is not None and o.scheduler is not None:
        raise click.UsageError("--model evaluates its runs one after another in this process, each with its "
                               "budgets: --scheduler is for maps")
    if o.model_file is not None and len(o.run_dirs) > 1:
        return _evaluate_with_model(o)
    fleet = len(o.run_dirs) > 1 or o.scheduler is not None
    try:
        if fleet:
            # The table across runs carries no uncertainties: their options would do nothing.
            for flag, given in (("--u-temperature", o.u_temperature is not None), ("--u-map", o.u_map is not None),
                                ("--u-model", o.u_model != 0.0)):
                if given:
                    raise click.UsageError(f"{flag} takes one run: the table across runs has no uncertainties "
                                           "(evaluate each run on its own for them)")
            check_report_free(o, report_folder_names(o.run_dirs, o.report_dir))  # before any work
        elif o.report_dir:
            check_report_paths(o.report_dir, (*REPORT_FILES, *UNCERTAINTY_FILES))  # before any work
            check_report_free(o)
        machine = load_machine(o.machine_file)
        expansion = o.expansion_for(machine)
        if fleet:
            return _evaluate_fleet(o, machine, expansion)
        run_dir = o.run_dirs[0]
        run = Run.load(run_dir)
        with_model = o.model_file is not None
        model = load_model(o.model_file, o.user_files) if with_model else machine.maps_for_run(run, o.maps)
        if "definition" in run.artefact:  # an artefact run (cmmpose simulate --artefact): cli/artefact.py
            return evaluate_artefact_run(run, model, o.temperature, o.reject, o.u_temperature, o.report_dir,
                                         o.as_json, {"temperature_policy": o.temperature_policy},
                                         strict_model=o.strict_model if with_model else None,
                                         outputs=writing("--report", [o.report_dir], o.inputs,
                                                         overwrite=o.overwrite))
        ev, check, caught = _evaluated(run, model, with_model, o.evaluate_keywords(expansion))
        say_caught(caught)
        unc = _evaluation_uncertainty(run, ev, model, o)
        files = []
        if o.report_dir:
            with writing("--report", [o.report_dir], o.inputs, overwrite=o.overwrite):  # exclusive, whole or none
                files = write_report(ev, Path(o.report_dir), getattr(model, "maps", model) if with_model else model)
                files += [Path(o.report_dir) / "uncertainty.json", Path(o.report_dir) / "uncertainty.md"]
                write_text(files[-2], unc.to_json(indent=2))
                write_text(files[-1], unc.to_markdown())
    except Error as exc:
        raise fail(exc) from None
    if o.as_json:
        click.echo(strict_json({**ev.to_dict(), "uncertainty": unc.to_dict(),
                                **({"model_check": check.to_dict()} if check is not None else {})}, indent=2))
    else:
        print_evaluation(ev, unc, o.verbose)
        if check is not None:
            print_model_check(check)
    for f in files:
        console.print(f"wrote {f}")
    if check is not None:
        strict_model_exit(model_doubts(caught) + ([check.verdict] if check.worse else []), o.strict_model)


@dataclass(frozen=True)
class EvaluateOptions:
    """What ``cmmpose evaluate`` was asked, from its flags: one object for the command and its helpers.

    The temperature policy's flags arrive as ``temperature_policy`` (built by
    :func:`~cmmpose.cli.temperature_options.temperature_options`); its ``out_of_range``,
    ``temperature_tolerance`` and ``log_hold`` are what the evaluation is given beside it."""

    run_dirs: tuple[str, ...]
    machine_file: str | None
    maps: tuple[str, ...]
    temperature: float | None
    temperature_policy: TemperaturePolicy
    #: --expansion, ppm/K; None: the machine's artefact expansion.
    expansion: float | None
    reject: float | None
    u_temperature: float | None
    u_map: float | None
    u_model: float
    report_dir: str | None
    as_json: bool
    skip_incomplete: bool
    scheduler: str | None
    scheduler_timeout: float
    model_file: str | None
    user_files: tuple[str, ...]
    strict_model: bool
    verbose: bool
    #: --overwrite: replace an earlier report (never an input).
    overwrite: bool = False

    @classmethod
    def from_flags(cls, flags: dict) -> EvaluateOptions:
        """The options from the command's click parameters (by their names)."""
        return cls(run_dirs=tuple(flags["run_dir"]), machine_file=flags["machine_file"], maps=flags["maps"],
                   temperature=flags["temperature"], temperature_policy=flags["temperature_policy"],
                   expansion=flags["expansion"], reject=flags["reject"], u_temperature=flags["u_temperature"],
                   u_map=flags["u_map"], u_model=flags["u_model"], report_dir=flags["report_dir"],
                   as_json=flags["as_json"], skip_incomplete=flags["skip_incomplete"], scheduler=flags["scheduler"],
                   scheduler_timeout=flags["scheduler_timeout"], model_file=flags["model_file"],
                   user_files=flags["user_files"], strict_model=flags["strict_model"], verbose=flags["verbose"],
                   overwrite=flags["overwrite"])

    @property
    def inputs(self) -> list:
        """Every file the evaluation reads (no --report file may be one): the runs' files, the machine file and
        its maps, the --maps files, the model and its user effects."""
        return command_inputs([self.machine_file, *self.maps, self.model_file, *self.user_files], self.run_dirs)

    def expansion_for(self, machine) -> float:
        """The artefact's expansion coefficient, ppm/K: --expansion, or the machine's."""
        return machine.artefact_expansion * 1e6 if self.expansion is None else self.expansion

    def evaluate_keywords(self, expansion: float) -> dict:
        """The keywords of :func:`cmmpose.evaluate` (and of the model check and the scale-out): the temperature,
        its policy (the whole and its fields), the fits' rejection, the expansion, skipping incomplete
        positions."""
        policy = self.temperature_policy
        return dict(temperature=self.temperature, reject=self.reject, out_of_range=policy.out_of_range,
                    temperature_tolerance=policy.temperature_tolerance, log_hold=policy.log_hold,
                    expansion_ppm_per_K=expansion, skip_incomplete=self.skip_incomplete, temperature_policy=policy)


def _evaluate_with_model(o: EvaluateOptions) -> None:
    """`evaluate RUN_DIR... --model m.json`: each run evaluated with the found model in turn (the model loaded
    once), each with its figures, budgets and warnings (an aliased choice that matters on that run); --json a
    list of the single-run documents, each with its ``run``; --report a folder per run."""
    from ..machine import load_machine
    from ..run import Run

    docs, files, doubts = [], [], []
    try:
        names = report_folder_names(o.run_dirs, o.report_dir)
        check_report_free(o, names)  # before any work
        machine = load_machine(o.machine_file)
        expansion = o.expansion_for(machine)
        model = load_model(o.model_file, o.user_files)
        for r, name in zip(o.run_dirs, names):
            run = Run.load(r)
            if "definition" in run.artefact:
                raise InputError(f"{r}: an artefact run: evaluate it on its own with --model")
            ev, check, caught = _evaluated(run, model, True, o.evaluate_keywords(expansion))
            said = [str(w.message) for w in caught if not issubclass(w.category, (DeprecationWarning,
                                                                                   PendingDeprecationWarning))]
            doubts += [f"{name}: {t}" for t in model_doubts(caught) + ([check.verdict] if check.worse else [])]
            for text in said:
                warn(f"{name}: {text}")
            unc = _evaluation_uncertainty(run, ev, model, o)
            if o.report_dir:
                folder = Path(o.report_dir) / name
                with writing("--report", [folder], o.inputs, overwrite=o.overwrite):  # this run's report or none
                    files += write_report(ev, folder, model.maps)
                    files += [folder / "uncertainty.json", folder / "uncertainty.md"]
                    write_text(files[-2], unc.to_json(indent=2))
                    write_text(files[-1], unc.to_markdown())
            if o.as_json:
                docs.append({"run": str(r), **ev.to_dict(), "uncertainty": unc.to_dict(), "warnings": said,
                             "model_check": check.to_dict()})
            else:
                print_evaluation(ev, unc, o.verbose, name=str(r))
                print_model_check(check)
    except Error as exc:
        raise fail(exc) from None
    if o.as_json:
        click.echo(strict_json(docs, indent=2))
    for f in files:
        console.print(f"wrote {f}")
    strict_model_exit(doubts, o.strict_model)


def evaluation_summary(ev, unc, name: str | None = None) -> Group:
    """The top of a ballbar evaluation on the console: each summary figure with its expanded uncertainty
    (k = 2) uncompensated and compensated, what the compensation did in words (each change's verb following
    its sign, unchanged within its uncertainty), the largest term of a length's budget, and the library's
    notes.

    Parameters
    ----------
    ev : Evaluation
        :func:`cmmpose.evaluate`'s result.
    unc : EvaluationUncertainty
        Its uncertainties (:func:`cmmpose.evaluation.ballbar_uncertainty.evaluation_uncertainty`).
    name : str, optional
        The run's name (its folder), in the title.
    """
    from ..diagnosis.wording import change_text

    results = {r.label: r for r in unc.results}
    labels = [r.label for r in ev.results]
    first = ev.results[0]
    t = Table(title=(f"{escape(name)}: " if name else "") + f"ballbar evaluation, {len(first.positions)} positions "
              f"(value ± U, k = {results[labels[0]].mean.k:g})", title_justify="left")
    t.add_column("figure", overflow="fold")
    for label in labels:
        t.add_column(label, justify="right", overflow="fold")
    for i, figure in enumerate(("mean length (mm)", "mean length at 20 C (mm)", "rms accuracy error (um)",
                                "B89 (um)")):
        cells = []
        for label in labels:
            f = results[label].figures[i]
            cells.append(f"{f.value:.4f} ± {f.U * 1e-3:.4f}" if f.unit == "mm" else f"{f.value:.2f} ± {f.U:.2f}")
        t.add_row(figure, *cells)
    lines = []
    if ev.compensated is not None and "uncompensated" in results and "compensated" in results:
        before, after = results["uncompensated"], results["compensated"]
        said = []
        for what, a, b in (("the rms accuracy error", before.rms_accuracy_error, after.rms_accuracy_error),
                           ("the B89 value", before.b89, after.b89)):
            said.append(change_text(what, a.value, b.value, math.hypot(a.u, b.u)))
        lines.append("compensated: " + "; ".join(said) + f" (improvement: rms {ev.improvement_rms:.1%}, "
                     f"B89 {ev.improvement_b89:.1%})")
    last = results[labels[-1]]
    budget = last.budgets.get("length")
    if budget is not None and budget.inputs:
        shares = budget.shares()
        k = max(range(len(shares)), key=shares.__getitem__)
        lines.append(f"a length's uncertainty ({last.label}): u = {budget.combined_standard_uncertainty:.2f} um, "
                     f"{shares[k]:.0%} of its variance from {budget.inputs[k].name}")
    lines += list(ev.provenance.get("notes", []))
    lines.append("every length, the budgets and what they leave out: --verbose (or --json, --report)")
    return Group(t, *(Text(line) for line in lines))


def print_evaluation(ev, unc, verbose: bool = False, name: str | None = None) -> None:
    """A ballbar evaluation on stdout at the terminal's width: the summary (:func:`evaluation_summary`);
    ``verbose``: then every length and the uncertainty budgets."""
    out = Console()
    out.print(evaluation_summary(ev, unc, name))
    if verbose:
        out.print(ev)
        out.print(unc)


def _evaluated(run, model, check: bool, options: dict):
    """The run evaluated with ``model`` (cmmpose.evaluate) and, with ``check``, the model checked as saved
    beside its plain maps (cmmpose.evaluation.model_check); the warnings caught, each kind every time it is
    given (the command says them once)."""

    with warnings.catch_warnings(record=True) as caught, aliased_choices_once():
        for category in (MapTemperatureWarning, AliasedChoiceWarning, ModelDomainWarning):
            warnings.simplefilter("always", category)
        ev = evaluate(run, model, **options)
        checked = check_model(run, model, evaluation=ev, **options) if check else None
    return ev, checked, caught


def _evaluation_uncertainty(run, ev, model, o: EvaluateOptions):
    """u (k = 2) and budgets of every figure of ``ev`` (cmmpose.evaluation.ballbar_uncertainty)."""
    from ..evaluation.ballbar_uncertainty import DEFAULT_U_TEMPERATURE_K, evaluation_uncertainty

    policy = o.temperature_policy
    with warnings.catch_warnings():  # the evaluation said what it clamped or extrapolated; not again at each
        for category in (ClampWarning, ExtrapolationWarning):  # +-step of the temperature sensitivity
            warnings.simplefilter("ignore", category)
        return evaluation_uncertainty(
            run, ev, model, o.temperature, reject=o.reject, out_of_range=policy.out_of_range,
            temperature_tolerance=policy.temperature_tolerance, log_hold=policy.log_hold,
            u_temperature_K=DEFAULT_U_TEMPERATURE_K if o.u_temperature is None else o.u_temperature,
            u_map_ppm=o.u_map, u_model_ppm=o.u_model, temperature_policy=policy)


def _evaluate_fleet(o: EvaluateOptions, machine, expansion: float) -> None:
    """`evaluate RUN_DIR...`: every run on a Dask scheduler (cmmpose.scale), then one table across them."""
    import logging

    from ..evaluation.ballbar import skipped_note
    from ..scale import evaluate_runs, fleet_summary

    run_dirs, maps, report_dir, as_json = o.run_dirs, o.maps, o.report_dir, o.as_json
    scheduler, options = o.scheduler or "threads", o.evaluate_keywords(expansion)
    logging.getLogger("distributed").setLevel(logging.WARNING)  # the local cluster's start-up chatter
    if maps == ("none",):
        model = None
    elif maps or not machine.is_default:
        model = load_maps(maps, machine)
    else:
        model = "run"  # each run.json names its bundled maps
    with Progress(TextColumn("evaluating"), BarColumn(), TextColumn("{task.completed:.0f}/{task.total:.0f} runs"),
                  console=console) as bar:
        task = bar.add_task("", total=len(run_dirs))
        evaluations = evaluate_runs(run_dirs, model, scheduler=scheduler, scheduler_timeout=o.scheduler_timeout,
                                    progress=lambda done, total: bar.update(task, completed=done), **options)
    rows = fleet_summary(run_dirs, evaluations)
    files = []
    if report_dir:
        from ..evaluation.artefact import ArtefactEvaluation  # here: the uncertainty budget's imports, ~80 ms
        from ..evaluation.plots import plot_fleet_trend

        directory = ensure_folder(report_dir)
        folders = [directory, *(directory / n for n in report_folder_names(run_dirs, report_dir))]
        with writing("--report", folders, o.inputs, overwrite=o.overwrite):  # exclusive; every report or none
            for name, ev in zip(report_folder_names(run_dirs, report_dir), evaluations):
                if isinstance(ev, ArtefactEvaluation):  # a plate or step-gauge run of the fleet
                    files += write_artefact_report(ev, directory / name)
                    continue
                files += write_report(ev, directory / name, model if not isinstance(model, str) else None)
            summary = directory / "summary.csv"
            fields = list(rows[0].__dataclass_fields__)
            write_text(summary, "\n".join([",".join(fields)] + [",".join(str(getattr(row, f)) for f in fields)
                                                                 for row in rows]) + "\n")
            files.append(summary)
            try:
                plot_fleet_trend(rows, directory / "trend.png")
                files.append(directory / "trend.png")
            except (ImportError, InputError) as exc:  # the table is still printed
                console.print(f"[yellow]no trend plot:[/] {escape(str(exc))}")
    if as_json:
        click.echo(strict_json([{**{k: (None if isinstance(v, float) and v != v else v) for k, v in row.__dict__.items()},
                                "skipped": ev.skipped} for row, ev in zip(rows, evaluations)],
                               indent=2))  # NaN (no value) as null: strict JSON
    else:
        table = Table(title=f"cmmpose evaluate: {len(rows)} runs on {scheduler}")
        table.add_column("run", overflow="fold")
        table.add_column("created", overflow="fold")
        table.add_column("temperature (C)", justify="right")
        artefact_runs = any(row.kind != "ballbar" for row in rows)
        for what in ("uncompensated", "compensated"):
            table.add_column(f"{what}\nrms (um)", justify="right")
            table.add_column("B89 | max|E| (um)" if artefact_runs else "B89 (um)", justify="right")
        if artefact_runs:  # a plate or step gauge has no ballbar lengths: its own figures
            table.caption = ("artefact runs (kind after the run): rms = rms ball deviation after each placement's "
                             "best-fit rigid transform, max|E| = largest ball-pair length error")
        um = lambda x: "-" if x != x else f"{x * 1e3:.1f}"  # noqa: E731 - NaN: no value
        for row in rows:
            table.add_row(escape(row.run) + ("" if row.kind == "ballbar" else f" ({row.kind})"), row.created, "-" if row.temperature != row.temperature else f"{row.temperature:.2f}",
                          um(row.rms_uncompensated), um(row.b89_uncompensated), um(row.rms_compensated),
                          um(row.b89_compensated))
        Console().print(table)
        for row, ev in zip(rows, evaluations):
            if ev.skipped:
                console.print(f"[yellow]{escape(row.run)}:[/] {escape(skipped_note(ev.skipped))}")
    for f in files:
        console.print(f"wrote {f}")
