"""The shipped EVK1000 image (build/evk1000/uwbcal-evk1000.bin, the USB build), byte for byte,
on the emulated EVK1000 (issue 10's machine: Unicorn's Cortex-M3 with modelled peripherals)
with the OTG FS model on its bus: enumerated as Linux does it, then the station answers over
the bulk endpoints, through a port reset in the middle of an answer.

Skipped where the emulated machine is not in the tree (before issue 10 is merged). What it
cannot see: the real OTG FS core and PHY (the model is ours), a real host controller.
"""

from __future__ import annotations

import random
from pathlib import Path

import pytest
from uwbcal.evk1000 import usbhost as uh
from uwbcal.link import framing
from uwbcal.link import proto_gen as pg
from uwbcal.simstations import repo_root

pytest.importorskip("unicorn", reason="the emulated EVK1000 needs unicorn (issue 10)")
machine_mod = pytest.importorskip("uwbcal.evk1000.machine",
                                  reason="no emulated EVK1000 (issue 10) in this tree")

IMAGE = repo_root() / "build" / "evk1000" / "uwbcal-evk1000.bin"
UID = bytes.fromhex("0123456789ABCDEF10325476")


@pytest.fixture
def usb() -> tuple[object, uh.UsbHost]:
    from uwbcal.evk1000.fpec import FlashFile
    from uwbcal.evk1000.radio import LocalRadio
    from uwbcal.evk1000.usbmachine import attach_usb

    if not IMAGE.is_file():
        pytest.skip(f"{IMAGE} not built: run `make firmware`")
    img = IMAGE.read_bytes()
    flash = FlashFile(None)
    flash.data[:len(img)] = img
    box: dict[str, object] = {}
    radio = LocalRadio(lambda: box["m"].time_us())  # type: ignore[attr-defined]
    m = machine_mod.Machine(flash, uid=UID, radio=radio, link_sink=lambda b: None)
    box["m"] = m
    _otg, host = attach_usb(m)
    return m, host


def answer(host: uh.UsbHost, frame: bytes, already: bytes = b"") -> framing.Frame:
    if frame:
        assert host.bulk_out(1, frame) == len(frame)
    buf = bytearray(already)
    for _ in range(500):
        if b"\0" in buf:
            break
        p = host.bulk_in_packet(1)
        if p is None:
            host.run(1000)
        else:
            buf += p
    f = framing.decode_frame(bytes(buf).split(b"\0")[0])
    assert isinstance(f, framing.Frame), f
    return f


def ping(seq: int, data: bytes) -> bytes:
    payload = pg.PingReq(data=data).encode()
    return framing.encode_frame(framing.Frame(type=pg.T_PING, seq=seq, payload=payload))


def test_the_image_enumerates_and_answers_over_usb(usb: tuple[object, uh.UsbHost]) -> None:
    _m, host = usb
    e = host.enumerate()
    assert uh.check_cdc_acm(e) == []
    assert (e.vid, e.pid, e.serial) == (pg.USB_VID, pg.USB_PID, UID.hex().upper())
    host.cdc_open()
    with pytest.raises(uh.UsbStall):
        host.control(0x80, uh.GET_DESCRIPTOR, 0x0600, 0, 10)  # DEVICE_QUALIFIER
    get_info = framing.encode_frame(framing.Frame(type=pg.T_GET_INFO, seq=1))
    info = pg.GetInfoResp.decode(answer(host, get_info).payload)
    assert info.board == "evk1000" and info.uid == UID
    rng = random.Random(5)
    for seq in range(2, 12):
        data = rng.randbytes(rng.choice([0, 53, 117, 300, 512]))
        f = answer(host, ping(seq, data))
        assert f.seq == seq and pg.PingResp.decode(f.payload).data == data


def test_port_reset_in_the_middle_of_an_answer(usb: tuple[object, uh.UsbHost]) -> None:
    _m, host = usb
    host.enumerate()
    host.cdc_open()
    data = bytes(range(1, 256)) + bytes(range(1, 246))
    assert host.bulk_out(1, ping(3, data)) > 0
    host.run(3000)
    part = bytearray()
    for _ in range(3):
        part += host.bulk_in_packet(1) or b""
    assert 0 < len(part) < len(data)
    host.port_reset()
    host.cdc_open()
    f = answer(host, b"", already=bytes(part))
    assert f.seq == 3 and pg.PingResp.decode(f.payload).data == data
    assert answer(host, ping(4, b"after")).seq == 4


def test_the_image_through_a_pty_like_ttyACM0(usb: tuple[object, uh.UsbHost]) -> None:
    from uwbcal.device import Device
    from uwbcal.evk1000.usbbridge import UsbPtyBridge

    _m, host = usb
    host.enumerate()
    host.cdc_open()
    with UsbPtyBridge(host, host.runner) as br, Device.open(br.path) as dev:  # type: ignore[arg-type]
        info = dev.info()
        assert info.board == "evk1000" and info.uid == UID and info.dev_id == 0xDECA0130
        for n in (0, 64, 117, 512):
            dev.ping(bytes(range(256))[:n] * 2 if n > 256 else bytes(range(n)))


def test_calibration_between_two_emulated_boards_over_usb(tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    import json

    from uwbcal import cli
    from uwbcal.sessions.store import Session
    from uwbcal.simstations import SimWorld

    if not IMAGE.is_file():
        pytest.skip(f"{IMAGE} not built: run `make firmware`")
    steps, per_step = 3, 30
    with SimWorld(scenario=repo_root() / "scenarios" / "two_stations.toml", board="evk1000", image=IMAGE,
                  workdir=tmp_path / "w", start_timeout_s=60.0) as w:
        rc = cli.main(["calibrate", "--tx", w.ports[0], "--rx", w.ports[1], "--steps", str(steps),
                       "--step-db", "3", "--per-step", str(per_step), "--spacing", "2ms",
                       "--out", str(tmp_path / "cal.db"), "--no-progress", "--json", "--no-analysis"])
        out = capsys.readouterr().out
        assert rc == 0, out
        codes = w.stop()
    assert all(c == 0 for c in codes.values()), codes
    run = json.loads(out.strip().splitlines()[-1])["run"]
    assert run["complete"] and run["records"] == steps * per_step
    assert run["losses"]["lost_frames"] == 0 and run["losses"]["n_missing"] == 0
    with Session.open(tmp_path / "cal.db", readonly=True) as s:
        seqs = sorted(s.read("triplets")["seq"].tolist())
    assert seqs == list(range(steps * per_step))  # no duplicate, no gap
