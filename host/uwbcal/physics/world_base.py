"""State every part of the world model shares: the scenario's switches and constants, the
station clocks, and the conversions between true time and each station's counter.

:class:`WorldBase` declares what :class:`uwbcal.physics.world.World` sets up in its
constructor; the parts (hardware, paths, transmitter, receiver, register synthesis, per-frame
API) are mixins built on it, one module each. Times s, station counters in device units.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from uwbcal import dw1000
from uwbcal.errors import ScenarioError
from uwbcal.physics import _num
from uwbcal.physics import effects as fx
from uwbcal.physics._num import Num
from uwbcal.physics.clock import StationClock
from uwbcal.physics.records import FloatArray, IntArray
from uwbcal.physics.scenario import Radio, Scenario

if TYPE_CHECKING:
    from uwbcal.physics.hardware import StationHardware
    from uwbcal.physics.paths import LinkPath

TU = dw1000.TIME_UNIT_S
MASK40 = dw1000.TIMESTAMP_MOD - 1
GRID_MASK = ~(dw1000.DELAYED_TX_GRID - 1)
INV_TU = 1.0 / TU


class WorldBase:
    """The shared state of a World (set by its constructor) and the clock conversions."""

    scenario: Scenario
    seed: int
    rng: np.random.Generator
    radio: Radio
    clocks: dict[int, StationClock]
    fx_tx_gain: fx.TxGain
    fx_path: fx.PathLoss
    fx_bias: fx.PowerBias
    fx_est: fx.RxPowerEstimate
    fx_car: fx.CarIntError
    fx_noise: fx.TimestampNoise
    fx_interf: fx.Interference
    fx_mp: fx.Multipath
    fx_temp: fx.Temperature
    _gain_tables: dict[int, FloatArray]
    _last_rx: dict[int, float]
    _station_ids: list[int]
    _wrap_on: bool
    _grid_on: bool
    _quant_on: bool
    _drift_per_c: float | None
    _tx_jitter_s: float
    _mp_on: bool
    _mp_scale: float
    _est_noise: bool
    _a_dbm: float
    _ln10_10: float
    _fp_fac: float
    _fp_fac_late: float
    _fp_sqrt: list[float]
    _std_noise: int
    _sfd_p: float
    _ttcki: int
    _ttck_k: float
    _hw: dict[int, StationHardware]
    _paths: dict[tuple[int, int], LinkPath]

    # -- stations and clocks --------------------------------------------------------------
    @property
    def station_ids(self) -> list[int]:
        """Station ids of the scenario."""
        return list(self._station_ids)

    def clock(self, station: int) -> StationClock:
        """The station's clock; ScenarioError for an unknown id."""
        try:
            return self.clocks[station]
        except KeyError:
            raise ScenarioError(f"no station {station} in scenario {self.scenario.name!r}") from None

    def _station(self, station: int) -> StationHardware:
        try:
            return self._hw[station]
        except KeyError:
            self.scenario.station(station)  # raises the ScenarioError naming the stations
            raise

    def _path(self, tx: int, rx: int) -> LinkPath:
        p = self._paths.get((tx, rx))
        if p is None:
            p = self._paths[(tx, rx)] = LinkPath(self, tx, rx)
        return p

    def local_s(self, station: int, t_s: npt.ArrayLike) -> FloatArray:
        """Unwrapped local time of a station, s, at true times t (s)."""
        return self.clock(station).local_s(t_s)

    def local_units(self, station: int, t_s: npt.ArrayLike) -> FloatArray:
        """Unwrapped local time of a station in device units (unquantised), at true times t (s)."""
        one = _num.one(t_s)
        if one is not None:
            return _num.arr(self.clock(station)._state(one[0])[0] / TU, one[1])
        return np.asarray(self.clock(station).local_s(t_s) / TU)

    def system_time(self, station: int, t_s: npt.ArrayLike) -> IntArray:
        """SYS_TIME register value (40 bits, truncated to the unit) at true times t (s)."""
        one = _num.one(t_s)
        if one is not None:
            units = self.clock(station)._state(one[0])[0] / TU
            return _num.arr(_num.to_int(_num.floor(units)) & MASK40, one[1])
        return np.asarray(np.floor(self.local_units(station, t_s)).astype(np.int64) & MASK40)

    def true_time_s(self, station: int, local_s: npt.ArrayLike) -> FloatArray:
        """True times, s, at which a station's unwrapped local clock reads ``local_s`` (s)."""
        return self.clock(station).true_s(local_s)

    def true_time_of_units(self, station: int, local_units: npt.ArrayLike) -> FloatArray:
        """True times, s, at which a station's unwrapped counter reads ``local_units``."""
        one = _num.one(local_units)
        if one is not None:
            return _num.arr(self.clock(station)._true_state(one[0] * TU)[0], one[1])
        return self.clock(station).true_s(_num.floats(local_units) * TU)

    def offset_ppm(self, station: int, t_s: npt.ArrayLike) -> FloatArray:
        """Clock frequency offset of a station against true time, ppm (+ = fast)."""
        return self.clock(station).offset_ppm(t_s)

    def temperature_c(self, station: int, t_s: npt.ArrayLike) -> FloatArray:
        """Station temperature, degC, at true times t (s)."""
        return self.clock(station).temperature_c(t_s)

    def _wrap(self, u: Any) -> Any:
        return u & MASK40 if self._wrap_on else u

    def wrap(self, units: npt.ArrayLike) -> IntArray:
        """Timestamps as recorded: modulo 2**40 if timestamp_wrap is on, else unchanged."""
        u = np.asarray(units, dtype=np.int64)
        return np.asarray(u & MASK40) if self._wrap_on else u


    def _delay_drift_s(self, temp_c: Num) -> Num | None:
        """Change of one hardware delay (TX or RX), s, at a station temperature (temperature effect)."""
        if self._drift_per_c is None:
            return None
        return self._drift_per_c * (temp_c - self.fx_temp.ref_c)
