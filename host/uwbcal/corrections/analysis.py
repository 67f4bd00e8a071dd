"""The corrections applied to session record tables (columns.TRIPLET, columns.RANGE).

Input is a mapping column name -> numpy array (one entry per record), as the session store
returns it; a column that is absent or entirely NULL (NaN) is treated as not provided. Output
is plain JSON-ready dicts (units in the key names: ``_m``, ``_s``, ``_dbm``, ``_ppm``) plus the
typed objects where callers need them (:class:`PowerCalibration`). This is what
`uwbcal analyze` and `uwbcal paper` run; it never reads simulation truth.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Final, NamedTuple

import numpy as np
import numpy.typing as npt

from uwbcal import dw1000
from uwbcal.corrections import drift as drift_mod
from uwbcal.corrections import power as power_mod
from uwbcal.corrections import twr as twr_mod
from uwbcal.corrections import validity as validity_mod
from uwbcal.corrections.power import PowerCalibration, PowerCurve
from uwbcal.corrections.validity import Validity
from uwbcal.corrections.zoffset import z_from_known_distance_m
from uwbcal.dw1000 import FloatArray
from uwbcal.errors import SessionError
from uwbcal.physics.scenario import Radio
from uwbcal.sessions.schema import INT_NULL

Records = Mapping[str, npt.NDArray[Any]]


def column(rec: Records, name: str) -> FloatArray | None:
    """Column as float64, or None when absent or all NULL/NaN."""
    if name not in rec or rec[name] is None:
        return None
    a = np.asarray(rec[name])
    if a.dtype == object:
        a = np.array([np.nan if v is None else v for v in a], dtype=np.float64)
    elif a.dtype.kind in "iu":
        a = np.where(a == INT_NULL, np.nan, a.astype(np.float64))
    a = a.astype(np.float64)
    if a.size == 0 or not np.isfinite(a).any():
        return None
    return a


def int_column(rec: Records, name: str) -> npt.NDArray[np.int64]:
    """Integer column (timestamps, gains); SessionError when missing or with NULLs."""
    a = column(rec, name)
    if a is None or not np.isfinite(a).all():
        raise SessionError(f"column {name!r} is missing or has NULL values")
    return a.astype(np.int64)


def subset(rec: Records, mask: npt.NDArray[np.bool_]) -> dict[str, npt.NDArray[Any]]:
    """Rows of every column where ``mask`` is true."""
    return {k: np.asarray(v)[mask] for k, v in rec.items() if v is not None}


def n_rows(rec: Records) -> int:
    """Number of records (length of the first provided column)."""
    for v in rec.values():
        if v is not None:
            return len(v)
    return 0


def pairs(rec: Records, a: str, b: str) -> list[tuple[int, int]]:
    """Distinct (a, b) station-id pairs present, sorted; (-1, -1) when the columns are missing."""
    ca, cb = column(rec, a), column(rec, b)
    if ca is None or cb is None:
        return [(-1, -1)] if n_rows(rec) else []
    return sorted({(int(x), int(y)) for x, y in zip(ca, cb, strict=True)})


def _pair_mask(rec: Records, a: str, b: str, pair: tuple[int, int]) -> npt.NDArray[np.bool_]:
    ca, cb = column(rec, a), column(rec, b)
    if ca is None or cb is None:
        return np.ones(n_rows(rec), dtype=bool)
    return np.asarray((ca == pair[0]) & (cb == pair[1]), dtype=bool)


def measured_level(rec: Records, suffix: str, prf_mhz: int = 64, a_dbm: float | None = None,
                   data_rate_kbps: int = 6810) -> FloatArray | None:
    """Measured RX level (dBm) of one message from its raw registers, or None if not recorded."""
    c = column(rec, f"cir_pwr{suffix}")
    n = column(rec, f"rxpacc{suffix}")
    if c is None or n is None:
        return None
    return power_mod.rx_level_from_registers(c, n, column(rec, f"rxpacc_nosat{suffix}"), prf_mhz, a_dbm,
                                             data_rate_kbps)


# --- drift --------------------------------------------------------------------------------

def analyze_drift_records(tr: Records, channel: int = 2, data_rate_kbps: int = 6810) -> list[dict[str, Any]]:
    """Eq. 1 on every (tx_station, rx_station) pair of a triplet table: one dict per pair.

    Residual C'_12 mean/std in metres with and without correction, and with the carrier
    integrator (mean of P1's and P2's DRX_CAR_INT) when recorded. In a power sweep only the
    triplets whose P2 gain equals P1/P3's are used (a drift run has all gains equal).
    """
    out: list[dict[str, Any]] = []
    g13, g2 = column(tr, "gain13"), column(tr, "gain2")
    equal = np.ones(n_rows(tr), dtype=bool)
    if g13 is not None and g2 is not None:
        equal = ~(np.isfinite(g13) & np.isfinite(g2) & (g13 != g2))
    for pair in pairs(tr, "tx_station", "rx_station"):
        sub = subset(tr, _pair_mask(tr, "tx_station", "rx_station", pair) & equal)
        if n_rows(sub) == 0:
            continue
        ts = column(sub, "t_s")
        order = np.argsort(ts if ts is not None else np.arange(n_rows(sub)), kind="stable")
        sub = {k: v[order] for k, v in sub.items()}
        res = drift_mod.analyze_drift(
            int_column(sub, "tx1"), int_column(sub, "tx2"), int_column(sub, "tx3"),
            int_column(sub, "rx1"), int_column(sub, "rx2"), int_column(sub, "rx3"),
            t_s=column(sub, "t_s"), car_int1=column(sub, "car_int1"), car_int2=column(sub, "car_int2"),
            channel=channel, data_rate_kbps=data_rate_kbps)
        d = res.to_dict()
        d["tx_station"], d["rx_station"] = pair
        d["triplets_used"] = n_rows(sub)
        out.append(d)
    return out


def drift_residual_series(tr: Records) -> dict[str, FloatArray]:
    """Per-triplet series for plots: t_s, C_12 and C'_12 (m), integrator-corrected (m) if recorded."""
    d = drift_mod.triplet_diffs(*(int_column(tr, n) for n in ("tx1", "tx2", "tx3", "rx1", "rx2", "rx3")))
    t = column(tr, "t_s")
    out = {"t_s": t if t is not None else np.arange(d.dtx12.size, dtype=np.float64),
           "uncorrected_m": drift_mod.units_to_m(drift_mod.c12_uncorrected(d)),
           "corrected_m": drift_mod.units_to_m(drift_mod.c12_corrected(d))}
    ci = [c for c in (column(tr, "car_int1"), column(tr, "car_int2")) if c is not None]
    if ci:
        car = ci[0] if len(ci) == 1 else 0.5 * (ci[0] + ci[1])
        out["carrier_integrator_m"] = drift_mod.units_to_m(drift_mod.c12_carrier_integrator(d, car))
        out["car_int_ppm"] = dw1000.car_int_to_ppm(car)
    for k in (1, 2):
        lv = measured_level(tr, str(k))
        if lv is not None:
            out[f"measured{k}_dbm"] = lv
    return out


