"""`uwbcal flash`: write the EVK1000 image to the board through an SWD probe (ST-LINK).

Finds ``build/evk1000/uwbcal-evk1000.{elf,bin}`` (or ``--image``), picks an installed tool
(OpenOCD, st-flash from stlink-tools, or pyOCD), prints the exact command and runs it
unless ``--dry-run``. Each tool erases only the pages the image covers, so the calibration
tables in the last two flash pages (0x0803F000..0x0803FFFF) survive a firmware update.
"""

from __future__ import annotations

import argparse
import json
import shlex
import shutil
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from uwbcal.errors import UwbcalError

FLASH_BASE = 0x08000000
"""Start of the STM32F105RC flash (bytes address); a .bin image is written here."""

IMAGE_STEM = "build/evk1000/uwbcal-evk1000"
"""The image `make firmware` writes, relative to the repository root."""

TOOLS = ("openocd", "st-flash", "pyocd")
"""Tools in the order ``--tool auto`` tries them."""

GDB_TOOLS = ("gdb-multiarch", "arm-none-eabi-gdb")
"""Debuggers ``--gdb HOST:PORT`` uses (the first installed): GDB's ``load`` through a GDB
server (OpenOCD's on a board, or the emulated EVK1000's stub, uwbcal.evk1000.gdbstub)."""

INSTALL_HINTS = {
    "openocd": "Debian package openocd",
    "st-flash": "Debian package stlink-tools",
    "pyocd": "pip install pyocd",
}
"""Where each tool comes from. Debian's python3-pyocd (0.13) predates pyOCD's ST-LINK support,
so pyOCD comes from PyPI."""

PYOCD_TARGET = "stm32f103rc"
"""pyOCD's built-in target for the STM32F105RC: pyOCD has no built-in F105 target (it needs
a CMSIS pack); the F103RC has the same flash controller, 2 KB pages and 256 KB of flash."""


class FlashError(UwbcalError):
    """Flashing could not start or the flashing tool failed."""


@dataclass(frozen=True)
class FlashPlan:
    """What `uwbcal flash` will run: the tool, the image (path) and the full argv."""

    tool: str
    image: Path
    command: list[str]


def find_repo_root(start: Path | None = None) -> Path | None:
    """The nearest directory at or above ``start`` (default: the working directory) that
    holds the EVK1000 board port, else the checkout this package was imported from."""
    here = (start or Path.cwd()).resolve()
    marker = Path("firmware/boards/evk1000/board.mk")
    for d in (here, *here.parents):
        if (d / marker).is_file():
            return d
    pkg_root = Path(__file__).resolve().parents[3]
    if (pkg_root / marker).is_file():
        return pkg_root
    return None


def find_image(explicit: Path | None, root: Path | None) -> Path:
    """The image to flash: ``explicit`` if given (it must exist), else the .elf or .bin of
    `make firmware` under ``root``. Raises FlashError with the fix when there is none."""
    if explicit is not None:
        if not explicit.is_file():
            raise FlashError(f"image {explicit} does not exist")
        if explicit.suffix not in (".elf", ".bin", ".hex"):
            raise FlashError(f"image {explicit}: expected a .elf, .bin or .hex file")
        return explicit
    if root is not None:
        for suffix in (".elf", ".bin"):
            candidate = root / (IMAGE_STEM + suffix)
            if candidate.is_file():
                return candidate
    where = root / IMAGE_STEM if root is not None else Path(IMAGE_STEM)
    raise FlashError(f"no firmware image at {where}.elf or .bin: run `make firmware` first")


def _sibling(image: Path, suffix: str) -> Path | None:
    other = image.with_suffix(suffix)
    return other if other.is_file() else None


def build_command(tool: str, image: Path) -> list[str]:
    """The argv that writes ``image`` with ``tool``, verifies it and resets the MCU."""
    if tool == "openocd":
        if image.suffix == ".bin":
            prog = f"program {image.as_posix()} {FLASH_BASE:#010x} verify reset exit"
        else:
            prog = f"program {image.as_posix()} verify reset exit"
        return ["openocd", "-f", "interface/stlink.cfg", "-f", "target/stm32f1x.cfg", "-c", prog]
    if tool == "st-flash":
        if image.suffix == ".hex":
            return ["st-flash", "--reset", "--format", "ihex", "write", str(image)]
        binary = image if image.suffix == ".bin" else _sibling(image, ".bin")
        if binary is None:
            raise FlashError(f"st-flash needs a .bin image and there is none beside {image}")
        return ["st-flash", "--reset", "write", str(binary), f"{FLASH_BASE:#010x}"]
    if tool == "pyocd":
        cmd = ["pyocd", "flash", "--target", PYOCD_TARGET]
        if image.suffix == ".bin":
            cmd += ["--base-address", f"{FLASH_BASE:#010x}"]
        return cmd + [str(image)]
    raise FlashError(f"unknown flashing tool {tool!r} (choose from {', '.join(TOOLS)})")


