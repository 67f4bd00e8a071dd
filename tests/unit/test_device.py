"""Device: typed calls, GET_INFO parsing, protocol-version check, PING echo check."""

from __future__ import annotations

import pytest
from test_link_client import FakeTransport, answer
from uwbcal.device import Device
from uwbcal.errors import ProtocolError
from uwbcal.link import proto_gen as pg
from uwbcal.link.client import Client
from uwbcal.link.framing import Frame

UID = bytes(range(0x10, 0x1C))


def station(protocol_version: int = pg.PROTOCOL_VERSION, corrupt_echo: bool = False):  # type: ignore[no-untyped-def]
    def h(req: Frame) -> list[bytes]:
        if req.type == pg.T_GET_INFO:
            r = pg.GetInfoResp(
                protocol_version=protocol_version,
                fw_major=0,
                fw_minor=1,
                fw_patch=2,
                git_hash="abcdef012345",
                board="evk1000",
                dev_id=0xDECA0130,
                uid=UID,
                max_payload=512,
            )
            return [answer(req, r.encode())]
        if req.type == pg.T_PING:
            return [answer(req, req.payload + (b"!" if corrupt_echo else b""))]
        return [answer(req)]

    return h


def device(**kw: object) -> Device:
    return Device(Client(FakeTransport(station(**kw)), timeout=0.05))  # type: ignore[arg-type]


def test_info() -> None:
    info = device().info()
    assert (info.board, info.firmware, info.git_hash, info.uid, info.max_payload) == (
        "evk1000",
        "0.1.2",
        "abcdef012345",
        UID,
        512,
    )
    assert info.radio_ok and info.uid_hex == UID.hex()
    d = info.as_dict()
    assert d["dev_id"] == "0xDECA0130" and d["uid"] == UID.hex() and d["port"] == "fake://station"


def test_info_protocol_mismatch() -> None:
    with pytest.raises(ProtocolError, match="protocol version 9"):
        device(protocol_version=9).info()


def test_ping_and_bad_echo() -> None:
    device().ping(b"\x00\x01")
    with pytest.raises(ProtocolError, match="echo differs"):
        device(corrupt_echo=True).ping(b"abc")


def test_call_is_typed() -> None:
    r = device().call(pg.ResetReq())
    assert isinstance(r, pg.ResetResp)
