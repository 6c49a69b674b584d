"""What every command shares: the console, the --machine/--maps/policy/scheduler options, argument parsing, and a library error as the command line says it."""

from __future__ import annotations

import logging
import math
import os
import warnings
from pathlib import Path

import click
from rich.console import Console
from rich.markup import escape

from .._arrays import as_triple
from .._json import dumps as strict_json
from ..atomicfile import FileGroup, check_not_input, check_outputs_free
from ..errormap import ErrorMap, ErrorMapSet
from ..errors import Error, ModelDomainWarning
from ..policy import cli_wording
from ..pose import check_pose_angles
from .temperature_options import temperature_options

console = Console(stderr=True)

#: The seed of every command's random numbers (``--seed``): a non-negative integer, as NumPy takes it.
SEED = click.IntRange(min=0)


class Positive(click.ParamType):
    """A finite number > 0 in ``unit`` (an option's size or noise level: ``--calibrated-length`` mm,
    ``--sigma`` um): nan, inf, 0 and negative values are a usage error naming the option, as the same
    values in a file are an error (``float`` and ``click.FloatRange`` let nan through)."""

    name = "float"

    def __init__(self, unit: str):
        self.unit = unit

    def convert(self, value, param, ctx):
        try:
            v = float(value)
        except (TypeError, ValueError):
            self.fail(f"expected a positive number of {self.unit}, got {value!r}", param, ctx)
        if not (math.isfinite(v) and v > 0):
            self.fail(f"expected a positive number of {self.unit}, got {value!r}", param, ctx)
        return v

    def __repr__(self) -> str:
        return f"Positive({self.unit!r})"


#: A finite length > 0, mm (a certified length or radius).
POSITIVE_MM = Positive("mm")


class Temperature(click.ParamType):
    """A machine's or a map's temperature, C, as every command takes it (``--temperature``): a finite number
    within the range the document schemas give a temperature (cmmpose.schemas.TEMPERATURE_C, -50..150
    C). Colder or hotter is no CMM's room, and -273.16 C, below absolute zero, is refused as such rather than
    "extrapolated"; a usage error (exit 2) naming the option, the value in six significant digits."""

    name = "float"

    def convert(self, value, param, ctx):
        from ..schemas import TEMPERATURE_C

        if isinstance(value, float):
            v = value
        else:
            try:
                if not str(value).isascii():
                    raise ValueError(value)
                v = float(value)
            except (TypeError, ValueError):
                self.fail(f"expected a temperature in degrees C, got {value!r}", param, ctx)
        lo, hi = TEMPERATURE_C
        if not (math.isfinite(v) and lo <= v <= hi):
            below = " (below absolute zero, -273.15 C)" if math.isfinite(v) and v < -273.15 else ""
            self.fail(f"{v:.6g} C{below} is outside {lo:g}..{hi:g} C, the temperatures of a CMM's room "
                      "(check the unit: degrees C)", param, ctx)
        return v

    def __repr__(self) -> str:
        return "Temperature()"


#: A machine's or a map's temperature, C (-50..150).
TEMPERATURE = Temperature()


# -- warnings: cmmpose's own as one line each, once per command ------------------------------------------------------

_said: set[str] = set()  # the warnings said while the current command runs (cli_warnings)


def _line(text) -> str:
    """``warning: <text>`` and a newline, or "" when the command has said it already (the library's warning,
    its log line and a command's own report of it are one warning)."""
    text = str(text).strip()
    if text in _said:
        return ""
    _said.add(text)
    return f"warning: {text}\n"


def warn(text: str) -> None:
    """``warning: <text>`` on stderr, one line, once per command (:func:`cli_warnings`)."""
    click.echo(_line(text), err=True, nl=False)


def say_caught(caught) -> None:
    """The warnings a command caught (``warnings.catch_warnings(record=True)``) said: cmmpose's own each as one
    line, once (:func:`warn`); any other passed on to Python's warnings as it was issued."""
    for w in caught:
        if _own(w.category, w.filename):
            warn(str(w.message))
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)


