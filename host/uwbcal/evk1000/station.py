"""One emulated EVK1000 station as a process, a drop-in for the native ``uwbcal-station``:

    python -m uwbcal.evk1000 --id N --flash PATH [--medium SOCKET] [--image BIN] [--elf ELF]
                             [--hse-fail] [--baud-timing] [--power-cut N] [--gdb [HOST:]PORT]
                             [--stats FILE]

prints ``PTY <path>`` on stdout and serves the host link there until SIGTERM: USART1 for an
image built with ``LINK=usart``, else (the default image) its USB CDC-ACM link, enumerated
by the USB host of :mod:`uwbcal.evk1000.usbhost` on the OTG FS model and bridged to the pty
as cdc_acm bridges /dev/ttyACM0 (:func:`image_has_usb` tells them apart). The flash file
holds the flash; ``--image`` first programs an image into it the way ``uwbcal flash`` does
(only the pages the image covers are erased: calibration tables survive), else the station
boots what the flash file holds. With ``--medium`` the DW1000 is the medium's model of
station N, in lock-step (:mod:`uwbcal.evk1000.radio`); without it a local register model
with empty air.

``--gdb`` first serves one GDB session with the CPU halted (uwbcal.evk1000.gdbstub), then
boots what the flash file holds. Exit codes: 0 on SIGTERM, 9 when the image faults (one line
on stderr naming the PC and the address), 10 when the power-cut switch fired.
"""

from __future__ import annotations

import argparse
import errno
import json
import os
import select
import signal
import struct
import sys
import termios
import tty
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from uwbcal.evk1000.errors import EmulatorError, PowerCut
from uwbcal.evk1000.fpec import FLASH_SIZE, PAGE_SIZE, FlashFile
from uwbcal.evk1000.image import Symbols, elf_beside
from uwbcal.evk1000.machine import Machine
from uwbcal.evk1000.radio import LocalRadio, TunnelRadio
from uwbcal.evk1000.uid import uid_for_station
from uwbcal.evk1000.usbbridge import UsbPtyBridge
from uwbcal.evk1000.usbhost import UsbHost
from uwbcal.evk1000.usbmachine import attach_usb

EXIT_FAULT = 9
EXIT_POWER_CUT = 10
#: CPU time between two lock-step synchronisations with the medium while the CPU runs, us.
SYNC_US = 50


