"""Power self-calibration: timestamp error against RX power from a P2 gain sweep (the paper's method).

A TX station sends triplets P1, P2, P3; P1 and P3 keep a constant gain (octet ``gain13``) while P2's
gain steps down (``step`` 0, 1, ...). After the drift correction of eq. 1, C'_12 = E(P2) - E(P1):
the timestamp error of P2 relative to the (unknown) error at P1's power. Per gain step this module
takes a robust mean of C'_12 and of P2's measured RX level (user manual 4.7.2, from CIR_PWR and
RXPACC), which gives the curve of timestamp error against *measured* power.

Measured against real power: the real RX power of step k is ``R + g_k`` with g_k the known nominal
gain change of P2 relative to P1/P3 (dB) and R P1's real power. The level estimate is right only
at low power (below about -85 dBm): fit ``measured_k = a + b g_k`` on the steps whose measured
level is below ``threshold_dbm`` (b absorbs a uniform error of the nominal step size, e.g. 2.5 dB
coarse steps taken as 3 dB), then extrapolate ``real_k = a + b g_k`` to every step.

The unknown constant: every error value is relative to E at P1/P3's real power
(``PowerCurve.reference_real_dbm``); the zero line of the curve is unknown and is absorbed, with
the hardware delays, by Z of the TWR equation.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from uwbcal import dw1000
from uwbcal.corrections.drift import c12_corrected, triplet_diffs, units_to_s
from uwbcal.dw1000 import ArrayLike, FloatArray
from uwbcal.errors import SessionError

#: Measured RX level (dBm) below which the DW1000 estimate tracks the real level (paper, APS011).
DEFAULT_THRESHOLD_DBM = -85.0


def rx_level_from_registers(cir_pwr: ArrayLike, rxpacc: ArrayLike, rxpacc_nosat: ArrayLike | None = None,
                            prf_mhz: int = 64, a_dbm: float | None = None,
                            data_rate_kbps: int = 6810) -> FloatArray:
    """Measured RX level, dBm, from raw registers (:func:`uwbcal.dw1000.rx_level_dbm`).

    Where RXPACC equals RXPACC_NOSAT the manual asks to subtract the SFD symbols from N
    (:func:`uwbcal.dw1000.rxpacc_n`, the same rule as the station's caltable.c); without
    ``rxpacc_nosat`` (an import that lacks it) RXPACC is used as read.
    """
    return dw1000.rx_level_dbm(cir_pwr, dw1000.rxpacc_n(rxpacc, rxpacc_nosat, data_rate_kbps), prf_mhz, a_dbm)


def robust_mean(x: ArrayLike, k: float = 4.0) -> tuple[float, float, int]:
    """Mean of the values within k robust sigmas (1.4826 MAD) of the median.

    Returns (mean, standard error of the mean, number of values kept), in the unit of ``x``.
    Non-finite values are ignored; an empty input gives (nan, nan, 0).
    """
    v = np.asarray(x, dtype=np.float64)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return float("nan"), float("nan"), 0
    med = float(np.median(v))
    mad = 1.4826 * float(np.median(np.abs(v - med)))
    kept = v if mad == 0.0 else v[np.abs(v - med) <= k * mad]
    n = int(kept.size)
    sem = float(np.std(kept, ddof=1) / np.sqrt(n)) if n > 1 else float("nan")
    return float(np.mean(kept)), sem, n


def _groups(keys: npt.NDArray[np.int64]) -> tuple[npt.NDArray[np.int64], list[npt.NDArray[np.intp]]]:
    """Unique keys (sorted) and, for each, the indices of its rows."""
    uniq, inv = np.unique(keys, return_inverse=True)
    order = np.argsort(inv, kind="stable")
    bounds = np.searchsorted(inv[order], np.arange(1, uniq.size))
    return uniq.astype(np.int64), list(np.split(order, bounds))


def isotonic_increasing(y: ArrayLike, w: ArrayLike | None = None) -> FloatArray:
    """Least-squares non-decreasing fit of ``y`` (pool adjacent violators), same unit as ``y``."""
    yy = np.asarray(y, dtype=np.float64)
    ww = np.ones_like(yy) if w is None else np.asarray(w, dtype=np.float64)
    vals: list[float] = []
    wts: list[float] = []
    cnt: list[int] = []
    for yi, wi in zip(yy, ww, strict=True):
        vals.append(float(yi))
        wts.append(float(wi))
        cnt.append(1)
        while len(vals) > 1 and vals[-2] > vals[-1]:
            wsum = wts[-2] + wts[-1]
            v = (vals[-2] * wts[-2] + vals[-1] * wts[-1]) / wsum
            c = cnt[-2] + cnt[-1]
            vals[-2:] = [v]
            wts[-2:] = [wsum]
            cnt[-2:] = [c]
    return np.repeat(np.asarray(vals), cnt).astype(np.float64)


@dataclass(frozen=True)
class PowerCurve:
    """Timestamp error of one receiving station against RX power: the table a station stores.

    ``measured_dbm`` is strictly increasing (measured RX level, dBm, as the station reads it);
    ``error_s`` the timestamp error at each point (s, measured minus true, relative to the unknown
    constant E(reference_real_dbm)); ``real_dbm`` the estimated real RX power of each point (dBm,
    increasing). Subtract :meth:`error_at_measured` from an RX timestamp to correct it.
    """

    measured_dbm: tuple[float, ...]
    error_s: tuple[float, ...]
    real_dbm: tuple[float, ...]
    reference_real_dbm: float
    reference_measured_dbm: float
    rx_station: int | None = None
    unknown_constant: str = ("error_s is E(P) - E(reference_real_dbm); the constant E(reference_real_dbm) "
                             "is unknown and goes into Z of the TWR equation")

    def __post_init__(self) -> None:
        m = np.asarray(self.measured_dbm)
        if not (len(self.measured_dbm) == len(self.error_s) == len(self.real_dbm)) or m.size == 0:
            raise ValueError("PowerCurve axes must be non-empty and of equal length")
        if m.size > 1 and not np.all(np.diff(m) > 0):
            raise ValueError("PowerCurve.measured_dbm must be strictly increasing")

    def error_at_measured(self, measured_dbm: ArrayLike) -> FloatArray:
        """Timestamp error, s, at a measured RX level (dBm); linear, clamped at the table ends."""
        return np.asarray(np.interp(np.asarray(measured_dbm, dtype=np.float64),
                                    self.measured_dbm, self.error_s), dtype=np.float64)

    def real_from_measured(self, measured_dbm: ArrayLike) -> FloatArray:
        """Estimated real RX power, dBm, from a measured level; below the table measured = real - offset."""
        x = np.asarray(measured_dbm, dtype=np.float64)
        y = np.interp(x, self.measured_dbm, self.real_dbm)
        below = x < self.measured_dbm[0]
        y = np.where(below, x + (self.real_dbm[0] - self.measured_dbm[0]), y)
        return np.asarray(y, dtype=np.float64)

    def error_at_real(self, real_dbm: ArrayLike) -> FloatArray:
        """Timestamp error, s, at a real RX power (dBm); linear, clamped at the table ends."""
        order = np.argsort(self.real_dbm)
        return np.asarray(np.interp(np.asarray(real_dbm, dtype=np.float64),
                                    np.asarray(self.real_dbm)[order], np.asarray(self.error_s)[order]),
                          dtype=np.float64)

    def to_dict(self) -> dict[str, Any]:
        """Plain dict for JSON (lists for the axes)."""
        d = asdict(self)
        for k in ("measured_dbm", "error_s", "real_dbm"):
            d[k] = list(d[k])
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> PowerCurve:
        """Inverse of :meth:`to_dict`."""
        return cls(measured_dbm=tuple(float(v) for v in d["measured_dbm"]),
                   error_s=tuple(float(v) for v in d["error_s"]),
                   real_dbm=tuple(float(v) for v in d["real_dbm"]),
                   reference_real_dbm=float(d["reference_real_dbm"]),
                   reference_measured_dbm=float(d["reference_measured_dbm"]),
                   rx_station=None if d.get("rx_station") is None else int(d["rx_station"]))


@dataclass(frozen=True)
class StepStats:
    """Statistics of one gain step: P2 gain, counts, measured/real power (dBm), error (s)."""

    step: int
    gain2: int
    nominal_db: float
    n: int
    n_used: int
    measured_dbm: float
    measured_sem_db: float
    measured_p1_dbm: float
    real_dbm: float
    error_s: float
    error_sem_s: float
    error_std_s: float


@dataclass(frozen=True)
class PowerCalibration:
    """Result of a power sweep: the curve, per-step statistics and the measured-vs-real fit.

    ``method`` "nominal": ``measured = offset_dbm + slope * nominal_db`` fitted on ``n_fit``
    steps below ``threshold_dbm`` and ``real = offset_dbm + slope * nominal_db`` for every step;
    "stitch": ``slope`` is the fitted fine-step scale and ``offset_dbm`` the real power of P1/P3
    (see :func:`stitch_real_power`).
    """

    curve: PowerCurve
    steps: tuple[StepStats, ...]
    offset_dbm: float
    slope: float
    threshold_dbm: float
    n_fit: int
    method: str = "nominal"

    def to_dict(self) -> dict[str, Any]:
        """Plain dict for JSON."""
        return {"curve": self.curve.to_dict(), "steps": [asdict(s) for s in self.steps],
                "offset_dbm": self.offset_dbm, "slope": self.slope,
                "threshold_dbm": self.threshold_dbm, "n_fit": self.n_fit, "method": self.method}


def fit_measured_vs_real(nominal_db: ArrayLike, measured_dbm: ArrayLike,
                         threshold_dbm: float = DEFAULT_THRESHOLD_DBM, fit_slope: bool = True,
                         min_points: int = 2) -> tuple[float, float, int]:
    """Fit measured = a + b * nominal on the points measured below ``threshold_dbm``.

    Returns (a in dBm, b dimensionless, number of points used). With fewer than ``min_points``
    points, or when the fitted points share one nominal gain, b is fixed at 1. Raises
    :class:`SessionError` when no point lies below the threshold.
    """
    g = np.asarray(nominal_db, dtype=np.float64)
    m = np.asarray(measured_dbm, dtype=np.float64)
    sel = np.isfinite(g) & np.isfinite(m) & (m < threshold_dbm)
    n = int(np.count_nonzero(sel))
    if n == 0:
        raise SessionError(f"power sweep: no step measured below {threshold_dbm} dBm, where the RX "
                           "level estimate is right; sweep further down or raise --threshold")
    gs, ms = g[sel], m[sel]
    if fit_slope and n >= max(2, min_points) and np.ptp(gs) > 0:
        b, a = np.polyfit(gs, ms, 1)
        return float(a), float(b), n
    return float(np.mean(ms - gs)), 1.0, n


def stitch_real_power(fine_db: ArrayLike, coarse: ArrayLike, measured_dbm: ArrayLike,
                      threshold_dbm: float = DEFAULT_THRESHOLD_DBM, k_boundary: int = 4,
                      iterations: int = 4) -> tuple[FloatArray, float, int]:
    """Real RX power per step by stitching coarse-gain segments (for fine-step sweeps).

    A real TX gain is ``fine_scale * fine_db + offset(coarse)``: the fine steps of one coarse
    setting are uniform, the coarse steps carry per-station errors of a few tenths of a dB
    (so a straight line through nominal gains, fitted in the low-power region, extrapolates
    badly over a 30 dB sweep). Here: (1) in the low-power region (measured below
    ``threshold_dbm``, where measured = real) fit measured = a_c + s * fine_db with one slope s
    and an intercept per coarse setting; (2) every other coarse segment, in order of rising
    power, gets the offset that makes its points continue the already-placed points as one
    smooth monotone measured-vs-real curve: a local quadratic through the ``k_boundary``
    placed points nearest the boundary plus the segment's ``k_boundary`` nearest points, with
    the segment's shift solved iteratively (measured = h(real) with h strictly increasing,
    so equal measured means equal real).

    Returns (real dBm per step, fine scale s, number of low-power steps used). Raises
    :class:`ValueError` when the sweep does not have the structure (a coarse segment with at
    least 3 low-power steps, every segment with at least 2 steps).
    """
    f = np.asarray(fine_db, dtype=np.float64)
    c = np.asarray(coarse, dtype=np.int64)
    m = np.asarray(measured_dbm, dtype=np.float64)
    segs = sorted({int(v) for v in c})
    low = m < threshold_dbm
    fit_segs = [g for g in segs if np.count_nonzero(low & (c == g)) >= 2]
    if not any(np.count_nonzero(low & (c == g)) >= 3 for g in segs) or any(
            np.count_nonzero(c == g) < 2 for g in segs):
        raise ValueError("sweep has no coarse segment with 3 low-power fine steps, or a segment of one step")
    # (1) common slope, one intercept per segment, on the low-power points
    sel = low & np.isin(c, fit_segs)
    cols = [f[sel]] + [(c[sel] == g).astype(np.float64) for g in fit_segs]
    coef = np.linalg.lstsq(np.stack(cols, axis=1), m[sel], rcond=None)[0]
    slope = float(coef[0])
    offset = {g: float(coef[1 + i]) for i, g in enumerate(fit_segs)}
    real = np.full(m.size, np.nan)
    for g in fit_segs:
        real[c == g] = offset[g] + slope * f[c == g]
    # (2) remaining segments by rising measured power
    rest = sorted((g for g in segs if g not in offset), key=lambda g: float(np.mean(m[c == g])))
    for g in rest:
        placed = np.flatnonzero(np.isfinite(real))
        seg = np.flatnonzero(c == g)
        seg = seg[np.argsort(m[seg])][:k_boundary]
        near = placed[np.argsort(-real[placed])][:k_boundary]
        x_rel = slope * f[seg]
        # start: continue the placed curve with the measured step of the nominal gains
        o = float(np.max(real[placed]) - np.min(x_rel) + 0.5)
        for _ in range(iterations):
            xs = np.concatenate([real[near], x_rel + o])
            x0 = float(np.max(real[near]))
            u = xs - x0
            cols2 = [np.ones_like(u), u]
            if xs.size >= 6:
                cols2.append(u**2)
            cols2.append(np.concatenate([np.zeros(near.size), np.ones(seg.size)]))
            q = np.linalg.lstsq(np.stack(cols2, axis=1), np.concatenate([m[near], m[seg]]), rcond=None)[0]
            deriv = float(q[1])  # slope of the local curve at the boundary
            if deriv <= 1e-3:
                break
            o += float(q[-1]) / deriv
        offset[g] = o
        real[c == g] = o + slope * f[c == g]
    return real, slope, int(np.count_nonzero(sel))


def calibrate_power(tx1: ArrayLike, tx2: ArrayLike, tx3: ArrayLike,
                    rx1: ArrayLike, rx2: ArrayLike, rx3: ArrayLike,
                    step: ArrayLike, gain13: ArrayLike, gain2: ArrayLike,
                    measured2_dbm: ArrayLike, measured1_dbm: ArrayLike | None = None,
                    threshold_dbm: float = DEFAULT_THRESHOLD_DBM, fit_slope: bool = True,
                    coarse_step_db: float = 3.0, rx_station: int | None = None,
                    clip_k: float = 4.0, method: str = "auto") -> PowerCalibration:
    """Power self-calibration from a P2 gain sweep; every array has one entry per triplet.

    ``measured2_dbm`` (and optionally ``measured1_dbm``) are the RX levels the receiver measured
    for P2 (and P1), dBm (see :func:`rx_level_from_registers`). ``gain13``/``gain2`` are TX_POWER
    octets; nominal gains use ``coarse_step_db`` (only the ratio of steps matters when the slope
    is fitted). Per step the error is the robust mean (``clip_k`` robust sigmas) of C'_12.

    ``method`` for the real power: "nominal" (the paper: a line through the nominal gains fitted
    below the threshold, :func:`fit_measured_vs_real`), "stitch" (:func:`stitch_real_power`,
    robust to per-coarse-setting gain errors; needs fine-step segments) or "auto" (stitch when
    the sweep allows it, else nominal).
    """
    d = triplet_diffs(tx1, tx2, tx3, rx1, rx2, rx3)
    err_s = units_to_s(c12_corrected(d))
    m2 = np.asarray(measured2_dbm, dtype=np.float64)
    m1 = None if measured1_dbm is None else np.asarray(measured1_dbm, dtype=np.float64)
    g13 = np.asarray(gain13, dtype=np.int64)
    g2 = np.asarray(gain2, dtype=np.int64)
    keys, idx = _groups(np.asarray(step, dtype=np.int64))
    rows: list[dict[str, Any]] = []
    for k, ii in zip(keys, idx, strict=True):
        e, e_sem, n_used = robust_mean(err_s[ii], clip_k)
        sub = err_s[ii]
        e_std = float(np.std(sub, ddof=1)) if sub.size > 1 else float("nan")
        mk, mk_sem, _ = robust_mean(m2[ii], clip_k)
        m1k = robust_mean(m1[ii], clip_k)[0] if m1 is not None else float("nan")
        oct2 = int(np.bincount(g2[ii] & 0xFF).argmax())
        oct13 = int(np.bincount(g13[ii] & 0xFF).argmax())
        nom = float(dw1000.gain_nominal_db(oct2, coarse_step_db)
                    - dw1000.gain_nominal_db(oct13, coarse_step_db))
        rows.append({"step": int(k), "gain2": oct2, "nominal_db": nom, "n": int(ii.size), "n_used": n_used,
                     "measured_dbm": mk, "measured_sem_db": mk_sem, "measured_p1_dbm": m1k,
                     "error_s": e, "error_sem_s": e_sem, "error_std_s": e_std})
    ok = [r for r in rows if np.isfinite(r["nominal_db"]) and np.isfinite(r["measured_dbm"])
          and np.isfinite(r["error_s"])]
    if not ok:
        raise SessionError("power sweep: no usable gain step (P2 output off or no data)")
    nom_arr = np.array([r["nominal_db"] for r in ok])
    meas_arr = np.array([r["measured_dbm"] for r in ok])
    a, b, n_fit = fit_measured_vs_real(nom_arr, meas_arr, threshold_dbm, fit_slope)
    real_arr = a + b * nom_arr
    used = "nominal"
    if method in ("auto", "stitch"):
        octs = np.array([r["gain2"] for r in ok], dtype=np.int64)
        fine_db = (octs & 31) * 0.5
        try:
            real_arr, b, n_fit = stitch_real_power(fine_db, octs >> 5, meas_arr, threshold_dbm)
            used = "stitch"
            oct13 = int(np.bincount(g13 & 0xFF).argmax())
            ref = np.flatnonzero(octs == oct13)
            a = float(real_arr[ref[0]]) if ref.size else float(real_arr[np.argmax(nom_arr)] - np.max(nom_arr))
        except ValueError:
            if method == "stitch":
                raise
    elif method != "nominal":
        raise ValueError(f"unknown real-power method {method!r} (auto, nominal, stitch)")
    steps = tuple(StepStats(real_dbm=float(rp), **r) for rp, r in zip(real_arr, ok, strict=True))

    # Table sorted by real power; measured axis made monotone (isotonic) and ties merged.
    order = np.argsort([s.real_dbm for s in steps], kind="stable")
    real = np.array([steps[i].real_dbm for i in order])
    err = np.array([steps[i].error_s for i in order])
    w = np.array([max(steps[i].n_used, 1) for i in order], dtype=np.float64)
    meas_iso = isotonic_increasing([steps[i].measured_dbm for i in order], w)
    uniq, start = np.unique(meas_iso, return_index=True)
    bounds = list(start[1:])
    ws = np.split(w, bounds)

    def merged(v: FloatArray) -> tuple[float, ...]:
        return tuple(float(np.average(x, weights=ww)) for x, ww in zip(np.split(v, bounds), ws, strict=True))

    p1 = np.array([s.measured_p1_dbm for s in steps])
    curve = PowerCurve(
        measured_dbm=tuple(float(u) for u in uniq),
        error_s=merged(err),
        real_dbm=merged(real),
        reference_real_dbm=a,
        reference_measured_dbm=float(np.mean(p1[np.isfinite(p1)])) if np.isfinite(p1).any() else float("nan"),
        rx_station=rx_station,
    )
    return PowerCalibration(curve=curve, steps=steps, offset_dbm=a, slope=b, threshold_dbm=threshold_dbm,
                            n_fit=n_fit, method=used)
