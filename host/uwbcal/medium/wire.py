"""Frames of the station<->medium tunnel (protocol/messages/tunnel.toml), tuned for speed.

The frame format is the project's one format (protocol/protocol.toml): COBS(header | payload |
crc32) 0x00 with header = version u8, type u8, flags u8, seq u16 little-endian and the CRC
CRC-32/ISO-HDLC (the same polynomial and reflection as :func:`zlib.crc32`). The medium handles
millions of tunnel frames per session, so this module decodes them with the C ``cobs`` and
``zlib`` routines and ``struct``, without the generic message machinery of uwbcal.link.

Every number here (version, flags, message types, error codes, wait-mode bits, field layouts,
the snapshot block) is taken from the generated :mod:`uwbcal.link.proto_gen`; nothing is
written by hand (tests/unit/test_one_definition.py fails the build if a literal copy returns).
"""

from __future__ import annotations

import struct
import zlib
from typing import Final

from cobs import cobs

from uwbcal.link import proto_gen as pg

PROTOCOL_VERSION: Final = pg.PROTOCOL_VERSION
FLAG_RESPONSE: Final = pg.FLAG_RESPONSE
HEADER: Final = pg.HEADER

# Message types (tunnel.toml, range 0x40-0x4F) and ERROR.
TUN_HELLO: Final = pg.T_TUN_HELLO
TUN_SPI_WRITE: Final = pg.T_TUN_SPI_WRITE
TUN_SPI_READ: Final = pg.T_TUN_SPI_READ
TUN_WAIT: Final = pg.T_TUN_WAIT
TUN_RESET: Final = pg.T_TUN_RESET
TUN_CANCEL: Final = pg.T_TUN_CANCEL
ERROR: Final = pg.T_ERROR

#: Wait mode bits of tun_wait (the tun_wait_mode enum).
MODE_IDLE: Final = pg.TUN_WAIT_MODE_IDLE
MODE_IGNORE_IRQ: Final = pg.TUN_WAIT_MODE_IGNORE_IRQ
MODE_SNAPSHOT: Final = pg.TUN_WAIT_MODE_SNAPSHOT
MODE_SNAPSHOT_TIME: Final = pg.TUN_WAIT_MODE_SNAPSHOT_TIME
#: Head of one block of a tun_wait snapshot: register file id, offset, byte count (then the bytes).
SNAP_BLOCK: Final = pg.TunSnapBlock._S

# Fixed parts of the tunnel payloads, from the generated codecs.
HELLO_REQ: Final = pg.TunHelloReq._S
U64: Final = pg.TunHelloResp._S
WAIT_REQ: Final = pg.TunWaitReq._S
WAIT_RESP: Final = pg.TunWaitResp._S
READ_REQ_LEN: Final = pg.TunSpiReadReq._S
ERROR_RESP: Final = pg.ErrorResp._S

_CRC: Final = struct.Struct("<I")  # the CRC trailer: u32 little-endian
assert _CRC.size == pg.CRC_SIZE


class FrameError(Exception):
    """A tunnel frame could not be decoded (bad COBS, CRC, version or length)."""

    def __init__(self, code: int, msg: str) -> None:
        super().__init__(msg)
        self.code = code


def encode(mtype: int, seq: int, payload: bytes, flags: int = 0) -> bytes:
    """One frame on the wire, delimiter included."""
    body = HEADER.pack(PROTOCOL_VERSION, mtype, flags, seq & 0xFFFF) + payload
    return bytes(cobs.encode(body + _CRC.pack(zlib.crc32(body)))) + b"\x00"


def decode(chunk: bytes) -> tuple[int, int, int, bytes]:
    """(type, flags, seq, payload) of one COBS-encoded frame without its delimiter."""
    try:
        raw = cobs.decode(chunk)
    except cobs.DecodeError as exc:
        raise FrameError(pg.ERR_BAD_COBS, f"bad COBS: {exc}") from exc
    if len(raw) < HEADER.size + _CRC.size:
        raise FrameError(pg.ERR_TOO_SHORT, f"frame of {len(raw)} bytes is too short")
    body = raw[:-_CRC.size]
    if zlib.crc32(body) != _CRC.unpack_from(raw, len(body))[0]:
        raise FrameError(pg.ERR_BAD_CRC, "CRC mismatch")
    version, mtype, flags, seq = HEADER.unpack_from(body)
    if version != PROTOCOL_VERSION:
        raise FrameError(pg.ERR_BAD_VERSION, f"protocol version {version}")
    return mtype, flags, seq, bytes(body[HEADER.size:])


def response(mtype: int, seq: int, payload: bytes) -> bytes:
    """The response frame to request (mtype, seq)."""
    return encode(mtype, seq, payload, FLAG_RESPONSE)


def error_frame(seq: int, code: int, request_type: int, detail: int = pg.DETAIL_NONE) -> bytes:
    """An ERROR answer to a request."""
    return encode(ERROR, seq, ERROR_RESP.pack(code, request_type, detail & 0xFFFF), FLAG_RESPONSE)


def parse_snapshot(snap: bytes) -> list[tuple[int, int, bytes]]:
    """The blocks (register id, offset, bytes) of a tun_wait snapshot (mode bit2)."""
    out: list[tuple[int, int, bytes]] = []
    o = 0
    while o + SNAP_BLOCK.size <= len(snap):
        rid, off, n = SNAP_BLOCK.unpack_from(snap, o)
        o += SNAP_BLOCK.size
        if o + n > len(snap):
            raise FrameError(pg.ERR_BAD_LENGTH, "snapshot block runs past the end")
        out.append((rid, off, bytes(snap[o:o + n])))
        o += n
    return out
