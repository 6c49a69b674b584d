"""The physical effects cmmpose knows, one file per effect, found through
this registry. ``cmmpose simulate --effect``, the diagnosis library and its
report all read it; a new module in this package is a new effect
(docs/adding-an-effect.md)."""

from __future__ import annotations

from .._registry import Registry
from ..errors import InputError
from ._base import Effect, Param

__all__ = ["Effect", "Param", "REGISTRY", "available", "get", "parse", "channel_roles", "channels"]


def _order(name: str):
    return (ORDER.index(name), "") if name in ORDER else (len(ORDER), name)


#: Listing order: machine, thermal, scanner, pose, artefact; new effects last.
ORDER = ("squareness", "scale", "roll", "axis-temperature", "squareness-temperature", "granite-gradient", "latency",
         "scanner-scale", "incidence", "alignment", "mount-offset", "artefact-expansion")

#: The effects by name: each public module's ``Effect`` subclasses, by their ``name``.
REGISTRY: Registry[type[Effect]] = Registry(
    "effect", order=_order,
    unknown=lambda name, names: InputError(f"effect {name!r}: unknown; available: {', '.join(names)}"),
).discover(__name__, __path__, Effect, "name")


def available() -> dict[str, type[Effect]]:
    """Effect classes by name, in the order of ``ORDER`` then by name."""
    return REGISTRY.as_dict()


def get(name: str) -> type[Effect]:
    """The effect class named ``name``."""
    return REGISTRY.get(name)


def parse(text: str) -> Effect:
    """``NAME:param=value,param=value`` (the CLI form) -> an effect."""
    name, _, rest = text.partition(":")
    cls = get(name.strip())
    units = cls.units()
    kwargs = {}
    for item in filter(None, (p.strip() for p in rest.split(","))):
        key, eq, value = item.partition("=")
        if not eq or key.strip() not in units:
            raise InputError(f"effect {cls.name}: parameter {item!r} is not one of {sorted(units)} (write key=value)")
        if key.strip() in kwargs:  # not the last one silently
            raise InputError(f"effect {cls.name}: {key.strip()} is given twice in {text!r}")
        if key.strip() in cls.text_fields():
            kwargs[key.strip()] = value.strip()
            continue
        try:
            kwargs[key.strip()] = float(value)
        except ValueError:
            raise InputError(f"effect {cls.name}: {key.strip()}={value!r} is not a number") from None
    return cls(**kwargs)


def channels() -> tuple[tuple[str, str], ...]:
    """Thermocouple channels (name, role) that effects bring to a run."""
    return tuple(c for cls in available().values() for c in cls.channels)


def channel_roles() -> tuple[str, ...]:
    """Thermocouple roles that effects introduce."""
    return tuple(dict.fromkeys(role for _, role in channels()))


