"""The EVK1000's USB CDC-ACM link: the real driver (firmware/boards/evk1000/usb, built for the
host as build/usbhosted/libevkusb.so) against the OTG FS model, enumerated and used the way
Linux does it. Device time is virtual; nothing here depends on wall-clock time.

What these tests cannot see: the ARM image itself (startup, clocks, NVIC, interrupt timing),
a real PHY and a real host controller. The model is ours; the descriptors are checked with an
independent parser (usb-protocol) but the register behaviour only against RM0008 as we read it.
"""

from __future__ import annotations

import random
import struct
from collections.abc import Iterator

import pytest
from uwbcal.device import Device
from uwbcal.evk1000 import usbhost as uh
from uwbcal.evk1000.usbhosted import HostedStation, default_lib
from uwbcal.link import framing
from uwbcal.link import proto_gen as pg

UID = bytes.fromhex("0123456789ABCDEF10325476")


@pytest.fixture
def station() -> HostedStation:
    if not default_lib().exists():
        pytest.skip(f"{default_lib()} not built: run `make usbhosted`")
    return HostedStation(uid=UID)


@pytest.fixture
def host(station: HostedStation) -> uh.UsbHost:
    h = uh.UsbHost(station.model, station)
    h.enumerate()
    h.cdc_open()
    return h


@pytest.fixture
def bridge(station: HostedStation, host: uh.UsbHost) -> Iterator[object]:
    from uwbcal.evk1000.usbbridge import UsbPtyBridge

    with UsbPtyBridge(host, station) as br:
        yield br


def ping_frame(seq: int, data: bytes) -> bytes:
    payload = pg.PingReq(data=data).encode()
    return framing.encode_frame(framing.Frame(type=pg.T_PING, seq=seq, payload=payload))


def read_frames(host: uh.UsbHost, station: HostedStation, n: int, budget_us: int = 200_000,
                already: bytes = b"") -> list[bytes]:
    """Collect ``n`` 0x00-terminated frames from bulk IN (after ``already``), letting the
    device run."""
    buf = bytearray(already)
    spent = 0
    while buf.count(0) < n and spent < budget_us:
        p = host.bulk_in_packet(1)
        if p is None:
            host.run(1000)
            spent += 1000
        else:
            buf += p
    return bytes(buf).split(b"\0")[:n]


# ---- enumeration -----------------------------------------------------------------------------

def test_enumeration_as_linux_does_it(station: HostedStation) -> None:
    h = uh.UsbHost(station.model, station)
    e = h.enumerate()
    assert uh.check_cdc_acm(e) == []
    assert (e.vid, e.pid) == (pg.USB_VID, pg.USB_PID)
    assert e.strings[int(e.device.iManufacturer)] == pg.USB_MANUFACTURER
    assert e.strings[int(e.device.iProduct)] == pg.USB_PRODUCT
    assert e.serial == UID.hex().upper()
    assert station.model.address == e.address != 0
    assert h.control(0x80, uh.GET_CONFIGURATION, 0, 0, 1) == b"\x01"
    # cdc_acm's open: line coding then DTR/RTS; the device gives the line coding back
    h.control(0x21, uh.SET_LINE_CODING, 0, 0, 7, struct.pack("<IBBB", 921600, 0, 0, 8))
    h.control(0x21, uh.SET_CONTROL_LINE_STATE, 3, 0, 0)
    assert h.control(0xA1, uh.GET_LINE_CODING, 0, 0, 7) == struct.pack("<IBBB", 921600, 0, 0, 8)
    assert station.lib.cdc_line_state() == 3
    # raising DTR brings one SERIAL_STATE notification (DCD, DSR) on the interrupt endpoint
    h.run(2000)
    note = h.bulk_in_packet(2)
    assert note == bytes([0xA1, 0x20, 0, 0, 0, 0, 2, 0, 0x03, 0])


