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
    from uwbcal.commands import _session
    from uwbcal.sessions import plan

    p = subparsers.add_parser("drift", help="clock drift session (P1/P2/P3 at one gain)",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--tx", help="port of the transmitting station")
    p.add_argument("--rx", help="port of the receiving station")
    p.add_argument("--count", type=int, default=2000, help="triplets")
    p.add_argument("--spacing", default="2ms", help="P1->P2 and P2->P3 spacing (e.g. 2ms, 150us)")
    p.add_argument("--period", default=None, help="P1 to next P1 (default 3 x spacing)")
    p.add_argument("--gain", default=hex(plan.TOP_GAIN), help="TX_POWER octet of every message")
    p.add_argument("--distance", type=float, default=None, help="nominal TX-RX distance, m (metadata)")
    _session.add_common_args(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run (or resume) a drift session, then the drift analysis."""
    from uwbcal.commands import _session as cs
    from uwbcal.sessions import plan as pl
    from uwbcal.sessions import runner as r

    with cs.command_stations(args, "drift", ("tx", "rx")) as ((tx, rx), radio, sti):

        def meta() -> dict[str, Any]:
            spacing = pl.parse_duration_us(args.spacing)
            period = pl.parse_duration_us(args.period) if args.period else pl.default_period_us(spacing)
            g = pl.parse_octet(args.gain)
            settings = {"command": "drift", "tx_port": args.tx, "rx_port": args.rx,
                        "tx_station": sti[0].station_id, "rx_station": sti[1].station_id,
                        "per_step": args.count, "spacing_us": spacing, "period_us": period, "gain13": g,
                        "gains2": [g], "distance_m": args.distance, "tx_antd": args.tx_antd,
                        "rx_antd": args.rx_antd}
            return r.session_meta("drift", "uwbcal drift", sti, radio, settings)

        return cs.run_triplet_command(args, tx, rx, sti, meta, "drift", "drift")
