"""`uwbcal demo`: the main job on simulated stations, end to end, in a few minutes.

1. starts a simulated world of two stations (scenarios/two_stations.toml: the radio medium,
   the physics World, two native firmware stations on ptys);
2. calibrates both directions (power self-calibration, P2 stepped down by 1 dB over 30 dB,
   firmware in the loop), the stations 1 m apart;
3. moves the tag to a few distances (the medium's control socket) and runs the paper's
   three-message TWR at each;
4. analyses the ranges with and without the corrections (clock drift, power curves of both
   stations, Z from one known distance) and prints a short report with where the plots are.
Every session is an ordinary session file in --out, readable by `uwbcal analyze`.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path
from typing import Any

DISTANCES_M = (1.0, 2.0, 4.0, 7.0)


def register(sub: Any) -> None:
    """Add the ``demo`` command."""
    p = sub.add_parser("demo", help="run the demo on simulated stations (no hardware needed)",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--seed", type=int, default=0, help="run seed of the simulation (default 0)")
    p.add_argument("--scenario", default="two_stations", help="scenario file or example name")
    p.add_argument("--out", type=Path, default=Path("out/demo"), help="directory for sessions and plots")
    p.add_argument("--per-step", type=int, default=60, help="triplets per calibration step")
    p.add_argument("--count", type=int, default=300, help="TWR exchanges per distance")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.add_argument("--json", action="store_true",
                   help="print one JSON summary on stdout (the running commentary goes to stderr)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run the demo; returns 0 when every session completed (--json: one summary object)."""
    if not args.json:
        return _demo(args)[0]
    import contextlib
    import json
    import sys

    with contextlib.redirect_stdout(sys.stderr):
        rc, summary = _demo(args)
    print(json.dumps(summary))
    return rc


