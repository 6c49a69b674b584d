"""The package's shape (docs/architecture.md): no import circles among the
modules' top-level imports, no module importing another's private names, a
curated public face (``dir(cmmpose)``), and a command line whose every
option has help, whose result-printing commands all take --json, and whose
moved commands still answer to their old spellings."""

import ast
import json
import sys
from pathlib import Path

import click
import pytest
from click.testing import CliRunner

import cmmpose
from cmmpose.cli import main

PACKAGE = Path(cmmpose.__file__).parent


def _modules() -> dict[str, Path]:
    out = {}
    for path in PACKAGE.rglob("*.py"):
        parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        out[".".join(parts)] = path
    return out


MODULES = _modules()


def _is_package(name: str) -> bool:
    return MODULES[name].name == "__init__.py"


def _top_level_imports(tree: ast.Module):
    """Imports run when the module is imported: at module level, in if/try at module level, not under
    ``if TYPE_CHECKING``; imports inside functions run later and are not counted."""
    for node in tree.body:
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            yield node
        elif isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            continue
        elif isinstance(node, (ast.If, ast.Try)):
            yield from (n for n in ast.walk(node) if isinstance(n, (ast.Import, ast.ImportFrom)))


def _imports(name: str):
    """(module imported, name taken from it or None, whether the name is itself a module) of ``name``."""
    package = name if _is_package(name) else name.rpartition(".")[0]
    for node in _top_level_imports(ast.parse(MODULES[name].read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            pairs = [(a.name, None) for a in node.names]
        else:
            base = package.split(".")[:len(package.split(".")) - node.level + 1] if node.level else []
            module = ".".join(base + ([node.module] if node.module else [])) if node.level else node.module
            pairs = [(module, a.name) for a in node.names]
        for module, attr in pairs:
            if not module or not module.startswith("cmmpose"):
                continue
            if attr and (f"{module}.{attr}" in MODULES or f"{module}.{attr}" == "cmmpose._core"):
                yield f"{module}.{attr}", attr, True  # a submodule (the compiled _core too)
            elif module in MODULES:
                yield module, attr, False


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on, found = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10 * len(graph)))
    for v in graph:
        if v not in index:
            visit(v)
    return found


def test_the_cycle_finder_finds_a_cycle():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_circles():
    graph = {}
    for name in MODULES:
        # an ancestor package is imported first whatever the module says: not an edge
        graph[name] = {t for t, _, _ in _imports(name)
                       if t in MODULES and not (_is_package(t) and (name + ".").startswith(t + "."))}
    assert _cycles(graph) == []


def test_no_module_imports_another_modules_private_names():
    private = [f"{name} imports {attr} from {target}" for name in MODULES for target, attr, is_module in _imports(name)
               if attr and attr.startswith("_") and not attr.startswith("__") and not is_module]
    assert private == []


def test_the_public_face_is_curated():
    names = dir(cmmpose)
    assert not [n for n in names if n.startswith("_") and n != "__version__"]
    assert "TYPE_CHECKING" not in names and "lazy_attributes" not in names
    assert set(cmmpose.__all__) <= set(names)
    for name in cmmpose.__all__:
        assert getattr(cmmpose, name) is not None, name
    # the public modules stay reachable
    for module in ("errors", "machine", "evaluation", "pointclouds", "cli"):
        assert getattr(__import__(f"cmmpose.{module}").__dict__[module], "__name__") == f"cmmpose.{module}"


def _commands(command=main, path=("cmmpose",)):
    if isinstance(command, click.Group):
        for name, sub in command.commands.items():
            yield from _commands(sub, (*path, name))
    else:
        yield " ".join(path), command


def test_every_option_of_every_command_has_help():
    missing = [f"{path} {p.opts[0]}" for path, cmd in _commands() for p in cmd.params
               if isinstance(p, click.Option) and not (p.help or "").strip()]
    assert missing == []


#: Commands that only write a file (and say "wrote ...") or record live: no result to print as JSON.
WRITERS = {"cmmpose acquire", "cmmpose machine example", "cmmpose artefact example", "cmmpose map plot",
           "cmmpose plot-map", "cmmpose artefact plan"}


def test_every_command_that_prints_results_takes_json():
    lacking = [path for path, cmd in _commands() if path not in WRITERS and not cmd.hidden
               and not any("--json" in p.opts for p in cmd.params if isinstance(p, click.Option))]
    assert lacking == []


def test_report_is_a_folder_everywhere():
    for path, cmd in _commands():
        for p in cmd.params:
            if "--report" in getattr(p, "opts", ()):
                assert not getattr(p.type, "dir_okay", True) is False, f"{path}: --report must take a folder"


def test_the_run_argument_has_one_name():
    names = {p.human_readable_name.rstrip(".") for _, cmd in _commands() for p in cmd.params
             if isinstance(p, click.Argument) and p.name in ("run_dir", "run_dirs")}
    assert names == {"RUN_DIR"}


@pytest.mark.parametrize("old, new", [(["iso230-2"], ["standards", "iso230-2"]),
                                      (["acceptance"], ["standards", "acceptance"]),
                                      (["interim-check"], ["standards", "interim-check"]),
                                      (["e3125-distances"], ["standards", "e3125-distances"]),
                                      (["acceptance-sphere"], ["standards", "acceptance-sphere"]),
                                      (["simulate-alignment"], ["calibrate", "simulate-alignment"]),
                                      (["plot-map"], ["map", "plot"])])
def test_moved_commands_answer_to_both_spellings(old, new):
    runner = CliRunner()
    assert runner.invoke(main, [*new, "--help"]).exit_code == 0
    with pytest.warns(FutureWarning, match=" ".join(new)):
        r = runner.invoke(main, [*old, "--no-such-option-to-stop-early"])
    assert r.exit_code == 2  # the old spelling parses the same options (then click stops on the unknown one)
    assert old[0] not in main.list_commands(click.Context(main)) or main.get_command(None, old[0]).hidden


def test_old_spelling_runs_the_same_command(tmp_path):
    out_old, out_new = tmp_path / "old.png", tmp_path / "new.png"
    pytest.importorskip("matplotlib")
    with pytest.warns(FutureWarning, match="map plot"):
        assert CliRunner().invoke(main, ["plot-map", "thesis", "-o", str(out_old)]).exit_code == 0
    assert CliRunner().invoke(main, ["map", "plot", "thesis", "-o", str(out_new)]).exit_code == 0
    assert out_old.stat().st_size > 0 and out_new.stat().st_size > 0


@pytest.mark.parametrize("args", [["effects"], ["machine", "configurations"], ["machine", "show"]])
def test_json_output_is_standard_json(args):
    r = CliRunner().invoke(main, [*args, "--json"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)


def test_simulate_and_compensate_print_json(tmp_path):
    r = CliRunner().invoke(main, ["simulate", "-o", str(tmp_path / "run"), "--json"])
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout)
    assert out["points"] > 0 and out["layout"] == "b89"


def test_diagnose_report_old_file_spelling_warns(tmp_path):
    from cmmpose.cli.common import report_folder_html

    ctx = click.Context(main.get_command(None, "diagnose"), info_name="diagnose")
    assert report_folder_html(ctx, None, str(tmp_path / "r")) == str(tmp_path / "r" / "diagnose.html")
    with pytest.warns(FutureWarning, match="folder"):
        assert report_folder_html(ctx, None, "x.html") == "x.html"


def test_the_machine_description_does_not_load_the_simulator():
    import subprocess

    code = "import sys, cmmpose.machine as m; m.load_machine(None); print('cmmpose.sim' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"