# --- power --------------------------------------------------------------------------------

class SessionRadio(NamedTuple):
    """The radio settings an analysis needs: channel, PRF (MHz), data rate (kb/s)."""

    channel: int
    prf_mhz: int
    data_rate_kbps: int


#: What a session that does not say (recorded before the radio was stored, or an import whose
#: source does not record it) used: the paper's settings (physics.scenario.Radio's defaults).
PAPER_SESSION_RADIO: Final = SessionRadio(Radio().channel, Radio().prf_mhz, Radio().data_rate_kbps)


def session_radio(meta: Mapping[str, Any]) -> SessionRadio:
    """A session's radio configuration (meta ``radio``), the paper's value for each setting the
    session leaves out or null. SessionError naming the setting when one is not the chip's."""
    radio = meta.get("radio") or {}
    if not isinstance(radio, Mapping):
        radio = {}
    allowed = {"channel": dw1000.CHANNELS, "prf_mhz": dw1000.PRFS, "data_rate_kbps": dw1000.DATA_RATES_KBPS}
    got = {}
    for key, ok in allowed.items():
        v = radio.get(key)
        v = getattr(PAPER_SESSION_RADIO, key) if v is None else v
        if v not in ok:
            raise SessionError(f"session radio.{key} is {v!r}, expected one of {ok}")
        got[key] = int(v)
    return SessionRadio(**got)


