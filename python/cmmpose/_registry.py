"""Plug-in discovery shared by the registries (effects, artefact kinds).

A registry is a package whose public modules each define subclasses of one base
class; every subclass with a non-empty key attribute registers itself under that
key. Discovery is deterministic (modules in name order) and refuses a key used twice.
"""
from __future__ import annotations

import importlib
import pkgutil
from collections.abc import Iterable


def discover(package: str, path: Iterable[str], base: type, key: str, what: str) -> dict[str, type]:
    """Import every public module of ``package`` and collect ``base`` subclasses by ``key``.

    Parameters
    ----------
    package : str
        Dotted name of the registry package (its ``__name__``).
    path : iterable of str
        The package's ``__path__``.
    base : type
        The base class plug-ins derive from (itself never registered).
    key : str
        Class attribute holding the registry name; classes where it is empty are skipped.
    what : str
        Words for the error message ("effect name", "artefact kind").
    """
    found: dict[str, type] = {}
    for info in sorted(pkgutil.iter_modules(path), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{package}.{info.name}")
        for obj in vars(module).values():
            if isinstance(obj, type) and issubclass(obj, base) and obj is not base and getattr(obj, key, None):
                name = getattr(obj, key)
                if name in found and found[name] is not obj:
                    raise RuntimeError(f"{what} {name!r} is used twice")
                found[name] = obj
    return found
