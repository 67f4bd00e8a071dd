"""Two-way ranging: the paper's TWR with drift and power corrections, and the baselines.

Messages (columns.RANGE): M1 ref->tag (ref TX ``t1r``, tag RX ``t1t``), M2 tag->ref (tag TX ``t2t``,
ref RX ``t2r``), M3 ref->tag (ref TX ``t3r``, tag RX ``t3t``). Differences are modulo 2**40.

The paper's last equation (device units or seconds alike):

    T_TOA = 0.5 (dT12^R - dT12^T - C13^RT / dT13^T (dT12^T + E1) - E2 - E1) + Z

with dT12^R = t2r - t1r, dT12^T = t2t - t1t, dT13^R = t3r - t1r, dT13^T = t3t - t1t,
C13^RT = dT13^R - dT13^T, E1 the tag's timestamp error of M1 and E2 the reference's of M2 (each
from that station's power curve at the measured level) and Z the constant hardware offset.

Derivation with the reference clock as time base, tag clock (1 + eps) t + phi and measured
RX timestamp = true + E: dT12^R = tau12 + tof + E2, dT12^T = (1 + eps)(tau12 - tof) - E1,
dT13^T = (1 + eps) tau13, C13 = -eps tau13, so C13 / dT13^T (dT12^T + E1) = -eps (tau12 - tof) and
the bracket is 2 tof + E1 + E2: T_TOA = tof exactly (E3 = E1 cancels in dT13^T).

Baselines: single-sided TWR 0.5 (Ra - Db) optionally with the carrier-integrator clock
correction, asymmetric double-sided TWR (Ra Rb - Da Db) / (Ra + Rb + Da + Db), and the APS011
fixed range-bias table against RX level (:func:`uwbcal.dw1000.aps011_bias_m`).
"""

from __future__ import annotations

import numpy as np

from uwbcal import dw1000
from uwbcal.dw1000 import ArrayLike, FloatArray


def _d(later: ArrayLike, earlier: ArrayLike) -> FloatArray:
    return dw1000.wrap_diff(later, earlier).astype(np.float64)


def paper_tof_units(t1r: ArrayLike, t1t: ArrayLike, t2t: ArrayLike, t2r: ArrayLike,
                    t3r: ArrayLike | None = None, t3t: ArrayLike | None = None,
                    e1_units: ArrayLike = 0.0, e2_units: ArrayLike = 0.0,
                    drift: bool = True) -> FloatArray:
    """The paper's T_TOA without Z, device units.

    ``e1_units``/``e2_units`` are the power errors E1 (tag, M1) and E2 (reference, M2) in device
    units (0 switches the power correction off). ``drift=False`` drops the C13 term (then M3 is
    not needed).
    """
    r12 = _d(t2r, t1r)
    t12 = _d(t2t, t1t)
    e1 = np.asarray(e1_units, dtype=np.float64)
    e2 = np.asarray(e2_units, dtype=np.float64)
    bracket = r12 - t12 - e2 - e1
    if drift:
        if t3r is None or t3t is None:
            raise ValueError("the drift-corrected TWR needs M3 (t3r, t3t)")
        r13 = _d(t3r, t1r)
        t13 = _d(t3t, t1t)
        bracket = bracket - (r13 - t13) / t13 * (t12 + e1)
    return np.asarray(0.5 * bracket, dtype=np.float64)


def ss_tof_units(t1r: ArrayLike, t1t: ArrayLike, t2t: ArrayLike, t2r: ArrayLike,
                 car_int_r2: ArrayLike | None = None, channel: int = 2,
                 data_rate_kbps: int = 6810) -> FloatArray:
    """Single-sided TWR time of flight, device units: 0.5 (Ra - Db * k).

    Ra = t2r - t1r (reference clock), Db = t2t - t1t (tag clock). Without ``car_int_r2`` k = 1.
    With the reference's DRX_CAR_INT of M2, ppm = car_int_to_ppm(...) is the TX-minus-RX (tag
    minus reference) clock offset (a positive integrator means the receiver runs fast), so a tag
    interval in reference units is Db * (1 - ppm * 1e-6) to first order: k = 1 - ppm * 1e-6, as in
    Decawave's SS-TWR example.
    """
    ra = _d(t2r, t1r)
    db = _d(t2t, t1t)
    if car_int_r2 is None:
        return np.asarray(0.5 * (ra - db), dtype=np.float64)
    ppm = dw1000.car_int_to_ppm(car_int_r2, channel, data_rate_kbps)
    return np.asarray(0.5 * (ra - db * (1.0 - ppm * 1e-6)), dtype=np.float64)


def ds_tof_units(t1r: ArrayLike, t1t: ArrayLike, t2t: ArrayLike, t2r: ArrayLike,
                 t3r: ArrayLike, t3t: ArrayLike) -> FloatArray:
    """Asymmetric double-sided TWR, device units: (Ra Rb - Da Db) / (Ra + Rb + Da + Db).

    Ra = t2r - t1r, Db = t2t - t1t, Rb = t3t - t2t, Da = t3r - t2r.
    """
    ra = _d(t2r, t1r)
    db = _d(t2t, t1t)
    rb = _d(t3t, t2t)
    da = _d(t3r, t2r)
    return np.asarray((ra * rb - da * db) / (ra + rb + da + db), dtype=np.float64)


def aps011_corrected_range_m(range_m: ArrayLike, level_dbm: ArrayLike) -> FloatArray:
    """Range minus the APS011 fixed bias (m) at the given RX level (dBm, PRF 64 MHz)."""
    return np.asarray(np.asarray(range_m, dtype=np.float64) - dw1000.aps011_bias_m(level_dbm),
                      dtype=np.float64)


def units_to_range_m(tof_units: ArrayLike) -> FloatArray:
    """Time of flight in device units to range in metres."""
    return np.asarray(np.asarray(tof_units, dtype=np.float64) * dw1000.METRES_PER_UNIT, dtype=np.float64)


def s_to_units(seconds: ArrayLike) -> FloatArray:
    """Seconds to device units."""
    return np.asarray(np.asarray(seconds, dtype=np.float64) / dw1000.TIME_UNIT_S, dtype=np.float64)
