"""`uwbcal ports [--json]`: the boards and simulated stations this machine can reach.

Boards: pyserial's list_ports, USB ports only (a board's host link is USB CDC or a USB-UART);
legacy UART devices without a USB id (/dev/ttyS*) are left out unless --all. Simulated stations:
every running `uwbcal sim` (uwbcal.simregistry). Says "no board found" when there is none.
"""

from __future__ import annotations

import argparse
import json
from typing import Any


def register(sub: Any) -> None:
    p = sub.add_parser("ports", help="list boards (USB serial ports) and running simulated stations",
                       description=__doc__)
    p.add_argument("--json", action="store_true", help="one JSON object instead of text")
    p.add_argument("--all", action="store_true", help="also serial ports without a USB id (/dev/ttyS*)")
    p.set_defaults(func=run)


def list_ports() -> list[dict[str, Any]]:
    """Every port pyserial sees: device, description, hwid, USB vid/pid when known."""
    from serial.tools import list_ports as lp

    out = []
    for p in sorted(lp.comports(), key=lambda p: p.device):
        out.append(
            {
                "port": p.device,
                "description": p.description,
                "hwid": p.hwid,
                "vid": p.vid,
                "pid": p.pid,
                "serial_number": p.serial_number,
            }
        )
    return out


def simulated() -> list[dict[str, Any]]:
    """Stations of every running `uwbcal sim`: port, station id, pid of the world."""
    from uwbcal import simregistry

    return [{"port": s["port"], "station": s["id"], "pid": w["pid"], "scenario": w.get("scenario")}
            for w in simregistry.running() for s in w["stations"]]


def run(args: argparse.Namespace) -> int:
    ports = [p for p in list_ports() if args.all or p["vid"] is not None]
    sims = simulated()
    if args.json:
        print(json.dumps({"ports": ports, "simulated": sims}))
        return 0
    if not ports:
        print("no board found (boards appear as USB serial ports; plug one in, or use --all)")
    for p in ports:
        print(f"{p['port']}  {p['description']}  [{p['hwid']}]")
    if sims:
        print("simulated stations:")
        for s in sims:
            print(f"  {s['port']}  station {s['station']}  (uwbcal sim pid {s['pid']})")
    else:
        print("no simulated station running (start some: uwbcal sim --scenario two_stations)")
    return 0
