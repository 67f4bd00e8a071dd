"""`uwbcal drift --tx P --rx P --count N --spacing 2ms --out S.db`: a clock drift session.

The TX station sends --count P1/P2/P3 triplets, all at one gain; the RX station streams every
triplet, written to the session as it arrives. Ends with `uwbcal analyze drift` (eq. 1 of
the paper against the uncorrected difference and the carrier integrator). `--resume S.db`
continues a broken session. Works against boards and simulated stations alike.
"""

from __future__ import annotations

import argparse
from typing import Any


def register(subparsers: Any) -> None:
    """Add the ``drift`` command."""
    from uwbcal.sessions import runner

    p = subparsers.add_parser("drift", help="clock drift session (P1/P2/P3 at one gain)",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--tx", help="port of the transmitting station")
    p.add_argument("--rx", help="port of the receiving station")
    p.add_argument("--count", type=int, default=2000, help="triplets")
    p.add_argument("--spacing", default="2ms", help="P1->P2 and P2->P3 spacing (e.g. 2ms, 150us)")
    p.add_argument("--period", default=None, help="P1 to next P1 (default 3 x spacing)")
    p.add_argument("--gain", default=hex(runner.TOP_GAIN), help="TX_POWER octet of every message")
    p.add_argument("--distance", type=float, default=None, help="nominal TX-RX distance, m (metadata)")
    runner.add_common_args(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run (or resume) a drift session, then the drift analysis."""
    from uwbcal.errors import SessionError
    from uwbcal.sessions import runner as r

    if args.resume is None and (args.tx is None or args.rx is None):
        raise r.RunError("give --tx PORT and --rx PORT")
    if args.resume is not None:
        from uwbcal.sessions.store import Session

        with Session.open(args.resume, readonly=True) as s0:
            st0 = s0.meta.get("settings") or {}
        if st0.get("command") != "drift":
            raise SessionError(f"{args.resume}: not a drift session ({st0.get('command')!r})")
        args.tx = args.tx or st0["tx_port"]
        args.rx = args.rx or st0["rx_port"]
    tx, rx = r.open_devices([args.tx, args.rx], args.timeout)
    with tx, rx:
        radio = dict(r.PAPER_RADIO)
        sti = [r.prepare(d, radio, args.tx_antd, args.rx_antd) for d in (tx, rx)]

        def meta() -> dict[str, Any]:
            spacing = r.parse_duration_us(args.spacing)
            period = r.parse_duration_us(args.period) if args.period else r.default_period_us(spacing)
            g = r.parse_octet(args.gain)
            settings = {"command": "drift", "tx_port": args.tx, "rx_port": args.rx,
                        "tx_station": sti[0].station_id, "rx_station": sti[1].station_id,
                        "per_step": args.count, "spacing_us": spacing, "period_us": period, "gain13": g,
                        "gains2": [g], "distance_m": args.distance, "tx_antd": args.tx_antd,
                        "rx_antd": args.rx_antd}
            return r.session_meta("drift", "uwbcal drift", sti, radio, settings)

        session, st = r.open_or_create(args.out, args.resume, meta, args.force)
        with session:
            r.check_same_stations(session, sti)
            for info in sti:
                session.add_station(info.station_id, info.uid, info.board, {"port": info.port,
                                                                            "firmware": info.firmware})
            plan = r.TripletPlan(per_step=int(st["per_step"]), spacing_us=int(st["spacing_us"]),
                                 period_us=int(st["period_us"]), gain13=int(st["gain13"]),
                                 gains2=tuple(int(g) for g in st["gains2"]))
            last = session.last_seq("triplets")
            done = 0 if last is None else last + 1
            res = r.run_triplets(tx, rx, session, plan, sti[0].station_id, sti[1].station_id,
                                 st.get("distance_m"), done=done, progress=not args.no_progress)
            r.record_run(session, "drift", res)
            return r.finish(args, session, "drift", res)
