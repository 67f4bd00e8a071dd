"""The typed API of one station (an EVK1000 board or a simulated station on a pty).

    with Device.open("/dev/ttyACM0") as dev:
        info = dev.info()

Measurement and calibration-table methods are added by their modules; everything goes through
:meth:`Device.call`, which sends a generated request dataclass and returns its response.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, TypeVar

from uwbcal.dw1000 import DEV_ID
from uwbcal.errors import DeviceTimeout, ProtocolError
from uwbcal.link import proto_gen as pg
from uwbcal.link.client import DEFAULT_RETRIES, DEFAULT_TIMEOUT_S, Client
from uwbcal.link.transport import Transport

R = TypeVar("R", bound=pg.Message)


@dataclass(frozen=True)
class DeviceInfo:
    """What GET_INFO says about a station."""

    port: str
    protocol_version: int
    firmware: str  # "major.minor.patch"
    git_hash: str
    board: str
    dev_id: int  # DW1000 DEV_ID register, 0 when no radio answers
    uid: bytes  # 96-bit MCU unique id
    max_payload: int  # bytes

    @property
    def uid_hex(self) -> str:
        return self.uid.hex()

    @property
    def radio_ok(self) -> bool:
        """True when the DW1000 answered with its DEV_ID."""
        return self.dev_id == DEV_ID

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready form (uid as hex, dev_id as 0x-hex)."""
        return {
            "port": self.port,
            "protocol_version": self.protocol_version,
            "firmware": self.firmware,
            "git_hash": self.git_hash,
            "board": self.board,
            "dev_id": f"0x{self.dev_id:08X}",
            "radio_ok": self.radio_ok,
            "uid": self.uid_hex,
            "max_payload": self.max_payload,
        }


class Device:
    """One station behind one link."""

    def __init__(self, client: Client) -> None:
        self.client = client
        self.port = client.port

    @classmethod
    def open(cls, port: str, *, timeout: float = DEFAULT_TIMEOUT_S, retries: int = DEFAULT_RETRIES) -> Device:
        """Open a port (LinkError naming it if that fails). Nothing is sent yet."""
        return cls(Client(Transport(port), timeout=timeout, retries=retries))

    def close(self) -> None:
        self.client.close()

    def __enter__(self) -> Device:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def call(self, req: pg.Request[R], *, timeout: float | None = None, retries: int | None = None) -> R:
        """Send any request and return its typed response (ErrorResponse on ERROR)."""
        return self.client.request(req, timeout=timeout, retries=retries)

    def ping(self, data: bytes = b"", *, timeout: float | None = None, retries: int | None = None) -> None:
        """Liveness check; ProtocolError if the echo differs."""
        resp = self.call(pg.PingReq(data=data), timeout=timeout, retries=retries)
        if resp.data != data:
            raise ProtocolError(
                f"{self.port}: PING echo differs ({len(resp.data)} bytes back, {len(data)} sent)"
            )

    def info(self) -> DeviceInfo:
        """GET_INFO; ProtocolError if the firmware speaks another protocol version."""
        r = self.call(pg.GetInfoReq())
        if r.protocol_version != pg.PROTOCOL_VERSION:
            raise ProtocolError(
                f"{self.port}: firmware speaks protocol version {r.protocol_version}, "
                f"this host version {pg.PROTOCOL_VERSION}: update one of them"
            )
        return DeviceInfo(
            port=self.port,
            protocol_version=r.protocol_version,
            firmware=f"{r.fw_major}.{r.fw_minor}.{r.fw_patch}",
            git_hash=r.git_hash,
            board=r.board,
            dev_id=r.dev_id,
            uid=r.uid,
            max_payload=r.max_payload,
        )

    def reset(self, *, wait_s: float = 5.0) -> None:
        """RESET, then wait (at most ``wait_s`` seconds) until the station answers PING again."""
        self.call(pg.ResetReq())
        deadline = time.monotonic() + wait_s
        while True:
            try:
                self.ping(timeout=0.2, retries=0)
                return
            except DeviceTimeout:
                if time.monotonic() >= deadline:
                    raise DeviceTimeout(f"{self.port}: no answer within {wait_s:g} s after RESET") from None
