"""What the medium asks of the world model, per frame and per station.

The medium has no physics of its own: :class:`RadioWorld` is the narrow interface it calls,
and :mod:`uwbcal.medium.world_adapter` implements it on top of :mod:`uwbcal.physics` (the same
World the vectorised simulator uses). Tests may implement it with an ideal world to check
the register and scheduling semantics in isolation.

Times: true time in seconds (float) since the start of the world; station clocks in DW1000
device units (unwrapped float; the register model wraps them to 40 bits).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

from uwbcal.medium.airtime import FrameFormat


@dataclass(frozen=True, slots=True)
class TxFrame:
    """A frame as it leaves a transmitter."""

    tx_station: int
    t_rmarker_s: float      #: true time the RMARKER leaves the TX antenna, s
    gain_octet: int         #: TX_POWER octet 2 (SHR and data)
    fmt: FrameFormat
    channel: int
    payload: bytes


@dataclass(frozen=True, slots=True)
class Reception:
    """The outcome of one frame at one listening receiver (from physics)."""

    arrival_s: float        #: true time the RMARKER reaches the receiver's antenna, s
    stamp_units: int        #: RX_STAMP (LDE_RXANTD already subtracted), unwrapped device units
    cir_pwr: int
    rxpacc: int
    rxpacc_nosat: int
    fp_ampl1: int
    fp_ampl2: int
    fp_ampl3: int
    std_noise: int
    fp_index: int
    car_int: int            #: DRX_CAR_INT, signed (21-bit range)
    ttcko: int              #: RX_TTCKO.RXTOFS, signed (19-bit range)


class RadioWorld(Protocol):
    """The world model as the medium sees it."""

    def station_ids(self) -> list[int]:
        """Ids of the stations the scenario names."""

    def local_units(self, station: int, t_s: float) -> float:
        """The station's DW1000 clock at true time t_s, device units, unwrapped."""

    def true_time(self, station: int, units: float) -> float:
        """Inverse of :meth:`local_units`: the true time (s) the station's clock reads ``units``."""

    def delayed_tx(self, station: int, dx_units: int, tx_antd: int) -> tuple[float, int]:
        """A delayed TX programmed at unwrapped DX_TIME ``dx_units`` with TX_ANTD ``tx_antd``:
        (true time the RMARKER leaves the antenna, s; TX_STAMP unwrapped, device units)."""

    def receive(self, frame: TxFrame, rx_stations: list[int],
                rx_antd: dict[int, int]) -> dict[int, Reception]:
        """What each listening station in ``rx_stations`` gets of ``frame`` (missing: lost).

        ``rx_antd`` is each receiver's programmed LDE_RXANTD register. The world keeps what
        it needs between calls (the previous reception at each receiver, for interference).
        """

    def temperature_c(self, station: int, t_s: float) -> float:
        """Chip temperature of the station at true time t_s, degC."""

    def otp_vtemp(self, station: int) -> int:
        """OTP word 0x009 of the station: byte 1 T23 (LTEMP at 23 degC), byte 0 LVBAT at 3.3 V."""
