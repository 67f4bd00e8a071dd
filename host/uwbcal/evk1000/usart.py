"""USART1 (RM0008 27.3 "USART functional description", 27.6 "USART registers").

Bytes from the host link are queued by :meth:`Usart.feed`; one at a time enters DR (RXNE
set, and with CR1.RXNEIE the USART1 interrupt pended). Reading DR takes it and lets the next
one in; a byte that arrives while RXNE is still set is not lost by this model (the queue
holds it) unless ``overrun`` is on, which then drops it and sets ORE as the chip would.
A byte written to DR goes to the host at once (``sink``).

Baud-rate timing is a switch (``baud_timing``). Off (the default): a byte takes no emulated
time on the wire in either direction, TXE and TC stay set. On: a frame of 10 bits (8N1) takes
10 x BRR cycles of PCLK2 (RM0008 27.3.4: BRR = f_PCLK / baud), so TXE stays clear for that long
after a write to DR (TC until the byte is out), and received bytes enter DR no faster than one
per frame time, as on the wire (86.8 us at 115200).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from typing import Final

from uwbcal.evk1000.errors import BusError
from uwbcal.evk1000.nvic import Nvic

USART1_BASE: Final = 0x40013800
IRQN_USART1: Final = 37
SR_PE, SR_FE, SR_NE, SR_ORE, SR_IDLE, SR_RXNE, SR_TC, SR_TXE = (1 << b for b in range(8))
CR1_RE, CR1_TE, CR1_RXNEIE, CR1_TCIE, CR1_TXEIE, CR1_UE = 1 << 2, 1 << 3, 1 << 5, 1 << 6, 1 << 7, 1 << 13


class Usart:
    """One USART: SR, DR, BRR, CR1, CR2, CR3, GTPR."""

    size = 0x400

    def __init__(self, nvic: Nvic, sink: Callable[[bytes], None], *, name: str = "USART1",
                 base: int = USART1_BASE, irqn: int = IRQN_USART1, overrun: bool = False,
                 baud_timing: bool = False, cycles: Callable[[], int] = lambda: 0,
                 cpu_per_pclk: Callable[[], float] = lambda: 1.0) -> None:
        self.name, self.base, self.irqn = name, base, irqn
        self.nvic = nvic
        self.sink = sink
        self.overrun = overrun
        self.baud_timing = baud_timing
        self._cycles = cycles                 #: CPU cycles now
        self._cpu_per_pclk = cpu_per_pclk     #: SYSCLK / PCLK2
        self._tx_free_at = 0                  #: CPU cycle at which the transmitter is free
        self._rx_next_at = 0                  #: CPU cycle at which the next byte may enter DR
        self.rx: deque[int] = deque()
        self.bytes_in = 0
        self.bytes_out = 0
        self.reset()

    def reset(self) -> None:
        """Reset values (SR = TXE | TC)."""
        self.sr = SR_TXE | SR_TC
        self.dr_in = 0
        self.brr = self.cr1 = self.cr2 = self.cr3 = self.gtpr = 0

    @property
    def rx_enabled(self) -> bool:
        """UE and RE: the receiver takes bytes."""
        return (self.cr1 & (CR1_UE | CR1_RE)) == (CR1_UE | CR1_RE)

    def feed(self, data: bytes) -> None:
        """Bytes arriving on RX from the host (dropped while the receiver is off)."""
        if not self.rx_enabled:
            return
        for b in data:
            if self.overrun and self.sr & SR_RXNE:
                self.sr |= SR_ORE
                continue
            self.rx.append(b)
        self._load()

    def _frame_cycles(self) -> int:
        """CPU cycles of one 10-bit frame at the programmed baud rate."""
        return round(10 * max(self.brr, 16) * self._cpu_per_pclk())

    def next_event_cycle(self) -> int | None:
        """With baud timing: when the next queued byte can enter DR."""
        if self.baud_timing and self.rx and not self.sr & SR_RXNE:
            return self._rx_next_at
        return None

    def tick(self, cycles: int) -> None:
        """Time passed: a queued byte may enter DR now."""
        if self.rx and not self.sr & SR_RXNE:
            self._load()

    def _load(self) -> None:
        if self.baud_timing and self.rx and not self.sr & SR_RXNE:
            now = self._cycles()
            if now < self._rx_next_at:
                self._irq()
                return
            self._rx_next_at = max(now, self._rx_next_at) + self._frame_cycles()
        if not self.sr & SR_RXNE and self.rx:
            self.dr_in = self.rx.popleft()
            self.bytes_in += 1
            self.sr |= SR_RXNE
        self._irq()

    def _irq(self) -> None:
        want = (self.sr & SR_RXNE and self.cr1 & CR1_RXNEIE) or (self.sr & SR_ORE and self.cr1 & CR1_RXNEIE) \
            or (self.sr & SR_TXE and self.cr1 & CR1_TXEIE) or (self.sr & SR_TC and self.cr1 & CR1_TCIE)
        if want and self.cr1 & CR1_UE:
            self.nvic.set_pending(self.irqn)
        else:
            self.nvic.clear_pending(self.irqn)

    @property
    def busy(self) -> bool:
        """Bytes wait to be read."""
        return bool(self.rx) or bool(self.sr & SR_RXNE)

    def read(self, offset: int, width: int) -> int:
        """Read SR, DR (clears RXNE and ORE), BRR, CR1..3, GTPR."""
        if offset == 0:
            if self.baud_timing:
                now = self._cycles()
                if now >= self._tx_free_at:
                    self.sr |= SR_TXE | SR_TC
                elif now >= self._tx_free_at - self._frame_cycles():
                    self.sr |= SR_TXE          # the shift register has the last byte
            return self.sr
        if offset == 4:
            v = self.dr_in
            self.sr &= ~(SR_RXNE | SR_ORE)
            self._load()
            return v
        regs = {8: self.brr, 12: self.cr1, 16: self.cr2, 20: self.cr3, 24: self.gtpr}
        if offset not in regs:
            raise BusError(f"{self.name} offset {offset:#x} is not a register")
        return regs[offset]

    def write(self, offset: int, width: int, value: int) -> None:
        """Write DR (sends the byte), SR (clears RXNE/TC by writing 0), BRR, CR1..3, GTPR."""
        if offset == 0:
            self.sr &= value | ~(SR_RXNE | SR_TC)
        elif offset == 4:
            if self.cr1 & CR1_UE and self.cr1 & CR1_TE:
                self.sink(bytes([value & 0xFF]))
                self.bytes_out += 1
            if self.baud_timing:
                now = self._cycles()
                self._tx_free_at = max(now, self._tx_free_at) + self._frame_cycles()
                self.sr &= ~(SR_TXE | SR_TC)
            else:
                self.sr |= SR_TXE | SR_TC
        elif offset == 8:
            self.brr = value & 0xFFFF
        elif offset == 12:
            self.cr1 = value & 0x3FFF
        elif offset == 16:
            self.cr2 = value & 0x7F7F
        elif offset == 20:
            self.cr3 = value & 0x7FF
        elif offset == 24:
            self.gtpr = value & 0xFFFF
        else:
            raise BusError(f"{self.name} offset {offset:#x} is not a register")
        self._load()