def session_prf_mhz(meta: Mapping[str, Any]) -> int:
    """The PRF (MHz) of a session's radio configuration (:func:`session_radio`)."""
    return session_radio(meta).prf_mhz


@dataclass(frozen=True)
class PowerOptions:
    """Options of the power self-calibration: threshold (dBm), slope fit, coarse step (dB), PRF,
    data rate (kb/s; the SFD symbols RXPACC counts when it equals RXPACC_NOSAT), real-power method
    (auto, nominal, stitch: see :func:`uwbcal.corrections.power.calibrate_power`)."""

    threshold_dbm: float = power_mod.DEFAULT_THRESHOLD_DBM
    fit_slope: bool = True
    coarse_step_db: float = 3.0
    prf_mhz: int = 64
    a_dbm: float | None = None
    data_rate_kbps: int = 6810
    method: str = "auto"


def calibrate_power_records(tr: Records,
                            opts: PowerOptions | None = None) -> dict[tuple[int, int], PowerCalibration]:
    """Power self-calibration of every (tx_station, rx_station) pair of a sweep's triplet table."""
    o = opts or PowerOptions()
    out: dict[tuple[int, int], PowerCalibration] = {}
    for pair in pairs(tr, "tx_station", "rx_station"):
        sub = subset(tr, _pair_mask(tr, "tx_station", "rx_station", pair))
        m2 = measured_level(sub, "2", o.prf_mhz, o.a_dbm, o.data_rate_kbps)
        if m2 is None:
            raise SessionError("power calibration needs P2's RX level registers (cir_pwr2, rxpacc2)")
        out[pair] = power_mod.calibrate_power(
            int_column(sub, "tx1"), int_column(sub, "tx2"), int_column(sub, "tx3"),
            int_column(sub, "rx1"), int_column(sub, "rx2"), int_column(sub, "rx3"),
            step=int_column(sub, "step"), gain13=int_column(sub, "gain13"), gain2=int_column(sub, "gain2"),
            measured2_dbm=m2, measured1_dbm=measured_level(sub, "1", o.prf_mhz, o.a_dbm, o.data_rate_kbps),
            threshold_dbm=o.threshold_dbm, fit_slope=o.fit_slope, coarse_step_db=o.coarse_step_db,
            rx_station=None if pair[1] < 0 else pair[1], method=o.method)
    return out


# --- TWR ----------------------------------------------------------------------------------

#: Methods compared by :func:`analyze_twr_records`, in display order, with a description.
TWR_METHODS: dict[str, str] = {
    "paper": "paper's TWR: drift (M3) + power curves (E1, E2) + Z",
    "paper_no_power": "paper's TWR with drift correction only (E1 = E2 = 0)",
    "paper_no_drift": "paper's TWR with power correction only (no C13 term)",
    "paper_none": "paper's TWR with neither correction (plain SS-TWR)",
    "paper_drift_aps011": "drift correction + APS011 fixed bias table instead of own curves",
    "ss_carint": "single-sided TWR with carrier-integrator clock correction",
    "ss_carint_aps011": "single-sided TWR, carrier integrator, APS011 table",
    "ds": "asymmetric double-sided TWR",
    "ds_aps011": "asymmetric double-sided TWR with APS011 table",
    "station": "the reference station's own corrected range (its table's curves and z shares)",
}


