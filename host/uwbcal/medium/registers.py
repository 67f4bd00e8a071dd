"""A DW1000 register model: what one station's driver sees over SPI.

Semantics follow the DW1000 user manual for the subset the driver uses
(firmware/dw1000/REGISTERS.md): SPI transaction headers (1 to 3 bytes), register files as
byte arrays, SYS_STATUS write-one-to-clear, the IRQ line = SYS_STATUS & SYS_MASK, SYS_CTRL
commands (TXSTRT, TXDLYS, TRXOFF, WAIT4RESP, RXENAB, RXDLYE), delayed TX on the 512-unit grid
with TX_ANTD added to TX_STAMP and HPDWARN when late, 40-bit wrap, SYS_TIME, RX_TIME, RX_FINFO,
RX_FQUAL, RX_TTCKI/RX_TTCKO, DRX_CAR_INT, RXPACC_NOSAT, LDE_RXANTD subtracted from RX_STAMP,
TX_POWER octets (coarse and fine gain), OTP reads and the temperature SAR.

The model holds no physics: every number of a reception (timestamps, quality registers,
carrier integrator) is handed in by the medium, which takes it from uwbcal.physics. Time is
the station's own DW1000 clock in device units (15.65 ps), unwrapped float, supplied by the
:class:`ChipHost`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Final, Protocol

from uwbcal import dw1000_facts as F
from uwbcal.dw1000 import (
    DELAYED_TX_GRID,
    DEV_ID,
    RX_TTCKI_BY_PRF,
    SAR_DEGC_PER_LSB,
    SAR_REF_DEGC,
    TIME_UNIT_S,
    TIMESTAMP_MOD,
)
from uwbcal.medium.airtime import PREAMBLE_LEN, FrameFormat
from uwbcal.medium.port import Reception
from uwbcal.medium.wire import SNAP_BLOCK

# Register file IDs, bits and sub-addresses: chip facts of protocol/dw1000.toml (generated
# uwbcal.dw1000_facts, the same values the firmware driver uses), under the names this model
# has always used.
DEV_ID_REG: Final = F.REG_DEV_ID
EUI: Final = F.REG_EUI
PANADR: Final = F.REG_PANADR
SYS_CFG: Final = F.REG_SYS_CFG
SYS_TIME: Final = F.REG_SYS_TIME
TX_FCTRL: Final = F.REG_TX_FCTRL
TX_BUFFER: Final = F.REG_TX_BUFFER
DX_TIME: Final = F.REG_DX_TIME
SYS_CTRL: Final = F.REG_SYS_CTRL
SYS_MASK: Final = F.REG_SYS_MASK
SYS_STATUS: Final = F.REG_SYS_STATUS
RX_FINFO: Final = F.REG_RX_FINFO
RX_BUFFER: Final = F.REG_RX_BUFFER
RX_FQUAL: Final = F.REG_RX_FQUAL
RX_TTCKI: Final = F.REG_RX_TTCKI
RX_TTCKO: Final = F.REG_RX_TTCKO
RX_TIME: Final = F.REG_RX_TIME
TX_TIME: Final = F.REG_TX_TIME
TX_ANTD: Final = F.REG_TX_ANTD
SYS_STATE: Final = F.REG_SYS_STATE
TX_POWER: Final = F.REG_TX_POWER
CHAN_CTRL: Final = F.REG_CHAN_CTRL
DRX_CONF: Final = F.REG_DRX_CONF
RF_CONF: Final = F.REG_RF_CONF
TX_CAL: Final = F.REG_TX_CAL
OTP_IF: Final = F.REG_OTP_IF
LDE_IF: Final = F.REG_LDE_IF
PMSC: Final = F.REG_PMSC

#: Size in bytes of each register file (user manual table 4); unknown IDs get 64 bytes.
SIZES: Final[dict[int, int]] = {
    0x00: 4, 0x01: 8, 0x03: 4, 0x04: 4, 0x06: 5, 0x08: 5, 0x09: 1024, 0x0A: 5, 0x0C: 2, 0x0D: 4,
    0x0E: 4, 0x0F: 5, 0x10: 4, 0x11: 1024, 0x12: 8, 0x13: 4, 0x14: 5, 0x15: 14, 0x17: 10,
    0x18: 2, 0x19: 5, 0x1A: 4, 0x1D: 4, 0x1E: 4, 0x1F: 4, 0x21: 41, 0x23: 33, 0x24: 12,
    0x25: 4064, 0x26: 44, 0x27: 46, 0x28: 58, 0x2A: 52, 0x2B: 21, 0x2C: 12, 0x2D: 18,
    0x2E: 0x2806 + 2, 0x2F: 41, 0x36: 48,
}

# SYS_CTRL bits.
SFCST: Final = F.SYS_CTRL_SFCST
TXSTRT: Final = F.SYS_CTRL_TXSTRT
TXDLYS: Final = F.SYS_CTRL_TXDLYS
TRXOFF: Final = F.SYS_CTRL_TRXOFF
WAIT4RESP: Final = F.SYS_CTRL_WAIT4RESP
RXENAB: Final = F.SYS_CTRL_RXENAB
RXDLYE: Final = F.SYS_CTRL_RXDLYE

# SYS_STATUS bits.
IRQS: Final = F.ST_IRQS
CPLOCK: Final = F.ST_CPLOCK
TXFRB: Final = F.ST_TXFRB
TXPRS: Final = F.ST_TXPRS
TXPHS: Final = F.ST_TXPHS
TXFRS: Final = F.ST_TXFRS
RXPRD: Final = F.ST_RXPRD
RXSFDD: Final = F.ST_RXSFDD
LDEDONE: Final = F.ST_LDEDONE
RXPHD: Final = F.ST_RXPHD
RXDFR: Final = F.ST_RXDFR
RXFCG: Final = F.ST_RXFCG
RXFCE: Final = F.ST_RXFCE
SLP2INIT: Final = F.ST_SLP2INIT
HPDWARN: Final = F.ST_HPDWARN
TX_DONE_BITS: Final = TXFRB | TXPRS | TXPHS | TXFRS
RX_GOOD_BITS: Final = RXPRD | RXSFDD | LDEDONE | RXPHD | RXDFR | RXFCG

# Offsets inside register files.
DRX_CAR_INT_OFF: Final = F.DRX_CAR_INT
RXPACC_NOSAT_OFF: Final = F.DRX_RXPACC_NOSAT
LDE_RXANTD_OFF: Final = F.LDE_RXANTD
OTP_ADDR_OFF: Final = F.OTP_ADDR
OTP_CTRL_OFF: Final = F.OTP_CTRL
OTP_RDAT_OFF: Final = F.OTP_RDAT
TC_SARC_OFF: Final = F.TC_SARC
TC_SARL_OFF: Final = F.TC_SARL
PMSC_CTRL0_SOFTRESET_OFF: Final = F.PMSC_SOFTRESET

#: Power-on values of the registers the driver reads before writing (user manual).
DEFAULTS: Final[dict[int, int]] = {
    DEV_ID_REG: DEV_ID,
    SYS_CFG: 0x00001200,
    TX_FCTRL: 0x0015400C,
    TX_POWER: 0x0E080222,
    CHAN_CTRL: 0x00000055,
    RX_TTCKI: RX_TTCKI_BY_PRF[64],
}
#: OTP address of the factory temperature (byte 1, at 23 degC) and battery (byte 0) readings.
OTP_VTEMP_ADDR: Final = F.OTP_VTEMP_ADDR

MASK40: Final = TIMESTAMP_MOD - 1


class ChipHost(Protocol):
    """What a register model needs from the medium, for one station."""

    def sys_time_units(self) -> float:
        """The station's DW1000 clock now, device units, unwrapped."""

    def start_tx(self, dx_units: int | None, tx_antd: int, fmt: FrameFormat) -> int | None:
        """Schedule a frame: delayed at unwrapped DX_TIME ``dx_units`` on this clock, or
        immediate (None). Returns TX_STAMP, unwrapped device units, or None when the host
        calls :meth:`Dw1000Model.tx_stamped` later (before TX_TIME can be read)."""

    def radio_off(self) -> None:
        """TRXOFF: cancel a pending TX and any reception in progress."""

    def rx_enable(self, at_units: float | None) -> None:
        """Turn the receiver on now (None) or at a time on this clock (delayed RX)."""

    def temperature_c(self) -> float:
        """The chip temperature now, degC."""


