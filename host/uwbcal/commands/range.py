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
    from uwbcal.commands import _session
    from uwbcal.sessions import plan

    p = subparsers.add_parser("range", help="two-way ranging session (paper, ss or ds TWR)",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--ref", help="port of the reference station")
    p.add_argument("--tag", help="port of the tag station")
    p.add_argument("--count", type=int, default=1000, help="exchanges")
    p.add_argument("--method", choices=("paper", "ss", "ds"), default="paper")
    p.add_argument("--distance", type=float, default=None, help="true (nominal) distance, m")
    p.add_argument("--period", default="10ms", help="M1 to next M1")
    p.add_argument("--reply", default="1ms", help="delay between a reception and the reply")
    p.add_argument("--gain", default=hex(plan.TOP_GAIN), help="TX_POWER octet of every message")
    p.add_argument("--power", type=Path, action="append", default=[], metavar="P.db",
                   help="calibrate session(s) whose power curves correct the ranges (repeatable)")
    _session.add_common_args(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run (or resume) a ranging session, then the TWR analysis."""
    from uwbcal.commands import _session as cs
    from uwbcal.sessions import plan as pl
    from uwbcal.sessions import runner as r

    with cs.command_stations(args, "range", ("ref", "tag")) as ((ref, tag), radio, sti):

        def meta() -> dict[str, Any]:
            settings = {"command": "range", "ref_port": args.ref, "tag_port": args.tag,
                        "ref_station": sti[0].station_id, "tag_station": sti[1].station_id,
                        "method": args.method, "count": args.count,
                        "period_us": pl.parse_duration_us(args.period),
                        "reply_us": pl.parse_duration_us(args.reply), "gain": pl.parse_octet(args.gain),
                        "distance_m": args.distance, "tx_antd": args.tx_antd, "rx_antd": args.rx_antd}
            return r.session_meta("twr", "uwbcal range", sti, radio, settings)

        with cs.command_session(args, sti, meta) as (session, st):
            res = r.run_ranges(ref, tag, session, pl.RangePlan.from_settings(st), sti[0].station_id,
                               sti[1].station_id, st.get("distance_m"),
                               done=r.records_done(session, "ranges"), progress=not args.no_progress)
            r.record_run(session, "range", res)
            return cs.finish(args, session, "twr", res, args.power)
