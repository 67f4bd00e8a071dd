"""Benchmark: the EVK1000's USB CDC-ACM link over the emulated bulk endpoints.

The USB driver and station core built for the host (build/usbhosted/libevkusb.so, `make
usbhosted`) run against the OTG FS model; the pty bridge moves at most 19 bulk packets per
1 ms frame (the USB 2.0 full-speed bulk limit). A program writes PING requests with 512-byte
payloads to the pty and reads the echoes back, as `uwbcal` would through /dev/ttyACM0.

Prints, in device time (what the link would carry if the chip keeps up as the harness lets it)
and in wall time (how fast this machine emulates it):

    bench usb_bulk_in: <B/s> device-time (<B/s> wall) ...
    bench usb_triplets_per_s: <n> triplets/s the link carries (paper: ~200/s at 2 ms spacing)

What it cannot show: the real chip's CPU time per packet (the harness charges 20 us of device
time per main-loop pass and per driver wait pass, not cycles), a real host controller's
scheduling, or the real bus. The triplet figure assumes full batches of 3 records per frame.
"""

from __future__ import annotations

import os
import select
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "host"))

from uwbcal.evk1000.usbbridge import UsbPtyBridge  # noqa: E402
from uwbcal.evk1000.usbhost import UsbHost  # noqa: E402
from uwbcal.evk1000.usbhosted import HostedStation, default_lib  # noqa: E402
from uwbcal.link import framing  # noqa: E402
from uwbcal.link import proto_gen as pg  # noqa: E402

N_PINGS = 300
PAYLOAD = 512


def triplet_wire_bytes() -> float:
    """Bytes on the wire per triplet in a full TRIPLETS batch (COBS frame + delimiter)."""
    n = pg.TripletsResp.TAIL_MAX
    recs = tuple(pg.TripletRecord(seq=i + 1, step=3, tx_station=1, gain13=0x1F, gain2=0x0F,
                                  tx=(1 << 39, 2, 3), rx=(4, 5, 1 << 38)) for i in range(n))
    payload = pg.TripletsResp(first_index=1000, records=recs).encode()
    frame = framing.encode_frame(framing.Frame(type=pg.T_TRIPLETS, seq=77, flags=pg.FLAG_STREAM,
                                               payload=payload))
    return len(frame) / n


def main() -> int:
    if not default_lib().exists():
        print(f"bench usb: {default_lib()} not built (make usbhosted)", file=sys.stderr)
        return 1
    st = HostedStation()
    host = UsbHost(st.model, st)
    host.enumerate()
    host.cdc_open()
    br = UsbPtyBridge(host, st)
    slave = br.slave
    if slave is None:
        print("bench usb: the bridge opened no pty", file=sys.stderr)
        return 1
    os.set_blocking(slave, False)
    data = bytes((i * 7 + 1) & 0xFF or 1 for i in range(PAYLOAD))
    ping = pg.PingReq(data=data).encode()
    reqs = [framing.encode_frame(framing.Frame(type=pg.T_PING, seq=s + 1, payload=ping))
            for s in range(N_PINGS)]
    expected = sum(len(r) for r in reqs)  # the echo has the same length
    got = 0
    out_i = 0
    t_dev0, wall0, mmio0 = st.time_us, time.perf_counter(), st.model.stats["mmio"]
    frames = 0
    while got < expected and frames < 200_000:
        # the program keeps a few requests in flight, as a session's reader would
        while out_i < N_PINGS and out_i * len(reqs[0]) - got < 4 * len(reqs[0]):
            os.write(slave, reqs[out_i])
            out_i += 1
        br.frame()
        frames += 1
        while select.select([slave], [], [], 0)[0]:
            try:
                chunk = os.read(slave, 65536)
            except BlockingIOError:
                break
            got += len(chunk)
    dev_s = (st.time_us - t_dev0) / 1e6
    wall_s = time.perf_counter() - wall0
    mmio = st.model.stats["mmio"] - mmio0
    br.stop()
    if got < expected:
        print(f"bench usb: only {got} of {expected} bytes came back", file=sys.stderr)
        return 1
    in_bps = got / dev_s
    per_triplet = triplet_wire_bytes()
    print(f"bench usb_bulk_in: {in_bps:,.0f} B/s device-time ({got / wall_s:,.0f} B/s wall) "
          f"({N_PINGS} PINGs of {PAYLOAD} B echoed, OUT carried as much, {frames} frames of 1 ms, "
          f"budget 19 packets/frame shared by OUT and IN)")
    print(f"bench usb_bulk_total: {2 * got / dev_s:,.0f} B/s device-time, OUT + IN")
    print(f"bench usb_mmio_per_kb: {mmio / (2 * got / 1024):.0f} register accesses per KB moved")
    print(f"bench usb_triplets_per_s: {in_bps / per_triplet:,.0f} triplets/s the bulk IN rate carries "
          f"({per_triplet:.1f} B per triplet in full batches; the paper's 2 ms spacing needs ~200/s: "
          f"x{in_bps / per_triplet / 200:.0f} margin)")
    print(f"bench usb_emulation_speed: {dev_s / wall_s:.2f} x real time "
          f"({wall_s:.2f} s wall for {dev_s:.2f} s of device time)")
    rc = calibration_over_usb()
    return rc or image_over_usb()


