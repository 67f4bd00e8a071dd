"""NVIC and the system control block of the Cortex-M3 (PM0056 4.2 "NVIC", 4.3 "SCB").

Exceptions are numbered as in the vector table: 1 reset, 2 NMI, 3 HardFault, ..., 11 SVCall,
14 PendSV, 15 SysTick, 16 + irqn for the STM32F105's 68 peripheral interrupts (RM0008 table
62). Priorities: the STM32F1 implements the top 4 bits of each 8-bit priority; a lower value
is more urgent; with AIRCR.PRIGROUP 0 (reset value) all 4 bits are preemption priority.
The machine takes the most urgent pending exception when it is more urgent than the current
execution priority (the most urgent active exception, or 0 with PRIMASK set).

Registers modelled: ISER, ICER, ISPR, ICPR, IABR, IPR (NVIC at 0xE000E100); CPUID, ICSR,
VTOR, AIRCR, SCR, CCR, SHPR1..3, SHCSR (SCB at 0xE000ED00). Anything else in the system
control space raises BusError.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Final

from uwbcal.evk1000.errors import BusError

SCS_BASE: Final = 0xE000E000
N_IRQ: Final = 68                 #: connectivity line (RM0008 table 62)
EXC_SYSTICK: Final = 15
EXC_PENDSV: Final = 14
EXC_HARDFAULT: Final = 3
CPUID_M3_R1P1: Final = 0x411FC231  #: PM0056 4.3.1, Cortex-M3 r1p1 as in STM32F105
VECTKEY: Final = 0x05FA


def irq_exception(irqn: int) -> int:
    """The exception number of peripheral interrupt ``irqn``."""
    return 16 + irqn


class Nvic:
    """Pending/enabled/active state and priorities of every exception, plus the SCB."""

    name = "NVIC/SCB"
    base = SCS_BASE + 0x100
    size = 0xC90           # 0xE000E100 .. 0xE000ED8F: NVIC, then SCB from 0xE000ED00

    def __init__(self, on_reset_request: Callable[[], None]) -> None:
        self.on_reset_request = on_reset_request
        self.reset()

    def reset(self) -> None:
        """Power-on / system reset values."""
        self.enabled = [False] * N_IRQ
        self.pending: set[int] = set()      #: exception numbers
        self.active: list[int] = []         #: exception numbers, outermost first
        self.prio = [0] * (16 + N_IRQ)      #: 8-bit priority per exception number
        self.prio[1], self.prio[2], self.prio[3] = -3, -2, -1
        self.vtor = 0
        self.scr = 0
        self.ccr = 0x200                    #: STKALIGN (8-byte stack alignment on entry)
        self.aircr_prigroup = 0
        self.shcsr = 0
        self.changed = True                 #: the machine re-checks for an exception to take

    # ---- interface of the other models ---------------------------------------------
    def set_pending(self, irqn: int) -> None:
        """A peripheral interrupt request (RM0008 table 62 number)."""
        self.pend_exception(irq_exception(irqn))

    def clear_pending(self, irqn: int) -> None:
        """A level interrupt went away before it was taken."""
        self.pending.discard(irq_exception(irqn))

    def pend_exception(self, exc: int) -> None:
        """Set an exception pending (SysTick, PendSV, or 16 + irqn)."""
        if exc not in self.pending:
            self.pending.add(exc)
            self.changed = True

    def _enabled(self, exc: int) -> bool:
        return exc < 16 or self.enabled[exc - 16]

    def execution_priority(self, primask: bool) -> int:
        """The current execution priority (PM0056 2.3.6): lower is more urgent; 256 = thread."""
        p = 256
        for exc in self.active:
            p = min(p, self.prio[exc])
        if primask:
            p = min(p, 0)
        return p

    def next_exception(self, primask: bool) -> int | None:
        """The pending exception to take now, if any (most urgent, then lowest number)."""
        best: int | None = None
        if not self.pending:
            return None
        limit = self.execution_priority(primask)
        for exc in self.pending:
            if not self._enabled(exc) or self.prio[exc] >= limit:
                continue
            if best is None or (self.prio[exc], exc) < (self.prio[best], best):
                best = exc
        return best

    def wake_pending(self) -> bool:
        """Any enabled exception pending, whatever the priority (wakes WFI, PM0056 2.5.2)."""
        return any(self._enabled(e) for e in self.pending)

    def activate(self, exc: int) -> None:
        """Exception entry: pending -> active."""
        self.pending.discard(exc)
        self.active.append(exc)

    def deactivate(self) -> int:
        """Exception return: the innermost active exception is done; returns its number."""
        if not self.active:
            raise BusError("exception return with no active exception")
        self.changed = True
        return self.active.pop()

    @property
    def current(self) -> int:
        """IPSR: the active exception number, 0 in thread mode."""
        return self.active[-1] if self.active else 0

    # ---- registers -------------------------------------------------------------------
    def read(self, offset: int, width: int) -> int:
        """Read a register (offset from 0xE000E100)."""
        addr = self.base + offset
        if 0xE000E400 <= addr < 0xE000E400 + N_IRQ:               # IPR, byte access allowed
            i = addr - 0xE000E400
            return int.from_bytes(bytes(p & 0xFF for p in self.prio[16 + i:16 + i + width]), "little")
        if width != 4:
            raise BusError(f"{width}-byte access to NVIC/SCB register {addr:#010x}")
        for base, kind in ((0xE000E100, "en"), (0xE000E180, "en"), (0xE000E200, "pend"),
                           (0xE000E280, "pend"), (0xE000E300, "act")):
            if base <= addr < base + 12:
                return self._bits(kind, (addr - base) // 4)
        if addr == 0xE000ED00:
            return CPUID_M3_R1P1
        if addr == 0xE000ED04:
            return self._icsr()
        if addr == 0xE000ED08:
            return self.vtor
        if addr == 0xE000ED0C:
            return (0xFA05 << 16) | (self.aircr_prigroup << 8)
        if addr == 0xE000ED10:
            return self.scr
        if addr == 0xE000ED14:
            return self.ccr
        if 0xE000ED18 <= addr < 0xE000ED24:                    # SHPR1..3
            n = 4 + (addr - 0xE000ED18)
            return int.from_bytes(bytes(p & 0xFF for p in self.prio[n:n + 4]), "little")
        if addr == 0xE000ED24:
            return self.shcsr
        raise BusError(f"NVIC/SCB register {addr:#010x} is not modelled")

    def _bits(self, kind: str, word: int) -> int:
        v = 0
        for bit in range(32):
            irqn = word * 32 + bit
            if irqn >= N_IRQ:
                break
            exc = irq_exception(irqn)
            on = (self.enabled[irqn] if kind == "en" else
                  exc in self.pending if kind == "pend" else exc in self.active)
            v |= int(on) << bit
        return v

    def _icsr(self) -> int:
        v = self.current
        if self.pending:
            v |= 1 << 22                                       # ISRPENDING
            v |= min(self.pending) << 12                       # VECTPENDING (approx.)
        if EXC_SYSTICK in self.pending:
            v |= 1 << 26
        if EXC_PENDSV in self.pending:
            v |= 1 << 28
        if len(self.active) <= 1:
            v |= 1 << 11                                       # RETTOBASE
        return v

    def write(self, offset: int, width: int, value: int) -> None:
        """Write a register (offset from 0xE000E100)."""
        addr = self.base + offset
        if 0xE000E400 <= addr < 0xE000E400 + N_IRQ:
            i = addr - 0xE000E400
            for k in range(width):
                if i + k < N_IRQ:
                    self.prio[16 + i + k] = (value >> (8 * k)) & 0xF0     # 4 bits implemented
            self.changed = True
            return
        if width != 4:
            raise BusError(f"{width}-byte write to NVIC/SCB register {addr:#010x}")
        self.changed = True
        for base, kind in ((0xE000E100, "set_en"), (0xE000E180, "clr_en"), (0xE000E200, "set_pend"),
                           (0xE000E280, "clr_pend")):
            if base <= addr < base + 12:
                word = (addr - base) // 4
                for bit in range(32):
                    irqn = word * 32 + bit
                    if not (value >> bit) & 1 or irqn >= N_IRQ:
                        continue
                    if kind == "set_en":
                        self.enabled[irqn] = True
                    elif kind == "clr_en":
                        self.enabled[irqn] = False
                    elif kind == "set_pend":
                        self.pending.add(irq_exception(irqn))
                    else:
                        self.pending.discard(irq_exception(irqn))
                return
        if addr == 0xE000ED04:                                 # ICSR
            if value & (1 << 26):
                self.pending.add(EXC_SYSTICK)
            if value & (1 << 25):
                self.pending.discard(EXC_SYSTICK)
            if value & (1 << 28):
                self.pending.add(EXC_PENDSV)
            if value & (1 << 27):
                self.pending.discard(EXC_PENDSV)
            return
        if addr == 0xE000ED08:
            self.vtor = value & 0x3FFFFF80
            return
        if addr == 0xE000ED0C:                                 # AIRCR
            if value >> 16 != VECTKEY:
                return                                         # ignored without the key
            self.aircr_prigroup = (value >> 8) & 7
            if value & (1 << 2):                               # SYSRESETREQ
                self.on_reset_request()
            return
        if addr == 0xE000ED10:
            self.scr = value & 0x16
            return
        if addr == 0xE000ED14:
            self.ccr = value & 0x31B
            return
        if 0xE000ED18 <= addr < 0xE000ED24:
            n = 4 + (addr - 0xE000ED18)
            for k in range(4):
                self.prio[n + k] = (value >> (8 * k)) & 0xF0
            return
        if addr == 0xE000ED24:
            self.shcsr = value
            return
        raise BusError(f"NVIC/SCB register {addr:#010x} is not modelled")
