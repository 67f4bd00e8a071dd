"""Reset and clock control of the connectivity line (RM0008 8.2 "Clocks", 8.3 "RCC registers").

Ready bits follow their enable bits at once (no start-up delay is modelled), except that a
switch, ``hse_fails``, keeps HSERDY low: the 12 MHz crystal does not start, so PLL2 (fed by
HSE through PREDIV2) and a PLL fed from PLL2 never lock either, and the firmware's bounded
waits time out into its HSI fallback. SWS follows SW when the selected source is ready.

The machine reads :meth:`Rcc.sysclk_hz` to turn CPU cycles into time: the emulated time
base follows the clock tree the image programs (72 MHz from HSE/PLL2/PLL, 8 MHz on HSI).
"""

from __future__ import annotations

from typing import Final

from uwbcal.evk1000.errors import BusError

RCC_BASE: Final = 0x40021000
HSI_HZ: Final = 8_000_000
HSE_HZ: Final = 12_000_000      #: the EVK1000 crystal

# CR bits
HSION, HSIRDY, HSEON, HSERDY = 1 << 0, 1 << 1, 1 << 16, 1 << 17
PLLON, PLLRDY, PLL2ON, PLL2RDY, PLL3ON, PLL3RDY = 1 << 24, 1 << 25, 1 << 26, 1 << 27, 1 << 28, 1 << 29

_NAMES: Final = {0x00: "CR", 0x04: "CFGR", 0x08: "CIR", 0x0C: "APB2RSTR", 0x10: "APB1RSTR",
                 0x14: "AHBENR", 0x18: "APB2ENR", 0x1C: "APB1ENR", 0x20: "BDCR", 0x24: "CSR",
                 0x28: "AHBRSTR", 0x2C: "CFGR2"}
_RESET: Final = {0x00: 0x00000083, 0x14: 0x00000014, 0x24: 0x0C000000}


class Rcc:
    """The RCC registers and the clock frequencies they select."""

    name = "RCC"
    base = RCC_BASE
    size = 0x400

    def __init__(self, hse_fails: bool = False) -> None:
        self.hse_fails = hse_fails
        self.regs: dict[int, int] = {}
        self.reset()

    def reset(self) -> None:
        """Reset values (RM0008 8.3)."""
        self.regs = {off: _RESET.get(off, 0) for off in _NAMES}

    # ---- the clock tree ----------------------------------------------------------------
    def _pll2_hz(self) -> int | None:
        if not self.regs[0] & PLL2RDY:
            return None
        c2 = self.regs[0x2C]
        prediv2 = ((c2 >> 4) & 0xF) + 1
        m = (c2 >> 8) & 0xF
        mul = {0xE: 16, 0xF: 20}.get(m, m + 2)
        return HSE_HZ * mul // prediv2

    def _pll_hz(self) -> int | None:
        if not self.regs[0] & PLLRDY:
            return None
        cfgr, c2 = self.regs[4], self.regs[0x2C]
        if cfgr & (1 << 16):                                   # PLLSRC = PREDIV1
            src = self._pll2_hz() if c2 & (1 << 16) else (HSE_HZ if self.regs[0] & HSERDY else None)
            if src is None:
                return None
            src //= (c2 & 0xF) + 1
        else:
            src = HSI_HZ // 2
        m = (cfgr >> 18) & 0xF
        if m == 0xD:
            return src * 13 // 2                               # x6.5
        return src * (m + 2)

    def sysclk_hz(self) -> int:
        """SYSCLK from CFGR.SWS."""
        sws = (self.regs[4] >> 2) & 3
        if sws == 1:
            return HSE_HZ
        if sws == 2:
            return self._pll_hz() or HSI_HZ
        return HSI_HZ

    def hclk_hz(self) -> int:
        """AHB clock (HPRE)."""
        hpre = (self.regs[4] >> 4) & 0xF
        div = 1 if hpre < 8 else 1 << (hpre - 7 + (1 if hpre >= 12 else 0))
        return self.sysclk_hz() // div

    def pclk2_hz(self) -> int:
        """APB2 clock (PPRE2): SPI1, USART1."""
        p = (self.regs[4] >> 11) & 7
        return self.hclk_hz() // (1 if p < 4 else 1 << (p - 3))

    def source_name(self) -> str:
        """'pll' or 'hsi' or 'hse': what SYSCLK runs on."""
        return {0: "hsi", 1: "hse", 2: "pll"}.get((self.regs[4] >> 2) & 3, "hsi")

    # ---- registers ---------------------------------------------------------------------
    def _settle(self) -> None:
        cr = self.regs[0]
        cr = (cr & ~HSIRDY) | (HSIRDY if cr & HSION else 0)
        cr = (cr & ~HSERDY) | (HSERDY if cr & HSEON and not self.hse_fails else 0)
        cr = (cr & ~PLL2RDY) | (PLL2RDY if cr & PLL2ON and cr & HSERDY else 0)
        cr = (cr & ~PLL3RDY) | (PLL3RDY if cr & PLL3ON and cr & HSERDY else 0)
        self.regs[0] = cr
        cfgr, c2 = self.regs[4], self.regs[0x2C]
        if cfgr & (1 << 16):
            src_ok = bool(cr & PLL2RDY) if c2 & (1 << 16) else bool(cr & HSERDY)
        else:
            src_ok = bool(cr & HSIRDY)
        self.regs[0] = (cr & ~PLLRDY) | (PLLRDY if cr & PLLON and src_ok else 0)
        cr = self.regs[0]
        sw = cfgr & 3
        ready = {0: cr & HSIRDY, 1: cr & HSERDY, 2: cr & PLLRDY}.get(sw, 0)
        if ready:
            self.regs[4] = (cfgr & ~0xC) | (sw << 2)

    def read(self, offset: int, width: int) -> int:
        """Read a register (byte and half-word reads of a word register are allowed)."""
        word = offset & ~3
        if word not in _NAMES:
            raise BusError(f"RCC offset {offset:#x} is not a register")
        return (self.regs[word] >> (8 * (offset & 3))) & ((1 << (8 * width)) - 1)

    def write(self, offset: int, width: int, value: int) -> None:
        """Write a register; ready bits and SWS are read-only and follow."""
        if width != 4 or offset not in _NAMES:
            raise BusError(f"{width}-byte RCC write at offset {offset:#x}")
        if offset == 0:
            ro = HSIRDY | HSERDY | PLLRDY | PLL2RDY | PLL3RDY
            self.regs[0] = (self.regs[0] & ro) | (value & ~ro)
        elif offset == 4:
            self.regs[4] = (self.regs[4] & 0xC) | (value & ~0xC)
        elif offset == 8:
            self.regs[8] = value & 0x0000FF00                  # ready flags cleared by the 1s
        else:
            self.regs[offset] = value
        self._settle()
