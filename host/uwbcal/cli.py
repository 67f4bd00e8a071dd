"""The `uwbcal` command line: discovers one subcommand per module in uwbcal.commands."""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys
from collections.abc import Sequence

from uwbcal import __version__, commands
from uwbcal.errors import UwbcalError


def build_parser() -> argparse.ArgumentParser:
    """The parser with every discovered subcommand registered."""
    parser = argparse.ArgumentParser(
        prog="uwbcal",
        description="DW1000 clock drift correction and power self-calibration, on boards or simulated.",
    )
    parser.add_argument("--version", action="version", version=f"uwbcal {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue  # shared glue (commands/_session.py), not a subcommand
        module = importlib.import_module(f"uwbcal.commands.{info.name}")
        module.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run one command; a UwbcalError becomes a one-line message and its exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except UwbcalError as exc:
        print(f"uwbcal {args.command}: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print(f"uwbcal {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 141
