"""A simulated station whose host link is the EVK1000's USB CDC-ACM link: the USB driver and
the station core (build/usbhosted/libevkusb.so) on the OTG FS model, enumerated by the USB
host as Linux would, its bulk endpoints served on a pty like /dev/ttyACM0.

    python -m uwbcal.evk1000.usbstation --id N [--flash PATH] [--medium SOCKET]

The same command line and first output line (``PTY <path>``) as the native ``uwbcal-station``,
so :class:`uwbcal.simstations.SimWorld` runs it as a station (``binary=`` a launcher of this
module, see :func:`write_launcher`). Exits 0 on SIGTERM or SIGINT.
"""

from __future__ import annotations

import argparse
import select
import sys
from pathlib import Path
from typing import Final

from uwbcal.errors import UwbcalError

#: UID of USB station N: "UWBC" "USB" 0 then N big-endian (distinct from native stations').
UID_PREFIX: Final = b"UWBCUSB\x00"


def uid_for_id(station_id: int) -> bytes:
    """The 12-byte UID of USB station ``station_id``."""
    return UID_PREFIX + station_id.to_bytes(4, "big")


def write_launcher(path: Path) -> Path:
    """An executable file that runs this module with this Python (for SimWorld's binary=)."""
    path.write_text(f"#!{sys.executable}\nimport sys\nfrom uwbcal.evk1000.usbstation import main\n"
                    "sys.exit(main())\n")
    path.chmod(0o755)
    return path


def main(argv: list[str] | None = None) -> int:
    from uwbcal.evk1000.usbbridge import UsbPtyBridge
    from uwbcal.evk1000.usbhost import UsbHost
    from uwbcal.evk1000.usbhosted import HostedStation

    p = argparse.ArgumentParser(prog="usbstation", description=__doc__.split("\n\n")[0])
    p.add_argument("--id", type=int, required=True, help="station id 1..65535 (also fixes the UID)")
    p.add_argument("--flash", type=Path, help="flash file (default: RAM)")
    p.add_argument("--medium", help="unix socket of the simulated medium")
    # Disturbances for tests, placed by traffic so they fall mid-session whatever the timing:
    p.add_argument("--reset-after-bytes", type=int, metavar="N",
                   help="reset the USB port and enumerate again once N bytes went to the host")
    p.add_argument("--stall-after-bytes", type=int, metavar="N",
                   help="stop reading bulk IN once N bytes went to the host ...")
    p.add_argument("--stall-us", type=int, default=60_000, metavar="US",
                   help="... for US microseconds of device time (default 60000)")
    args = p.parse_args(argv)
    if not 1 <= args.id <= 65535:
        p.error("--id: 1..65535")
    try:
        st = HostedStation(uid=uid_for_id(args.id), station_id=args.id, flash=args.flash, medium=args.medium)
        host = UsbHost(st.model, st)
        host.enumerate()
        host.cdc_open()
        bridge = UsbPtyBridge(host, st)
    except UwbcalError as e:
        print(f"usbstation {args.id}: {e}", file=sys.stderr)
        return 1
    print(f"PTY {bridge.path}", flush=True)
    idle = 0
    reset_at, stall_at, stall_end = args.reset_after_bytes, args.stall_after_bytes, None
    peak = 0
    while not st.should_exit():
        moved = bridge.frame()
        peak = max(peak, int(st.lib.cdc_tx_queued()))
        idle = 0 if moved else idle + 1
        if reset_at is not None and bridge.bytes_in >= reset_at:
            reset_at = None
            print(f"usbstation {args.id}: port reset at {st.time_us} us after {bridge.bytes_in} bytes",
                  file=sys.stderr, flush=True)
            bridge.reset_and_reenumerate()
        if stall_at is not None and bridge.bytes_in >= stall_at:
            stall_at, stall_end, bridge.reading = None, st.time_us + args.stall_us, False
            print(f"usbstation {args.id}: host stops reading at {st.time_us} us for {args.stall_us} us "
                  f"(TX ring holds {st.lib.cdc_tx_queued()} bytes)",
                  file=sys.stderr, flush=True)
        if stall_end is not None and st.time_us >= stall_end:
            stall_end, bridge.reading = None, True
        if not st.medium and idle > 20:  # no medium to wait on: wait for the program
            select.select([bridge.master], [], [], 0.005)
    print(f"usbstation {args.id}: exit: bus resets {st.lib.usbd_bus_resets()}, bytes to host "
          f"{bridge.bytes_in}, from host {bridge.bytes_out}, tx dropped {st.tx_dropped}, "
          f"tx failures {st.tx_failures}, TX ring peak {peak} bytes", file=sys.stderr, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