def test_check_cdc_acm_sees_a_broken_descriptor(host: uh.UsbHost) -> None:
    e = host.enumerate()
    bad = bytearray(e.config_raw)
    union_at = bytes(bad).index(bytes([5, 0x24, 0x06]))
    bad[union_at + 4] = 0  # subordinate interface 0: wrong
    broken = uh.Enumeration(e.address, e.device, bytes(bad), uh.parse_configuration(bytes(bad)), e.strings)
    assert any("Union" in p for p in uh.check_cdc_acm(broken))
    with pytest.raises(uh.UsbError, match="bLength"):
        uh.parse_configuration(bytes(bad[:20]) + b"\x09\x04")


@pytest.mark.parametrize(
    "bm, req, value, index, length",
    [
        (0x80, uh.GET_DESCRIPTOR, 0x0600, 0, 10),   # DEVICE_QUALIFIER: full-speed only
        (0x80, uh.GET_DESCRIPTOR, 0x0700, 0, 9),    # OTHER_SPEED_CONFIGURATION
        (0x80, uh.GET_DESCRIPTOR, 0x0309, 0x409, 255),  # no string 9
        (0x80, uh.GET_DESCRIPTOR, 0x0201, 0, 9),    # no configuration 1 (index)
        (0x00, uh.SET_FEATURE, 1, 0, 0),            # DEVICE_REMOTE_WAKEUP: not offered
        (0x00, uh.SET_CONFIGURATION, 2, 0, 0),
        (0xC0, 0x55, 0, 0, 4),                      # vendor request
        (0x40, 0x01, 0, 0, 0),
        (0x21, 0x20, 0, 1, 7),                      # class request to the data interface
        (0xA1, 0x01, 0, 0, 64),                     # GET_ENCAPSULATED_RESPONSE: not supported
        (0x02, uh.CLEAR_FEATURE, 0, 0x83, 0),       # halt of an endpoint that does not exist
        (0x81, uh.GET_STATUS, 0, 5, 2),             # status of interface 5
    ],
)
def test_unsupported_setup_gets_stall_never_a_hang(host: uh.UsbHost, bm: int, req: int, value: int,
                                                   index: int, length: int) -> None:
    data = bytes(length) if not bm & 0x80 else b""
    t0 = host.time_us
    with pytest.raises(uh.UsbStall):
        host.control(bm, req, value, index, length, data)
    assert host.time_us - t0 < 100_000  # answered at once (device time), not by a timeout
    # EP0 works again with the next SETUP
    assert host.control(0x80, uh.GET_STATUS, 0, 0, 2) == b"\0\0"


def test_random_setups_get_an_answer_or_a_stall_never_a_hang(host: uh.UsbHost) -> None:
    rng = random.Random(2026)
    stalls = answers = 0
    for _ in range(300):
        bm = rng.choice([0x00, 0x01, 0x02, 0x80, 0x81, 0x82, 0x21, 0xA1, 0x22, 0x40, 0xC0,
                         rng.randrange(256)])
        req = rng.randrange(256)
        if bm & 0x60 == 0 and req in (uh.SET_ADDRESS, uh.SET_CONFIGURATION):
            continue  # these move the device to another state on purpose
        value, index = rng.randrange(0x10000), rng.choice([0, 1, 0x81, 0x82, 0x01, rng.randrange(0x10000)])
        length = rng.choice([0, 1, 2, 7, 9, 18, 64, 65, 255, rng.randrange(0x10000)])
        if rng.random() < 0.3:  # a well-formed request, with any wLength
            bm, req, value, index = rng.choice([(0x80, uh.GET_DESCRIPTOR, 0x0100, 0),
                                                (0x80, uh.GET_DESCRIPTOR, 0x0200, 0),
                                                (0x80, uh.GET_DESCRIPTOR, 0x0302, 0x409),
                                                (0xA1, uh.GET_LINE_CODING, 0, 0)])
        if not bm & 0x80:
            length = min(length, 200)
        try:
            got = host.control(bm, req, value, index, length, b"" if bm & 0x80 else bytes(length))
            assert len(got) <= length
            answers += 1
        except uh.UsbStall:
            stalls += 1
        assert host.control(0x80, uh.GET_STATUS, 0, 0, 2) == b"\0\0"  # EP0 still answers
    assert stalls > 100 and answers > 5


