"""Arguments renamed for one name per concept (docs/conventions.md, "Names"):
the old keyword keeps working for now, with a FutureWarning naming the new
one, and a unit change converts the value (``expansion`` in 1/K becomes
``expansion_ppm_per_K``)."""

from __future__ import annotations

import functools
import warnings
from collections.abc import Callable

from .errors import InputTypeError


def renamed(**old: str | tuple[str, Callable[[object], object]]):
    """Decorator: accept each old keyword as its new name.

    Parameters
    ----------
    **old : str or (str, callable)
        Old keyword -> new keyword, or (new keyword, conversion of the old
        value into the new one's unit).
    """

    def wrap(function):
        @functools.wraps(function)
        def call(*args, **kwargs):
            for name, target in old.items():
                if name not in kwargs:
                    continue
                new, convert = (target, None) if isinstance(target, str) else target
                if new in kwargs:
                    raise InputTypeError(f"{function.__name__}: give {new}= only ({name}= is its older name)",
                                         option=name)
                value = kwargs.pop(name)
                warnings.warn(f"{function.__name__}: {name}= is now {new}="
                              + (" (in the new name's unit; the value was converted)" if convert else ""),
                              FutureWarning, stacklevel=2)
                kwargs[new] = convert(value) if convert and value is not None else value
            return function(*args, **kwargs)

        return call

    return wrap


def per_kelvin_to_ppm(value):
    """A coefficient of expansion in 1/K as ppm/K."""
    return float(value) * 1e6
