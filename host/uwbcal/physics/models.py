"""Closed-form physical models behind the effects (pure, vectorised functions).

Every public function takes numpy arrays (or scalars) and returns float64 arrays. Units are in
the names: ``_s`` seconds, ``_dbm`` dBm, ``_db`` dB, ``_m`` metres, ``_hz`` hertz, ``_ppm`` parts
per million. Sources are in :mod:`uwbcal.physics.effects`.

The formulas the world evaluates per frame are written once, in the underscored forms
(``_friis_loss_db`` ...), which take a Python float or a float64 array and return the same
kind with identical bits (rules in :mod:`uwbcal.physics._num`); the public functions wrap them.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from uwbcal import dw1000
from uwbcal.physics import _num
from uwbcal.physics._num import Num

FloatArray = npt.NDArray[np.float64]

#: Weights of FP_AMPL1..3 in the first-path power (squared amplitudes, sum 1): a fixed,
#: plausible split; only their sum enters dw1000.fp_power_dbm.
FP_SPLIT = (0.45, 0.35, 0.20)


def friis_loss_db(distance_m: npt.ArrayLike, freq_hz: float, exponent: float = 2.0) -> FloatArray:
    """Free-space path loss, dB: 10 * exponent * log10(4 pi d f / c) (Friis for exponent 2)."""
    return np.asarray(_friis_loss_db(np.asarray(distance_m, dtype=np.float64), freq_hz, exponent))


def _friis_loss_db(d: Num, freq_hz: float, exponent: float) -> Num:
    """:func:`friis_loss_db` of a float or a float64 array."""
    return 10.0 * exponent * _num.log10(4.0 * np.pi * d * freq_hz / dw1000.C_LIGHT)


def bias_curve_m(
    level_dbm: npt.ArrayLike,
    c0_m: float,
    amplitude_m: float,
    centre_dbm: float,
    width_db: float,
    slope_m_per_db: float,
) -> FloatArray:
    """Range bias, m, at true RX level (dBm): c0 + a tanh((p0 - P)/w) + s (p0 - P).

    With the PowerBias defaults this is a least-squares fit to APS011 (dw1000.aps011_bias_m).
    Positive = range too long (late timestamps); decreasing in power.
    """
    lv = np.asarray(level_dbm, dtype=np.float64)
    return np.asarray(_bias_curve_m(lv, c0_m, amplitude_m, centre_dbm, width_db, slope_m_per_db))


def _bias_curve_m(
    level_dbm: Num, c0_m: float, amplitude_m: float, centre_dbm: float, width_db: float, slope_m_per_db: float
) -> Num:
    """:func:`bias_curve_m` of a float or a float64 array."""
    x = centre_dbm - level_dbm
    return c0_m + amplitude_m * _num.tanh(x / width_db) + slope_m_per_db * x


def estimated_level_dbm(
    true_dbm: npt.ArrayLike, knee_dbm: float, knee_width_db: float, high_slope: float
) -> FloatArray:
    """The chip's RX level estimate without noise, dBm: P - (1-k) w ln(1 + exp((P - knee)/w)).

    Slope 1 far below the knee, ``high_slope`` (k) far above; strictly increasing for k > 0.
    """
    p = np.asarray(true_dbm, dtype=np.float64)
    return np.asarray(_estimated_level_dbm(p, knee_dbm, knee_width_db, high_slope))


def _estimated_level_dbm(p: Num, knee_dbm: float, knee_width_db: float, high_slope: float) -> Num:
    """:func:`estimated_level_dbm` of a float or a float64 array."""
    return p - (1.0 - high_slope) * knee_width_db * _num.logaddexp0((p - knee_dbm) / knee_width_db)


def true_level_dbm(
    est_dbm: npt.ArrayLike, knee_dbm: float, knee_width_db: float, high_slope: float
) -> FloatArray:
    """Inverse of :func:`estimated_level_dbm` (Newton iterations, to < 1e-9 dB)."""
    e = np.asarray(est_dbm, dtype=np.float64)
    p = e.copy()
    # a good start: where the estimate is far above the knee, invert the asymptote
    hi = e > knee_dbm
    p = np.where(hi, knee_dbm + (e - knee_dbm) / high_slope, p)
    for _ in range(60):
        f = estimated_level_dbm(p, knee_dbm, knee_width_db, high_slope) - e
        sig = 1.0 / (1.0 + np.exp(-(p - knee_dbm) / knee_width_db))
        p = p - f / (1.0 - (1.0 - high_slope) * sig)
        if np.all(np.abs(f) < 1e-10):
            break
    return np.asarray(p)


def interference_shift_s(gap_s: npt.ArrayLike, amplitude_ps: float, tau_s: float) -> FloatArray:
    """Timestamp shift, s, of a reception ``gap_s`` after the previous one: A exp(-gap/tau).

    A gap of +inf or NaN (no previous reception) gives 0.
    """
    return np.asarray(_interference_shift_s(np.asarray(gap_s, dtype=np.float64), amplitude_ps, tau_s))


def _interference_shift_s(g: Num, amplitude_ps: float, tau_s: float) -> Num:
    """:func:`interference_shift_s` of a float or a float64 array."""
    return amplitude_ps * 1e-12 * _num.exp_quiet(-_num.isnan_to_inf(g) / tau_s)


def timestamp_sigma_s(rx_dbm: npt.ArrayLike, floor_ps: float, snr_ps: float, ref_dbm: float) -> FloatArray:
    """RX timestamp jitter, s: sqrt(floor**2 + (snr * 10**((ref - P)/20))**2)."""
    return np.asarray(_timestamp_sigma_s(np.asarray(rx_dbm, dtype=np.float64), floor_ps, snr_ps, ref_dbm))


def _timestamp_sigma_s(p: Num, floor_ps: float, snr_ps: float, ref_dbm: float) -> Num:
    """:func:`timestamp_sigma_s` of a float or a float64 array (``low * low``: numpy's ``low**2``)."""
    low = snr_ps * _num.power(10.0, (ref_dbm - p) / 20.0)
    return 1e-12 * _num.sqrt(floor_ps**2 + low * low)


def warmup_phase_ppm_s(tau_s: npt.ArrayLike, warmup_ppm: float, warmup_tau_s: float) -> FloatArray:
    """Integral over [0, tau] of warmup_ppm * exp(-u / T), ppm*s: warmup_ppm T (1 - exp(-tau/T))."""
    t = np.asarray(tau_s, dtype=np.float64)
    return np.asarray(warmup_ppm * warmup_tau_s * -np.expm1(-t / warmup_tau_s))


def heating_c(
    tau_s: npt.ArrayLike, ambient_c: float, self_heating_c: float, heating_tau_s: float, ramp_c_per_s: float
) -> FloatArray:
    """Temperature, degC, tau s after power-on: ambient + heat (1 - exp(-tau/T)) + ramp tau (tau >= 0)."""
    t = np.asarray(tau_s, dtype=np.float64)
    return np.asarray(_heating_c(t, ambient_c, self_heating_c, heating_tau_s, ramp_c_per_s))


def _heating_c(
    tau_s: Num, ambient_c: float, self_heating_c: float, heating_tau_s: float, ramp_c_per_s: float
) -> Num:
    """:func:`heating_c` of a float or a float64 array."""
    t = _num.maximum0(tau_s)
    return ambient_c + self_heating_c * -_num.expm1(-t / heating_tau_s) + ramp_c_per_s * t


def heating_integral_c_s(
    tau_s: npt.ArrayLike,
    ambient_c: float,
    self_heating_c: float,
    heating_tau_s: float,
    ramp_c_per_s: float,
    ref_c: float,
) -> FloatArray:
    """Integral over [0, tau] of (T(u) - ref), degC*s, in closed form (tau >= 0)."""
    t = np.maximum(np.asarray(tau_s, dtype=np.float64), 0.0)
    return np.asarray(
        (ambient_c - ref_c) * t
        + self_heating_c * (t + heating_tau_s * np.expm1(-t / heating_tau_s))
        + 0.5 * ramp_c_per_s * t * t
    )
