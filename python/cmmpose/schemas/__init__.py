"""One schema per kind of document a user gives cmmpose, and the one check
of a document against it (issue 35, "one door in").

Kinds (:data:`KINDS`): ``model`` (a saved model, JSON), ``machine`` (a
machine file, TOML), ``artefact`` (an artefact file, TOML), ``run`` (a
run's ``run.json``), ``alignments`` (an alignment library, JSON) and
``plan`` (an acquisition plan, JSON). User effects are Python files, code rather than
documents: they have no schema. Each schema is defined once, here, as a JSON
Schema (draft 2020-12) dict; :func:`validate` checks a parsed document with
the :mod:`jsonschema` library, and ``python -m cmmpose.schemas`` writes them
to ``docs/schemas/<kind>.schema.json`` for editors (docs/formats.md,
"Schemas").

Every loader calls :func:`validate` right after parsing, before it builds
anything; :func:`loads_json` parses JSON refusing a repeated key (TOML's
reader refuses one itself).
"""

from __future__ import annotations

import functools
import json
import logging
from pathlib import Path

from ..atomicfile import write_text
from ..errors import InputError
from . import alignments, artefact, machine, model, plan, run
from ._common import TEMPERATURE_C, check, loads_json, no_repeats, short, validator

__all__ = ["KINDS", "schema", "validate", "loads_json", "schema_text", "write_schemas", "no_repeats", "short",
           "TEMPERATURE_C"]

_log = logging.getLogger(__name__)

#: The document kinds, each with the module that defines its schema.
KINDS = {"model": model, "machine": machine, "artefact": artefact, "run": run, "alignments": alignments, "plan": plan}


def _kind(kind: str):
    if kind not in KINDS:
        raise InputError(f"schema kind {kind!r}: not one of {', '.join(KINDS)}", what="kind", value=kind,
                         allowed=tuple(KINDS))
    return KINDS[kind]


@functools.lru_cache(maxsize=None)
def _cached(kind: str) -> str:
    return json.dumps(_kind(kind).schema(), sort_keys=False)


def schema(kind: str) -> dict:
    """The schema of the document kind ``kind`` (a fresh dict)."""
    return json.loads(_cached(kind))


@functools.lru_cache(maxsize=None)
def _validator(kind: str):
    return validator(schema(kind))


def validate(document, kind: str, path, *, error=InputError):
    """Check ``document`` (as parsed from the file ``path``) against the schema of ``kind``.

    Parameters
    ----------
    document : dict
        The parsed JSON or TOML.
    kind : {'model', 'machine', 'artefact', 'run', 'alignments', 'plan'}
    path : str or path-like
        The file (or what names the document), first in any message.
    error : type of InputError
        The class raised (a run's reader raises its own).

    Returns
    -------
    dict
        ``document``, unchanged.

    Raises
    ------
    InputError (or ``error``)
        One line naming the file, the key path and what is wrong there.
    """
    check(document, _validator(kind), path, error=error)
    return document


def schema_text(kind: str) -> str:
    """The published text of ``kind``'s schema (``docs/schemas/<kind>.schema.json``)."""
    return json.dumps(schema(kind), indent=2, ensure_ascii=False) + "\n"


def write_schemas(folder) -> list[Path]:
    """Write every kind's schema to ``folder/<kind>.schema.json``, each
    atomically (:mod:`cmmpose.atomicfile`); returns the paths written."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for kind in KINDS:
        path = folder / f"{kind}.schema.json"
        write_text(path, schema_text(kind))
        _log.info("wrote %s", path)
        out.append(path)
    return out
