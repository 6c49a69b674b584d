"""The scanner + scales stream: one framed binary record per profile
(docs/protocols.md, "Scanner and scales").

Why binary: a full Hyscan profile is 1024 (u, v) points 6.6 times a second
(3.3 Hz mirror, both directions). As float32 pairs that is 8 KB a profile,
54 KB/s; as ASCII decimal text with micrometre resolution it would be about
2.5 times more, beyond what an RS-232 link at 921600 baud carries. A binary
frame is also parsed with one ``numpy.frombuffer`` call instead of a float
conversion per number.

Frame layout (little-endian), CRC-32 (ISO-HDLC, ``zlib.crc32``)::

    offset  size  field
    0       4     magic  A5 5A 50 52  (0xA5 0x5A 'P' 'R')
    4       4     seq    u32, 0 after power-up or reset, +1 per record
    8       8     time   u64, device time stamp, microseconds since power-up
    16      4     scan   u32, sweep number set by the part program
    20      2     n      u16, points in the profile (0..4096)
    22      2     flags  u16, bit 0: mirror moving backwards (informational)
    24      24    D,E,F  3 x f64, scale readings latched with the profile, mm
    48      4     hcrc   u32, CRC-32 of bytes 0..47
    52      8n    u, v   n x (f32 u, f32 v), scan-plane coordinates, mm
    52+8n   4     crc    u32, CRC-32 of bytes 0..51+8n (the whole frame)

The header CRC lets a reader trust ``n`` before the payload has arrived, so a
corrupted length can never make it wait for or swallow the records behind it;
the frame CRC covers the points. A reader that finds a bad header or frame
searches for the next magic from the byte after the bad one's start, so a cut
record never hides the good record that follows it.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass

import numpy as np

__all__ = [
    "MAGIC",
    "HEADER",
    "HEADER_SIZE",
    "MAX_POINTS",
    "ProfileHeader",
    "encode_profile",
    "decode_header",
    "decode_points",
    "FrameParser",
    "Rejection",
]

MAGIC = b"\xa5\x5aPR"
#: Header fields before the header CRC: magic, seq, time_us, scan, n, flags, D, E, F.
HEADER = struct.Struct("<4sIQIHH3d")
HEADER_SIZE = HEADER.size + 4  # 52 bytes, with the header CRC
_CRC = struct.Struct("<I")
#: Largest number of points accepted in one profile.
MAX_POINTS = 4096
POINT_DTYPE = np.dtype([("u", "<f4"), ("v", "<f4")])


@dataclass(frozen=True)
class ProfileHeader:
    """The header of one profile record.

    Attributes
    ----------
    seq : int
        Sequence number (0 after power-up or reset).
    time_us : int
        Device time stamp, microseconds since power-up.
    scan : int
        Sweep number.
    n : int
        Points in the profile.
    flags : int
        Bit 0: mirror moving backwards.
    scales : tuple of float
        D, E, F scale readings, mm.
    """

    seq: int
    time_us: int
    scan: int
    n: int
    flags: int
    scales: tuple[float, float, float]


def encode_profile(seq: int, time_us: int, scan: int, scales, uv, flags: int = 0) -> bytes:
    """One profile record as bytes.

    Parameters
    ----------
    seq : int
        Sequence number, 0..2**32-1.
    time_us : int
        Device time stamp, microseconds (0..2**64-1).
    scan : int
        Sweep number, 0..2**32-1.
    scales : sequence of 3 float
        D, E, F scale readings, mm.
    uv : array_like, shape (n, 2)
        Scan-plane points u, v, mm (sent as float32).
    flags : int
        Bit 0: mirror moving backwards.

    Returns
    -------
    bytes
        The frame, 56 + 8 n bytes.
    """
    pts = np.ascontiguousarray(uv, dtype="<f4").reshape(-1, 2)
    n = len(pts)
    if n > MAX_POINTS:
        raise ValueError(f"profile of {n} points: at most {MAX_POINTS} per record")
    head = HEADER.pack(MAGIC, seq & 0xFFFFFFFF, time_us, scan, n, flags, *(float(x) for x in scales))
    head += _CRC.pack(zlib.crc32(head))
    body = head + pts.tobytes()
    return body + _CRC.pack(zlib.crc32(body))


def decode_header(frame) -> ProfileHeader:
    """The header of a frame (assumed checked by ``FrameParser``)."""
    _, seq, time_us, scan, n, flags, d, e, f = HEADER.unpack_from(frame, 0)
    return ProfileHeader(seq, time_us, scan, n, flags, (d, e, f))


def decode_points(frame) -> np.ndarray:
    """The (n, 2) float32 u, v points of a frame, mm (a view on ``frame``)."""
    n = struct.unpack_from("<H", frame, 20)[0]
    return np.frombuffer(frame, dtype="<f4", count=2 * n, offset=HEADER_SIZE).reshape(n, 2)


@dataclass(frozen=True)
class Rejection:
    """Bytes the parser could not use.

    Attributes
    ----------
    reason : str
        ``garbage`` (bytes between records that start no record),
        ``header_crc`` (a magic followed by a header failing its CRC),
        ``bad_length`` (a header with more than ``MAX_POINTS`` points),
        ``truncated`` (a record cut short: the next record's magic and valid
        header start inside it), ``crc`` (a whole record failing its CRC).
    nbytes : int
        Bytes skipped.
    offset : int
        Stream offset of the first skipped byte (bytes since the port opened).
    seq : int or None
        The sequence number of the rejected record's header, if it had a valid one.
    """

    reason: str
    nbytes: int
    offset: int
    seq: int | None = None


class FrameParser:
    """Incremental parser: feed bytes, get complete good frames and rejections.

    Resynchronises at the next magic after anything bad; keeps at most one
    incomplete frame of bytes between calls.
    """

    def __init__(self):
        self._buf = bytearray()
        self._offset = 0  # stream offset of _buf[0]
        self._garbage_start: int | None = None
        self._garbage_len = 0

    @property
    def pending(self) -> int:
        """Bytes held waiting for the rest of a frame."""
        return len(self._buf)

    def _skip(self, k: int, out_rej: list) -> None:
        """Drop k bytes that are not part of any frame (garbage)."""
        if k <= 0:
            return
        if self._garbage_start is None:
            self._garbage_start = self._offset
        self._garbage_len += k
        del self._buf[:k]
        self._offset += k

    def _end_garbage(self, out_rej: list) -> None:
        if self._garbage_len:
            out_rej.append(Rejection("garbage", self._garbage_len, self._garbage_start))
            self._garbage_start, self._garbage_len = None, 0

    def feed(self, data: bytes) -> tuple[list[bytes], list[Rejection]]:
        """Add received bytes.

        Parameters
        ----------
        data : bytes
            Bytes as read from the port.

        Returns
        -------
        frames : list of bytes
            Complete frames that passed both CRCs, in stream order.
        rejections : list of Rejection
            What was skipped, in stream order.
        """
        buf = self._buf
        buf += data
        frames: list[bytes] = []
        rej: list[Rejection] = []
        while True:
            k = buf.find(MAGIC)
            if k < 0:
                # keep the last 3 bytes: they may be the start of a magic
                self._skip(len(buf) - (len(MAGIC) - 1), rej)
                break
            self._skip(k, rej)
            if len(buf) < HEADER_SIZE:
                break
            mv = memoryview(buf)
            hcrc = _CRC.unpack_from(buf, HEADER.size)[0]
            ok = zlib.crc32(mv[: HEADER.size]) == hcrc
            n = struct.unpack_from("<H", buf, 20)[0]
            seq = struct.unpack_from("<I", buf, 4)[0]
            mv.release()
            if not ok:
                self._end_garbage(rej)
                rej.append(Rejection("header_crc", 1, self._offset))
                self._drop_one()
                continue
            if n > MAX_POINTS:
                self._end_garbage(rej)
                rej.append(Rejection("bad_length", 1, self._offset, seq))
                self._drop_one()
                continue
            size = HEADER_SIZE + 8 * n + 4
            if len(buf) < size:
                # a record cut short shows itself as a good header inside the wait
                nxt, _ = self._next_good_header(1, len(buf))
                if nxt is None:
                    break
                self._end_garbage(rej)
                rej.append(Rejection("truncated", nxt, self._offset, seq))
                del buf[:nxt]
                self._offset += nxt
                continue
            mv = memoryview(buf)
            good = zlib.crc32(mv[: size - 4]) == _CRC.unpack_from(buf, size - 4)[0]
            mv.release()
            if good:
                self._end_garbage(rej)
                frames.append(bytes(buf[:size]))
                del buf[:size]
                self._offset += size
                continue
            nxt, incomplete = self._next_good_header(1, size)
            if nxt is None and incomplete:
                break  # a magic near the end whose header has not all arrived: wait
            self._end_garbage(rej)
            if nxt is not None:
                rej.append(Rejection("truncated", nxt, self._offset, seq))
                del buf[:nxt]
                self._offset += nxt
            else:
                rej.append(Rejection("crc", size, self._offset, seq))
                del buf[:size]
                self._offset += size
        return frames, rej

    def _drop_one(self) -> None:
        del self._buf[:1]
        self._offset += 1

    def _next_good_header(self, start: int, stop: int) -> tuple[int | None, bool]:
        """(index of the first magic in buf[start:stop] followed by a header
        that passes its CRC, or None; whether a magic there still lacks part
        of its header)."""
        buf = self._buf
        k = start
        while True:
            k = buf.find(MAGIC, k, stop + len(MAGIC) - 1)
            if k < 0 or k >= stop:
                return None, False
            if k + HEADER_SIZE > len(buf):
                return None, True
            mv = memoryview(buf)
            ok = zlib.crc32(mv[k : k + HEADER.size]) == _CRC.unpack_from(buf, k + HEADER.size)[0]
            mv.release()
            if ok:
                return k, False
            k += 1

    def flush(self) -> list[Rejection]:
        """End of stream (port closed): whatever is held is a rejected partial record."""
        rej: list[Rejection] = []
        self._end_garbage(rej)
        if self._buf:
            seq = struct.unpack_from("<I", self._buf, 4)[0] if len(self._buf) >= 8 and self._buf.startswith(MAGIC) else None
            rej.append(Rejection("truncated" if seq is not None else "garbage", len(self._buf), self._offset, seq))
            self._offset += len(self._buf)
            self._buf.clear()
        return rej
