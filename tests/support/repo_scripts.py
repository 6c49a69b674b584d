"""The repository's scripts (benches, docs helpers, pinned-data makers) loaded as modules by their path, for
tests that reuse their cases (a bench's virtual machines, a script's figures)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

from repo import REPO


def load_script(path: Path, *, register: bool = False) -> ModuleType:
    """The Python file at ``path`` as a module named after it (``register``: also in ``sys.modules``, for a
    script whose dataclasses look their module up)."""
    spec = importlib.util.spec_from_file_location(path.stem, path)
    module = importlib.util.module_from_spec(spec)
    if register:
        sys.modules[path.stem] = module
    spec.loader.exec_module(module)
    return module


def bench(name: str) -> ModuleType:
    """``benches/<name>.py`` as a module."""
    return load_script(REPO / "benches" / f"{name}.py")
