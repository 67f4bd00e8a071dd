"""`uwbcal ports [--json]`: the boards and simulated stations this machine can reach.

Boards: pyserial's list_ports, USB ports only (a board's host link is USB CDC or a USB-UART);
legacy UART devices without a USB id (/dev/ttyS*) are left out unless --all. A USB CDC-ACM port
with the station's USB vendor and product ID (protocol/protocol.toml [usb]) is a uwbcal station,
and its USB serial number is the station's UID. Simulated stations: every running `uwbcal sim`
(uwbcal.simregistry). Says "no board found" when there is none.
"""

from __future__ import annotations

import argparse
import json
from typing import Any

from uwbcal.link import proto_gen as pg


def register(sub: Any) -> None:
    p = sub.add_parser("ports", help="list boards (USB serial ports; uwbcal stations marked with their "
                       "UID) and running simulated stations", description=__doc__)
    p.add_argument("--json", action="store_true", help="one JSON object instead of text")
    p.add_argument("--all", action="store_true", help="also serial ports without a USB id (/dev/ttyS*)")
    p.add_argument("--stations", action="store_true", help="only the ports that are uwbcal stations")
    p.set_defaults(func=run)


def station_uid(vid: int | None, pid: int | None, serial: str | None) -> str | None:
    """The UID (24 hex digits) of a uwbcal station port, or None when the USB IDs are not the
    station's or the serial number is not a UID."""
    if vid != pg.USB_VID or pid != pg.USB_PID or not serial:
        return None
    s = serial.strip().upper()
    if len(s) != 24 or any(c not in "0123456789ABCDEF" for c in s):
        return None
    return s


def describe(p: Any) -> dict[str, Any]:
    """One pyserial ListPortInfo as a dict, with ``station_uid`` (None if not a station)."""
    uid = station_uid(p.vid, p.pid, p.serial_number)
    return {
        "port": p.device,
        "description": p.description,
        "hwid": p.hwid,
        "vid": p.vid,
        "pid": p.pid,
        "serial_number": p.serial_number,
        "station_uid": uid,
    }


def list_ports() -> list[dict[str, Any]]:
    """Every port pyserial sees: device, description, hwid, USB vid/pid/serial when known."""
    from serial.tools import list_ports as lp

    return [describe(p) for p in sorted(lp.comports(), key=lambda p: p.device)]


def simulated() -> list[dict[str, Any]]:
    """Stations of every running `uwbcal sim`: port, station id, pid of the world."""
    from uwbcal import simregistry

    return [{"port": s["port"], "station": s["id"], "pid": w["pid"], "scenario": w.get("scenario")}
            for w in simregistry.running() for s in w["stations"]]


def run(args: argparse.Namespace) -> int:
    ports = [p for p in list_ports() if args.all or p["vid"] is not None]
    if args.stations:
        ports = [p for p in ports if p["station_uid"]]
    sims = simulated()
    if args.json:
        print(json.dumps({"ports": ports, "simulated": sims}))
        return 0
    if not ports:
        print("no board found (boards appear as USB serial ports; plug one in, or use --all)")
    for p in ports:
        mark = f"  uwbcal station, UID {p['station_uid']}" if p["station_uid"] else ""
        print(f"{p['port']}  {p['description']}  [{p['hwid']}]{mark}")
    if sims:
        print("simulated stations:")
        for s in sims:
            print(f"  {s['port']}  station {s['station']}  (uwbcal sim pid {s['pid']})")
    else:
        print("no simulated station running (start some: uwbcal sim --scenario two_stations)")
    return 0
