"""Benchmark of the vectorised simulator and the session store.

Prints:
  bench simulate_triplets: <value> triplets/s (bar >= 1e6)
  bench simulate_ranges: <value> exchanges/s
  bench world_transmit_per_frame: <us> us/frame (the firmware-in-the-loop path: World.transmit
    of one frame to one receiver, as the medium calls it; delayed_tx and clock reads alongside)
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

from uwbcal import vectorsim as sim  # noqa: E402
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


def best_us(fn, count: int, repeats: int) -> float:  # type: ignore[no-untyped-def]
    """Best time per call (us) over ``repeats`` runs of ``fn(i)`` for i in range(count)."""
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        for i in range(count):
            fn(i)
        best = min(best, time.perf_counter() - t0)
    return best / count * 1e6


def per_frame(sc) -> None:  # type: ignore[no-untyped-def]
    """Per-frame World calls as uwbcal.medium makes them (P1/P2/P3 150 us apart, 20 ms period)."""
    w = World(sc, seed=1)
    tx, rx = sc.station_ids[0], sc.station_ids[1]
    antd = {rx: 16436}

    frame = [0]

    def transmit(i: int) -> None:
        k = frame[0] = frame[0] + 1  # time keeps running over the repeats (interference gaps)
        w.transmit(tx, 1.0 + (k // 3) * 0.02 + (k % 3) * 150e-6, 0x1F, receivers=[rx], rx_antd=antd)

    def delayed(i: int) -> None:
        w.delayed_tx(tx, [100_000_000 + i * 9_600_000], 16436)

    def clocks(i: int) -> None:
        float(w.local_units(tx, 1.0 + i * 1e-3))
        float(w.true_time_of_units(rx, 1e8 + i * 1e6))

    n = int(os.environ.get("BENCH_FRAMES", "3000"))
    us_tx = best_us(transmit, n, 5)
    us_dtx = best_us(delayed, n, 5)
    us_clk = best_us(clocks, n, 5) / 2
    print(
        f"bench world_transmit_per_frame: {us_tx:.1f} us/frame (World.transmit to one receiver, "
        f"paper_antenna, best of 5 x {n}; World.delayed_tx {us_dtx:.1f} us, "
        f"local_units/true_time_of_units {us_clk:.1f} us per call)",
        flush=True,
    )


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

    per_frame(sc)

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
