"""The EVK1000's USB link and station core, built for the host, against the OTG FS model.

``build/usbhosted/libevkusb.so`` (``make usbhosted``) is firmware/boards/evk1000/usb/*.c and
firmware/core built with ``-DOTG_HOSTED`` (usb/hosted/hosted_board.c): every OTG FS register
access the driver makes calls :class:`uwbcal.evk1000.otgfs.OtgFs`; the driver's interrupt
handler runs whenever the model's interrupt line is high and the "CPU" is at a point where
the chip would take it (between main-loop passes and inside the driver's bounded waits).

This runs the exact driver C code, not the ARM image: startup, clocks, NVIC priorities and
real preemption points are not exercised (the emulated EVK1000, issue 10, does that).
Time is virtual microseconds (``time_us``), advanced by the harness.
"""

from __future__ import annotations

import ctypes
import os
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Final

from uwbcal.errors import UwbcalError
from uwbcal.evk1000.otgfs import OtgFs

#: Device time one main-loop pass is taken to cost, us (the chip needs far less; a larger
#: value only makes timeouts come sooner in the harness).
POLL_US: Final = 20
#: Device time one driver wait pass costs, us.
WAIT_US: Final = 20
#: Longest the main loop idles before it polls again, us (APP_IDLE_MAX_US is 10 ms).
IDLE_US: Final = 1000

#: UID of a hosted station unless told otherwise ("UWBCHST" + 1).
DEFAULT_UID: Final = bytes.fromhex("555742434853540000000001")

_READ = ctypes.CFUNCTYPE(ctypes.c_uint32, ctypes.c_uint32)
_WRITE = ctypes.CFUNCTYPE(None, ctypes.c_uint32, ctypes.c_uint32)
_WAIT = ctypes.CFUNCTYPE(None)


def default_lib() -> Path:
    """``$UWBCAL_USBHOSTED`` or build/usbhosted/libevkusb.so of the source tree."""
    env = os.environ.get("UWBCAL_USBHOSTED")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[3] / "build" / "usbhosted" / "libevkusb.so"


