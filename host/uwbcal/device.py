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

    # ---- measurement (protocol/messages/measurement.toml) ----------------------------------
    def radio_config(self, channel: int = 2, prf_mhz: int = 64, preamble_len: int = 128,
                     data_rate: int = 2, preamble_code: int = 0, tx_antd: int = 16436,
                     rx_antd: int = 16436) -> pg.RadioConfigResp:
        """Configure the DW1000 (default: the paper's settings); returns DEV_ID and the station id."""
        return self.call(pg.RadioConfigReq(channel=channel, prf_mhz=prf_mhz, preamble_len=preamble_len,
                                           data_rate=data_rate, preamble_code=preamble_code,
                                           tx_antd=tx_antd, rx_antd=rx_antd))

    def listen(self, role: int, peer: int = 0xFFFF, reply_us: int = 0) -> None:
        """Receive triplets (role 0, streamed) or act as ranging tag (role 1) for ``peer``."""
        self.call(pg.ListenReq(role=role, peer=peer, reply_us=reply_us))

    def seq_start(self, per_step: int, spacing_us: int, period_us: int, gain13: int, gains2: bytes) -> int:
        """Start a P1/P2/P3 plan; returns the number of triplets it will send."""
        return self.call(pg.SeqStartReq(per_step=per_step, spacing_us=spacing_us, period_us=period_us,
                                        gain13=gain13, gains2=gains2)).total

    def range_start(self, method: int, tag: int, count: int, period_us: int, reply_us: int,
                    gain: int) -> None:
        """Reference role: run ``count`` ranging exchanges with station ``tag``."""
        self.call(pg.RangeStartReq(method=method, tag=tag, count=count, period_us=period_us,
                                   reply_us=reply_us, gain=gain))

    def stop(self) -> pg.StopResp:
        """Stop whatever runs; returns the counters."""
        return self.call(pg.StopReq())

    def status(self) -> pg.StatusResp:
        """What runs and its counters."""
        return self.call(pg.StatusReq())
