"""`uwbcal sim [--stations N] [--seed S] [--scenario S] [--board native|evk1000] [--json]`:
run simulated stations until SIGINT/SIGTERM.

Prints ``station <id>: <port>`` per station once each answers PING (with --json one line
``{"stations": [{"id": 1, "port": "/dev/pts/7"}, ...]}``), then waits; on SIGINT or SIGTERM it
stops every process it started and exits 0. If a station dies meanwhile, it stops the others
and exits non-zero. A running world is announced (uwbcal.simregistry) so that `uwbcal ports`
lists its stations and, from another terminal, with a radio medium (--scenario):

  uwbcal sim move 2 --to 1.5,0,0      put station 2 at x=1.5 m, y=0, z=0 (m)
  uwbcal sim where 2                  print station 2's position (m)
  uwbcal sim list                     the running simulated worlds and their stations

(--pid P picks the world when several run.)
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import sys
import threading
from pathlib import Path
from types import FrameType
from typing import Any

from uwbcal.physics.scenario import BOARDS
from uwbcal.simstations import SimError, SimWorld


def register(sub: Any) -> None:
    p = sub.add_parser("sim", help="run simulated stations on ptys until interrupted; move them",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("action", nargs="?", choices=("move", "where", "list"), default=None,
                   help="control a running world instead of starting one")
    p.add_argument("station", nargs="?", type=int, default=None, help="station id (move, where)")
    p.add_argument("--to", default=None, metavar="X,Y,Z", help="move: new position, m")
    p.add_argument("--pid", type=int, default=None, help="move/where: the world of this `uwbcal sim` pid")
    p.add_argument("--stations", type=int, default=2, help="number of stations, ids 1..N (default 2)")
    p.add_argument("--seed", type=int, default=0, help="seed of the simulation (default 0)")
    p.add_argument("--json", action="store_true", help="print one JSON line with the ports")
    p.add_argument("--scenario", default=None, metavar="FILE",
                   help="scenario TOML (or example name): start the radio medium and its stations")
    p.add_argument("--board", choices=BOARDS, default=None,
                   help="run every station as this board (default: native, or the scenario's "
                        "per-station `board` key); evk1000 runs build/evk1000/uwbcal-evk1000.bin "
                        "in the emulator (uwbcal.evk1000)")
    p.set_defaults(func=run)


def parse_position(text: str) -> tuple[float, float, float]:
    """'1.5,0,0' -> (1.5, 0.0, 0.0), m (SimError names what is wrong)."""
    try:
        v = tuple(float(x) for x in text.split(","))
    except ValueError:
        v = ()
    if len(v) != 3 or not all(math.isfinite(x) for x in v):
        raise SimError(f"--to {text!r}: give three numbers in m, e.g. 1.5,0,0")
    return (v[0], v[1], v[2])


def control(args: argparse.Namespace) -> int:
    """`sim move|where|list`: talk to a running world's medium."""
    from uwbcal import simregistry
    from uwbcal.medium.launcher import control as medium_control

    if args.action == "list":
        worlds = simregistry.running()
        if args.json:
            print(json.dumps({"worlds": worlds}))
            return 0
        if not worlds:
            print("no simulated world is running (start one: uwbcal sim --scenario two_stations)")
        for w in worlds:
            st = ", ".join(f"{s['id']}: {s['port']}" for s in w["stations"])
            sc = f"; scenario {w['scenario']}" if w.get("scenario") else ""
            print(f"pid {w['pid']}: stations {st}{sc}")
        return 0
    if args.station is None:
        raise SimError(f"sim {args.action}: give the station id (e.g. uwbcal sim {args.action} 2)")
    world = simregistry.the_world(args.pid)
    if args.action == "move":
        if args.to is None:
            raise SimError("sim move: give --to X,Y,Z (m)")
        x, y, z = parse_position(args.to)
        medium_control(world["medium_socket"], f"move {args.station} {x!r} {y!r} {z!r}")
    pos = [float(v) for v in medium_control(world["medium_socket"], f"where {args.station}").split()[1:]]
    if args.json:
        print(json.dumps({"station": args.station, "position_m": pos, "pid": world["pid"]}))
    else:
        print(f"station {args.station} at {pos[0]:g}, {pos[1]:g}, {pos[2]:g} m")
    return 0


def run(args: argparse.Namespace) -> int:
    if args.action is not None:
        return control(args)
    if not 1 <= args.stations <= 64:
        raise SimError("--stations must be 1..64")
    stop = threading.Event()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        stop.set()

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    scenario = None
    if getattr(args, "scenario", None):
        from uwbcal.physics.scenario import find_scenario

        scenario = find_scenario(args.scenario)
    world = SimWorld(n_stations=args.stations, seed=args.seed, scenario=scenario,
                     board=getattr(args, "board", None) or "native")
    announced: Path | None = None
    try:
        world.start()
        from uwbcal import simregistry

        announced = simregistry.announce([{"id": s.id, "port": s.port} for s in world.stations],
                                         world.medium_socket, None if scenario is None else str(scenario))
        if args.json:
            print(json.dumps({"stations": [{"id": s.id, "port": s.port} for s in world.stations]}))
        else:
            for s in world.stations:
                print(f"station {s.id}: {s.port}")
        sys.stdout.flush()
        while not stop.wait(0.25):
            dead = [s for s in world.stations if s.process.poll() is not None]
            if dead:
                s = dead[0]
                raise SimError(f"station {s.id} exited with code {s.process.returncode} (log: {s.log_path})")
    finally:
        world.stop()
        if announced is not None:
            announced.unlink(missing_ok=True)
        for signum, handler in old.items():
            signal.signal(signum, handler)
    return 0
