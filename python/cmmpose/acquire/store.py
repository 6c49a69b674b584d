"""The acquisition journal: an append-only file of checksummed blocks, written
while recording and read back after a clean stop or a crash
(docs/protocols.md, "Journal").

File layout (little-endian)::

    file header  8 bytes   "CMMPJNL" 0x01
    block        20 bytes  magic "BLK" 0x01, u32 block number (0, 1, ...),
                           u32 record count, u32 payload length,
                           u32 CRC-32 of bytes 4..15 of the block header + payload
                 payload   records, back to back
    record       13 bytes  u8 kind, u32 data length, f64 host time (s, Unix epoch)
                 data      kind 1: a scanner frame exactly as received
                           kind 2: f64 host send time + the logger's answer line (UTF-8)
                           kind 3: an event, UTF-8 JSON object

Every block is written with one ``write`` call and then ``fsync``; a block
either reads back whole with a good CRC or is the torn tail of a crash. The
reader stops at the first block that is incomplete, fails its CRC or is out of
sequence, and reports the bytes from there to the end of the file as the torn
tail.
"""

from __future__ import annotations

import json
import os
import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import AcquisitionError

__all__ = [
    "JOURNAL_NAME",
    "LOG_NAME",
    "FILE_MAGIC",
    "SCANNER",
    "THERMO",
    "EVENT",
    "JournalWriter",
    "JournalContents",
    "TornTail",
    "read_journal",
    "encode_record",
]

JOURNAL_NAME = "journal.cmmj"
LOG_NAME = "acquire.log"
FILE_MAGIC = b"CMMPJNL\x01"
BLOCK_MAGIC = b"BLK\x01"
_BLOCK = struct.Struct("<4sIIII")
_RECORD = struct.Struct("<BId")
_TX = struct.Struct("<d")
SCANNER, THERMO, EVENT = 1, 2, 3
_KINDS = {SCANNER: "scanner", THERMO: "thermo", EVENT: "event"}


def encode_record(kind: int, host_time: float, data: bytes) -> bytes:
    """One journal record.

    Parameters
    ----------
    kind : int
        ``SCANNER``, ``THERMO`` or ``EVENT``.
    host_time : float
        Host receive time, s since the Unix epoch.
    data : bytes
        The record's data (see the module docstring).
    """
    return _RECORD.pack(kind, len(data), host_time) + data


