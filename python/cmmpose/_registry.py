"""The one registry mechanism: effects, artefact kinds, point formats and map formats.

A :class:`Registry` holds entries by name. It refuses a second entry under a name
already taken (the same object registered again is not a second entry), names the
valid names when asked for an unknown one, and lists its entries in a stable order
(registration order, or the order a registry states). Built-in entries may load
lazily, on the registry's first read (``load``).

A package-style registry (effects, artefact kinds) is a package whose public
modules each define subclasses of one base class; every subclass with a non-empty
key attribute registers itself under that key (:meth:`Registry.discover`).
Discovery is deterministic: modules in name order.

Callers dispatch on what an entry declares (its attributes), never on its name.
"""
from __future__ import annotations

import importlib
import pkgutil
import threading
from collections.abc import Callable, Iterable, Iterator
from typing import Any, Generic, TypeVar

__all__ = ["Registry", "discover", "import_modules"]

T = TypeVar("T")


class Registry(Generic[T]):
    """Entries by name; a second entry under a taken name is refused.

    Parameters
    ----------
    what : str
        Words for messages ("effect", "artefact kind", "point-file format").
    unknown : callable, optional
        ``unknown(name, names) -> Exception``: the error :meth:`get` raises for a
        name not registered (``names``: the valid ones, in order). Default: a
        ``KeyError`` naming them.
    order : callable, optional
        Sort key of a name for listings; default: registration order (the sort is
        stable, so names with equal keys keep that order).
    load : callable, optional
        Run once, before the registry is first read (not before a registration):
        imports the modules of built-in entries, which register themselves.
    """

    def __init__(self, what: str, *, unknown: Callable[[str, list[str]], Exception] | None = None,
                 order: Callable[[str], Any] | None = None, load: Callable[[], None] | None = None):
        self.what = what
        self._unknown = unknown
        self._order = order
        self._load = load
        self._entries: dict[str, T] = {}
        self._loaded = load is None
        #: Held while the built-ins load: threads reading at once (a Dask scheduler's workers) must not see the
        #: registry before they have registered.
        self._lock = threading.RLock()

    def register(self, name: str, entry: T) -> T:
        """Register ``entry`` under ``name``; returns it.

        Raises
        ------
        ValueError
            When ``name`` is empty or already holds another entry (a plug-in
            never silently replaces another).
        """
        if not isinstance(name, str) or not name:
            raise ValueError(f"{self.what}: a name is a non-empty text, got {name!r}")
        with self._lock:
            old = self._entries.get(name)
            if old is not None and old is not entry:
                raise ValueError(f"{self.what} {name!r} is registered already ({_describe(old)}); a second entry "
                                 f"of the same name ({_describe(entry)}) is refused")
            self._entries[name] = entry
        return entry

    def discover(self, package: str, path: Iterable[str], base: type, key: str) -> Registry[T]:
        """Import every public module of ``package`` (name order) and register its ``base`` subclasses by ``key``.

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
        """
        for module in import_modules(package, path):
            for obj in vars(module).values():
                if isinstance(obj, type) and issubclass(obj, base) and obj is not base and getattr(obj, key, None):
                    self.register(getattr(obj, key), obj)
        return self

    def _entries_loaded(self) -> dict[str, T]:
        if not self._loaded:
            with self._lock:
                if not self._loaded:
                    self._load()
                    self._loaded = True
        return self._entries

    def names(self) -> list[str]:
        """The registered names, in the registry's order."""
        names = list(self._entries_loaded())
        return sorted(names, key=self._order) if self._order is not None else names

    def get(self, name: str) -> T:
        """The entry ``name``; the registry's ``unknown`` error (naming the valid names) otherwise."""
        entries = self._entries_loaded()
        try:
            return entries[name]
        except (KeyError, TypeError):  # TypeError: an unhashable name
            if self._unknown is not None:
                raise self._unknown(name, self.names()) from None
            raise KeyError(f"{self.what} {name!r}: unknown; known: {', '.join(self.names())}") from None

    def items(self) -> list[tuple[str, T]]:
        """``(name, entry)`` pairs in the registry's order."""
        entries = self._entries_loaded()
        return [(n, entries[n]) for n in self.names()]

    def values(self) -> list[T]:
        """The entries in the registry's order."""
        return [e for _, e in self.items()]

    def as_dict(self) -> dict[str, T]:
        """A new dict of the entries by name, in the registry's order."""
        return dict(self.items())

    def __contains__(self, name: object) -> bool:
        try:
            return name in self._entries_loaded()
        except TypeError:
            return False

    def __iter__(self) -> Iterator[str]:
        return iter(self.names())

    def __len__(self) -> int:
        return len(self._entries_loaded())

    def __repr__(self) -> str:
        return f"Registry({self.what!r}: {', '.join(self.names())})"


def _describe(entry) -> str:
    """An entry in a message: a class by its dotted name, another object by its type and description."""
    if isinstance(entry, type):
        return f"{entry.__module__}.{entry.__qualname__}"
    description = getattr(entry, "description", "")
    return f"a {type(entry).__name__}" + (f": {description}" if description else "")


def import_modules(package: str, path: Iterable[str]) -> list:
    """Import the public modules of ``package`` (those whose name does not start with ``_``), in name order."""
    return [importlib.import_module(f"{package}.{info.name}")
            for info in sorted(pkgutil.iter_modules(path), key=lambda m: m.name) if not info.name.startswith("_")]


def discover(package: str, path: Iterable[str], base: type, key: str, what: str) -> dict[str, type]:
    """The ``base`` subclasses of ``package``'s public modules by ``key`` (:meth:`Registry.discover`), as a dict
    in module order; ``ValueError`` when a key is used twice. ``what`` words the messages ("artefact kind")."""
    return Registry(what).discover(package, path, base, key).as_dict()
