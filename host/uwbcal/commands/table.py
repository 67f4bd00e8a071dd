"""`uwbcal table build|show|push|pull|verify|info|erase`: calibration tables on stations.

  uwbcal table build S.db --out T.json [--station ID] [--z-m Z]   from a power-sweep session
  uwbcal table show T.json                                        print a table
  uwbcal table push --port P T.json [--force]                     write it to a station's flash
  uwbcal table pull --port P [--out F]                            read the station's table
  uwbcal table verify --port P T.json                             the station holds exactly T
  uwbcal table info --port P                                      slot states and sequences
  uwbcal table erase --port P                                     remove the station's table

push refuses a table made for another station (UID) or another radio configuration unless
--force; NaN, unordered axes and values out of physical bounds are refused always, naming the
field. docs/TABLES.md describes the format and the flash store.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from uwbcal.errors import SessionError, TableError


def register(subparsers: Any) -> None:
    """Add the ``table`` command and its subcommands."""
    p = subparsers.add_parser("table", help="build, show, push, pull and verify calibration tables",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="table_command", required=True, metavar="SUBCOMMAND")

    b = sub.add_parser("build", help="build a table from a power-sweep session")
    b.add_argument("session", type=Path, help="session file (SQLite) of a P1/P2/P3 power sweep")
    b.add_argument("--out", type=Path, required=True, help="table file to write (JSON)")
    b.add_argument("--station", type=int, default=None, metavar="ID",
                   help="receiving station the table is for (default: the only one in the session)")
    b.add_argument("--uid", default=None, help="station UID, 24 hex digits (default: from the session)")
    zg = b.add_mutually_exclusive_group()
    zg.add_argument("--z-m", type=float, default=None, metavar="Z",
                    help="Z of the station pair, m (from `uwbcal analyze twr`); the table gets half")
    zg.add_argument("--z-ps", type=float, default=None, metavar="PS", help="this station's z share, ps")
    b.add_argument("--channel", type=int, default=None, help="radio channel (default: session, else 2)")
    b.add_argument("--prf", type=int, default=None, help="PRF, MHz (default: session, else 64)")
    b.add_argument("--preamble", type=int, default=None, help="preamble length (default: session, else 128)")
    b.add_argument("--threshold", type=float, default=-85.0, metavar="DBM",
                   help="measured level below which the estimate is taken as right (default -85)")
    b.add_argument("--coarse-step-db", type=float, default=3.0, help="nominal coarse gain step, dB")
    b.set_defaults(func=run_build)

    s = sub.add_parser("show", help="print a table file")
    s.add_argument("table", type=Path)
    s.add_argument("--json", action="store_true", help="print the decoded fields as JSON")
    s.set_defaults(func=run_show)

    for name, hlp in (("push", "write a table to a station's flash"),
                      ("verify", "check that a station holds exactly this table")):
        q = sub.add_parser(name, help=hlp)
        q.add_argument("--port", required=True, help="serial port, pty or socket:// URL of the station")
        q.add_argument("table", type=Path)
        if name == "push":
            q.add_argument("--force", action="store_true",
                           help="push even if the table was made for another UID or radio configuration")
            _radio_args(q)
        q.set_defaults(func=run_push if name == "push" else run_verify)

    r = sub.add_parser("pull", help="read a station's table")
    r.add_argument("--port", required=True)
    r.add_argument("--out", type=Path, default=None, help="write it to this file (JSON); default: print it")
    r.set_defaults(func=run_pull)

    i = sub.add_parser("info", help="slot states, sequence numbers, the active table")
    i.add_argument("--port", required=True)
    i.set_defaults(func=run_info)

    e = sub.add_parser("erase", help="erase both table slots of a station")
    e.add_argument("--port", required=True)
    e.set_defaults(func=run_erase)


def _radio_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--channel", type=int, default=2, help="the station's radio channel (default 2)")
    p.add_argument("--prf", type=int, default=64, help="the station's PRF, MHz (default 64)")
    p.add_argument("--preamble", type=int, default=128, help="the station's preamble length (default 128)")


def _uid_hex(text: str) -> bytes:
    digits = "".join(c for c in str(text) if c in "0123456789abcdefABCDEF")
    if len(digits) != 24:
        raise TableError(f"station UID {text!r} is not 12 bytes of hex")
    return bytes.fromhex(digits)


def _open(port: str) -> Any:
    """The station's request/response client (uwbcal.link.client.Client)."""
    from uwbcal.device import Device

    return Device.open(port).client


def _station_uid(dev: Any) -> bytes:
    """The station's UID (GET_INFO; ProtocolError if it speaks another protocol version)."""
    from uwbcal.device import Device

    return bytes(Device(dev).info().uid)


