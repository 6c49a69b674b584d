"""One file, or a group of files, written whole or not at all (docs/formats.md, "How files are written").

:class:`AtomicFile` writes a regular file to a temporary file beside it and renames it into place (exclusively
without ``overwrite``: of two writers one fails), and a special file (``/dev/null``, a FIFO, ``-`` for standard
output) as a stream; :func:`atomic_write`, :func:`write_text`, :func:`write_bytes` and :func:`save_figure` are its
short forms. :class:`FileGroup` puts every file written in its block in place together, or none of them.
"""

from __future__ import annotations

import contextlib
import contextvars
import errno
import logging
import os
import shutil
import stat
import sys
import tempfile
import time
from pathlib import Path

from ..errors import InputError, OutputError, quoting
from .paths import (FAILURE_REASONS, STDOUT, check_not_input, current_umask, exists_error, fsync_folder, lexists,
                    output_error, stat_or_none, temp_path)

_log = logging.getLogger("cmmpose")

#: Seconds to wait for a reader to open a FIFO before giving up (s).
FIFO_OPEN_TIMEOUT = 30.0


def _make_temp(folder) -> tuple[int, str]:
    """A new file beside the target, created exclusively (mode 0600): its descriptor and name."""
    for _ in range(100):
        name = temp_path(folder if str(folder) else ".")
        try:
            return os.open(name, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o600), str(name)
        except FileExistsError:
            continue
    raise FileExistsError(errno.EEXIST, "no free temporary name", str(folder))

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
        ``OutputError``). Inside a :class:`FileGroup` that takes this file
        (its ``only``) the group's setting wins.

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
        groups = [g for g in _GROUP.get() if g.claims(path)]
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
        st = stat_or_none(p)
        if st is not None and stat.S_ISDIR(st.st_mode):
            raise InputError(f"{p}: is a folder, expected a file name for the {what}")
        if not overwrite and (st is None and lexists(p) or st is not None and stat.S_ISREG(st.st_mode)):
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
        self.mode_bits = stat.S_IMODE(st.st_mode) if st is not None else 0o666 & ~current_umask()
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
                fsync_folder(self.target.parent)
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
    only : iterable of path-like, optional
        The group's files (or the folders whose files it is): a writer
        joins only for a target that is one of them or lies directly in one
        of them (any spelling or link). Any other file written in the
        block, such as a writer's own scratch file that it reads back, is
        written as it would be outside the group. None: every writer joins.
    """

    def __init__(self, *, overwrite: bool = True, inputs=(), what: str = "output", only=None):
        self.overwrite = overwrite
        self.inputs = [i for i in inputs if i is not None]
        self.what = what
        self.only = None if only is None else {os.path.realpath(p) for p in only if p is not None}
        self.members: list[AtomicFile] = []

    def claims(self, path) -> bool:
        """Whether a file written at ``path`` in the block joins the group (see ``only``)."""
        if self.only is None:
            return True
        if str(path) == STDOUT:
            return False
        real = os.path.realpath(path)
        return real in self.only or os.path.dirname(real) in self.only

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
                if self.overwrite and lexists(m.target):
                    aside = str(temp_path(m.target.parent, ".old"))
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
                reason = FAILURE_REASONS.get(exc.errno) or exc.strerror or str(exc)
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
            fsync_folder(folder)

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
