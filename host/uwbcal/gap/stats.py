"""Statistics machinery of the gap diagnosis, on plain numpy arrays (no physics here).

- :func:`bh_fdr`: Benjamini-Hochberg adjusted p-values.
- :func:`two_sample_stats`: location (Welch t), scale (log SD ratio) and shape (KS distance)
  of one sample against a reference sample, vectorised over many cells.
- :func:`floor_pvalues`: p-values of observed statistics against a sim-vs-sim noise floor
  (one statistic per simulated seed), with a Student-t predictive so p is not limited to
  1/(K+1) by the number of seeds K.
- :func:`group_features`: per-group, per-cell mean, log SD and lag-1 autocorrelation of an
  observable (the feature vector that attribution fits).
- :func:`lasso_cd`: Lasso by cyclic coordinate descent (the sparse cross-check).
- :func:`bootstrap_mean_ci`: percentile bootstrap CI of a mean over groups.
"""

from __future__ import annotations

from typing import Final, Literal

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

#: Statistics per cell and their names, in order of :func:`two_sample_stats`' output.
STAT_NAMES: Final = ("mean", "robust_loc", "scale", "shape")
#: Which statistics are two-sided (signed) and which one-sided distances (log scale).
STAT_SIGNED: Final = (True, True, True, False)
#: Feature statistics per group cell, in order of :func:`group_features`' output.
FEATURE_NAMES: Final = ("mean", "robust_loc", "log_scale", "lag1", "tail")


def bh_fdr(p: npt.ArrayLike) -> FloatArray:
    """Benjamini-Hochberg adjusted p-values (q-values); NaN entries stay NaN."""
    pv = np.asarray(p, dtype=np.float64)
    out = np.full(pv.shape, np.nan)
    ok = np.isfinite(pv)
    x = pv[ok]
    m = x.size
    if m == 0:
        return out
    from scipy.stats import false_discovery_control

    out[ok] = false_discovery_control(x, method="bh")
    return out


def robust_loc_scale(xs: FloatArray) -> tuple[float, float]:
    """(interquartile mean, mean absolute deviation from it) of a sorted sample.

    Both are averages, so they stay continuous for quantised data (a median or an IQR of
    timestamps jumps in whole device units); both resist the tails (multipath, outliers).
    """
    n = xs.size
    lo, hi = int(np.floor(0.25 * n)), int(np.ceil(0.75 * n))
    mid = xs[lo : max(hi, lo + 1)]
    loc = float(np.mean(mid))
    return loc, float(np.mean(np.abs(xs - loc)))


def two_sample_stats(
    x: FloatArray,
    ref_sorted: FloatArray,
    ref_mean: float,
    ref_var: float,
    x_sorted: FloatArray | None = None,
    x_robust: tuple[float, float] | None = None,
    ref_robust: tuple[float, float] | None = None,
    x_moments: tuple[float, float] | None = None,
) -> FloatArray:
    """(mean, median, scale, shape) of sample ``x`` against a reference sample.

    mean: Welch t of the mean difference (signed); median: difference of the robust
    locations (interquartile means) in units of the reference's robust scale (signed);
    scale: log ratio of the robust scales (mean absolute deviations; signed); shape: the KS
    distance of the two samples, each robustly standardised by its own location and scale,
    so shape is not a copy of location and scale. ``ref_sorted`` is the sorted
    reference (size N), ``ref_mean`` and ``ref_var`` its full (not subsampled) moments.
    ``x_sorted``, ``x_robust`` (:func:`robust_loc_scale` of ``x_sorted``), ``x_moments``
    (``np.mean(x)``, ``np.var(x, ddof=1)``) and ``ref_robust`` (of ``ref_sorted``) may be passed
    when known: a sample compared with many references is then sorted and summed once (the
    result is the same).
    """
    n = x.size
    if n < 5 or ref_sorted.size < 5:
        return np.full(4, np.nan)
    xs = np.sort(x) if x_sorted is None else x_sorted
    moments = (float(np.mean(x)), float(np.var(x, ddof=1))) if x_moments is None else x_moments
    x_rob = robust_loc_scale(xs) if x_robust is None else x_robust
    ref_rob = robust_loc_scale(ref_sorted) if ref_robust is None else ref_robust
    t, med, scale, (loc_x, den_x, loc_r, den_r) = location_scale(
        n, ref_sorted.size, moments, ref_mean, ref_var, x_rob, ref_rob
    )
    zr = (ref_sorted - loc_r) / den_r
    return np.array([t, med, scale, ks_distance(xs, loc_x, den_x, zr)])


