"""Names of a package that load their module on first use (PEP 562).

A package lists, for each such name, the submodule that defines it; the
module is imported the first time the name is looked up (attribute access,
``from package import name``, ``import *``), and the name is then bound in
the package like any other. Commands that never touch the name never pay for
importing its module.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable


def lazy_attributes(package: str, table: dict[str, tuple[str, str | None]],
                    namespace: dict) -> tuple[Callable[[str], object], Callable[[], list[str]]]:
    """The ``__getattr__`` and ``__dir__`` of a package with lazily loaded names.

    Parameters
    ----------
    package : str
        The package's ``__name__``.
    table : dict of str -> (str, str or None)
        Name -> (submodule relative to the package, attribute of it); an
        attribute of None makes the name the submodule itself.
    namespace : dict
        The package's ``globals()``: a loaded name is bound there.

    Returns
    -------
    (callable, callable)
        ``__getattr__(name)`` and ``__dir__()`` for the package module.
    """

    def __getattr__(name: str) -> object:
        try:
            module, attribute = table[name]
        except KeyError:
            raise AttributeError(f"module {package!r} has no attribute {name!r}") from None
        loaded = importlib.import_module(f".{module}", package)
        value = loaded if attribute is None else getattr(loaded, attribute)
        namespace[name] = value
        return value

    def __dir__() -> list[str]:
        return sorted(set(namespace) | set(table))

    return __getattr__, __dir__
