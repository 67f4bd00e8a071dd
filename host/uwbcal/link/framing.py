"""Frames on the wire: ``COBS(header | payload | crc32) 0x00`` (protocol/PROTOCOL.md).

COBS comes from the ``cobs`` package, the CRC (CRC-32/ISO-HDLC) from ``crcmod``'s predefined
catalogue; the header layout and limits from the generated :mod:`uwbcal.link.proto_gen`.
:class:`FrameDecoder` classifies bad input exactly as the firmware does (same error code and
detail), which protocol/vectors.json checks for both.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import crcmod.predefined
from cobs import cobs

from uwbcal.link import proto_gen as pg

#: CRC-32/ISO-HDLC of a byte string (``crcmod`` catalogue name ``crc-32``).
crc32 = crcmod.predefined.mkCrcFun(pg.CRC_CRCMOD)
#: Longest encoded frame, delimiter excluded (COBS adds at most 1 byte per 254, plus 1).
WIRE_MAX = pg.FRAME_MAX + pg.FRAME_MAX // 254 + 1
_CRC = struct.Struct("<I")


@dataclass(frozen=True)
class Frame:
    """One decoded frame: header fields and payload."""

    type: int
    seq: int
    flags: int = 0
    payload: bytes = b""
    version: int = pg.PROTOCOL_VERSION

    @property
    def is_response(self) -> bool:
        return bool(self.flags & pg.FLAG_RESPONSE)

    @property
    def is_stream(self) -> bool:
        return bool(self.flags & pg.FLAG_STREAM)


@dataclass(frozen=True)
class FrameError:
    """A rejected frame: ``code`` is a protocol error code (bad_cobs, bad_crc, too_long,
    too_short), ``detail`` as the firmware would report it."""

    code: int
    detail: int

    @property
    def name(self) -> str:
        return pg.ERROR_NAMES.get(self.code, f"error {self.code}")


def raw_frame(frame: Frame) -> bytes:
    """header | payload | crc (not COBS-encoded)."""
    if len(frame.payload) > pg.MAX_PAYLOAD:
        raise ValueError(f"payload of {len(frame.payload)} bytes exceeds {pg.MAX_PAYLOAD}")
    body = pg.HEADER.pack(frame.version, frame.type, frame.flags, frame.seq) + frame.payload
    return body + _CRC.pack(crc32(body))


def encode_frame(frame: Frame) -> bytes:
    """The frame on the wire: COBS-encoded, with its trailing 0x00 delimiter."""
    return bytes(cobs.encode(raw_frame(frame))) + b"\x00"


def cobs_error_offset(data: bytes) -> int | None:
    """Offset of the byte that makes ``data`` invalid COBS (as firmware/core/cobs.c), or None."""
    i = 0
    n = len(data)
    while i < n:
        code = data[i]
        if code == 0 or i + code > n:
            return i
        z = data.find(0, i + 1, i + code)
        if z >= 0:
            return z
        i += code
    return None


def decode_frame(encoded: bytes) -> Frame | FrameError:
    """Decode one frame (delimiter excluded, non-empty) or say why it is rejected."""
    n = len(encoded)
    sat = min(n, 0xFFFF)
    if n > WIRE_MAX:
        return FrameError(pg.ERR_TOO_LONG, sat)
    off = cobs_error_offset(encoded)
    if off is not None:
        return FrameError(pg.ERR_BAD_COBS, off)
    raw = bytes(cobs.decode(encoded))
    if len(raw) > pg.FRAME_MAX:
        return FrameError(pg.ERR_TOO_LONG, sat)
    if len(raw) < pg.HEADER_SIZE + pg.CRC_SIZE:
        return FrameError(pg.ERR_TOO_SHORT, len(raw))
    body = raw[: -pg.CRC_SIZE]
    if crc32(body) != _CRC.unpack_from(raw, len(body))[0]:
        return FrameError(pg.ERR_BAD_CRC, pg.DETAIL_NONE)
    version, type_, flags, seq = pg.HEADER.unpack_from(body, 0)
    return Frame(type=type_, seq=seq, flags=flags, payload=body[pg.HEADER_SIZE :], version=version)


class FrameDecoder:
    """Streaming decoder: bytes in, frames (or frame errors) out. Garbage resynchronises at
    the next 0x00; an overlong frame is dropped and reported once; empty frames are skipped."""

    def __init__(self) -> None:
        self._buf = bytearray()
        self._count = 0

    def feed(self, data: bytes) -> list[Frame | FrameError]:
        out: list[Frame | FrameError] = []
        start = 0
        while True:
            z = data.find(0, start)
            chunk = data[start:] if z < 0 else data[start:z]
            self._count += len(chunk)
            room = WIRE_MAX + 1 - len(self._buf)
            if room > 0:
                self._buf += chunk[:room]
            if z < 0:
                return out
            if self._count:
                if self._count > WIRE_MAX:
                    out.append(FrameError(pg.ERR_TOO_LONG, min(self._count, 0xFFFF)))
                else:
                    out.append(decode_frame(bytes(self._buf)))
            self._buf.clear()
            self._count = 0
            start = z + 1
