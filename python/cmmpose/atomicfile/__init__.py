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
- A group of files (a map set, a command's outputs) is written with
  :class:`FileGroup`: every member is written beside its target first, then
  all are put in place; a failure puts back what was there and removes what
  was new, so the group appears whole or not at all. A group given ``only``
  (its files or their folders) takes only those; a writer's scratch file
  elsewhere is written as outside the group.
- A run directory is written into a temporary folder beside it and renamed
  into place whole when the name is free (exclusive: of two writers one
  fails), or swapped in under a lock on the folder (:func:`staged_folder`):
  each file it replaces is first set aside, and deleted only once every new
  file is in place.

The modules: :mod:`.paths` (the checks before any work, the temporary names, an ``OSError`` as ``OutputError``),
:mod:`.files` (:class:`AtomicFile`, its short forms and :class:`FileGroup`), :mod:`.folders` (a run directory
written whole, :func:`locked_update`, :func:`replace_link`) and :mod:`.termination`
(:func:`raise_on_termination`); callers import the names below from ``cmmpose.atomicfile``.
"""

from .files import FIFO_OPEN_TIMEOUT, AtomicFile, FileGroup, atomic_write, save_figure, write_bytes, write_text
from .folders import locked_update, replace_link, staged_folder
from .paths import STDOUT, check_not_input, check_output, check_outputs_free, ensure_folder, exists_error, output_error
from .termination import raise_on_termination

__all__ = ["STDOUT", "FIFO_OPEN_TIMEOUT", "AtomicFile", "FileGroup", "atomic_write", "write_text", "write_bytes",
           "save_figure", "check_output", "check_outputs_free", "check_not_input", "ensure_folder", "output_error",
           "staged_folder", "locked_update", "replace_link", "raise_on_termination", "exists_error"]
