"""Departures from the believed world in forms of their own, for blind validation of `uwbcal gap`.

Written apart from the physics catalogue (this module imports nothing from
:mod:`uwbcal.physics` or :mod:`uwbcal.gap.model`; only chip constants from :mod:`uwbcal.dw1000`),
so the diagnosis cannot recognise its own functions: each departure has another functional form
and other parameters than the catalogue effect it stands for.

Every function takes triplet records (``dict`` of column arrays, the session layout) and returns
new records; timestamps are changed in whole device units (15.65 ps), RX levels through the
registers (CIR_PWR scaled, so the level the chip reports moves). Forms:

- clock (:func:`clock_departure`): a station's frequency departs from the believed one by
  ``dfreq(t)`` ppm, with ``two_time_constants`` (a warm-up of two exponentials, not the
  catalogue's one), ``wander_ou`` (a sum of two Ornstein-Uhlenbeck processes with Laplace
  innovations, not a Gaussian random walk), ``constant`` (an offset), and the decoys
  ``freq_step`` (a step at one moment) and ``cycle`` (a sinusoidal temperature cycle);
- noise: :func:`extra_jitter` (Student-t, 5 degrees of freedom, on all receivers or one, or in
  a time window of one direction: the burst decoy);
- NLOS: :func:`late_paths` (each reception late with probability p by a log-normal excess path,
  not the catalogue's exponential);
- power (sweeps with RX registers): :func:`level_bias` (a tanh-shaped timestamp bias against the
  reported P2 level), :func:`level_saturation` (reported levels compress above a knee with a
  slope of their own), :func:`step_gain_errors` (every gain step's real power off by its own
  error, level and bias together);
- decoy :func:`p3_drift` (P3's RX stamp drifts slowly: outside every catalogue effect).

What these forms cannot check: departures the simulator's own base already shares (a null is
the believed scenario simulated by the project's simulator, the only way a null is a null).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from uwbcal.dw1000 import (
    METRES_PER_UNIT,
    TIME_UNIT_S,
    TIMESTAMP_MOD,
    ppm_to_car_int,
    rx_level_dbm,
    wrap_diff,
)

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
Rec = dict[str, Any]
#: Frequency departure of a clock, ppm, as a function of time (s, array in, array out).
FreqFn = Callable[[FloatArray], FloatArray]

RX: Final = ("rx1", "rx2", "rx3")


def _copy(rec: Mapping[str, Any]) -> Rec:
    return {k: (None if v is None else np.array(v, copy=True)) for k, v in rec.items()}


def message_times(rec: Mapping[str, Any]) -> FloatArray:
    """(n, 3) approximate times (s) of P1, P2, P3 of every record, on the session's time axis."""
    t = np.asarray(rec["t_s"], np.float64)
    d12 = wrap_diff(np.asarray(rec["tx2"], np.int64), np.asarray(rec["tx1"], np.int64)) * TIME_UNIT_S
    d13 = wrap_diff(np.asarray(rec["tx3"], np.int64), np.asarray(rec["tx1"], np.int64)) * TIME_UNIT_S
    return np.stack([t, t + d12, t + d13], axis=1)


def _shift(rec: Rec, col: str, units: npt.ArrayLike, mask: npt.NDArray[np.bool_] | None = None) -> None:
    """Add whole device units to a timestamp column (kept modulo 2**40 when it was raw 40-bit)."""
    old = np.asarray(rec[col], np.int64)
    add = np.rint(np.asarray(units, np.float64)).astype(np.int64)
    if mask is not None:
        add = np.where(mask, add, 0)
    new = old + add
    rec[col] = new % TIMESTAMP_MOD if np.all(old < TIMESTAMP_MOD) else new


# --- clock ----------------------------------------------------------------------------------


def two_time_constants(a1_ppm: float, tau1_s: float, a2_ppm: float, tau2_s: float, t0_s: float) -> FreqFn:
    """Warm-up of two exponentials: a1 exp(-(t+t0)/tau1) + a2 exp(-(t+t0)/tau2), ppm."""
    return lambda t: a1_ppm * np.exp(-(t + t0_s) / tau1_s) + a2_ppm * np.exp(-(t + t0_s) / tau2_s)