def run_build(args: argparse.Namespace) -> int:
    """Power calibration of one receiving station from a session, written as a table."""
    from uwbcal import tables
    from uwbcal.corrections import analysis
    from uwbcal.sessions.store import Session

    if not args.session.exists():
        raise SessionError(f"{args.session}: no such session file")
    s = Session.open(args.session, readonly=True)
    try:
        meta = s.meta
        stations = s.stations()
        tr = s.read("triplets")
    finally:
        s.close()
    radio = meta.get("radio") or {}
    prf = args.prf or analysis.session_prf_mhz(meta)
    opts = analysis.PowerOptions(threshold_dbm=args.threshold, coarse_step_db=args.coarse_step_db,
                                 prf_mhz=prf)
    cals = analysis.calibrate_power_records(tr, opts)
    by_rx = {rx: c for (_tx, rx), c in cals.items()}
    if args.station is None:
        if len(by_rx) != 1:
            raise TableError(f"the session has receiving stations {sorted(by_rx)}: choose one with --station")
        rx = next(iter(by_rx))
    else:
        rx = args.station
        if rx not in by_rx:
            raise TableError(f"station {rx} received no power sweep in this session (has {sorted(by_rx)})")
    if args.uid is not None:
        uid = _uid_hex(args.uid)
    else:
        known = {str(k): v for k, v in (meta.get("station_uids") or {}).items()}
        known.update({str(st["id"]): st["uid"] for st in stations if st.get("uid")})
        if str(rx) not in known:
            raise TableError(f"the session names no UID for station {rx}: give --uid")
        uid = _uid_hex(known[str(rx)])
    from uwbcal import dw1000

    z_ps = 0.0
    if args.z_m is not None:
        z_ps = 0.5 * args.z_m / dw1000.C_LIGHT * 1e12
    elif args.z_ps is not None:
        z_ps = args.z_ps
    # data rate (kb/s) -> its code; 6800 is how some tools write 6.81 Mb/s
    rate_code = {r: code for code, r in enumerate(dw1000.DATA_RATES_KBPS)} | {6800: 2}
    rate = rate_code.get(int(radio.get("data_rate_kbps") or 6810), 2)
    data = tables.build(uid, by_rx[rx].curve, channel=args.channel or int(radio.get("channel") or 2),
                        prf_mhz=prf, preamble_len=args.preamble or int(radio.get("preamble_length") or 128),
                        data_rate=rate, z_ps=z_ps)
    tables.save(args.out, data)
    t = tables.decode(data)
    print(f"wrote {args.out}: station {rx} uid {uid.hex()}, {t.n_curve} curve points "
          f"{t.curve_dbm[0]:.1f} .. {t.curve_dbm[t.n_curve - 1]:.1f} dBm, crc32 0x{t.crc32:08X}")
    return 0


def run_show(args: argparse.Namespace) -> int:
    """Print a table file."""
    from uwbcal import tables

    data = tables.load(args.table)
    if args.json:
        print(json.dumps(tables.to_json(data)["fields"], indent=1))
    else:
        print(tables.describe(data))
    return 0


def run_push(args: argparse.Namespace) -> int:
    """Check, write and commit a table; the station checks again."""
    from uwbcal import tables

    data = tables.load(args.table)
    dev = _open(args.port)
    try:
        uid = _station_uid(dev)
        r = tables.push(dev, data, uid=uid, radio=(args.channel, args.prf, args.preamble), force=args.force)
    finally:
        dev.close()
    print(f"{args.port}: table written to slot {r.slot}, sequence {r.sequence}")
    return 0


def run_pull(args: argparse.Namespace) -> int:
    """Read the station's active table."""
    from uwbcal import tables
    from uwbcal.link import proto_gen as pg
    from uwbcal.link.client import ErrorResponse

    dev = _open(args.port)
    try:
        try:
            data = tables.pull(dev)
        except ErrorResponse as exc:
            if exc.code == pg.ERR_NOT_FOUND:
                raise TableError(f"{args.port}: the station has no table") from None
            raise
    finally:
        dev.close()
    if args.out is None:
        print(tables.describe(data))
    else:
        tables.save(args.out, data)
        print(f"wrote {args.out}: {len(data)} bytes, crc32 0x{tables.decode(data).crc32:08X}")
    return 0


def run_verify(args: argparse.Namespace) -> int:
    """Exit 0 when the station's active table is byte for byte the file's."""
    from uwbcal import tables
    from uwbcal.link import proto_gen as pg
    from uwbcal.link.client import ErrorResponse

    want = tables.load(args.table)
    dev = _open(args.port)
    try:
        try:
            got = tables.pull(dev)
        except ErrorResponse as exc:
            if exc.code == pg.ERR_NOT_FOUND:
                raise TableError(f"{args.port}: the station has no table") from None
            raise
        i = tables.info(dev)
    finally:
        dev.close()
    if got != want:
        diff = next(k for k in range(min(len(got), len(want)) + 1)
                    if k == min(len(got), len(want)) or got[k] != want[k])
        raise TableError(f"{args.port}: the station's table differs from {args.table} (first at byte {diff}, "
                         f"field {tables.field_at(diff)})")
    if not i.applied:
        print(f"{args.port}: table matches but the station does not apply it", file=sys.stderr)
        return 1
    print(f"{args.port}: table matches {args.table} (crc32 0x{i.table_crc32:08X}, slot {i.active})")
    return 0


def run_info(args: argparse.Namespace) -> int:
    """Slot states and sequences."""
    from uwbcal import tables

    dev = _open(args.port)
    try:
        print(tables.describe_info(tables.info(dev)))
    finally:
        dev.close()
    return 0


def run_erase(args: argparse.Namespace) -> int:
    """Erase both slots."""
    from uwbcal import tables

    dev = _open(args.port)
    try:
        tables.erase(dev)
    finally:
        dev.close()
    print(f"{args.port}: tables erased")
    return 0
