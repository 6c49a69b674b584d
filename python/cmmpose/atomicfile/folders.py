"""A folder written whole, a file updated under a lock, a link replaced atomically (docs/formats.md, "How
files are written").

:func:`staged_folder`: a run directory is written into a temporary folder beside it and renamed into place whole
when the name is free (exclusive: of two writers one fails), or swapped in under a lock on the folder: each file it
replaces is first set aside, and deleted only once every new file is in place. :func:`locked_update`: a
read-modify-write of one file under a lock on its folder. :func:`replace_link`: a symbolic link re-pointed by a
rename.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import logging
import os
import shutil
from pathlib import Path

from ..errors import OutputError
from .paths import current_umask, ensure_folder, fsync_folder, lexists, output_error, temp_path

_log = logging.getLogger("cmmpose")


def _make_temp_folder(parent, suffix: str) -> Path:
    """A new folder beside the target (mode 0700 until chmod): ``.cmmpose-XXXXXXXXXXXX<suffix>``."""
    for _ in range(100):
        name = temp_path(parent, suffix)
        try:
            os.mkdir(name, 0o700)
            return name
        except FileExistsError:
            continue
    raise FileExistsError(errno.EEXIST, "no free temporary name", str(parent))


@contextlib.contextmanager
def staged_folder(folder, replace=(), *, error=OutputError, exclusive: bool = False):
    """Write a folder's files elsewhere and swap them in whole.

    ``with staged_folder(run_dir, replace=names) as stage:`` yields a new
    temporary folder beside ``folder``; write the new files into it. When the
    block ends, every entry of ``stage`` takes the place of the entry of the
    same name in ``folder`` (created if missing), and the entries named in
    ``replace`` that the new set lacks are removed: each replaced entry is
    first renamed aside and deleted only when all the new ones are in place;
    a failure on the way puts the old ones back. Other files in ``folder``
    are left alone. If the block raises, ``stage`` is deleted and ``folder``
    is untouched.

    Parameters
    ----------
    folder : path-like
        The folder to update.
    replace : iterable of str
        Names (relative to ``folder``; ``a/b`` for inside a sub-folder) that
        belong to the set being replaced.
    error : type
        The ``cmmpose.Error`` subclass an ``OSError`` becomes (its message
        names ``folder``).
    exclusive : bool
        The folder must be missing or empty: the stage is renamed into its
        place whole, which fails if another writer filled it meanwhile (then
        ``error`` says so and nothing of this one is left). Without it, a
        folder that is missing or empty is made the same way, and one that
        holds files is swapped into under a lock on it (two writers swap one
        after the other, never interleaved).
    """
    shown = folder
    folder = Path(os.path.abspath(folder))  # "." has a name and a parent
    parent = folder.parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
        stage = _make_temp_folder(parent, ".new")
    except OSError as exc:
        raise error(str(output_error(shown, exc))) from None
    try:
        try:
            os.chmod(stage, 0o777 & ~current_umask())
            yield stage
            if not _rename_in_whole(stage, folder) and not _swap_in(stage, folder, list(replace), exclusive):
                raise error(f"{shown}: another writer filled the folder while this one worked; nothing of this "
                            "one was written into it", option="overwrite", remedy="overwrite_run")
        except OSError as exc:
            raise error(str(output_error(shown, exc))) from None
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def _fsync_tree(stage: Path) -> None:
    for p in sorted(stage.rglob("*")):
        if p.is_dir():
            fsync_folder(p)
            continue
        fd = os.open(p, os.O_RDONLY | os.O_CLOEXEC)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def _rename_in_whole(stage: Path, folder: Path) -> bool:
    """Rename ``stage`` to ``folder`` if no such name exists (atomic: a folder that another writer made
    meanwhile is never replaced). False if ``folder`` exists."""
    if lexists(folder):
        return False
    _fsync_tree(stage)
    try:
        os.rename(stage, folder)  # replaces only a missing name or an empty folder
    except OSError as exc:
        if exc.errno in (errno.ENOTEMPTY, errno.EEXIST):
            return False
        raise
    fsync_folder(folder.parent)
    return True


def _swap_in(stage: Path, folder: Path, replace: list[str], exclusive: bool = False) -> bool:
    """Move ``stage``'s entries into ``folder`` (see :func:`staged_folder`), under a lock on ``folder``;
    ``exclusive``: only into an empty folder (False if it holds anything, checked under the lock)."""
    folder.mkdir(parents=True, exist_ok=True)
    lock = os.open(folder, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    try:
        fcntl.flock(lock, fcntl.LOCK_EX)  # two writers swap one after the other; released on exit or death
        if exclusive and any(folder.iterdir()):
            return False
        _swap_in_locked(stage, folder, replace)
        return True
    finally:
        os.close(lock)


def _swap_in_locked(stage: Path, folder: Path, replace: list[str]) -> None:
    new = [p.relative_to(stage) for p in sorted(stage.rglob("*")) if not p.is_dir()]
    old = [Path(n) for n in replace if (folder / n).is_file() or (folder / n).is_symlink()]
    for rel in new:  # on disk before any old file is set aside
        fd = os.open(stage / rel, os.O_RDONLY | os.O_CLOEXEC)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
    aside = _make_temp_folder(folder.parent, ".old")
    moved_aside: list[Path] = []
    moved_in: list[Path] = []
    try:
        for rel in sorted(set(old) | {r for r in new if (folder / r).exists() or (folder / r).is_symlink()}):
            (aside / rel).parent.mkdir(parents=True, exist_ok=True)
            os.replace(folder / rel, aside / rel)
            moved_aside.append(rel)
        for rel in new:
            (folder / rel).parent.mkdir(parents=True, exist_ok=True)
            os.replace(stage / rel, folder / rel)
            moved_in.append(rel)
    except BaseException:
        for rel in reversed(moved_in):
            with contextlib.suppress(OSError):
                os.replace(folder / rel, stage / rel)
        kept = False
        for rel in reversed(moved_aside):
            try:
                os.replace(aside / rel, folder / rel)
            except OSError as exc:
                kept = True
                _log.error("cannot put %s back into %s (%s): it is kept in %s", rel, folder, exc.strerror or exc, aside)
        if not kept:
            shutil.rmtree(aside, ignore_errors=True)
        raise
    shutil.rmtree(aside, ignore_errors=True)
    # sub-folders emptied by the swap (e.g. a run's truth/ when the new run has none)
    for rel in sorted({Path(n).parent for n in replace if Path(n).parent != Path(".")}, reverse=True):
        with contextlib.suppress(OSError):
            (folder / rel).rmdir()
    fsync_folder(folder)


@contextlib.contextmanager
def locked_update(path):
    """``with locked_update(path): read, change, write``: a read-modify-write of ``path`` (an alignment
    library) under a lock on its folder, so that two writers updating one file take turns and neither's
    change is lost (each would otherwise read the old file and the last rename would drop the other's).
    The folder is made if missing; the lock is released on exit, or by the system if the process dies."""
    folder = ensure_folder(Path(os.path.abspath(path)).parent)
    try:
        fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    except OSError as exc:
        raise output_error(path, exc) from None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)


def replace_link(link, target) -> None:
    """Point the symbolic link ``link`` at ``target`` atomically: a new link
    beside it renamed over it, so ``link`` always names the old or the new."""
    link = Path(link)
    for _ in range(100):
        tmp = temp_path(link.parent)
        try:
            os.symlink(target, tmp)
            break
        except FileExistsError:
            continue
    else:
        raise OutputError(f"{link}: cannot make a temporary link beside it")
    try:
        os.replace(tmp, link)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
