"""How cmmpose writes every file (docs/formats.md, "How files are written").

- A regular file (or a new one) is written to a temporary file beside it
  (``.cmmpose-XXXXXXXXXXXX.tmp``: a short fixed-length name, so any name
  the file system allows for the target works), flushed to disk (fsync) and
  renamed over the target
  (:func:`os.replace`): a crash, a full disk or a failed write leaves the
  earlier file whole. A symbolic link is followed: the file it points to is
  replaced and the link kept. The new file gets the permissions of the file
  it replaces, or for a new file those the user's umask allows (0644 under
  umask 022), never the temporary file's 0600.
- A special file (a character device such as ``/dev/null``, a FIFO) is
  written as a stream, never replaced by a rename; ``-`` means standard
  output where a command accepts it. A format that must go back to fix its
  header (NPY, PLY, PTS, E57) is spooled to a temporary file first and then
  copied into the stream.
- A folder is refused with ``InputError``; so is an output that is the same
  file as one of the command's inputs (:func:`check_not_input`, by
  :func:`os.path.samefile`: any spelling, a symbolic or a hard link).
- The temporary file is removed on every error path, including a failing
  ``close()``; an ``OSError`` while writing (a full disk, a read-only file
  system, no permission) becomes :class:`~cmmpose.errors.OutputError`
  naming the file. The command line turns SIGTERM and SIGHUP into an
  exception (:func:`raise_on_termination`) so that the same clean-up runs as
  on Ctrl-C. Only SIGKILL or a power cut can leave a ``.tmp`` file behind;
  the earlier file is whole even then.
- One door out: with ``overwrite=False`` an output is created exclusively.
  An existing target is refused (:func:`check_output`, before any work), and
  the finished file is put in place by a hard link that fails if the name
  exists meanwhile (:func:`os.link`; where the file system has no hard links,
  an exclusive reservation of the name): of two writers of one name, exactly
  one succeeds and the other gets ``OutputError``, its file never replacing
  the first one's.
- A group of files (a map set) is written with :class:`FileGroup`: every
  member is written beside its target first, then all are put in place; a
  failure puts back what was there and removes what was new, so the group
  appears whole or not at all.
- A run directory is written into a temporary folder beside it and renamed
  into place whole when the name is free (exclusive: of two writers one
  fails), or swapped in under a lock on the folder (:func:`staged_folder`):
  each file it replaces is first set aside, and deleted only once every new
  file is in place.
"""

from __future__ import annotations

import contextlib
import contextvars
import errno
import fcntl
import logging
import os
import secrets
import shutil
import signal
import stat
import sys
import tempfile
import time
from pathlib import Path

from .errors import InputError, OutputError, quoting

__all__ = ["STDOUT", "FIFO_OPEN_TIMEOUT", "AtomicFile", "FileGroup", "atomic_write", "write_text", "write_bytes",
           "save_figure", "check_output", "check_outputs_free", "check_not_input", "ensure_folder", "output_error",
           "staged_folder", "locked_update", "replace_link", "raise_on_termination", "exists_error"]

_log = logging.getLogger("cmmpose")

#: The output name that means standard output, where a command accepts it.
STDOUT = "-"
#: Seconds to wait for a reader to open a FIFO before giving up (s).
FIFO_OPEN_TIMEOUT = 30.0

_REASONS = {
    errno.ENOSPC: "no space left on the device",
    errno.EDQUOT: "disk quota exceeded",
    errno.EROFS: "read-only file system",
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
    errno.EFBIG: "file too large for the file system",
}


def output_error(path, exc: OSError) -> OutputError:
    """``OutputError`` naming ``path`` and why ``exc`` stopped the write."""
    reason = _REASONS.get(exc.errno) or exc.strerror or str(exc) or type(exc).__name__
    return OutputError(f"{path}: cannot write ({reason}); any earlier file there is unchanged")


def _umask() -> int:
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


def _stat(path: Path):
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