class HostedStation:
    """One station whose host link is the USB driver on the OTG FS model.

    ``wait_hook`` (set by the pty bridge) is what the USB host does while the firmware waits
    inside the driver or for the radio: it must only issue transactions, never run the device
    itself.
    """

    def __init__(self, uid: bytes = DEFAULT_UID, lib: Path | None = None, station_id: int = 1,
                 flash: Path | None = None, medium: str | None = None) -> None:
        path = lib or default_lib()
        if not path.exists():
            raise UwbcalError(f"{path}: not built (run `make usbhosted`)")
        # A private copy: the dynamic loader shares one instance per path, and a station must
        # boot with its static RAM zeroed as the chip does.
        self._dir = tempfile.TemporaryDirectory(prefix="uwbcal-usbhosted-")
        private = Path(self._dir.name) / path.name
        shutil.copyfile(path, private)
        self.lib = ctypes.CDLL(str(private))
        self.model = OtgFs()
        self.medium = medium is not None
        self._t = 0
        self.in_isr = False
        self.resets = 0
        self.wait_hook: Callable[[], None] | None = None
        # keep the callbacks alive as long as the library may call them
        self._cbs = (_READ(self._read), _WRITE(self._write), _WAIT(self._wait))
        self.lib.hosted_set_callbacks(*self._cbs)
        self._bus_cb = _WAIT(self._bus)
        self.lib.hosted_set_bus_callback(self._bus_cb)
        self.lib.hosted_set_time_us.argtypes = [ctypes.c_uint64]
        self.lib.hosted_time_us.restype = ctypes.c_uint64
        self.lib.hosted_idle.argtypes = [ctypes.c_uint32]
        self.lib.hosted_attach.argtypes = [ctypes.c_uint16, ctypes.c_char_p, ctypes.c_char_p]
        self.lib.hosted_tx_failures.restype = ctypes.c_uint32
        self.lib.cdc_tx_dropped.restype = ctypes.c_uint32
        if len(uid) != 12:
            raise ValueError("uid: 12 bytes")
        self.lib.hosted_set_uid((ctypes.c_uint8 * 12)(*uid))
        f = str(flash).encode() if flash is not None else None
        m = medium.encode() if medium is not None else None
        if self.lib.hosted_attach(station_id, f, m) != 0:
            raise UwbcalError(f"USB station {station_id}: the medium at {medium} does not answer")
        self.error: Exception | None = None
        self.lib.hosted_init()
        self.check()
        if not self.model.connected:
            raise UwbcalError("USB driver: init did not connect (D+ pull-up off)")

    # ---- callbacks from C -----------------------------------------------------------------
    def _read(self, offset: int) -> int:
        try:
            return self.model.read(offset, 4)
        except Exception as e:  # an exception cannot cross the C frames: kept, raised after
            self.error = self.error or e
            return 0

    def _write(self, offset: int, value: int) -> None:
        try:
            self.model.write(offset, 4, value)
        except Exception as e:
            self.error = self.error or e

    def check(self) -> None:
        """Raise what the model reported while C code was running (a driver bug)."""
        if self.error is not None:
            e, self.error = self.error, None
            raise e

    def _wait(self) -> None:
        self.advance(WAIT_US)
        self._bus()

    def _bus(self) -> None:
        """The USB host and the interrupt run while the firmware waits (driver or radio)."""
        try:
            if self.wait_hook is not None:
                self.wait_hook()
            self.service_irq()
        except Exception as e:  # cannot cross the C frames: kept, raised after
            self.error = self.error or e

    # ---- the "CPU" ----------------------------------------------------------------------------
    @property
    def time_us(self) -> int:
        """The station's time (board_time_us): the medium's virtual time when attached."""
        return int(self.lib.hosted_time_us()) if self.medium else self._t

    def advance(self, us: int) -> None:
        """Let ``us`` of device time pass with the firmware idle (with the medium: a wait in
        virtual time, which ends early on radio or link events)."""
        if self.medium:
            self.lib.hosted_idle(us)
        else:
            self._t += us
            self.lib.hosted_set_time_us(self._t)

    def set_link_fd(self, fd: int) -> None:
        """Input on ``fd`` (the bridge's pty) ends the firmware's idle waits early."""
        self.lib.hosted_set_link_fd(fd)

    def should_exit(self) -> bool:
        """SIGTERM or SIGINT arrived (a station process)."""
        return bool(self.lib.hosted_should_exit())

    def service_irq(self) -> None:
        """Run the OTG FS interrupt handler while the line is high (level-sensitive, bounded)."""
        if self.in_isr:
            return
        self.in_isr = True
        try:
            for _ in range(64):
                if not self.model.irq_line:
                    break
                self.lib.hosted_irq()
                self.check()
        finally:
            self.in_isr = False

    def run_us(self, us: int) -> None:
        """The station's main loop for ``us`` of device time (the DeviceRunner of usbhost)."""
        end = self.time_us + us
        while True:
            self.service_irq()
            r = self.lib.hosted_poll()
            self.check()
            if r == 2:  # RESET: the firmware restarts, the core is reset, the host sees a detach
                self.resets += 1
                self.model.reset_core()
                self.lib.hosted_init()
            self.service_irq()
            now = self.time_us
            if now >= end or self.should_exit():
                return
            if r == 1 and self.medium:
                continue  # virtual time stands still while the station works
            self.advance(POLL_US if r == 1 else min(IDLE_US, max(end - now, 1)))

    @property
    def tx_failures(self) -> int:
        """Link writes the station core counted as failed."""
        return int(self.lib.hosted_tx_failures())

    @property
    def tx_dropped(self) -> int:
        """Bytes the CDC-ACM link could not send (no host, or the host did not read)."""
        return int(self.lib.cdc_tx_dropped())
