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

import numpy as np
import numpy.typing as npt

from uwbcal import dw1000
from uwbcal.errors import ScenarioError
from uwbcal.physics import effects as fx
from uwbcal.physics import models
from uwbcal.physics.scenario import Scenario, Station

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

TU = dw1000.TIME_UNIT_S
_MASK40 = dw1000.TIMESTAMP_MOD - 1
#: RX_TTCKI value per PRF (user manual: 0x01F00000 at 16 MHz, 0x01FC0000 at 64 MHz).
TTCKI = {16: 0x01F00000, 64: 0x01FC0000}
#: Nominal first-path index (RX_TIME.FP_INDEX integer part) of a clean reception.
FP_INDEX_NOMINAL = 745
#: RXPACC_NOSAT - RXPACC in simulated records: never equal, so RXPACC needs no SFD correction.
RXPACC_NOSAT_EXTRA = 8


def _f(x: npt.ArrayLike) -> FloatArray:
    return np.asarray(x, dtype=np.float64)


class StationClock:
    """One station's clock: local(t) = counter0 + tau + 1e-6 * Phi(tau), tau = t - power_on.

    Phi (ppm*s) is the integral of the frequency offset y(u) = ppm + warmup_ppm exp(-u/T_w)
    + tempco (T(u) - ref) + wander(u), in closed form (wander: exact integral of a linearly
    interpolated random walk). Before power-on the clock is extrapolated at y(0).
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

    def _wander(self, taup: FloatArray) -> tuple[FloatArray, FloatArray]:
        """(frequency ppm, integral ppm*s) of the wander at tau >= 0 (exact integral of the
        linearly interpolated random walk)."""
        x = taup * (1.0 / self.w_h)
        k = x.astype(np.int64)
        self._extend(int(k.max()) if k.size else 0)
        s = taup - k * self.w_h
        w0 = self._w[k]
        dw = self._dw[k]
        return w0 + dw * s, self._wc[k] + s * (w0 + 0.5 * dw * s)

    # -- frequency and phase --------------------------------------------------------------
    def temperature_c(self, t_s: npt.ArrayLike) -> FloatArray:
        """Station temperature, degC, at true times t (s)."""
        tau = _f(t_s) - self.power_on_s
        return models.heating_c(tau, self.ambient_c, self.heat_c, self.heat_tau, self.ramp)

    def _y0(self) -> float:
        return self.ppm + self.warm_ppm + self.tempco * (self.ambient_c - self.ref_c)

    def state(self, t_s: npt.ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(unwrapped local time s, frequency offset ppm, temperature degC) at true times t (s).

        One evaluation shares the exponentials of warm-up and heating between the phase, the
        frequency and the temperature.
        """
        t = _f(t_s)
        tau = t - self.power_on_s
        taup = np.maximum(tau, 0.0)
        phi = self.ppm * taup
        y = np.full(tau.shape, self.ppm)
        if self.warm_ppm:
            ex = np.exp(taup * (-1.0 / self.warm_tau))
            y += self.warm_ppm * ex
            phi += (self.warm_ppm * self.warm_tau) * (1.0 - ex)
        if self.heat_c or self.ramp:
            eh = np.exp(taup * (-1.0 / self.heat_tau))
            temp = self.ambient_c + self.heat_c * (1.0 - eh) + self.ramp * taup
            if self.tempco:
                y += self.tempco * (temp - self.ref_c)
                phi += self.tempco * (
                    (self.ambient_c - self.ref_c) * taup
                    + self.heat_c * (taup - self.heat_tau * (1.0 - eh))
                    + 0.5 * self.ramp * taup * taup
                )
        else:
            temp = np.full(tau.shape, self.ambient_c)
            if self.tempco:
                y += self.tempco * (self.ambient_c - self.ref_c)
                phi += (self.tempco * (self.ambient_c - self.ref_c)) * taup
        if self.w_sigma:
            wf, wi = self._wander(taup)
            y += wf
            phi += wi
        if tau.size and float(tau.min()) < 0.0:
            phi = phi + self._y0() * np.minimum(tau, 0.0)
        local = (self.counter0_s + tau) + 1e-6 * phi
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

    def true_state(self, local_s: npt.ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Inverse of :meth:`local_s`: (true times s at which the clock reads ``local_s``,
        frequency offset ppm there, temperature degC there). Newton iterations; exact to < 1e-15 s."""
        target = _f(local_s)
        t = self.power_on_s + (target - self.counter0_s) / (1.0 + 1e-6 * self._y0())
        for _ in range(8):
            local, y, temp = self.state(t)
            step = (local - target) / (1.0 + 1e-6 * y)
            t = t - step
            # the residual after a step of size d is about 0.5e-6 |dy/dt| d**2: negligible below 10 us
            if not step.size or float(np.max(np.abs(step))) < 1e-5:
                break
        return np.asarray(t), y, temp

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


class World:
    """A simulated world built from a :class:`Scenario` and a run seed (default: the scenario's)."""

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

    # -- stations and clocks --------------------------------------------------------------
    @property
    def station_ids(self) -> list[int]:
        """Station ids of the scenario."""
        return self.scenario.station_ids

    def clock(self, station: int) -> StationClock:
        """The station's clock; ScenarioError for an unknown id."""
        try:
            return self.clocks[station]
        except KeyError:
            raise ScenarioError(f"no station {station} in scenario {self.scenario.name!r}") from None

    def local_s(self, station: int, t_s: npt.ArrayLike) -> FloatArray:
        """Unwrapped local time of a station, s, at true times t (s)."""
        return self.clock(station).local_s(t_s)

    def local_units(self, station: int, t_s: npt.ArrayLike) -> FloatArray:
        """Unwrapped local time of a station in device units (unquantised), at true times t (s)."""
        return np.asarray(self.clock(station).local_s(t_s) / TU)

    def system_time(self, station: int, t_s: npt.ArrayLike) -> IntArray:
        """SYS_TIME register value (40 bits, truncated to the unit) at true times t (s)."""
        return np.asarray(np.floor(self.local_units(station, t_s)).astype(np.int64) & _MASK40)

    def true_time_s(self, station: int, local_s: npt.ArrayLike) -> FloatArray:
        """True times, s, at which a station's unwrapped local clock reads ``local_s`` (s)."""
        return self.clock(station).true_s(local_s)

    def true_time_of_units(self, station: int, local_units: npt.ArrayLike) -> FloatArray:
        """True times, s, at which a station's unwrapped counter reads ``local_units``."""
        return self.clock(station).true_s(_f(local_units) * TU)

    def offset_ppm(self, station: int, t_s: npt.ArrayLike) -> FloatArray:
        """Clock frequency offset of a station against true time, ppm (+ = fast)."""
        return self.clock(station).offset_ppm(t_s)

    def temperature_c(self, station: int, t_s: npt.ArrayLike) -> FloatArray:
        """Station temperature, degC, at true times t (s)."""
        return self.clock(station).temperature_c(t_s)

    def wrap(self, units: npt.ArrayLike) -> IntArray:
        """Timestamps as recorded: modulo 2**40 if timestamp_wrap is on, else unchanged."""
        u = np.asarray(units, dtype=np.int64)
        return np.asarray(u & _MASK40) if self.scenario.effects["timestamp_wrap"].enabled else u

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
        return np.asarray(self.scenario.station(station).tx_ref_dbm + self.tx_gain_db(station, gain_octet))

    # -- propagation ----------------------------------------------------------------------
    def nominal_distance_m(self, a: int, b: int) -> float:
        """Scenario distance between two stations (link length or geometry), m."""
        return self.scenario.distance_m(a, b)

    def propagation(
        self, tx: int, rx: int, gain_octet: npt.ArrayLike, distance_m: npt.ArrayLike | None = None
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(true RX power dBm, time of flight s, distance m) of frames from tx to rx.

        ``distance_m`` overrides the scenario geometry (a schedule's tag positions). Air: Friis
        at the channel frequency plus antenna gains minus the link's extra loss; cable: fixed
        attenuation, delay length / (velocity_factor c).
        """
        link = self.scenario.link(tx, rx)
        p_tx = self.tx_power_dbm(tx, gain_octet)
        d = _f(self.nominal_distance_m(tx, rx) if distance_m is None else distance_m)
        d = np.broadcast_to(d, p_tx.shape) if d.ndim == 0 or d.shape != p_tx.shape else d
        if link.kind == "cable":
            return (
                np.asarray(p_tx - link.attenuation_db),
                np.asarray(d / (link.velocity_factor * dw1000.C_LIGHT)),
                np.asarray(d, dtype=np.float64),
            )
        pl = self.fx_path
        d_loss = d if pl.enabled else np.full(d.shape, pl.ref_distance_m)
        gains = self.scenario.station(tx).antenna_gain_dbi + self.scenario.station(rx).antenna_gain_dbi
        loss = models.friis_loss_db(d_loss, self.radio.freq_hz, pl.exponent)
        return (
            np.asarray(p_tx + gains - link.extra_loss_db - loss),
            np.asarray(d / dw1000.C_LIGHT),
            np.asarray(d, dtype=np.float64),
        )

    # -- TX -------------------------------------------------------------------------------
    def _delay_drift_s(self, temp_c: FloatArray) -> FloatArray | None:
        """Change of one hardware delay (TX or RX), s, at a station temperature (temperature effect)."""
        if not self.fx_temp.enabled or not self.fx_temp.range_drift_m_per_c:
            return None
        per_c = self.fx_temp.range_drift_m_per_c / dw1000.C_LIGHT / 2.0
        return np.asarray(per_c * (temp_c - self.fx_temp.ref_c))

    def delayed_tx(self, station: int, dx_time_units: npt.ArrayLike, tx_antd: int | None = None) -> TxBatch:
        """Delayed transmissions programmed at unwrapped local ``dx_time_units`` (DX_TIME).

        The frame starts at DX_TIME with the low 9 bits cleared (delayed_tx_grid); TX_STAMP is
        that plus TX_ANTD (``tx_antd`` register value, default the station's); the frame leaves
        the antenna at that grid time plus the true TX delay (antenna_delay, temperature) and
        TX jitter, converted to true time through the station's clock.
        """
        st = self.scenario.station(station)
        e = self.scenario.effects
        dx = np.asarray(dx_time_units, dtype=np.int64)
        grid = dx & ~np.int64(dw1000.DELAYED_TX_GRID - 1) if e["delayed_tx_grid"].enabled else dx
        antd = st.tx_antd if tx_antd is None else int(tx_antd)
        stamp_u = grid + antd
        true_delay_units = st.tx_antd + (
            st.tx_delay_error_ps * 1e-12 / TU if e["antenna_delay"].enabled else 0.0
        )
        clock = self.clock(station)
        t, y, temp = clock.true_state((grid + true_delay_units) * TU)
        drift = self._delay_drift_s(temp)
        if drift is not None:
            t += drift
        if self.fx_noise.enabled and self.fx_noise.tx_jitter_ps:
            t += self.rng.standard_normal(t.shape) * (self.fx_noise.tx_jitter_ps * 1e-12)
        return TxBatch(
            stamp=self.wrap(stamp_u),
            stamp_unwrapped=np.asarray(stamp_u),
            grid_units=np.asarray(grid),
            t_true_s=np.asarray(t),
            temp_c=temp,
            offset_ppm=y,
        )

    # -- RX -------------------------------------------------------------------------------
    def power_bias_s(self, station: int, rx_dbm: npt.ArrayLike) -> FloatArray:
        """True power-dependent timestamp error of a station, s, at true RX power (dBm)."""
        b = self.fx_bias
        p = _f(rx_dbm)
        if not b.enabled:
            return np.zeros(p.shape)
        st = self.scenario.station(station)
        m = models.bias_curve_m(
            p - st.bias_shift_db, b.c0_m, b.amplitude_m, b.centre_dbm, b.width_db, b.slope_m_per_db
        )
        return np.asarray(st.bias_scale * m / dw1000.C_LIGHT + st.bias_offset_ps * 1e-12)

    def estimated_dbm(self, rx_dbm: npt.ArrayLike) -> FloatArray:
        """The chip's noiseless RX level estimate, dBm, at true RX power (rx_power_estimate)."""
        e = self.fx_est
        if not e.enabled:
            return _f(rx_dbm).copy()
        return models.estimated_level_dbm(rx_dbm, e.knee_dbm, e.knee_width_db, e.high_slope)

    def car_int_power_error_ppm(self, station: int, rx_dbm: npt.ArrayLike) -> FloatArray:
        """Noiseless power-dependent error of a station's carrier integrator, ppm."""
        c = self.fx_car
        p = _f(rx_dbm)
        if not c.enabled:
            return np.zeros(p.shape)
        st = self.scenario.station(station)
        return np.asarray(st.car_int_scale * c.slope_ppm_per_db * (p - c.ref_dbm))

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
        e = self.scenario.effects
        st_rx = self.scenario.station(rx)
        t_tx = _f(t_tx_s)
        n = t_tx.shape
        octet = np.broadcast_to(np.asarray(gain_octet, dtype=np.int64), n)
        rx_dbm, tof, dist = self.propagation(tx, rx, octet, distance_m)
        rng = self.rng
        mp = self.fx_mp
        late: BoolArray | None = None
        t_arr = t_tx + tof
        if mp.enabled and mp.probability > 0:
            late = rng.random(n) < mp.probability
            extra = np.where(late, rng.exponential(mp.mean_bias_m / dw1000.C_LIGHT, n), 0.0)
            t_arr = t_arr + extra
        local, y_rx, temp = self.clock(rx).state(t_arr)
        bias = self.power_bias_s(rx, rx_dbm)
        err = bias.copy()
        const = 0.0
        if e["antenna_delay"].enabled and st_rx.rx_delay_error_ps:
            const += st_rx.rx_delay_error_ps * 1e-12
        if rx_antd is not None:
            const += (st_rx.rx_antd - int(rx_antd)) * TU
        if const:
            err += const
        drift = self._delay_drift_s(temp)
        if drift is not None:
            err += drift
        if self.fx_interf.enabled and gap_s is not None:
            err += models.interference_shift_s(gap_s, self.fx_interf.amplitude_ps, self.fx_interf.tau_s)
        tn = self.fx_noise
        if tn.enabled:
            sigma = models.timestamp_sigma_s(rx_dbm, tn.floor_ps, tn.snr_ps, tn.ref_dbm)
            if st_rx.noise_scale != 1.0:  # this receiver's jitter scale (Station.noise_scale)
                sigma = sigma * st_rx.noise_scale
            err += rng.standard_normal(n) * sigma
        exact = (local + err) * (1.0 / TU)
        q = np.floor(exact) if e["quantisation"].enabled else np.rint(exact)
        stamp_u = q.astype(np.int64)
        frac = exact - (q if e["quantisation"].enabled else np.floor(exact))
        y_tx = self.clock(tx).offset_ppm(t_tx) if tx_offset_ppm is None else _f(tx_offset_ppm)
        offset = ((1.0 + 1e-6 * y_rx) / (1.0 + 1e-6 * y_tx) - 1.0) * 1e6
        est = self.estimated_dbm(rx_dbm)
        fe = self.fx_est
        if fe.enabled and fe.noise_db:
            est += rng.standard_normal(n) * fe.noise_db
        regs = self._registers(rx, est, rx_dbm, offset, frac, late)
        return RxBatch(
            stamp=self.wrap(stamp_u),
            stamp_unwrapped=stamp_u,
            regs=regs,
            t_arrival_s=np.asarray(t_arr),
            rx_dbm=rx_dbm,
            est_dbm=np.asarray(est),
            bias_s=bias,
            error_s=np.asarray(err),
            offset_ppm=np.asarray(offset),
            temp_c=temp,
            distance_m=dist,
            tof_s=tof,
            detected=np.asarray(rx_dbm >= self.radio_sensitivity_dbm),
        )

    #: Below this true RX power (dBm) a frame is not detected (6.8 Mb/s, 128 preamble, typical).
    radio_sensitivity_dbm = -106.0

    def _registers(
        self,
        rx: int,
        est: FloatArray,
        rx_dbm: FloatArray,
        offset_ppm: FloatArray,
        frac_units: FloatArray,
        late: BoolArray | None,
    ) -> dict[str, IntArray]:
        """RX quality registers for estimated levels ``est`` (dBm): dw1000.rx_level_dbm(CIR_PWR,
        RXPACC) reads ``est`` back (to CIR_PWR's rounding), the first-path power is est - fp_delta_db."""
        n = est.shape
        radio = self.radio
        a = dw1000.RX_LEVEL_A_DBM[radio.prf_mhz]
        rng = self.rng
        rxpacc = radio.preamble_length - 4 - rng.integers(0, 13, n)
        n2 = rxpacc * rxpacc
        lin = np.exp((est + a) * (np.log(10.0) / 10.0))
        lin *= n2
        cir = np.rint(lin * 2.0**-17)
        np.clip(cir, 1, 0xFFFF, out=cir)
        fe = self.fx_est
        fp_fac = 10.0 ** (-(fe.fp_delta_db if fe.enabled else 0.0) / 10.0)
        if late is not None:
            s_fp = lin * np.where(late, fp_fac * 10.0 ** (-self.fx_mp.fp_drop_db / 10.0), fp_fac)
        else:
            s_fp = lin * fp_fac
        amp = np.sqrt(s_fp)
        regs: dict[str, IntArray] = {
            "cir_pwr": cir.astype(np.int64),
            "rxpacc": rxpacc,
            "rxpacc_nosat": rxpacc + RXPACC_NOSAT_EXTRA,
        }
        for i, w in enumerate(models.FP_SPLIT, start=1):
            f = np.rint(amp * np.sqrt(w))
            np.minimum(f, 0xFFFF, out=f)
            regs[f"fp_ampl{i}"] = f.astype(np.int64)
        regs["std_noise"] = np.full(n, int(round(fe.std_noise)), dtype=np.int64)
        regs["fp_index"] = (frac_units * 64).astype(np.int64) + FP_INDEX_NOMINAL * 64
        # carrier integrator: positive = RX clock fast (manual); car_int_to_ppm reads TX-minus-RX
        c = self.fx_car
        tx_minus_rx = -offset_ppm
        if c.enabled:
            tx_minus_rx = tx_minus_rx + self.car_int_power_error_ppm(rx, rx_dbm)
            if c.noise_ppm:
                tx_minus_rx += rng.standard_normal(n) * c.noise_ppm
        car = np.rint(dw1000.ppm_to_car_int(tx_minus_rx, radio.channel, radio.data_rate_kbps))
        np.clip(car, -(1 << 20), (1 << 20) - 1, out=car)
        regs["car_int"] = car.astype(np.int64)
        ttcki = TTCKI[radio.prf_mhz]
        tt = np.rint(offset_ppm * (-1e-6 * ttcki))
        np.clip(tt, -(1 << 18), (1 << 18) - 1, out=tt)
        regs["ttcko"] = tt.astype(np.int64)
        regs["ttcki"] = np.full(n, ttcki, dtype=np.int64)
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
        rxs = [s for s in self.station_ids if s != tx] if receivers is None else list(receivers)
        for rx in rxs:
            d = None if distances_m is None or rx not in distances_m else distances_m[rx]
            t_prev = self._last_rx.get(rx)
            gap = None
            if t_prev is not None:
                link = self.scenario.link(tx, rx)
                dist = self.nominal_distance_m(tx, rx) if d is None else d
                speed = dw1000.C_LIGHT * (link.velocity_factor if link.kind == "cable" else 1.0)
                gap = np.asarray([t_true_s + dist / speed - t_prev])
            b = self.receive(
                tx,
                rx,
                np.asarray([t_true_s]),
                np.asarray([gain_octet]),
                None if d is None else [d],
                gap,
                None if rx_antd is None else rx_antd.get(rx),
            )
            self._last_rx[rx] = float(b.t_arrival_s[0])
            out[rx] = Reception(
                rx_station=rx,
                stamp=int(b.stamp[0]),
                stamp_unwrapped=int(b.stamp_unwrapped[0]),
                regs={k: int(v[0]) for k, v in b.regs.items()},
                t_arrival_s=float(b.t_arrival_s[0]),
                rx_dbm=float(b.rx_dbm[0]),
                est_dbm=float(b.est_dbm[0]),
                bias_s=float(b.bias_s[0]),
                error_s=float(b.error_s[0]),
                offset_ppm=float(b.offset_ppm[0]),
                temp_c=float(b.temp_c[0]),
                distance_m=float(b.distance_m[0]),
                detected=bool(b.detected[0]),
                extra={"tof_s": float(b.tof_s[0])},
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
