"""Smoke test of the ARM image in QEMU: the EVK1000 firmware, built for QEMU's
`stm32vldiscovery` machine (`make firmware-qemu`), answers PING and GET_INFO on USART1,
which QEMU exposes as a TCP socket that pyserial opens as ``socket://``.

What this exercises of the real image: the startup code, the vector table, the clock
bring-up timing out and falling back to HSI (QEMU's RCC never reports ready), SysTick time,
the USART1 link with its RX interrupt and ring buffer, framing, dispatch and the station
loop, all compiled by arm-none-eabi-gcc for the Cortex-M3. Not exercised: the DW1000 (QEMU
has no SPI slave for it, DEV_ID reads 0), the flash driver (QEMU's flash interface is a
placeholder), the 72 MHz clock tree, the real UID.

Not in `make test` (pyproject's testpaths): run `pytest tests/qemu`. Skips with the reason
when qemu-system-arm or arm-none-eabi-gcc is missing (Debian: qemu-system-arm,
gcc-arm-none-eabi libnewlib-arm-none-eabi), or when the firmware's static RAM no longer fits
the machine's 8 KB (the link of `make firmware-qemu` overflows): see
firmware/boards/qemu/README.md. UWBCAL_QEMU_IMAGE=path.elf runs a prebuilt image instead.
"""

from __future__ import annotations

import os
import shutil
import socket
import struct
import subprocess
import time
import zlib
from collections.abc import Iterator
from pathlib import Path

import pytest
import serial
from cobs import cobs
from uwbcal.link import proto_gen as pg

REPO = Path(__file__).resolve().parents[2]
IMAGE = REPO / "build/qemu/uwbcal-qemu.elf"
BOOT_TIMEOUT_S = 30.0
"""Wall-clock bound for the firmware to answer its first PING (QEMU boot plus the clock
code's bounded waits, which all time out in QEMU)."""

pytestmark = [
    pytest.mark.skipif(shutil.which("qemu-system-arm") is None,
                       reason="qemu-system-arm not installed (Debian package qemu-system-arm)"),
    pytest.mark.skipif(shutil.which("arm-none-eabi-gcc") is None,
                       reason="arm-none-eabi-gcc not installed (run tools/bootstrap.sh)"),
]


def encode_frame(msg_type: int, seq: int, payload: bytes = b"") -> bytes:
    """header | payload | CRC-32/ISO-HDLC (little-endian), COBS-encoded, 0x00-terminated."""
    raw = pg.HEADER.pack(pg.PROTOCOL_VERSION, msg_type, 0, seq) + payload
    raw += struct.pack("<I", zlib.crc32(raw))
    return bytes(cobs.encode(raw)) + b"\x00"


def decode_frame(wire: bytes) -> tuple[int, int, int, bytes]:
    """(type, flags, seq, payload) of one frame without its delimiter; checks the CRC."""
    raw = cobs.decode(wire)
    body, crc = raw[:-4], struct.unpack("<I", raw[-4:])[0]
    assert zlib.crc32(body) == crc, "CRC mismatch in a frame from the firmware"
    version, msg_type, flags, seq = pg.HEADER.unpack_from(body)
    assert version == pg.PROTOCOL_VERSION
    return msg_type, flags, seq, body[pg.HEADER_SIZE:]


class Station:
    """The QEMU station's host link, through pyserial's socket:// transport."""

    def __init__(self, url: str) -> None:
        self.port = serial.serial_for_url(url, timeout=0.1)
        self.buf = b""

    def request(self, msg_type: int, seq: int, payload: bytes = b"",
                timeout_s: float = 2.0) -> tuple[int, int, int, bytes] | None:
        """Send one request; the first frame answering ``seq``, or None on timeout."""
        self.port.write(encode_frame(msg_type, seq, payload))
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            self.buf += self.port.read(256)
            while b"\x00" in self.buf:
                wire, self.buf = self.buf.split(b"\x00", 1)
                if not wire:
                    continue
                frame = decode_frame(wire)
                if frame[2] == seq:
                    return frame
        return None

    def write_raw(self, data: bytes) -> None:
        self.port.write(data)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def build_image() -> Path:
    """The image to run: UWBCAL_QEMU_IMAGE, or `make firmware-qemu`'s output."""
    prebuilt = os.environ.get("UWBCAL_QEMU_IMAGE")
    if prebuilt:
        return Path(prebuilt)
    build = subprocess.run(["make", "-s", "firmware-qemu"], cwd=REPO, capture_output=True, text=True)
    if build.returncode != 0:
        out = build.stdout + build.stderr
        if "region `RAM' overflowed" in out or "over the size bars" in out:
            why = next((ln.strip() for ln in out.splitlines() if "overflowed" in ln), "")
            pytest.skip("the firmware's static RAM does not fit QEMU stm32vldiscovery's 8 KB "
                        f"({why.rsplit(': ', 1)[-1]}; see firmware/boards/qemu/README.md)")
        pytest.fail(f"make firmware-qemu failed:\n{out}")
    return IMAGE


@pytest.fixture(scope="module")
def station() -> Iterator[Station]:
    image = build_image()
    port = free_port()
    qemu = subprocess.Popen(
        ["qemu-system-arm", "-M", "stm32vldiscovery", "-nographic", "-monitor", "none",
         "-serial", f"tcp:127.0.0.1:{port},server=on,wait=on", "-kernel", str(image)],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
    )
    try:
        deadline = time.monotonic() + 10.0
        st: Station | None = None
        while st is None:
            try:
                st = Station(f"socket://127.0.0.1:{port}")
            except serial.SerialException:
                if time.monotonic() > deadline or qemu.poll() is not None:
                    raise
                time.sleep(0.1)
        # The USART drops bytes until the firmware has enabled it: ping until it answers.
        boot_deadline = time.monotonic() + BOOT_TIMEOUT_S
        seq = 1
        while st.request(pg.T_PING, seq, b"boot", timeout_s=0.5) is None:
            assert time.monotonic() < boot_deadline, "the QEMU station never answered PING"
            st.write_raw(b"\x00")  # resynchronise after a partly dropped frame
            seq += 1
        yield st
        st.port.close()
    finally:
        qemu.kill()
        qemu.wait(timeout=10)


def test_ping_echoes_data(station: Station) -> None:
    frame = station.request(pg.T_PING, 100, b"\x00\x01uwbcal\xff")
    assert frame is not None
    msg_type, flags, _, payload = frame
    assert msg_type == pg.T_PING and flags & pg.FLAG_RESPONSE
    assert pg.PingResp.decode(payload).data == b"\x00\x01uwbcal\xff"


def test_get_info(station: Station) -> None:
    frame = station.request(pg.T_GET_INFO, 101)
    assert frame is not None and frame[0] == pg.T_GET_INFO
    info = pg.GetInfoResp.decode(frame[3])
    assert info.protocol_version == pg.PROTOCOL_VERSION
    assert info.board == "evk1000-qemu"
    assert info.uid == b"QEMUQEMU\x00\x00\x00\x01"
    assert info.dev_id == 0  # no DW1000 behind QEMU's SPI1
    assert info.max_payload == pg.MAX_PAYLOAD


def test_garbage_then_normal_answer(station: Station) -> None:
    station.write_raw(bytes(range(1, 200)) + b"\x00\xff\xfe\x00")
    frame = station.request(pg.T_PING, 102, b"after garbage", timeout_s=5.0)
    assert frame is not None and frame[0] == pg.T_PING
    assert pg.PingResp.decode(frame[3]).data == b"after garbage"
