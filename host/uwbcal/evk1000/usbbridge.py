"""The bulk endpoints of an emulated USB CDC-ACM device as a pty: the host side of
/dev/ttyACM0 (Linux's cdc_acm and tty layer), so any program, `uwbcal info` included, opens
the emulated USB station exactly as it opens a board.

Per 1 ms full-speed frame the bridge moves at most :data:`PACKETS_PER_FRAME` bulk packets
(USB 2.0 5.8.4: 19 x 64-byte bulk transactions fit a full-speed frame), OUT first (bytes the
program wrote to the pty), then IN (written to the pty), like cdc_acm's queued read URBs.
``reading = False`` models a host that stopped reading (port closed or throttled): IN tokens
stop, the device's IN FIFO stays full and its writes wait, then time out.
Units: device time in microseconds, sizes in bytes.
"""

from __future__ import annotations

import os
import pty
import queue
import select
import termios
import threading
import tty
from collections.abc import Callable
from typing import Final, Protocol

from uwbcal.evk1000.otgfs import EPCTL_EPENA
from uwbcal.evk1000.usbhost import FRAME_US, UsbHost

PACKETS_PER_FRAME: Final = 19
SLOT_US: Final = FRAME_US / PACKETS_PER_FRAME
#: Device time the station runs between two looks at the slots, us.
RUN_US: Final = 25
EP_DATA: Final = 1
#: Bytes the bridge takes from the pty ahead of the device (the rest waits in the pty).
MAX_PENDING: Final = 1 << 20


class BridgedDevice(Protocol):
    """What the bridge needs of the device side: the host-side harness (usbhosted.
    HostedStation) or the emulated EVK1000 (usbmachine.MachineRunner)."""

    wait_hook: Callable[[], None] | None

    @property
    def time_us(self) -> int: ...
    def run_us(self, us: int) -> None: ...
    def service_irq(self) -> None: ...
    def should_exit(self) -> bool: ...
    def set_link_fd(self, fd: int) -> None: ...