def test_a_new_setup_wins_over_an_abandoned_data_stage(host: uh.UsbHost) -> None:
    # The host reads only the first packet of the configuration descriptor, then sends
    # another request: the answer must not be preceded by the stale rest.
    assert host.dev.setup(host.addr, uh.setup_packet(0x80, uh.GET_DESCRIPTOR, 0x0200, 0, 255)) == "ACK"
    host.run(1000)
    first = host.dev.in_token(host.addr, 0)
    assert first.handshake == "ACK" and len(first.data) == 64
    host.run(1000)
    assert host.control(0x80, uh.GET_STATUS, 0, 0, 2) == b"\0\0"
    assert host.control(0x80, uh.GET_CONFIGURATION, 0, 0, 1) == b"\x01"


def test_endpoint_halt_and_clear(host: uh.UsbHost, station: HostedStation) -> None:
    host.control(0x02, uh.SET_FEATURE, 0, 0x81, 0)
    assert host.control(0x82, uh.GET_STATUS, 0, 0x81, 2) == b"\x01\x00"
    with pytest.raises(uh.UsbError, match="STALL"):
        host.bulk_in_packet(1)
    host.control(0x02, uh.CLEAR_FEATURE, 0, 0x81, 0)  # also resets the data toggle, both sides
    assert host.control(0x82, uh.GET_STATUS, 0, 0x81, 2) == b"\x00\x00"
    assert host.bulk_out(1, ping_frame(7, b"after halt")) > 0
    assert read_frames(host, station, 1)[0] != b""


# ---- bulk data ---------------------------------------------------------------------------------

def test_transfer_of_a_multiple_of_64_ends_with_a_zero_length_packet(host: uh.UsbHost,
                                                                    station: HostedStation) -> None:
    # A PING of n non-zero bytes answers with a frame of n + 11 bytes on the wire (5-byte
    # header, 4-byte CRC, 1 COBS overhead byte, the 0x00 delimiter), if the header and CRC
    # have no zero; pick the seq so that they have none.
    for seq in range(1, 200):
        frame = ping_frame(seq, bytes([0x41]) * 117)
        if len(frame) == 128:
            break
    host.bulk_out(1, frame)
    host.run(2000)
    sizes = []
    for _ in range(200):
        p = host.bulk_in_packet(1)
        if p is None:
            host.run(1000)
            continue
        sizes.append(len(p))
        if len(p) < 64:
            break
    assert sizes == [64, 64, 0]


def test_station_answers_through_the_pty_like_ttyACM0(bridge: object, station: HostedStation) -> None:
    path = bridge.path  # type: ignore[attr-defined]
    rng = random.Random(11)
    with Device.open(path) as dev:
        info = dev.info()
        assert info.board == "evk1000/hosted"
        assert info.uid == UID
        for _ in range(60):
            dev.ping(rng.randbytes(rng.choice([0, 1, 52, 53, 64, 117, 118, 300, 500, 512])))
        with open(path, "wb", buffering=0) as raw:  # garbage, then a normal answer
            raw.write(b"\x13\x37garbage\x00\x00\xff" * 20)
        dev.ping(b"still here")
    assert station.tx_dropped == 0


def test_bus_reset_mid_session_then_resume_nothing_lost(bridge: object, station: HostedStation) -> None:
    br = bridge
    resets0 = station.lib.usbd_bus_resets()
    rng = random.Random(3)
    sent = answered = 0
    with Device.open(br.path) as dev:  # type: ignore[attr-defined]
        for i in range(80):
            if i in (20, 50):
                br.call(br.reset_and_reenumerate)  # type: ignore[attr-defined]
            data = rng.randbytes(200)
            sent += 1
            dev.ping(data)  # ProtocolError if the echo differs; DeviceTimeout if lost for good
            answered += 1
    assert answered == sent
    assert station.lib.usbd_bus_resets() - resets0 >= 4  # two resets per enumeration, twice