def constant(ppm: float) -> FreqFn:
    """A constant frequency offset, ppm."""
    return lambda t: np.full(np.shape(t), ppm)


def freq_step(ppm: float, at_s: float) -> FreqFn:
    """DECOY (no catalogue effect): the frequency jumps by ``ppm`` at ``at_s``."""
    return lambda t: np.where(t >= at_s, ppm, 0.0)


def cycle(amplitude_ppm: float, period_s: float, phase: float) -> FreqFn:
    """DECOY (no catalogue effect): a sinusoidal frequency cycle (an air-conditioner cycle)."""
    return lambda t: amplitude_ppm * np.sin(2 * np.pi * t / period_s + phase)


def wander_ou(
    rng: np.random.Generator,
    sigma_ppm: float,
    taus_s: tuple[float, float],
    t_end_s: float,
    dt_s: float = 0.05,
) -> FreqFn:
    """Frequency wander: sum of two Ornstein-Uhlenbeck processes (time constants ``taus_s``) with
    Laplace innovations, each with stationary SD ``sigma_ppm`` / sqrt(2), tabulated every ``dt_s``."""
    n = int(np.ceil(t_end_s / dt_s)) + 2
    grid = np.arange(n) * dt_s
    total = np.zeros(n)
    for tau in taus_s:
        a = np.exp(-dt_s / tau)
        sd = sigma_ppm / np.sqrt(2.0)
        innov = rng.laplace(0.0, sd * np.sqrt(1 - a * a) / np.sqrt(2.0), n)
        x = np.zeros(n)
        x[0] = rng.normal(0.0, sd)
        for i in range(1, n):
            x[i] = a * x[i - 1] + innov[i]
        total += x - x[0]
    return lambda t: np.interp(t, grid, total)


