"""`uwbcal range --ref P --tag P --count N --method paper|ss|ds --distance M --out S.db`.

Two-way ranging between a reference and a tag: the paper's three-message exchange (paper),
single-sided (ss) or asymmetric double-sided (ds) TWR, every timestamp recorded as it
arrives. Ends with `uwbcal analyze twr` (with the power curves of --power sessions, if any).
`--resume S.db` continues a broken session. Works against boards and simulated stations.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any


def register(subparsers: Any) -> None:
    """Add the ``range`` command."""
    from uwbcal.sessions import runner

    p = subparsers.add_parser("range", help="two-way ranging session (paper, ss or ds TWR)",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--ref", help="port of the reference station")
    p.add_argument("--tag", help="port of the tag station")
    p.add_argument("--count", type=int, default=1000, help="exchanges")
    p.add_argument("--method", choices=("paper", "ss", "ds"), default="paper")
    p.add_argument("--distance", type=float, default=None, help="true (nominal) distance, m")
    p.add_argument("--period", default="10ms", help="M1 to next M1")
    p.add_argument("--reply", default="1ms", help="delay between a reception and the reply")
    p.add_argument("--gain", default=hex(runner.TOP_GAIN), help="TX_POWER octet of every message")
    p.add_argument("--power", type=Path, action="append", default=[], metavar="P.db",
                   help="calibrate session(s) whose power curves correct the ranges (repeatable)")
    runner.add_common_args(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run (or resume) a ranging session, then the TWR analysis."""
    from uwbcal.errors import SessionError
    from uwbcal.sessions import runner as r

    if args.resume is None and (args.ref is None or args.tag is None):
        raise r.RunError("give --ref PORT and --tag PORT")
    if args.resume is not None:
        from uwbcal.sessions.store import Session

        with Session.open(args.resume, readonly=True) as s0:
            st0 = s0.meta.get("settings") or {}
        if st0.get("command") != "range":
            raise SessionError(f"{args.resume}: not a range session ({st0.get('command')!r})")
        args.ref = args.ref or st0["ref_port"]
        args.tag = args.tag or st0["tag_port"]
    ref, tag = r.open_devices([args.ref, args.tag], args.timeout)
    with ref, tag:
        radio = dict(r.PAPER_RADIO)
        sti = [r.prepare(d, radio, args.tx_antd, args.rx_antd) for d in (ref, tag)]

        def meta() -> dict[str, Any]:
            settings = {"command": "range", "ref_port": args.ref, "tag_port": args.tag,
                        "ref_station": sti[0].station_id, "tag_station": sti[1].station_id,
                        "method": args.method, "count": args.count,
                        "period_us": r.parse_duration_us(args.period),
                        "reply_us": r.parse_duration_us(args.reply), "gain": r.parse_octet(args.gain),
                        "distance_m": args.distance, "tx_antd": args.tx_antd, "rx_antd": args.rx_antd}
            return r.session_meta("twr", "uwbcal range", sti, radio, settings)

        session, st = r.open_or_create(args.out, args.resume, meta, args.force)
        with session:
            r.check_same_stations(session, sti)
            for info in sti:
                session.add_station(info.station_id, info.uid, info.board, {"port": info.port,
                                                                            "firmware": info.firmware})
            plan = r.RangePlan(method=str(st["method"]), count=int(st["count"]),
                               period_us=int(st["period_us"]), reply_us=int(st["reply_us"]),
                               gain=int(st["gain"]))
            last = session.last_seq("ranges")
            done = 0 if last is None else last + 1
            res = r.run_ranges(ref, tag, session, plan, sti[0].station_id, sti[1].station_id,
                               st.get("distance_m"), done=done, progress=not args.no_progress)
            r.record_run(session, "range", res)
            return r.finish(args, session, "twr", res, args.power)