def causal_mean(x: FloatArray, groups: FloatArray | None, window: int) -> FloatArray:
    """Mean of the last ``window`` values (this one included) within each group, in row order.

    A station can average its RX level estimate over recent frames from the same peer before
    looking up E; this removes most of the level noise (about 0.2 dB per frame) from E1, E2.
    """
    if window <= 1:
        return x
    out = np.empty_like(x)
    keys = np.zeros(x.size) if groups is None else groups
    for g in np.unique(keys):
        idx = np.flatnonzero(keys == g)
        c = np.concatenate([[0.0], np.cumsum(x[idx])])
        k = np.arange(1, idx.size + 1)
        lo = np.maximum(k - window, 0)
        out[idx] = (c[k] - c[lo]) / (k - lo)
    return out


def twr_ranges_m(rg: Records, curves: Mapping[int, PowerCurve] | None = None,
                 channel: int = 2, level_window: int = 1) -> dict[str, FloatArray]:
    """Range (m, before Z) per method for every exchange of a range table; methods needing
    unavailable data (M3, registers, curves) are left out. ``level_window`` > 1 averages each
    station's measured RX level over that many recent exchanges (per station pair) before the
    curve and APS011 look-ups (1: every frame's own level, the paper's way)."""
    t1r, t1t, t2t, t2r = (int_column(rg, n) for n in ("t1r", "t1t", "t2t", "t2r"))
    c3r, c3t = column(rg, "t3r"), column(rg, "t3t")
    m3ok = (np.isfinite(c3r) & np.isfinite(c3t)) if c3r is not None and c3t is not None else None
    have_m3 = m3ok is not None and bool(m3ok.any())
    lv1 = measured_level(rg, "_t1")
    lv2 = measured_level(rg, "_r2")
    if level_window > 1:
        ref_c, tag_c = column(rg, "ref_station"), column(rg, "tag_station")
        grp = None if ref_c is None or tag_c is None else ref_c * 65536 + tag_c
        lv1 = None if lv1 is None else causal_mean(lv1, grp, level_window)
        lv2 = None if lv2 is None else causal_mean(lv2, grp, level_window)
    out: dict[str, FloatArray] = {}
    m = twr_mod.units_to_range_m
    out["paper_none"] = m(twr_mod.paper_tof_units(t1r, t1t, t2t, t2r, drift=False))
    e1 = e2 = None
    if curves and lv1 is not None and lv2 is not None:
        tag = column(rg, "tag_station")
        ref = column(rg, "ref_station")
        if tag is not None and ref is not None:
            e1 = np.full(t1r.size, np.nan)
            e2 = np.full(t1r.size, np.nan)
            for sid, c in curves.items():
                e1 = np.where(tag == sid, twr_mod.s_to_units(c.error_at_measured(lv1)), e1)
                e2 = np.where(ref == sid, twr_mod.s_to_units(c.error_at_measured(lv2)), e2)
            if not (np.isfinite(e1).all() and np.isfinite(e2).all()):
                e1 = e2 = None
    aps = None
    if lv1 is not None and lv2 is not None:
        aps = dw1000.aps011_bias_m(0.5 * (lv1 + lv2))
    if e1 is not None and e2 is not None:
        out["paper_no_drift"] = m(twr_mod.paper_tof_units(t1r, t1t, t2t, t2r, e1_units=e1, e2_units=e2,
                                                          drift=False))
    if have_m3 and c3r is not None and c3t is not None and m3ok is not None:
        # single-sided rows (no M3) give NaN in the methods that need M3
        t3r = np.where(m3ok, c3r, 0.0).astype(np.int64)
        t3t = np.where(m3ok, c3t, 0.0).astype(np.int64)
        out["paper_no_power"] = m(twr_mod.paper_tof_units(t1r, t1t, t2t, t2r, t3r, t3t))
        if e1 is not None and e2 is not None:
            out["paper"] = m(twr_mod.paper_tof_units(t1r, t1t, t2t, t2r, t3r, t3t, e1, e2))
        if aps is not None:
            out["paper_drift_aps011"] = out["paper_no_power"] - aps
        out["ds"] = m(twr_mod.ds_tof_units(t1r, t1t, t2t, t2r, t3r, t3t))
        if aps is not None:
            out["ds_aps011"] = out["ds"] - aps
        for k in ("paper_no_power", "paper", "paper_drift_aps011", "ds", "ds_aps011"):
            if k in out:
                out[k] = np.where(m3ok, out[k], np.nan)
    ci = column(rg, "car_int_r2")
    if ci is not None and np.isfinite(ci).all():
        out["ss_carint"] = m(twr_mod.ss_tof_units(t1r, t1t, t2t, t2r, ci, channel))
        if aps is not None:
            out["ss_carint_aps011"] = out["ss_carint"] - aps
    st = column(rg, "range_station_m")
    if st is not None:
        out["station"] = st
    return {k: out[k] for k in TWR_METHODS if k in out}


