"""`uwbcal table build|show|push|pull|verify|info|erase`: calibration tables on stations.

  uwbcal table build S.db --out T.json [--station ID] [--z-m Z]   from a power-sweep session
  uwbcal table build FLEET.db --out tables/                       every station of a fleet session
  uwbcal table show T.json                                        print a table
  uwbcal table push --port P T.json [--force]                     write it to a station's flash
  uwbcal table push --all --ports P1,P2,P3 tables/                each station the table for its UID
  uwbcal table pull --port P [--out F]                            read the station's table
  uwbcal table verify --port P T.json                             the station holds exactly T
  uwbcal table info --port P                                      slot states and sequences
  uwbcal table erase --port P                                     remove the station's table

push refuses a table made for another station (UID) or another radio configuration unless
--force; NaN, unordered axes and values out of physical bounds are refused always, naming the
field. Every subcommand takes --json. A built table's T.json carries its ``validity`` (the
swept RX levels and the level estimate's trusted region). docs/TABLES.md describes the format
and the flash store.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
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
    b.add_argument("--out", type=Path, required=True,
                   help="table file (JSON); a directory when the session calibrated several stations")
    b.add_argument("--station", type=int, default=None, metavar="ID",
                   help="receiving station the table is for (default: every one in the session)")
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
    b.add_argument("--antenna", type=Path, default=None, metavar="ANTD.json",
                   help="antenna delays from `uwbcal antenna ... --out`: the table carries the station's "
                        "TX_ANTD/LDE_RXANTD, programmed by the firmware")
    b.add_argument("--json", action="store_true", help="print one JSON object")
    b.set_defaults(func=run_build)

    s = sub.add_parser("show", help="print a table file")
    s.add_argument("table", type=Path)
    s.add_argument("--json", action="store_true", help="print the decoded fields as JSON")
    s.set_defaults(func=run_show)

    for name, hlp in (("push", "write a table to a station's flash"),
                      ("verify", "check that a station holds exactly this table")):
        q = sub.add_parser(name, help=hlp)
        q.add_argument("--port", help="serial port, pty or socket:// URL of the station")
        q.add_argument("table", type=Path, help="table file (JSON); with --all, the directory of tables")
        q.add_argument("--all", action="store_true",
                       help="every station of --ports gets the table of the directory made for its UID")
        q.add_argument("--ports", default=None, metavar="P1,P2,...", help="with --all: the stations' ports")
        q.add_argument("--json", action="store_true", help="print one JSON object")
        if name == "push":
            q.add_argument("--force", action="store_true",
                           help="push even if the table was made for another UID or radio configuration")
            _radio_args(q)
        q.set_defaults(func=run_push if name == "push" else run_verify)

    r = sub.add_parser("pull", help="read a station's table")
    r.add_argument("--port", required=True, help="serial port, pty or socket:// URL of the station")
    r.add_argument("--out", type=Path, default=None, help="write it to this file (JSON); default: print it")
    r.add_argument("--json", action="store_true", help="print one JSON object")
    r.set_defaults(func=run_pull)

    i = sub.add_parser("info", help="slot states, sequence numbers, the active table")
    i.add_argument("--port", required=True, help="serial port, pty or socket:// URL of the station")
    i.add_argument("--json", action="store_true", help="print one JSON object")
    i.set_defaults(func=run_info)

    e = sub.add_parser("erase", help="erase both table slots of a station")
    e.add_argument("--port", required=True, help="serial port, pty or socket:// URL of the station")
    e.add_argument("--json", action="store_true", help="print one JSON object")
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


def _emit(args: argparse.Namespace, obj: dict[str, Any], text: str) -> None:
    """One JSON object with --json, else the text."""
    print(json.dumps(obj) if getattr(args, "json", False) else text)


def run_build(args: argparse.Namespace) -> int:
    """Power calibration of the receiving station(s) of a session, written as table(s).

    With one receiving station (or --station) ``--out`` is the table file; with several and no
    --station, ``--out`` is a directory that gets ``station<ID>.json`` for every one of them.
    """
    from uwbcal import tables
    from uwbcal.corrections import analysis, validity
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
    # a fleet session calibrates each station from several transmitters: one sweep per station
    by_rx = {rx: cal for rx, (_c, cal) in
             validity.loudest_per_station((rx, c.curve, c) for (_tx, rx), c in cals.items()).items()}
    if args.station is None:
        if not by_rx:
            raise TableError(f"{args.session}: no receiving station has a power sweep")
        chosen = sorted(by_rx)
    else:
        if args.station not in by_rx:
            raise TableError(f"station {args.station} received no power sweep in this session "
                             f"(has {sorted(by_rx)})")
        chosen = [args.station]
    several = len(chosen) > 1
    if several and args.uid is not None:
        raise TableError(f"--uid names one station; the session has {chosen}: add --station")
    if several:
        args.out.mkdir(parents=True, exist_ok=True)
    known = {str(k): v for k, v in (meta.get("station_uids") or {}).items()}
    known.update({str(st["id"]): st["uid"] for st in stations if st.get("uid")})
    from uwbcal import dw1000

    z_ps = 0.0
    if args.z_m is not None:
        z_ps = 0.5 * args.z_m / dw1000.C_LIGHT * 1e12
    elif args.z_ps is not None:
        z_ps = args.z_ps
    settings = meta.get("settings") or {}
    distances = settings.get("distances_m") or {}
    # data rate (kb/s) -> its code; 6800 is how some tools write 6.81 Mb/s
    rate_code = {r: code for code, r in enumerate(dw1000.DATA_RATES_KBPS)} | {6800: 2}
    rate = rate_code.get(int(radio.get("data_rate_kbps") or 6810), 2)
    antd: dict[int, int] = {}
    if args.antenna is not None:
        from uwbcal.corrections.antenna import AntennaSolution

        try:
            sol = AntennaSolution.from_dict(json.loads(args.antenna.read_text()))
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise TableError(f"{args.antenna}: not an antenna solution ({exc})") from None
        antd = {s: sol.antd_units(s) for s in sol.stations}
    written: list[dict[str, Any]] = []
    lines: list[str] = []
    for rx in chosen:
        if args.uid is not None:
            uid = _uid_hex(args.uid)
        elif str(rx) in known:
            uid = _uid_hex(known[str(rx)])
        else:
            raise TableError(f"the session names no UID for station {rx}: give --uid")
        d = distances.get(str(rx), settings.get("distance_m"))
        val = validity.of_calibration(by_rx[rx], None if d is None else float(d)).to_dict()
        preamble = args.preamble or int(radio.get("preamble_length") or 128)
        if antd and rx not in antd:
            raise TableError(f"{args.antenna} has no antenna delay for station {rx} (has {sorted(antd)})")
        data = tables.build(uid, by_rx[rx].curve, channel=args.channel or int(radio.get("channel") or 2),
                            prf_mhz=prf, preamble_len=preamble, data_rate=rate, z_ps=z_ps,
                            tx_antd=antd.get(rx, 0), rx_antd=antd.get(rx, 0))
        out = args.out / f"station{rx}.json" if several else args.out
        tables.save(out, data, val)
        t = tables.decode(data)
        written.append({"station": rx, "uid": uid.hex(), "file": str(out), "n_curve": t.n_curve,
                        "crc32": f"0x{t.crc32:08X}", "z_ps": t.z_ps, "validity": val})
        lo, hi = val["swept_measured_dbm"]
        lines.append(f"wrote {out}: station {rx} uid {uid.hex()}, {t.n_curve} curve points "
                     f"{t.curve_dbm[0]:.1f} .. {t.curve_dbm[t.n_curve - 1]:.1f} dBm, crc32 0x{t.crc32:08X}; "
                     f"valid for measured levels {lo:.1f} .. {hi:.1f} dBm")
    target = f"--all --ports P1,P2,... {args.out}" if several else f"--port PORT {written[0]['file']}"
    hint = f"next: uwbcal table push {target}" + ("" if several else f"  then: uwbcal table verify {target}")
    if args.z_m is None and args.z_ps is None:
        hint += ("\n      (Z is 0: after a range session at a known distance, `uwbcal analyze twr RANGE.db` "
                 "prints Z; rebuild with --z-m Z)")
    _emit(args, {"tables": written, "next": hint}, "\n".join([*lines, hint]))
    return 0


def run_show(args: argparse.Namespace) -> int:
    """Print a table file."""
    from uwbcal import tables
    from uwbcal.errors import TableError

    data = tables.load(args.table)
    bad = tables.problem(data)
    err = None if bad is None else TableError(
        f"{args.table}: invalid table: {tables.FIELD_NAMES[bad[0]]}: {bad[1]}")
    if not args.json:
        print(tables.describe(data))
        if err is not None:  # shown for diagnosis, but not a usable table
            raise err
        return 0
    # one JSON object: the fields, and for an invalid table what is wrong with it and the error
    fields = tables.to_json(data)["fields"]
    fields["invalid"] = None if bad is None else {"field": tables.FIELD_NAMES[bad[0]], "reason": bad[1]}
    if err is not None:
        fields.update(error=str(err), code=err.exit_code)
    print(json.dumps(fields, allow_nan=False))
    return 0 if err is None else err.exit_code


def _targets(args: argparse.Namespace) -> list[tuple[str, Path]]:
    """(port, table file) pairs of a push/verify: one, or with --all every port of --ports paired
    with the table in the directory made for its UID (TableError names a port without one)."""
    from uwbcal import tables

    if not args.all:
        if args.port is None:
            raise TableError("give --port PORT (or --all --ports P1,P2,... DIR)")
        return [(args.port, args.table)]
    if not args.ports:
        raise TableError("--all needs --ports P1,P2,... (the stations to push to)")
    if not args.table.is_dir():
        raise TableError(f"{args.table}: with --all, give the directory `uwbcal table build` wrote")
    by_uid = {tables.decode(tables.load(f)).uid: f for f in sorted(args.table.glob("*.json"))}
    out: list[tuple[str, Path]] = []
    for port in args.ports.split(","):
        dev = _open(port)
        try:
            uid = _station_uid(dev)
        finally:
            dev.close()
        if uid not in by_uid:
            raise TableError(f"{port}: no table in {args.table} is made for its UID {uid.hex()}")
        out.append((port, by_uid[uid]))
    return out


def run_push(args: argparse.Namespace) -> int:
    """Check, write and commit a table (or every station's with --all); the station checks again."""
    from uwbcal import tables

    done: list[dict[str, Any]] = []
    for port, path in _targets(args):
        data = tables.load(path)
        dev = _open(port)
        try:
            uid = _station_uid(dev)
            r = tables.push(dev, data, uid=uid, radio=(args.channel, args.prf, args.preamble),
                            force=args.force)
        finally:
            dev.close()
        done.append({"port": port, "table": str(path), "slot": r.slot, "sequence": r.sequence})
    text = [f"{d['port']}: {d['table']} written to slot {d['slot']}, sequence {d['sequence']}" for d in done]
    hint = "next: uwbcal table verify " + ("--all --ports " + args.ports + f" {args.table}" if args.all
                                          else f"--port {args.port} {args.table}")
    _emit(args, {"pushed": done, "next": hint}, "\n".join([*text, hint]))
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
        _emit(args, tables.to_json(data), tables.describe(data))
    else:
        tables.save(args.out, data)
        _emit(args, {"file": str(args.out), "size": len(data), "crc32": f"0x{tables.decode(data).crc32:08X}"},
              f"wrote {args.out}: {len(data)} bytes, crc32 0x{tables.decode(data).crc32:08X}")
    return 0


def _pull_or_none(dev: Any, port: str) -> bytes:
    """The station's table (TableError when it has none)."""
    from uwbcal import tables
    from uwbcal.link import proto_gen as pg
    from uwbcal.link.client import ErrorResponse

    try:
        return tables.pull(dev)
    except ErrorResponse as exc:
        if exc.code == pg.ERR_NOT_FOUND:
            raise TableError(f"{port}: the station has no table") from None
        raise


def run_verify(args: argparse.Namespace) -> int:
    """Exit 0 when every station's active table is byte for byte its file's and applied."""
    from uwbcal import tables

    results: list[dict[str, Any]] = []
    for port, path in _targets(args):
        want = tables.load(path)
        dev = _open(port)
        try:
            got = _pull_or_none(dev, port)
            i = tables.info(dev)
        finally:
            dev.close()
        if got != want:
            diff = next(k for k in range(min(len(got), len(want)) + 1)
                        if k == min(len(got), len(want)) or got[k] != want[k])
            raise TableError(f"{port}: the station's table differs from {path} (first at byte {diff}, "
                             f"field {tables.field_at(diff)})")
        results.append({"port": port, "table": str(path), "matches": True, "applied": bool(i.applied),
                        "crc32": f"0x{i.table_crc32:08X}", "slot": i.active})
    lines = []
    for r in results:
        if r["applied"]:
            lines.append(f"{r['port']}: table matches {r['table']} (crc32 {r['crc32']}, slot {r['slot']})")
        else:
            lines.append(f"{r['port']}: table matches but the station does not apply it")
    _emit(args, {"verified": results}, "\n".join(lines))
    return 0 if all(r["applied"] for r in results) else 1


def run_info(args: argparse.Namespace) -> int:
    """Slot states and sequences."""
    from uwbcal import tables

    dev = _open(args.port)
    try:
        i = tables.info(dev)
    finally:
        dev.close()
    _emit(args, {"port": args.port, **dataclasses.asdict(i)}, tables.describe_info(i))
    return 0


def run_erase(args: argparse.Namespace) -> int:
    """Erase both slots."""
    from uwbcal import tables

    dev = _open(args.port)
    try:
        tables.erase(dev)
    finally:
        dev.close()
    _emit(args, {"port": args.port, "erased": True}, f"{args.port}: tables erased")
    return 0
