"""Benchmark: the EVK1000 image in the emulator (uwbcal.evk1000) through a calibration session.

Two stations of scenarios/two_stations.toml run build/evk1000/uwbcal-evk1000.bin (built first
with `make firmware`) against the simulated medium; the host runs `uwbcal calibrate` (3 steps,
--per-step triplets each, 2 ms spacing, P1 -> P1 period 6 ms). Each station's counters are
read before and after the session (SIGUSR1 -> --stats file), so boot is not counted. Prints

    bench evk1000_emu_triplets: <n>/s emulated vs <n>/s on boards (x<ratio> of real time)
    bench evk1000_emu_<tx|rx>_cycles: <n> per triplet (<pct> % of a 72 MHz CPU's time ...)
    bench evk1000_emu_<tx|rx>_mmio: <n> peripheral accesses per triplet
    bench evk1000_emu_<tx|rx>_stack: <n> bytes high-water mark
    bench evk1000_emu_<tx|rx>_link: <n> link bytes per triplet over the image's link

Cycles are executed instructions at one cycle each (a lower bound: a Cortex-M3 with two flash
wait states needs more), plus flash stalls; "busy" excludes the time asleep in WFI.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "host"))

STEPS, SPACING_US = 3, 2000


def _stats(path: Path, pid: int, old: float) -> dict[str, int]:
    os.kill(pid, signal.SIGUSR1)
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        if path.is_file() and path.stat().st_mtime > old:
            try:
                return dict(json.loads(path.read_text()))
            except ValueError:
                pass
        time.sleep(0.05)
    raise RuntimeError(f"no statistics from pid {pid} in {path}")


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--per-step", type=int, default=50, help="triplets per step (3 steps)")
    args = p.parse_args()
    if subprocess.call(["make", "-s", "firmware"], cwd=REPO, stdout=subprocess.DEVNULL) != 0:
        print("bench evk1000_emu: `make firmware` failed (arm-none-eabi-gcc missing?)")
        return 1
    from uwbcal import cli
    from uwbcal.evk1000.station import image_has_usb
    from uwbcal.sessions import plan
    from uwbcal.simstations import SimWorld, evk1000_image

    link_name = "USB CDC-ACM" if image_has_usb(evk1000_image().read_bytes()) else "USART1"
    n = STEPS * args.per_step
    period_us = plan.default_period_us(SPACING_US)
    with tempfile.TemporaryDirectory(prefix="bench-evk-") as tmp:
        work = Path(tmp)
        stats = work / "stats-{id}.json"
        world = SimWorld(scenario=REPO / "scenarios" / "two_stations.toml", board="evk1000",
                         workdir=work / "w", extra_args=["--stats", str(stats)], start_timeout_s=60.0)
        world.start()
        try:
            files = {st.id: Path(str(stats).replace("{id}", str(st.id))) for st in world.stations}
            before = {st.id: _stats(files[st.id], st.process.pid, 0.0) for st in world.stations}
            t0 = time.perf_counter()
            rc = cli.main(["calibrate", "--tx", world.ports[0], "--rx", world.ports[1], "--steps", str(STEPS),
                           "--step-db", "3", "--per-step", str(args.per_step), "--spacing", "2ms",
                           "--out", str(work / "cal.db"), "--no-progress", "--no-analysis", "--json"])
            wall = time.perf_counter() - t0
            after = {st.id: _stats(files[st.id], st.process.pid, files[st.id].stat().st_mtime)
                     for st in world.stations}
        finally:
            world.stop()
    if rc != 0:
        print(f"bench evk1000_emu: the calibration failed (exit {rc})")
        return 1
    ids = sorted(after)
    virt_s = (after[ids[0]]["time_us"] - before[ids[0]]["time_us"]) * 1e-6
    print(f"bench evk1000_emu_triplets: {n / wall:.1f}/s emulated vs {1e6 / period_us:.1f}/s on boards "
          f"(x{(n / wall) / (1e6 / period_us):.2f} of real time; {n} triplets, {wall:.1f} s wall, "
          f"{virt_s:.2f} s virtual)")
    for sid, role in zip(ids, ("tx", "rx"), strict=False):
        d = {k: after[sid][k] - before[sid][k] for k in after[sid] if isinstance(after[sid][k], int)}
        busy = d["cycles"] - d["sleep_cycles"]
        per = busy / n
        load = busy / (after[sid]["sysclk_hz"] * virt_s) * 100 if virt_s > 0 else float("nan")
        print(f"bench evk1000_emu_{role}_cycles: {per:.0f} per triplet ({load:.1f} % of a "
              f"{after[sid]['sysclk_hz'] / 1e6:.0f} MHz CPU's time busy, instructions at 1 cycle; "
              f"{d['instructions'] / n:.0f} instructions, {d['exceptions'] / n:.1f} exceptions)")
        print(f"bench evk1000_emu_{role}_mmio: {d['mmio_accesses'] / n:.0f} peripheral accesses per triplet "
              f"({d['spi_transactions'] / n:.1f} SPI transactions, "
              f"{d['round_trips'] / n:.1f} medium round trips)")
        print(f"bench evk1000_emu_{role}_stack: {after[sid]['stack_high_water']} bytes high-water mark "
              f"(of the >= 4096 reserved)")
        link = (d["link_bytes_in"] + d["link_bytes_out"]) / n
        print(f"bench evk1000_emu_{role}_link: {link:.1f} link bytes per triplet over {link_name} "
              f"(on USART1 it would take {link * 10 / 115200 * 1e3:.2f} ms at 115200 8N1)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
