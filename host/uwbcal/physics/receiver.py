"""Reception: RX power, the power-dependent timestamp bias, the chip's level estimate, every
timestamp error (delays, temperature, interference, noise, multipath), quantisation to
RX_STAMP, and the RX registers; vectorised over a session or per frame. Times s, powers dBm.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from uwbcal import dw1000
from uwbcal.physics import _num, models
from uwbcal.physics._num import Num, Shape
from uwbcal.physics.hardware import StationHardware
from uwbcal.physics.paths import Propagation
from uwbcal.physics.records import FloatArray, RxBatch
from uwbcal.physics.rx_registers import RegisterSynthesis
from uwbcal.physics.world_base import INV_TU, TU


class Receiver(Propagation, RegisterSynthesis):
    """Receptions of frames (:meth:`receive`), once for a frame or for arrays."""

    #: Below this true RX power (dBm) a frame is not detected (6.8 Mb/s, 128 preamble, typical).
    radio_sensitivity_dbm = -106.0

    def _power_bias_s(self, hw: StationHardware, p: Num, n: Shape) -> Num:
        b = self.fx_bias
        if not b.enabled:
            return _num.full(n, 0.0)
        m = models._bias_curve_m(
            p - hw.bias_shift_db, b.c0_m, b.amplitude_m, b.centre_dbm, b.width_db, b.slope_m_per_db
        )
        return hw.bias_scale * m / dw1000.C_LIGHT + hw.bias_offset_s

    def power_bias_s(self, station: int, rx_dbm: npt.ArrayLike) -> FloatArray:
        """True power-dependent timestamp error of a station, s, at true RX power (dBm)."""
        p = _num.floats(rx_dbm)
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
        return np.asarray(self._estimated_dbm(_num.floats(rx_dbm)))

    def car_int_power_error_ppm(self, station: int, rx_dbm: npt.ArrayLike) -> FloatArray:
        """Noiseless power-dependent error of a station's carrier integrator, ppm."""
        c = self.fx_car
        p = _num.floats(rx_dbm)
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
            k = self.fx_mp.excess_shape
            draw = (
                _num.exponential(rng, self._mp_scale, n)
                if k == 1.0
                else _num.gamma(rng, k, self._mp_scale / k, n)
            )
            extra = _num.where(late, draw, 0.0)
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
            draw = _num.normal(rng, n)
            if tn.tail_weight > 0.0:  # Student-t of 1/w dof and SD 1: the normal over sqrt(V / (dof - 2))
                dof = 1.0 / tn.tail_weight  # V chi-square of dof, i.e. gamma(dof / 2, 2)
                draw = draw * _num.sqrt((dof - 2.0) / _num.gamma(rng, 0.5 * dof, 2.0, n))
            err += draw * sigma
        exact = (local + err) * INV_TU
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
        t_tx = _num.floats(t_tx_s)
        n = t_tx.shape
        octet = np.broadcast_to(np.asarray(gain_octet, dtype=np.int64), n)
        dist = None if distance_m is None else _num.floats(distance_m)
        if dist is not None and (dist.ndim == 0 or dist.shape != n):
            dist = np.broadcast_to(dist, n)
        stamp_u, regs, t_arr, rx_dbm, est, bias, err, offset, temp, d_m, tof = self._rx(
            tx, rx, t_tx, octet, dist, None if gap_s is None else _num.floats(gap_s), rx_antd,
            None if tx_offset_ppm is None else _num.floats(tx_offset_ppm), n,
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



def reception_gaps(rx_station: npt.ArrayLike, t_arrival_s: npt.ArrayLike) -> FloatArray:
    """Time since the previous reception at the same station, s (inf for a station's first).

    Vectorised over a whole session: sorts by (station, time), differences within a station.
    """
    st = np.asarray(rx_station, dtype=np.int64)
    t = _num.floats(t_arrival_s)
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
