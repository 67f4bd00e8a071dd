"""`uwbcal calibrate --tx P --rx P --step-db 0.5 --steps K --per-step N --spacing 2ms --out S.db`.

Power self-calibration (the paper's method): the TX station sends P1/P2/P3 triplets, P1 and
P3 at a constant gain, P2 stepping down by --step-db per step; the RX station streams every
triplet, written to the session as it arrives. Ends with `uwbcal analyze power` on the
session. `--resume S.db` continues a broken session (no duplicate, no missing record).
Works against boards and simulated stations alike.

A fleet: `uwbcal calibrate --stations P1,P2,P3 ... --out fleet.db` runs the same sweep over
every ordered pair (each station transmits to each other), one session, one progress bar, one
summary; `uwbcal table build fleet.db --out tables/` then writes every station's table. A
fleet session is not resumable yet: re-run it (or the pairs that failed, with --tx/--rx).
"""

from __future__ import annotations

import argparse
import time
from typing import Any


def register(subparsers: Any) -> None:
    """Add the ``calibrate`` command."""
    from uwbcal.commands import _session
    from uwbcal.sessions import plan

    p = subparsers.add_parser("calibrate", help="power self-calibration session (P2 gain steps)",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--tx", help="port of the transmitting station")
    p.add_argument("--rx", help="port of the receiving station (the one being calibrated)")
    p.add_argument("--stations", default=None, metavar="P1,P2,...",
                   help="a fleet: ports of three or more stations (or two), every ordered pair calibrated")
    p.add_argument("--step-db", type=float, default=0.5, help="P2 gain step, dB (0.5 multiples)")
    p.add_argument("--steps", type=int, default=61,
                   help="number of gain steps (61 x 0.5 dB = 30 dB)")
    p.add_argument("--per-step", type=int, default=2000, help="triplets per step")
    p.add_argument("--spacing", default="2ms", help="P1->P2 and P2->P3 spacing (e.g. 2ms, 150us)")
    p.add_argument("--period", default=None, help="P1 to next P1 (default 3 x spacing: every message "
                                                   "one spacing after the previous)")
    p.add_argument("--gain13", default=hex(plan.TOP_GAIN), help="TX_POWER octet of P1/P3 and of the "
                                                                   "first P2 step (0x1f = coarse 0, fine 31)")
    p.add_argument("--coarse-step-db", type=float, default=3.0,
                   help="nominal coarse gain step used to build the ladder, dB")
    p.add_argument("--distance", type=float, default=None, help="nominal TX-RX distance, m (metadata)")
    _session.add_common_args(p)
    p.set_defaults(func=run)


def _sweep(args: argparse.Namespace) -> Any:
    """The sweep plan of the command line (sessions/plan.TripletPlan.sweep)."""
    from uwbcal.sessions import plan as pl

    spacing = pl.parse_duration_us(args.spacing)
    period = pl.parse_duration_us(args.period) if args.period else None
    return pl.TripletPlan.sweep(steps=args.steps, per_step=args.per_step, step_db=args.step_db,
                                spacing_us=spacing, period_us=period, gain13=pl.parse_octet(args.gain13),
                                coarse_step_db=args.coarse_step_db)


def run(args: argparse.Namespace) -> int:
    """Run (or resume) a calibration session, then the power analysis."""
    from uwbcal.commands import _session as cs
    from uwbcal.sessions import runner as r

    if args.stations is not None:
        return run_fleet(args)
    with cs.command_stations(args, "calibrate", ("tx", "rx")) as ((tx, rx), radio, sti):

        def meta() -> dict[str, Any]:
            sweep = _sweep(args)
            settings = {"command": "calibrate", "tx_port": args.tx, "rx_port": args.rx,
                        "tx_station": sti[0].station_id, "rx_station": sti[1].station_id,
                        "per_step": sweep.per_step, "spacing_us": sweep.spacing_us,
                        "period_us": sweep.period_us, "gain13": sweep.gain13, "gains2": list(sweep.gains2),
                        "step_db": args.step_db, "steps": args.steps,
                        "distance_m": args.distance, "tx_antd": args.tx_antd, "rx_antd": args.rx_antd}
            return r.session_meta("power", "uwbcal calibrate", sti, radio, settings)

        return cs.run_triplet_command(args, tx, rx, sti, meta, "calibrate", "power")


def run_fleet(args: argparse.Namespace) -> int:
    """Every ordered pair of ``--stations`` in one session, then the power analysis of all."""
    from contextlib import ExitStack

    from uwbcal.commands import _session as cs
    from uwbcal.sessions import runner as r

    ports = [p for p in args.stations.split(",") if p]
    if len(ports) < 2 or len(set(ports)) != len(ports):
        raise r.RunError(f"--stations needs two or more different ports, got {args.stations!r}")
    if args.tx or args.rx or args.resume:
        raise r.RunError("--stations replaces --tx/--rx, and a fleet session cannot be resumed yet")
    sweep = _sweep(args)
    devs = cs.open_devices(ports, args.timeout, args.retries)
    with ExitStack() as stack:
        for d in devs:
            stack.enter_context(d)
        radio = dict(r.PAPER_RADIO)
        sti = [r.prepare(d, radio, args.tx_antd, args.rx_antd) for d in devs]
        pairs = [(a, b) for a in range(len(devs)) for b in range(len(devs)) if a != b]
        settings = {"command": "calibrate", "fleet_ports": ports,
                    "pairs": [[sti[a].station_id, sti[b].station_id] for a, b in pairs],
                    "per_step": sweep.per_step, "spacing_us": sweep.spacing_us, "period_us": sweep.period_us,
                    "gain13": sweep.gain13, "gains2": list(sweep.gains2), "step_db": args.step_db,
                    "steps": args.steps, "distance_m": args.distance, "tx_antd": args.tx_antd,
                    "rx_antd": args.rx_antd}
        with cs.command_session(args, sti, lambda: r.session_meta("power", "uwbcal calibrate --stations",
                                                                  sti, radio, settings)) as (session, _st):
            bar = r.Progress(sweep.total * len(pairs), 0, f"{len(pairs)} pairs", not args.no_progress)
            seen = [0]

            def tick(next_seq: int) -> None:
                bar.update(next_seq - seen[0])
                seen[0] = next_seq

            results = []
            t0 = time.monotonic()
            try:
                for a, b in pairs:
                    seen[0] = 0
                    results.append(r.run_triplets(devs[a], devs[b], session, sweep, sti[a].station_id,
                                                  sti[b].station_id, args.distance, progress=False,
                                                  on_record=tick))
            finally:
                bar.close()
            losses: dict[str, Any] = {"n_missing": 0, "lost_frames": 0, "duplicates": 0, "index_gaps": 0,
                                      "per_pair": {}}
            for (a, b), res in zip(pairs, results, strict=True):
                for k in ("n_missing", "lost_frames", "duplicates", "index_gaps"):
                    losses[k] += int(res.losses.get(k, 0))
                losses["per_pair"][f"{sti[a].station_id}->{sti[b].station_id}"] = res.losses["n_missing"]
            total = r.RunResult(records=session.count("triplets"), expected=sweep.total * len(pairs),
                                wall_s=time.monotonic() - t0, losses=losses,
                                counters={"pairs": len(pairs)})
            r.record_run(session, "calibrate --stations", total)
            return cs.finish(args, session, "power", total)
