"""Per-station timestamp noise and time-local departures, from the real records alone.

**Per-station noise** (:func:`station_noise`). In direction i -> j the eq. 1 residual carries
the TX jitter of station i and the RX jitter of station j, both through the same factor, so its
variance is v_ij = a_i + b_j (a: TX jitter variance, b: RX jitter variance, in m^2 of the
residual). With two nodes the two directions give two equations in four unknowns: only
v_01 - v_10 = (a_0 - b_0) - (a_1 - b_1) is known, so a noisier receiver and a noisier
transmitter cannot be told apart (the report says so). With three or more nodes every contrast
b_j - b_k = v_ij - v_ik and a_i - a_k is identified (one common constant between all a and all b
is not: the split of the floor between TX and RX). Reported: each station's RX and TX excess
over the quietest station, as an RMS in ps of one timestamp (sqrt of the variance difference
divided by the residual's factor 1 + k^2 + (1 - k)^2, k = P1->P2 / P1->P3), with a bootstrap
CI over records. A station is **named** when its variance exceeds the mean of the other
stations' on the same side by more than the bootstrap SE of that contrast allows, Bonferroni over
the 2N contrasts at ``level`` (``z`` per row). Not the excess over the quietest: that one's CI is
about a distance to the sample minimum, which is above zero in a null (the simulated four-node
nulls of tests/unit/test_gap_nnode.py named a station at every seed tried, 7 of 7). Variances are
robust ((1.4826 MAD)^2 of the residual around its median), so a late-path tail is not read as
jitter.

**Time-local departures** (:func:`local_departures`). Per direction, windows of ``window_s``
(half-overlapping): the log ratio of the window's robust scale to the direction's, in units of
its standard error (1.166 / sqrt(n) for a log MAD of a normal sample); windows above the
Bonferroni-corrected threshold (over all windows and directions, level ``alpha``) are reported,
merged where they overlap. A burst of extra jitter in one direction shows here instead of
raising the global floor. This report is from the real records alone, with a normal sample's
standard error; the verdict's test of the same windows (:mod:`uwbcal.gap.criticism`, ``burst``)
takes the standard error and the mean from re-simulations with the named effects instead, so that
late paths or a heavy-tailed jitter the scenario holds are not read as a departure.

What these cannot see: jitter common to all stations (the floor itself, the simulation's job),
noise that is not white per message (a slow wander is removed with the residual's median), and
with two nodes anything that separates TX from RX.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from uwbcal.dw1000 import METRES_PER_UNIT, TIME_UNIT_S, wrap_diff
from uwbcal.gap import observables as obs_mod
from uwbcal.gap.config import FloatArray, IntArray

_C_M_PER_PS = METRES_PER_UNIT / TIME_UNIT_S * 1e-12


def _robust_var(x: FloatArray) -> float:
    x = x[np.isfinite(x)]
    if x.size < 10:
        return float("nan")
    med = float(np.median(x))
    return float((1.4826 * np.median(np.abs(x - med))) ** 2)


def _factor(rec: Mapping[str, Any], sel: np.ndarray) -> float:
    """1 + k^2 + (1 - k)^2 with k = P1->P2 / P1->P3 (median over the selected records)."""
    d12 = wrap_diff(np.asarray(rec["tx2"], np.int64)[sel], np.asarray(rec["tx1"], np.int64)[sel])
    d13 = wrap_diff(np.asarray(rec["tx3"], np.int64)[sel], np.asarray(rec["tx1"], np.int64)[sel])
    k = float(np.median(d12 / np.maximum(d13, 1)))
    return 1.0 + k * k + (1.0 - k) ** 2


def station_noise(
    rec: Mapping[str, Any], n_boot: int = 300, level: float = 0.95, seed: int = 0, prf_mhz: int = 64
) -> dict[str, Any]:
    """Per-station RX / TX timestamp-noise excess over the quietest station (see the module doc).
    ``prf_mhz``: the session's PRF (MHz), for the observables."""
    ob = obs_mod.observables(rec, prf_mhz)
    if "drift_residual_m" not in ob or rec.get("tx_station") is None:
        return {"separable": False, "reason": "no eq. 1 residual in these records"}
    r = ob["drift_residual_m"]
    tx = np.asarray(rec["tx_station"], np.int64)
    rx = np.asarray(rec["rx_station"], np.int64)
    nodes = sorted(set(tx.tolist()) | set(rx.tolist()))
    pairs = sorted({(int(a), int(b)) for a, b in zip(tx, rx, strict=True)})
    idx = {p: np.flatnonzero((tx == p[0]) & (rx == p[1])) for p in pairs}
    g = _factor(rec, np.ones(tx.size, bool))
    per_dir = {
        f"{a}->{b}": {
            "n": int(idx[(a, b)].size),
            "rms_ps": float(np.sqrt(_robust_var(r[idx[(a, b)]]) / g) / _C_M_PER_PS),
        }
        for a, b in pairs
    }
    out: dict[str, Any] = {"directions": per_dir, "nodes": nodes}
    if len(nodes) < 3:
        out.update(
            separable=False,
            reason=f"{len(nodes)} nodes: each direction mixes one station's TX jitter with the other's "
            "RX jitter; a noisier receiver and a noisier transmitter give the same records",
        )
        return out
    col = {n: i for i, n in enumerate(nodes)}
    x = np.zeros((len(pairs), 2 * len(nodes)))
    for row, (a, b) in enumerate(pairs):
        x[row, col[a]] = 1.0  # TX of a
        x[row, len(nodes) + col[b]] = 1.0  # RX of b

    def solve(v: FloatArray) -> tuple[FloatArray, FloatArray]:
        ok = np.isfinite(v)
        sol = np.linalg.lstsq(x[ok], v[ok], rcond=None)[0]
        a, b = sol[: len(nodes)], sol[len(nodes) :]
        return a - a.min(), b - b.min()

    v0 = np.array([_robust_var(r[idx[p]]) for p in pairs])
    a0, b0 = solve(v0)
    rng = np.random.default_rng(seed)
    boots = []
    for _ in range(n_boot):
        vb = np.array([_robust_var(r[rng.choice(idx[p], idx[p].size)]) for p in pairs])
        boots.append(np.concatenate(solve(vb)))
    bs = np.array(boots)
    q = (1.0 - level) / 2.0
    lo, hi = np.nanquantile(bs, q, axis=0), np.nanquantile(bs, 1.0 - q, axis=0)

    def ps(var_m2: float) -> float:
        return float(np.sign(var_m2) * np.sqrt(abs(var_m2) / g) / _C_M_PER_PS)

    # the contrast of each station with the mean of the others on its side (a null: zero), its SE
    # from the same bootstrap; named past the Bonferroni z of the 2N one-sided tests
    from scipy.stats import norm

    m = len(nodes)
    est0 = np.concatenate([a0, b0])
    contrast = _contrasts(est0, m)
    se = np.nanstd(np.array([_contrasts(b, m) for b in bs]), axis=0, ddof=1)
    z_named = float(norm.isf((1.0 - level) / 2.0 / (2 * m)))
    rows = []
    for i, n in enumerate(nodes):
        for side, est, j in (("rx", b0, len(nodes) + i), ("tx", a0, i)):
            z = float(contrast[j] / se[j]) if se[j] > 0 else float("nan")
            rows.append(
                {
                    "station": n,
                    "side": side,
                    "excess_rms_ps": ps(float(est[i])),
                    "ci_ps": [ps(float(lo[j])), ps(float(hi[j]))],
                    "excess_over_others_rms_ps": ps(float(contrast[j])),
                    "z": z,
                    "named": bool(z > z_named),
                }
            )
    out.update(
        separable=True,
        excess_over_quietest=rows,
        named=[f"station {rw['station']} {rw['side'].upper()}" for rw in rows if rw["named"]],
        level=level,
        z_named=z_named,
    )
    return out


