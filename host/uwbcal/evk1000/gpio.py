"""GPIO ports and AFIO (RM0008 9.1 "GPIO functional description", 9.2 "GPIO registers",
9.4 "AFIO registers").

Each pin has a 4-bit configuration (CNF[1:0] MODE[1:0], RM0008 table 20). A pin's level is
what the MCU drives (general-purpose or alternate-function output: ODR; open drain: ODR 0
pulls low, 1 releases) or, when it is an input or released, what the board drives from
outside (:meth:`GpioPort.drive`), else the pull resistor (input with pull: ODR selects up or
down), else low. Every change of a pin's level is reported to the listeners (the EXTI edge
detectors, the DW1000 chip select and reset), so nothing is polled.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Final

from uwbcal.evk1000.errors import BusError

GPIOA_BASE: Final = 0x40010800
AFIO_BASE: Final = 0x40010000
PORT_STRIDE: Final = 0x400

Listener = Callable[[int, int, int], None]      #: (port index 0=A, pin, new level)


class GpioPort:
    """One GPIO port (CRL, CRH, IDR, ODR, BSRR, BRR, LCKR)."""

    size = 0x400

    def __init__(self, index: int, listeners: list[Listener]) -> None:
        self.index = index
        self.name = f"GPIO{'ABCDEFG'[index]}"
        self.base = GPIOA_BASE + index * PORT_STRIDE
        self.listeners = listeners
        self.external: dict[int, int] = {}      #: pin -> level driven by the board
        self.reset()

    def reset(self) -> None:
        """Reset values: every pin input floating (CRL = CRH = 0x44444444)."""
        self.cr = [0x4] * 16
        self.odr = 0
        self.lckr = 0
        self.levels = self._levels()

    def _pin_level(self, pin: int) -> int:
        nib = self.cr[pin]
        mode, cnf = nib & 3, nib >> 2
        out = (self.odr >> pin) & 1
        if mode != 0:                                   # output
            if cnf & 1 and out:                         # open drain, released
                return self.external.get(pin, 0)
            return out
        ext = self.external.get(pin)
        if ext is not None:
            return ext
        if cnf == 2:                                    # input with pull-up/down
            return out
        return 0

    def _levels(self) -> int:
        return sum(self._pin_level(p) << p for p in range(16))

    def _update(self) -> None:
        new = self._levels()
        diff, self.levels = new ^ self.levels, new
        if diff:
            for pin in range(16):
                if (diff >> pin) & 1:
                    for cb in self.listeners:
                        cb(self.index, pin, (new >> pin) & 1)

    def drive(self, pin: int, level: int | None) -> None:
        """The board drives ``pin`` to ``level`` (None: releases it)."""
        if level is None:
            self.external.pop(pin, None)
        else:
            self.external[pin] = level & 1
        self._update()

    def level(self, pin: int) -> int:
        """The pin's level now."""
        return (self.levels >> pin) & 1

    def read(self, offset: int, width: int) -> int:
        """Read CRL, CRH, IDR, ODR, LCKR (BSRR, BRR read 0)."""
        if width != 4:
            raise BusError(f"{width}-byte access to {self.name} (word access only)")
        if offset in (0, 4):
            first = 0 if offset == 0 else 8
            return sum(self.cr[first + i] << (4 * i) for i in range(8))
        if offset == 8:
            return self.levels
        if offset == 12:
            return self.odr
        if offset in (16, 20):
            return 0
        if offset == 24:
            return self.lckr
        raise BusError(f"{self.name} offset {offset:#x} is not a register")

    def write(self, offset: int, width: int, value: int) -> None:
        """Write CRL, CRH, ODR, BSRR (set low half, reset high half; set wins), BRR, LCKR."""
        if width != 4:
            raise BusError(f"{width}-byte access to {self.name} (word access only)")
        if offset in (0, 4):
            first = 0 if offset == 0 else 8
            for i in range(8):
                self.cr[first + i] = (value >> (4 * i)) & 0xF
        elif offset == 8:
            return                                      # IDR is read-only
        elif offset == 12:
            self.odr = value & 0xFFFF
        elif offset == 16:
            self.odr = (self.odr & ~(value >> 16)) | (value & 0xFFFF)
        elif offset == 20:
            self.odr &= ~(value & 0xFFFF)
        elif offset == 24:
            self.lckr = value & 0x1FFFF
            return
        else:
            raise BusError(f"{self.name} offset {offset:#x} is not a register")
        self._update()


class Afio:
    """AFIO: EVCR, MAPR, EXTICR1..4, MAPR2; the EXTI line sources are read by the EXTI."""

    name = "AFIO"
    base = AFIO_BASE
    size = 0x400

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        """All zero: every EXTI line from port A."""
        self.regs = [0] * 8

    def exti_port(self, line: int) -> int:
        """The port index (0 = A) EXTI ``line`` listens to."""
        return (self.regs[2 + line // 4] >> (4 * (line % 4))) & 0xF

    def read(self, offset: int, width: int) -> int:
        """Read a register."""
        if width != 4 or offset > 0x1C or offset % 4:
            raise BusError(f"{width}-byte AFIO access at offset {offset:#x}")
        return self.regs[offset // 4]

    def write(self, offset: int, width: int, value: int) -> None:
        """Write a register."""
        if width != 4 or offset > 0x1C or offset % 4:
            raise BusError(f"{width}-byte AFIO access at offset {offset:#x}")
        self.regs[offset // 4] = value
