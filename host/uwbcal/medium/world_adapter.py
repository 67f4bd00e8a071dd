"""The medium's :class:`~uwbcal.medium.port.RadioWorld` on top of :class:`uwbcal.physics.world.World`.

No physics here: each call forwards to the World the vectorised simulator uses (clock
conversions, :meth:`World.delayed_tx`, :meth:`World.transmit`) and reshapes the result into
register values. The only state of its own is where stations have been moved to at run time
(the medium's control socket: ``move``, or the scenario's scripted ``[[moves]]`` as virtual time
passes them), passed to the World as per-receiver distances.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

from uwbcal.medium.port import Reception, TxFrame
from uwbcal.physics.scenario import Scenario, load_scenario
from uwbcal.physics.world import World

#: OTP word 0x009 of a simulated chip: byte 1 T23 (LTEMP at 23 degC), byte 0 LVBAT. A chip
#: fact of the register model (factory calibration differs per chip), not physics.
OTP_T23_BASE = 0x80
OTP_VBAT = 0xB0


class MediumWorldAdapter:
    """uwbcal.physics.World seen through the medium's port."""

    def __init__(self, scenario: Scenario, seed: int | None = None) -> None:
        self.scenario = scenario
        self.world = World(scenario, seed)
        self.positions: dict[int, tuple[float, float, float]] = {}
        #: The scenario's scripted moves not yet played (sorted by time).
        self._moves = list(scenario.moves)
        self._ids = list(scenario.station_ids)
        self._clocks = {sid: self.world.clock(sid) for sid in self._ids}
        #: Wall-clock seconds spent in the World (for the benchmark's breakdown).
        self.busy_s = 0.0

    @classmethod
    def from_file(cls, path: str | Path, seed: int | None = None) -> MediumWorldAdapter:
        """Load the scenario (path or example name); ScenarioError on a bad file."""
        return cls(load_scenario(path), seed)

    # ---- port ----------------------------------------------------------------------------
    def station_ids(self) -> list[int]:
        """Ids of the scenario's stations."""
        return list(self._ids)

    def local_units(self, station: int, t_s: float) -> float:
        """The station's DW1000 counter at true time t_s, device units, unwrapped."""
        return float(self.world.local_units(station, t_s))

    def true_time(self, station: int, units: float) -> float:
        """True time (s) at which the station's counter reads ``units``."""
        return float(self.world.true_time_of_units(station, units))

    def delayed_tx(self, station: int, dx_units: int, tx_antd: int) -> tuple[float, int]:
        """(true time the frame leaves the antenna, s; TX_STAMP unwrapped) of a delayed TX."""
        t0 = time.perf_counter()
        b = self.world.delayed_tx(station, [dx_units], tx_antd)
        self.busy_s += time.perf_counter() - t0
        return float(b.t_true_s[0]), int(b.stamp_unwrapped[0])

    def receive(self, frame: TxFrame, rx_stations: list[int],
                rx_antd: dict[int, int]) -> dict[int, Reception]:
        """Receptions of one frame at the listening stations (World.transmit); lost ones left out."""
        t0 = time.perf_counter()
        while self._moves and self._moves[0].t_s <= frame.t_rmarker_s:
            mv = self._moves.pop(0)
            self.positions[mv.station] = mv.position_m
        dist = None
        if self.positions:
            dist = {rx: self.distance_m(frame.tx_station, rx) for rx in rx_stations}
        recs = self.world.transmit(frame.tx_station, frame.t_rmarker_s, frame.gain_octet,
                                   receivers=rx_stations, distances_m=dist, rx_antd=rx_antd)
        out: dict[int, Reception] = {}
        for rx, r in recs.items():
            if not r.detected:
                continue
            g = r.regs
            out[rx] = Reception(
                arrival_s=r.t_arrival_s, stamp_units=r.stamp_unwrapped, cir_pwr=g["cir_pwr"],
                rxpacc=g["rxpacc"], rxpacc_nosat=g["rxpacc_nosat"], fp_ampl1=g["fp_ampl1"],
                fp_ampl2=g["fp_ampl2"], fp_ampl3=g["fp_ampl3"], std_noise=g["std_noise"],
                fp_index=g["fp_index"], car_int=g["car_int"], ttcko=g["ttcko"])
        self.busy_s += time.perf_counter() - t0
        return out

    def temperature_c(self, station: int, t_s: float) -> float:
        """Chip temperature, degC (World)."""
        return float(self.world.temperature_c(station, t_s))

    def otp_vtemp(self, station: int) -> int:
        """OTP word 0x009 of this station's chip."""
        return ((OTP_T23_BASE + (station * 7) % 16) << 8) | OTP_VBAT

    # ---- run-time control ----------------------------------------------------------------
    def move(self, station: int, position_m: tuple[float, float, float]) -> None:
        """Put a station at a new position (m); later frames use the new distance."""
        self.scenario.station(station)
        self.positions[station] = position_m

    def position_m(self, station: int) -> tuple[float, float, float]:
        """Current position of a station, m."""
        return self.positions.get(station, self.scenario.station(station).position_m)

    def distance_m(self, a: int, b: int) -> float:
        """Current distance between two stations, m (a cable link keeps its length)."""
        link = self.scenario.link(a, b)
        if link.kind == "cable" or (a not in self.positions and b not in self.positions):
            return self.scenario.distance_m(a, b)
        return float(math.dist(self.position_m(a), self.position_m(b)))