def pick_tool(
    requested: str,
    which: Callable[[str], str | None] = shutil.which,
    require_installed: bool = True,
) -> str:
    """The tool to use: ``requested`` if installed (or not ``require_installed``, as for a
    dry run naming its tool), or with "auto" the first installed one (a dry run with none
    installed shows the first of TOOLS)."""
    if requested != "auto":
        if requested not in TOOLS:
            raise FlashError(f"unknown flashing tool {requested!r} (choose from {', '.join(TOOLS)})")
        if require_installed and which(requested) is None:
            raise FlashError(f"{requested} is not installed ({INSTALL_HINTS[requested]})")
        return requested
    for tool in TOOLS:
        if which(tool) is not None:
            return tool
    if not require_installed:
        return TOOLS[0]  # a dry run shows the first tool's command even with none installed
    hint = "; ".join(f"{t}: {h}" for t, h in INSTALL_HINTS.items())
    raise FlashError(f"no flashing tool found (openocd, st-flash or pyocd); install one ({hint})")


def gdb_command(gdb: str, target: str, image: Path) -> list[str]:
    """The argv that loads an ELF image through the GDB server at ``target`` (HOST:PORT),
    resets the MCU and detaches, as one would through OpenOCD's GDB server."""
    if image.suffix != ".elf":
        elf = _sibling(image, ".elf")
        if elf is None:
            raise FlashError(f"--gdb loads an ELF image and there is none beside {image}")
        image = elf
    return [gdb, "-nx", "-batch", "-ex", "set confirm off", "-ex", f"target extended-remote {target}",
            "-ex", "load", "-ex", "monitor reset", "-ex", "detach", str(image)]


def plan_gdb(image: Path | None, target: str, root: Path | None = None,
             which: Callable[[str], str | None] = shutil.which) -> FlashPlan:
    """The plan for ``--gdb HOST:PORT``: the first installed debugger of GDB_TOOLS."""
    host, _, port = target.rpartition(":")
    if not host or not port.isdigit():
        raise FlashError(f"--gdb {target!r}: expected HOST:PORT")
    found = find_image(image, root if root is not None else find_repo_root())
    for gdb in GDB_TOOLS:
        if which(gdb) is not None:
            return FlashPlan(tool=gdb, image=found, command=gdb_command(gdb, target, found))
    raise FlashError("--gdb needs gdb-multiarch or arm-none-eabi-gdb (Debian package gdb-multiarch)")


def plan(
    image: Path | None,
    tool: str,
    root: Path | None = None,
    which: Callable[[str], str | None] = shutil.which,
    require_installed: bool = True,
) -> FlashPlan:
    """Decide tool, image and command without running anything."""
    found = find_image(image, root if root is not None else find_repo_root())
    chosen = pick_tool(tool, which, require_installed)
    return FlashPlan(tool=chosen, image=found, command=build_command(chosen, found))


def execute(p: FlashPlan, capture: bool) -> subprocess.CompletedProcess[str]:
    """Run the plan's command; raise FlashError when it cannot start or exits non-zero."""
    try:
        result = subprocess.run(p.command, check=False, text=True, capture_output=capture)
    except OSError as exc:
        raise FlashError(f"could not run {p.command[0]}: {exc.strerror or exc}") from exc
    if result.returncode != 0:
        detail = ""
        if capture and (result.stderr or result.stdout):
            lines = (result.stderr or result.stdout).strip().splitlines()
            # gdb goes on after a failed connection: its first line is the cause
            detail = f": {lines[0] if p.tool in GDB_TOOLS else lines[-1]}" if lines else ""
        raise FlashError(f"{p.tool} failed with exit code {result.returncode}{detail}")
    return result


def run(args: argparse.Namespace) -> int:
    """Entry point of `uwbcal flash`."""
    # A dry run shows the command even where no tool is installed.
    if getattr(args, "gdb", None):
        p = plan_gdb(args.image, args.gdb)
    else:
        p = plan(args.image, args.tool, require_installed=not args.dry_run)
    shown = shlex.join(p.command)
    if args.json:
        if not args.dry_run:
            execute(p, capture=True)
        print(
            json.dumps(
                {
                    "tool": p.tool,
                    "image": str(p.image),
                    "command": p.command,
                    "dry_run": bool(args.dry_run),
                    "flashed": not args.dry_run,
                }
            )
        )
        return 0
    print(shown)
    sys.stdout.flush()
    if args.dry_run:
        return 0
    execute(p, capture=False)
    print(f"flashed {p.image} with {p.tool}")
    return 0


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add the `flash` subcommand."""
    parser = subparsers.add_parser(
        "flash",
        help="write the EVK1000 firmware image through an ST-LINK (SWD)",
        description="Write build/evk1000/uwbcal-evk1000 to an EVK1000 over SWD with OpenOCD, "
        "st-flash or pyOCD. The calibration-table pages are not erased.",
    )
    parser.add_argument("--image", type=Path, help="image to write (.elf, .bin or .hex)")
    parser.add_argument("--tool", choices=("auto", *TOOLS), default="auto", help="flashing tool")
    parser.add_argument("--gdb", metavar="HOST:PORT", default=None,
                        help="load through a GDB server instead (OpenOCD's, or an emulated "
                             "EVK1000's: python -m uwbcal.evk1000 --gdb PORT) with gdb-multiarch")
    parser.add_argument("--dry-run", action="store_true", help="print the command, do not run it")
    parser.add_argument("--json", action="store_true", help="print one JSON line")
    parser.set_defaults(func=run)
