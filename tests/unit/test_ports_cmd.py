"""`uwbcal ports` recognises a USB station by its VID/PID and its UID serial number (fake
pyserial ports: the ListPortInfo fields are what pyserial reads from sysfs on Linux)."""

from __future__ import annotations

import json
from types import SimpleNamespace
from typing import Any

import pytest
from uwbcal import cli
from uwbcal.commands import ports
from uwbcal.link import proto_gen as pg


def fake(device: str, vid: int | None, pid: int | None, serial: str | None) -> Any:
    hwid = f"USB VID:PID={vid:04X}:{pid:04X} SER={serial}" if vid is not None else "n/a"
    return SimpleNamespace(device=device, description="desc", hwid=hwid, vid=vid, pid=pid,
                           serial_number=serial)


def test_station_uid_rules() -> None:
    uid = "0123456789ABCDEF10325476"
    assert ports.station_uid(pg.USB_VID, pg.USB_PID, uid) == uid
    assert ports.station_uid(pg.USB_VID, pg.USB_PID, uid.lower()) == uid
    assert ports.station_uid(pg.USB_VID, pg.USB_PID + 1, uid) is None   # another product
    assert ports.station_uid(0x0483, 0x5740, uid) is None               # ST's VCP IDs
    assert ports.station_uid(pg.USB_VID, pg.USB_PID, "12345") is None    # not a UID
    assert ports.station_uid(pg.USB_VID, pg.USB_PID, None) is None
    assert ports.station_uid(None, None, None) is None


def test_ports_json_marks_stations(monkeypatch: pytest.MonkeyPatch,
                                   capsys: pytest.CaptureFixture[str]) -> None:
    from serial.tools import list_ports as lp

    fakes = [fake("/dev/ttyACM0", pg.USB_VID, pg.USB_PID, "0123456789ABCDEF10325476"),
             fake("/dev/ttyACM1", pg.USB_VID, pg.USB_PID, "00000000000000000000000B"),
             fake("/dev/ttyUSB0", 0x0403, 0x6001, "A50285BI"),
             fake("/dev/ttyS0", None, None, None)]
    monkeypatch.setattr(lp, "comports", lambda: fakes)
    monkeypatch.setattr(ports, "simulated", lambda: [])     # no `uwbcal sim` running here
    assert cli.main(["ports", "--json"]) == 0                # USB ports only: no /dev/ttyS0
    out = json.loads(capsys.readouterr().out)["ports"]
    uids = [p["station_uid"] for p in out]
    assert uids == ["0123456789ABCDEF10325476", "00000000000000000000000B", None]
    assert cli.main(["ports", "--json", "--all"]) == 0
    assert "/dev/ttyS0" in [p["port"] for p in json.loads(capsys.readouterr().out)["ports"]]
    assert cli.main(["ports", "--stations"]) == 0
    text = capsys.readouterr().out.splitlines()
    marked = [t for t in text if "uwbcal station, UID" in t]
    assert len(marked) == 2 and not any("ttyUSB0" in t for t in text)
