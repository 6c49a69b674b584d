"""Where an output may go, checked before any work, and what the writers share (docs/formats.md, "How files
are written").

The checks: an output is no folder, its folder exists, it is none of the command's inputs (:func:`check_not_input`,
by :func:`os.path.samefile`), it does not exist without ``overwrite`` (:func:`check_output`,
:func:`check_outputs_free`, :func:`exists_error`); :func:`ensure_folder` makes a folder. What the writers share:
the short fixed-length temporary names (:data:`TEMP_PREFIX`, :func:`temp_path`), the umask a new file's permissions
follow, a folder's fsync, and an ``OSError`` worded as :class:`~cmmpose.errors.OutputError` naming the file
(:func:`output_error`).
"""

from __future__ import annotations

import errno
import os
import secrets
import stat
from pathlib import Path

from ..errors import InputError, OutputError

#: The output name that means standard output, where a command accepts it.
STDOUT = "-"
#: Why a write failed, by errno, as messages say it.
FAILURE_REASONS = {
    errno.ENOSPC: "no space left on the device",
    errno.EDQUOT: "disk quota exceeded",
    errno.EROFS: "read-only file system",
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
    errno.EFBIG: "file too large for the file system",
}


def output_error(path, exc: OSError) -> OutputError:
    """``OutputError`` naming ``path`` and why ``exc`` stopped the write."""
    reason = FAILURE_REASONS.get(exc.errno) or exc.strerror or str(exc) or type(exc).__name__
    return OutputError(f"{path}: cannot write ({reason}); any earlier file there is unchanged")


def current_umask() -> int:
    """The process's umask, read without changing it where Linux tells it."""
    try:
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def stat_or_none(path: Path):
    """``os.stat`` of ``path`` (following links), or None if nothing is there."""
    try:
        return os.stat(path)
    except (FileNotFoundError, NotADirectoryError):
        return None
    except OSError as exc:
        raise output_error(path, exc) from None


#: Every temporary name cmmpose makes starts with this (then 12 random hex digits and ``.tmp``, ``.new`` or
#: ``.old``): short and of fixed length, so a target whose name is as long as the file system allows still
#: gets a temporary file beside it.
TEMP_PREFIX = ".cmmpose-"


def temp_path(folder, suffix: str = ".tmp") -> Path:
    """A new temporary name in ``folder``: ``.cmmpose-XXXXXXXXXXXX<suffix>`` (nothing is made)."""
    return Path(folder) / f"{TEMP_PREFIX}{secrets.token_hex(6)}{suffix}"

def exists_error(path, what: str = "output", *, meanwhile: bool = False) -> OutputError:
    """``OutputError``: ``path`` exists and ``overwrite`` was not given (``meanwhile``: another writer made
    it while this one worked; this one's result was not put there)."""
    if meanwhile:
        return OutputError(f"{path}: another writer created it while this one worked; the {what} was not written "
                           "over it", file=str(path), option="overwrite", remedy="overwrite")
    return OutputError(f"{path}: exists; the {what} is never written over an existing file without being told",
                       file=str(path), option="overwrite", remedy="overwrite")


def lexists(path) -> bool:
    """Whether anything (a broken link too) is at ``path``; ``OutputError`` if that cannot be told."""
    try:
        os.lstat(path)
        return True
    except (FileNotFoundError, NotADirectoryError):
        return False
    except OSError as exc:
        raise output_error(path, exc) from None


def check_output(path, *, overwrite: bool = True, what: str = "output") -> Path:
    """``path`` as a Path after the checks made before any work: ``InputError``
    if it is a folder or its folder does not exist; ``OutputError`` if it exists
    and ``overwrite`` is False (:func:`exists_error`). Special files pass. Messages name the
    path as given (``./a.csv``)."""
    shown, path = path, Path(path)
    if str(path) == STDOUT:
        return path
    st = stat_or_none(path)
    if st is not None and stat.S_ISDIR(st.st_mode):
        raise InputError(f"{shown}: is a folder, expected a file name")
    if st is None:
        real = Path(os.path.realpath(path))
        folder = real.parent
        if not folder.is_dir():
            raise InputError(f"{shown}: the folder {path.parent if str(path.parent) else '.'} does not exist")
    if not overwrite and (st is None and lexists(path) or st is not None and stat.S_ISREG(st.st_mode)):
        raise exists_error(shown, what)
    return path


def check_outputs_free(paths, inputs=(), *, overwrite: bool = True, what: str = "output") -> list[Path]:
    """Check every path of an output group before any work: no folder, no missing folder, none of
    ``inputs`` (any spelling or link: :func:`check_not_input`), no two the same file, and none existing
    unless ``overwrite``. The paths as Paths (messages name each as given)."""
    given = list(paths)
    seen: dict[str, Path] = {}
    for p in given:
        check_not_input(p, inputs, what)
        check_output(p, overwrite=overwrite, what=what)
        key = os.path.realpath(p)
        if key in seen:
            raise InputError(f"{p}: the {what} names the same file as {seen[key]}; give names that differ")
        seen[key] = p
    return [Path(p) for p in given]


def ensure_folder(path) -> Path:
    """The folder ``path``, made with its parents if missing: ``InputError``
    if a file is in the way, ``OutputError`` if it cannot be made."""
    path = Path(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise InputError(f"{path}: is a file, expected a folder") from None
    except OSError as exc:
        raise output_error(path, exc) from None
    return path


def check_not_input(output, inputs, what: str = "output") -> None:
    """``InputError`` if ``output`` is the same file (or folder) as one of
    ``inputs`` by :func:`os.path.samefile`: ``a.csv``, ``./a.csv``, an absolute
    path, a symbolic or a hard link to it. Paths that do not exist yet, ``-``
    and special files (``/dev/null``) pass.

    Parameters
    ----------
    output : path-like or None
        What the command will write.
    inputs : iterable of path-like
        What it reads (None entries are skipped).
    what : str
        How the message names the output (e.g. ``"--save-model"``).
    """
    if output is None or str(output) == STDOUT:
        return
    st = stat_or_none(Path(output))
    if st is None or not (stat.S_ISREG(st.st_mode) or stat.S_ISDIR(st.st_mode)):
        return
    for inp in inputs:
        if inp is None or str(inp) == STDOUT:
            continue
        try:
            same = os.path.samefile(output, inp)
        except (OSError, ValueError):
            continue
        if same:
            raise InputError(f"{output}: the {what} is the same file as the input {inp}; an input is never "
                             f"overwritten, give another name")

def fsync_folder(folder: Path) -> None:
    """Make a rename in ``folder`` durable (best effort: not every file system can)."""
    try:
        fd = os.open(folder if str(folder) else ".", os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)
