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
from types import ModuleType


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
        # The package's public face: its __all__ (else every public name), its
        # public submodules and the lazy names; no private module or helper.
        listed = namespace.get("__all__")
        names = set(listed) if listed is not None else {n for n in namespace if not n.startswith("_")}
        names |= {n for n, v in namespace.items() if isinstance(v, ModuleType) and not n.startswith("_")}
        return sorted(names | set(table))

    return __getattr__, __dir__


class LazyModule:
    """A module imported on first attribute access, for a heavy dependency
    that a module's import must not pay for (pyarrow: about 0.1 s, loaded by
    ``import cmmpose`` otherwise, though only the commands that read or
    write Arrow, Parquet or fast CSV use it).

    Written at the top of a module in place of its import, so that the
    dependency is still declared there: ``pa = LazyModule("pyarrow")``. The
    name must not be used at module level (a type annotation is fine under
    ``from __future__ import annotations``).
    """

    __slots__ = ("_name", "_module")

    def __init__(self, name: str):
        object.__setattr__(self, "_name", name)
        object.__setattr__(self, "_module", None)

    def _load(self):
        module = object.__getattribute__(self, "_module")
        if module is None:
            module = importlib.import_module(object.__getattribute__(self, "_name"))
            object.__setattr__(self, "_module", module)
        return module

    def __getattr__(self, attribute: str) -> object:
        return getattr(object.__getattribute__(self, "_load")(), attribute)

    def __setattr__(self, attribute: str, value) -> None:  # e.g. a test's monkeypatch: set on the module
        setattr(object.__getattribute__(self, "_load")(), attribute, value)

    def __delattr__(self, attribute: str) -> None:
        delattr(object.__getattribute__(self, "_load")(), attribute)

    def __repr__(self) -> str:
        return f"<lazily imported module {object.__getattribute__(self, '_name')!r}>"