#: A declared distance whose raw range (before Z) differs by more than this is questioned, m:
#: Z of a DW1000 pair with Decawave's default antenna delays is usually within about 0.15 m.
DISTANCE_SUSPECT_M = 0.25
#: Between distances of one session Z cancels: a per-distance offset this far from the others
#: questions that distance, m.
DISTANCE_SPREAD_M = 0.1


def distance_warnings(dkey: FloatArray, uniq: FloatArray, raw_m: FloatArray) -> list[str]:
    """Warnings when the declared distances disagree with what the ranges imply.

    ``raw_m`` is a range before Z (m, one per exchange), ``dkey`` the declared distance of each
    exchange and ``uniq`` the distinct ones. One distance: its median raw range must lie within
    :data:`DISTANCE_SUSPECT_M` of it (Z unknown, so a smaller mistake cannot be seen). Several:
    raw range minus distance must agree between distances within :data:`DISTANCE_SPREAD_M`
    (Z cancels), judged against the median offset of all distances.
    """
    off = []
    for dv in uniq:
        r = raw_m[(dkey == dv) & np.isfinite(raw_m)]
        off.append(float(np.median(r)) - float(dv) if r.size else float("nan"))
    offs = np.asarray(off)
    out: list[str] = []
    if uniq.size == 1:
        if np.isfinite(offs[0]) and abs(offs[0]) > DISTANCE_SUSPECT_M:
            out.append(f"declared distance {uniq[0]:g} m but the ranges read {uniq[0] + offs[0]:.2f} m "
                       f"before Z ({offs[0]:+.2f} m): if the distance is wrong, Z absorbs the mistake and "
                       f"every later range inherits it; measure again and give --distance")
        return out
    ref = float(np.nanmedian(offs))
    for dv, o in zip(uniq, offs, strict=True):
        if np.isfinite(o) and abs(o - ref) > DISTANCE_SPREAD_M:
            out.append(f"declared distance {dv:g} m reads {dv + o - ref:.2f} m against the session's other "
                       f"distances ({o - ref:+.2f} m): check where the station stood")
    return out


def corrections_applied(rg: Records, curves: Mapping[int, PowerCurve] | None,
                        validity: Mapping[int, Validity] | None,
                        distances: FloatArray | None = None) -> dict[str, Any]:
    """Which corrections the TWR analysis applied to how many records, and the power curves'
    coverage (:func:`uwbcal.corrections.validity.twr_coverage`) with their warnings."""
    n = n_rows(rg)
    c3r, c3t = column(rg, "t3r"), column(rg, "t3t")
    n_m3 = int((np.isfinite(c3r) & np.isfinite(c3t)).sum()) if c3r is not None and c3t is not None else 0
    lv1, lv2 = measured_level(rg, "_t1"), measured_level(rg, "_r2")
    n_lv = int((np.isfinite(lv1) & np.isfinite(lv2)).sum()) if lv1 is not None and lv2 is not None else 0
    tag, ref = column(rg, "tag_station"), column(rg, "ref_station")
    val = dict(validity or {})
    for sid, c in (curves or {}).items():
        val.setdefault(sid, validity_mod.of_curve(c))
    used = {k: v for k, v in val.items() if k in (curves or {})}
    coverage = validity_mod.twr_coverage(tag, ref, lv1, lv2, used, distances)
    n_power = 0
    if curves and tag is not None and ref is not None and n_lv:
        have = np.isin(tag, list(curves)) & np.isin(ref, list(curves))
        n_power = int(have.sum())
    n_clamped = sum(c["n_above"] + c["n_below"] for c in coverage)
    return {"records": n,
            "drift_eq1": {"applied": n_m3,
                          "why_not": None if n_m3 == n else "no M3 (single-sided exchanges)"},
            "power_curves": {"applied": n_power, "outside_swept_span": n_clamped,
                             "stations": sorted(curves or {}),
                             "why_not": None if n_power == n else
                             ("no curve for a station of the pair" if curves else "no power curves given")},
            "aps011": {"applied": n_lv},
            "coverage": coverage,
            "warnings": [c["warning"] for c in coverage if c["warning"]]}


