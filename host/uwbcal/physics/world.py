"""The world model: station clocks, propagation, received power, timestamps and RX registers.

One implementation serves both users:
- the vectorised simulator (:mod:`uwbcal.simulate`) calls :meth:`World.delayed_tx` and
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
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from uwbcal import dw1000
from uwbcal.errors import ScenarioError
from uwbcal.physics import _num, models
from uwbcal.physics import effects as fx
from uwbcal.physics._num import Num, Shape
from uwbcal.physics.scenario import Scenario, Station

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

TU = dw1000.TIME_UNIT_S
_MASK40 = dw1000.TIMESTAMP_MOD - 1
#: Nominal first-path index (RX_TIME.FP_INDEX integer part) of a clean reception.
FP_INDEX_NOMINAL = 745
#: RXPACC_NOSAT - RXPACC in simulated records: never equal, so RXPACC needs no SFD correction.
RXPACC_NOSAT_EXTRA = 8
_GRID_MASK = ~(dw1000.DELAYED_TX_GRID - 1)
_INV_TU = 1.0 / TU


def _f(x: npt.ArrayLike) -> FloatArray:
    return np.asarray(x, dtype=np.float64)


class StationClock:
    """One station's clock: local(t) = counter0 + tau + 1e-6 * Phi(tau), tau = t - power_on.

    Phi (ppm*s) is the integral of the frequency offset y(u) = ppm + warmup_ppm exp(-u/T_w)
    + tempco (T(u) - ref) + wander(u), in closed form (wander: exact integral of a linearly
    interpolated random walk). Before power-on the clock is extrapolated at y(0).

    The public methods take and return arrays; :meth:`_state` and :meth:`_true_state` are the
    one implementation, evaluated on a Python float per frame or on an array (uwbcal.physics._num).
    """

    def __init__(self, station: Station, scenario: Scenario, run_seed: int) -> None:
        e = scenario.effects
        self.station_id = station.id
        self.ppm = station.ppm if e["clock_offset"].enabled else 0.0
        self.warm_ppm = station.warmup_ppm if e["warmup"].enabled else 0.0
        self.warm_tau = station.warmup_tau_s
        self.power_on_s = station.power_on_s
        hw = np.random.default_rng([scenario.seed, station.id, 7])
        c0 = station.counter_offset_units
        if c0 is None:
            c0 = int(hw.integers(0, dw1000.TIMESTAMP_MOD))
        self.counter0_units = int(c0)
        self.counter0_s = c0 * TU
        temp = e["temperature"]
        assert isinstance(temp, fx.Temperature)
        self.temp_on = temp.enabled
        self.ambient_c = station.ambient_c
        self.heat_c = station.self_heating_c if temp.enabled else 0.0
        self.heat_tau = temp.heating_tau_s
        self.ramp = temp.ramp_c_per_s if temp.enabled else 0.0
        self.ref_c = temp.ref_c
        self.tempco = station.tempco_ppm_per_c if temp.enabled else 0.0
        wander = e["clock_wander"]
        assert isinstance(wander, fx.ClockWander)
        self.w_sigma = wander.sigma_ppm_per_sqrt_s if wander.enabled else 0.0
        self.w_h = wander.grid_s
        self._w_rng = np.random.default_rng([run_seed, station.id, 11])
        self._w = np.zeros(1)  # frequency at grid points, ppm
        self._wc = np.zeros(1)  # its integral at grid points, ppm*s
        self._dw = np.zeros(0)  # slope between grid points, ppm/s
        # constant subexpressions of _state, evaluated once (same expressions, same values)
        self._warm_k = -1.0 / self.warm_tau
        self._warm_phase = self.warm_ppm * self.warm_tau
        self._heat_k = -1.0 / self.heat_tau
        self._amb_ref = self.ambient_c - self.ref_c
        self._tempco_amb = self.tempco * (self.ambient_c - self.ref_c)
        self._half_ramp = 0.5 * self.ramp
        self._inv_h = 1.0 / self.w_h
        self._y0_ppm = self.ppm + self.warm_ppm + self.tempco * (self.ambient_c - self.ref_c)
        self._rate0 = 1.0 + 1e-6 * self._y0_ppm

    # -- wander ---------------------------------------------------------------------------
    def _extend(self, kmax: int) -> None:
        n_have = self._w.size
        if kmax + 2 <= n_have:
            return
        n_new = max(kmax + 2 - n_have, 4096)
        steps = self._w_rng.standard_normal(n_new) * (self.w_sigma * np.sqrt(self.w_h))
        w_new = self._w[-1] + np.cumsum(steps)
        w_all = np.concatenate([self._w, w_new])
        seg = 0.5 * self.w_h * (w_all[n_have - 1 : -1] + w_all[n_have:])
        self._wc = np.concatenate([self._wc, self._wc[-1] + np.cumsum(seg)])
        self._w = w_all
        self._dw = np.diff(w_all) / self.w_h

    def _wander(self, taup: Num) -> tuple[Num, Num]:
        """(frequency ppm, integral ppm*s) of the wander at tau >= 0 (exact integral of the
        linearly interpolated random walk)."""
        k = _num.to_int(taup * self._inv_h)
        self._extend(_num.max_int(k))
        s = taup - k * self.w_h
        w0 = _num.take(self._w, k)
        dw = _num.take(self._dw, k)
        return w0 + dw * s, _num.take(self._wc, k) + s * (w0 + 0.5 * dw * s)

    # -- frequency and phase --------------------------------------------------------------
    def temperature_c(self, t_s: npt.ArrayLike) -> FloatArray:
        """Station temperature, degC, at true times t (s)."""
        one = _num.one(t_s)
        tau = (one[0] if one is not None else _f(t_s)) - self.power_on_s
        temp = models._heating_c(tau, self.ambient_c, self.heat_c, self.heat_tau, self.ramp)
        return np.asarray(temp) if one is None else _num.arr(temp, one[1])

    def _y0(self) -> float:
        return self._y0_ppm

    def _state(self, t: Num) -> tuple[Num, Num, Num]:
        """(local time s, frequency offset ppm, temperature degC) at true time(s) t: a float or
        a float64 array (the one implementation behind :meth:`state`)."""
        tau = t - self.power_on_s
        taup = _num.maximum0(tau)
        phi = self.ppm * taup
        y = _num.full(None if isinstance(tau, float) else tau.shape, self.ppm)
        if self.warm_ppm:
            ex = _num.exp(taup * self._warm_k)
            y += self.warm_ppm * ex
            phi += self._warm_phase * (1.0 - ex)
        if self.heat_c or self.ramp:
            eh = _num.exp(taup * self._heat_k)
            temp = self.ambient_c + self.heat_c * (1.0 - eh) + self.ramp * taup
            if self.tempco:
                y += self.tempco * (temp - self.ref_c)
                phi += self.tempco * (
                    self._amb_ref * taup
                    + self.heat_c * (taup - self.heat_tau * (1.0 - eh))
                    + self._half_ramp * taup * taup
                )
        else:
            temp = _num.full(None if isinstance(tau, float) else tau.shape, self.ambient_c)
            if self.tempco:
                y += self._tempco_amb
                phi += self._tempco_amb * taup
        if self.w_sigma:
            wf, wi = self._wander(taup)
            y += wf
            phi += wi
        if _num.any_negative(tau):
            phi = phi + self._y0_ppm * _num.minimum0(tau)
        local = (self.counter0_s + tau) + 1e-6 * phi
        return local, y, temp

    def state(self, t_s: npt.ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(unwrapped local time s, frequency offset ppm, temperature degC) at true times t (s).

        One evaluation shares the exponentials of warm-up and heating between the phase, the
        frequency and the temperature.
        """
        one = _num.one(t_s)
        if one is not None:
            local, y, temp = self._state(one[0])
            return _num.arr(local, one[1]), _num.arr(y, one[1]), _num.arr(temp, one[1])
        local, y, temp = self._state(_f(t_s))
        return np.asarray(local), np.asarray(y), np.asarray(temp)

    def offset_ppm(self, t_s: npt.ArrayLike) -> FloatArray:
        """Frequency offset y of the clock against true time, ppm (+ = fast), at true times t."""
        return self.state(t_s)[1]

    def phase_ppm_s(self, tau: npt.ArrayLike) -> FloatArray:
        """Phi(tau), ppm*s: integral of the frequency offset from power-on (tau = t - power_on)."""
        local = self.state(_f(tau) + self.power_on_s)[0]
        return np.asarray((local - self.counter0_s - _f(tau)) * 1e6)

    def local_s(self, t_s: npt.ArrayLike) -> FloatArray:
        """Unwrapped local time, s, at true times t (s)."""
        return self.state(t_s)[0]

    def _true_state(self, target: Num) -> tuple[Num, Num, Num]:
        """:meth:`true_state` of a float or a float64 array."""
        t = self.power_on_s + (target - self.counter0_s) / self._rate0
        for _ in range(8):
            local, y, temp = self._state(t)
            step = (local - target) / (1.0 + 1e-6 * y)
            t = t - step
            # the residual after a step of size d is about 0.5e-6 |dy/dt| d**2: negligible below 10 us
            if _num.all_below(step, 1e-5):
                break
        return t, y, temp

    def true_state(self, local_s: npt.ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Inverse of :meth:`local_s`: (true times s at which the clock reads ``local_s``,
        frequency offset ppm there, temperature degC there). Newton iterations; exact to < 1e-15 s."""
        one = _num.one(local_s)
        if one is not None:
            t, y, temp = self._true_state(one[0])
            return _num.arr(t, one[1]), _num.arr(y, one[1]), _num.arr(temp, one[1])
        t, y, temp = self._true_state(_f(local_s))
        return np.asarray(t), np.asarray(y), np.asarray(temp)

    def true_s(self, local_s: npt.ArrayLike) -> FloatArray:
        """Inverse of :meth:`local_s`: true times, s, at which the clock reads ``local_s``."""
        return self.true_state(local_s)[0]


@dataclass
class TxBatch:
    """Delayed transmissions. ``stamp`` TX_STAMP (device units; modulo 2**40 if timestamp_wrap
    is on), ``stamp_unwrapped`` the same unwrapped, ``grid_units`` the start time actually used
    (DX_TIME with low 9 bits cleared, unwrapped), ``t_true_s`` true time the frame leaves the
    antenna (s), ``temp_c`` TX station temperature, ``offset_ppm`` TX clock frequency offset
    (ppm) at departure."""

    stamp: IntArray
    stamp_unwrapped: IntArray
    grid_units: IntArray
    t_true_s: FloatArray
    temp_c: FloatArray
    offset_ppm: FloatArray


@dataclass
class RxBatch:
    """Receptions at one station. ``stamp``/``stamp_unwrapped`` RX_STAMP (device units),
    ``regs`` the RX quality registers (names of columns.RX_QUALITY, int64), and the truth:
    ``t_arrival_s`` true arrival at the antenna, ``rx_dbm`` true RX power, ``est_dbm`` the chip's
    estimate, ``bias_s`` the power-dependent timestamp error (curve + station offset),
    ``error_s`` every timestamp error together (bias, delays, interference, multipath, noise),
    ``offset_ppm`` RX-minus-TX clock frequency offset, ``temp_c`` RX temperature,
    ``distance_m`` distance (or cable length), ``tof_s`` propagation time, ``detected``
    whether the power is above the radio's sensitivity."""

    stamp: IntArray
    stamp_unwrapped: IntArray
    regs: dict[str, IntArray]
    t_arrival_s: FloatArray
    rx_dbm: FloatArray
    est_dbm: FloatArray
    bias_s: FloatArray
    error_s: FloatArray
    offset_ppm: FloatArray
    temp_c: FloatArray
    distance_m: FloatArray
    tof_s: FloatArray
    detected: BoolArray


@dataclass
class Reception:
    """One frame received by one station (per-frame path): scalars of an :class:`RxBatch`."""

    rx_station: int
    stamp: int
    stamp_unwrapped: int
    regs: dict[str, int]
    t_arrival_s: float
    rx_dbm: float
    est_dbm: float
    bias_s: float
    error_s: float
    offset_ppm: float
    temp_c: float
    distance_m: float
    detected: bool
    extra: dict[str, float] = field(default_factory=dict)


class _Hardware:
    """Per-station constants of a World, evaluated once from the scenario (same expressions as
    per call before; the scenario is immutable)."""

    __slots__ = (
        "station", "power_table", "power_list", "bias_shift_db", "bias_scale", "bias_offset_s",
        "car_k", "rx_err0_s", "rx_antd", "noise_scale", "tx_antd", "tx_true_delay_units", "others",
    )

    def __init__(self, world: World, st: Station, gain_table: FloatArray) -> None:
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
        self.tx_antd = st.tx_antd
        self.tx_true_delay_units = st.tx_antd + (
            st.tx_delay_error_ps * 1e-12 / TU if e["antenna_delay"].enabled else 0.0
        )
        self.others = [s for s in world.scenario.station_ids if s != st.id]


class _Path:
    """Constants of the link from one station to another, evaluated once."""

    __slots__ = ("cable", "attenuation_db", "cable_speed", "gains_db", "extra_loss_db", "distance_m",
                 "loss_db", "ref_loss_db", "gap_speed")

    def __init__(self, world: World, tx: int, rx: int) -> None:
        sc = world.scenario
        link = sc.link(tx, rx)
        pl = world.fx_path
        self.cable = link.kind == "cable"
        self.attenuation_db = link.attenuation_db
        self.cable_speed = link.velocity_factor * dw1000.C_LIGHT
        self.gains_db = sc.station(tx).antenna_gain_dbi + sc.station(rx).antenna_gain_dbi
        self.extra_loss_db = link.extra_loss_db
        #: nominal distance, m, and the path loss there (at ref_distance_m if path_loss is off)
        self.distance_m = sc.distance_m(tx, rx)
        f = world.radio.freq_hz
        self.ref_loss_db: float = models._friis_loss_db(pl.ref_distance_m, f, pl.exponent)
        self.loss_db: float = (
            models._friis_loss_db(self.distance_m, f, pl.exponent) if pl.enabled else self.ref_loss_db
        )
        #: signal speed for the per-frame interference gap
        self.gap_speed = dw1000.C_LIGHT * (link.velocity_factor if self.cable else 1.0)


class World:
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
        self._ttcki = dw1000.RX_TTCKI_BY_PRF[self.radio.prf_mhz]
        self._ttck_k = -1e-6 * self._ttcki
        self._hw = {s.id: _Hardware(self, s, self._gain_tables[s.id]) for s in scenario.stations}
        self._paths: dict[tuple[int, int], _Path] = {}

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

    def _station(self, station: int) -> _Hardware:
        try:
            return self._hw[station]
        except KeyError:
            self.scenario.station(station)  # raises the ScenarioError naming the stations
            raise

    def _path(self, tx: int, rx: int) -> _Path:
        p = self._paths.get((tx, rx))
        if p is None:
            p = self._paths[(tx, rx)] = _Path(self, tx, rx)
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
            return _num.arr(_num.to_int(_num.floor(units)) & _MASK40, one[1])
        return np.asarray(np.floor(self.local_units(station, t_s)).astype(np.int64) & _MASK40)

    def true_time_s(self, station: int, local_s: npt.ArrayLike) -> FloatArray:
        """True times, s, at which a station's unwrapped local clock reads ``local_s`` (s)."""
        return self.clock(station).true_s(local_s)

    def true_time_of_units(self, station: int, local_units: npt.ArrayLike) -> FloatArray:
        """True times, s, at which a station's unwrapped counter reads ``local_units``."""
        one = _num.one(local_units)
        if one is not None:
            return _num.arr(self.clock(station)._true_state(one[0] * TU)[0], one[1])
        return self.clock(station).true_s(_f(local_units) * TU)

    def offset_ppm(self, station: int, t_s: npt.ArrayLike) -> FloatArray:
        """Clock frequency offset of a station against true time, ppm (+ = fast)."""
        return self.clock(station).offset_ppm(t_s)

    def temperature_c(self, station: int, t_s: npt.ArrayLike) -> FloatArray:
        """Station temperature, degC, at true times t (s)."""
        return self.clock(station).temperature_c(t_s)

    def _wrap(self, u: Any) -> Any:
        return u & _MASK40 if self._wrap_on else u

    def wrap(self, units: npt.ArrayLike) -> IntArray:
        """Timestamps as recorded: modulo 2**40 if timestamp_wrap is on, else unchanged."""
        u = np.asarray(units, dtype=np.int64)
        return np.asarray(u & _MASK40) if self._wrap_on else u

    # -- TX power -------------------------------------------------------------------------
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

    # -- propagation ----------------------------------------------------------------------
    def nominal_distance_m(self, a: int, b: int) -> float:
        """Scenario distance between two stations (link length or geometry), m."""
        return self.scenario.distance_m(a, b)

    def _propagation(self, tx: int, rx: int, octet: Any, d: Num | None, n: Shape) -> tuple[Num, Num, Num]:
        """(RX power dBm, time of flight s, distance m) of one frame (``n`` None: ints/floats) or
        of arrays of shape ``n`` (``d`` None: the nominal distance)."""
        hw = self._station(tx)
        path = self._path(tx, rx)
        if n is None:
            p_tx = hw.power_list[octet & 0xFF]
        else:
            p_tx = hw.power_table[octet & 0xFF]
        loss = None
        if d is None:
            d = path.distance_m if n is None else np.broadcast_to(_f(path.distance_m), n)
            loss = path.loss_db
        if path.cable:
            return p_tx - path.attenuation_db, d / path.cable_speed, d
        pl = self.fx_path
        if loss is None:
            f = self.radio.freq_hz
            loss = models._friis_loss_db(d, f, pl.exponent) if pl.enabled else path.ref_loss_db
        return p_tx + path.gains_db - path.extra_loss_db - loss, d / dw1000.C_LIGHT, d

    def propagation(
        self, tx: int, rx: int, gain_octet: npt.ArrayLike, distance_m: npt.ArrayLike | None = None
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(true RX power dBm, time of flight s, distance m) of frames from tx to rx.

        ``distance_m`` overrides the scenario geometry (a schedule's tag positions). Air: Friis
        at the channel frequency plus antenna gains minus the link's extra loss; cable: fixed
        attenuation, delay length / (velocity_factor c).
        """
        octet = np.asarray(gain_octet, dtype=np.int64)
        d = None if distance_m is None else _f(distance_m)
        if d is not None and (d.ndim == 0 or d.shape != octet.shape):
            d = np.broadcast_to(d, octet.shape)
        p, tof, dist = self._propagation(tx, rx, octet, d, octet.shape)
        return np.asarray(p), np.asarray(tof), np.asarray(dist, dtype=np.float64)

    # -- TX -------------------------------------------------------------------------------
    def _delay_drift_s(self, temp_c: Num) -> Num | None:
        """Change of one hardware delay (TX or RX), s, at a station temperature (temperature effect)."""
        if self._drift_per_c is None:
            return None
        return self._drift_per_c * (temp_c - self.fx_temp.ref_c)

    def _tx(self, station: int, dx: Any, tx_antd: int | None, n: Shape) -> tuple[Any, Any, Num, Num, Num]:
        """(TX_STAMP unwrapped, grid units, true departure s, temperature, offset ppm) of delayed
        transmissions at DX_TIME ``dx`` (an int, ``n`` None, or an int64 array of shape ``n``)."""
        hw = self._station(station)
        grid = dx & _GRID_MASK if self._grid_on else dx
        antd = hw.tx_antd if tx_antd is None else int(tx_antd)
        stamp_u = grid + antd
        t, y, temp = self.clocks[station]._true_state((grid + hw.tx_true_delay_units) * TU)
        drift = self._delay_drift_s(temp)
        if drift is not None:
            t += drift
        if self._tx_jitter_s:
            t += _num.normal(self.rng, n) * self._tx_jitter_s
        return stamp_u, grid, t, temp, y

    def delayed_tx(self, station: int, dx_time_units: npt.ArrayLike, tx_antd: int | None = None) -> TxBatch:
        """Delayed transmissions programmed at unwrapped local ``dx_time_units`` (DX_TIME).

        The frame starts at DX_TIME with the low 9 bits cleared (delayed_tx_grid); TX_STAMP is
        that plus TX_ANTD (``tx_antd`` register value, default the station's); the frame leaves
        the antenna at that grid time plus the true TX delay (antenna_delay, temperature) and
        TX jitter, converted to true time through the station's clock.
        """
        one = _num.one_int(dx_time_units)
        if one is not None:
            stamp_u, grid, t, temp, y = self._tx(station, one[0], tx_antd, None)
            sh = one[1]
            return TxBatch(
                stamp=_num.arr(self._wrap(stamp_u), sh),
                stamp_unwrapped=_num.arr(stamp_u, sh),
                grid_units=_num.arr(grid, sh),
                t_true_s=_num.arr(t, sh),
                temp_c=_num.arr(temp, sh),
                offset_ppm=_num.arr(y, sh),
            )
        dx = np.asarray(dx_time_units, dtype=np.int64)
        stamp_u, grid, t, temp, y = self._tx(station, dx, tx_antd, dx.shape)
        return TxBatch(
            stamp=self.wrap(stamp_u),
            stamp_unwrapped=np.asarray(stamp_u),
            grid_units=np.asarray(grid),
            t_true_s=np.asarray(t),
            temp_c=np.asarray(temp),
            offset_ppm=np.asarray(y),
        )

    # -- RX -------------------------------------------------------------------------------
    def _power_bias_s(self, hw: _Hardware, p: Num, n: Shape) -> Num:
        b = self.fx_bias
        if not b.enabled:
            return _num.full(n, 0.0)
        m = models._bias_curve_m(
            p - hw.bias_shift_db, b.c0_m, b.amplitude_m, b.centre_dbm, b.width_db, b.slope_m_per_db
        )
        return hw.bias_scale * m / dw1000.C_LIGHT + hw.bias_offset_s

    def power_bias_s(self, station: int, rx_dbm: npt.ArrayLike) -> FloatArray:
        """True power-dependent timestamp error of a station, s, at true RX power (dBm)."""
        p = _f(rx_dbm)
        if not self.fx_bias.enabled:
            return np.zeros(p.shape)
        return np.asarray(self._power_bias_s(self._station(station), p, p.shape))

    def _estimated_dbm(self, p: Num) -> Num:
        e = self.fx_est
        if not e.enabled:
            return _num.copy(p)
        return models._estimated_level_dbm(p, e.knee_dbm, e.knee_width_db, e.high_slope)

    def estimated_dbm(self, rx_dbm: npt.ArrayLike) -> FloatArray:
        """The chip's noiseless RX level estimate, dBm, at true RX power (rx_power_estimate)."""
        return np.asarray(self._estimated_dbm(_f(rx_dbm)))

    def car_int_power_error_ppm(self, station: int, rx_dbm: npt.ArrayLike) -> FloatArray:
        """Noiseless power-dependent error of a station's carrier integrator, ppm."""
        c = self.fx_car
        p = _f(rx_dbm)
        if not c.enabled:
            return np.zeros(p.shape)
        return np.asarray(self._station(station).car_k * (p - c.ref_dbm))

    def _rx(
        self,
        tx: int,
        rx: int,
        t_tx: Num,
        octet: Any,
        distance_m: Num | None,
        gap_s: Num | None,
        rx_antd: int | None,
        y_tx: Num | None,
        n: Shape,
    ) -> tuple[Any, dict[str, Any], Num, Num, Num, Num, Num, Num, Num, Num, Num]:
        """The reception model, once for a frame (floats, ``n`` None) and for arrays of shape ``n``:
        (RX_STAMP unwrapped, registers, arrival, rx_dbm, est_dbm, bias, error, offset, temp,
        distance, tof). Random draws in a fixed order (multipath, noise, estimate, registers)."""
        hw = self._station(rx)
        rx_dbm, tof, dist = self._propagation(tx, rx, octet, distance_m, n)
        rng = self.rng
        late = None
        t_arr = t_tx + tof
        if self._mp_on:
            late = _num.uniform(rng, n) < self.fx_mp.probability
            extra = _num.where(late, _num.exponential(rng, self._mp_scale, n), 0.0)
            t_arr = t_arr + extra
        local, y_rx, temp = self.clocks[rx]._state(t_arr)
        bias = self._power_bias_s(hw, rx_dbm, n)
        err = _num.copy(bias)
        const = hw.rx_err0_s
        if rx_antd is not None:
            const += (hw.rx_antd - int(rx_antd)) * TU
        if const:
            err += const
        drift = self._delay_drift_s(temp)
        if drift is not None:
            err += drift
        if self.fx_interf.enabled and gap_s is not None:
            err += models._interference_shift_s(gap_s, self.fx_interf.amplitude_ps, self.fx_interf.tau_s)
        tn = self.fx_noise
        if tn.enabled:
            sigma = models._timestamp_sigma_s(rx_dbm, tn.floor_ps, tn.snr_ps, tn.ref_dbm)
            if hw.noise_scale != 1.0:  # this receiver's jitter scale (Station.noise_scale)
                sigma = sigma * hw.noise_scale
            err += _num.normal(rng, n) * sigma
        exact = (local + err) * _INV_TU
        q = _num.floor(exact) if self._quant_on else _num.rint(exact)
        stamp_u = _num.to_int(q)
        frac = exact - (q if self._quant_on else _num.floor(exact))
        if y_tx is None:
            y_tx = self.clocks[tx]._state(t_tx)[1]
        offset = ((1.0 + 1e-6 * y_rx) / (1.0 + 1e-6 * y_tx) - 1.0) * 1e6
        est = self._estimated_dbm(rx_dbm)
        if self._est_noise:
            est += _num.normal(rng, n) * self.fx_est.noise_db
        regs = self._registers(hw, est, rx_dbm, offset, frac, late, n)
        return stamp_u, regs, t_arr, rx_dbm, est, bias, err, offset, temp, dist, tof

    def receive(
        self,
        tx: int,
        rx: int,
        t_tx_s: npt.ArrayLike,
        gain_octet: npt.ArrayLike,
        distance_m: npt.ArrayLike | None = None,
        gap_s: npt.ArrayLike | None = None,
        rx_antd: int | None = None,
        tx_offset_ppm: npt.ArrayLike | None = None,
    ) -> RxBatch:
        """Receptions at ``rx`` of frames that left ``tx``'s antenna at true times ``t_tx_s``.

        ``gain_octet`` TX_POWER octet per frame, ``distance_m`` per-frame distance (default the
        scenario's), ``gap_s`` time since the previous reception at ``rx`` (interference;
        None or inf: none), ``rx_antd`` the programmed RX antenna delay register (default the
        station's), ``tx_offset_ppm`` the TX clock's offset at departure if known
        (:attr:`TxBatch.offset_ppm`; else evaluated). Returns RX_STAMP, registers and truth.
        """
        one = _num.one(t_tx_s)
        if one is not None:  # one frame: evaluate on floats
            o = _num.one_int(gain_octet)
            d = None if distance_m is None else _num.one(distance_m)
            g = None if gap_s is None else _num.one(gap_s)
            y = None if tx_offset_ppm is None else _num.one(tx_offset_ppm)
            if not (o is None or (distance_m is not None and d is None) or (gap_s is not None and g is None)
                    or (tx_offset_ppm is not None and y is None)):
                r = self._rx(tx, rx, one[0], o[0], None if d is None else d[0], None if g is None else g[0],
                             rx_antd, None if y is None else y[0], None)
                return self._rx_batch(r, one[1])
        t_tx = _f(t_tx_s)
        n = t_tx.shape
        octet = np.broadcast_to(np.asarray(gain_octet, dtype=np.int64), n)
        dist = None if distance_m is None else _f(distance_m)
        if dist is not None and (dist.ndim == 0 or dist.shape != n):
            dist = np.broadcast_to(dist, n)
        stamp_u, regs, t_arr, rx_dbm, est, bias, err, offset, temp, d_m, tof = self._rx(
            tx, rx, t_tx, octet, dist, None if gap_s is None else _f(gap_s), rx_antd,
            None if tx_offset_ppm is None else _f(tx_offset_ppm), n,
        )
        return RxBatch(
            stamp=self.wrap(stamp_u),
            stamp_unwrapped=stamp_u,
            regs=regs,
            t_arrival_s=np.asarray(t_arr),
            rx_dbm=np.asarray(rx_dbm),
            est_dbm=np.asarray(est),
            bias_s=np.asarray(bias),
            error_s=np.asarray(err),
            offset_ppm=np.asarray(offset),
            temp_c=np.asarray(temp),
            distance_m=np.asarray(d_m, dtype=np.float64),
            tof_s=np.asarray(tof),
            detected=np.asarray(rx_dbm >= self.radio_sensitivity_dbm),
        )

    def _rx_batch(self, r: tuple[Any, ...], sh: tuple[int, ...]) -> RxBatch:
        """An :class:`RxBatch` of arrays of shape ``sh`` from one frame's values of :meth:`_rx`."""
        stamp_u, regs, t_arr, rx_dbm, est, bias, err, offset, temp, dist, tof = r
        a = _num.arr
        return RxBatch(
            stamp=a(self._wrap(stamp_u), sh),
            stamp_unwrapped=a(stamp_u, sh),
            regs={k: a(v, sh) for k, v in regs.items()},
            t_arrival_s=a(t_arr, sh),
            rx_dbm=a(rx_dbm, sh),
            est_dbm=a(est, sh),
            bias_s=a(bias, sh),
            error_s=a(err, sh),
            offset_ppm=a(offset, sh),
            temp_c=a(temp, sh),
            distance_m=a(float(dist), sh),
            tof_s=a(tof, sh),
            detected=a(bool(rx_dbm >= self.radio_sensitivity_dbm), sh),
        )

    #: Below this true RX power (dBm) a frame is not detected (6.8 Mb/s, 128 preamble, typical).
    radio_sensitivity_dbm = -106.0

    def _registers(
        self,
        hw: _Hardware,
        est: Num,
        rx_dbm: Num,
        offset_ppm: Num,
        frac_units: Num,
        late: Any,
        n: Shape,
    ) -> dict[str, Any]:
        """RX quality registers for estimated levels ``est`` (dBm): dw1000.rx_level_dbm(CIR_PWR,
        RXPACC) reads ``est`` back (to CIR_PWR's rounding), the first-path power is est - fp_delta_db."""
        radio = self.radio
        rng = self.rng
        rxpacc = radio.preamble_length - 4 - _num.integers(rng, 0, 13, n)
        n2 = rxpacc * rxpacc
        lin = _num.exp((est + self._a_dbm) * self._ln10_10)
        lin *= n2
        cir = _num.clip_(_num.rint(lin * 2.0**-17), 1, 0xFFFF)
        if late is not None:
            s_fp = lin * _num.where(late, self._fp_fac_late, self._fp_fac)
        else:
            s_fp = lin * self._fp_fac
        amp = _num.sqrt(s_fp)
        regs: dict[str, Any] = {
            "cir_pwr": _num.to_int(cir),
            "rxpacc": rxpacc,
            "rxpacc_nosat": rxpacc + RXPACC_NOSAT_EXTRA,
        }
        for i, sw in enumerate(self._fp_sqrt, start=1):
            f = _num.minimum_(_num.rint(amp * sw), 0xFFFF)
            regs[f"fp_ampl{i}"] = _num.to_int(f)
        regs["std_noise"] = _num.full_int(n, self._std_noise)
        regs["fp_index"] = _num.to_int(frac_units * 64) + FP_INDEX_NOMINAL * 64
        # carrier integrator: positive = RX clock fast (manual); car_int_to_ppm reads TX-minus-RX
        c = self.fx_car
        tx_minus_rx = -offset_ppm
        if c.enabled:
            tx_minus_rx = tx_minus_rx + hw.car_k * (rx_dbm - c.ref_dbm)
            if c.noise_ppm:
                tx_minus_rx += _num.normal(rng, n) * c.noise_ppm
        car_f = dw1000.ppm_to_car_int(tx_minus_rx, radio.channel, radio.data_rate_kbps)
        car = _num.rint(float(car_f) if n is None else car_f)
        regs["car_int"] = _num.to_int(_num.clip_(car, -(1 << 20), (1 << 20) - 1))
        tt = _num.clip_(_num.rint(offset_ppm * self._ttck_k), -(1 << 18), (1 << 18) - 1)
        regs["ttcko"] = _num.to_int(tt)
        regs["ttcki"] = _num.full_int(n, self._ttcki)
        return regs

    # -- per-frame convenience for the medium ---------------------------------------------
    def transmit(
        self,
        tx: int,
        t_true_s: float,
        gain_octet: int,
        receivers: Iterable[int] | None = None,
        distances_m: Mapping[int, float] | None = None,
        rx_antd: Mapping[int, int] | None = None,
    ) -> dict[int, Reception]:
        """One frame leaving ``tx``'s antenna at true time ``t_true_s`` (s) with a TX_POWER octet:
        its reception at each receiver (default every other station).

        Stateful only in the interference gap: the world remembers each receiver's last
        reception time. Pass ``distances_m`` to override geometry per receiver, ``rx_antd`` for
        the LDE_RXANTD register each receiver's firmware programmed.
        """
        out: dict[int, Reception] = {}
        rxs = self._station(tx).others if receivers is None else receivers
        t = float(t_true_s)
        octet = _num.one_int(gain_octet)
        o = octet[0] if octet is not None else int(np.asarray(gain_octet, dtype=np.int64))
        sens = self.radio_sensitivity_dbm
        for rx in rxs:
            d = None if distances_m is None or rx not in distances_m else float(distances_m[rx])
            t_prev = self._last_rx.get(rx)
            gap = None
            if t_prev is not None:
                path = self._path(tx, rx)
                dist = path.distance_m if d is None else d
                gap = t + dist / path.gap_speed - t_prev
            stamp_u, regs, t_arr, rx_dbm, est, bias, err, offset, temp, dist_m, tof = self._rx(
                tx, rx, t, o, d, gap, None if rx_antd is None else rx_antd.get(rx), None, None
            )
            self._last_rx[rx] = t_arr
            out[rx] = Reception(
                rx_station=rx,
                stamp=int(self._wrap(stamp_u)),
                stamp_unwrapped=int(stamp_u),
                regs={k: int(v) for k, v in regs.items()},
                t_arrival_s=float(t_arr),
                rx_dbm=float(rx_dbm),
                est_dbm=float(est),
                bias_s=float(bias),
                error_s=float(err),
                offset_ppm=float(offset),
                temp_c=float(temp),
                distance_m=float(dist_m),
                detected=bool(rx_dbm >= sens),
                extra={"tof_s": float(tof)},
            )
        return out


def reception_gaps(rx_station: npt.ArrayLike, t_arrival_s: npt.ArrayLike) -> FloatArray:
    """Time since the previous reception at the same station, s (inf for a station's first).

    Vectorised over a whole session: sorts by (station, time), differences within a station.
    """
    st = np.asarray(rx_station, dtype=np.int64)
    t = _f(t_arrival_s)
    order = np.lexsort((t, st))
    ts, ss = t[order], st[order]
    g = np.empty_like(ts)
    if ts.size:
        g[0] = np.inf
        g[1:] = ts[1:] - ts[:-1]
        g[1:][ss[1:] != ss[:-1]] = np.inf
    out = np.empty_like(g)
    out[order] = g
    return out