def _demo(args: argparse.Namespace) -> tuple[int, dict[str, Any]]:
    """The demo; returns (exit code, JSON-able summary)."""
    from uwbcal import dw1000
    from uwbcal.commands import _session as cs
    from uwbcal.commands import analyze as an
    from uwbcal.medium.launcher import MediumProcess
    from uwbcal.physics.scenario import find_scenario, load_scenario
    from uwbcal.sessions import plan as pl
    from uwbcal.sessions import runner as r
    from uwbcal.sessions.store import Session
    from uwbcal.simstations import SimWorld, station_binary

    t_start = time.monotonic()
    station_binary()        # a missing station is said before anything is written
    scenario_path = find_scenario(args.scenario)
    scenario = load_scenario(scenario_path)
    if len(scenario.stations) < 2:
        raise r.RunError(f"{scenario_path}: the demo needs two stations")
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    plots = out / "plots"
    plots.mkdir(exist_ok=True)
    medium = MediumProcess(scenario_path)
    ok = True
    lines: list[str] = []
    with SimWorld(seed=args.seed, scenario=scenario_path, medium=medium, workdir=out / "world") as world:
        ports = world.ports
        print(f"demo: scenario {scenario.name!r}, stations on {', '.join(ports)}, sessions in {out}/")
        devs = cs.open_devices(ports, 2.0)
        try:
            radio = dict(r.PAPER_RADIO)
            info = [r.prepare(d, radio, r.DEFAULT_ANTD, r.DEFAULT_ANTD) for d in devs]
            ids = [i.station_id for i in info]
            # -- 1. power self-calibration, both directions (1 dB steps over 30 dB), with the
            #       stations 1 m apart so that the sweep covers every level the ranging sees.
            base = scenario.station(ids[0]).position_m
            cal_d = min(DISTANCES_M)
            medium.move(ids[1], (base[0] + cal_d, base[1], base[2]))
            plan = pl.TripletPlan.sweep(steps=31, per_step=args.per_step, step_db=1.0, spacing_us=2000)
            gains2 = list(plan.gains2)
            cal_paths: list[Path] = []
            for a, b in ((0, 1), (1, 0)):
                path = out / f"calibrate_{ids[a]}to{ids[b]}.db"
                settings = {"command": "calibrate", "tx_port": ports[a], "rx_port": ports[b],
                            "tx_station": ids[a], "rx_station": ids[b], "per_step": plan.per_step,
                            "spacing_us": plan.spacing_us, "period_us": plan.period_us,
                            "gain13": plan.gain13, "gains2": gains2, "step_db": 1.0, "steps": len(gains2),
                            "distance_m": cal_d}
                meta = r.session_meta("power", "uwbcal demo", [info[a], info[b]], radio, settings)
                meta.update(scenario=scenario.to_toml(), seed=args.seed)
                print(f"calibrating station {ids[b]} (receiving from {ids[a]}): {plan.total} triplets")
                with Session.create(path, meta, overwrite=True) as s:
                    res = r.run_triplets(devs[a], devs[b], s, plan, ids[a], ids[b], cal_d,
                                         progress=not args.no_progress)
                    r.record_run(s, "calibrate", res)
                    pw = an._finite(an.analyze_power_session(s, plots / f"cal_{ids[a]}to{ids[b]}", -85.0,
                                                             True, 3.0))
                    s.set_result("analyze_power", pw)
                ok = ok and res.complete
                cal_paths.append(path)
                c = pw["calibrations"][0]
                errs = [st["error_s"] for st in c["steps"] if st.get("error_s") is not None]
                span = (max(errs) - min(errs)) * dw1000.C_LIGHT if errs else float("nan")
                lines.append(f"calibration {ids[a]}->{ids[b]}: {res.records}/{res.expected} triplets, "
                             f"{res.losses['n_missing']} lost; RX level estimate right below "
                             f"{c['threshold_dbm']:.0f} dBm ({c['n_fit']} steps fitted); timestamp error "
                             f"spans {span * 100:.1f} cm over the sweep")
            # -- 2. ranging at a few distances ----------------------------------------------
            ref, tag = devs
            rpath = out / "range.db"
            rsettings = {"command": "range", "ref_port": ports[0], "tag_port": ports[1],
                         "ref_station": ids[0], "tag_station": ids[1], "method": "paper",
                         "count": args.count * len(DISTANCES_M),
                         "period_us": 10_000, "reply_us": 1000, "gain": pl.TOP_GAIN,
                         "distances_m": list(DISTANCES_M)}
            meta = r.session_meta("twr", "uwbcal demo", info, radio, rsettings)
            meta.update(scenario=scenario.to_toml(), seed=args.seed)
            with Session.create(rpath, meta, overwrite=True) as s:

                def move(d: float) -> None:
                    medium.move(ids[1], (base[0] + d, base[1], base[2]))
                    print(f"ranging at {d:g} m: {args.count} exchanges (paper's three-message TWR)")

                rp = pl.RangePlan(method="paper", count=args.count, period_us=10_000, reply_us=1000,
                                  gain=pl.TOP_GAIN)
                res = r.run_ranges_at(ref, tag, s, rp, ids[0], ids[1], DISTANCES_M, move,
                                      progress=not args.no_progress)
                ok = ok and res.complete
                r.record_run(s, "range", res)
                twr = an._finite(an.analyze_twr_session(s, plots / "range", cal_paths, None))
                s.set_result("analyze_twr", twr)
        finally:
            for dev in devs:
                dev.close()
    lines += _twr_lines(twr)
    print()
    print("demo report")
    print("-----------")
    for ln in lines:
        print(ln)
    print(f"sessions: {', '.join(str(p) for p in [*cal_paths, rpath])}")
    print(f"plots:    {plots}/ (cal_*/power_curve_*.png, cal_*/measured_vs_real_*.png, range/twr.png)")
    print(f"demo: {'done' if ok else 'INCOMPLETE'} in {time.monotonic() - t_start:.0f} s")
    summary = {"ok": ok, "sessions": [str(p) for p in [*cal_paths, rpath]], "plots": str(plots),
               "wall_s": round(time.monotonic() - t_start, 1), "distances_m": twr["distances_m"],
               "std_all_m": {k: m["std_all_m"] for k, m in twr["methods"].items()},
               "warnings": twr.get("warnings", [])}
    return (0 if ok else 1), summary


def _twr_lines(twr: dict[str, Any]) -> list[str]:
    """Range error per distance for the methods that show what the corrections do."""
    show = [("paper_none", "no correction"), ("paper_no_power", "drift only"),
            ("paper", "drift + power curves"), ("paper_drift_aps011", "drift + APS011 table")]
    methods = twr["methods"]
    out = [f"ranging (Z from {twr['z_distance_m']:g} m), mean error per distance, cm:",
           "  " + f"{'method':24s}" + "".join(f"{d:>8g} m" for d in twr["distances_m"]) + "   std all"]
    for key, label in show:
        m = methods.get(key)
        if m is None:
            continue
        cells = "".join(f"{p['mean_error_m'] * 100:+10.2f}" if not _nan(p["mean_error_m"]) else f"{'-':>10s}"
                        for p in m["per_distance"])
        out.append(f"  {label:24s}{cells}   {m['std_all_m'] * 100:6.2f}")
    return out


def _nan(x: Any) -> bool:
    return x is None or (isinstance(x, float) and math.isnan(x))
