"""SysTick timer of the Cortex-M3 (PM0056 4.4 "SysTick timer").

A 24-bit down counter clocked by the processor clock (CSR.CLKSOURCE = 1) or HCLK / 8. It is
not stepped: its value is computed from the machine's cycle counter, so reading SYST_CVR in
a busy loop sees time pass exactly as the emulated instructions make it pass. When the count
goes from 1 to 0 COUNTFLAG is set and, with TICKINT, the SysTick exception is pended; the
next clock reloads RVR.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Final

from uwbcal.evk1000.errors import BusError

SYSTICK_BASE: Final = 0xE000E010
MASK24: Final = 0xFFFFFF


class SysTick:
    """SYST_CSR, SYST_RVR, SYST_CVR, SYST_CALIB."""

    name = "SysTick"
    base = SYSTICK_BASE
    size = 0x10

    def __init__(self, cycles: Callable[[], int], pend: Callable[[], None]) -> None:
        self._cycles = cycles
        self._pend = pend
        self.reset()

    def reset(self) -> None:
        """Reset values (PM0056 4.4: CSR 0, RVR/CVR unknown: 0 here)."""
        self.csr = 0
        self.rvr = 0
        self._origin = 0        #: tick count at which the counter held _start
        self._start = 0
        self._next_wrap: int | None = None   #: tick count of the next 1 -> 0 transition
        self.wraps = 0

    @property
    def enabled(self) -> bool:
        """CSR.ENABLE."""
        return bool(self.csr & 1)

    def _div(self) -> int:
        return 1 if self.csr & 4 else 8

    def _ticks(self) -> int:
        return self._cycles() // self._div()

    def value(self) -> int:
        """SYST_CVR now."""
        if not self.enabled:
            return self._start
        e = self._ticks() - self._origin
        if e <= self._start:
            return self._start - e
        if self.rvr == 0:
            return 0
        return self.rvr - ((e - self._start - 1) % (self.rvr + 1))

    def _schedule(self) -> None:
        if not self.enabled:
            self._next_wrap = None
            return
        now = self._ticks()
        e = now - self._origin
        if e < self._start:
            self._next_wrap = self._origin + self._start
        elif self.rvr == 0:
            self._next_wrap = None
        else:
            period = self.rvr + 1
            k = (e - self._start) // period + 1
            self._next_wrap = self._origin + self._start + k * period

    def next_event_cycle(self) -> int | None:
        """The cycle count at which the counter next reaches 0, if it runs."""
        if self._next_wrap is None:
            return None
        return self._next_wrap * self._div()

    def advance(self) -> None:
        """Called by the machine after time passed: pend the exception for a wrap."""
        nw = self._next_wrap
        if nw is None or self._ticks() < nw:
            return
        self.csr |= 1 << 16                                   # COUNTFLAG
        self.wraps += 1
        if self.csr & 2:
            self._pend()
        self._schedule()

    def read(self, offset: int, width: int) -> int:
        """Read SYST_CSR (clears COUNTFLAG), RVR, CVR or CALIB."""
        if width != 4:
            raise BusError(f"{width}-byte access to SysTick")
        if offset == 0:
            self.advance()
            v = self.csr
            self.csr &= ~(1 << 16)
            return v
        if offset == 4:
            return self.rvr
        if offset == 8:
            return self.value()
        if offset == 12:
            return 0x40000000 | 9000       # CALIB: NOREF, TENMS for 9 MHz (HCLK / 8 at 72 MHz)
        raise BusError(f"SysTick offset {offset:#x}")

    def write(self, offset: int, width: int, value: int) -> None:
        """Write SYST_CSR, RVR or CVR (any write clears the counter)."""
        if width != 4:
            raise BusError(f"{width}-byte access to SysTick")
        if offset == 0:
            cur = self.value()
            self.csr = (self.csr & (1 << 16)) | (value & 7)
            self._origin, self._start = self._ticks(), cur
        elif offset == 4:
            self.rvr = value & MASK24
        elif offset == 8:
            self._origin, self._start = self._ticks(), 0
            self.csr &= ~(1 << 16)
        elif offset == 12:
            return
        else:
            raise BusError(f"SysTick offset {offset:#x}")
        self._schedule()