def analyze_twr_records(rg: Records, curves: Mapping[int, PowerCurve] | None = None,
                        z_distance_m: float | None = None, channel: int = 2,
                        distances: FloatArray | None = None, level_window: int = 1,
                        validity: Mapping[int, Validity] | None = None) -> dict[str, Any]:
    """Range error per distance for each method, Z of each from one known distance.

    ``distances`` (m, one per exchange) defaults to the ``distance_m`` column (the nominal
    ground truth). ``z_distance_m`` picks the calibration distance (default: the median of the
    distinct distances). Per method: Z (m), per-distance mean error / std (m), the std of all
    errors after Z (m, the paper's 0.015 m figure), the std and RMS of the per-distance means.
    ``corrections`` says which corrections were applied to how many records and where the
    power curves were extrapolated (``validity`` per station, else the curves' own spans);
    ``warnings`` lists those and declared distances the ranges contradict.
    """
    dist = distances if distances is not None else column(rg, "distance_m")
    if dist is None:
        raise SessionError("TWR analysis needs the distance_m column (ground truth) in the range table")
    ranges = twr_ranges_m(rg, curves, channel, level_window)
    dkey = np.round(dist, 4)
    uniq = np.unique(dkey[np.isfinite(dkey)])
    if uniq.size == 0:
        raise SessionError("no exchange has a known distance")
    zd = float(uniq[np.argmin(np.abs(uniq - (np.median(uniq) if z_distance_m is None else z_distance_m)))])
    methods: dict[str, Any] = {}
    for name, r in ranges.items():
        at = dkey == zd
        z = z_from_known_distance_m(r[at], zd)
        err = r + z - dist
        ok = np.isfinite(err)
        per = []
        for dv in uniq:
            sel = ok & (dkey == dv)
            e = err[sel]
            per.append({"distance_m": float(dv), "n": int(e.size),
                        "mean_error_m": float(np.mean(e)) if e.size else float("nan"),
                        "std_error_m": float(np.std(e, ddof=1)) if e.size > 1 else float("nan")})
        means = np.array([p["mean_error_m"] for p in per])
        methods[name] = {
            "description": TWR_METHODS[name], "z_m": z,
            "std_all_m": float(np.std(err[ok], ddof=1)) if ok.sum() > 1 else float("nan"),
            "std_of_means_m": float(np.std(means, ddof=1)) if means.size > 1 else 0.0,
            "rms_of_means_m": float(np.sqrt(np.mean(means**2))),
            "mean_within_std_m": float(np.nanmean([p["std_error_m"] for p in per])),
            "n": int(ok.sum()),
            "per_distance": per,
        }
    applied = corrections_applied(rg, curves, validity, dist)
    raw = ranges.get("paper_no_power", ranges["paper_none"])
    warnings = applied["warnings"] + distance_warnings(dkey, uniq, raw)
    return {"z_distance_m": zd, "distances_m": [float(v) for v in uniq], "methods": methods,
            "have_curves": bool(curves), "missing_methods": [k for k in TWR_METHODS if k not in ranges],
            "corrections": applied, "warnings": warnings}
