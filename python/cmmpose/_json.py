"""Standard JSON out of every result: :func:`dumps` never writes ``NaN`` or
``Infinity`` (which are not JSON; ``json.dumps`` writes them by default).

- NaN is "no value" (a length at 20 C without a temperature, a size error
  without a nominal radius) and becomes ``null``.
- An infinity is a result that overflowed (inputs near 1e300): it becomes
  ``null`` too, and a top-level object gains ``"non_finite"``, a list of
  ``{"key": "results[0].rms_um", "value": "inf"}`` naming each such value, so
  the overflow is stated, not hidden; in a top-level list each object states
  its own. A bare number that is infinite raises ``ValueError`` (nowhere to
  state it).

Everything is then written with ``allow_nan=False``.
"""

from __future__ import annotations

import json
import math

import numpy as np

__all__ = ["dumps", "finite_or_none"]


def finite_or_none(obj, path: str = "", found: list | None = None):
    """``obj`` with NaN and infinities (Python or NumPy floats, arrays too)
    replaced by None; each infinity's key path is appended to ``found``."""
    if isinstance(obj, dict):
        return {k: finite_or_none(v, f"{path}.{k}" if path else str(k), found) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_or_none(v, f"{path}[{i}]", found) for i, v in enumerate(obj)]
    if isinstance(obj, np.ndarray):
        return finite_or_none(obj.tolist(), path, found)
    if isinstance(obj, (float, np.floating)):
        x = float(obj)
        if math.isfinite(x):
            return x
        if math.isinf(x) and found is not None:
            found.append({"key": path or "(value)", "value": "inf" if x > 0 else "-inf"})
        return None
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj


def _stated(obj, where: str):
    """``obj`` cleaned; a dict gains ``non_finite`` naming its infinities."""
    found: list = []
    clean = finite_or_none(obj, "", found)
    if found:
        if not isinstance(clean, dict):
            raise ValueError(f"not finite, cannot be written as JSON: {where or '(value)'}")
        clean["non_finite"] = list(clean.get("non_finite") or []) + found
    return clean


def dumps(obj, *, default=None, **kw) -> str:
    """``json.dumps(obj, **kw)`` as standard JSON (module docstring).

    Parameters
    ----------
    obj : dict, list or scalar
        The result, as its ``to_dict()`` gives it.
    default : callable, optional
        As ``json.dumps``'s: objects it converts are cleaned the same way.
    **kw
        Other ``json.dumps`` options (``indent``, ...).

    Raises
    ------
    ValueError
        An infinity that is not inside an object.
    """
    if isinstance(obj, (list, tuple)):  # a table of results: each object states its own
        clean = [_stated(v, f"[{i}]") for i, v in enumerate(obj)]
    else:
        clean = _stated(obj, "")
    def hook(o):
        more: list = []
        out = finite_or_none(default(o), "", more)
        if more:
            raise ValueError(f"not finite, cannot be written as JSON: {type(o).__name__}")
        return out

    return json.dumps(clean, default=None if default is None else hook, allow_nan=False, **kw)
