"""`uwbcal simulate SCENARIO --experiment drift|power|twr ... --out S.db`: a simulated session.

Writes a session file (docs/SESSIONS.md) with the records and the simulation truth, made by
the vectorised simulator (uwbcal.vectorsim) from a scenario (docs/SCENARIOS.md).
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from typing import Any

from uwbcal.errors import ScenarioError

_UNITS = {"": 1.0, "s": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "ns": 1e-9, "min": 60.0}


def parse_duration(text: str) -> float:
    """A duration with an optional unit (s, ms, us, ns, min) in seconds: "2ms" -> 0.002."""
    m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)\s*([a-zµ]*)\s*", text)
    if not m or m.group(2) not in _UNITS:
        raise argparse.ArgumentTypeError(f"not a duration: {text!r} (e.g. 2ms, 150us, 0.05s)")
    value = float(m.group(1)) * _UNITS[m.group(2)]
    if value <= 0:
        raise argparse.ArgumentTypeError(f"duration must be positive: {text!r}")
    return value


def _distances(text: str) -> list[float]:
    try:
        out = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a comma-separated list of metres: {text!r}") from None
    if not out or any(d <= 0 for d in out):
        raise argparse.ArgumentTypeError(f"distances must be positive metres: {text!r}")
    return out


def register(subparsers: Any) -> None:
    """Add the `simulate` subcommand."""
    p = subparsers.add_parser(
        "simulate",
        help="simulate a drift run, power sweep or TWR run into a session file",
        description="Simulate a session from a scenario (a TOML path or an example name such as "
        "paper_cable, paper_antenna, two_stations) and write it as a session file.",
    )
    p.add_argument("scenario", help="scenario TOML file or example name")
    p.add_argument("--experiment", "-e", choices=("drift", "power", "twr"), required=True)
    p.add_argument("--count", type=int, default=4000, help="triplets of a drift run (default 4000)")
    p.add_argument(
        "--spacing",
        type=parse_duration,
        default=2e-3,
        help="P1->P2->P3 spacing (default 2ms; the paper also uses 150us)",
    )
    p.add_argument(
        "--period",
        type=parse_duration,
        default=None,
        help="time between triplets / exchanges (default 50ms triplets, 20ms TWR)",
    )
    p.add_argument("--step-db", type=float, default=0.5, help="power sweep: P2 gain step, dB (default 0.5)")
    p.add_argument("--steps", type=int, default=40, help="power sweep: number of P2 gain levels (default 40)")
    p.add_argument(
        "--per-step", type=int, default=2000, help="power sweep: triplets per level (default 2000)"
    )
    p.add_argument(
        "--distances",
        type=_distances,
        default=None,
        help="TWR: comma-separated distances in m (default the paper's 11 from 0.562 to 3.515)",
    )
    p.add_argument(
        "--per-distance", type=int, default=2000, help="TWR: exchanges per distance (default 2000)"
    )
    p.add_argument("--reply", type=parse_duration, default=1e-3, help="TWR reply delays (default 1ms)")
    p.add_argument("--tx-station", "--tx", dest="tx", type=int, default=None, metavar="ID",
                   help="TX / reference station id of the scenario (default the first)")
    p.add_argument("--rx-station", "--rx", dest="rx", type=int, default=None, metavar="ID",
                   help="RX / tag station id of the scenario (default the second)")
    p.add_argument(
        "--gain",
        type=lambda s: int(s, 0),
        default=None,
        help="TX_POWER octet of P1/P3 or TWR messages (default 0x1f: coarse 0, fine 15.5 dB)",
    )
    p.add_argument("--seed", type=int, default=None, help="run seed (default the scenario's)")
    p.add_argument("--effects-off", default="", help="comma-separated effects to switch off")
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="EFFECT.PARAM=VALUE",
        help="override an effect parameter (repeatable), e.g. interference.amplitude_ps=20",
    )
    p.add_argument(
        "--out", "-o", default=None, help="session file to write (default <scenario>_<experiment>.db)"
    )
    p.add_argument("--force", action="store_true", help="overwrite an existing session file")
    p.add_argument("--json", action="store_true", help="print a JSON summary")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Build the schedule, simulate it, write the session, print a summary."""
    import numpy as np

    from uwbcal import vectorsim as sim
    from uwbcal.physics import load_scenario

    sc = load_scenario(args.scenario)
    off = [x.strip() for x in args.effects_off.split(",") if x.strip()]
    if off:
        sc = sc.with_effects(enabled={name: False for name in off})
    overrides: dict[str, dict[str, float]] = {}
    for item in args.set:
        m = re.fullmatch(r"\s*([a-z_0-9]+)\.([a-z_0-9]+)\s*=\s*(\S+)\s*", item)
        if not m:
            raise ScenarioError(f"--set {item!r}: expected EFFECT.PARAM=VALUE")
        try:
            value = float(m.group(3))
        except ValueError:
            raise ScenarioError(f"--set {item!r}: {m.group(3)!r} is not a number") from None
        overrides.setdefault(m.group(1), {})[m.group(2)] = value
    if overrides:
        sc = sc.with_effects(params=overrides)
    gain = sim.DEFAULT_GAIN if args.gain is None else args.gain
    if not 0 <= gain <= 0xFF:
        raise ScenarioError(f"--gain {gain:#x} is not a TX_POWER octet")
    settings: dict[str, Any] = {"spacing_s": args.spacing, "tx": args.tx, "rx": args.rx, "gain": gain}
    schedule: sim.TripletSchedule | sim.RangeSchedule
    if args.experiment == "drift":
        period = args.period or 0.05
        schedule = sim.drift_schedule(
            sc, args.count, spacing_s=args.spacing, period_s=period, tx=args.tx, rx=args.rx, gain=gain
        )
        settings.update(count=args.count, period_s=period)
    elif args.experiment == "power":
        period = args.period or 0.05
        schedule = sim.power_schedule(
            sc,
            steps=args.steps,
            per_step=args.per_step,
            step_db=args.step_db,
            spacing_s=args.spacing,
            period_s=period,
            tx=args.tx,
            rx=args.rx,
            gain13=gain,
        )
        settings.update(steps=args.steps, per_step=args.per_step, step_db=args.step_db, period_s=period)
    else:
        period = args.period or 0.02
        dists = args.distances or list(sim.PAPER_DISTANCES_M)
        schedule = sim.twr_schedule(
            sc,
            dists,
            per_distance=args.per_distance,
            period_s=period,
            reply_s=args.reply,
            reply2_s=args.reply,
            ref=args.tx,
            tag=args.rx,
            gain=gain,
        )
        settings.update(
            distances_m=dists, per_distance=args.per_distance, period_s=period, reply_s=args.reply
        )
    if off:
        settings["effects_off"] = off
    if overrides:
        settings["effect_params"] = overrides
    out = args.out or f"{sc.name}_{args.experiment}.db"
    seed = sc.seed if args.seed is None else args.seed
    path = sim.simulate_session(
        sc, schedule, out, seed=seed, experiment=args.experiment, settings=settings, overwrite=args.force
    )
    summary = {
        "session": str(path),
        "scenario": sc.name,
        "experiment": args.experiment,
        "seed": seed,
        "records": len(schedule),
        "table": "triplets" if isinstance(schedule, sim.TripletSchedule) else "ranges",
        "duration_s": float(np.max(schedule.t_s) - np.min(schedule.t_s)) if len(schedule) else 0.0,
    }
    if args.json:
        json.dump(summary, sys.stdout)
        sys.stdout.write("\n")
    else:
        print(
            f"wrote {summary['records']} {summary['table']} ({args.experiment}, scenario {sc.name}, "
            f"seed {seed}) to {path}"
        )
    return 0
