"""SPI1 (RM0008 25.3 "SPI functional description", 25.5 "SPI and I2S registers") with the
DW1000 on it: chip select on PA4 (software NSS), the chip behind a :class:`~uwbcal.evk1000.
radio.Radio` (the DW1000 register model of uwbcal.medium.registers, the medium's own).

A byte written to DR while SPE and MSTR are set is exchanged at once: RXNE is set with the
byte the chip clocks out (OVR if RXNE was still set), TXE stays set, BSY stays clear. No SPI
clock timing is modelled (at 18 MHz a byte takes 0.44 us on the board).

Transactions are framed by the chip select (DW1000 user manual 2.3.1.2): the first 1 to 3
bytes are the header (bit 7 write, bit 6 sub-index follows, then bit 7 of byte 1 extended
index follows). A write is handed to the radio when CS rises; a read fetches data from the
radio in chunks as the bytes are clocked (a read has no length on the wire).
"""

from __future__ import annotations

from typing import Final

from uwbcal.evk1000.errors import BusError
from uwbcal.evk1000.radio import Radio
from uwbcal.medium.client import TunnelClient
from uwbcal.medium.registers import Dw1000Model

SPI1_BASE: Final = 0x40013000
CR1_MSTR, CR1_SPE = 1 << 2, 1 << 6
SR_RXNE, SR_TXE, SR_OVR, SR_BSY = 1 << 0, 1 << 1, 1 << 6, 1 << 7
READ_CHUNK: Final = 64        #: bytes asked of the radio per read round trip


class Spi:
    """SPI1 as master with the DW1000 as its one slave."""

    name = "SPI1"
    base = SPI1_BASE
    size = 0x400

    def __init__(self, radio: Radio) -> None:
        self.radio = radio
        self.transactions = 0
        self.bytes = 0
        self.reset()

    def reset(self) -> None:
        """Reset values (SR = TXE)."""
        self.cr1 = self.cr2 = 0
        self.sr = SR_TXE
        self.rx = 0
        self.cs = False
        self._hdr = bytearray()
        self._data = bytearray()
        self._rbuf = b""
        self._rpos = 0
        self._roff = 0

    # ---- chip select (GPIO listener) --------------------------------------------------
    def on_pin(self, port: int, pin: int, level: int) -> None:
        """PA4 is the DW1000 chip select (active low)."""
        if port != 0 or pin != 4:
            return
        if level == 0 and not self.cs:
            self.cs = True
            self._hdr.clear()
            self._data.clear()
            self._rbuf, self._rpos = b"", 0
        elif level == 1 and self.cs:
            self.cs = False
            if self._hdr and self._header_done() and self._hdr[0] & 0x80:
                self.radio.spi_write(bytes(self._hdr), bytes(self._data))
            if self._hdr:
                self.transactions += 1

    def _header_done(self) -> bool:
        h = self._hdr
        if not h:
            return False
        if not h[0] & 0x40:
            return True
        if len(h) < 2:
            return False
        return not h[1] & 0x80 or len(h) >= 3

    def _exchange(self, mosi: int) -> int:
        self.bytes += 1
        if not self.cs:
            return 0xFF                                     # nobody drives MISO
        if not self._header_done():
            self._hdr.append(mosi)
            if self._header_done():
                _, _rid, self._roff = Dw1000Model.parse_header(bytes(self._hdr))
            return 0
        if self._hdr[0] & 0x80:
            self._data.append(mosi)
            return 0
        if self._rpos >= len(self._rbuf):
            rid = self._hdr[0] & 0x3F
            hdr = TunnelClient.header(False, rid, self._roff)
            self._rbuf, self._rpos = self.radio.spi_read(hdr, READ_CHUNK), 0
            self._roff += READ_CHUNK
        b = self._rbuf[self._rpos]
        self._rpos += 1
        return b

    # ---- registers ---------------------------------------------------------------------
    def read(self, offset: int, width: int) -> int:
        """Read CR1, CR2, SR, DR (clears RXNE), CRC registers (0)."""
        if offset == 0:
            return self.cr1
        if offset == 4:
            return self.cr2
        if offset == 8:
            return self.sr
        if offset == 12:
            v = self.rx
            self.sr &= ~SR_RXNE
            return v
        if offset in (0x10, 0x14, 0x18, 0x1C, 0x20):
            return 0
        raise BusError(f"SPI1 offset {offset:#x} is not a register")

    def write(self, offset: int, width: int, value: int) -> None:
        """Write CR1, CR2, SR (clears CRCERR), DR (exchanges a byte)."""
        if offset == 0:
            self.cr1 = value & 0xFFFF
        elif offset == 4:
            self.cr2 = value & 0xF7
        elif offset == 8:
            self.sr &= ~(1 << 4) | value
        elif offset == 12:
            if self.cr1 & (CR1_SPE | CR1_MSTR) != (CR1_SPE | CR1_MSTR):
                return                                      # disabled: nothing shifts
            miso = self._exchange(value & 0xFF)
            if self.sr & SR_RXNE:
                self.sr |= SR_OVR
            self.rx = miso
            self.sr |= SR_RXNE | SR_TXE
        elif offset in (0x10, 0x1C, 0x20):
            return
        else:
            raise BusError(f"SPI1 offset {offset:#x} is not writable")

