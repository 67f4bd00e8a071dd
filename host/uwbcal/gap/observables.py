"""Observables and regimes of a session's triplet records, for real and simulated sessions alike.

Every function takes the record arrays in the layout of :mod:`uwbcal.sessions.columns`
(``dict[str, array]``; a missing or all-NULL column may be absent or None) and is vectorised.

Observables (one value per record, NaN where the source lacks the columns):

- ``drift_residual_m``: the paper's eq. 1 residual C'_12 in metres (timestamp residual of P2
  after the three-message drift correction).
- ``clock_rate_ppm``: the RX-minus-TX clock rate from P1 -> P3, C_13 / dT_13^TX, ppm.
- ``rx_level_dbm``: RX level estimate of P2 (user manual 4.7.2), when CIR_PWR and RXPACC exist.
- ``p13_level_db``: RX level estimate of P3 minus P1, dB (interference, gain drift).
- ``car_int_ppm_minus_rate``: carrier-integrator clock offset at P1 minus ``clock_rate_ppm``,
  ppm (its power-dependent error), when DRX_CAR_INT exists.

Regimes (categorical codes per record): ``direction`` (TX -> RX station pair), ``time``
(blocks of equal duration of ``t_s``; the cross-validation groups of drift runs), ``step``
(power-sweep step; the groups of power sweeps), ``rx_power`` (3 dB bins of the P2 RX level
estimate), ``spacing`` (0.1 ms classes of the P1 -> P2 spacing; one class for all records of a
session of three or more transmitters taking turns whose spacings spread over more than
:data:`MAX_SPACING_CLASSES` classes, :func:`spacing_keys`), ``temperature`` (1 degC bins),
``distance`` (cm classes).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from uwbcal.dw1000 import METRES_PER_UNIT, car_int_to_ppm, rx_level_dbm, rxpacc_n, wrap_diff
from uwbcal.sessions.schema import INT_NULL

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
Records = Mapping[str, "npt.NDArray[Any] | None"]

#: Observable names and units.
OBSERVABLES: Final[dict[str, str]] = {
    "drift_residual_m": "m",
    "clock_rate_ppm": "ppm",
    "rx_level_dbm": "dBm",
    "p13_level_db": "dB",
    "car_int_ppm_minus_rate": "ppm",
}
#: Regime variables (categorical).
REGIMES: Final = ("direction", "time", "step", "rx_power", "spacing", "temperature", "distance")


def _col(rec: Records, name: str) -> npt.NDArray[Any] | None:
    v = rec.get(name)
    if v is None:
        return None
    a = np.asarray(v)
    if a.dtype == object:
        if all(x is None for x in a.tolist()):
            return None
        a = np.array([np.nan if x is None else x for x in a.tolist()], dtype=np.float64)
    if a.dtype.kind == "f" and a.size and not np.any(np.isfinite(a)):
        return None
    if a.dtype.kind in "iu":
        null = a == INT_NULL
        if a.size and np.all(null):
            return None
        if np.any(null):
            return np.where(null, np.nan, a.astype(np.float64))
    return a


def n_records(rec: Records) -> int:
    """Number of records."""
    s = _col(rec, "seq")
    return 0 if s is None else int(s.shape[0])


def observables(rec: Records, prf_mhz: int = 64) -> dict[str, FloatArray]:
    """The observables available in these records (name -> values per record).

    ``prf_mhz`` is the session's PRF (meta ``radio.prf_mhz``; :func:`uwbcal.corrections.analysis.
    session_prf_mhz`): the RX level estimate's constant A depends on it (121.74 dBm at 64 MHz).
    """
    out: dict[str, FloatArray] = {}
    ts = [_col(rec, k) for k in ("tx1", "tx2", "tx3", "rx1", "rx2", "rx3")]
    if all(t is not None for t in ts):
        tx1, tx2, tx3, rx1, rx2, rx3 = (np.asarray(t).astype(np.int64) for t in ts)
        d12t = wrap_diff(tx2, tx1).astype(np.float64)
        d13t = wrap_diff(tx3, tx1).astype(np.float64)
        c12 = wrap_diff(rx2, rx1) - d12t
        c13 = wrap_diff(rx3, rx1) - d13t
        with np.errstate(divide="ignore", invalid="ignore"):
            out["drift_residual_m"] = (c12 - c13 / d13t * d12t) * METRES_PER_UNIT
            out["clock_rate_ppm"] = c13 / d13t * 1e6
    lv = levels(rec, prf_mhz)
    if 2 in lv:
        out["rx_level_dbm"] = lv[2]
    if 1 in lv and 3 in lv:
        out["p13_level_db"] = lv[3] - lv[1]
    ci = _col(rec, "car_int1")
    if ci is not None and "clock_rate_ppm" in out:
        out["car_int_ppm_minus_rate"] = car_int_to_ppm(np.asarray(ci, np.float64)) - out["clock_rate_ppm"]
    return {
        k: np.asarray(v, dtype=np.float64)
        for k, v in out.items()
        if np.count_nonzero(np.isfinite(v)) >= 3 and float(np.nanstd(v)) > 0.0
    }


def levels(rec: Records, prf_mhz: int = 64) -> dict[int, FloatArray]:
    """RX level estimate (dBm, user manual 4.7.2) of message k (1, 2, 3) where CIR_PWR and RXPACC exist."""
    lv: dict[int, FloatArray] = {}
    for k in (1, 2, 3):
        c, n = _col(rec, f"cir_pwr{k}"), _col(rec, f"rxpacc{k}")
        if c is not None and n is not None:
            with np.errstate(invalid="ignore", divide="ignore"):
                n_k = rxpacc_n(n, _col(rec, f"rxpacc_nosat{k}"))
                lv[k] = np.asarray(rx_level_dbm(np.asarray(c, np.float64), n_k, prf_mhz), np.float64)
    return lv


@dataclass(frozen=True)
class Regimes:
    """Regime keys per record (absolute, so real and simulated sessions share them).

    Keys: ``direction`` = 1000 * tx_station + rx_station; ``time`` = block index for the
    given edges; ``step`` = the step; ``rx_power``, ``spacing``, ``temperature``,
    ``distance`` = floor(value / width) with the widths of :data:`WIDTHS`. -1 marks NaN.
    """

    keys: dict[str, IntArray]
    t_edges: FloatArray


#: Class widths of the continuous regimes and their units.
WIDTHS: Final[dict[str, tuple[float, str]]] = {
    "rx_power": (3.0, "dBm"),
    "spacing": (0.1, "ms"),
    "temperature": (1.0, "degC"),
    "distance": (0.01, "m"),
}


#: More distinct 0.1 ms spacing classes than this, with three or more transmitters: one class.
MAX_SPACING_CLASSES: Final = 8
#: The spacing key of that one class (far above any 0.1 ms class of a real spacing).
SPACING_POOLED: Final = 10**9


def spacing_keys(spacing_ms: FloatArray, tx_station: npt.NDArray[Any] | None) -> IntArray:
    """Spacing regime keys: 0.1 ms classes of the P1 -> P2 spacing (ms), or :data:`SPACING_POOLED`
    for every record when three or more stations transmit and the spacings spread over more than
    :data:`MAX_SPACING_CLASSES` classes (-1: no spacing).

    N nodes taking turns (the asil four-node logger) send P1, P2, P3 of one transmitter N turns
    apart, each turn 17..33 ms: P1 -> P2 takes some 27 classes between 79 and 117 ms, so a
    direction's records (12 directions) fell into classes of a few records, below every cell's
    minimum, and a four-node session had no feature left to attribute. Such spacings are not a
    condition of the experiment but the logger's turns, and the residual's factor
    1 + k^2 + (1 - k)^2 (k = P1->P2 / P1->P3) moves by under 2 % over them: one class. Two-node runs
    (two modes, 23 and 33.4 ms) and designed spacings (a few values) keep their classes; the
    rule reads the spacings and transmitters alone, so the re-simulations, which copy the real
    schedule, get the same keys. A subsample (every k-th record of a long session) keeps the
    decision unless a session has about the limit of classes with some of one record only.
    """
    keys = _bins(np.asarray(spacing_ms, np.float64), WIDTHS["spacing"][0])
    if tx_station is None:
        return keys
    ok = keys >= 0
    if np.unique(np.asarray(tx_station)[ok]).size >= 3 and np.unique(keys[ok]).size > MAX_SPACING_CLASSES:
        return np.where(ok, SPACING_POOLED, -1).astype(np.int64)
    return keys


def label(regime: str, key: int, t_edges: FloatArray | None = None) -> str:
    """Human label of one regime key."""
    if key < 0:
        return "n/a"
    if regime == "spacing" and key == SPACING_POOLED:
        return "all spacings"
    if regime == "direction":
        return f"{key // 1000}->{key % 1000}"
    if regime == "time" and t_edges is not None and key + 1 < len(t_edges):
        return f"{t_edges[key]:.1f}..{t_edges[key + 1]:.1f} s"
    if regime == "step":
        return f"step {key}"
    if regime == "fold":
        return f"fold {key}"
    if regime in WIDTHS:
        w, u = WIDTHS[regime]
        return f"{key * w:.4g}..{(key + 1) * w:.4g} {u}"
    return str(key)


def _bins(x: FloatArray, width: float) -> IntArray:
    ok = np.isfinite(x)
    out = np.full(x.shape, -1, dtype=np.int64)
    out[ok] = np.floor(x[ok] / width + 1e-9).astype(np.int64)
    return out


def regimes(rec: Records, t_edges: FloatArray | None = None, n_time_blocks: int = 8,
            prf_mhz: int = 64) -> Regimes:
    """Regime keys of each record. ``t_edges`` (s) fixes the time blocks (from the real session);
    ``prf_mhz`` the session's PRF (the RX level estimate's constant A depends on it)."""
    n = n_records(rec)
    keys: dict[str, IntArray] = {}
    txs, rxs = _col(rec, "tx_station"), _col(rec, "rx_station")
    if txs is not None and rxs is not None:
        keys["direction"] = np.asarray(txs, np.int64) * 1000 + np.asarray(rxs, np.int64)
    t = _col(rec, "t_s")
    edges = np.array([0.0, np.inf])
    if t is not None:
        tf = np.asarray(t, np.float64)
        edges = time_edges(tf, n_time_blocks) if t_edges is None else np.asarray(t_edges, np.float64)
        keys["time"] = np.clip(np.searchsorted(edges, tf, side="right") - 1, 0, len(edges) - 2).astype(
            np.int64
        )
    st = _col(rec, "step")
    if st is not None:
        keys["step"] = np.asarray(st, np.int64)
    obs = observables(rec, prf_mhz)
    if "rx_level_dbm" in obs:
        keys["rx_power"] = _bins(obs["rx_level_dbm"], WIDTHS["rx_power"][0])
    sp = _col(rec, "spacing_s")
    if sp is not None:
        keys["spacing"] = spacing_keys(np.asarray(sp, np.float64) * 1e3, txs)
    tc = _col(rec, "temp_c")
    if tc is not None:
        keys["temperature"] = _bins(np.asarray(tc, np.float64), WIDTHS["temperature"][0])
    dm = _col(rec, "distance_m")
    if dm is not None:
        keys["distance"] = _bins(np.asarray(dm, np.float64), WIDTHS["distance"][0])
    keys = {k: v for k, v in keys.items() if v.shape[0] == n}
    return Regimes(keys=keys, t_edges=edges)


def time_edges(t_s: FloatArray, n_blocks: int) -> FloatArray:
    """Edges (s) of ``n_blocks`` time blocks of equal duration covering ``t_s``."""
    lo, hi = float(np.nanmin(t_s)), float(np.nanmax(t_s))
    e = np.linspace(lo, hi, n_blocks + 1)
    e[-1] = np.nextafter(hi, np.inf)
    return e
