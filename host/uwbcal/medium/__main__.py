"""``python -m uwbcal.medium --scenario FILE --socket PATH [--seed S]``: run the radio medium.

Prints one line ``medium: listening on PATH`` on stdout once the socket accepts stations,
then serves until SIGTERM/SIGINT.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from uwbcal.errors import UwbcalError


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit code."""
    p = argparse.ArgumentParser(prog="python -m uwbcal.medium", description=__doc__)
    p.add_argument("--scenario", required=True, help="scenario TOML file")
    p.add_argument("--socket", required=True, help="unix socket path the stations connect to")
    p.add_argument("--seed", type=int, default=None, help="override the scenario's seed")
    p.add_argument("--log-dir", default=None, help="write per-station TX/RX logs here")
    p.add_argument("--no-pace", action="store_true",
                   help="freeze virtual time while every station idles (deterministic; host "
                        "timeouts then see no time pass)")
    p.add_argument("--verbose", action="store_true")
    args = p.parse_args(argv)
    from uwbcal.medium.core import Medium
    from uwbcal.medium.server import MediumServer, install_signal_handlers
    from uwbcal.medium.world_adapter import MediumWorldAdapter

    try:
        world = MediumWorldAdapter.from_file(args.scenario, seed=args.seed)
    except UwbcalError as exc:
        print(f"medium: error: {exc}", file=sys.stderr)
        return exc.exit_code
    medium = Medium(world, pace_idle=not args.no_pace, log_dir=args.log_dir)
    server = MediumServer(medium, args.socket, verbose=args.verbose)
    install_signal_handlers(server)
    print(f"medium: listening on {args.socket}", flush=True)
    try:
        server.serve()
    except SystemExit:
        pass
    finally:
        server.close()
        if args.verbose:
            print(f"medium: {medium.frames} frames, {medium.receptions} receptions, "
                  f"virtual time {medium.now_ps / 1e12:.3f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