def location_scale(
    n: int,
    nr: int,
    x_moments: tuple[float, float],
    ref_mean: float,
    ref_var: float,
    x_robust: tuple[float, float],
    ref_robust: tuple[float, float],
) -> tuple[float, float, float, tuple[float, float, float, float]]:
    """(mean, median, scale) of :func:`two_sample_stats` from the samples' sizes, moments and robust
    (location, scale), and the standardisations of its KS distance: (sample location, its divisor,
    reference location, its divisor), each sample's own location and scale (+ a tiny guard)."""
    mean_x, var_x = x_moments
    t = (mean_x - ref_mean) / np.sqrt(var_x / n + ref_var / nr + 1e-300)
    loc_x, sc_x = x_robust
    loc_r, sc_r = ref_robust
    tiny = 1e-300 + 1e-12 * max(abs(loc_r), abs(loc_x))
    med = (loc_x - loc_r) / (sc_r + tiny)
    scale = np.log((sc_x + tiny) / (sc_r + tiny))
    return float(t), float(med), float(scale), (loc_x, sc_x + tiny, loc_r, sc_r + tiny)


#: Index strides of :func:`ks_distance`'s levels: the ECDF difference is evaluated at every
#: 1024th sorted value, then every 32nd and every one only where a block can hold the maximum.
_KS_STRIDES: Final = (1024, 32, 1)