class JournalWriter:
    """Appends blocks to a journal file; one instance per recording.

    Parameters
    ----------
    path : str or path-like
        The journal file; created (must not exist unless ``append``).
    fsync : bool
        ``os.fsync`` after every block (survives power loss, not only a
        crash of the recorder).
    append : bool
        Continue an existing journal (after ``read_journal`` found where its
        good blocks end); the block numbering continues from ``next_block``.
    next_block : int
        Number of the next block when appending.
    """

    def __init__(self, path, *, fsync: bool = True, append: bool = False, next_block: int = 0):
        self.path = Path(path)
        self.fsync = fsync
        self.blocks = next_block
        self.bytes_written = 0
        flags = os.O_WRONLY | os.O_APPEND | os.O_CREAT | (0 if append else os.O_EXCL)
        try:
            self._fd = os.open(self.path, flags, 0o644)
            if not append:
                self._write(FILE_MAGIC)
        except FileExistsError:
            raise AcquisitionError(f"{self.path}: a journal already exists (a run was recorded here; recover it or choose another directory)") from None
        except OSError as exc:
            raise AcquisitionError(f"{self.path}: cannot open for writing ({exc.strerror or exc})") from None

    def _write(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            n = os.write(self._fd, view)
            view = view[n:]
        self.bytes_written += len(data)

    def write_block(self, records: list[bytes]) -> int:
        """Write one block of encoded records (``encode_record``) and sync it.

        Returns
        -------
        int
            Bytes written.
        """
        payload = b"".join(records)
        head = struct.pack("<III", self.blocks, len(records), len(payload))
        crc = zlib.crc32(payload, zlib.crc32(head))
        block = BLOCK_MAGIC + head + struct.pack("<I", crc) + payload
        try:
            self._write(block)
            if self.fsync:
                os.fsync(self._fd)
        except OSError as exc:
            raise AcquisitionError(f"{self.path}: write of block {self.blocks} failed ({exc.strerror or exc})") from None
        self.blocks += 1
        return len(block)

    def close(self) -> None:
        """Close the file (after a final ``write_block``)."""
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None


@dataclass(frozen=True)
class TornTail:
    """Bytes at the end of a journal that are not a whole good block.

    Attributes
    ----------
    offset : int
        File offset where the bad bytes start.
    nbytes : int
        Bytes from there to the end of the file.
    reason : str
        ``incomplete block`` (a crash mid-write), ``bad magic``, ``bad CRC``
        or ``block out of sequence``.
    block : int
        Number the block at ``offset`` should have had.
    """

    offset: int
    nbytes: int
    reason: str
    block: int


@dataclass
class JournalContents:
    """Everything a journal holds, in order of arrival.

    Attributes
    ----------
    scanner : list of (float, bytes)
        Host receive time (s) and frame of every good scanner record.
    thermo : list of (float, float, str)
        Host send time, host receive time (s) and answer line of every good logger scan.
    events : list of dict
        Events (rejections, gaps, resets, reconnects, ...), each with ``t`` (host time, s).
    blocks : int
        Good blocks read.
    good_bytes : int
        File offset where the good blocks end.
    torn_tail : TornTail or None
        What follows the last good block, if anything.
    """

    scanner: list = field(default_factory=list)
    thermo: list = field(default_factory=list)
    events: list = field(default_factory=list)
    blocks: int = 0
    good_bytes: int = 0
    torn_tail: TornTail | None = None


def read_journal(path) -> JournalContents:
    """Read a journal, stopping at its torn tail if it has one.

    Parameters
    ----------
    path : str or path-like
        The journal file (``RUN_DIR/journal.cmmj``).

    Returns
    -------
    JournalContents
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise AcquisitionError(f"{path}: cannot read the journal ({exc.strerror or exc})") from None
    if not data.startswith(FILE_MAGIC):
        raise AcquisitionError(f"{path}: not a cmmpose journal (the first 8 bytes are {data[:8]!r})")
    out = JournalContents()
    pos = len(FILE_MAGIC)
    mv = memoryview(data)
    while pos < len(data):
        reason = None
        if len(data) - pos < _BLOCK.size:
            reason = "incomplete block"
        else:
            magic, number, count, length, crc = _BLOCK.unpack_from(data, pos)
            end = pos + _BLOCK.size + length
            if magic != BLOCK_MAGIC:
                reason = "bad magic"
            elif end > len(data):
                reason = "incomplete block"
            elif zlib.crc32(mv[pos + _BLOCK.size : end], zlib.crc32(mv[pos + 4 : pos + 16])) != crc:
                reason = "bad CRC"
            elif number != out.blocks:
                reason = "block out of sequence"
        if reason:
            out.torn_tail = TornTail(pos, len(data) - pos, reason, out.blocks)
            break
        _read_records(path, out, data, pos + _BLOCK.size, end, count, number)
        out.blocks += 1
        pos = end
    out.good_bytes = pos if out.torn_tail is None else out.torn_tail.offset
    return out


def _read_records(path: Path, out: JournalContents, data: bytes, pos: int, end: int, count: int, block: int) -> None:
    for k in range(count):
        if pos + _RECORD.size > end:
            raise AcquisitionError(f"{path}: block {block} record {k}: runs past the block (a writer bug, the CRC was good)")
        kind, n, host = _RECORD.unpack_from(data, pos)
        pos += _RECORD.size
        payload = data[pos : pos + n]
        pos += n
        if kind == SCANNER:
            out.scanner.append((host, payload))
        elif kind == THERMO:
            out.thermo.append((_TX.unpack_from(payload)[0], host, payload[_TX.size :].decode("utf-8", "replace")))
        elif kind == EVENT:
            ev = json.loads(payload.decode("utf-8"))
            out.events.append(ev)
        else:
            raise AcquisitionError(f"{path}: block {block} record {k}: unknown kind {kind}")


def thermo_data(host_tx: float, line: str) -> bytes:
    """Data of a THERMO record: host send time (s) and the answer line."""
    return _TX.pack(host_tx) + line.encode("utf-8")


def event_data(event: dict) -> bytes:
    """Data of an EVENT record."""
    return json.dumps(event, allow_nan=False, separators=(",", ":")).encode("utf-8")


def kind_name(kind: int) -> str:
    """'scanner', 'thermo' or 'event'."""
    return _KINDS[kind]
