"""Per-station hardware of the world model: the constants a scenario fixes for each station
(antenna delays, bias curve shift, RX and TX noise scales) and the TX gain table, whose coarse-gain errors
are drawn from the scenario seed when the scenario leaves them open (the same hardware in
every run). Gains dB, powers dBm, delays device units.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from uwbcal.physics.records import FloatArray
from uwbcal.physics.scenario import Station
from uwbcal.physics.world_base import TU, WorldBase


class StationHardware:
    """Per-station constants of a World, evaluated once from the scenario (same expressions as
    per call before; the scenario is immutable)."""

    __slots__ = (
        "station", "power_table", "power_list", "bias_shift_db", "bias_scale", "bias_offset_s",
        "car_k", "rx_err0_s", "rx_antd", "noise_scale", "tx_antd", "tx_true_delay_units", "others",
        "tx_noise_scale",
    )

    def __init__(self, world: WorldBase, st: Station, gain_table: FloatArray) -> None:
        e = world.scenario.effects
        self.station = st
        #: TX output power per TX_POWER octet, dBm: tx_ref_dbm + actual gain
        self.power_table = np.asarray(st.tx_ref_dbm + gain_table)
        self.power_list: list[float] = self.power_table.tolist()
        self.bias_shift_db = st.bias_shift_db
        self.bias_scale = st.bias_scale
        self.bias_offset_s = st.bias_offset_ps * 1e-12
        self.car_k = st.car_int_scale * world.fx_car.slope_ppm_per_db
        const = 0.0
        if e["antenna_delay"].enabled and st.rx_delay_error_ps:
            const += st.rx_delay_error_ps * 1e-12
        self.rx_err0_s = const
        self.rx_antd = st.rx_antd
        self.noise_scale = st.noise_scale
        self.tx_noise_scale = st.tx_noise_scale
        self.tx_antd = st.tx_antd
        self.tx_true_delay_units = st.tx_antd + (
            st.tx_delay_error_ps * 1e-12 / TU if e["antenna_delay"].enabled else 0.0
        )
        self.others = [s for s in world.scenario.station_ids if s != st.id]




class TxPower(WorldBase):
    """TX gain and output power per TX_POWER octet (tx_gain effect)."""

    def _gain_table(self, st: Station) -> FloatArray:
        g = self.fx_tx_gain
        octets = np.arange(256)
        coarse, fine = octets >> 5, octets & 31
        if g.enabled:
            errs = st.coarse_errors_db
            if errs is None:
                hw = np.random.default_rng([self.scenario.seed, st.id, 13])
                drawn = hw.normal(0.0, g.coarse_sigma_db, 7)
                drawn[0] = 0.0
                errs = tuple(float(x) for x in drawn)
            table = fine * g.fine_step_db * st.fine_scale - coarse * g.coarse_step_db
            table = table + np.asarray(errs + (0.0,))[coarse]
        else:
            table = fine * g.fine_step_db - coarse * g.coarse_step_db
        return np.asarray(np.where(coarse == 7, -np.inf, table), dtype=np.float64)

    def tx_gain_db(self, station: int, gain_octet: npt.ArrayLike) -> FloatArray:
        """Actual TX gain, dB relative to coarse 0 / fine 0, of TX_POWER octets (tx_gain effect)."""
        self.clock(station)
        return np.asarray(self._gain_tables[station][np.asarray(gain_octet, dtype=np.int64) & 0xFF])

    def tx_power_dbm(self, station: int, gain_octet: npt.ArrayLike) -> FloatArray:
        """TX output power, dBm: the station's tx_ref_dbm plus the actual gain."""
        self.clock(station)
        return np.asarray(self._hw[station].power_table[np.asarray(gain_octet, dtype=np.int64) & 0xFF])
