"""Small CSV tables the user writes by hand (sphere fits, plate centres, pairs).

One reader so every such table refuses the same things with the same words:
an unreadable file, no header, a repeated column (which one holds the values
would be ambiguous), a missing column, a row whose field count differs from
the header's. Lines starting with '#' and blank lines are comments.
"""
from __future__ import annotations

import csv
from collections.abc import Iterable
from pathlib import Path

from .errors import InputError, read_input_text


def read_csv_table(path, required: Iterable[str]) -> tuple[list[str], list[tuple[int, dict[str, str]]]]:
    """Read a comma-separated table with a header row.

    Parameters
    ----------
    path : str or Path
        The CSV file.
    required : iterable of str
        Column names that must be present (others are allowed).

    Returns
    -------
    header : list of str
        The column names, stripped, in file order.
    rows : list of (int, dict)
        Each data row with its 1-based line number in the file; values are
        stripped strings keyed by column name.

    Raises
    ------
    InputError
        Naming the file and line.
    """
    path = Path(path)
    required = list(required)
    text = read_input_text(path, "table")  # the one door in: a FIFO or a device refused, the size bounded
    lines = [(k + 1, ln) for k, ln in enumerate(text.splitlines()) if ln.strip() and not ln.startswith("#")]
    if not lines:
        raise InputError(f"{path}: no header (expected columns {', '.join(required)})")
    head_line = lines[0][0]
    header = [h.strip() for h in next(csv.reader([lines[0][1]]))]
    repeated = sorted({h for h in header if header.count(h) > 1})
    if repeated:
        raise InputError(f"{path}:{head_line}: column(s) {', '.join(repeated)} repeated (columns "
                         + "; ".join(f"{c} at {', '.join(str(j + 1) for j, n in enumerate(header) if n == c)}"
                                     for c in repeated) + "): which one holds the values is ambiguous")
    missing = [c for c in required if c not in header]
    if missing:
        raise InputError(f"{path}:{head_line}: missing column(s) {', '.join(missing)}")
    rows = []
    for (line, _), fields in zip(lines[1:], csv.reader([ln for _, ln in lines[1:]])):
        if len(fields) != len(header):
            raise InputError(f"{path}:{line}: {len(fields)} fields, the header has {len(header)}")
        rows.append((line, {name: value.strip() for name, value in zip(header, fields)}))
    return header, rows
