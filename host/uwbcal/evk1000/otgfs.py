"""A register-level model of the STM32F105's USB OTG FS core in device mode (RM0008 chapter 28).

It is an emulator peripheral (``name``, ``base``, ``size``, ``read``, ``write``) on the CPU
side and a USB device on the bus side: the host (usbhost.py) sends it tokens with
:meth:`OtgFs.setup`, :meth:`OtgFs.out`, :meth:`OtgFs.in_token` and bus events with
:meth:`OtgFs.bus_reset`, :meth:`OtgFs.suspend`, :meth:`OtgFs.resume`. Each token is one
transaction and answers as the device would on the wire: data, ``ACK``, ``NAK`` or ``STALL``.

What is modelled (RM0008 28.16 registers, 28.17 programming model): core soft reset, FIFO
sizing (GRXFSIZ, DIEPTXF0..3, 320 words), the shared RX FIFO with its status words (GRXSTSP:
SETUP data / SETUP done / OUT data / OUT done, XFRC and STUP raised when the status word is
popped, as the core does), one TX FIFO per IN endpoint (DTXFSTS in words), transfer size
and packet count counters, EPENA/NAK/STALL/SD0PID, the data toggle, device address, soft
disconnect, the interrupt tree (DIEPINT/DOEPINT -> DAINT -> GINTSTS -> the NVIC line 67),
bus reset, enumeration done, suspend and resume.

What is not: isochronous endpoints, host mode, OTG (SRP/HNP), SOF timing (no SOF interrupt),
the PHY's electrical behaviour, and exact cycle timing. A device address set on the SETUP of
SET_ADDRESS is used from the next control transfer on (the real core answers the status
stage at the old address; the model latches the address per control transfer).
Units: offsets in bytes from ``base``, FIFO sizes in 32-bit words, packet sizes in bytes.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Final, Literal, Protocol

from uwbcal.evk1000.errors import BusError

BASE: Final = 0x5000_0000
IRQN: Final = 67  # RM0008 table 62: OTG_FS global interrupt
FIFO_RAM_WORDS: Final = 320  # 1.25 KB on the connectivity line
N_EP: Final = 4  # EP0..EP3 in each direction

# core global registers (28.16.2)
GOTGCTL, GOTGINT, GAHBCFG, GUSBCFG, GRSTCTL = 0x000, 0x004, 0x008, 0x00C, 0x010
GINTSTS, GINTMSK, GRXSTSR, GRXSTSP, GRXFSIZ, DIEPTXF0 = 0x014, 0x018, 0x01C, 0x020, 0x024, 0x028
GCCFG, CID = 0x038, 0x03C
# device registers (28.16.4)
DCFG, DCTL, DSTS, DIEPMSK, DOEPMSK, DAINT, DAINTMSK = 0x800, 0x804, 0x808, 0x810, 0x814, 0x818, 0x81C
PCGCCTL: Final = 0xE00

GINT_RXFLVL: Final = 1 << 4
GINT_USBSUSP: Final = 1 << 11
GINT_USBRST: Final = 1 << 12
GINT_ENUMDNE: Final = 1 << 13
GINT_IEPINT: Final = 1 << 18
GINT_OEPINT: Final = 1 << 19
GINT_WKUPINT: Final = 1 << 31
#: GINTSTS bits cleared by writing 1 (the others are read-only summaries).
GINT_W1C: Final = 0xF030_FC0A | GINT_USBSUSP | GINT_USBRST | GINT_ENUMDNE
EPCTL_USBAEP: Final = 1 << 15
EPCTL_NAKSTS: Final = 1 << 17
EPCTL_STALL: Final = 1 << 21
EPCTL_CNAK: Final = 1 << 26
EPCTL_SNAK: Final = 1 << 27
EPCTL_SD0PID: Final = 1 << 28
EPCTL_EPDIS: Final = 1 << 30
EPCTL_EPENA: Final = 1 << 31
EPINT_XFRC: Final = 1 << 0
EPINT_EPDISD: Final = 1 << 1
EPINT_STUP: Final = 1 << 3
PKTSTS_OUT_DATA, PKTSTS_OUT_DONE, PKTSTS_SETUP_DONE, PKTSTS_SETUP_DATA = 2, 3, 4, 6

Handshake = Literal["ACK", "NAK", "STALL", "TIMEOUT"]


class Nvic(Protocol):
    """The interrupt controller side the model needs (the emulator's NVIC)."""

    def set_pending(self, irqn: int) -> None: ...
    def clear_pending(self, irqn: int) -> None: ...


class OtgFsModelError(BusError):
    """The firmware drove the core in a way the hardware does not allow (e.g. overfilled a
    TX FIFO, popped an empty RX FIFO): a driver bug, reported instead of silently absorbed
    (on the emulated machine, with the PC)."""


@dataclass
class _InEp:
    ctl: int = 0
    intr: int = 0
    tsiz: int = 0
    fifo: bytearray = field(default_factory=bytearray)  # whole words, as written
    toggle: int = 0


@dataclass
class _OutEp:
    ctl: int = 0
    intr: int = 0
    tsiz: int = 0
    toggle: int = 0


@dataclass
class InResult:
    """The answer to one IN token: a handshake and, for ``ACK``, the packet and its PID."""

    handshake: Handshake
    data: bytes = b""
    pid: int = 0


class OtgFs:
    """The OTG FS core (device mode) as an emulator peripheral and a USB device."""

    name = "otg_fs"
    base = BASE
    size = 0x2_0000

    def __init__(self, nvic: Nvic | None = None, vbus: bool = True) -> None:
        self.nvic = nvic
        self.vbus = vbus
        self.irq_line = False
        self.reset_core()
        #: transactions seen, for benchmarks and tests
        self.stats = {"setup": 0, "in": 0, "out": 0, "nak": 0, "stall": 0, "mmio": 0}

    # ---- state ---------------------------------------------------------------------------
    def reset_core(self) -> None:
        """Power-on / CSRST state of every register (RM0008 28.16 reset values)."""
        self.r: dict[int, int] = {GAHBCFG: 0, GUSBCFG: 0x0A00, GINTSTS: 0x0400_0020, GINTMSK: 0,
                                  GRXFSIZ: 0x200, DIEPTXF0: 0x0200_0200, GCCFG: 0, CID: 0x0000_1000,
                                  DCFG: 0x0220_0000, DCTL: 0, DSTS: 0x10, DIEPMSK: 0, DOEPMSK: 0,
                                  DAINTMSK: 0, PCGCCTL: 0, GOTGCTL: 0x0001_0000, GOTGINT: 0}
        self.txf = {n: 0x0200_0400 for n in range(1, N_EP)}
        self.ins = [_InEp() for _ in range(N_EP)]
        self.outs = [_OutEp() for _ in range(N_EP)]
        self.rxq: deque[tuple[int, bytes]] = deque()
        self.rx_words_used = 0
        self.rx_cur: deque[int] = deque()
        self.rx_cur_words = 0
        self.ctrl_addr = 0
        self._update_irq()

    def reset(self) -> None:
        """System reset of the MCU (the machine's peripheral interface): the core's reset
        values, so the D+ pull-up is off until the firmware initialises it again."""
        self.reset_core()

    # ---- helpers -----------------------------------------------------------------------------
    @property
    def address(self) -> int:
        """The device address the driver programmed (DCFG.DAD)."""
        return (self.r[DCFG] >> 4) & 0x7F

    @property
    def connected(self) -> bool:
        """The D+ pull-up is on: transceiver powered, VBUS seen, not soft-disconnected."""
        g = self.r[GCCFG]
        return bool(self.vbus and g & (1 << 16) and g & (1 << 19) and not self.r[DCTL] & 0x2)

    def _rx_words_total(self) -> int:
        return self.r[GRXFSIZ] & 0xFFFF

    def _tx_words_total(self, ep: int) -> int:
        return (self.r[DIEPTXF0] if ep == 0 else self.txf[ep]) >> 16

    def _in_mps(self, ep: int) -> int:
        c = self.ins[ep].ctl
        return (64, 32, 16, 8)[c & 3] if ep == 0 else c & 0x7FF

    def _out_mps(self, ep: int) -> int:
        c = self.outs[ep].ctl
        return (64, 32, 16, 8)[c & 3] if ep == 0 else c & 0x7FF

    def _daint(self) -> int:
        v = 0
        for ep in range(N_EP):
            if self.ins[ep].intr & self.r[DIEPMSK]:
                v |= 1 << ep
            if self.outs[ep].intr & self.r[DOEPMSK]:
                v |= 1 << (16 + ep)
        return v

    def _gintsts(self) -> int:
        v = self.r[GINTSTS] & ~(GINT_RXFLVL | GINT_IEPINT | GINT_OEPINT)
        if self.rxq or self.rx_cur:
            v |= GINT_RXFLVL
        d = self._daint() & self.r[DAINTMSK]
        if d & 0xFFFF:
            v |= GINT_IEPINT
        if d >> 16:
            v |= GINT_OEPINT
        return v

    def _update_irq(self) -> None:
        """The interrupt is a level: pending in the NVIC while the line is high, so one still
        high when the handler returns is taken again (PM0056 4.2.9)."""
        line = bool(self.r[GAHBCFG] & 1 and self._gintsts() & self.r[GINTMSK])
        if self.nvic is not None and (line or self.irq_line):
            (self.nvic.set_pending if line else self.nvic.clear_pending)(IRQN)
        self.irq_line = line

    def _rx_push(self, sts: int, ep: int, data: bytes, dpid: int = 0) -> None:
        word = ep | (len(data) << 4) | (dpid << 15) | (sts << 17)
        self.rxq.append((word, data))
        self.rx_words_used += 1 + (len(data) + 3) // 4

    def _rx_room(self, nbytes: int) -> bool:
        return self.rx_words_used + 1 + (nbytes + 3) // 4 + 1 <= self._rx_words_total()

    # ---- CPU side ----------------------------------------------------------------------------
    def read(self, offset: int, width: int) -> int:
        """A word read by the CPU (the core only allows 32-bit accesses)."""
        self.stats["mmio"] += 1
        self._check_width(offset, width)
        if offset >= 0x1000:
            return self._fifo_pop(offset)
        if offset == GINTSTS:
            return self._gintsts()
        if offset == GRSTCTL:
            return 1 << 31  # AHBIDL; resets and flushes complete at once
        if offset in (GRXSTSR, GRXSTSP):
            return self._rx_status(pop=offset == GRXSTSP)
        if offset == DAINT:
            return self._daint()
        if offset == DSTS:
            return self.r[DSTS]
        if 0x104 <= offset < 0x104 + 4 * (N_EP - 1):
            return self.txf[(offset - 0x104) // 4 + 1]
        if 0x900 <= offset < 0x900 + 0x20 * N_EP:
            return self._in_reg(offset - 0x900, None)
        if 0xB00 <= offset < 0xB00 + 0x20 * N_EP:
            return self._out_reg(offset - 0xB00, None)
        return self.r.get(offset, 0)

    def write(self, offset: int, width: int, value: int) -> None:
        """A word write by the CPU."""
        self.stats["mmio"] += 1
        self._check_width(offset, width)
        value &= 0xFFFF_FFFF
        if offset >= 0x1000:
            self._fifo_push(offset, value)
        elif offset == GINTSTS:
            self.r[GINTSTS] &= ~(value & GINT_W1C)
        elif offset == GRSTCTL:
            if value & 1:
                self.reset_core()
                return
            if value & (1 << 5):  # TXFFLSH, TXFNUM 0x10 = all
                n = (value >> 6) & 0x1F
                for ep in range(N_EP) if n == 0x10 else [n]:
                    if ep < N_EP:
                        self.ins[ep].fifo.clear()
            if value & (1 << 4):  # RXFFLSH
                self.rxq.clear()
                self.rx_cur.clear()
                self.rx_words_used = 0
        elif offset == GOTGINT:
            self.r[GOTGINT] &= ~value
        elif 0x104 <= offset < 0x104 + 4 * (N_EP - 1):
            self.txf[(offset - 0x104) // 4 + 1] = value
        elif 0x900 <= offset < 0x900 + 0x20 * N_EP:
            self._in_reg(offset - 0x900, value)
        elif 0xB00 <= offset < 0xB00 + 0x20 * N_EP:
            self._out_reg(offset - 0xB00, value)
        elif offset in (GRXSTSR, GRXSTSP, CID, DSTS, DAINT):
            pass  # read-only
        else:
            self.r[offset] = value
        self._update_irq()

    def _check_width(self, offset: int, width: int) -> None:
        if width != 4 or offset % 4:
            raise OtgFsModelError(f"OTG FS: {width}-byte access at +0x{offset:X}: 32-bit accesses only")

    def _check_fifo_map(self, ep: int) -> None:
        """When IN endpoint ``ep`` is enabled, its TX FIFO must lie in the 320 words after
        the RX FIFO and not overlap another enabled endpoint's (RM0008 28.11.3)."""
        def span(n: int) -> tuple[int, int]:
            reg = self.r[DIEPTXF0] if n == 0 else self.txf[n]
            return reg & 0xFFFF, (reg & 0xFFFF) + (reg >> 16)

        a, b = span(ep)
        if a < self._rx_words_total() or b > FIFO_RAM_WORDS or a == b:
            raise OtgFsModelError(f"OTG FS: TX FIFO {ep} at words [{a}, {b}) outside "
                                  f"[{self._rx_words_total()}, {FIFO_RAM_WORDS})")
        for n in range(N_EP):
            if n != ep and (self.ins[n].ctl & EPCTL_USBAEP or n == 0):
                c, d = span(n)
                if a < d and c < b:
                    raise OtgFsModelError(f"OTG FS: TX FIFOs {ep} and {n} overlap")

    @staticmethod
    def _ctl_write(e: _InEp | _OutEp, value: int) -> int:
        """A write to DIEPCTLx / DOEPCTLx (28.16.4): EPENA only set here (cleared by the core
        or EPDIS), NAKSTS through SNAK / CNAK, SD0PID resets the toggle. Returns the new value;
        e.intr gets EPDISD when an enabled endpoint is disabled."""
        ctl = (e.ctl & (EPCTL_NAKSTS | EPCTL_EPENA)) | (
            value & ~(EPCTL_CNAK | EPCTL_SNAK | EPCTL_SD0PID | EPCTL_EPDIS | EPCTL_NAKSTS))
        if value & EPCTL_SNAK:
            ctl |= EPCTL_NAKSTS
        if value & EPCTL_CNAK:
            ctl &= ~EPCTL_NAKSTS
        if value & EPCTL_SD0PID:
            e.toggle = 0
        if value & EPCTL_EPDIS and ctl & EPCTL_EPENA:
            ctl &= ~EPCTL_EPENA
            e.intr |= EPINT_EPDISD
        return ctl

    def _in_reg(self, rel: int, value: int | None) -> int:
        ep, reg = rel // 0x20, rel % 0x20
        e = self.ins[ep]
        if value is None:
            if reg == 0x18:  # DTXFSTS: free words in the TX FIFO
                return self._tx_words_total(ep) - len(e.fifo) // 4
            return {0x00: e.ctl, 0x08: e.intr, 0x10: e.tsiz}.get(reg, 0)
        if reg == 0x00:
            ctl = self._ctl_write(e, value)
            if ctl & EPCTL_EPENA and not e.ctl & EPCTL_EPENA:
                self._check_fifo_map(ep)
            e.ctl = ctl
        elif reg == 0x08:
            e.intr &= ~value
        elif reg == 0x10:
            e.tsiz = value
        return 0

    def _out_reg(self, rel: int, value: int | None) -> int:
        ep, reg = rel // 0x20, rel % 0x20
        e = self.outs[ep]
        if value is None:
            return {0x00: e.ctl, 0x08: e.intr, 0x10: e.tsiz}.get(reg, 0)
        if reg == 0x00:
            e.ctl = self._ctl_write(e, value)
        elif reg == 0x08:
            e.intr &= ~value
        elif reg == 0x10:
            e.tsiz = value
        return 0

    def _fifo_push(self, offset: int, value: int) -> None:
        ep = offset // 0x1000 - 1
        if not 0 <= ep < N_EP:
            raise OtgFsModelError(f"OTG FS: write to FIFO window +0x{offset:X} (no such IN endpoint)")
        e = self.ins[ep]
        if len(e.fifo) // 4 >= self._tx_words_total(ep):
            raise OtgFsModelError(f"OTG FS: TX FIFO {ep} overfilled ({self._tx_words_total(ep)} words)")
        e.fifo += value.to_bytes(4, "little")

    def _rx_status(self, pop: bool) -> int:
        if not self.rxq:
            raise OtgFsModelError("OTG FS: GRXSTS read with the RX FIFO empty")
        word, data = self.rxq[0]
        if not pop:
            return word
        self.rxq.popleft()
        self.rx_words_used -= 1
        padded = data + b"\0" * (-len(data) % 4)
        self.rx_cur = deque(int.from_bytes(padded[i:i + 4], "little") for i in range(0, len(padded), 4))
        ep, sts = word & 0xF, (word >> 17) & 0xF
        # The core raises the endpoint interrupt when the "done" status word is popped.
        if sts == PKTSTS_SETUP_DONE:
            self.outs[0].intr |= EPINT_STUP
        elif sts == PKTSTS_OUT_DONE:
            self.outs[ep].intr |= EPINT_XFRC
        self._update_irq()
        return word

    def _fifo_pop(self, offset: int) -> int:
        if not self.rx_cur:
            raise OtgFsModelError(f"OTG FS: RX FIFO read at +0x{offset:X} past the packet's data")
        self.rx_words_used -= 1
        v = self.rx_cur.popleft()
        self._update_irq()
        return v

    # ---- bus side ------------------------------------------------------------------------------
    def _addressed(self, addr: int, ep: int) -> bool:
        if not self.connected or self.r[DSTS] & 1:
            return False
        return addr == self.address or (ep == 0 and addr == self.ctrl_addr)

    def bus_reset(self) -> None:
        """The host drives SE0 for >= 10 ms: USBRST now, then ENUMDNE at full speed."""
        self.r[DSTS] = (self.r[DSTS] & ~0x7) | (3 << 1)  # ENUMSPD = full speed (48 MHz PHY)
        self.r[GINTSTS] |= GINT_USBRST | GINT_ENUMDNE
        self.ctrl_addr = 0
        for i in self.ins:
            i.toggle = 0
        for o in self.outs:
            o.toggle = 0
        self._update_irq()

    def suspend(self) -> None:
        """3 ms of bus idle: USBSUSP and DSTS.SUSPSTS."""
        self.r[DSTS] |= 1
        self.r[GINTSTS] |= GINT_USBSUSP
        self._update_irq()

    def resume(self) -> None:
        """Host resume signalling: WKUPINT, SUSPSTS cleared."""
        self.r[DSTS] &= ~1
        self.r[GINTSTS] |= GINT_WKUPINT
        self._update_irq()

    def setup(self, addr: int, packet: bytes) -> Handshake:
        """A SETUP transaction to EP0: 8 bytes, always DATA0. The core accepts it even while
        EP0 is STALLed (the STALL is cleared) if the RX FIFO has room."""
        if len(packet) != 8:
            raise ValueError("a SETUP packet is 8 bytes")
        if not self._addressed(addr, 0):
            return "TIMEOUT"
        self.stats["setup"] += 1
        if not self._rx_room(8):
            return "TIMEOUT"  # the core drops it; the host retries
        self.ctrl_addr = addr
        o, i = self.outs[0], self.ins[0]
        o.ctl &= ~EPCTL_STALL
        i.ctl &= ~EPCTL_STALL
        o.toggle, i.toggle = 1, 1  # the next data stage packet is DATA1
        stupcnt = (o.tsiz >> 29) & 3
        o.tsiz = (o.tsiz & ~(3 << 29)) | (max(stupcnt - 1, 0) << 29)
        self._rx_push(PKTSTS_SETUP_DATA, 0, packet)
        self._rx_push(PKTSTS_SETUP_DONE, 0, b"")
        o.ctl = (o.ctl | EPCTL_NAKSTS) & ~EPCTL_EPENA
        self._update_irq()
        return "ACK"

    def out(self, addr: int, ep: int, data: bytes, pid: int) -> Handshake:
        """An OUT transaction: the host sends a DATA0/1 packet to OUT endpoint ``ep``."""
        if not self._addressed(addr, ep) or ep >= N_EP:
            return "TIMEOUT"
        self.stats["out"] += 1
        e = self.outs[ep]
        if e.ctl & EPCTL_STALL:
            self.stats["stall"] += 1
            return "STALL"
        mps = self._out_mps(ep)
        if len(data) > mps:
            raise ValueError(f"OUT packet of {len(data)} bytes > wMaxPacketSize {mps}")
        if not e.ctl & EPCTL_EPENA or e.ctl & EPCTL_NAKSTS or not self._rx_room(len(data)):
            self.stats["nak"] += 1
            return "NAK"
        if pid != e.toggle:
            return "ACK"  # a retry of a packet already received: ACKed and dropped (8.6.4)
        e.toggle ^= 1
        self._rx_push(PKTSTS_OUT_DATA, ep, data, pid)
        pktcnt = (e.tsiz >> 19) & (0x3FF if ep else 1)
        xfr = e.tsiz & (0x7F if ep == 0 else 0x7FFFF)
        pktcnt, xfr = max(pktcnt - 1, 0), max(xfr - len(data), 0)
        e.tsiz = (e.tsiz & ~((0x3FF << 19) | 0x7FFFF)) | (pktcnt << 19) | xfr
        if pktcnt == 0 or len(data) < mps:
            self._rx_push(PKTSTS_OUT_DONE, ep, b"")
            e.ctl = (e.ctl | EPCTL_NAKSTS) & ~EPCTL_EPENA
        self._update_irq()
        return "ACK"

    def in_token(self, addr: int, ep: int) -> InResult:
        """An IN transaction: the device answers with a packet from the endpoint's TX FIFO."""
        if not self._addressed(addr, ep) or ep >= N_EP:
            return InResult("TIMEOUT")
        self.stats["in"] += 1
        e = self.ins[ep]
        if e.ctl & EPCTL_STALL:
            self.stats["stall"] += 1
            return InResult("STALL")
        if not e.ctl & EPCTL_EPENA or e.ctl & EPCTL_NAKSTS:
            self.stats["nak"] += 1
            return InResult("NAK")
        mps = self._in_mps(ep)
        pktcnt = (e.tsiz >> 19) & (3 if ep == 0 else 0x3FF)
        xfr = e.tsiz & (0x7F if ep == 0 else 0x7FFFF)
        n = min(mps, xfr)
        if len(e.fifo) < n or pktcnt == 0:
            self.stats["nak"] += 1
            return InResult("NAK")  # the FIFO is not filled yet (the core NAKs an underrun)
        words = (n + 3) // 4
        data = bytes(e.fifo[:n])
        del e.fifo[: 4 * words]
        pid = e.toggle
        e.toggle ^= 1
        pktcnt -= 1
        xfr -= n
        e.tsiz = (e.tsiz & ~((0x3FF << 19) | 0x7FFFF)) | (pktcnt << 19) | xfr
        if pktcnt == 0:
            e.ctl &= ~EPCTL_EPENA
            e.intr |= EPINT_XFRC
        self._update_irq()
        return InResult("ACK", data, pid)