def _own(category, filename) -> bool:
    """Whether a Python warning is cmmpose's own: a category of cmmpose's (ClampWarning, IllConditionedFit, ...)
    or one the command line issues itself (``warnings.warn_explicit(..., "cmmpose", 0)``)."""
    return category.__module__.split(".")[0] == "cmmpose" or filename == "cmmpose"


class cli_warnings:  # noqa: N801 - used as a function: with cli_warnings(): ...
    """While a command runs (cmmpose.cli.main): cmmpose's own Python warnings and the library's log lines of
    level WARNING printed as ``warning: <message>``, one line each, once (:func:`warn`) - not Python's
    ``file:line: Category: message`` and its source line. The library still warns as it does
    (``warnings.warn``: a caller's filters and ``catch_warnings`` see the same); only how the command line
    shows a warning changes (``warnings.formatwarning``), and other packages' warnings keep Python's form."""

    def __enter__(self):
        class Lines(logging.Handler):
            def emit(self, record):
                warn(record.getMessage())

        def formatwarning(message, category, filename, lineno, line=None):
            if _own(category, filename):
                return _line(message)
            return self.formatwarning(message, category, filename, lineno, line)

        _said.clear()
        self.formatwarning, warnings.formatwarning = warnings.formatwarning, formatwarning
        self.logger, self.handler = logging.getLogger("cmmpose"), Lines(logging.WARNING)
        self.logger.addHandler(self.handler)  # instead of logging's last resort: the bare message
        return self

    def __exit__(self, *exc):
        warnings.formatwarning = self.formatwarning
        self.logger.removeHandler(self.handler)
        _said.clear()
        return False


def _plot_suffixes() -> tuple[str, ...] | None:
    """The suffixes matplotlib can save a figure as ('png', 'pdf', 'svg', ...); None without matplotlib."""
    try:
        from matplotlib.backend_bases import FigureCanvasBase
    except ImportError:
        return None
    return tuple(sorted(FigureCanvasBase.get_supported_filetypes()))


def check_plot_path(path, flag: str) -> None:
    """The one check of a plot file's name, which every command naming one (:func:`plot_option`) makes before
    any work: a usage error naming ``flag`` when the suffix is not a format matplotlib can save (no suffix:
    matplotlib's default, PNG). Without matplotlib nothing is checked (the command says it is missing)."""
    if path is None:
        return
    suffix = Path(path).suffix.lower().removeprefix(".")
    known = _plot_suffixes()
    if suffix and known is not None and suffix not in known:
        raise click.BadParameter(f"{path}: '.{suffix}' is not an image format a plot can be saved as; name the file "
                                 f"with one of {', '.join('.' + k for k in known)}", param_hint=flag)


def plot_option(*names: str, help: str, required: bool = False):  # noqa: A002 - click's name
    """An option naming a plot file (``--plot FILE``, ``map plot -o FILE``); the command checks its suffix
    (:func:`check_plot_path`) after its inputs-are-not-outputs check and before any work."""
    return click.option(*names, type=click.Path(dir_okay=False), default=None, required=required, help=help)


def expansion_ppm(ctx, param, value):
    """The callback of every option taking an artefact's expansion coefficient (ppm/K): a usage error outside
    the range a machine file accepts (cmmpose.machine.EXPANSION_RANGE_PPM)."""
    if value is None:
        return None
    from ..machine import EXPANSION_RANGE_PPM  # here: the machine file's imports only when one is given

    lo, hi = EXPANSION_RANGE_PPM
    if not lo <= value <= hi:
        raise click.BadParameter(f"{value:g} ppm/K is outside {lo:g}..{hi:g} ppm/K (a coefficient of expansion in "
                                 "ppm/K, e.g. 11.5 for steel)", ctx=ctx, param=param)
    return value


