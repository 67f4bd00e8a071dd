"""`uwbcal range --ref P --tag P --count N --method paper|ss|ds --distance M --out S.db`.

Several distances in one session: `--distances 1,2,4,7 --moves` (--count exchanges at each).
On simulated stations (`uwbcal sim --scenario ...`) the tag is moved along x from the
reference by the medium; on boards the command asks you to move the tag and press Enter.

Two-way ranging between a reference and a tag: the paper's three-message exchange (paper),
single-sided (ss) or asymmetric double-sided (ds) TWR, every timestamp recorded as it
arrives. Ends with `uwbcal analyze twr` (with the power curves of --power sessions, if any).
`--resume S.db` continues a broken session. Works against boards and simulated stations.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
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
    p.add_argument("--distance", type=float, default=None, help="true (tape-measured) distance, m")
    p.add_argument("--distances", default=None, metavar="D1,D2,...",
                   help="several distances, m, --count exchanges at each (needs --moves)")
    p.add_argument("--moves", action="store_true",
                   help="move the tag between --distances: the simulator moves it, on boards you are asked")
    p.add_argument("--period", default="10ms", help="M1 to next M1")
    p.add_argument("--reply", default="1ms", help="delay between a reception and the reply")
    p.add_argument("--gain", default=hex(plan.TOP_GAIN), help="TX_POWER octet of every message")
    p.add_argument("--power", type=Path, action="append", default=[], metavar="P.db|T.json",
                   help="calibrate session(s) or tables whose power curves correct the ranges (repeatable)")
    _session.add_common_args(p)
    p.set_defaults(func=run)


def parse_distances(text: str) -> list[float]:
    """'1,2,4,7' -> [1.0, 2.0, 4.0, 7.0] m (RunError names a bad entry)."""
    from uwbcal.sessions.runner import RunError

    out = []
    for part in text.split(","):
        try:
            v = float(part)
        except ValueError:
            raise RunError(f"--distances: {part!r} is not a number of metres (e.g. 1,2,4,7)") from None
        if not 0 < v < 1000:
            raise RunError(f"--distances: {v:g} m is not a distance (0 .. 1000 m)")
        out.append(v)
    return out


def placer(ref_port: str, tag_port: str, ref_id: int, tag_id: int) -> Callable[[float], None]:
    """How the tag gets to each distance: the medium of a running `uwbcal sim` moves it along x
    from the reference; for boards, a prompt on stdin (RunError when stdin is closed)."""
    from uwbcal import simregistry
    from uwbcal.medium.launcher import control
    from uwbcal.sessions.runner import RunError

    world = simregistry.world_of_port(tag_port)
    if world is not None and world.get("medium_socket"):
        sock = str(world["medium_socket"])

        def move(d: float) -> None:
            x, y, z = (float(v) for v in control(sock, f"where {ref_id}").split()[1:])
            control(sock, f"move {tag_id} {x + d!r} {y!r} {z!r}")
            print(f"moved station {tag_id} to {d:g} m from station {ref_id} (simulated)", file=sys.stderr)

        return move

    def ask(d: float) -> None:
        print(f"move the tag ({tag_port}) to {d:g} m from the reference ({ref_port}), then press Enter",
              file=sys.stderr, flush=True)
        if not sys.stdin.readline():
            raise RunError(f"no answer on stdin while waiting for the tag at {d:g} m")

    return ask


#: A declared distance further than this from a simulated world's true one is questioned, m.
SIM_DISTANCE_TOLERANCE_M = 0.01


def check_simulated_distance(ref_port: str, tag_port: str, ref_id: int, tag_id: int,
                             declared_m: float) -> float | None:
    """On simulated stations, the medium's true distance (m); warns on stderr when --distance
    declares another. None on boards (their distance is the user's tape measure)."""
    import math

    from uwbcal import simregistry
    from uwbcal.medium.launcher import control

    world = simregistry.world_of_port(tag_port)
    if world is None or not world.get("medium_socket") or simregistry.world_of_port(ref_port) != world:
        return None
    sock = str(world["medium_socket"])
    a = [float(v) for v in control(sock, f"where {ref_id}").split()[1:]]
    b = [float(v) for v in control(sock, f"where {tag_id}").split()[1:]]
    true_m = math.dist(a, b)
    if abs(true_m - declared_m) > SIM_DISTANCE_TOLERANCE_M:
        print(f"uwbcal range: warning: --distance {declared_m:g} m, but the simulated stations are "
              f"{true_m:.3f} m apart (move one: uwbcal sim move {tag_id} --to X,Y,Z); Z will absorb the "
              f"difference", file=sys.stderr)
    return true_m


def run(args: argparse.Namespace) -> int:
    """Run (or resume) a ranging session at one or several distances, then the TWR analysis."""
    from uwbcal.commands import _session as cs
    from uwbcal.sessions import plan as pl
    from uwbcal.sessions import runner as r

    distances = parse_distances(args.distances) if args.distances else None
    if distances is not None and args.distance is not None:
        raise r.RunError("give --distance (one) or --distances (several), not both")
    if distances is not None and len(distances) > 1 and not args.moves:
        raise r.RunError("--distances with several values needs --moves (the tag moves between them)")
    with cs.command_stations(args, "range", ("ref", "tag")) as ((ref, tag), radio, sti):
        if args.distance is not None:
            check_simulated_distance(args.ref, args.tag, sti[0].station_id, sti[1].station_id, args.distance)

        def meta() -> dict[str, Any]:
            settings = {"command": "range", "ref_port": args.ref, "tag_port": args.tag,
                        "ref_station": sti[0].station_id, "tag_station": sti[1].station_id,
                        "method": args.method, "count": args.count,
                        "period_us": pl.parse_duration_us(args.period),
                        "reply_us": pl.parse_duration_us(args.reply), "gain": pl.parse_octet(args.gain),
                        "distance_m": args.distance, "distances_m": distances,
                        "tx_antd": args.tx_antd, "rx_antd": args.rx_antd}
            return r.session_meta("twr", "uwbcal range", sti, radio, settings)

        with cs.command_session(args, sti, meta) as (session, st):
            plan = pl.RangePlan.from_settings(st)
            if st.get("distances_m"):
                place = placer(args.ref, args.tag, sti[0].station_id, sti[1].station_id)
                res = r.run_ranges_at(ref, tag, session, plan, sti[0].station_id, sti[1].station_id,
                                      [float(d) for d in st["distances_m"]], place,
                                      progress=not args.no_progress)
            else:
                res = r.run_ranges(ref, tag, session, plan, sti[0].station_id, sti[1].station_id,
                                   st.get("distance_m"), progress=not args.no_progress)
            r.record_run(session, "range", res)
            own = cs.pull_tables([ref, tag], [sti[0].station_id, sti[1].station_id])
            return cs.finish(args, session, "twr", res, args.power, station_tables=own)