def test_host_that_stops_reading_then_resumes(host: uh.UsbHost, station: HostedStation) -> None:
    # 1. The host stops reading for 1 s (the IN FIFO is full, then the TX ring holds the rest:
    # 4 answers of ~411 bytes): nothing is lost, nothing waits.
    host.bulk_out(1, b"".join(ping_frame(s, bytes([s]) * 400) for s in range(1, 5)))
    host.run(1_000_000)
    frames = read_frames(host, station, 4)
    assert [framing.decode_frame(f).seq for f in frames] == [1, 2, 3, 4]  # type: ignore[union-attr]
    assert station.tx_dropped == 0

    # 2. More than the ring holds (8 answers, ~3.3 KB): the station's write waits for room,
    # bounded (50 ms of device time). The host reads again 30 ms into that wait (from the
    # driver's wait hook, where the chip would take the USB interrupt): nothing is lost.
    got = bytearray()
    waiting_since: list[int] = []

    def host_reads_again_later() -> None:
        if not waiting_since:
            waiting_since.append(station.time_us)
        if station.time_us >= waiting_since[0] + 30_000:
            got.extend(host.bulk_in_packet(1) or b"")

    station.wait_hook = host_reads_again_later
    host.bulk_out(1, b"".join(ping_frame(s, bytes([s]) * 400) for s in range(10, 18)))
    host.run(20_000)
    station.wait_hook = None
    assert waiting_since, "the ring never filled: the test did not test the wait"
    frames = read_frames(host, station, 8, already=bytes(got))
    assert [framing.decode_frame(f).seq for f in frames] == list(range(10, 18))  # type: ignore[union-attr]
    assert station.tx_dropped == 0

    # 3. The host is gone for 1 s with more pending than the ring holds: the station does not
    # hang; it drops what cannot be sent, counts it, and answers normally once the host reads.
    host.bulk_out(1, b"".join(ping_frame(s, bytes([s]) * 400) for s in range(20, 30)))
    host.run(1_000_000)
    assert station.tx_dropped > 0 and station.tx_failures > 0
    empties = 0
    while empties < 2:  # what the FIFO and the ring held (a ZLP reads as empty too)
        empties = 0 if host.bulk_in(1, 1 << 20, idle_us=20_000) else empties + 1
    host.bulk_out(1, ping_frame(99, b"back"))
    # a frame cut by the drop may come first (the host's decoder skips it at the delimiter)
    got2 = [framing.decode_frame(f) for f in read_frames(host, station, 2)]
    assert any(isinstance(g, framing.Frame) and g.seq == 99 and g.is_response for g in got2)


def test_bus_reset_cuts_a_transfer_the_rest_follows(host: uh.UsbHost, station: HostedStation) -> None:
    # An answer is half sent when the host resets the port; after enumeration the unsent rest
    # follows: the byte stream has no gap.
    host.bulk_out(1, ping_frame(3, bytes(range(1, 256)) + bytes(range(1, 246))))
    host.run(2000)
    part = bytearray()
    for _ in range(3):
        part += host.bulk_in_packet(1) or b""
    assert 0 < len(part) < 500
    host.enumerate()
    host.cdc_open()
    frames = read_frames(host, station, 1, already=bytes(part))
    got = framing.decode_frame(frames[0])
    assert isinstance(got, framing.Frame) and got.seq == 3


def test_suspend_and_resume(host: uh.UsbHost, station: HostedStation) -> None:
    station.model.suspend()
    host.run(5000)
    assert station.lib.usbd_suspended() == 1
    station.model.resume()
    host.run(1000)
    assert station.lib.usbd_suspended() == 0
    host.bulk_out(1, ping_frame(5, b"awake"))
    got = framing.decode_frame(read_frames(host, station, 1)[0])
    assert isinstance(got, framing.Frame) and got.seq == 5