def parse_effects(texts, flag: str = "--effect") -> list:
    """The effects of a simulating command's ``--effect NAME:param=value,...`` (:func:`cmmpose.sim.parse_effect`):
    a usage error naming the flag for one that would simulate nothing (every parameter at its no-op default,
    :func:`cmmpose.sim.effects.inert`) or an expansion coefficient (ppm/K) outside the machine file's range."""
    from ..sim.effects import inert, parse_effect

    parsed = []
    for text in texts:
        try:
            effect = parse_effect(text)
        except Error as exc:
            raise click.BadParameter(str(exc), param_hint=flag) from None
        reason = inert(effect)
        if reason:
            raise click.BadParameter(f"{text!r}: {reason}", param_hint=flag)
        for name, unit in effect.units().items():
            if unit == "ppm/K":
                try:
                    expansion_ppm(None, None, getattr(effect, name))
                except click.BadParameter as exc:
                    raise click.BadParameter(f"{text!r}: {name} = {exc.message}", param_hint=flag) from None
        parsed.append(effect)
    return parsed


def map_specs(ctx, param, value):
    """The ``--maps`` callback of every command : an empty value (``--maps ""``) is a usage error, not the
    current folder."""
    try:
        from ..machine import check_map_specs  # here: the machine file's imports only for commands given maps

        return check_map_specs(value)
    except Error as exc:
        raise click.BadParameter(str(exc).removeprefix("maps: "), param_hint="--maps") from None



def load_maps(specs: tuple[str, ...], machine=None) -> ErrorMap | ErrorMapSet:
    """'thesis' (bundled 20/25/30 C set), 'appendix-b' (22 C controller map),
    or paths: canonical .csv maps or controller .txt files; several make a
    set. With a machine: its maps when none are named, stacked as it is."""
    from ..machine import read_maps

    return machine.maps(specs) if machine is not None else read_maps(specs)


def machine_option(f):
    """--machine FILE, the same on every command."""
    return click.option("--machine", "machine_file", type=click.Path(exists=True, dir_okay=False), default=None,
                        help="Machine file (TOML: configuration, travel, maps, scanner, mount; "
                             "`cmmpose machine example`). Default: the thesis machine.")(f)


def machine_row(table, machine) -> None:
    """The machine a command used, in its summary table."""
    table.add_row("machine", f"{machine.name} ({machine.kinematics}; {machine.source})")


def kernel_report_rows(table, report, temperature_tolerance) -> None:
    """What the kernel clamped, held or extrapolated, in a summary table (rows only where it did)."""
    if report.clamped:
        x, y, z = report.clamped_position
        table.add_row("clamped", f"X {x}, Y {y}, Z {z}, temperature {report.clamped_temperature}")
    if report.held_temperature:
        table.add_row("held at the maps' edge",
                      f"{report.held_temperature:,} temperatures within {temperature_tolerance:g} K outside")
    if report.extrapolated_temperature:
        table.add_row("extrapolated", f"{report.extrapolated_temperature:,} temperatures, up to "
                                      f"{report.max_extrapolation:.2f} K beyond the maps")


def travel_notes(machine, built) -> list[str]:
    """Where a map misses the machine's travel (a point there cannot be compensated)."""
    return [f"the map covers {axis} {mlo:g}..{mhi:g} mm, less than {machine.name}'s travel {lo:g}..{hi:g} mm "
            f"({machine.source}): points beyond it cannot be compensated"
            for axis, (lo, hi), (mlo, mhi) in machine.uncovered(built.ranges)]


def triple(text: str, name: str) -> tuple[float, float, float]:
    if not text.strip():
        # An empty value would otherwise fall back to a default in silence.
        raise click.BadParameter("an empty value: give three comma-separated numbers, or leave the option out",
                                 param_hint=name)
    try:
        if not text.isascii():  # float() reads Arabic-Indic and other digits: "٩٠" is not typed as 90 on purpose
            raise ValueError(text)
        vals = tuple(float(x) for x in text.split(","))
    except ValueError:
        raise click.BadParameter(f"expected three comma-separated numbers, got {text!r}", param_hint=name) from None
    if len(vals) != 3:
        raise click.BadParameter(f"expected three comma-separated numbers, got {text!r}", param_hint=name)
    return vals  # type: ignore[return-value]


def pose_angles(text: str, name: str) -> tuple[float, float, float]:
    """Three pose angles alpha,beta,gamma in degrees from an option's ``text``:
    a usage error when empty, not three finite numbers or beyond +-360 deg."""
    try:
        return check_pose_angles(name, triple(text, name))
    except Error as exc:
        raise click.BadParameter(str(exc).removeprefix(f"{name}: "), param_hint=name) from None