def _temp_path(folder, suffix: str = ".tmp") -> Path:
    return Path(folder) / f"{TEMP_PREFIX}{secrets.token_hex(6)}{suffix}"


def _make_temp(folder) -> tuple[int, str]:
    """A new file beside the target, created exclusively (mode 0600): its descriptor and name."""
    for _ in range(100):
        name = _temp_path(folder if str(folder) else ".")
        try:
            return os.open(name, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o600), str(name)
        except FileExistsError:
            continue
    raise FileExistsError(errno.EEXIST, "no free temporary name", str(folder))


def _make_temp_folder(parent, suffix: str) -> Path:
    """A new folder beside the target (mode 0700 until chmod): ``.cmmpose-XXXXXXXXXXXX<suffix>``."""
    for _ in range(100):
        name = _temp_path(parent, suffix)
        try:
            os.mkdir(name, 0o700)
            return name
        except FileExistsError:
            continue
    raise FileExistsError(errno.EEXIST, "no free temporary name", str(parent))


def exists_error(path, what: str = "output", *, meanwhile: bool = False) -> OutputError:
    """``OutputError``: ``path`` exists and ``overwrite`` was not given (``meanwhile``: another writer made
    it while this one worked; this one's result was not put there)."""
    if meanwhile:
        return OutputError(f"{path}: another writer created it while this one worked; the {what} was not written "
                           "over it", file=str(path), option="overwrite", remedy="overwrite")
    return OutputError(f"{path}: exists; the {what} is never written over an existing file without being told",
                       file=str(path), option="overwrite", remedy="overwrite")