class UsbPtyBridge:
    """pty <-> bulk OUT/IN of one enumerated CDC-ACM device."""

    def __init__(self, host: UsbHost, station: BridgedDevice,
                 pty_master: tuple[int, str] | None = None) -> None:
        """A new raw pty, or ``pty_master`` = (master fd, slave path) of one already handed
        out (the emulated station prints its pty before it knows which link the image has)."""
        self.host = host
        self.station = station
        self.slave: int | None = None
        if pty_master is not None:
            self.master, self.path = pty_master
        else:
            self.master, self.slave = pty.openpty()
            tty.setraw(self.slave)
            attrs = termios.tcgetattr(self.slave)
            attrs[3] &= ~termios.ECHO
            termios.tcsetattr(self.slave, termios.TCSANOW, attrs)
            self.path = os.ttyname(self.slave)
        os.set_blocking(self.master, False)
        self.dropped = 0
        self.reading = True
        self.enumerating = False
        self.pending_out = b""
        self.bytes_in = 0
        self.bytes_out = 0
        self._slot_t = 0.0
        self._calls: queue.Queue[tuple[Callable[[], object], queue.Queue[object]]] = queue.Queue()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        station.wait_hook = self.service
        station.set_link_fd(self.master)  # program input ends an idle early

    # ---- one frame ------------------------------------------------------------------------------
    def _write_pty(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            try:
                n = os.write(self.master, view)
            except BlockingIOError:
                select.select([], [self.master], [], 0.05)
                continue
            except OSError:  # nobody holds the pty open: dropped, as a closed ttyACM drops
                self.dropped += len(view)
                return
            view = view[n:]

    def _in_once(self) -> bool:
        p = self.host.bulk_in_packet(0x80 | EP_DATA)
        if p is None:
            return False
        if p:
            self.bytes_in += len(p)
            self._write_pty(p)
        return True

    def _take_slot(self) -> bool:
        """One bulk transaction slot: PACKETS_PER_FRAME per 1 ms of device time (a backlog of
        at most one frame is caught up)."""
        now = self.station.time_us
        if self._slot_t > now:
            return False
        self._slot_t = max(self._slot_t, now - FRAME_US) + SLOT_US
        return True

    def busy(self) -> bool:
        """Bytes wait to go OUT, or the device has an IN transfer queued."""
        return bool(self.pending_out) or bool(self.host.dev.ins[EP_DATA].ctl & EPCTL_EPENA)

    def service(self) -> None:
        """The host uses the bulk slots that passed, OUT and IN, without running the device:
        while the firmware waits (in its driver, or for the radio; on the chip the USB
        interrupt preempts the wait), or between the emulated CPU's slices."""
        if self.enumerating:
            return
        self._drain_pty()
        while self._take_slot():
            did = bool(self.pending_out) and self._out_once()
            if not did and self.reading:
                did = self._in_once()
            self.station.service_irq()
            if not did:
                break

    def _out_once(self) -> bool:
        chunk = self.pending_out[:64]
        pid = self.host.toggle_out.get(EP_DATA, 0)
        if self.host.dev.out(self.host.addr, EP_DATA, chunk, pid) != "ACK":
            return False
        self.host.toggle_out[EP_DATA] = pid ^ 1
        self.pending_out = self.pending_out[len(chunk):]
        self.bytes_out += len(chunk)
        return True

    def _drain_pty(self) -> None:
        """Take what the program wrote. Always: pending pty input ends the firmware's idle
        waits at once (as host input does for a native station), so it must not linger."""
        if len(self.pending_out) < MAX_PENDING:
            try:
                self.pending_out += os.read(self.master, MAX_PENDING)
            except (BlockingIOError, OSError):
                pass

    def frame(self) -> int:
        """1 ms of device time: in each transaction slot one OUT packet (bytes the program
        wrote) or else one IN token, the device running in between. Returns packets moved."""
        moved = 0
        end = self.station.time_us + FRAME_US
        while self.station.time_us < end:
            self._drain_pty()
            if self._take_slot():
                did = bool(self.pending_out) and self._out_once()
                if not did and self.reading:
                    did = self._in_once()
                moved += did
                self.station.service_irq()
                # a slot with nothing to move: the device runs to the end of the frame
                self.station.run_us(RUN_US if did else max(end - self.station.time_us, 1))
            else:
                self.station.run_us(RUN_US)
            if self.station.should_exit():
                break
        self.host.time_us = self.station.time_us
        return moved

    # ---- bus events, run between frames on the bridge's thread ----------------------------------------
    def call(self, fn: Callable[[], object], timeout_s: float = 60.0) -> object:
        """Run ``fn`` on the bridge thread between two frames (every call into the device
        happens on that thread); returns its result or raises its exception."""
        if self._thread is None:
            return fn()
        box: queue.Queue[object] = queue.Queue()
        self._calls.put((fn, box))
        r = box.get(timeout=timeout_s)
        if isinstance(r, BaseException):
            raise r
        return r

    def reset_and_reenumerate(self) -> None:
        """A port reset in the middle of traffic (Linux's usb_reset_device, on error recovery):
        bus reset, enumeration again, cdc_acm's line setup again; the tty stays."""
        self.enumerating = True  # no bulk traffic until the configuration is back
        try:
            self.host.port_reset()
            self.host.cdc_open()
        finally:
            self.enumerating = False

    def _run_calls(self) -> None:
        while True:
            try:
                fn, box = self._calls.get_nowait()
            except queue.Empty:
                return
            try:
                box.put(fn())
            except BaseException as e:  # handed to the caller's thread
                box.put(e)

    # ---- background service ------------------------------------------------------------------------
    def serve(self) -> None:
        """Frames until stop(): when nothing moves, wait (real time) for the program to write."""
        idle = 0
        while not self._stop.is_set():
            self._run_calls()
            moved = self.frame()
            idle = 0 if moved else idle + 1
            if idle > 20:
                select.select([self.master], [], [], 0.005)

    def start(self) -> UsbPtyBridge:
        self._thread = threading.Thread(target=self.serve, name="usb-pty-bridge", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=10)
        for fd in (self.master, self.slave):
            if fd is None:
                continue
            try:
                os.close(fd)
            except OSError:
                pass

    def __enter__(self) -> UsbPtyBridge:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
