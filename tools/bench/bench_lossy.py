"""Benchmark: a 1,200-triplet calibration through a lossy link (uwbcal.link.lossy on both
station links), at several per-byte fault rates; the issue-12 measurement, redone.

For each rate (drop, duplicate and corrupt each at that probability per byte and direction)
prints

    bench lossy_<rate>: <records>/<expected> records, <missing> missing, <dups> duplicate rows,
        <fetched> fetched, <remeasured> re-measured in <passes> plans, <wall> s

Simulated stations (the optimised build, $UWBCAL_STATION) and the two_stations scenario; the
wall time is on a shared machine (load printed).
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "host"))

RATES = ("0", "1e-4", "1e-3")
STEPS, PER_STEP = 10, 120


def main() -> int:
    from uwbcal import cli
    from uwbcal.sessions.store import Session
    from uwbcal.simstations import SimWorld

    scenario = REPO / "scenarios" / "two_stations.toml"
    with tempfile.TemporaryDirectory() as tmp, SimWorld(scenario=scenario, workdir=Path(tmp) / "w") as world:
        for rate in RATES:
            proxy = subprocess.Popen([sys.executable, "-m", "uwbcal.link.lossy", "--drop", rate, "--dup",
                                      rate, "--corrupt", rate, "--seed", "1", *world.ports],
                                     stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                                     env=dict(os.environ, PYTHONPATH=str(REPO / "host")))
            assert proxy.stdout is not None
            ports = [proxy.stdout.readline().split()[-1] for _ in world.ports]
            db = Path(tmp) / f"lossy_{rate}.db"
            out = io.StringIO()
            t0 = time.monotonic()
            with contextlib.redirect_stdout(out):
                rc = cli.main(["calibrate", "--tx", ports[0], "--rx", ports[1], "--steps", str(STEPS),
                               "--step-db", "3", "--per-step", str(PER_STEP), "--spacing", "2ms", "--out",
                               str(db), "--no-progress", "--no-analysis", "--json", "--timeout", "0.5"])
            wall = time.monotonic() - t0
            proxy.terminate()
            proxy.wait()
            if rc not in (0, 10):
                print(f"bench lossy_{rate}: the session failed (exit {rc})")
                return 1
            run = json.loads(out.getvalue().strip().splitlines()[-1])["run"]
            lo = run["losses"]
            with Session.open(db, readonly=True) as s:
                seq = s.read("triplets", ["seq"])["seq"]
            dup_rows = int(seq.size - len(set(seq.tolist())))
            print(f"bench lossy_{rate}: {run['records']}/{run['expected']} records, {lo['n_missing']} "
                  f"missing, {dup_rows} duplicate rows, {lo['lost_frames']} stream frames lost, "
                  f"{lo['fetched']} fetched, "
                  f"{lo['remeasured']} re-measured in {lo['passes']} plans, {wall:.1f} s "
                  f"(load {os.getloadavg()[0]:.1f})", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
