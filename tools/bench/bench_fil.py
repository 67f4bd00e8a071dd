"""Benchmark: a paper-sized power calibration through the firmware in the loop.

The paper's over-the-air calibration: 0.5 dB steps over 20 dB (41 steps), 2000 triplets per
step, 2 ms between messages (P1 -> P2 -> P3 -> next P1: period 6 ms), i.e. 82,000 triplets.
On boards that takes 82,000 x 6 ms = 492 s in real time. Here two native firmware stations
(the optimised build, $UWBCAL_STATION) run it against the simulated medium, with the host
session code writing every record to a session file, exactly as `uwbcal calibrate` does.

By default the run is shortened to --per-step triplets per step (same 41 steps) and the
simulated time is extrapolated linearly to 2000 per step (the cost per triplet does not depend
on how many there are); --per-step 2000 runs the whole thing. Prints

    bench fil_power_calibration: sim <s> s vs real-time <s> s (x<speedup>, bar >= 5x)

plus the breakdown per triplet (medium CPU, of which the physics World; stations; host; tunnel
frames, setup included), the machine load, since the figure is wall-clock time on a shared
machine, and the CPU the lock-step processes are pinned to ($UWBCAL_SIM_CPU, uwbcal.simstations).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "host"))

STEPS, STEP_DB, PAPER_PER_STEP, SPACING_US = 41, 0.5, 2000, 2000


def _cpu_s(pid: int) -> float:
    """User + system CPU seconds of a process (from /proc), 0 if unknown."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return 0.0


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--per-step", type=int, default=100, help="triplets per step actually run (2000 = full)")
    p.add_argument("--scenario", default=str(REPO / "scenarios" / "two_stations.toml"))
    args = p.parse_args()

    from uwbcal.commands._session import open_devices
    from uwbcal.medium.launcher import MediumProcess
    from uwbcal.sessions import plan as pl
    from uwbcal.sessions import runner as r
    from uwbcal.sessions.store import Session
    from uwbcal.simstations import SimWorld, sim_cpu

    plan = pl.TripletPlan.sweep(steps=STEPS, per_step=args.per_step, step_db=STEP_DB, spacing_us=SPACING_US)
    period_us = plan.period_us
    paper_total = STEPS * PAPER_PER_STEP
    real_time_s = paper_total * period_us * 1e-6
    load0 = os.getloadavg()[0]
    with tempfile.TemporaryDirectory(prefix="uwbcal-bench-") as tmp:
        medium = MediumProcess(args.scenario)
        with SimWorld(scenario=Path(args.scenario), medium=medium, workdir=Path(tmp) / "w") as world:
            devs = open_devices(world.ports, 5.0)
            radio = dict(r.PAPER_RADIO)
            info = [r.prepare(d, radio, r.DEFAULT_ANTD, r.DEFAULT_ANTD) for d in devs]
            meta = r.session_meta("power", "bench_fil", info, radio, {"command": "calibrate"})
            pids = [st.process.pid for st in world.stations]
            mpid = medium.process.pid if medium.process else 0
            cpu0 = [_cpu_s(pid) for pid in [mpid, *pids]]
            host0 = time.process_time()
            with Session.create(Path(tmp) / "bench.db", meta) as s:
                t0 = time.perf_counter()
                res = r.run_triplets(devs[0], devs[1], s, plan, info[0].station_id,
                                     info[1].station_id, None, progress=False)
                wall = time.perf_counter() - t0
            host_cpu = time.process_time() - host0
            cpu1 = [_cpu_s(pid) for pid in [mpid, *pids]]
            stats = medium.control("stats")
            for d in devs:
                d.close()
    if not res.complete:
        print(f"bench fil_power_calibration: FAILED: {res.records}/{res.expected} records, "
              f"losses {res.losses}")
        return 1
    cpu = sim_cpu()
    pinned = "medium and stations not pinned" if cpu is None else f"medium and stations on CPU {cpu}"
    scale = paper_total / plan.total
    sim_s = wall * scale
    speedup = real_time_s / sim_s
    extrap = "" if scale == 1 else (f", extrapolated x{scale:.0f} from {plan.total} triplets "
                                    f"run in {wall:.1f} s")
    print(f"bench fil_power_calibration: sim {sim_s:.1f} s vs real-time {real_time_s:.1f} s "
          f"(x{speedup:.2f}, bar >= 5x{extrap})")
    physics = next((w.split("=")[1] for w in stats.split() if w.startswith("physics_s=")), "?")
    frames = next((w.split("=")[1] for w in stats.split() if w.startswith("tunnel_frames=")), "?")
    med_cpu, st_cpu = cpu1[0] - cpu0[0], sum(cpu1[1:]) - sum(cpu0[1:])
    print(f"bench fil_per_triplet: {wall / plan.total * 1e3:.3f} ms wall "
          f"(real time {period_us / 1e3:.1f} ms); "
          f"CPU per triplet: medium {med_cpu / plan.total * 1e3:.3f} ms (physics World "
          f"{float(physics) / plan.total * 1e3 if physics != '?' else float('nan'):.3f} ms), stations "
          f"{st_cpu / plan.total * 1e3:.3f} ms, host {host_cpu / plan.total * 1e3:.3f} ms; "
          f"{int(frames) / plan.total if frames != '?' else float('nan'):.1f} tunnel frames "
          f"(machine load {load0:.1f} -> {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs; "
          f"{pinned})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
