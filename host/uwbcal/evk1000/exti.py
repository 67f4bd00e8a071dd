"""External interrupt/event controller (RM0008 10.2 "EXTI", 10.3 "EXTI registers").

Lines 0..15 watch the GPIO pin of their number on the port AFIO_EXTICRx selects. An edge
enabled in RTSR/FTSR sets the line's PR bit; with IMR set, the line's NVIC interrupt is
pended (EXTI0..4: their own vectors; 5..9 share EXTI9_5, 10..15 share EXTI15_10). PR is
write-one-to-clear; SWIER sets PR by software.
"""

from __future__ import annotations

from typing import Final

from uwbcal.evk1000.errors import BusError
from uwbcal.evk1000.gpio import Afio
from uwbcal.evk1000.nvic import Nvic

EXTI_BASE: Final = 0x40010400
IRQN_EXTI0: Final = 6
IRQN_EXTI9_5: Final = 23
IRQN_EXTI15_10: Final = 40


def line_irqn(line: int) -> int:
    """The NVIC interrupt of EXTI line 0..15 (RM0008 table 62)."""
    if line < 5:
        return IRQN_EXTI0 + line
    return IRQN_EXTI9_5 if line < 10 else IRQN_EXTI15_10


class Exti:
    """IMR, EMR, RTSR, FTSR, SWIER, PR for lines 0..19."""

    name = "EXTI"
    base = EXTI_BASE
    size = 0x400

    def __init__(self, nvic: Nvic, afio: Afio) -> None:
        self.nvic = nvic
        self.afio = afio
        self.edges = 0
        self.reset()

    def reset(self) -> None:
        """All zero."""
        self.imr = self.emr = self.rtsr = self.ftsr = self.pr = 0

    def on_pin(self, port: int, pin: int, level: int) -> None:
        """GPIO listener: pin ``pin`` of port ``port`` changed to ``level``."""
        if self.afio.exti_port(pin) != port:
            return
        bit = 1 << pin
        if (level and self.rtsr & bit) or (not level and self.ftsr & bit):
            self._trigger(pin)

    def _trigger(self, line: int) -> None:
        self.edges += 1
        self.pr |= 1 << line
        if self.imr & (1 << line):
            self.nvic.set_pending(line_irqn(line))

    def read(self, offset: int, width: int) -> int:
        """Read a register."""
        if width != 4:
            raise BusError(f"{width}-byte EXTI access")
        regs = {0: self.imr, 4: self.emr, 8: self.rtsr, 12: self.ftsr, 16: 0, 20: self.pr}
        if offset not in regs:
            raise BusError(f"EXTI offset {offset:#x} is not a register")
        return regs[offset]

    def write(self, offset: int, width: int, value: int) -> None:
        """Write a register (PR: 1 clears)."""
        if width != 4:
            raise BusError(f"{width}-byte EXTI access")
        value &= 0xFFFFF
        if offset == 0:
            self.imr = value
        elif offset == 4:
            self.emr = value
        elif offset == 8:
            self.rtsr = value
        elif offset == 12:
            self.ftsr = value
        elif offset == 16:
            for line in range(20):
                if value & (1 << line):
                    self._trigger(line)
        elif offset == 20:
            self.pr &= ~value
        else:
            raise BusError(f"EXTI offset {offset:#x} is not a register")