def _contrasts(est: FloatArray, m: int) -> FloatArray:
    """Each entry minus the mean of the others on its side (TX: the first ``m``, RX: the rest)."""
    out = np.empty_like(est)
    for part in (slice(0, m), slice(m, 2 * m)):
        x = est[part]
        out[part] = x - (np.sum(x) - x) / max(m - 1, 1)
    return out


def _median_without(xs: FloatArray, skip: IntArray) -> np.float64:
    """np.median of sorted ``xs`` without the entries at the sorted positions ``skip``, with
    np.median's arithmetic (the middle value, or the mean of the middle two)."""
    n = xs.size - skip.size
    free_before = skip - np.arange(skip.size)  # kept entries before each skipped one

    def kth(k: int) -> float:  # the k-th (from 0) kept entry
        return float(xs[k + int(np.searchsorted(free_before, k, side="right"))])

    if n % 2:
        return np.float64(kth(n // 2))
    return np.float64(np.mean(np.array([kth(n // 2 - 1), kth(n // 2)])))


def windows(ts: FloatArray, window_s: float = 10.0, min_n: int = 30) -> list[tuple[float, float, int, int]]:
    """The time windows of one direction's records at times ``ts`` (s): ``window_s`` long,
    half-overlapping, from the first record on, each as (start s, end s, i0, i1) with [i0, i1)
    the records with start <= t < end in time order (``np.argsort(ts, kind="stable")``); only
    windows with at least ``min_n`` records inside and outside. None when the direction has
    fewer than 2 ``min_n`` records."""
    if ts.size < 2 * min_n:
        return []
    ts_t = np.sort(ts, kind="stable")
    out: list[tuple[float, float, int, int]] = []
    for start in np.arange(ts_t[0], ts_t[-1] - window_s / 2, window_s / 2):
        i0, i1 = (int(i) for i in np.searchsorted(ts_t, [start, start + window_s], side="left"))
        if min_n <= i1 - i0 <= ts.size - min_n:
            out.append((float(start), float(start + window_s), i0, i1))
    return out


def window_log_ratios(values_t: FloatArray, wins: list[tuple[float, float, int, int]]) -> FloatArray:
    """log(median absolute deviation inside / outside) of each window of :func:`windows`, the
    deviations taken from the whole direction's median: ``values_t`` are the direction's values
    in time order (non-finite ones are left out of every median). A window whose jitter is that of
    the rest gives about 0."""
    if not np.all(np.isfinite(values_t)):  # rare (a re-simulated record lost): plain nan-medians
        dev = np.abs(values_t - np.nanmedian(values_t))
        return np.array(
            [np.log(np.nanmedian(dev[i0:i1]) / max(float(np.nanmedian(np.r_[dev[:i0], dev[i1:]])), 1e-300))
             for _s, _e, i0, i1 in wins]
        )
    dev = np.abs(values_t - np.median(values_t))
    # the median of the rest is read off the sorted deviations with the window's entries skipped
    # (np.median of each complement was most of the time: a partition of the whole direction per window)
    by_dev = np.argsort(dev)
    dev_sorted = dev[by_dev]
    rank = np.empty(dev.size, np.int64)
    rank[by_dev] = np.arange(dev.size)
    out = np.empty(len(wins))
    for k, (_s, _e, i0, i1) in enumerate(wins):
        med_in = np.median(dev[i0:i1])
        med_out = _median_without(dev_sorted, np.sort(rank[i0:i1]))
        out[k] = np.log(med_in / max(float(med_out), 1e-300))
    return out


def local_departures(
    rec: Mapping[str, Any], window_s: float = 10.0, alpha: float = 0.01, min_n: int = 30, prf_mhz: int = 64
) -> list[dict[str, Any]]:
    """Time windows whose eq. 1 residual spread departs from the rest of their direction.
    ``prf_mhz``: the session's PRF (MHz), for the observables."""
    from scipy.stats import norm

    ob = obs_mod.observables(rec, prf_mhz)
    if "drift_residual_m" not in ob or rec.get("t_s") is None:
        return []
    r = ob["drift_residual_m"]
    t = np.asarray(rec["t_s"], np.float64)
    tx = np.asarray(rec["tx_station"], np.int64)
    rx = np.asarray(rec["rx_station"], np.int64)
    cands: list[tuple[str, float, float, int, float, float]] = []
    n_tests = 0
    for a, b in sorted({(int(p), int(q)) for p, q in zip(tx, rx, strict=True)}):
        sel = (tx == a) & (rx == b) & np.isfinite(r)
        ts, rs = t[sel], r[sel]
        wins = windows(ts, window_s, min_n)
        if not wins:
            continue
        by_t = np.argsort(ts, kind="stable")
        ratios = window_log_ratios(rs[by_t], wins)
        n_tests += len(wins)
        for (start, end, i0, i1), lr in zip(wins, ratios, strict=True):
            nw = i1 - i0
            z = float(lr / (1.166 / np.sqrt(nw)))
            cands.append((f"{a}->{b}", start, end, nw, z, float(np.exp(lr))))
    if not n_tests:
        return []
    thr = float(norm.isf(alpha / (2 * n_tests)))
    hits = sorted([c for c in cands if abs(c[4]) > thr], key=lambda c: (c[0], c[1]))
    merged: list[dict[str, Any]] = []
    for d, s, e, nw, z, ratio in hits:
        if merged and merged[-1]["direction"] == d and s <= merged[-1]["end_s"]:
            m = merged[-1]
            m["end_s"] = e
            if abs(z) > abs(m["z"]):
                m.update(z=z, scale_ratio=ratio, n=nw)
            continue
        merged.append({"direction": d, "start_s": s, "end_s": e, "n": nw, "z": z, "scale_ratio": ratio})
    for m in merged:
        m["threshold_z"] = thr
    return merged
