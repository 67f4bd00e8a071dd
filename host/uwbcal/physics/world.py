"""The world model: station clocks, propagation, received power, timestamps and RX registers.

One implementation serves both users:
- the vectorised simulator (:mod:`uwbcal.vectorsim`) calls :meth:`World.delayed_tx` and
  :meth:`World.receive` with whole-session arrays;
- the simulated medium (:mod:`uwbcal.medium`) calls the same functions per frame (arrays of
  length 1, or the scalar convenience :meth:`World.transmit`) and converts between true time
  and each station's clock with :meth:`World.local_units` / :meth:`World.true_time_of_units`.

Time: true time ``t`` in SI seconds since the session start. A station's local time is its
unwrapped system-time counter in seconds (``local_s``) or device units (``local_units``,
1 unit = dw1000.TIME_UNIT_S = 15.65 ps); registers hold it modulo 2**40.

Random draws: hardware values a scenario leaves open (counter offsets, coarse-gain errors) come
from the scenario's seed, so a station is the same hardware in every run; per-frame noise
and clock wander come from the run seed (``World(scenario, seed)``, default the scenario's).
Same scenario, same seed, same sequence of calls: identical results.

One module per concept, each a part of :class:`World`: clock (station clocks), hardware
(per-station draws, TX gain), paths (propagation), transmitter (delayed TX), receiver (RX
model), rx_registers (register synthesis), frame (the medium's per-frame API); world_base holds
the state they share, records the types they return.
"""

from __future__ import annotations

import numpy as np

from uwbcal import dw1000
from uwbcal.errors import ScenarioError
from uwbcal.physics import effects as fx
from uwbcal.physics import models
from uwbcal.physics.clock import StationClock
from uwbcal.physics.frame import FrameApi
from uwbcal.physics.hardware import StationHardware, TxPower
from uwbcal.physics.receiver import reception_gaps
from uwbcal.physics.records import Reception, RxBatch, TxBatch
from uwbcal.physics.scenario import Scenario
from uwbcal.physics.transmitter import Transmitter

__all__ = ["Reception", "RxBatch", "StationClock", "TxBatch", "World", "reception_gaps"]


class World(FrameApi, Transmitter, TxPower):
    """A simulated world built from a :class:`Scenario` and a run seed (default: the scenario's).

    Each formula is implemented once (:meth:`_tx`, :meth:`_rx`, :meth:`StationClock._state`)
    and evaluated either on a Python float (one frame: :meth:`transmit`, length-1 arrays) or
    on arrays (the vectorised simulator), with identical results (uwbcal.physics._num).
    Scenario-derived constants are evaluated once here.
    """

    def __init__(self, scenario: Scenario, seed: int | None = None) -> None:
        if not scenario.stations:
            raise ScenarioError(f"scenario {scenario.name!r} has no stations")
        self.scenario = scenario
        self.seed = int(scenario.seed if seed is None else seed)
        self.rng = np.random.default_rng([self.seed, 1])
        self.radio = scenario.radio
        self.clocks = {s.id: StationClock(s, scenario, self.seed) for s in scenario.stations}
        e = scenario.effects
        self.fx_tx_gain: fx.TxGain = e["tx_gain"]  # type: ignore[assignment]
        self.fx_path: fx.PathLoss = e["path_loss"]  # type: ignore[assignment]
        self.fx_bias: fx.PowerBias = e["power_bias"]  # type: ignore[assignment]
        self.fx_est: fx.RxPowerEstimate = e["rx_power_estimate"]  # type: ignore[assignment]
        self.fx_car: fx.CarIntError = e["car_int_error"]  # type: ignore[assignment]
        self.fx_noise: fx.TimestampNoise = e["timestamp_noise"]  # type: ignore[assignment]
        self.fx_interf: fx.Interference = e["interference"]  # type: ignore[assignment]
        self.fx_mp: fx.Multipath = e["multipath"]  # type: ignore[assignment]
        self.fx_temp: fx.Temperature = e["temperature"]  # type: ignore[assignment]
        self._gain_tables = {s.id: self._gain_table(s) for s in scenario.stations}
        self._last_rx: dict[int, float] = {}
        # switches and constant subexpressions, evaluated once
        self._station_ids = [s.id for s in scenario.stations]
        self._wrap_on = e["timestamp_wrap"].enabled
        self._grid_on = e["delayed_tx_grid"].enabled
        self._quant_on = e["quantisation"].enabled
        ft = self.fx_temp
        self._drift_per_c: float | None = (
            ft.range_drift_m_per_c / dw1000.C_LIGHT / 2.0 if ft.enabled and ft.range_drift_m_per_c else None
        )
        tn = self.fx_noise
        self._tx_jitter_s = tn.tx_jitter_ps * 1e-12 if tn.enabled and tn.tx_jitter_ps else 0.0
        mp = self.fx_mp
        self._mp_on = mp.enabled and mp.probability > 0
        self._mp_scale = mp.mean_bias_m / dw1000.C_LIGHT
        fe = self.fx_est
        self._est_noise = fe.enabled and bool(fe.noise_db)
        self._a_dbm = dw1000.RX_LEVEL_A_DBM[self.radio.prf_mhz]
        self._ln10_10 = np.log(10.0) / 10.0
        self._fp_fac = 10.0 ** (-(fe.fp_delta_db if fe.enabled else 0.0) / 10.0)
        self._fp_fac_late = self._fp_fac * 10.0 ** (-mp.fp_drop_db / 10.0)
        self._fp_sqrt = [float(np.sqrt(w)) for w in models.FP_SPLIT]
        self._std_noise = int(round(fe.std_noise))
        self._sfd_p = float(fe.sfd_in_rxpacc) if fe.enabled else 0.0
        self._ttcki = dw1000.RX_TTCKI_BY_PRF[self.radio.prf_mhz]
        self._ttck_k = -1e-6 * self._ttcki
        self._hw = {s.id: StationHardware(self, s, self._gain_tables[s.id]) for s in scenario.stations}
        self._paths = {}
