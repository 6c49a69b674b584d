"""The temperature policy's command-line flags: one click decorator built
from the fields of :class:`~cmmpose.temperature.TemperaturePolicy` (each
field's metadata holds its flag and help), so every command offers the same
flags with the same defaults and help (docs/conventions.md)."""

from __future__ import annotations

import dataclasses
import functools
import inspect

import click

from ..errors import InputError
from ..temperature import TemperaturePolicy

__all__ = ["temperature_options"]


def temperature_options(log: bool = True):
    """A click decorator adding the policy's flags, built from the fields of
    :class:`TemperaturePolicy` (same names, defaults and help on every
    command). The command receives ``temperature_policy`` (a
    :class:`TemperaturePolicy`) and, if its signature names them, the
    fields as keywords too (``out_of_range``, ``temperature_tolerance``,
    ``log_hold``, ...), so older commands keep their parameters.

    Parameters
    ----------
    log : bool
        Also the flags that read a thermocouple log (``--log-hold``,
        ``--on-gap``, ``--max-gap``, ``--broken-channels``, ``--sensor``);
        False: the map side only (a command given temperatures, not a log).
    """
    fields = [f for f in dataclasses.fields(TemperaturePolicy) if log or f.metadata.get("map_side")]

    def wrap(f):
        params = inspect.signature(f).parameters
        takes_all = any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values())

        @functools.wraps(f)
        def command(*args, **kwargs):
            values = {fl.name: kwargs.pop(fl.name) for fl in fields}
            sensors = values.get("sensors")
            if sensors is not None:
                values["sensors"] = tuple(sensors)
            try:
                policy = TemperaturePolicy(**values)
            except InputError as exc:
                flag = next((fl.metadata["flag"] for fl in fields if str(exc).startswith(fl.name)), None)
                raise click.BadParameter(str(exc).split(": ", 1)[-1], param_hint=flag) from None
            for name, value in values.items():
                if name in params or takes_all:
                    kwargs[name] = getattr(policy, name) if name != "sensors" else value
            if "temperature_policy" in params or takes_all:
                kwargs["temperature_policy"] = policy
            return f(*args, **kwargs)

        for fl in reversed(fields):
            meta = fl.metadata
            kw = {"help": meta["help"], "show_default": fl.default is not None and fl.default != ()}
            if "choices" in meta:
                kw["type"] = click.Choice(list(meta["choices"]))
            elif "type" in meta:
                kw["type"] = meta["type"]
            if meta.get("multiple"):
                kw["multiple"] = True
                kw["metavar"] = "ROLE=CHANNEL[,...]"
            kw["default"] = fl.default
            command = click.option(meta["flag"], fl.name, **kw)(command)
        return command

    return wrap
