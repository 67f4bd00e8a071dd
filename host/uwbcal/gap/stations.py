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
(half-overlapping): the log ratio of the window's spread to the rest of the direction's
(:func:`window_log_ratios`: a clipped mean deviation), in units of its standard error for a
normal sample (:func:`_clipped_cv` x sqrt(1/n_in + 1/n_out)); windows above the
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
from typing import Any, Final

import numpy as np

from uwbcal.dw1000 import METRES_PER_UNIT, TIME_UNIT_S, wrap_diff
from uwbcal.gap import observables as obs_mod
from uwbcal.gap.config import FloatArray

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


def windows(ts: FloatArray, window_s: float = 10.0, min_n: int = 30) -> list[tuple[float, float, int, int]]:
    """The time windows of one direction's records at times ``ts`` (s): ``window_s`` long,
    half-overlapping, from the first record on, each as (start s, end s, i0, i1) with [i0, i1)
    the records with start <= t < end in time order (``np.argsort(ts, kind="stable")``); only
    windows with at least ``min_n`` records inside and outside. Empty when the direction has
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


#: Where the window spread clips each absolute deviation, in robust SDs of the whole direction.
CLIP_SD: Final = 2.5


def _clipped_cv(c: float = CLIP_SD) -> float:
    """Coefficient of variation of min(|X|, c) for a standard normal X: the standard error of a
    window's log clipped mean deviation is this over sqrt(n) (a normal sample)."""
    from scipy.stats import norm

    tail = 2.0 * float(norm.sf(c))
    m1 = 2.0 * float(norm.pdf(0.0) - norm.pdf(c)) + c * tail
    m2 = (1.0 - tail - 2.0 * c * float(norm.pdf(c))) + c * c * tail
    return float(np.sqrt(m2 - m1 * m1) / m1)


def window_log_ratios(values_t: FloatArray, wins: list[tuple[float, float, int, int]]) -> FloatArray:
    """log(clipped mean deviation inside / outside) of each window of :func:`windows`:
    ``values_t`` are the direction's values in time order (non-finite ones left out). A window whose
    jitter is that of the rest gives about 0.

    The deviation is |v - median| of the whole direction, clipped at :data:`CLIP_SD` robust SDs
    (1.4826 MAD; 1.2533 x the mean deviation where more than half the values sit on the median):
    far late paths count as clipped values, so a window's spread does not follow the size of
    a few of them, only how many there are. Not a median of the deviations: the eq. 1 residual
    of timestamps in whole DW1000 ticks (15.65 ps) takes values on a lattice, and with a floor
    below the tick every window's median deviation is the same lattice value (the ratios of
    re-simulations were exactly 0, and any real difference infinitely many SDs out)."""
    ok = np.isfinite(values_t)
    v = np.where(ok, values_t, 0.0)
    dev = np.abs(v - np.median(values_t[ok])) if np.any(ok) else np.zeros_like(v)
    sd = 1.4826 * float(np.median(dev[ok])) if np.any(ok) else 0.0
    if not sd > 0:
        sd = 1.2533 * float(np.mean(dev[ok])) if np.any(ok) else 0.0
    if not sd > 0:
        return np.zeros(len(wins))
    d = np.where(ok, np.minimum(dev, CLIP_SD * sd), 0.0)
    cs = np.concatenate([[0.0], np.cumsum(d)])
    cn = np.concatenate([[0], np.cumsum(ok)])
    out = np.empty(len(wins))
    for k, (_s, _e, i0, i1) in enumerate(wins):
        s_in, n_in = cs[i1] - cs[i0], cn[i1] - cn[i0]
        s_out, n_out = cs[-1] - s_in, cn[-1] - n_in
        if n_in == 0 or n_out == 0 or s_in <= 0 or s_out <= 0:
            out[k] = np.nan
            continue
        out[k] = np.log((s_in / n_in) / (s_out / n_out))
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
        cv = _clipped_cv()
        for (start, end, i0, i1), lr in zip(wins, ratios, strict=True):
            nw = i1 - i0
            z = float(lr / (cv * np.sqrt(1.0 / nw + 1.0 / (rs.size - nw))))
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