def program_image(flash: FlashFile, image: bytes) -> None:
    """Write an image at the start of flash as a flasher does: the pages it covers erased,
    then programmed; every other page (the calibration tables) untouched."""
    if len(image) > FLASH_SIZE:
        raise EmulatorError(f"image of {len(image)} bytes does not fit in {FLASH_SIZE} bytes of flash")
    pages = -(-len(image) // PAGE_SIZE)
    flash.store(0, image + b"\xff" * (pages * PAGE_SIZE - len(image)))


class PtyLink:
    """The host end: the slave of a pty, opened by the host as it opens /dev/ttyACM0."""

    def __init__(self) -> None:
        self.master, slave = os.openpty()
        self.path = os.ttyname(slave)
        tty.setraw(slave, termios.TCSANOW)
        os.close(slave)
        os.set_blocking(self.master, False)
        self.dropped = 0

    def fd(self) -> int | None:
        """The fd to wait on, or None while no host holds the slave open (POLLHUP)."""
        p = select.poll()
        p.register(self.master, select.POLLIN)
        ev = p.poll(0)
        if ev and ev[0][1] & select.POLLHUP and not ev[0][1] & select.POLLIN:
            return None
        return self.master

    def read(self) -> bytes:
        """Bytes the host sent (non-blocking)."""
        try:
            return os.read(self.master, 4096)
        except OSError as exc:
            if exc.errno in (errno.EAGAIN, errno.EIO):
                return b""
            raise

    def write(self, data: bytes) -> None:
        """Bytes to the host; dropped while nobody listens (as a USB CDC port does)."""
        try:
            os.write(self.master, data)
        except OSError:
            self.dropped += len(data)


@dataclass
class StationStats:
    """What a run of the image cost (the benchmark and ``--stats`` report these)."""

    cycles: int
    instructions: int
    sleep_cycles: int
    mmio_accesses: int
    exceptions: int
    stack_high_water: int
    round_trips: int
    link_bytes_in: int
    link_bytes_out: int
    spi_transactions: int
    flash_ops: int
    resets: int
    sysclk_hz: int
    time_us: int


def stats_of(m: Machine, bridge: UsbPtyBridge | None = None) -> StationStats:
    """The counters of a machine now; the link's bytes are the USB bridge's when the image
    talks over USB, else USART1's."""
    link_in = bridge.bytes_out if bridge is not None else m.usart1.bytes_in    # host -> station
    link_out = bridge.bytes_in if bridge is not None else m.usart1.bytes_out   # station -> host
    return StationStats(cycles=m.cycles, instructions=m.instructions, sleep_cycles=m.sleep_cycles,
                        mmio_accesses=m.mmio_accesses, exceptions=m.exceptions_taken,
                        stack_high_water=m.stack_high_water(),
                        round_trips=getattr(m.radio, "round_trips", 0), link_bytes_in=link_in,
                        link_bytes_out=link_out, spi_transactions=m.spi1.transactions,
                        flash_ops=m.fpec.ops, resets=m.resets, sysclk_hz=m.sysclk_hz, time_us=m.time_us())


class Station:
    """The machine, its host link and its radio, and the loop that runs them."""

    def __init__(self, sid: int, flash: FlashFile, link: PtyLink, medium: str | None, *,
                 symbols: Symbols, hse_fails: bool = False, cut_at: int | None = None,
                 baud_timing: bool = False) -> None:
        self.link = link
        self.bridge: UsbPtyBridge | None = None
        self.wait_hook: Callable[[], None] | None = None  # (BridgedDevice; unused: a real CPU)
        holder: list[Machine] = []

        def now() -> int:
            return holder[0].time_us() if holder else 0

        uid = uid_for_station(sid)
        radio: TunnelRadio | LocalRadio
        radio = TunnelRadio(medium, sid, uid, now) if medium else LocalRadio(now)
        self.radio = radio
        self.machine = Machine(flash, uid=uid, radio=radio, link_sink=link.write, hse_fails=hse_fails,
                               cut_at=cut_at, symbols=symbols, baud_timing=baud_timing)
        holder.append(self.machine)
        if isinstance(radio, TunnelRadio):
            self.machine.t0_us = radio.now_us
        self.running = True
        self.usb_host: UsbHost | None = None

    def start_usb(self) -> None:
        """The image has a USB link (:func:`image_has_usb`): put the OTG FS model on the bus,
        enumerate the device as Linux does, open it as cdc_acm does, and bridge its bulk
        endpoints to this station's pty (the one already printed)."""
        if self.usb_host is None:
            self.otg, self.usb_host = attach_usb(self.machine)
        self.usb_host.runner = self
        self.usb_host.enumerate()
        self.usb_host.cdc_open()
        self.bridge = UsbPtyBridge(self.usb_host, self, pty_master=(self.link.master, self.link.path))

    # ---- the device side of the USB host and bridge (usbhost.DeviceRunner, BridgedDevice) ----
    @property
    def time_us(self) -> int:
        return self.machine.time_us()

    def run_us(self, us: int) -> None:
        """Run the station (CPU, radio, link) for ``us`` of emulated time."""
        end = self.machine.time_us() + us
        while self.running and self.machine.time_us() < end:
            self._step(end)

    def service_irq(self) -> None:
        """Nothing: the NVIC model takes the USB interrupt when the CPU runs."""

    def should_exit(self) -> bool:
        return not self.running

    def set_link_fd(self, fd: int) -> None:
        """Nothing: the sleep below watches the bridge's pty itself."""

    def _irq_line(self) -> None:
        self.machine.gpio[1].drive(5, int(self.radio.irq))    # DW1000 IRQ on PB5

    def _pump_link(self) -> None:
        if self.bridge is not None:
            self.bridge.service()   # the USB host's bulk slots that passed, OUT and IN
            return
        if not self.machine.usart1.rx_enabled:
            return              # before the image enables its receiver the bytes wait in the pty
        data = self.link.read()
        if data:
            self.machine.usart1.feed(data)

    def _wake_fd(self) -> int | None:
        return self.link.fd()  # the bridge serves the same pty

    def _step(self, until_us: int | None = None) -> None:
        """One slice of CPU time, the link, the radio; a WFI with nothing pending sleeps until
        the next timer event, the radio IRQ, host input or ``until_us``."""
        m, radio = self.machine, self.radio
        slice_cycles = SYNC_US * m.sysclk_hz // 1_000_000
        why = m.run(slice_cycles)
        self._pump_link()
        now = m.time_us()
        if isinstance(radio, TunnelRadio) and now - radio.med_us >= SYNC_US:
            radio.sync()
        self._irq_line()
        if why == "wfi" and not m.nvic.wake_pending():
            ev = m.next_event_cycle()
            deadline = now + 1_000_000 if ev is None else max(now, m.time_us_at(ev))
            if until_us is not None:
                deadline = min(deadline, max(until_us, now + 1))
            if self.bridge is not None and self.bridge.busy():
                deadline = min(deadline, now + 1000)  # the host polls again next frame
            t = radio.sleep(deadline, m.in_function("board_idle"), self._wake_fd())
            m.advance_to_us(t)
            self._irq_line()
            self._pump_link()

    def serve(self) -> None:
        """Run until :attr:`running` goes false (signal) or the image faults."""
        while self.running:
            self._step()


def image_has_usb(flash: bytes) -> bool:
    """The image's OTG FS interrupt vector (RM0008 table 62, position 67) is its own handler,
    not the default one every unused vector shares (WWDG's, position 0): a USB build."""
    if len(flash) < 4 * (16 + 68):
        return False
    vec: tuple[int, ...] = struct.unpack_from("<84I", flash, 0)
    return bool(vec[16 + 67] != vec[16 + 0])


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``python -m uwbcal.evk1000``."""
    p = argparse.ArgumentParser(prog="python -m uwbcal.evk1000", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--id", type=int, required=True, help="station id 1..65535 (fixes the UID)")
    p.add_argument("--flash", default=None, help="flash file (256 KB; created erased)")
    p.add_argument("--medium", default=None, help="unix socket of the radio medium")
    p.add_argument("--image", default=None, help="program this .bin into flash before booting")
    p.add_argument("--elf", default=None, help="symbols for messages (default: the .elf beside --image)")
    p.add_argument("--hse-fail", action="store_true", help="the 12 MHz crystal does not start")
    p.add_argument("--baud-timing", action="store_true",
                   help="USART1 bytes take their time on the wire at the programmed baud rate")
    p.add_argument("--power-cut", type=int, default=None, metavar="N",
                   help="cut the power during the N-th flash operation (erase or half-word program)")
    p.add_argument("--gdb", default=None, metavar="[HOST:]PORT",
                   help="first serve one GDB session on this TCP port (the CPU halted), then boot "
                        "what the flash holds")
    p.add_argument("--stats", default=None, metavar="FILE",
                   help="write run statistics (JSON) here on exit and on SIGUSR1 ({id}: the station id)")
    args = p.parse_args(argv)
    if not 1 <= args.id <= 65535:
        p.error("--id must be 1..65535")
    tag = f"uwbcal-evk1000 {args.id}"
    try:
        flash = FlashFile(args.flash)
        elf = Path(args.elf) if args.elf else (elf_beside(Path(args.image)) if args.image else None)
        if args.image:
            program_image(flash, Path(args.image).read_bytes())
        symbols = Symbols.from_elf(elf) if elf else Symbols()
        link = PtyLink()
        station = Station(args.id, flash, link, args.medium, symbols=symbols, hse_fails=args.hse_fail,
                          cut_at=args.power_cut, baud_timing=args.baud_timing)
    except (OSError, EmulatorError) as exc:
        print(f"{tag}: error: {exc}", file=sys.stderr)
        return EXIT_FAULT

    def stop(_sig: int, _frame: Any) -> None:
        station.running = False
        if station.machine.in_emu:
            station.machine.uc.emu_stop()       # an exception raised in a Unicorn hook is lost
        else:
            raise SystemExit(0)

    stats_path = Path(args.stats.replace("{id}", str(args.id))) if args.stats else None

    def dump(_sig: int = 0, _frame: Any = None) -> None:
        if stats_path is not None:
            stats_path.write_text(json.dumps(stats_of(station.machine, station.bridge).__dict__) + "\n")

    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
    signal.signal(signal.SIGUSR1, dump)
    print(f"PTY {link.path}", flush=True)
    code = 0
    try:
        if args.gdb:
            from uwbcal.evk1000.gdbstub import GdbStub

            host, _, port = args.gdb.rpartition(":")
            stub = GdbStub(station.machine, host or "127.0.0.1", int(port))
            print(f"{tag}: GDB stub listening on {host or '127.0.0.1'}:{stub.port}", file=sys.stderr,
                  flush=True)
            how = stub.serve_session()
            stub.close()
            print(f"{tag}: GDB session ended ({how}); booting the flash", file=sys.stderr, flush=True)
            if how == "kill":
                return 0
            station.machine.reset()
        if image_has_usb(bytes(flash.data[:4 * 84])):
            station.start_usb()  # bytes the host sends meanwhile wait in the pty
        station.serve()
    except SystemExit:
        code = 0
    except PowerCut as exc:
        print(f"{tag}: {exc}", file=sys.stderr)
        code = EXIT_POWER_CUT
    except EmulatorError as exc:
        print(f"{tag}: error: {exc}", file=sys.stderr)
        code = EXIT_FAULT
    except (ConnectionError, OSError) as exc:
        print(f"{tag}: radio tunnel lost: {exc}", file=sys.stderr)
        code = EXIT_FAULT
    finally:
        for ev in station.machine.events:
            print(f"{tag}: {ev}", file=sys.stderr)
        st = stats_of(station.machine, station.bridge)
        print(f"{tag}: {st}", file=sys.stderr)
        dump()
        flash.close()
    return code
