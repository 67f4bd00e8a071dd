"""A simulated station whose host link is the EVK1000's USB CDC-ACM link: the USB driver and
the station core (build/usbhosted/libevkusb.so) on the OTG FS model, enumerated by the USB
host as Linux would, its bulk endpoints served on a pty like /dev/ttyACM0.

    python -m uwbcal.evk1000.usbstation --id N [--flash PATH] [--medium SOCKET]

The same command line and first output line (``PTY <path>``) as the native ``uwbcal-station``,
so :class:`uwbcal.simworld.SimWorld` runs it as a station (``binary=`` a launcher of this
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
    while not st.should_exit():
        moved = bridge.frame()
        idle = 0 if moved else idle + 1
        if not st.medium and idle > 20:  # no medium to wait on: wait for the program
            select.select([bridge.master], [], [], 0.005)
    return 0


if __name__ == "__main__":
    sys.exit(main())
