"""One station's clock: crystal offset, warm-up, wander and temperature, true <-> local time.

Times: true time in SI seconds since the session start; a station's local time is its
unwrapped system-time counter in seconds. Offsets in ppm (+ = fast). Part of the world model
(:class:`uwbcal.physics.world.World` holds one clock per station).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from uwbcal import dw1000
from uwbcal.physics import _num, models
from uwbcal.physics import effects as fx
from uwbcal.physics._num import Num
from uwbcal.physics.records import FloatArray
from uwbcal.physics.scenario import Scenario, Station

TU = dw1000.TIME_UNIT_S


class StationClock:
    """One station's clock: local(t) = counter0 + tau + 1e-6 * Phi(tau), tau = t - power_on.

    Phi (ppm*s) is the integral of the frequency offset y(u) = ppm + warmup_ppm exp(-u/T_w)
    + warmup2_ppm exp(-u/T_w2) + tempco (T(u) - ref) + wander(u), in closed form (wander: exact
    integral of a linearly interpolated random walk). Before power-on the clock is extrapolated
    at y(0).

    The public methods take and return arrays; :meth:`_state` and :meth:`_true_state` are the
    one implementation, evaluated on a Python float per frame or on an array (uwbcal.physics._num).
    """

    def __init__(self, station: Station, scenario: Scenario, run_seed: int) -> None:
        e = scenario.effects
        self.station_id = station.id
        self.ppm = station.ppm if e["clock_offset"].enabled else 0.0
        self.warm_ppm = station.warmup_ppm if e["warmup"].enabled else 0.0
        self.warm_tau = station.warmup_tau_s
        self.warm2_ppm = station.warmup2_ppm if e["warmup"].enabled else 0.0
        self.warm2_tau = station.warmup2_tau_s
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
        self._warm2_k = -1.0 / self.warm2_tau
        self._warm2_phase = self.warm2_ppm * self.warm2_tau
        self._heat_k = -1.0 / self.heat_tau
        self._amb_ref = self.ambient_c - self.ref_c
        self._tempco_amb = self.tempco * (self.ambient_c - self.ref_c)
        self._half_ramp = 0.5 * self.ramp
        self._inv_h = 1.0 / self.w_h
        self._y0_ppm = self.ppm + self.warm_ppm + self.warm2_ppm + self.tempco * (self.ambient_c - self.ref_c)
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
        tau = (one[0] if one is not None else _num.floats(t_s)) - self.power_on_s
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
        if self.warm2_ppm:
            ex2 = _num.exp(taup * self._warm2_k)
            y += self.warm2_ppm * ex2
            phi += self._warm2_phase * (1.0 - ex2)
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
        return _num.eval3(self._state, t_s)

    def offset_ppm(self, t_s: npt.ArrayLike) -> FloatArray:
        """Frequency offset y of the clock against true time, ppm (+ = fast), at true times t."""
        return self.state(t_s)[1]

    def phase_ppm_s(self, tau: npt.ArrayLike) -> FloatArray:
        """Phi(tau), ppm*s: integral of the frequency offset from power-on (tau = t - power_on)."""
        local = self.state(_num.floats(tau) + self.power_on_s)[0]
        return np.asarray((local - self.counter0_s - _num.floats(tau)) * 1e6)

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
        return _num.eval3(self._true_state, local_s)

    def true_s(self, local_s: npt.ArrayLike) -> FloatArray:
        """Inverse of :meth:`local_s`: true times, s, at which the clock reads ``local_s``."""
        return self.true_state(local_s)[0]
