"""`uwbcal ports [--json]`: list the serial ports of this machine (pyserial's list_ports)."""

from __future__ import annotations

import argparse
import json
from typing import Any


def register(sub: Any) -> None:
    p = sub.add_parser("ports", help="list serial ports (boards appear as USB or UART ports)")
    p.add_argument("--json", action="store_true", help="one JSON object instead of text")
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


def run(args: argparse.Namespace) -> int:
    ports = list_ports()
    if args.json:
        print(json.dumps({"ports": ports}))
        return 0
    if not ports:
        print("no serial ports found (simulated stations: `uwbcal sim` prints their ptys)")
    for p in ports:
        print(f"{p['port']}  {p['description']}  [{p['hwid']}]")
    return 0
