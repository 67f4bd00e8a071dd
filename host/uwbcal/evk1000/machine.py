"""The emulated STM32F105RC: Unicorn's Cortex-M3, the memory map, exceptions, time, faults.

Memory map (RM0008 3.3): flash 256 KB at 0x08000000 (read/execute for the CPU; writes go to
the FPEC model), SRAM 64 KB at 0x20000000, the peripherals attached with :meth:`attach`
(each 4 KB page that holds one is an MMIO page; an address in such a page that no
peripheral claims is a bus error), the system control space 0xE000E000. Anything else is
unmapped: an access there stops the machine with an :class:`EmulatorError` naming the PC,
the address and the access, never a silent zero. Peripheral registers must be accessed
naturally aligned; an unaligned one is reported likewise.

Exceptions (PM0056 2.3.7 "Exception entry and return"): Unicorn has no NVIC, so the machine
does entry and return. Entry at an instruction boundary: the 8-word frame (r0-r3, r12, lr,
return address, xPSR) pushed on the current stack with 8-byte alignment (xPSR bit 9 when
padded), LR = EXC_RETURN (0xFFFFFFF9 from thread mode, 0xFFFFFFF1 from a handler), PC = the
vector at VTOR + 4 * number. Return: a branch to an EXC_RETURN value, which Unicorn reports as
an exception at 0xFFFFFFFx, unstacks the frame. Tail-chaining and preemption follow from
taking the most urgent pending exception whenever the execution priority allows
(:class:`~uwbcal.evk1000.nvic.Nvic`). IPSR holds the active exception's number (MRS reads
it); Unicorn's own exception return (QEMU's, which needs QEMU's NVIC) is never run: the
interrupt hook stops emulation when the branch to EXC_RETURN raises it.

Time: ``cycles`` counts executed instructions at one cycle each (a lower bound of a real
Cortex-M3 at 2 flash wait states), plus the cycles the CPU stalls (flash BSY) or sleeps
(WFI). Cycles become microseconds through the SYSCLK the RCC model selects (72 MHz, or 8
MHz on HSI), from :attr:`Machine.t0_us` (the medium's time at power-on).

Stack: at power-on the RAM is painted with 0xA5A5A5A5; :meth:`Machine.stack_high_water`
finds the deepest stack word ever written.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from typing import Any, Final

from unicorn import (
    UC_ARCH_ARM,
    UC_ERR_EXCEPTION,
    UC_HOOK_BLOCK,
    UC_HOOK_INTR,
    UC_HOOK_MEM_INVALID,
    UC_HOOK_MEM_READ,
    UC_HOOK_MEM_WRITE,
    UC_HOOK_MEM_WRITE_PROT,
    UC_MEM_FETCH_PROT,
    UC_MEM_FETCH_UNMAPPED,
    UC_MEM_READ,
    UC_MEM_READ_PROT,
    UC_MEM_READ_UNMAPPED,
    UC_MEM_WRITE_PROT,
    UC_MEM_WRITE_UNMAPPED,
    UC_MODE_MCLASS,
    UC_MODE_THUMB,
    UC_PROT_ALL,
    UC_PROT_EXEC,
    UC_PROT_READ,
)
from unicorn import arm_const as A
from unicorn.unicorn import Uc, UcError

from uwbcal.evk1000 import Peripheral
from uwbcal.evk1000.errors import BusError, EmulatorError, PowerCut
from uwbcal.evk1000.exti import Exti
from uwbcal.evk1000.fpec import FLASH_BASE, FLASH_SIZE, FlashFile, Fpec
from uwbcal.evk1000.gpio import Afio, GpioPort, Listener
from uwbcal.evk1000.image import Symbols
from uwbcal.evk1000.nvic import EXC_SYSTICK, Nvic
from uwbcal.evk1000.radio import Radio
from uwbcal.evk1000.rcc import Rcc
from uwbcal.evk1000.spi import Spi
from uwbcal.evk1000.systick import SysTick
from uwbcal.evk1000.uid import DeviceSignature
from uwbcal.evk1000.usart import Usart

SRAM_BASE: Final = 0x20000000
SRAM_SIZE: Final = 64 * 1024
PAINT: Final = 0xA5A5A5A5
PAGE: Final = 0x1000
WFI: Final = 0xBF30
_REGS: Final = (A.UC_ARM_REG_R0, A.UC_ARM_REG_R1, A.UC_ARM_REG_R2, A.UC_ARM_REG_R3, A.UC_ARM_REG_R12,
                A.UC_ARM_REG_LR)
_ACCESS: Final = {UC_MEM_READ_UNMAPPED: "read of unmapped", UC_MEM_WRITE_UNMAPPED: "write to unmapped",
                  UC_MEM_FETCH_UNMAPPED: "instruction fetch from unmapped",
                  UC_MEM_READ_PROT: "read of protected", UC_MEM_WRITE_PROT: "write to protected",
                  UC_MEM_FETCH_PROT: "instruction fetch from non-executable"}


class Machine:
    """One STM32F105RC with the EVK1000's wiring (SPI1 + DW1000, USART1 link)."""

    def __init__(self, flash: FlashFile, *, uid: bytes, radio: Radio, link_sink: Callable[[bytes], None],
                 hse_fails: bool = False, cut_at: int | None = None, symbols: Symbols | None = None,
                 baud_timing: bool = False) -> None:
        self.symbols = symbols or Symbols()
        # Unicorn's Python binding is untyped: the engine is held as Any.
        uc: Any = Uc(UC_ARCH_ARM, UC_MODE_THUMB | UC_MODE_MCLASS)  # type: ignore[no-untyped-call]
        self.uc: Any = uc
        self.in_emu = False
        uc.ctl_set_cpu_model(A.UC_CPU_ARM_CORTEX_M3)
        uc.mem_map(FLASH_BASE, FLASH_SIZE, UC_PROT_READ | UC_PROT_EXEC)
        uc.mem_map(SRAM_BASE, SRAM_SIZE, UC_PROT_ALL)
        self.flash = flash
        uc.mem_write(FLASH_BASE, bytes(flash.data))
        self.cycles = 0
        self.t0_us = 0
        self._clk = (0, 0, 8_000_000)            # (cycles, ps, hz) at the last clock change
        self.pc = 0
        self.mmio_accesses = 0
        self.exceptions_taken = 0
        self.instructions = 0
        self.sleep_cycles = 0
        self.resets = 0
        self.events: list[str] = []              #: things the image did that a user should know
        self._icount: dict[int, int] = {}
        self._stop_at = 0
        self._fault: str | None = None
        self._power_cut: PowerCut | None = None
        self._reset_requested = False
        self._check_primask = False
        self._intno: int | None = None
        self._periphs: list[Peripheral] = []
        self._slots: dict[int, list[Peripheral]] = {}
        self._mapped_pages: set[int] = set()
        self._tickers: list[Any] = []
        self._rstn_low = False

        self.nvic = Nvic(self._request_reset)
        self.systick = SysTick(lambda: self.cycles, lambda: self.nvic.pend_exception(EXC_SYSTICK))
        self.rcc = Rcc(hse_fails=hse_fails)
        self.fpec = Fpec(flash, self._mirror, self._stall, cut_at)
        self.afio = Afio()
        self.exti = Exti(self.nvic, self.afio)
        self.spi1 = Spi(radio)
        self.radio = radio
        listeners: list[Listener] = [self.exti.on_pin, self.spi1.on_pin, self._on_rstn]
        self.gpio = [GpioPort(i, listeners) for i in range(5)]
        self.usart1 = Usart(self.nvic, link_sink, baud_timing=baud_timing, cycles=lambda: self.cycles,
                            cpu_per_pclk=lambda: self.rcc.sysclk_hz() / self.rcc.pclk2_hz())
        self.signature = DeviceSignature(uid)
        own: tuple[Peripheral, ...] = (self.nvic, self.systick, self.rcc, self.fpec, self.afio, self.exti,
                                       self.spi1, *self.gpio, self.usart1, self.signature)
        for p in own:
            self.attach(p)
        self.gpio[0].drive(0, 1)                 # DW1000 RSTn: the chip holds it high when running
        self.gpio[0].drive(10, 1)                # USART1 RX idles high

        uc.hook_add(UC_HOOK_BLOCK, self._on_block)
        uc.hook_add(UC_HOOK_MEM_INVALID, self._on_invalid)
        uc.hook_add(UC_HOOK_MEM_WRITE_PROT, self._on_flash_write, begin=FLASH_BASE,
                    end=FLASH_BASE + FLASH_SIZE - 1)
        uc.hook_add(UC_HOOK_INTR, self._on_intr)
        # Unicorn splits an unaligned access into aligned pieces before the MMIO callbacks see
        # it: the alignment of peripheral accesses is checked on the access as issued.
        for lo, hi in ((0x40000000, 0x5FFFFFFF), (0xE0000000, 0xE00FFFFF)):
            uc.hook_add(UC_HOOK_MEM_READ | UC_HOOK_MEM_WRITE, self._check_align, begin=lo, end=hi)
        self.power_on()

    # ---- peripherals -----------------------------------------------------------------
    def attach(self, p: Peripheral) -> None:
        """Map a peripheral (see the package docstring for the interface)."""
        self._periphs.append(p)
        for slot in range(p.base >> 10, (p.base + p.size - 1 >> 10) + 1):
            self._slots.setdefault(slot, []).append(p)
        for page in range(p.base // PAGE, (p.base + p.size - 1) // PAGE + 1):
            if page not in self._mapped_pages:
                self._mapped_pages.add(page)
                base = page * PAGE
                self.uc.mmio_map(base, PAGE, self._mmio_read, base, self._mmio_write, base)
        if hasattr(p, "tick"):
            self._tickers.append(p)

    def _find(self, addr: int) -> Peripheral:
        for p in self._slots.get(addr >> 10, ()):
            if p.base <= addr < p.base + p.size:
                return p
        raise BusError("no peripheral at this address")

    def _mmio_read(self, uc: Any, offset: int, size: int, base: int) -> int:
        addr = base + offset
        self.mmio_accesses += 1
        try:
            if addr % size:
                raise BusError("unaligned peripheral access")
            p = self._find(addr)
            return p.read(addr - p.base, size)
        except BusError as exc:
            self._stop_fault(f"{size}-byte read at {addr:#010x}: {exc}")
            return 0

    def _mmio_write(self, uc: Any, offset: int, size: int, value: int, base: int) -> None:
        addr = base + offset
        self.mmio_accesses += 1
        p: Peripheral | None = None
        try:
            if addr % size:
                raise BusError("unaligned peripheral access")
            p = self._find(addr)
            p.write(addr - p.base, size, value & ((1 << (8 * size)) - 1))
        except BusError as exc:
            self._stop_fault(f"{size}-byte write of {value:#x} at {addr:#010x}: {exc}")
        except PowerCut as exc:
            self._power_cut = exc
            uc.emu_stop()
        if p is self.rcc:
            self._clock_changed()
        if self.nvic.changed:
            self._stop_at = 0                    # take a newly pending exception at once

    def _on_flash_write(self, uc: Any, access: int, addr: int, size: int, value: int, _: object) -> bool:
        self.mmio_accesses += 1
        try:
            self.fpec.program(addr, size, value)
        except BusError as exc:
            self._stop_fault(f"{size}-byte write of {value:#x} at {addr:#010x}: {exc}")
            return False
        except PowerCut as exc:
            self._power_cut = exc
            uc.emu_stop()
        return True

    def _check_align(self, uc: Any, access: int, addr: int, size: int, value: int, _: object) -> None:
        if addr % size:
            what = "read" if access == UC_MEM_READ else "write"
            self._stop_fault(f"{size}-byte {what} at {addr:#010x}: unaligned peripheral access")

    def _mirror(self, addr: int, data: bytes) -> None:
        self.uc.mem_write(addr, data)

    def _on_rstn(self, port: int, pin: int, level: int) -> None:
        if port != 0 or pin != 0:
            return
        if level == 0:
            self._rstn_low = True
        elif self._rstn_low:
            self._rstn_low = False
            self.radio.reset()

    # ---- time --------------------------------------------------------------------------
    @property
    def sysclk_hz(self) -> int:
        """The CPU clock now, Hz."""
        return self._clk[2]

    def time_ps(self) -> int:
        """Emulated time since power-on plus :attr:`t0_us`, ps."""
        c0, ps0, hz = self._clk
        return self.t0_us * 1_000_000 + ps0 + (self.cycles - c0) * 10**12 // hz

    def time_us(self) -> int:
        """Emulated time, us (the medium's clock)."""
        return self.time_ps() // 1_000_000

    def time_us_at(self, cycle: int) -> int:
        """The time (us, rounded up) at which the cycle count reaches ``cycle`` (same clock)."""
        c0, ps0, hz = self._clk
        ps = self.t0_us * 1_000_000 + ps0 + (cycle - c0) * 10**12 // hz
        return -(-ps // 1_000_000)

    def _clock_changed(self) -> None:
        hz = self.rcc.sysclk_hz()
        if hz != self._clk[2]:
            self._clk = (self.cycles, self.time_ps() - self.t0_us * 1_000_000, hz)

    def _stall(self, seconds: float) -> None:
        self.cycles += round(seconds * self._clk[2])

    def cycles_at_us(self, t_us: int) -> int:
        """The cycle count at which the time reaches ``t_us``."""
        c0, ps0, hz = self._clk
        ps = t_us * 1_000_000 - self.t0_us * 1_000_000 - ps0
        return c0 + -(-ps * hz // 10**12)

    def advance_to_us(self, t_us: int) -> None:
        """Time passes without instructions (the CPU slept) until ``t_us``."""
        c = self.cycles_at_us(t_us)
        if c > self.cycles:
            self.sleep_cycles += c - self.cycles
            self.cycles = c

    def next_event_cycle(self) -> int | None:
        """The next cycle at which a timer wants the CPU (SysTick, peripheral events)."""
        ev = self.systick.next_event_cycle()
        for p in self._tickers:
            nxt = getattr(p, "next_event_cycle", None)
            if nxt is not None:
                c = nxt()
                if c is not None and (ev is None or c < ev):
                    ev = c
        return ev

    # ---- reset and power -----------------------------------------------------------------
    def power_on(self) -> None:
        """Power-on: RAM painted (its content is undefined), then a reset."""
        self.uc.mem_write(SRAM_BASE, struct.pack("<I", PAINT) * (SRAM_SIZE // 4))
        self.reset()

    def _request_reset(self) -> None:
        self._reset_requested = True
        self.uc.emu_stop()

    def reset(self) -> None:
        """System reset (SYSRESETREQ): core and peripherals to reset values, RAM kept."""
        self.resets += 1
        for p in self._periphs:
            r = getattr(p, "reset", None)
            if r is not None:
                r()
        self._clock_changed()
        self._reset_requested = False
        for reg in (*_REGS, A.UC_ARM_REG_R4, A.UC_ARM_REG_R5, A.UC_ARM_REG_R6, A.UC_ARM_REG_R7,
                    A.UC_ARM_REG_R8, A.UC_ARM_REG_R9, A.UC_ARM_REG_R10, A.UC_ARM_REG_R11):
            self.uc.reg_write(reg, 0)
        self.uc.reg_write(A.UC_ARM_REG_PRIMASK, 0)
        self.uc.reg_write(A.UC_ARM_REG_XPSR, 1 << 24)
        sp, pc = struct.unpack("<II", bytes(self.flash.data[0:8]))
        self.initial_sp = sp
        self.uc.reg_write(A.UC_ARM_REG_SP, sp)
        self.uc.reg_write(A.UC_ARM_REG_LR, 0xFFFFFFFF)
        self.bootable = bool(pc & 1) and FLASH_BASE <= pc < FLASH_BASE + FLASH_SIZE
        self.pc = pc & ~1 if self.bootable else FLASH_BASE

    # ---- faults ------------------------------------------------------------------------
    def where(self, pc: int | None = None) -> str:
        """``PC 0x... (function+off)``."""
        return "PC " + self.symbols.describe(self.uc.reg_read(A.UC_ARM_REG_PC) if pc is None else pc)

    def _stop_fault(self, what: str) -> None:
        if self._fault is None:
            self._fault = f"{what} at {self.where()}"
        self.uc.emu_stop()

    def _on_invalid(self, uc: Any, access: int, addr: int, size: int, value: int, _: object) -> bool:
        if access == UC_MEM_WRITE_PROT and FLASH_BASE <= addr < FLASH_BASE + FLASH_SIZE:
            return False                                  # handled by _on_flash_write's fault
        if access == UC_MEM_FETCH_UNMAPPED and addr >= 0xFFFFFFF0:
            return False                                  # EXC_RETURN: handled in run()
        kind = _ACCESS.get(access, f"access {access} to")
        if self._fault is None:
            self._fault = f"{kind} address {addr:#010x} ({size} bytes) at {self.where()}"
        return False

    def _on_intr(self, uc: Any, intno: int, _: object) -> None:
        # A CPU exception Unicorn cannot deliver (no NVIC): with this hook installed Unicorn
        # would resume at the faulting PC, so stop and let run() look at it.
        self._intno = intno
        uc.emu_stop()

    # ---- execution ------------------------------------------------------------------
    def _on_block(self, uc: Any, addr: int, size: int, _: object) -> None:
        n = self._icount.get(addr)
        if n is None:
            code = bytes(uc.mem_read(addr, size))
            n = i = 0
            while i < size:
                i += 4 if code[i + 1] >> 3 in (0x1D, 0x1E, 0x1F) else 2
                n += 1
            self._icount[addr] = n
        self.cycles += n
        self.instructions += n
        if self.cycles >= self._stop_at:
            uc.emu_stop()
        elif self._check_primask and not uc.reg_read(A.UC_ARM_REG_PRIMASK):
            uc.emu_stop()

    def _service(self) -> None:
        """Between slices: timers, reset requests, exceptions to take."""
        self.systick.advance()
        if self._reset_requested:
            self.reset()
        nv = self.nvic
        self._check_primask = False
        if nv.pending:
            primask = bool(self.uc.reg_read(A.UC_ARM_REG_PRIMASK))
            exc = nv.next_exception(primask)
            if exc is not None:
                self._enter(exc)
            elif primask and nv.next_exception(False) is not None:
                self._check_primask = True
        nv.changed = False

    def _enter(self, exc: int) -> None:
        uc = self.uc
        sp = uc.reg_read(A.UC_ARM_REG_SP)
        xpsr = (uc.reg_read(A.UC_ARM_REG_XPSR) & ~0x3FF) | self.nvic.current | (1 << 24)
        frame_sp = (sp - 32) & ~7
        if frame_sp != sp - 32:
            xpsr |= 1 << 9
        if frame_sp < SRAM_BASE:
            raise EmulatorError(f"stack overflow: exception {exc} entry with SP {sp:#010x} "
                                f"at {self.where(self.pc)}")
        vals = [uc.reg_read(r) for r in _REGS]
        uc.mem_write(frame_sp, struct.pack("<8I", *vals, self.pc, xpsr))
        uc.reg_write(A.UC_ARM_REG_SP, frame_sp)
        uc.reg_write(A.UC_ARM_REG_LR, 0xFFFFFFF9 if not self.nvic.active else 0xFFFFFFF1)
        self.nvic.activate(exc)
        vec_addr = self.nvic.vtor + 4 * exc
        if vec_addr < FLASH_SIZE:
            vec_addr += FLASH_BASE                        # boot alias: flash at 0
        vector = struct.unpack("<I", bytes(uc.mem_read(vec_addr, 4)))[0]
        if not vector & 1:
            raise EmulatorError(f"exception {exc}: vector {vector:#010x} at {vec_addr:#010x} is not a Thumb "
                                f"address (taken at {self.where(self.pc)})")
        handler = self.symbols.describe(vector & ~1)
        if "Default_Handler" in handler or "HardFault" in handler:
            self.events.append(f"exception {exc} taken to the default handler at {self.where(self.pc)}")
        # IPSR = the exception number, so that MRS IPSR in a handler reads it (Unicorn's own
        # exception return is never reached: the UC_HOOK_INTR hook stops on it, see run()).
        uc.reg_write(A.UC_ARM_REG_XPSR, (xpsr & ~0x3FF & ~(1 << 9)) | (1 << 24) | exc)
        self.pc = vector & ~1
        self.exceptions_taken += 1

    def _return(self, exc_return: int) -> None:
        uc = self.uc
        if exc_return not in (0xFFFFFFF9, 0xFFFFFFF1):
            raise EmulatorError(f"EXC_RETURN {exc_return:#010x} (process stack) is not modelled")
        to_thread = exc_return == 0xFFFFFFF9
        self.nvic.deactivate()
        if to_thread != (not self.nvic.active):
            raise EmulatorError(f"EXC_RETURN {exc_return:#010x} does not match the active exceptions "
                                f"{self.nvic.active}")
        sp = uc.reg_read(A.UC_ARM_REG_SP)
        frame = struct.unpack("<8I", bytes(uc.mem_read(sp, 32)))
        for reg, val in zip(_REGS, frame[:6], strict=True):
            uc.reg_write(reg, val)
        xpsr = frame[7]
        uc.reg_write(A.UC_ARM_REG_SP, sp + 32 + (4 if xpsr & (1 << 9) else 0))
        uc.reg_write(A.UC_ARM_REG_XPSR, (xpsr & ~0x3FF & ~(1 << 9)) | (1 << 24) | self.nvic.current)
        self.pc = frame[6] & ~1

    def run(self, budget_cycles: int) -> str:
        """Execute until ``budget_cycles`` have passed ("budget") or the CPU sleeps in WFI
        with nothing pending ("wfi"). Raises EmulatorError on a fault, PowerCut on a cut."""
        if not self.bootable:
            sp, pc = struct.unpack("<II", bytes(self.flash.data[0:8]))
            raise EmulatorError(f"the flash holds no bootable image: reset vector {pc:#010x} "
                                "(erased flash reads 0xffffffff)")
        end = self.cycles + budget_cycles
        uc = self.uc
        while True:
            self._service()
            if self.cycles >= end:
                return "budget"
            stop = end
            ev = self.next_event_cycle()
            if ev is not None and ev < stop:
                stop = ev
            self._stop_at = stop
            self._intno = None
            c0, i0 = self.cycles, self.instructions
            err: UcError | None = None
            self.in_emu = True
            try:
                uc.emu_start(self.pc | 1, 0xFFFFFFFF)
            except UcError as exc:
                err = exc
            finally:
                self.in_emu = False
            self.pc = uc.reg_read(A.UC_ARM_REG_PC)
            for p in self._tickers:
                p.tick(self.cycles - c0)
            if self._power_cut is not None:
                raise self._power_cut
            if self._fault is not None:
                msg, self._fault = self._fault, None
                raise EmulatorError(msg)
            if err is not None or self._intno is not None:
                if self.pc >= 0xFFFFFFF0 and (self._intno is not None or err.errno == UC_ERR_EXCEPTION):
                    self._return(self.pc | 1)
                    continue
                raise EmulatorError(f"CPU exception ({err or 'interrupt'} {self._intno}) "
                                    f"at {self.where(self.pc)}")
            if self._reset_requested:
                continue
            if self.instructions > i0 and self._halfword(self.pc - 2) == WFI:
                if not self.nvic.wake_pending():
                    return "wfi"

    def _halfword(self, addr: int) -> int:
        return int(struct.unpack("<H", bytes(self.uc.mem_read(addr, 2)))[0])

    def in_function(self, name: str) -> bool:
        """The PC is inside function ``name`` (needs the ELF's symbols)."""
        r = self.symbols.range(name)
        return r is not None and r[0] <= self.pc < r[1]

    # ---- stack -------------------------------------------------------------------------
    def stack_high_water(self) -> int:
        """The deepest stack use since power-on, bytes below the initial SP.

        From the end of static RAM (``_end_static`` of the ELF) up, the first word that is not
        the paint; without the ELF, down from the top to the first 16 painted words in a row
        (which a large uninitialised local array could fool)."""
        top = self.initial_sp
        ram = bytes(self.uc.mem_read(SRAM_BASE, SRAM_SIZE))
        words = struct.unpack(f"<{SRAM_SIZE // 4}I", ram)
        floor = self.symbols.addr("_end_static")
        if floor is not None and SRAM_BASE <= floor < top:
            i = (floor - SRAM_BASE) // 4
            while i < len(words) and words[i] == PAINT:
                i += 1
            return int(top - (SRAM_BASE + 4 * i))
        i = (top - SRAM_BASE) // 4 - 1
        run = 0
        while i >= 0:
            run = run + 1 if words[i] == PAINT else 0
            if run >= 16:
                return int(top - (SRAM_BASE + 4 * (i + 16)))
            i -= 1
        return int(top - SRAM_BASE)