def image_over_usb(n_pings: int = 40) -> int:
    """The shipped image on the emulated EVK1000 (issue 10's machine, when in the tree): bulk
    bytes/s in emulated time and the CPU's share of it (instructions per KB at 72 MHz)."""
    try:
        from uwbcal.evk1000 import machine as machine_mod  # type: ignore[attr-defined]
        from uwbcal.evk1000.fpec import FlashFile  # type: ignore[import-not-found]
        from uwbcal.evk1000.radio import LocalRadio  # type: ignore[import-not-found]
    except ImportError:
        print("bench usb_image: skipped (no emulated EVK1000 in this tree: issue 10)")
        return 0
    from uwbcal.evk1000.usbmachine import attach_usb

    img = (REPO / "build" / "evk1000" / "uwbcal-evk1000.bin").read_bytes()
    flash = FlashFile(None)
    flash.data[:len(img)] = img
    box: dict[str, object] = {}
    radio = LocalRadio(lambda: box["m"].time_us())  # type: ignore[attr-defined]
    m = machine_mod.Machine(flash, uid=bytes(12), radio=radio, link_sink=lambda b: None)
    box["m"] = m
    _otg, host = attach_usb(m)
    host.enumerate()
    host.cdc_open()
    data = bytes((i * 7 + 1) & 0xFF or 1 for i in range(PAYLOAD))
    ping = pg.PingReq(data=data).encode()
    t0, i0, w0, moved = m.time_us(), m.instructions, time.perf_counter(), 0
    for s in range(n_pings):
        req = framing.encode_frame(framing.Frame(type=pg.T_PING, seq=s + 1, payload=ping))
        host.bulk_out(1, req)
        got = bytearray()
        while b"\0" not in got:
            p = host.bulk_in_packet(1)
            if p is None:
                host.run(100)
            else:
                got += p
        moved += len(req) + len(got)
    dev_s = (m.time_us() - t0) / 1e6
    instr = m.instructions - i0
    wall = time.perf_counter() - w0
    print(f"bench usb_image: {moved / dev_s:,.0f} B/s OUT + IN in emulated time, one PING of {PAYLOAD} B "
          f"at a time ({moved / wall:,.0f} B/s wall); the image ran {instr / (moved / 1024):,.0f} "
          f"instructions per KB moved ({instr / (dev_s * 72e6) * 100:.1f} % of a 72 MHz CPU)")
    return 0


def calibration_over_usb(steps: int = 5, per_step: int = 100) -> int:
    """A power calibration (2 ms spacing) between two USB stations on the simulated medium:
    records per second of virtual time that arrived, and the wall-time cost per triplet."""
    import json
    import tempfile

    from uwbcal import cli
    from uwbcal.evk1000.usbstation import write_launcher
    from uwbcal.simstations import SimWorld, repo_root

    with tempfile.TemporaryDirectory(prefix="bench-usb-") as d:
        exe = write_launcher(Path(d) / "usbstation")
        with SimWorld(scenario=repo_root() / "scenarios" / "two_stations.toml", binary=exe,
                      workdir=Path(d) / "w", start_timeout_s=60) as w:
            t0 = time.perf_counter()
            import contextlib
            import io

            buf = io.StringIO()
            with contextlib.redirect_stdout(buf):
                rc = cli.main(["calibrate", "--tx", w.ports[0], "--rx", w.ports[1], "--steps", str(steps),
                               "--step-db", "3", "--per-step", str(per_step), "--spacing", "2ms",
                               "--out", str(Path(d) / "cal.db"), "--no-progress", "--json", "--no-analysis"])
            wall = time.perf_counter() - t0
    if rc != 0:
        print(f"bench usb: calibration over USB failed: {buf.getvalue()[-300:]}", file=sys.stderr)
        return 1
    run = json.loads(buf.getvalue().strip().splitlines()[-1])["run"]
    n = int(run["records"])
    print(f"bench usb_calibration: {n} of {steps * per_step} triplets over the emulated USB link, "
          f"{run['losses']['n_missing']} missing; {wall / n * 1e3:.2f} ms wall per triplet "
          f"(2 ms spacing: one triplet per 6 ms of virtual time, ~167 records/s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
