"""Frames of the station<->medium tunnel (protocol/messages/tunnel.toml), tuned for speed.

The frame format is the project's one format (protocol/protocol.toml): COBS(header | payload |
crc32) 0x00 with header = version u8, type u8, flags u8, seq u16 little-endian and the CRC
CRC-32/ISO-HDLC (the same polynomial and reflection as :func:`zlib.crc32`). The medium handles
millions of tunnel frames per session, so this module decodes them with the C ``cobs`` and
``zlib`` routines and ``struct``, without the generic message machinery of uwbcal.link.

Message type numbers and field layouts are the tunnel.toml ones; :func:`check_against_toml`
(run by the unit tests) fails if this module and the toml disagree.
"""

from __future__ import annotations

import struct
import tomllib
import zlib
from pathlib import Path
from typing import Final

from cobs import cobs

PROTOCOL_VERSION: Final = 1
FLAG_RESPONSE: Final = 0x01
HEADER: Final = struct.Struct("<BBBH")

# Message types (protocol/messages/tunnel.toml, range 0x40-0x4F) and ERROR (0x7F).
TUN_HELLO: Final = 0x40
TUN_SPI_WRITE: Final = 0x41
TUN_SPI_READ: Final = 0x42
TUN_WAIT: Final = 0x43
TUN_RESET: Final = 0x44
TUN_CANCEL: Final = 0x45
ERROR: Final = 0x7F

# Error codes (protocol/protocol.toml [errors]).
ERR_BAD_CRC: Final = 2
ERR_BAD_VERSION: Final = 5
ERR_UNKNOWN_TYPE: Final = 6
ERR_BAD_LENGTH: Final = 7
ERR_BAD_VALUE: Final = 8

#: Wait mode bits of tun_wait.
MODE_IDLE: Final = 0x01
MODE_IGNORE_IRQ: Final = 0x02
MODE_SNAPSHOT: Final = 0x04
MODE_SNAPSHOT_TIME: Final = 0x08
#: One block of a tun_wait snapshot: register file id, offset, byte count (then the bytes).
SNAP_BLOCK: Final = struct.Struct("<BHB")

HELLO_REQ: Final = struct.Struct("<H12s")
U64: Final = struct.Struct("<Q")
WAIT_REQ: Final = struct.Struct("<QB")
WAIT_RESP: Final = struct.Struct("<QB")
READ_REQ_LEN: Final = struct.Struct("<H")
ERROR_RESP: Final = struct.Struct("<BBH")

_CRC: Final = struct.Struct("<I")


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
        raise FrameError(1, f"bad COBS: {exc}") from exc
    if len(raw) < HEADER.size + 4:
        raise FrameError(4, f"frame of {len(raw)} bytes is too short")
    body = raw[:-4]
    if zlib.crc32(body) != _CRC.unpack_from(raw, len(raw) - 4)[0]:
        raise FrameError(ERR_BAD_CRC, "CRC mismatch")
    version, mtype, flags, seq = HEADER.unpack_from(body)
    if version != PROTOCOL_VERSION:
        raise FrameError(ERR_BAD_VERSION, f"protocol version {version}")
    return mtype, flags, seq, bytes(body[HEADER.size:])


def response(mtype: int, seq: int, payload: bytes) -> bytes:
    """The response frame to request (mtype, seq)."""
    return encode(mtype, seq, payload, FLAG_RESPONSE)


def error_frame(seq: int, code: int, request_type: int, detail: int = 0xFFFF) -> bytes:
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
            raise FrameError(ERR_BAD_LENGTH, "snapshot block runs past the end")
        out.append((rid, off, bytes(snap[o:o + n])))
        o += n
    return out


def check_against_toml(root: Path) -> list[str]:
    """Differences between this module's constants and protocol/messages/tunnel.toml.

    ``root`` is the repository root. Returns human-readable mismatches (empty when in sync).
    """
    doc = tomllib.loads((root / "protocol" / "messages" / "tunnel.toml").read_text())
    want = {"tun_hello": TUN_HELLO, "tun_spi_write": TUN_SPI_WRITE, "tun_spi_read": TUN_SPI_READ,
            "tun_wait": TUN_WAIT, "tun_reset": TUN_RESET, "tun_cancel": TUN_CANCEL}
    layouts = {
        "tun_hello": (["u16", "bytes[12]"], ["u64"]),
        "tun_spi_write": (["u8", "tail"], []),
        "tun_spi_read": (["u16", "tail"], ["tail"]),
        "tun_wait": (["u64", "u8"], ["u64", "u8", "tail"]),
        "tun_reset": ([], []),
        "tun_cancel": ([], []),
    }
    bad: list[str] = []
    seen = {m["name"]: m for m in doc["message"]}
    for name, mtype in want.items():
        m = seen.get(name)
        if m is None:
            bad.append(f"{name} missing from tunnel.toml")
            continue
        if m["type"] != mtype:
            bad.append(f"{name}: type {m['type']:#x} in toml, {mtype:#x} here")
        req = [f["type"] for f in m.get("request", [])]
        resp = [f["type"] for f in m.get("response", [])]
        if (req, resp) != layouts[name]:
            bad.append(f"{name}: layout {req}/{resp} in toml, {layouts[name]} here")
    for name in seen:
        if name not in want:
            bad.append(f"{name} in tunnel.toml is not handled by the medium")
    return bad
