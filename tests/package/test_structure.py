"""The package's shape (docs/architecture.md): no import circles among the
modules' imports (top-level ones, and those inside functions too), no module importing another's private names, a
curated public face (``dir(cmmpose)``), and a command line whose every
option has help and whose result-printing commands all take --json."""

import ast
import json
import subprocess
import sys
from pathlib import Path

import click
import pytest
from click.testing import CliRunner

import cmmpose
from cmmpose.cli import main
from repo import REPO

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


def _all_imports(tree: ast.Module):
    """Every import of a module, those inside functions (run later, on first use) included; not those under
    ``if TYPE_CHECKING``."""
    skip = {id(n) for node in ast.walk(tree) if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test)
            for n in ast.walk(node)}
    return [n for n in ast.walk(tree) if isinstance(n, (ast.Import, ast.ImportFrom)) and id(n) not in skip]


def _imports(name: str, deferred: bool = False):
    """(module imported, name taken from it or None, whether the name is itself a module) of ``name``: its
    top-level imports, or with ``deferred`` every import it makes, inside functions too."""
    package = name if _is_package(name) else name.rpartition(".")[0]
    tree = ast.parse(MODULES[name].read_text(encoding="utf-8"))
    for node in (_all_imports(tree) if deferred else _top_level_imports(tree)):
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


@pytest.mark.parametrize("deferred", [False, True], ids=["top-level", "inside functions too"])
def test_no_import_circles(deferred):
    """Issue 34: an import inside a function is a dependency all the same (the model applied by compensation
    and evaluation once lived in the diagnosis, reached from inside functions: 16 modules in one circle)."""
    graph = {}
    for name in MODULES:
        # an ancestor package is imported first whatever the module says: not an edge
        graph[name] = {t for t, _, _ in _imports(name, deferred)
                       if t in MODULES and not (_is_package(t) and (name + ".").startswith(t + "."))}
    assert _cycles(graph) == []


def test_no_module_imports_another_modules_private_names():
    # imports inside functions too
    private = [f"{name} imports {attr} from {target}" for name in MODULES
               for target, attr, is_module in _imports(name, deferred=True)
               if attr and attr.startswith("_") and not attr.startswith("__") and not is_module]
    assert private == []


def test_no_module_imports_a_private_module_of_another_package():
    """Issue 34: a helper used across packages is public where it lives (``artefacts.base``,
    ``formats.pointformats.common``); a private module (``_name``) serves its own package only (those at the root,
    ``cmmpose._validate``, serve the whole package)."""
    crossing = []
    for name in MODULES:
        for target, _, _ in _imports(name, deferred=True):
            parts = target.split(".")
            for i, part in enumerate(parts):
                owner = ".".join(parts[:i])
                if part.startswith("_") and not part.startswith("__") and not (
                        name == owner or name.startswith(owner + ".")):
                    crossing.append(f"{name} imports {target}")
    assert crossing == []


def test_the_public_face_is_curated():
    names = dir(cmmpose)
    assert not [n for n in names if n.startswith("_") and n != "__version__"]
    assert "TYPE_CHECKING" not in names and "lazy_attributes" not in names
    assert set(cmmpose.__all__) <= set(names)
    for name in cmmpose.__all__:
        assert getattr(cmmpose, name) is not None, name
    # the public modules stay reachable
    for module in ("errors", "machine", "evaluation", "formats", "cli"):
        assert getattr(__import__(f"cmmpose.{module}").__dict__[module], "__name__") == f"cmmpose.{module}"


def _commands(command=main, path=("cmmpose",)):
    if isinstance(command, click.Group):
        ctx = click.Context(command)
        for name in command.list_commands(ctx):
            yield from _commands(command.get_command(ctx, name), (*path, name))
    else:
        yield " ".join(path), command


def test_every_option_of_every_command_has_help():
    missing = [f"{path} {p.opts[0]}" for path, cmd in _commands() for p in cmd.params
               if isinstance(p, click.Option) and not (p.help or "").strip()]
    assert missing == []


#: Commands that only write a file (and say "wrote ...") or record live: no result to print as JSON.
WRITERS = {"cmmpose acquire", "cmmpose machine example", "cmmpose artefact example", "cmmpose map plot",
           "cmmpose artefact plan"}


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


def test_the_machine_description_does_not_load_the_simulator():
    import subprocess

    code = "import sys, cmmpose.machine as m; m.load_machine(None); print('cmmpose.sim' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"


# The layers of docs/architecture.md, top to bottom; a module may import its own layer or any below it.
LAYERS = [
    ("cli",),
    ("diagnosis", "standards", "calibration", "acquire", "scale", "sim"),
    ("evaluation",),
    ("compensation", "filecompensation"),
    ("model",),
    ("fitting", "centre_uncertainty", "run", "machine", "errormap", "point_uncertainty", "uncertainty_columns", "pose",
     "scanner", "temperature", "layouts", "placement", "kernel_report", "policy", "effects", "artefacts", "formats",
     "schemas"),
    ("atomicfile", "errors", "_json", "_csvtable", "_registry", "_validate", "_arrays", "_lazy", "_threads", "_core"),
]
# Known upward imports, each with its reason; the test fails on any other, and on one of these that is gone (so the
# list and docs/architecture.md stay true).
UPWARD = {
    # The default map uncertainty is the interferometer calibration's air budget (thesis section 3.3).
    ("evaluation/ballbar_uncertainty", "calibration.interferometer.air"),
}