def offset_mm(text: str, name: str) -> tuple[float, float, float]:
    """A mount offset U1,V1,W1 in mm from an option's ``text``: a usage error
    when empty or not three finite numbers."""
    try:
        return as_triple(name, triple(text, name))
    except Error as exc:
        raise click.BadParameter(str(exc).removeprefix(f"{name}: "), param_hint=name) from None


def check_outputs(outputs: dict, run_dirs=(), files=()) -> None:
    """``InputError`` if an output (flag -> path, None for not given) is one of the
    files the command reads: the runs' files (``cmmpose.run.RUN_FILES``) and ``files``
    (cmmpose.atomicfile.check_not_input: any spelling or link)."""
    inputs = command_inputs(files, run_dirs)
    for flag, path in outputs.items():
        check_not_input(path, inputs, flag)


def command_inputs(files=(), run_dirs=()) -> list:
    """Every file a command reads, for its outputs to be checked against (through links): ``files`` that are
    given (a --maps name such as 'thesis' names no file and is left out), the map files a machine file among
    them names, and the runs' files (``cmmpose.run.RUN_FILES``)."""
    from ..run import RUN_FILES

    given = [f for f in files if f and str(f) != "-"]
    inputs = [Path(r) / n for r in run_dirs for n in RUN_FILES] + given
    inputs += [m for f in given if str(f).lower().endswith(".toml") for m in _machine_maps(f)]
    return inputs


def overwrite_option(help_text: str = "Replace an existing output file (never an input)."):
    """--overwrite, the same flag on every command that writes a file: without it an existing output is refused
    before any work and each output is created exclusively (cmmpose.atomicfile, docs/formats.md)."""
    return click.option("--overwrite", is_flag=True, help=help_text)


def check_free(outputs: dict, inputs=(), *, overwrite: bool, folders_made: bool = False) -> None:
    """Before any work, every output (flag -> a path, several paths, or None when not given) checked by
    :func:`cmmpose.atomicfile.check_outputs_free`: no folder, none of ``inputs`` (any spelling or link), no two
    the same file and, without ``overwrite``, none existing (``OutputError``: ``use --overwrite to replace it``).
    ``folders_made``: the outputs go in folders the command makes (a --report folder): one still missing holds
    nothing to replace and is not an error."""
    for flag, paths in outputs.items():
        if paths is None:
            continue
        paths = [paths] if isinstance(paths, (str, os.PathLike)) else [p for p in paths if p is not None]
        if folders_made:
            paths = [p for p in paths if Path(os.path.realpath(p)).parent.is_dir()]
        check_outputs_free(paths, inputs, overwrite=overwrite, what=flag)


def writing(what: str, outputs, inputs=(), *, overwrite: bool) -> FileGroup:
    """``with writing("--report", [folder], inputs, overwrite=o.overwrite): ...``: every file the block writes
    (through cmmpose.atomicfile, whichever writer) at one of ``outputs`` or directly in one of them (a folder) is
    created exclusively without ``overwrite`` (of two writers one fails), is never one of ``inputs``, and these
    files appear together or not at all (:class:`cmmpose.atomicfile.FileGroup`); messages name them as ``what``
    (the flag). A writer's scratch files elsewhere are written as they are outside the group."""
    return FileGroup(overwrite=overwrite, inputs=[i for i in inputs if i is not None], what=what,
                     only=[o for o in outputs if o is not None])


def _machine_maps(path) -> list:
    """The map files a machine file names (inputs too), or none if it is not a machine file that loads."""
    from ..machine import load_machine

    try:
        return list(load_machine(path).map_files)
    except (Error, OSError):
        return []


def fail(exc: Exception) -> click.ClickException:
    """A library error as the CLI reports it: worded from its fields for the
    command line (the remedy names this command's flag, or says it has none;
    cmmpose.errors.Error.render)."""
    from ..errors import MissingFileError

    text = cli_wording(exc, click.get_current_context(silent=True))
    if isinstance(exc, MissingFileError):  # a name that names no file: a usage error (exit 2), as click says it
        return click.UsageError(text)
    return click.ClickException(text)


