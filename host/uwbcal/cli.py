"""The `uwbcal` command line: discovers one subcommand per module in uwbcal.commands."""

from __future__ import annotations

import argparse
import importlib
import json
import pkgutil
import sys
from collections.abc import Sequence
from typing import NoReturn

from uwbcal import __version__, commands
from uwbcal.errors import UwbcalError


class UsageError(UwbcalError):
    """The command line itself is wrong (unknown option, missing argument)."""

    exit_code = 2


class _Parser(argparse.ArgumentParser):
    """argparse that raises UsageError instead of exiting, so --json can report it as JSON."""

    def error(self, message: str) -> NoReturn:
        raise UsageError(f"{message} (see `{self.prog} --help`)")


def build_parser() -> argparse.ArgumentParser:
    """The parser with every discovered subcommand registered."""
    parser = _Parser(
        prog="uwbcal",
        description="DW1000 clock drift correction and power self-calibration, on boards or simulated.",
        epilog="Start: `uwbcal ports` (boards and running simulated stations), `uwbcal sim --scenario "
               "two_stations` (simulated ones); the main job is in README.md. Every command takes --json.",
    )
    parser.add_argument("--version", action="version", version=f"uwbcal {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue  # shared glue (commands/_session.py), not a subcommand
        module = importlib.import_module(f"uwbcal.commands.{info.name}")
        module.register(sub)
    return parser


def _fail(command: str, exc: UwbcalError, as_json: bool) -> int:
    """Report an error as one line (stderr), or with --json as {"error", "code"} on stdout."""
    if as_json:
        print(json.dumps({"error": str(exc), "code": exc.exit_code, "command": command,
                          "kind": type(exc).__name__}))
    else:
        print(f"uwbcal {command}: error: {exc}", file=sys.stderr)
    return exc.exit_code


def main(argv: Sequence[str] | None = None) -> int:
    """Run one command; a UwbcalError becomes a one-line message and its exit code (with
    ``--json``: one JSON object ``{"error": ..., "code": ...}`` on stdout)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    as_json = "--json" in argv
    try:
        args = parser.parse_args(argv)
    except UsageError as exc:
        return _fail(next((a for a in argv if not a.startswith("-")), ""), exc, as_json)
    try:
        return int(args.func(args) or 0)
    except UwbcalError as exc:
        return _fail(args.command, exc, bool(getattr(args, "json", False)))
    except KeyboardInterrupt:
        print(f"uwbcal {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 141
