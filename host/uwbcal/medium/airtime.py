"""DW1000 frame timing (user manual section 10 / IEEE 802.15.4a UWB PHY as the DW1000 runs it).

These are chip facts of the register model, not physics: how long a frame configured by
TX_FCTRL stays on the air. Durations in seconds.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

#: Preamble symbol duration, s, per PRF (MHz): 496 chips (64 MHz) / 496 chips at 16 MHz
#: PRF with different spreading; values from the user manual (1017.63 ns and 993.59 ns).
PREAMBLE_SYMBOL_S: Final[dict[int, float]] = {64: 1017.63e-9, 16: 993.59e-9}
#: Duration of one data bit, s, per TXBR code (0 = 110 kb/s, 1 = 850 kb/s, 2 = 6.81 Mb/s).
BIT_S: Final[dict[int, float]] = {0: 8205.13e-9, 1: 1025.64e-9, 2: 128.21e-9}
#: PHR bit duration, s: 110 kb/s at 110 kb/s, otherwise 850 kb/s.
PHR_BIT_S: Final[dict[int, float]] = {0: 8205.13e-9, 1: 1025.64e-9, 2: 1025.64e-9}
#: SFD length in symbols per TXBR code (standard SFD 8, 64 at 110 kb/s).
SFD_SYMBOLS: Final[dict[int, int]] = {0: 64, 1: 8, 2: 8}
#: TX_FCTRL (TXPSR | PE << 2) -> preamble length in symbols.
PREAMBLE_LEN: Final[dict[int, int]] = {
    0x1: 64, 0x5: 128, 0x9: 256, 0xD: 512, 0x2: 1024, 0x6: 1536, 0xA: 2048, 0x3: 4096,
}
PHR_BITS: Final = 21


@dataclass(frozen=True, slots=True)
class FrameFormat:
    """What TX_FCTRL says about a frame: length (bytes, CRC included), rate, PRF, preamble."""

    length: int
    txbr: int
    prf_mhz: int
    preamble_symbols: int
    ranging: bool

    @classmethod
    def from_tx_fctrl(cls, v: int) -> FrameFormat:
        """Decode TX_FCTRL's low 32 bits (TFLEN|TFLE 9:0, TXBR 14:13, TR 15, TXPRF 17:16, TXPSR/PE 21:18)."""
        length = v & 0x3FF
        txbr = (v >> 13) & 3
        prf = 16 if ((v >> 16) & 3) == 1 else 64
        psr_pe = (v >> 18) & 0xF
        return cls(length=length, txbr=txbr if txbr in BIT_S else 2, prf_mhz=prf,
                   preamble_symbols=PREAMBLE_LEN.get(psr_pe, 128), ranging=bool((v >> 15) & 1))

    def shr_s(self) -> float:
        """Preamble + SFD: time from the start of the frame to the RMARKER, s."""
        return (self.preamble_symbols + SFD_SYMBOLS[self.txbr]) * PREAMBLE_SYMBOL_S[self.prf_mhz]

    def tail_s(self) -> float:
        """PHR + data (Reed-Solomon parity included): time from the RMARKER to the frame's end, s."""
        bits = 8 * self.length
        rs = 48 * ((bits + 329) // 330)
        return PHR_BITS * PHR_BIT_S[self.txbr] + (bits + rs) * BIT_S[self.txbr]
