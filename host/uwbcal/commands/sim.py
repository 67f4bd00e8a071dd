"""`uwbcal sim [--stations N] [--seed S] [--scenario S] [--board native|evk1000] [--json]`:
run simulated stations until SIGINT/SIGTERM.

Prints ``station <id>: <port>`` per station once each answers PING (with --json one line
``{"stations": [{"id": 1, "port": "/dev/pts/7"}, ...]}``), then waits; on SIGINT or SIGTERM it
stops every process it started and exits 0. If a station dies meanwhile, it stops the others
and exits non-zero.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
from types import FrameType
from typing import Any

from uwbcal.physics.scenario import BOARDS
from uwbcal.simworld import SimError, SimWorld


def register(sub: Any) -> None:
    p = sub.add_parser("sim", help="run simulated stations on ptys until interrupted")
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


def run(args: argparse.Namespace) -> int:
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
    try:
        world.start()
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
        for signum, handler in old.items():
            signal.signal(signum, handler)
    return 0