def ks_distance(xs: FloatArray, loc: float, den: float, zr: FloatArray) -> float:
    """KS distance of the sample ``z = (xs - loc) / den`` (``xs`` sorted, ``den`` > 0) from the
    sorted reference ``zr`` (both dimensionless):
    max over i of max(|i/n - F(z_i)|, |(i - 1)/n - F(z_i)|), F the ECDF of ``zr``.

    Exactly that maximum (the same float: each term is computed by the same operations as over
    every i), by branch and bound: with i_k = (k + 1)/n, both i_k and F(z_k) grow with k, so
    between two evaluated indices s < e every term is at most max(i_e - 1/n - F(z_s), F(z_e) - i_s);
    a block whose bound (plus 1e-12 for rounding) is below the largest term found is never
    searched. The ECDF is then looked up for a few thousand of the n values, not all of them (a
    binary search per value was most of the localisation's time).
    """
    n, nr = xs.size, zr.size
    inv_n = 1.0 / n

    def terms(idx: IntArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        cdf = np.searchsorted(zr, (xs[idx] - loc) / den, side="right") / nr
        i = (idx + 1) / n
        return np.maximum(np.abs(i - cdf), np.abs(i - inv_n - cdf)), cdf, i

    if n <= 4 * _KS_STRIDES[0]:
        return float(np.max(terms(np.arange(n))[0]))
    idx = np.unique(np.append(np.arange(0, n, _KS_STRIDES[0]), n - 1))
    val, cdf, i = terms(idx)
    best = float(np.max(val))
    for stride in _KS_STRIDES[1:]:
        bound = np.maximum(i[1:] - inv_n - cdf[:-1], cdf[1:] - i[:-1]) + 1e-12
        open_ = (idx[1:] - idx[:-1] > 1) & (bound >= best)
        if not np.any(open_):
            break
        s, e = idx[:-1][open_], idx[1:][open_]
        cnt = (e - s - 1) // stride  # new indices s + stride, s + 2 stride, ... < e
        first = np.repeat(np.cumsum(cnt) - cnt, cnt)
        new = np.repeat(s, cnt) + stride * (np.arange(int(cnt.sum())) - first + 1)
        v_new, c_new, i_new = terms(new)
        best = max(best, float(np.max(v_new))) if new.size else best
        order = np.argsort(np.concatenate([idx, new]), kind="stable")
        idx = np.concatenate([idx, new])[order]
        cdf = np.concatenate([cdf, c_new])[order]
        i = np.concatenate([i, i_new])[order]
    return best


class LeaveOneOut:
    """A sorted pooled reference of K seeds' values, searched without one seed (its leave-one-out
    references) after a standardisation of each: ``count(j, q, loc, den)`` is the number of values
    r of the pool not from seed j with (r - loc) / den <= q, exactly as np.searchsorted(zr, q,
    "right") on zr = (the reference without seed j - loc) / den, without building that reference.

    ``pool`` sorted (M,), ``src`` (M,) the seed of each value (0..k-1).
    """

    def __init__(self, pool: FloatArray, src: IntArray, k: int) -> None:
        self.pool = pool
        order = np.argsort(src, kind="stable")  # by seed, each seed's values still sorted
        self.own = pool[order]
        self.n_own = np.bincount(src, minlength=k)
        self.off = np.concatenate([[0], np.cumsum(self.n_own)[:-1]])
        # (seed, value) as complex numbers, which numpy orders by real part, then imaginary part:
        # one search finds a value among one seed's values
        self.keys = np.empty(pool.size, np.complex128)
        self.keys.real, self.keys.imag = src[order], self.own
        self.sizes = pool.size - self.n_own  # size of each leave-one-out reference

    def count(self, j: IntArray, q: FloatArray, loc: FloatArray, den: FloatArray) -> IntArray:
        """Per query: #{r in the pool without seed j[i]: (r - loc[i]) / den[i] <= q[i]}."""
        t = loc + q * den  # about where (r - loc) / den crosses q; corrected exactly below
        below = _settle(self.pool, np.searchsorted(self.pool, t, side="right"), q, loc, den, None)
        key = np.empty(t.size, np.complex128)
        key.real, key.imag = j, t
        at = np.searchsorted(self.keys, key, side="right")
        own = _settle(self.own, at, q, loc, den, (self.keys, j, self.off[j], self.off[j] + self.n_own[j]))
        return np.asarray(below - (own - self.off[j]), dtype=np.int64)


def _settle(
    vals: FloatArray,
    p: IntArray,
    q: FloatArray,
    loc: FloatArray,
    den: FloatArray,
    seg: tuple[npt.NDArray[np.complex128], IntArray, IntArray, IntArray] | None,
) -> IntArray:
    """Move each position p to the exact count of ``vals`` in its range (all of them, or with
    ``seg`` = (complex keys, seed, first, end) one seed's) whose (v - loc) / den <= q: the
    standardisation is monotone in v, so the count is where it crosses q; a step moves past a
    whole run of equal values (all sides of the crossing are checked with the same float
    operations as a standardised array, (v - loc) / den)."""
    lo = np.zeros_like(p) if seg is None else seg[2]
    hi = np.full_like(p, vals.size) if seg is None else seg[3]
    p = p.copy()
    while True:
        up = p < hi
        up[up] = (vals[p[up]] - loc[up]) / den[up] <= q[up]
        down = p > lo
        down[down] = (vals[p[down] - 1] - loc[down]) / den[down] > q[down]
        if not (np.any(up) or np.any(down)):
            return p
        if np.any(up):  # past the run of values equal to vals[p]
            p[up] = _run_edge(vals, vals[p[up]], seg, up, "right")
        if np.any(down):  # to the start of the run of values equal to vals[p - 1]
            p[down] = _run_edge(vals, vals[p[down] - 1], seg, down, "left")


def _run_edge(
    vals: FloatArray,
    v: FloatArray,
    seg: tuple[npt.NDArray[np.complex128], IntArray, IntArray, IntArray] | None,
    mask: npt.NDArray[np.bool_],
    side: Literal["left", "right"],
) -> IntArray:
    """np.searchsorted(vals, v, side), or within each query's seed with ``seg`` (:func:`_settle`)."""
    if seg is None:
        return np.searchsorted(vals, v, side=side)
    key = np.empty(v.size, np.complex128)
    key.real, key.imag = seg[1][mask], v
    return np.searchsorted(seg[0], key, side=side)


#: Index strides of :func:`ks_distances`' levels (more than :data:`_KS_STRIDES`: a level costs a
#: few numpy calls for all problems together, and each search there costs more).
_KS_LEVELS: Final = (1024, 128, 16, 4, 1)


def ks_distances(
    xs: FloatArray,
    start: IntArray,
    n: IntArray,
    loc: FloatArray,
    den: FloatArray,
    ref: LeaveOneOut,
    seed: IntArray,
    ref_loc: FloatArray,
    ref_den: FloatArray,
) -> FloatArray:
    """:func:`ks_distance` of many samples against leave-one-out references at once, the same floats.

    Problem p: the sorted sample ``xs[start[p] : start[p] + n[p]]`` standardised by ``loc[p]``,
    ``den[p]``, against the reference ``ref`` without seed ``seed[p]``, standardised by
    ``ref_loc[p]``, ``ref_den[p]``. The branch and bound of :func:`ks_distance` runs on every
    problem in the same numpy calls (a localisation cell has 2 K of them).
    """
    n_p = start.size
    if n_p == 0:
        return np.zeros(0)
    nr = ref.sizes[seed]

    def terms(prob: IntArray, idx: IntArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        nn = n[prob]
        q = (xs[start[prob] + idx] - loc[prob]) / den[prob]
        cdf = ref.count(seed[prob], q, ref_loc[prob], ref_den[prob]) / nr[prob]
        i = (idx + 1) / nn
        return np.maximum(np.abs(i - cdf), np.abs(i - 1.0 / nn - cdf)), cdf, i

    def grid(first: IntArray, last: IntArray, stride: int) -> tuple[IntArray, IntArray]:
        """(entry, index) of first, first + stride, ... < last for every entry."""
        cnt = np.maximum((last - first - 1) // stride + 1, 0)
        rep = np.repeat(np.arange(first.size), cnt)
        return rep, first[rep] + stride * (np.arange(rep.size) - np.repeat(np.cumsum(cnt) - cnt, cnt))

    best = np.full(n_p, -np.inf)

    def keep_best(prob: IntArray, val: FloatArray) -> None:
        """best[p] = max(best[p], the values of problem p); ``prob`` is sorted."""
        if prob.size:
            cut = np.flatnonzero(np.concatenate([[True], prob[1:] != prob[:-1]]))
            best[prob[cut]] = np.maximum(best[prob[cut]], np.maximum.reduceat(val, cut))

    # level 0: every problem at 0, S, 2 S, ... and its last value; blocks between neighbours
    rep, idx = grid(np.zeros(n_p, np.int64), n, _KS_LEVELS[0])
    tail = np.flatnonzero((n - 1) % _KS_LEVELS[0] != 0)
    prob = np.concatenate([rep, tail])
    idx = np.concatenate([idx, (n - 1)[tail]])
    order = np.lexsort((idx, prob))
    prob, idx = prob[order], idx[order]
    val, cdf, i = terms(prob, idx)
    keep_best(prob, val)
    inner = prob[1:] == prob[:-1]
    # the open blocks: problem, first and last index, and the ECDF and i/n there
    bp, bs, be = prob[:-1][inner], idx[:-1][inner], idx[1:][inner]
    cs, ce, is_, ie = cdf[:-1][inner], cdf[1:][inner], i[:-1][inner], i[1:][inner]
    for level, stride in enumerate(_KS_LEVELS[1:], 1):
        bound = np.maximum(ie - 1.0 / n[bp] - cs, ce - is_) + 1e-12
        keep = (be - bs > 1) & (bound >= best[bp])
        if not np.any(keep):
            break
        bp, bs, be, cs, ce, is_, ie = (x[keep] for x in (bp, bs, be, cs, ce, is_, ie))
        rep, idx = grid(bs + stride, be, stride)
        val, cdf, i = terms(bp[rep], idx)
        keep_best(bp[rep], val)
        if level == len(_KS_LEVELS) - 1:
            break
        # each open block becomes the blocks between its first index, the new ones and its last
        nb = bs.size
        cnt = np.bincount(rep, minlength=nb)
        pos = np.cumsum(cnt + 1) - (cnt + 1)  # where each block's points start, its first first
        size = int(cnt.sum()) + nb
        pts = np.empty(size, np.int64)
        c_pt, i_pt = np.empty(size), np.empty(size)
        blk = np.repeat(np.arange(nb), cnt + 1)
        first = np.zeros(size, bool)
        first[pos] = True
        pts[pos], c_pt[pos], i_pt[pos] = bs, cs, is_
        rest = ~first
        pts[rest], c_pt[rest], i_pt[rest] = idx, cdf, i
        # blocks: (point, next point) within a block, and (last point, the block's end)
        last = np.append(pos[1:], size) - 1
        nxt = np.arange(1, size + 1)
        end = np.zeros(size, bool)
        end[last] = True
        e_idx = np.where(end, be[blk], pts[np.minimum(nxt, size - 1)])
        e_cdf = np.where(end, ce[blk], c_pt[np.minimum(nxt, size - 1)])
        e_i = np.where(end, ie[blk], i_pt[np.minimum(nxt, size - 1)])
        bp, bs, be, cs, ce, is_, ie = bp[blk], pts, e_idx, c_pt, e_cdf, i_pt, e_i
    return best


def to_floor_scale(x: FloatArray, signed: tuple[bool, ...] = STAT_SIGNED) -> FloatArray:
    """Statistics (..., S) on the scale their floor is judged on: signed ones as they are, the
    positive distances (``signed`` False; default :data:`STAT_SIGNED`) as log (a copy)."""
    out = np.array(x, dtype=np.float64)
    sgn = np.asarray(signed[: out.shape[-1]])
    out[..., ~sgn] = np.log(np.maximum(out[..., ~sgn], 1e-12))
    return out


def floor_tail_dof(
    null: FloatArray, family: IntArray, min_values: int = 60, scaled: bool = False
) -> FloatArray:
    """Degrees of freedom of the floor's predictive per cell and statistic, from its own tails.

    ``null`` (K, C, S) as in :func:`floor_pvalues`; ``family`` (C,) groups cells whose statistics
    share a distribution (the same observable). Each seed's statistic is standardised against the
    other K - 1 seeds of its cell (Student t with K - 2 dof if the statistic were normal); per
    family and statistic the pooled values give a maximum-likelihood t dof (location 0, scale 1).
    A statistic with heavier tails across run seeds than a normal one (a rare run with a wider
    RX-level spread, say) then gets fewer dof, so one such run is not a discovery. Capped at K - 1.
    ``scaled``: ``null`` is already on the floor's scale (:func:`to_floor_scale`).
    """
    from scipy import stats as sps

    nul = np.array(null, dtype=np.float64) if scaled else to_floor_scale(null)
    k = nul.shape[0]
    out = np.full(nul.shape[1:], float(max(k - 1, 1)))
    if k < 5:
        return out
    z = np.full_like(nul, np.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        for j in range(k):
            others = np.delete(nul, j, axis=0)
            m = np.nanmean(others, axis=0)
            sd = np.nanstd(others, axis=0, ddof=1) * np.sqrt(1.0 + 1.0 / (k - 1))
            z[j] = (nul[j] - m) / np.where(sd > 0, sd, np.nan)
    for f in np.unique(family):
        cells = family == f
        for si in range(nul.shape[-1]):
            v = z[:, cells, si].ravel()
            v = v[np.isfinite(v)]
            if v.size < min_values:
                continue
            df, _, _ = sps.t.fit(v, floc=0.0, fscale=1.0)
            out[cells, si] = float(np.clip(df, 1.0, k - 1))
    return out


def floor_pvalues(
    observed: FloatArray,
    null: FloatArray,
    dof: FloatArray | None = None,
    signed: tuple[bool, ...] = STAT_SIGNED,
    scaled: bool = False,
) -> tuple[FloatArray, FloatArray]:
    """Two-sided p-values and floor z-scores of statistics against their sim-vs-sim floor.

    ``observed`` has shape (C, S) for C cells and the S statistics of :data:`STAT_NAMES`;
    ``null`` shape (K, C, S): the same statistics of K simulated seeds, each against the
    other seeds. Signed statistics are compared on their own scale (two-sided), distances
    on log scale (one-sided, larger is worse). The predictive distribution of a new null
    statistic is Student t with K-1 degrees of freedom around the floor's mean with the
    floor's SD * sqrt(1 + 1/K); ``dof`` (C, S), if given, replaces K - 1 (:func:`floor_tail_dof`).
    ``signed``: which of the S statistics are signed (default :data:`STAT_SIGNED`, the
    localisation's); the others are positive distances, judged on log scale, one-sided.
    ``scaled``: both are already on that scale (:func:`to_floor_scale`).
    """
    from scipy import stats

    sgn = np.asarray(signed[: observed.shape[-1]])
    if scaled:
        obs = np.array(observed, dtype=np.float64)
        nul = np.array(null, dtype=np.float64)
    else:
        obs = to_floor_scale(observed, signed)
        nul = to_floor_scale(null, signed)
    k = np.sum(np.isfinite(nul), axis=0)
    with np.errstate(invalid="ignore"):
        mu = np.nanmean(nul, axis=0)
        sd = np.nanstd(nul, axis=0, ddof=1)
    sd = np.maximum(np.nan_to_num(sd, nan=0.0), 1e-12)
    z = (obs - mu) / (sd * np.sqrt(1.0 + 1.0 / np.maximum(k, 1)))
    df = np.maximum(k - 1, 1) if dof is None else np.minimum(np.maximum(k - 1, 1), dof)
    p = np.where(sgn, 2.0 * stats.t.sf(np.abs(z), df), stats.t.sf(z, df))
    bad = (k < 3) | ~np.isfinite(obs)
    p[bad] = np.nan
    z[bad] = np.nan
    return p, z


def group_features(
    values: FloatArray,
    cell: IntArray,
    n_cells: int,
    order_key: FloatArray,
    min_count: int = 5,
    order: IntArray | None = None,
) -> FloatArray:
    """Per-cell (mean, robust location, log robust scale, lag-1 autocorrelation, tail), shape (n_cells, 5).

    tail = log(SD / mean absolute deviation): log(1.2533) for a normal sample, larger for heavy
    tails (multipath), smaller for bimodal ones.

    Robust location and scale as in :func:`robust_loc_scale` (interquartile mean, mean
    absolute deviation from it). ``cell`` is each value's cell index in [0, n_cells);
    ``order_key`` orders the values in time (the lag-1 pairs are consecutive values of the
    same cell). Cells with fewer than ``min_count`` values are NaN. Units: mean and location
    in the observable's unit, log scale of that unit, autocorrelation and tail dimensionless.
    ``order``, if given, is ``np.lexsort((order_key, cell))`` (known to the caller when many
    sessions share their cells and times); all values must then be finite.
    """
    ok = np.isfinite(values)
    if order is not None and not np.all(ok):
        raise ValueError("group_features: a precomputed order needs finite values")
    c = cell[ok]
    if order is None:
        order = np.lexsort((order_key[ok], c))
    return GroupPlan(c, n_cells, order, min_count).features(values[ok])


class GroupPlan:
    """The index work of :func:`group_features` for one layout: which cell each value is in and
    their (cell, time) order. Sessions that share the layout (every re-simulation of the real
    schedule, when the same records are finite) share the plan; :meth:`features` then does only
    the arithmetic on the values, the same operations in the same order as without a plan."""

    def __init__(self, cell: IntArray, n_cells: int, order: IntArray, min_count: int) -> None:
        self.cell, self.n_cells, self.order, self.min_count = cell, n_cells, order, min_count
        self.cnt = np.bincount(cell, minlength=n_cells)
        cs = cell[order]
        # cell of each pair of neighbours in the (cell, time) order, n_cells where the cell changes
        # (a bin of its own, dropped: the cells' bins see the same products in the same order)
        self.lag_cell = np.where(cs[1:] == cs[:-1], cs[1:], n_cells)
        self.start = np.concatenate([[0], np.cumsum(self.cnt)[:-1]])
        self.segments = [
            (int(self.start[ci]), int(self.start[ci] + self.cnt[ci])) for ci in np.flatnonzero(self.cnt > 1)
        ]
        self.lo = np.floor(0.25 * self.cnt).astype(np.int64)
        self.hi = np.maximum(np.ceil(0.75 * self.cnt).astype(np.int64), self.lo + 1)
        self.good = self.cnt >= min_count

    def features(self, v: FloatArray) -> FloatArray:
        """:func:`group_features` of the finite values ``v`` (one per entry of ``cell``), (n_cells, 5)."""
        n_cells, c, cnt = self.n_cells, self.cell, self.cnt
        out = np.full((n_cells, 5), np.nan)
        if v.size == 0:
            return out
        s1 = np.bincount(c, weights=v, minlength=n_cells)
        mean = s1 / np.maximum(cnt, 1)
        dev = v - mean[c]
        s2 = np.bincount(c, weights=dev * dev, minlength=n_cells)
        ds = dev[self.order]
        prod = np.bincount(self.lag_cell, weights=ds[1:] * ds[:-1], minlength=n_cells + 1)[:n_cells]
        lag1 = prod / np.maximum(s2, 1e-300)
        # values sorted by (cell, value), as v[np.lexsort((v, c))]: ``order`` already groups them by
        # cell (ascending), so each cell's segment is sorted on its own (a third of the time)
        vs = v[self.order]
        for lo_, hi_ in self.segments:
            vs[lo_:hi_] = np.sort(vs[lo_:hi_])
        csum = np.concatenate([[0.0], np.cumsum(vs)])
        start, lo, hi = self.start, self.lo, self.hi
        loc = (csum[np.minimum(start + hi, vs.size)] - csum[start + lo]) / (hi - lo)
        mad = np.bincount(c, weights=np.abs(v - loc[c]), minlength=n_cells) / np.maximum(cnt, 1)
        good = self.good
        out[good, 0] = mean[good]
        out[good, 1] = loc[good]
        out[good, 2] = np.log(np.maximum(mad[good], 1e-300))
        out[good, 3] = lag1[good]
        sd = np.sqrt(s2 / np.maximum(cnt - 1, 1))
        out[good, 4] = np.log(np.maximum(sd[good], 1e-300) / np.maximum(mad[good], 1e-300))
        return out


def lasso_cd(x: FloatArray, y: FloatArray, lam: float, n_iter: int = 500, tol: float = 1e-8) -> FloatArray:
    """Lasso: argmin_b 0.5 ||y - X b||^2 + lam ||b||_1 by cyclic coordinate descent."""
    n, p = x.shape
    b = np.zeros(p)
    col2 = np.sum(x * x, axis=0)
    r = y.copy()
    for _ in range(n_iter):
        delta = 0.0
        for j in range(p):
            if col2[j] <= 0:
                continue
            rho = float(x[:, j] @ r) + col2[j] * b[j]
            new = np.sign(rho) * max(abs(rho) - lam, 0.0) / col2[j]
            if new != b[j]:
                r -= x[:, j] * (new - b[j])
                delta = max(delta, abs(new - b[j]))
                b[j] = new
        if delta < tol:
            break
    return b


def bootstrap_mean_ci(
    values: FloatArray, rng: np.random.Generator, n_boot: int = 2000, level: float = 0.95
) -> tuple[float, float, float]:
    """(mean, low, high): percentile bootstrap CI of the mean of ``values`` (one per group)."""
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return (float("nan"),) * 3
    idx = rng.integers(0, v.size, size=(n_boot, v.size))
    means = v[idx].mean(axis=1)
    a = (1.0 - level) / 2.0
    return float(v.mean()), float(np.quantile(means, a)), float(np.quantile(means, 1.0 - a))


def ratio_ci(
    num: FloatArray, den: FloatArray, rng: np.random.Generator, n_boot: int = 2000, level: float = 0.95
) -> tuple[float, float, float]:
    """(ratio, low, high) of sum(num)/sum(den), bootstrap over groups (paired entries)."""
    a = np.asarray(num, dtype=np.float64)
    b = np.asarray(den, dtype=np.float64)
    ok = np.isfinite(a) & np.isfinite(b)
    a, b = a[ok], b[ok]
    if a.size == 0 or np.sum(b) == 0:
        return (float("nan"),) * 3
    idx = rng.integers(0, a.size, size=(n_boot, a.size))
    den_b = b[idx].sum(axis=1)
    r = np.where(den_b != 0, a[idx].sum(axis=1) / np.where(den_b != 0, den_b, 1.0), np.nan)
    q = (1.0 - level) / 2.0
    return float(a.sum() / b.sum()), float(np.nanquantile(r, q)), float(np.nanquantile(r, 1.0 - q))


def shrink_ci(
    exc_before: FloatArray,
    exc_after: FloatArray,
    rng: np.random.Generator,
    n_boot: int = 2000,
    level: float = 0.95,
) -> tuple[float, float, float]:
    """(shrink, low, high) of 1 - |sum(after)| / sum(before), bootstrap over groups.

    ``exc_*`` are per-group excess losses (loss minus its null expectation); the absolute value
    makes a model that over-predicts the scatter (negative excess) count as a mismatch too.
    """
    a = np.asarray(exc_before, dtype=np.float64)
    b = np.asarray(exc_after, dtype=np.float64)
    ok = np.isfinite(a) & np.isfinite(b)
    a, b = a[ok], b[ok]
    if a.size == 0 or a.sum() <= 0:
        return (float("nan"),) * 3
    idx = rng.integers(0, a.size, size=(n_boot, a.size))
    den = a[idx].sum(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(den > 0, 1.0 - np.abs(b[idx].sum(axis=1)) / den, np.nan)
    q = (1.0 - level) / 2.0
    return float(1.0 - abs(b.sum()) / a.sum()), float(np.nanquantile(r, q)), float(np.nanquantile(r, 1.0 - q))
