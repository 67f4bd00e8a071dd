"""protocol/vectors.json through the Python side: every CRC, COBS, frame and malformed vector
(the C tests compile the same file: tests/firmware/vectors_gen.h)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import pytest
from cobs import cobs
from uwbcal.link import proto_gen as pg
from uwbcal.link.framing import (
    Frame,
    FrameDecoder,
    FrameError,
    cobs_error_offset,
    crc32,
    decode_frame,
    encode_frame,
    raw_frame,
)

VECTORS = json.loads((Path(__file__).resolve().parents[2] / "protocol" / "vectors.json").read_text())
FRAME_LEVEL = {pg.ERR_BAD_COBS, pg.ERR_BAD_CRC, pg.ERR_TOO_LONG, pg.ERR_TOO_SHORT}


def as_json(value: Any) -> Any:
    """A decoded value in the vectors' notation: bytes as hex, tuples as lists, structs as dicts."""
    if isinstance(value, bytes):
        return value.hex()
    if isinstance(value, tuple):
        return [as_json(v) for v in value]
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: as_json(getattr(value, f.name)) for f in dataclasses.fields(value)}
    return value


def test_vector_file_is_complete() -> None:
    assert len(VECTORS["crc"]) >= 2 and len(VECTORS["cobs"]) >= 10
    assert len(VECTORS["frames"]) >= 10 and len(VECTORS["malformed"]) >= 10
    names = {pg.ERROR_NAMES[c] for c in FRAME_LEVEL} | {
        "bad_version",
        "unknown_type",
        "bad_length",
        "bad_flags",
    }
    assert names <= {m["error"]["code"] for m in VECTORS["malformed"]}


def test_crc_check_value() -> None:
    assert crc32(b"123456789") == pg.CRC_CHECK == 0xCBF43926


@pytest.mark.parametrize("vec", VECTORS["crc"], ids=lambda v: v["name"])
def test_crc(vec: dict[str, Any]) -> None:
    assert crc32(bytes.fromhex(vec["data"])) == int(vec["crc"], 16)


@pytest.mark.parametrize("vec", VECTORS["cobs"], ids=lambda v: v["name"])
def test_cobs(vec: dict[str, Any]) -> None:
    dec, enc = bytes.fromhex(vec["decoded"]), bytes.fromhex(vec["encoded"])
    assert cobs.encode(dec) == enc
    assert cobs.decode(enc) == dec
    assert cobs_error_offset(enc) is None
    assert 0 not in enc


@pytest.mark.parametrize("vec", VECTORS["frames"], ids=lambda v: v["name"])
def test_frame(vec: dict[str, Any]) -> None:
    wire = bytes.fromhex(vec["wire"])
    assert wire.endswith(b"\x00") and wire.count(0) == 1
    f = decode_frame(wire[:-1])
    assert isinstance(f, Frame)
    h = vec["header"]
    assert (f.version, f.type, f.flags, f.seq) == (h["version"], h["type"], h["flags"], h["seq"])
    assert f.payload.hex() == vec["payload"]
    assert raw_frame(f).hex() == vec["raw"]
    assert encode_frame(f) == wire
    assert bytes.fromhex(vec["raw"])[-4:] == int(vec["crc"], 16).to_bytes(4, "little")
    table = pg.REQUESTS if vec["direction"] == "request" else pg.RESPONSES
    cls = table[f.type]
    assert cls.NAME == vec["message"]
    msg = cls.decode(f.payload)
    assert as_json(msg) == vec["fields"]
    assert msg.encode() == f.payload
    # byte by byte through the streaming decoder gives the same frame
    dec = FrameDecoder()
    items = [x for b in wire for x in dec.feed(bytes([b]))]
    assert items == [f]


@pytest.mark.parametrize("vec", VECTORS["malformed"], ids=lambda v: v["name"])
def test_malformed(vec: dict[str, Any]) -> None:
    err = vec["error"]
    code = next(c for c, n in pg.ERROR_NAMES.items() if n == err["code"])
    items = FrameDecoder().feed(bytes.fromhex(vec["wire"]))
    assert len(items) == 1
    if code in FRAME_LEVEL:
        assert items[0] == FrameError(code, err["detail"])
        assert err["seq"] == 0 and err["request_type"] == 0
    else:
        req = items[0]
        assert isinstance(req, Frame)
        assert (req.seq, req.type) == (err["seq"], err["request_type"])
    # the expected answer is an ERROR frame naming the code, the request type and the detail
    resp = decode_frame(bytes.fromhex(vec["response"])[:-1])
    assert isinstance(resp, Frame)
    assert (resp.type, resp.flags, resp.seq) == (pg.T_ERROR, pg.FLAG_RESPONSE, err["seq"])
    e = pg.ErrorResp.decode(resp.payload)
    assert (e.code, e.request_type, e.detail) == (code, err["request_type"], err["detail"])
