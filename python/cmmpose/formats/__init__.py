"""File formats: point files and point clouds (``pointformats``: one module per
format, found through its registry; ``pointfiles``: the scanner points
``u, v, D, E, F``; ``pointclouds``: X, Y, Z clouds), error-map files
(``mapformats``: the registry; ``mapfiles``: the canonical CSV; ``controller``:
the thesis's controller file; ``iso230``: ISO 230-2 linear results;
``linuxcnc``: LinuxCNC compensation tables) and the conversion of linear-axis
results into map components (``linearaxis``). docs/formats.md describes each.

Importing the package loads nothing: each module loads on first use.
"""

from __future__ import annotations

from .._lazy import lazy_attributes

__getattr__, __dir__ = lazy_attributes(__name__, {
    name: (name, None) for name in
    ("pointformats", "pointfiles", "pointclouds", "mapformats", "mapfiles", "controller", "iso230", "linuxcnc",
     "linearaxis")
}, globals())

del annotations, lazy_attributes
__all__ = ["pointformats", "pointfiles", "pointclouds", "mapformats", "mapfiles", "controller", "iso230", "linuxcnc",
           "linearaxis"]