def policy_options(log_hold: bool = True):
    """The temperature policy's flags, the same on every command: built from
    the fields of cmmpose.temperature.TemperaturePolicy
    (:func:`cmmpose.cli.temperature_options.temperature_options`; ``log_hold=False``: the
    map side only, for a command given temperatures rather than a log)."""
    return temperature_options(log=log_hold)


def _scheduler_spec(ctx, param, value):
    """--scheduler: a usage error unless threads, processes or tcp://host:port."""
    from ..scale import check_scheduler  # here: the scale-out's imports only for the commands that scale out

    try:
        return None if value is None else check_scheduler(value)
    except Error as exc:
        raise click.BadParameter(str(exc), param_hint="--scheduler") from None


def scheduler_options(help_text: str):
    """--scheduler and --scheduler-timeout, the same on every command that scales out (cmmpose.scale)."""

    from ..scale import SCHEDULER_TIMEOUT

    def wrap(f):
        f = click.option("--scheduler-timeout", type=click.FloatRange(min=0, min_open=True, max=1e6),
                         default=SCHEDULER_TIMEOUT, show_default=True,
                         help="s: the longest wait for a scheduler at an address to accept the connection "
                              "and answer (a port that never answers is an error after it).")(f)
        return click.option("--scheduler", default=None, callback=_scheduler_spec, help=help_text)(f)

    return wrap

class console_log:  # noqa: N801 - used as a function: with console_log(): ...
    """Library log lines (logger ``cmmpose``, level INFO and above) printed as notes and warnings while a
    command runs (a warning once, :func:`warn`)."""

    def __enter__(self):
        class Handler(logging.Handler):
            def emit(self, record):
                if record.levelno >= logging.WARNING:
                    warn(record.getMessage())  # once, with the command's other warnings
                else:
                    console.print(f"note: {escape(record.getMessage())}")

        self.logger = logging.getLogger("cmmpose")
        self.handler = Handler(logging.INFO)
        self.level = self.logger.level
        self.logger.addHandler(self.handler)
        if self.logger.getEffectiveLevel() > logging.INFO:
            self.logger.setLevel(logging.INFO)
        return self

    def __exit__(self, *exc):
        self.logger.removeHandler(self.handler)
        self.logger.setLevel(self.level)
        return False


def json_option(f):
    """--json, the same on every command that prints results."""
    return click.option("--json", "as_json", is_flag=True, help="Print the result as JSON instead of the table.")(f)


def table_data(table) -> dict | list:
    """A rich summary table's cells as JSON-ready data: label -> value for a
    table without a header, else one dict per row keyed by the headers."""
    columns = [[str(c) for c in col._cells] for col in table.columns]
    rows = list(zip(*columns))
    if not table.show_header and len(columns) == 2:
        return dict(rows)
    headers = [str(col.header).replace("\n", " ") for col in table.columns]
    return [dict(zip(headers, row)) for row in rows]


def show(table, as_json: bool, data=None, width: int | None = None) -> None:
    """Print ``table``, or with ``as_json`` ``data`` (default: the table's
    cells, :func:`table_data`) as standard JSON on stdout."""
    if as_json:
        click.echo(strict_json(table_data(table) if data is None else data, indent=2))
    else:
        Console(width=width).print(table)


def report_folder_html(ctx, param, value):
    """--report of a command whose report is one HTML file: the folder it goes in (``DIR/<command>.html``,
    the folder made if missing). An existing path that is not a folder is passed on as it is, marked, for the
    command to refuse after its inputs-are-not-outputs check (:func:`check_report_file`)."""
    if value is None:
        return None
    if _existing_non_folder(value):
        return _NotAFolder(value)  # refused by check_report_file (after check_outputs: an input is named as such)
    return str(Path(value) / f"{ctx.info_name}.html")


class _NotAFolder(str):
    """A --report value naming an existing path that is not a folder (see :func:`report_folder_html`)."""


def _existing_non_folder(path) -> bool:
    return Path(path).exists() and not Path(path).is_dir()