@dataclass(slots=True)
class RxFrame:
    """Everything the registers show after a good reception: the physics' register values
    (:class:`~uwbcal.medium.port.Reception`) and the frame itself."""

    rec: Reception             #: RX_STAMP and the quality registers, from physics
    payload: bytes             #: frame bytes without the 2 CRC bytes
    fmt: FrameFormat           #: the transmitter's TX_FCTRL


@dataclass
class Dw1000Model:
    """Register files of one DW1000 and their side effects."""

    host: ChipHost
    otp: dict[int, int] = field(default_factory=dict)
    regs: dict[int, bytearray] = field(default_factory=dict)
    tx_count: int = 0
    rx_count: int = 0
    late_count: int = 0
    _wait4resp: bool = False
    #: Preparation the chip needs before the preamble of a delayed TX, device units (a
    #: model parameter: REGISTERS.md 5.3).
    min_lead_units: float = 0.0

    def __post_init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        """RSTn: every register to its power-on value."""
        self.regs = {}
        for rid, size in SIZES.items():
            self.regs[rid] = bytearray(size)
        for rid, val in DEFAULTS.items():
            self.set(rid, 0, val, SIZES[rid] if SIZES[rid] <= 8 else 4)

    # ---- raw access --------------------------------------------------------------------
    def _file(self, rid: int) -> bytearray:
        f = self.regs.get(rid)
        if f is None:
            f = self.regs[rid] = bytearray(64)
        return f

    def get(self, rid: int, off: int, n: int) -> int:
        """Little-endian value of n bytes at (rid, off)."""
        return int.from_bytes(self._file(rid)[off:off + n], "little")

    def set(self, rid: int, off: int, value: int, n: int) -> None:
        """Store a little-endian value of n bytes at (rid, off) without side effects."""
        self._file(rid)[off:off + n] = (value & ((1 << (8 * n)) - 1)).to_bytes(n, "little")

    @property
    def status(self) -> int:
        """SYS_STATUS, 40 bits."""
        return int.from_bytes(self.regs[SYS_STATUS], "little")

    def set_status(self, bits: int) -> None:
        """Raise SYS_STATUS bits (the chip's events)."""
        st = self.status | bits
        self.regs[SYS_STATUS][:] = st.to_bytes(5, "little")
        self._update_irqs()

    def _update_irqs(self) -> None:
        f = self.regs[SYS_STATUS]
        st = int.from_bytes(f[0:4], "little") & ~IRQS
        if st & int.from_bytes(self.regs[SYS_MASK], "little"):
            st |= IRQS
        f[0:4] = st.to_bytes(4, "little")

    @property
    def irq(self) -> bool:
        """The IRQ line: any SYS_STATUS event bit enabled in SYS_MASK."""
        return bool(self.regs[SYS_STATUS][0] & IRQS)

    # ---- SPI ---------------------------------------------------------------------------
    @staticmethod
    def parse_header(hdr: bytes) -> tuple[bool, int, int]:
        """(is_write, register id, offset) of a 1 to 3 byte transaction header."""
        b0 = hdr[0]
        rid = b0 & 0x3F
        off = 0
        if b0 & 0x40 and len(hdr) > 1:
            off = hdr[1] & 0x7F
            if hdr[1] & 0x80 and len(hdr) > 2:
                off |= hdr[2] << 7
        return bool(b0 & 0x80), rid, off

    def spi_read(self, hdr: bytes, n: int) -> bytes:
        """Bytes clocked out by the chip for a read transaction."""
        _, rid, off = self.parse_header(hdr)
        if rid == SYS_TIME:
            t = int(self.host.sys_time_units()) & MASK40 & ~(DELAYED_TX_GRID - 1)
            self.set(SYS_TIME, 0, t, 5)
        elif rid == TX_CAL and off <= TC_SARL_OFF + 1 < off + n:
            pass  # TC_SARL was latched when the SAR was started
        f = self._file(rid)
        data = bytes(f[off:off + n])
        if len(data) < n:
            data += bytes(n - len(data))
        return data

    def snapshot(self, with_time: bool = True) -> bytes:
        """The tun_wait snapshot (tunnel.toml, mode bit2): blocks (rid u8, off u16, n u8, bytes)
        of what :meth:`spi_read` returns now for the reads a driver makes on waking.

        SYS_TIME if ``with_time``; SYS_STATUS and TX_TIME always; the received frame's
        registers (REGISTERS.md 5.4) and RX_BUFFER when RXFCG is set. Built with
        :meth:`spi_read` itself, so every byte is what the read would return.
        """
        out = bytearray()
        if with_time:  # the one computed register: through spi_read
            out += _SNAP_TIME_HDR
            out += self.spi_read(_SYS_TIME_READ, 5)
        # The others are plain bytes of their files, each block inside its file: what
        # spi_read returns, without its dispatch.
        regs = self.regs
        for head, rid, off, n in _SNAP_ALWAYS:
            out += head
            out += regs[rid][off:off + n]
        if regs[SYS_STATUS][1] & (RXFCG >> 8):
            for head, rid, off, n in _SNAP_RX:
                out += head
                out += regs[rid][off:off + n]
            flen = int.from_bytes(regs[RX_FINFO][0:2], "little") & 0x3FF
            if flen > 2:
                n = min(flen - 2, 255)
                out += SNAP_BLOCK.pack(RX_BUFFER, 0, n)
                out += regs[RX_BUFFER][0:n]
        return bytes(out)

    def spi_write(self, hdr: bytes, data: bytes) -> None:
        """Apply a write transaction and its side effects."""
        _, rid, off = self.parse_header(hdr)
        if rid == SYS_STATUS:
            f = self.regs[SYS_STATUS]
            for i, b in enumerate(data):
                if off + i < 5:
                    f[off + i] &= ~b & 0xFF
            self._update_irqs()
            return
        if rid in (DEV_ID_REG, SYS_TIME, RX_FINFO, RX_FQUAL, RX_TIME, TX_TIME, RX_TTCKO, RX_BUFFER):
            return  # read-only files
        f = self._file(rid)
        end = off + len(data)
        if end > len(f):
            f.extend(bytes(end - len(f)))
        f[off:end] = data
        if rid == SYS_CTRL:
            cmd = self.get(SYS_CTRL, 0, 4)
            self.set(SYS_CTRL, 0, cmd & ~(SFCST | TXSTRT | TXDLYS | TRXOFF | RXENAB | RXDLYE), 4)
            self._command(cmd)
        elif rid == SYS_MASK:
            self._update_irqs()
        elif rid == OTP_IF and off <= OTP_CTRL_OFF < end:
            ctrl = self.get(OTP_IF, OTP_CTRL_OFF, 2)
            if ctrl & 0x02:  # OTPREAD (with OTPRDEN): latch OTP_RDAT from OTP_ADDR
                addr = self.get(OTP_IF, OTP_ADDR_OFF, 2) & 0x7FF
                self.set(OTP_IF, OTP_RDAT_OFF, self.otp.get(addr, 0), 4)
                self.set(OTP_IF, OTP_CTRL_OFF, ctrl & ~0x02, 2)
        elif rid == TX_CAL and off <= TC_SARC_OFF < end:
            if self.get(TX_CAL, TC_SARC_OFF, 1) & 1:
                self._latch_sar()
        elif rid == PMSC and off <= PMSC_CTRL0_SOFTRESET_OFF < end:
            if (self.get(PMSC, PMSC_CTRL0_SOFTRESET_OFF, 1) & 0xF0) != 0xF0:
                self.host.radio_off()  # RX soft reset: the receiver is reset, nothing else

    def _latch_sar(self) -> None:
        """Start of a SAR conversion: latch temperature (and battery) into TC_SARL."""
        t23 = (self.otp.get(OTP_VTEMP_ADDR, 0) >> 8) & 0xFF
        raw = int(round((self.host.temperature_c() - SAR_REF_DEGC) / SAR_DEGC_PER_LSB)) + t23
        vbat = self.otp.get(OTP_VTEMP_ADDR, 0) & 0xFF
        self.set(TX_CAL, TC_SARL_OFF, vbat, 1)
        self.set(TX_CAL, TC_SARL_OFF + 1, max(0, min(255, raw)), 1)

    def _command(self, cmd: int) -> None:
        if cmd & TRXOFF:
            self.host.radio_off()
        if cmd & TXSTRT:
            fmt = FrameFormat.from_tx_fctrl(self.get(TX_FCTRL, 0, 4))
            antd = self.get(TX_ANTD, 0, 2)
            dx_unwrapped: int | None = None
            if cmd & TXDLYS:
                now = int(self.host.sys_time_units())
                dx = self.get(DX_TIME, 0, 5)
                lead = ((dx & ~(DELAYED_TX_GRID - 1)) - now) % TIMESTAMP_MOD
                # The preamble and SFD go out before the RMARKER: a start already past (or
                # more than half the 40-bit period away, the manual's HPDWARN) is late.
                shr_units = fmt.shr_s() / TIME_UNIT_S
                if lead >= TIMESTAMP_MOD // 2 or lead < shr_units + self.min_lead_units:
                    # Late: HPDWARN at once; nothing goes out until TRXOFF cancels the TX
                    # (REGISTERS.md 5.3 step 6).
                    self.set_status(HPDWARN)
                    self.late_count += 1
                    return
                dx_unwrapped = now + ((dx - now) % TIMESTAMP_MOD)
            stamp = self.host.start_tx(dx_unwrapped, antd, fmt)
            if stamp is not None:
                self.tx_stamped(stamp, antd)
            self.tx_count += 1
            self._wait4resp = bool(cmd & WAIT4RESP)
        elif cmd & RXENAB:
            if cmd & RXDLYE:
                dxr = self.get(DX_TIME, 0, 5) & ~(DELAYED_TX_GRID - 1)
                t_now = int(self.host.sys_time_units())
                self.host.rx_enable(float(t_now + (dxr - t_now) % TIMESTAMP_MOD))
            else:
                self.host.rx_enable(None)

    def tx_stamped(self, stamp: int, antd: int) -> None:
        """The TX_STAMP of the frame started last (unwrapped): TX_TIME and TX_RAWST."""
        self.set(TX_TIME, 0, stamp & MASK40, 5)
        self.set(TX_TIME, 5, (stamp - antd) & MASK40, 5)  # TX_RAWST

    def tx_done(self) -> bool:
        """The frame is out: raise the TX status bits. True if WAIT4RESP asks for RX now."""
        self.set_status(TX_DONE_BITS)
        w, self._wait4resp = self._wait4resp, False
        return w

    def deliver(self, f: RxFrame) -> None:
        """A good frame was received: fill the RX register files and raise RXFCG and friends."""
        rx = f.rec
        stamp = rx.stamp_units
        raw = stamp + self.get(LDE_IF, LDE_RXANTD_OFF, 2)
        t = self.regs[RX_TIME]
        t[0:5] = (stamp & MASK40).to_bytes(5, "little")
        t[5:7] = (rx.fp_index & 0xFFFF).to_bytes(2, "little")
        t[7:9] = (rx.fp_ampl1 & 0xFFFF).to_bytes(2, "little")
        t[9:14] = (raw & MASK40).to_bytes(5, "little")
        q = self.regs[RX_FQUAL]
        q[0:2] = (rx.std_noise & 0xFFFF).to_bytes(2, "little")
        q[2:4] = (rx.fp_ampl2 & 0xFFFF).to_bytes(2, "little")
        q[4:6] = (rx.fp_ampl3 & 0xFFFF).to_bytes(2, "little")
        q[6:8] = (rx.cir_pwr & 0xFFFF).to_bytes(2, "little")
        length = len(f.payload) + 2
        fmt = f.fmt
        psr_pe = _PSR_PE_OF_LEN.get(fmt.preamble_symbols, 0x5)
        finfo = ((length & 0x3FF) | (fmt.txbr << 13) | (int(fmt.ranging) << 15)
                 | ((1 if fmt.prf_mhz == 16 else 2) << 16) | ((psr_pe & 3) << 18)
                 | ((rx.rxpacc & 0xFFF) << 20))
        self.set(RX_FINFO, 0, finfo, 4)
        self.regs[RX_BUFFER][0:len(f.payload)] = f.payload
        self.set(DRX_CONF, DRX_CAR_INT_OFF, rx.car_int & 0x1FFFFF, 3)
        self.set(DRX_CONF, RXPACC_NOSAT_OFF, rx.rxpacc_nosat, 2)
        self.set(RX_TTCKI, 0, RX_TTCKI_BY_PRF[fmt.prf_mhz], 4)
        self.set(RX_TTCKO, 0, rx.ttcko & 0x7FFFF, 3)
        self.rx_count += 1
        self.set_status(RX_GOOD_BITS)

    def tx_gain_octet(self, shr: bool = True) -> int:
        """TX_POWER octet in use: octet 2 (SHR and data) or octet 1 (PHR)."""
        return self.regs[TX_POWER][2 if shr else 1]

    def tx_payload(self, fmt: FrameFormat) -> bytes:
        """The frame bytes (without the 2 CRC bytes) in TX_BUFFER."""
        return bytes(self.regs[TX_BUFFER][0:max(0, fmt.length - 2)])


_PSR_PE_OF_LEN: Final[dict[int, int]] = {v: k for k, v in PREAMBLE_LEN.items()}


_SYS_TIME_READ: Final = bytes([SYS_TIME])
_SNAP_TIME_HDR: Final = SNAP_BLOCK.pack(SYS_TIME, 0, 5)


def _snap_blocks(blocks: tuple[tuple[int, int, int], ...]) -> tuple[tuple[bytes, int, int, int], ...]:
    for rid, off, n in blocks:
        assert off + n <= SIZES[rid], "a snapshot block must lie inside its register file"
    return tuple((SNAP_BLOCK.pack(rid, off, n), rid, off, n) for rid, off, n in blocks)


_SNAP_ALWAYS: Final = _snap_blocks(((SYS_STATUS, 0, 5), (TX_TIME, 0, 10)))
_SNAP_RX: Final = _snap_blocks(((RX_FINFO, 0, 4), (RX_TIME, 0, 14), (RX_FQUAL, 0, 8),
                                (DRX_CONF, DRX_CAR_INT_OFF, 6), (RX_TTCKI, 0, 4), (RX_TTCKO, 0, 5)))
