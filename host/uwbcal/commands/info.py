"""`uwbcal info --port P [--json]`: what a station says about itself (GET_INFO)."""

from __future__ import annotations

import argparse
import json
from typing import Any

from uwbcal.device import Device, DeviceInfo


def register(sub: Any) -> None:
    p = sub.add_parser("info", help="show what a station reports about itself (GET_INFO)")
    p.add_argument("--port", required=True, help="serial port, pty, socket://host:port or loop://")
    p.add_argument("--json", action="store_true", help="one JSON object instead of text")
    p.add_argument("--timeout", type=float, default=1.0, help="seconds per attempt (default 1)")
    p.set_defaults(func=run)


def format_info(info: DeviceInfo) -> str:
    """Human-readable lines."""
    radio = (
        "DW1000 answers"
        if info.radio_ok
        else ("no radio answers" if info.dev_id == 0 else "unexpected DEV_ID")
    )
    rows = [
        ("port", info.port),
        ("board", info.board),
        ("firmware", f"{info.firmware} (git {info.git_hash})"),
        ("protocol", str(info.protocol_version)),
        ("uid", info.uid_hex),
        ("dev_id", f"0x{info.dev_id:08X} ({radio})"),
        ("max payload", f"{info.max_payload} bytes"),
    ]
    return "\n".join(f"{k:<12} {v}" for k, v in rows)


def run(args: argparse.Namespace) -> int:
    with Device.open(args.port, timeout=args.timeout) as dev:
        info = dev.info()
    print(json.dumps(info.as_dict()) if args.json else format_info(info))
    return 0
