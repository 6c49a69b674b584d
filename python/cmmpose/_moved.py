"""Old import paths of modules that moved into folders (issue 26: the folders
draw docs/architecture.md). ``import cmmpose.mapfiles`` and
``from cmmpose.mapfiles import read_map`` keep working with a FutureWarning
naming the new path; the old name is a thin module that forwards every
attribute to the new one, so classes keep one identity (and pickle under the
new path).
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import warnings
from types import ModuleType

#: Old module (under cmmpose) -> where it lives now.
MOVED = {
    "pointformats": "formats.pointformats",
    "pointfiles": "formats.pointfiles",
    "pointclouds": "formats.pointclouds",
    "mapformats": "formats.mapformats",
    "mapfiles": "formats.mapfiles",
    "controller": "formats.controller",
    "iso230": "formats.iso230",
    "linuxcnc": "formats.linuxcnc",
    "linearaxis": "formats.linearaxis",
    "evaluation_files": "evaluation.files",
    "evaluation_uncertainty": "evaluation.ballbar_uncertainty",
    "artefact_evaluation": "evaluation.artefact",
    "metrics": "evaluation.metrics",
    "uncertainty": "evaluation.uncertainty",
    "plots": "evaluation.plots",
    "report": "kernel_report",
    "diagnosis.report": "diagnosis.html_report",
}


def new_name(name: str) -> str | None:
    """The module's current dotted name for an old one (``cmmpose.X[.Y]``), else None."""
    package, _, rest = name.partition(".")
    if package != "cmmpose" or not rest:
        return None
    parts = rest.split(".")
    for k in range(len(parts), 0, -1):  # the longest moved prefix
        head = ".".join(parts[:k])
        if head in MOVED:
            return f"cmmpose.{MOVED[head]}" + "".join(f".{p}" for p in parts[k:])
    return None


class _Forward(importlib.abc.Loader):
    def __init__(self, target: str):
        self.target = target

    def create_module(self, spec):
        return None  # a plain module, filled in by exec_module

    def exec_module(self, module: ModuleType) -> None:
        warnings.warn(f"{module.__name__} moved to {self.target}; import it from there "
                      "(the old path will be removed in a later release)", FutureWarning, stacklevel=2)
        real = importlib.import_module(self.target)
        module.__getattr__ = lambda attribute: getattr(real, attribute)  # PEP 562
        module.__dir__ = lambda: dir(real)
        module.__doc__ = real.__doc__
        module.__all__ = getattr(real, "__all__", [n for n in dir(real) if not n.startswith("_")])
        if hasattr(real, "__path__"):  # a package: its submodules resolve through this finder too
            module.__path__ = []


class _Finder(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        new = new_name(name)
        if new is None:
            return None
        return importlib.util.spec_from_loader(name, _Forward(new), is_package=name == "cmmpose.pointformats")


def install() -> None:
    """Put the finder on ``sys.meta_path`` once."""
    if not any(isinstance(f, _Finder) for f in sys.meta_path):
        sys.meta_path.insert(0, _Finder())


def attribute(name: str) -> ModuleType:
    """``cmmpose.<old>`` as an attribute of the package (``import cmmpose; cmmpose.mapfiles``)."""
    if name not in MOVED:
        raise AttributeError(f"module 'cmmpose' has no attribute {name!r}")
    return importlib.import_module(f"cmmpose.{name}")