def _lexists(path) -> bool:
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
    and ``overwrite`` is False (:func:`exists_error`). Special files pass."""
    path = Path(path)
    if str(path) == STDOUT:
        return path
    st = _stat(path)
    if st is not None and stat.S_ISDIR(st.st_mode):
        raise InputError(f"{path}: is a folder, expected a file name")
    if st is None:
        real = Path(os.path.realpath(path))
        folder = real.parent
        if not folder.is_dir():
            raise InputError(f"{path}: the folder {path.parent if str(path.parent) else '.'} does not exist")
    if not overwrite and (st is None and _lexists(path) or st is not None and stat.S_ISREG(st.st_mode)):
        raise exists_error(path, what)
    return path


def check_outputs_free(paths, inputs=(), *, overwrite: bool = True, what: str = "output") -> list[Path]:
    """Check every path of an output group before any work: no folder, no missing folder, none of
    ``inputs`` (any spelling or link: :func:`check_not_input`), no two the same file, and none existing
    unless ``overwrite``. The paths as Paths."""
    paths = [Path(p) for p in paths]
    seen: dict[str, Path] = {}
    for p in paths:
        check_not_input(p, inputs, what)
        check_output(p, overwrite=overwrite, what=what)
        key = os.path.realpath(p)
        if key in seen:
            raise InputError(f"{p}: the {what} names the same file as {seen[key]}; give names that differ")
        seen[key] = p
    return paths


def _put_in_place(tmp: str, target: Path, overwrite: bool, what: str = "output") -> None:
    """Rename ``tmp`` to ``target``: over it (``overwrite``), or only if the name is free, atomically
    (a hard link that fails on an existing name; where links are not supported, an exclusive
    reservation of the name then a rename over it). ``OutputError`` if the name was taken."""
    if overwrite:
        os.replace(tmp, target)
        return
    try:
        os.link(tmp, target, follow_symlinks=False)
    except FileExistsError:
        raise exists_error(target, what, meanwhile=True) from None
    except OSError as exc:
        if exc.errno not in (errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EMLINK, errno.ENOSYS, errno.EXDEV):
            raise
        try:
            fd = os.open(target, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o600)
        except FileExistsError:
            raise exists_error(target, what, meanwhile=True) from None
        os.close(fd)
        os.replace(tmp, target)
        return
    try:
        os.unlink(tmp)
    except OSError as exc:  # the file is in place; only the second name is left
        _log.warning("cannot remove the temporary name %s (%s)", tmp, exc.strerror or exc)


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
    st = _stat(Path(output))
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


def _open_fifo(path: Path, timeout: float) -> int:
    """A write descriptor on the FIFO ``path`` once a reader has opened it,
    or ``OutputError`` after ``timeout`` seconds without one."""
    end = time.monotonic() + timeout
    while True:
        try:
            fd = os.open(path, os.O_WRONLY | os.O_NONBLOCK | os.O_CLOEXEC)
        except OSError as exc:
            if exc.errno != errno.ENXIO:  # ENXIO: no reader yet
                raise output_error(path, exc) from None
            if time.monotonic() >= end:
                raise OutputError(f"{path}: no reader opened the FIFO within {timeout:g} s") from None
            time.sleep(0.02)
            continue
        os.set_blocking(fd, True)
        return fd


class AtomicFile:
    """One output being written: ``f`` is the open file object; :meth:`commit`
    puts it in place, :meth:`abort` drops it (see the module's docstring).

    Parameters
    ----------
    path : path-like
        The target: a file (new or existing), a special file, or ``-``.
    mode : {"w", "wb"}
        Text (UTF-8 by default) or binary.
    encoding, newline : str, optional
        For text mode, as :func:`open`.
    inputs : iterable of path-like
        The command's inputs: a target that is one of them is refused
        (:func:`check_not_input`).
    stdout : bool
        Accept ``-`` for standard output.
    spool : bool
        The writer seeks or reopens the file by name (:attr:`name`): a stream
        target is then written through a temporary file copied into it on
        :meth:`commit`.
    what : str
        How messages name the output.
    overwrite : bool
        Replace an existing file (the default). False: create it
        exclusively: an existing file is refused now, and one that another
        writer makes meanwhile is never replaced (:meth:`commit` raises
        ``OutputError``). Inside a :class:`FileGroup` the group's setting wins.

    Raises
    ------
    InputError
        A folder, a missing folder, ``-`` where it is not accepted, an input.
    OutputError
        The temporary file cannot be made (a read-only folder, no permission);
        the target exists and ``overwrite`` is False.
    """

    def __init__(self, path, mode: str = "wb", *, encoding: str | None = "utf-8", newline: str | None = None,
                 inputs=(), stdout: bool = False, spool: bool = False, what: str = "output",
                 overwrite: bool = True):
        if mode not in ("w", "wb"):
            raise ValueError(f"mode must be 'w' or 'wb', got {mode!r}")
        groups = _GROUP.get()
        self.group = groups[-1] if groups else None
        if self.group is not None:
            overwrite = self.group.overwrite
            inputs = [*inputs, *self.group.inputs]
        self.overwrite = overwrite
        self.what = what
        self.f = None
        self.path = path
        self.binary = mode == "wb"
        self._text = {} if self.binary else {"encoding": encoding, "newline": newline}
        self.tmp: str | None = None  # a temporary file to remove on failure
        self.stream = None  # a stream target: the spool is copied into it
        self._own_stream = True
        self.done = False
        self.kind = "file"  # "file": renamed into place; "stream": written into; "spool": copied into a stream
        if str(path) == STDOUT:
            if not stdout:
                raise InputError(f"'-' (standard output) is not accepted for the {what}; give a file name")
            self.target = None
            out = sys.stdout.buffer if self.binary else sys.stdout
            self._own_stream = False
            self._stream_target(out, spool)
            return
        p = Path(path)
        check_not_input(p, inputs, what)
        st = _stat(p)
        if st is not None and stat.S_ISDIR(st.st_mode):
            raise InputError(f"{p}: is a folder, expected a file name for the {what}")
        if not overwrite and (st is None and _lexists(p) or st is not None and stat.S_ISREG(st.st_mode)):
            raise exists_error(p, what)
        if st is not None and not stat.S_ISREG(st.st_mode):
            self.target = p
            try:
                fd = (_open_fifo(p, FIFO_OPEN_TIMEOUT) if stat.S_ISFIFO(st.st_mode)
                      else os.open(p, os.O_WRONLY | os.O_CLOEXEC))
            except OSError as exc:
                raise output_error(p, exc) from None
            out = os.fdopen(fd, mode, **self._text)
            try:
                self._stream_target(out, spool)
            except BaseException:
                out.close()
                raise
            return
        # a link is followed: the file it names is replaced, the link stays
        self.target = Path(os.path.realpath(p)) if p.is_symlink() else p
        folder = self.target.parent if str(self.target.parent) else Path(".")
        if not folder.is_dir():
            raise InputError(f"{p}: the folder {folder} does not exist")
        self.mode_bits = stat.S_IMODE(st.st_mode) if st is not None else 0o666 & ~_umask()
        try:
            fd, self.tmp = _make_temp(folder)
        except OSError as exc:
            raise output_error(p, exc) from None
        try:
            self.f = os.fdopen(fd, mode, **self._text)
        except BaseException:
            os.close(fd)
            self._remove_tmp()
            raise

    def _stream_target(self, out, spool: bool) -> None:
        if not spool:
            self.kind = "stream"
            self.f = out
            return
        self.kind = "spool"
        self.stream = out
        try:
            fd, self.tmp = tempfile.mkstemp(prefix="cmmpose-spool.", suffix=".tmp")
        except OSError as exc:
            raise output_error(f"{self.path} (its spool in {tempfile.gettempdir()})", exc) from None
        try:
            self.f = os.fdopen(fd, "wb" if self.binary else "w", **self._text)
        except BaseException:
            os.close(fd)
            self._remove_tmp()
            raise

    @property
    def name(self) -> str | None:
        """The file name being written (a writer that opens it itself uses
        it), or None when writing straight into a stream."""
        return self.tmp

    def fail(self, exc: OSError) -> OutputError:
        """Abort and return the ``OutputError`` for ``exc`` (to raise)."""
        self.abort()
        return output_error(self.path, exc)

    def commit(self) -> None:
        """Flush to disk and rename into place (or finish the stream).

        Raises
        ------
        OutputError
            Writing, flushing or closing failed; the temporary file is removed
            and the target left as it was.
        """
        if self.done:
            return
        try:
            if self.kind == "stream":
                self.f.flush()
                if self._own_stream:
                    self.f.close()
            elif self.kind == "spool":  # copy into the stream
                if not self.f.closed:
                    self.f.close()
                with open(self.tmp, "rb") as src:
                    dst = self.stream if self.binary else self.stream.buffer
                    self.stream.flush()
                    shutil.copyfileobj(src, dst, 1 << 20)
                    dst.flush()
                if self._own_stream:
                    self.stream.close()
                self._remove_tmp()
            else:
                if not self.f.closed:
                    self.f.flush()
                    os.fsync(self.f.fileno())
                    self.f.close()
                else:  # a writer that wrote the file by name
                    fd = os.open(self.tmp, os.O_RDONLY | os.O_CLOEXEC)
                    try:
                        os.fsync(fd)
                    finally:
                        os.close(fd)
                os.chmod(self.tmp, self.mode_bits)
                if self.group is not None:  # put in place with the rest of the group
                    self.group.staged(self)
                    self.done = True
                    return
                _put_in_place(self.tmp, self.target, self.overwrite, self.what)
                self.tmp = None
                _fsync_folder(self.target.parent)
        except OSError as exc:
            raise self.fail(exc) from None
        except BaseException:
            self.abort()
            raise
        self.done = True
        _log.debug("wrote %s", self.path)

    def abort(self) -> None:
        """Close without committing and remove the temporary file; the target
        is left as it was. Never raises (an error is on its way already)."""
        if self.done:
            return
        self.done = True
        for f, own in ((self.f, self.kind != "stream" or self._own_stream), (self.stream, self._own_stream)):
            if f is not None and own and not f.closed:
                with contextlib.suppress(Exception):
                    f.close()  # a failing flush still closes the descriptor
        self._remove_tmp()

    def _remove_tmp(self) -> None:
        if self.tmp is not None:
            with contextlib.suppress(FileNotFoundError):
                try:
                    os.unlink(self.tmp)
                except OSError as exc:
                    _log.warning("cannot remove the temporary file %s (%s)", self.tmp, exc.strerror or exc)
            self.tmp = None

    def __enter__(self):
        return self.f

    def __exit__(self, kind, exc, tb):
        if kind is None:
            self.commit()
            return False
        self.abort()
        if isinstance(exc, OSError) and exc.filename in (None, self.tmp, str(self.path)):
            raise output_error(self.path, exc) from None
        return False


def _fsync_folder(folder: Path) -> None:
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


def atomic_write(path, mode: str = "w", **options) -> AtomicFile:
    """``with atomic_write(path) as f: ...``: ``f`` is committed when the block
    ends and dropped if it raises (options as :class:`AtomicFile`)."""
    return AtomicFile(path, mode, **options)


def write_text(path, text: str, **options) -> None:
    """Write ``text`` (UTF-8) to ``path`` as the module's docstring says."""
    with AtomicFile(path, "w", **options) as f:
        f.write(text)


def write_bytes(path, data: bytes, **options) -> None:
    """Write ``data`` to ``path`` as the module's docstring says."""
    with AtomicFile(path, "wb", **options) as f:
        f.write(data)


def save_figure(fig, path, **options) -> None:
    """``fig.savefig`` through :class:`AtomicFile`, in the format the suffix names
    (matplotlib's default for none); ``options`` go to ``savefig``."""
    import matplotlib

    fmt = Path(path).suffix[1:].lower() or matplotlib.rcParams["savefig.format"]
    with AtomicFile(path, "wb") as f:
        fig.savefig(f, format=fmt, **options)


#: The groups being written in this thread or task, innermost last (:class:`FileGroup`); a writer's
#: :class:`AtomicFile` joins the last. A context variable: another thread's writers never join.
_GROUP: contextvars.ContextVar[tuple] = contextvars.ContextVar("cmmpose_file_group", default=())


class FileGroup:
    """Files that appear together or not at all (a map set: one file per temperature).

    ``with FileGroup(overwrite=False, inputs=[...]) as group: m.write(p) ...``:
    every :class:`AtomicFile` opened in the block (so every writer of cmmpose)
    is written beside its target and kept there; when the block ends they are
    put in place together. Should one of them fail (its name taken meanwhile
    without ``overwrite``, a full disk, a signal), the ones already in place
    are taken out again and the files they replaced put back, so nothing of
    the group remains; if the block raises, nothing is put in place at all.

    Parameters
    ----------
    overwrite : bool
        Replace existing files (set aside first, put back on failure); False:
        each member is created exclusively (:func:`_put_in_place`).
    inputs : iterable of path-like
        Files no member may be (:func:`check_not_input`).
    what : str
        How messages name the group (e.g. ``"--corrected-maps"``).
    """

    def __init__(self, *, overwrite: bool = True, inputs=(), what: str = "output"):
        self.overwrite = overwrite
        self.inputs = [i for i in inputs if i is not None]
        self.what = what
        self.members: list[AtomicFile] = []

    def staged(self, member: AtomicFile) -> None:
        """Called by a member's commit: it is whole beside its target."""
        self.members.append(member)

    def __enter__(self):
        self._token = _GROUP.set((*_GROUP.get(), self))
        return self

    def __exit__(self, kind, exc, tb):
        _GROUP.reset(self._token)
        if kind is not None:
            self._drop()  # nothing was put in place: say so of the whole group
            if issubclass(kind, OutputError) and self.members:
                message, fields = quoting(exc, after=f"; nothing of the {self.what} was written")
                raise OutputError(message, **fields) from None
            return False
        try:
            self._commit()
        finally:
            self._drop()
        return False

    def _drop(self) -> None:
        for m in self.members:
            m._remove_tmp()

    def _commit(self) -> None:
        placed: list[tuple[AtomicFile, str | None]] = []  # member, where the file it replaced was set aside
        targets = {}
        for m in self.members:
            key = os.path.realpath(m.target)
            if key in targets:
                raise InputError(f"{m.path}: the {self.what} writes the same file twice ({targets[key]}); "
                                 "nothing of it was written")
            targets[key] = m.path
        try:
            for m in self.members:
                aside = None
                if self.overwrite and _lexists(m.target):
                    aside = str(_temp_path(m.target.parent, ".old"))
                    try:  # a second name: the target is never missing
                        os.link(m.target, aside, follow_symlinks=False)
                    except OSError as exc:
                        if exc.errno not in (errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EMLINK,
                                             errno.ENOSYS):
                            raise
                        os.rename(m.target, aside)  # no hard links here: set aside, missing for a moment
                _put_in_place(m.tmp, m.target, self.overwrite, self.what)
                m.tmp = None
                placed.append((m, aside))
        except BaseException as exc:
            left = self._undo(placed)
            if isinstance(exc, OSError):
                failed = self.members[len(placed)].path
                reason = _REASONS.get(exc.errno) or exc.strerror or str(exc)
                raise OutputError(f"{failed}: cannot write ({reason}); "
                                  + (f"nothing of the {self.what} was written and any earlier files are unchanged"
                                     if not left else f"the {self.what} is incomplete: {', '.join(left)} could not "
                                     "be put back as they were"), file=str(failed)) from None
            if left:
                _log.error("the %s is incomplete: %s could not be put back as they were", self.what, ", ".join(left))
            raise
        for _, aside in placed:
            if aside is not None:
                with contextlib.suppress(OSError):
                    os.unlink(aside)
        for folder in {m.target.parent for m in self.members}:
            _fsync_folder(folder)

    def _undo(self, placed) -> list[str]:
        """Take the placed members out again and put back what they replaced: the paths that could not be."""
        left = []
        for m, aside in reversed(placed):
            try:
                if aside is not None:
                    os.replace(aside, m.target)
                else:
                    os.unlink(m.target)
            except OSError as exc:
                left.append(str(m.path))
                _log.error("cannot restore %s (%s)", m.path, exc.strerror or exc)
        return left


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
            os.chmod(stage, 0o777 & ~_umask())
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
            _fsync_folder(p)
            continue
        fd = os.open(p, os.O_RDONLY | os.O_CLOEXEC)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def _rename_in_whole(stage: Path, folder: Path) -> bool:
    """Rename ``stage`` to ``folder`` if no such name exists (atomic: a folder that another writer made
    meanwhile is never replaced). False if ``folder`` exists."""
    if _lexists(folder):
        return False
    _fsync_tree(stage)
    try:
        os.rename(stage, folder)  # replaces only a missing name or an empty folder
    except OSError as exc:
        if exc.errno in (errno.ENOTEMPTY, errno.EEXIST):
            return False
        raise
    _fsync_folder(folder.parent)
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
    _fsync_folder(folder)


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
        tmp = _temp_path(link.parent)
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


class _Terminated(SystemExit):
    """SIGTERM or SIGHUP, raised so that ``finally`` blocks and :meth:`AtomicFile.abort` run."""


def raise_on_termination() -> None:
    """Make SIGTERM and SIGHUP raise ``SystemExit(128 + signal)`` in the main
    thread, as Ctrl-C raises ``KeyboardInterrupt``: every ``finally`` runs and
    no temporary file is left. For the command line (a library leaves the
    process's signal handlers alone); does nothing outside the main thread."""

    def handler(signum, frame):
        name = signal.Signals(signum).name
        _log.warning("%s received: stopping, removing temporary files", name)
        raise _Terminated(128 + signum)

    for sig in (signal.SIGTERM, getattr(signal, "SIGHUP", None)):
        if sig is None:
            continue
        try:
            if signal.getsignal(sig) in (signal.SIG_DFL, None):
                signal.signal(sig, handler)
        except (ValueError, OSError):  # not the main thread
            return