def check_report_file(path, flag: str = "--report") -> None:
    """The check of a --report that :func:`report_folder_html` passed on, made after the command's
    :func:`check_outputs` and before any work: a usage error naming ``flag`` for an existing path that is not
    a folder - a user's file (notes.txt, or an earlier report.html) is never replaced by the report."""
    if isinstance(path, _NotAFolder):
        raise click.BadParameter(f"{path}: exists and is not a folder (--report names a folder, made if missing, "
                                 "for the HTML report); give another name", param_hint=flag)


def skip_incomplete_option(f):
    """--skip-incomplete, the same on every command that evaluates ballbar positions."""
    return click.option("--skip-incomplete", is_flag=True,
                        help="Leave out positions whose ball scans are missing, duplicated or mislabelled (listed in "
                             "the output, its JSON and the report); without it such a position is an error.")(f)


def model_options(help_text: str):
    """--model and --user-effect: a model a diagnosis saved, used where maps would be (compensate, evaluate)."""
    def wrap(f):
        f = click.option("--strict-model", is_flag=True,
                         help="With --model: exit with status 1 when the model is applied outside the domain it was "
                              "fitted on, where its correction is not determined, or (evaluate) where it makes a run "
                              "worse than its plain maps beyond the uncertainties: a production line can gate on "
                              "it.")(f)
        f = click.option("--user-effect", "user_files", multiple=True, type=click.Path(exists=True, dir_okay=False),
                         help="With --model: a Python file defining a user effect the model holds (repeatable).")(f)
        return click.option("--model", "model_file", type=click.Path(dir_okay=False), default=None,
                            help="Compensate with a model a diagnosis saved (`cmmpose diagnose --save-model`): its "
                                 f"maps and effects{help_text} Instead of --maps.")(f)
    return wrap


def check_model_or_maps(model_file, user_files, maps, strict_model: bool = False) -> None:
    """--model replaces --maps; --user-effect and --strict-model only make sense with --model."""
    if model_file is None and user_files:
        raise click.UsageError("--user-effect is for the effects of a --model")
    if model_file is None and strict_model:
        raise click.UsageError("--strict-model checks a --model: give one")
    if model_file is not None and maps:
        raise click.UsageError("give --maps or --model (whose maps it holds), not both")


class aliased_choices_once:  # noqa: N801 - used as a function: with aliased_choices_once(): ...
    """While a command applies a --model: its aliased-choice warnings (``AliasedChoiceWarning``, which the
    command prints) are not printed a second time from the library's log line."""

    def __enter__(self):
        import logging

        self.logger = logging.getLogger("cmmpose.model.alternatives")
        self.propagate, self.handler = self.logger.propagate, logging.NullHandler()
        self.logger.addHandler(self.handler)
        self.logger.propagate = False
        return self

    def __exit__(self, *exc):
        self.logger.removeHandler(self.handler)
        self.logger.propagate = self.propagate
        return False


def load_model(model_file, user_files=()):
    """The model saved in ``model_file`` (``--model``), with the user effects it names."""
    from ..model import Model, load_user_effects

    return Model.load(model_file, load_user_effects(user_files))


def model_doubts(caught) -> list[str]:
    """What a --model's application said that --strict-model gates on: its ``ModelDomainWarning`` texts."""
    return [str(w.message) for w in caught if issubclass(w.category, ModelDomainWarning)]


def strict_model_exit(doubts, strict_model: bool) -> None:
    """With --strict-model, exit with status 1 when the model's application was doubted (``doubts``: the
    sentences, already printed); the results are printed and written all the same."""
    if strict_model and doubts:
        console.print(f"[bold red]--strict-model:[/] the model's application was doubted {len(doubts)} time(s) "
                      f"(above): exit status 1")
        raise click.exceptions.Exit(1)


def print_model_check(check) -> None:
    """The model as saved against its plain maps on a run (cmmpose.evaluation.model_check), in words."""
    colour = "red" if check.worse else "green" if check.change_um < -check.change_u_um else "yellow"
    console.print(f"[bold {colour}]model check:[/] {escape(check.verdict)}")
    if check.correction_um > 0:
        console.print(f"model correction here: {check.correction_um:.2f} um rms beyond the plain maps, predicted "
                      f"standard uncertainty {check.correction_u_um:.2f} um (from its parameters' covariance)")