def _upward_imports():
    rank = {m: i for i, ms in enumerate(LAYERS) for m in ms}
    found = set()
    for f in PACKAGE.rglob("*.py"):
        rel = f.relative_to(PACKAGE).with_suffix("")
        parts = list(rel.parts)
        here = parts[:-1] if parts[-1] != "__init__" else parts[:-1]
        if parts[-1] == "__init__":
            parts = parts[:-1]
        if not parts or parts[0] not in rank:
            continue
        for node in ast.walk(ast.parse(f.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and node.level:
                base = here[:len(here) - (node.level - 1)]
                targets = [[*base, *node.module.split(".")]] if node.module else [[*base, a.name] for a in node.names]
                for t in targets:
                    if t and t[0] in rank and rank[t[0]] < rank[parts[0]]:
                        found.add(("/".join(rel.parts), ".".join(t)))
    return found


def test_modules_import_only_their_layer_or_below():
    rank = {m for ms in LAYERS for m in ms}
    tops = {p.stem if p.is_file() else p.name for p in PACKAGE.iterdir()
            if (p.suffix in (".py", ".so") or (p.is_dir() and (p / "__init__.py").exists())) and p.stem != "__init__"}
    assert tops - {"_core.abi3", "__main__"} <= rank | {"_core"}, tops - rank  # every root module is in a layer
    assert _upward_imports() == UPWARD


def test_a_command_imports_only_its_own_module():
    # Issue 27: `cmmpose fit` must not pay for the diagnosis, Dask or the acquisition (start-up < 0.2 s wall).
    code = ("import sys\n"
            "from click.testing import CliRunner\n"
            "from cmmpose.cli import main\n"
            "r = CliRunner().invoke(main, ['fit', '--help'])\n"
            "assert r.exit_code == 0, r.output\n"
            "heavy = ['cmmpose.cli.diagnose', 'cmmpose.cli.acquire', 'cmmpose.diagnosis', 'cmmpose.scale',\n"
            "         'cmmpose.acquire', 'cmmpose.sim', 'cmmpose.calibration', 'dask', 'scipy', 'matplotlib']\n"
            "print([m for m in heavy if m in sys.modules])\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"


# --- The Rust core's modules (issue 26: kernel <-> blocks <-> thermal was a circle) ---

RUST_CORE = REPO / "rust" / "core" / "src"


def _rust_code(text: str) -> str:
    """A Rust file's code without comments and without its ``#[cfg(test)]`` modules
    (test code may use any module: the layers are the library's)."""
    lines, out, skipping, test_attr = text.splitlines(), [], False, False
    for line in lines:
        code = line.split("//", 1)[0]
        if skipping:
            if line.startswith("}"):
                skipping = False
            continue
        if code.strip() == "#[cfg(test)]" and not line.startswith(" "):
            test_attr = True
            continue
        if test_attr and code.startswith("#["):
            continue
        if test_attr and code.lstrip().startswith(("mod ", "pub mod ", "pub(crate) mod ")):
            test_attr = False
            skipping = not code.rstrip().endswith(";")
            continue
        test_attr = False
        out.append(code)
    return "\n".join(out)


def _rust_module_graph(src: Path) -> dict[str, set[str]]:
    """Top-level module of the crate -> the top-level modules its code names
    (``crate::x`` in ``use`` lines and in paths, ``use crate::{x, y}`` too).
    A directory module (``fit/``) is one node; files included only as test
    modules (``#[cfg(test)] #[path = "..."] mod tests;``) are left out."""
    import re

    test_files = set()
    for path in src.rglob("*.rs"):
        test_files |= set(re.findall(r'#\[cfg\(test\)\]\s*#\[path\s*=\s*"([^"]+)"\]', path.read_text()))
    graph: dict[str, set[str]] = {}
    for path in src.rglob("*.rs"):
        rel = path.relative_to(src)
        if rel.name in test_files or rel.name in ("lib.rs", "main.rs"):
            continue
        node = rel.parts[0] if len(rel.parts) > 1 else rel.stem
        code = _rust_code(path.read_text())
        names = set(re.findall(r"\bcrate::([a-z_][a-z0-9_]*)", code))
        for group in re.findall(r"\bcrate::\{([^}]*)\}", code):
            names |= {g.strip().split("::")[0] for g in group.split(",") if g.strip()}
        graph.setdefault(node, set()).update(n for n in names if n != node)
    for targets in list(graph.values()):
        for t in targets:
            graph.setdefault(t, set())
    return graph


def test_the_rust_module_reader_sees_uses_and_circles(tmp_path):
    (tmp_path / "a.rs").write_text("use crate::b::X;\n// crate::c in a comment\nfn f() { crate::d::g(); }\n")
    (tmp_path / "b.rs").write_text("use crate::{c, d::Y};\n#[cfg(test)]\nmod tests {\n    use crate::a::Z;\n}\n")
    (tmp_path / "c.rs").write_text("pub fn h() {}\n#[cfg(test)]\n#[path = \"c_tests.rs\"]\nmod tests;\n")
    (tmp_path / "c_tests.rs").write_text("use crate::a::Z;\n")
    (tmp_path / "d.rs").write_text("pub(crate) use crate::a::X;\n")
    graph = _rust_module_graph(tmp_path)
    assert graph == {"a": {"b", "d"}, "b": {"c", "d"}, "c": set(), "d": {"a"}}
    assert _cycles(graph) == [["a", "b", "d"]]


def test_no_rust_module_circles():
    graph = _rust_module_graph(RUST_CORE)
    # the reader sees the core's layers (a renamed folder would make this test vacuous)
    assert {"blocks", "source"} <= graph["kernel"] and "source" in graph["thermal"], graph
    assert _cycles(graph) == []