def clock_departure(rec: Mapping[str, Any], station: int, dfreq: FreqFn, dt_s: float = 0.01) -> Rec:
    """Records as if ``station``'s clock ran ``dfreq(t)`` ppm off the believed one.

    The station's phase departure is phi(t) = integral of dfreq, 1e-6 s per s. Its RX stamps move
    by +phi; its TX stamps are programmed on its own clock (delayed TX), so the real emission
    moves instead and the receivers' stamps move by -phi. The carrier integrator of P1
    (``car_int1``, where recorded) measures the carrier's frequency offset, so it follows the
    departure too: it moves by the change of the triplet's P1-to-P3 clock rate, with the
    register's sign (a receiver running faster reads a lower transmitter-minus-receiver offset).
    """
    out = _copy(rec)
    tm = message_times(rec)
    lo, hi = float(np.min(tm)) - 1.0, float(np.max(tm)) + 1.0
    grid = np.arange(lo, hi + dt_s, dt_s)
    f = dfreq(grid) * 1e-6
    phi = np.concatenate([[0.0], np.cumsum(0.5 * (f[1:] + f[:-1]) * dt_s)])
    ph = np.interp(tm, grid, phi) / TIME_UNIT_S  # device units
    rx_is = np.asarray(rec["rx_station"]) == station
    tx_is = np.asarray(rec["tx_station"]) == station
    sign = np.where(rx_is, 1.0, 0.0) - np.where(tx_is, 1.0, 0.0)
    for k, col in enumerate(RX):
        _shift(out, col, sign * ph[:, k])
    ci = rec.get("car_int1")
    if ci is not None:
        d13 = wrap_diff(np.asarray(rec["tx3"], np.int64), np.asarray(rec["tx1"], np.int64)).astype(np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            d_rate_ppm = np.where(d13 > 0, sign * (ph[:, 2] - ph[:, 0]) / d13 * 1e6, 0.0)
        old = np.asarray(ci)
        out["car_int1"] = (old + np.rint(ppm_to_car_int(-d_rate_ppm))).astype(old.dtype)
    return out


# --- noise and late paths -------------------------------------------------------------------


def extra_jitter(
    rec: Mapping[str, Any],
    rng: np.random.Generator,
    scale_ps: float,
    rx_station: int | None = None,
    tx_station: int | None = None,
    window_s: tuple[float, float] | None = None,
) -> Rec:
    """Extra RX timestamp jitter: Student t (5 dof) scaled to SD ``scale_ps``, on the records of
    one receiver / transmitter (None: all) and, if given, only within ``window_s``."""
    out = _copy(rec)
    n = np.asarray(rec["rx1"]).size
    sel = np.ones(n, bool)
    if rx_station is not None:
        sel &= np.asarray(rec["rx_station"]) == rx_station
    if tx_station is not None:
        sel &= np.asarray(rec["tx_station"]) == tx_station
    if window_s is not None:
        t = np.asarray(rec["t_s"], np.float64)
        sel &= (t >= window_s[0]) & (t < window_s[1])
    sd_t5 = np.sqrt(5.0 / 3.0)
    for col in RX:
        noise = rng.standard_t(5, n) / sd_t5 * scale_ps * 1e-12 / TIME_UNIT_S
        _shift(out, col, noise, sel)
    return out


def late_paths(rec: Mapping[str, Any], rng: np.random.Generator, prob: float, median_m: float) -> Rec:
    """Each reception independently late with probability ``prob`` by a log-normal excess path
    (median ``median_m``, log-SD 0.6)."""
    out = _copy(rec)
    n = np.asarray(rec["rx1"]).size
    for col in RX:
        hit = rng.random(n) < prob
        extra_m = median_m * np.exp(0.6 * rng.standard_normal(n))
        _shift(out, col, extra_m / METRES_PER_UNIT, hit)
    return out


# --- power (records with RX registers) ------------------------------------------------------


def reported_level(rec: Mapping[str, Any], k: int) -> FloatArray:
    """The RX level the chip reports for message k (1, 2, 3), dBm."""
    return rx_level_dbm(np.asarray(rec[f"cir_pwr{k}"], np.float64), np.asarray(rec[f"rxpacc{k}"], np.float64))


def _set_level(out: Rec, k: int, delta_db: FloatArray) -> None:
    """Move message k's reported level by ``delta_db`` through CIR_PWR (kept a positive integer)."""
    c = np.asarray(out[f"cir_pwr{k}"], np.float64) * 10.0 ** (np.asarray(delta_db) / 10.0)
    out[f"cir_pwr{k}"] = np.maximum(np.rint(c), 1).astype(np.asarray(out[f"cir_pwr{k}"]).dtype)


def level_bias(rec: Mapping[str, Any], amplitude_m: float, centre_dbm: float, width_db: float) -> Rec:
    """P2's RX stamp biased by amplitude * tanh((L2 - centre) / width) metres of path, L2 the
    reported P2 level (a bias curve of another shape than the catalogue's)."""
    out = _copy(rec)
    lv = reported_level(rec, 2)
    _shift(out, "rx2", amplitude_m * np.tanh((lv - centre_dbm) / width_db) / METRES_PER_UNIT)
    return out


def level_saturation(rec: Mapping[str, Any], knee_dbm: float, slope: float) -> Rec:
    """Reported levels compress above ``knee_dbm``: L' = knee + slope (L - knee) (all three messages)."""
    out = _copy(rec)
    for k in (1, 2, 3):
        lv = reported_level(rec, k)
        new = np.where(lv > knee_dbm, knee_dbm + slope * (lv - knee_dbm), lv)
        _set_level(out, k, new - lv)
    return out


def step_gain_errors(
    rec: Mapping[str, Any], rng: np.random.Generator, sd_db: float, bias_m_per_db: float
) -> Rec:
    """Every gain step's real P2 power off by its own error e_s ~ N(0, sd_db) (the steps are not
    uniform): P2's reported level moves by e_s and its stamp by ``bias_m_per_db`` * e_s metres."""
    out = _copy(rec)
    step = np.asarray(rec["step"], np.int64)
    steps = np.unique(step)
    err = dict(zip(steps.tolist(), rng.normal(0.0, sd_db, steps.size).tolist(), strict=True))
    e = np.array([err[int(s)] for s in step])
    _set_level(out, 2, e)
    _shift(out, "rx2", bias_m_per_db * e / METRES_PER_UNIT)
    return out


def p3_drift(rec: Mapping[str, Any], metres_per_s: float) -> Rec:
    """DECOY (no catalogue effect): P3's RX stamp drifts by ``metres_per_s`` x t of path."""
    out = _copy(rec)
    t = np.asarray(rec["t_s"], np.float64)
    _shift(out, "rx3", metres_per_s * (t - t.min()) / METRES_PER_UNIT)
    return out
