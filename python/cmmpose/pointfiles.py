"""Point files for the CLI: CSV with a header row (u, v, D, E, F and an
optional T) or NPY ((N, 5) or (N, 6) in that column order, or a structured
array with those field names). Units: mm and degrees C."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .errors import InputError

REQUIRED = ("u", "v", "D", "E", "F")


def read_points(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Read ``uv`` (N, 2), ``scales`` (N, 3) and temperatures (N,) or None."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    if path.suffix.lower() == ".npy":
        try:
            a = np.load(path, allow_pickle=False)
        except (OSError, ValueError) as exc:
            raise InputError(f"{path}: not a readable .npy file ({exc})") from None
        if a.dtype.names:
            names = a.dtype.names
            missing = [c for c in REQUIRED if c not in names]
            if missing:
                raise InputError(f"{path}: fields {missing} missing (have {list(names)})")
            cols = [a[c] for c in REQUIRED] + ([a["T"]] if "T" in names else [])
            a = np.column_stack(cols).astype(np.float64)
        elif a.ndim != 2 or a.shape[1] not in (5, 6):
            raise InputError(f"{path}: expected shape (N, 5) or (N, 6) with columns u, v, D, E, F[, T], got {a.shape}")
        a = np.asarray(a, dtype=np.float64)
        has_t = a.shape[1] == 6
    else:
        with path.open(encoding="utf-8") as f:
            header = [h.strip() for h in f.readline().strip().split(",")]
        missing = [c for c in REQUIRED if c not in header]
        if missing:
            raise InputError(f"{path}:1: header must name columns u, v, D, E, F (and optionally T); missing {missing}")
        order = [header.index(c) for c in REQUIRED]
        has_t = "T" in header
        if has_t:
            order.append(header.index("T"))
        try:
            a = np.loadtxt(path, delimiter=",", skiprows=1, usecols=order, ndmin=2, dtype=np.float64)
        except ValueError as exc:
            raise InputError(_first_bad_line(path, len(header), order) or f"{path}: {exc}") from None
    uv = np.ascontiguousarray(a[:, 0:2])
    scales = np.ascontiguousarray(a[:, 2:5])
    temps = np.ascontiguousarray(a[:, 5]) if has_t else None
    return uv, scales, temps


def _first_bad_line(path: Path, width: int, used: list[int]) -> str | None:
    """On the error path only: the first line that is ragged or not numeric."""
    with path.open(encoding="utf-8") as f:
        next(f)
        for lineno, line in enumerate(f, start=2):
            if not line.strip():
                continue
            fields = line.rstrip("\n").split(",")
            if len(fields) != width:
                return f"{path}:{lineno}: expected {width} fields like the header, got {len(fields)}"
            for k in used:
                try:
                    float(fields[k])
                except ValueError:
                    return f"{path}:{lineno}: value {fields[k].strip()!r} in column {k + 1} is not a number"
    return None


def write_points(path: str | Path, xyz: np.ndarray) -> None:
    """Write (N, 3) machine coordinates: CSV with header X,Y,Z (mm, 6 decimals = 1 nm) or NPY."""
    path = Path(path)
    if path.suffix.lower() == ".npy":
        np.save(path, xyz)
    else:
        np.savetxt(path, xyz, delimiter=",", fmt="%.6f", header="X,Y,Z", comments="")
