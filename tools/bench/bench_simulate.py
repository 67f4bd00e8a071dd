"""Benchmark of the vectorised simulator and the session store.

Prints:
  bench simulate_triplets: <value> triplets/s (bar >= 1e6)
  bench simulate_ranges: <value> exchanges/s
  bench session_write: <value> rows/s
  bench session_read: <value> rows/s
Figures are the best of several repeats (the machine is shared); benchmarks measure, tests
never assert on time. Exit 0 if it ran (the bar is reported, not enforced).
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "host"))

from uwbcal import simulate as sim  # noqa: E402
from uwbcal.physics import World, load_scenario  # noqa: E402
from uwbcal.sessions.store import Session  # noqa: E402


def best_rate(fn, count: int, repeats: int) -> float:  # type: ignore[no-untyped-def]
    """Best rate (count per second) over ``repeats`` runs of ``fn``."""
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return count / best


def main() -> int:
    n = int(os.environ.get("BENCH_TRIPLETS", "1000000"))
    sc = load_scenario("paper_antenna")
    sched = sim.power_schedule(sc, steps=50, per_step=n // 50, step_db=0.5, period_s=0.02)
    world = World(sc, seed=1)
    sim.run_triplets(world, sim.drift_schedule(sc, 1000))  # warm-up (imports, caches)
    rate = best_rate(lambda: sim.run_triplets(World(sc, seed=1), sched), len(sched), 3)
    print(
        f"bench simulate_triplets: {rate:.3g} triplets/s (bar >= 1e6; {len(sched)} triplets, "
        f"paper_antenna, all default effects, best of 3)",
        flush=True,
    )

    rsched = sim.twr_schedule(sc, per_distance=20000)
    rrate = best_rate(lambda: sim.run_ranges(World(sc, seed=1), rsched), len(rsched), 3)
    print(
        f"bench simulate_ranges: {rrate:.3g} exchanges/s ({len(rsched)} paper TWR exchanges, best of 3)",
        flush=True,
    )

    rec, truth = sim.run_triplets(World(sc, seed=1), sim.drift_schedule(sc, 200000))
    rows = len(rec["seq"])
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "bench.db"

        def write() -> None:
            with Session.create(path, {"kind": "simulated"}, overwrite=True) as s:
                s.append("triplets", rec)

        wrate = best_rate(write, rows, 2)
        size = path.stat().st_size

        def read() -> None:
            with Session.open(path) as s:
                s.read("triplets")

        rdrate = best_rate(read, rows, 2)
    print(
        f"bench session_write: {wrate:.3g} rows/s ({rows} triplet rows x {len(rec)} columns, "
        f"{size / rows:.0f} bytes/row, committed every 20000 rows)",
        flush=True,
    )
    print(
        f"bench session_read: {rdrate:.3g} rows/s (Session.read of {rows} triplet rows into arrays)",
        flush=True,
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
