"""The embedded flash and its program/erase controller, FPEC (RM0008 3.3.3 "Embedded Flash
memory"; PM0075 "STM32F10xxx Flash memory microcontrollers" 2.3 and 3 for the sequences and
registers).

Flash: 256 KB at 0x08000000 in 2 KB pages, kept in a file (the station's "flash file") that
survives restarts; erased bytes read 0xFF. Registers: ACR, KEYR, OPTKEYR, SR, CR, AR, OBR,
WRPR at 0x40022000.

- Unlock: KEY1 then KEY2 into KEYR clears CR.LOCK; any other sequence locks the FPEC until
  the next reset (PM0075 2.3.1).
- Program (CR.PG): one 16-bit write to a flash address programs one half-word. A half-word
  that does not read 0xFFFF is not programmed and SR.PGERR is set (writing 0x0000 is
  allowed, PM0075 2.3.3); a byte or word write is a bus error.
- Page erase (CR.PER, AR, CR.STRT): the page reads 0xFF; mass erase (CR.MER) likewise.
- SR.BSY is set while an operation runs and SR.EOP when it ends (write 1 to clear). The CPU
  stalls while BSY (code runs from flash), so an operation costs emulated time but no
  instructions: erase 20 ms, program 52.5 us (datasheet DS6014 typical values).
- Power cut: ``cut_at`` = N cuts the power during the N-th flash operation (erase or
  half-word program, counted from 1 since this FPEC was made). The operation is left half
  done -- an erase reaches only the first half of its page, a half-word gets only the
  programmable 1->0 bits of its low byte -- and :class:`PowerCut` is raised: the emulated
  MCU stops there.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import Final

from uwbcal.evk1000.errors import BusError, PowerCut

FLASH_BASE: Final = 0x08000000
FLASH_SIZE: Final = 256 * 1024
PAGE_SIZE: Final = 2048
FPEC_BASE: Final = 0x40022000
KEY1: Final = 0x45670123
KEY2: Final = 0xCDEF89AB
SR_BSY, SR_PGERR, SR_WRPRTERR, SR_EOP = 1 << 0, 1 << 2, 1 << 4, 1 << 5
CR_PG, CR_PER, CR_MER, CR_STRT, CR_LOCK = 1 << 0, 1 << 1, 1 << 2, 1 << 6, 1 << 7
ERASE_S: Final = 20e-3
PROGRAM_S: Final = 52.5e-6


class FlashFile:
    """The flash array, mirrored in a file (created erased, 0xFF, when missing)."""

    def __init__(self, path: str | os.PathLike[str] | None, size: int = FLASH_SIZE) -> None:
        self.size = size
        self.path = Path(path) if path is not None else None
        self.data = bytearray(b"\xff" * size)
        self._fd: int | None = None
        if self.path is not None:
            self._fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            old = os.pread(self._fd, size, 0)
            self.data[:len(old)] = old
            if len(old) < size:
                os.pwrite(self._fd, bytes(self.data[len(old):]), len(old))

    def store(self, offset: int, data: bytes) -> None:
        """Change bytes at ``offset`` (memory and file)."""
        self.data[offset:offset + len(data)] = data
        if self._fd is not None:
            os.pwrite(self._fd, data, offset)

    def close(self) -> None:
        """Close the file."""
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None


class Fpec:
    """The flash interface registers and the program/erase operations."""

    name = "FLASH"
    base = FPEC_BASE
    size = 0x400

    def __init__(self, flash: FlashFile, mirror: Callable[[int, bytes], None],
                 stall: Callable[[float], None], cut_at: int | None = None) -> None:
        self.flash = flash
        self.mirror = mirror          #: copies changed bytes into the CPU's view (address, bytes)
        self.stall = stall            #: the CPU waits this many seconds (BSY)
        self.cut_at = cut_at
        self.ops = 0                  #: flash operations started
        self.erases = 0
        self.programs = 0
        self.reset()

    def reset(self) -> None:
        """Reset values: locked, ACR 0x30."""
        self.acr = 0x30
        self.sr = 0
        self.cr = CR_LOCK
        self.ar = 0
        self._key_stage = 0
        self._key_error = False

    def _store(self, offset: int, data: bytes) -> None:
        self.flash.store(offset, data)
        self.mirror(FLASH_BASE + offset, data)

    def _begin(self) -> bool:
        """Count an operation; True if the power is cut during it."""
        self.ops += 1
        return self.cut_at is not None and self.ops == self.cut_at

    def program(self, addr: int, width: int, value: int) -> None:
        """A CPU write to flash memory (only half-words with CR.PG; anything else is a fault)."""
        if width != 2:
            raise BusError(f"{width}-byte write to flash at {addr:#010x} (flash is programmed by "
                           "half-words only)")
        if not self.cr & CR_PG or self.cr & CR_LOCK:
            raise BusError(f"write to flash at {addr:#010x} without CR.PG set and the FPEC unlocked")
        if addr & 1:
            raise BusError(f"unaligned half-word flash program at {addr:#010x}")
        off = addr - FLASH_BASE
        old = int.from_bytes(self.flash.data[off:off + 2], "little")
        cut = self._begin()
        self.programs += 1
        if old != 0xFFFF and value != 0:
            self.sr |= SR_PGERR
            return
        if cut:
            partial = old & (value | 0xFF00)          # only the low byte's bits got programmed
            self._store(off, partial.to_bytes(2, "little"))
            raise PowerCut(f"power cut during flash operation {self.ops} (program {addr:#010x})")
        self._store(off, (old & value).to_bytes(2, "little"))
        self.stall(PROGRAM_S)
        self.sr |= SR_EOP

    def _erase(self, first: int, count: int) -> None:
        cut = self._begin()
        self.erases += 1
        n = count * PAGE_SIZE
        if cut:
            self._store(first, b"\xff" * (n // 2))
            raise PowerCut(f"power cut during flash operation {self.ops} (erase {FLASH_BASE + first:#010x})")
        self._store(first, b"\xff" * n)
        self.stall(ERASE_S * count)
        self.sr |= SR_EOP

    def read(self, offset: int, width: int) -> int:
        """Read ACR, SR, CR, AR, OBR, WRPR."""
        if width != 4:
            raise BusError(f"{width}-byte access to the FLASH interface (word access only)")
        regs = {0: self.acr, 0xC: self.sr, 0x10: self.cr, 0x14: self.ar, 0x1C: 0x03FFFFFC,
                0x20: 0xFFFFFFFF}
        if offset not in regs:
            raise BusError(f"FLASH interface offset {offset:#x} is not readable")
        return regs[offset]

    def write(self, offset: int, width: int, value: int) -> None:
        """Write ACR, KEYR, SR (1 clears), CR (STRT starts an erase), AR."""
        if width != 4:
            raise BusError(f"{width}-byte access to the FLASH interface (word access only)")
        if offset == 0:
            self.acr = value & 0x1F
        elif offset == 4:                                        # KEYR
            if self._key_error or not self.cr & CR_LOCK:
                self._key_error = True                           # PM0075 2.3.1: locked till reset
                self.cr |= CR_LOCK
                return
            if self._key_stage == 0 and value == KEY1:
                self._key_stage = 1
            elif self._key_stage == 1 and value == KEY2:
                self._key_stage = 0
                self.cr &= ~CR_LOCK
            else:
                self._key_error = True
        elif offset == 8:
            return                                               # OPTKEYR: option bytes not modelled
        elif offset == 0xC:
            self.sr &= ~(value & (SR_PGERR | SR_WRPRTERR | SR_EOP))
        elif offset == 0x10:
            if self.cr & CR_LOCK:
                return                                           # locked: CR cannot change
            self.cr = value & 0x3F7
            if value & CR_STRT:
                self.cr &= ~CR_STRT
                if self.cr & CR_PER:
                    off = (self.ar - FLASH_BASE) & ~(PAGE_SIZE - 1)
                    if not 0 <= off < self.flash.size:
                        raise BusError(f"page erase of {self.ar:#010x}, outside the flash")
                    self._erase(off, 1)
                elif self.cr & CR_MER:
                    self._erase(0, self.flash.size // PAGE_SIZE)
        elif offset == 0x14:
            self.ar = value
        else:
            raise BusError(f"FLASH interface offset {offset:#x} is not writable")
