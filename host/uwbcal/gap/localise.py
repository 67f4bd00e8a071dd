"""Step 1 of the diagnosis: where do the real records differ from the re-simulations?

Per observable and regime bin, four two-sample statistics of the real records against the
pooled re-simulations, judged against the sim-vs-sim noise floor (Benjamini-Hochberg FDR).

Like is compared with like: the floor compares each simulated seed with the pool of the other
K - 1 seeds, and the real records are compared with the same leave-one-out pools of K - 1 seeds
(the statistic averaged over the K pools), so a statistic that depends on the pool's size (a
robust location of a two-mode sample, a KS distance against a discrete reference) is not
offset against its own floor. Where the session has several directions (TX -> RX pairs), which
differ by design (the clock rate is +x ppm one way and -x ppm the other), every regime bin is
split by direction and no cell pools directions.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from uwbcal.gap import observables as obs_mod
from uwbcal.gap import stats
from uwbcal.gap.config import Config, FloatArray, Records
from uwbcal.gap.forked import forked_map


@dataclass
class Cell:
    """One localisation cell's result."""

    observable: str
    regime: str
    key: int
    label: str
    n_real: int
    real_mean: float
    sim_mean: float
    real_sd: float
    sim_sd: float
    z: tuple[float, ...]
    p: tuple[float, ...]
    q: tuple[float, ...]
    direction: int = -1  # direction key (1000 * tx + rx) the cell is restricted to; -1 all
    #: the raw statistics behind z, p, q (:data:`stats.STAT_NAMES`): the real records' (S,) and
    #: each run seed's against the other seeds (K, S); kept so several diagnoses' floors can be
    #: pooled into one decision (:func:`pooled`)
    stat_obs: FloatArray | None = field(default=None, compare=False, repr=False)
    stat_null: FloatArray | None = field(default=None, compare=False, repr=False)

    @property
    def ident(self) -> tuple[str, str, int, int]:
        """What identifies the cell across diagnoses: (observable, regime, key, direction)."""
        return (self.observable, self.regime, self.key, self.direction)

    def to_json(self) -> dict[str, Any]:
        return {
            "observable": self.observable,
            "unit": obs_mod.OBSERVABLES.get(self.observable, ""),
            "regime": self.regime,
            "key": self.key,
            "direction": obs_mod.label("direction", self.direction) if self.direction >= 0 else "all",
            "label": self.label,
            "n_real": self.n_real,
            "real_mean": self.real_mean,
            "sim_mean": self.sim_mean,
            "real_sd": self.real_sd,
            "sim_sd": self.sim_sd,
            "mean_diff": self.real_mean - self.sim_mean,
            "sd_ratio": self.real_sd / self.sim_sd if self.sim_sd > 0 else float("nan"),
            "cohen_d": (self.real_mean - self.sim_mean) / self.sim_sd if self.sim_sd > 0 else float("nan"),
            **{f"z_{s}": v for s, v in zip(stats.STAT_NAMES, self.z, strict=True)},
            **{f"p_{s}": v for s, v in zip(stats.STAT_NAMES, self.p, strict=True)},
            **{f"q_{s}": v for s, v in zip(stats.STAT_NAMES, self.q, strict=True)},
        }


Summary = tuple[dict[str, FloatArray], obs_mod.Regimes]


def summarise(
    rec: Records,
    t_edges: FloatArray,
    regimes: obs_mod.Regimes | None = None,
    prf_mhz: int = 64,
    ob: dict[str, FloatArray] | None = None,
) -> Summary:
    """Observables and regime keys of one session (what localisation needs).

    ``regimes`` (the real session's) are used when the record counts agree: a re-simulation
    of the real schedule is compared record slot by record slot in the real conditions.
    ``prf_mhz`` is the session's PRF (MHz; the RX level observables depend on it). ``ob``: the
    records' observables at that PRF, if already computed.
    """
    ob = obs_mod.observables(rec, prf_mhz) if ob is None else ob
    n = obs_mod.n_records(rec)
    if regimes is not None and all(v.shape[0] == n for v in regimes.keys.values()):
        return ob, regimes
    return ob, obs_mod.regimes(rec, t_edges=t_edges, prf_mhz=prf_mhz)


def localise(real: Summary, sims: Sequence[Summary], cfg: Config, t_edges: FloatArray) -> list[Cell]:
    """Two-sample tests per observable and regime bin against the sim-vs-sim floor, BH-FDR."""
    rng = np.random.default_rng(cfg.seed + 7)
    ro, rr = real
    so = [x[0] for x in sims]
    sr = [x[1] for x in sims]
    k = len(sims)
    Spec = tuple[str, str, int, int, npt.NDArray[np.bool_], list[npt.NDArray[np.bool_]]]
    specs: list[Spec] = []
    dirs = rr.keys.get("direction")
    split = (
        dirs is not None and np.unique(dirs[dirs >= 0]).size >= 2 and all("direction" in s.keys for s in sr)
    )
    # (direction key, real mask, sim masks): the whole session, or one entry per direction
    parts: list[tuple[int, npt.NDArray[np.bool_], list[npt.NDArray[np.bool_]]]] = []
    same: dict[tuple[int, int, int], npt.NDArray[np.bool_]] = {}

    def equal(a: npt.NDArray[Any], v: int, b: npt.NDArray[np.bool_] | None = None) -> npt.NDArray[np.bool_]:
        """(a == v) [& b], once per array object: re-simulations share the real session's regimes."""
        key = (id(a), v, id(b))
        if key not in same:
            same[key] = (a == v) if b is None else (a == v) & b
        return same[key]

    if split and dirs is not None:
        ud, dcnt = np.unique(dirs[dirs >= 0], return_counts=True)
        parts = [
            (int(d), dirs == d, [equal(s.keys["direction"], int(d)) for s in sr])
            for d in ud[dcnt >= cfg.min_cell]
        ]
    else:
        parts = [(-1, np.ones(next(iter(ro.values())).shape[0], bool), [np.ones(1, bool)] * k)]
    for name, rv in ro.items():
        if any(name not in o for o in so):
            continue
        if not split:
            specs.append((name, "all", 0, -1, np.isfinite(rv), [np.isfinite(o[name]) for o in so]))
        for reg, keys in rr.keys.items():
            if any(reg not in s.keys for s in sr):
                continue
            if split and reg == "direction":
                for d, dm, sdm in parts:
                    specs.append((name, reg, d, -1, dm, sdm))
                continue
            for d, dm, sdm in parts:
                kd = keys[dm & (keys >= 0)]
                uk, cnt = np.unique(kd, return_counts=True)
                if uk.size < 2:
                    continue
                for key in uk[cnt >= cfg.min_cell]:
                    smasks = [
                        equal(s.keys[reg], int(key), sdm[j] if d >= 0 else None) for j, s in enumerate(sr)
                    ]
                    specs.append((name, reg, int(key), d, dm & (keys == key), smasks))
    # the KS reference subsamples are drawn here, in cell order, so the random stream does not
    # depend on how the cells are shared among processes
    finite = {name: [np.isfinite(o[name]) for o in so] for name in {sp[0] for sp in specs}}
    # None where a seed's values are all finite (the usual case: its cell values need no second mask)
    nonfinite = {name: [None if bool(np.all(f)) else f for f in fs] for name, fs in finite.items()}
    picks: list[npt.NDArray[np.int64] | None] = []
    for name, _reg, _key, _d, _rmask, smasks in specs:
        size = sum(int(np.count_nonzero(smasks[j] & finite[name][j])) for j in range(k))
        picks.append(rng.choice(size, cfg.ks_ref_max, replace=False) if size > cfg.ks_ref_max else None)
    _CELLS.update(ro=ro, so=so, specs=specs, picks=picks, t_edges=t_edges, finite=nonfinite)
    try:
        results = _map_cells(len(specs), cfg.jobs)
    finally:
        _CELLS.clear()
    cells: list[Cell] = []
    cell_spec: list[int] = []
    ns_ = len(stats.STAT_NAMES)
    obs_stats = np.full((len(specs), ns_), np.nan)
    null_stats = np.full((k, len(specs), ns_), np.nan)
    for ci, res in enumerate(results):
        if res is None:
            continue
        null_stats[:, ci], obs_stats[ci], cell = res
        cell_spec.append(ci)
        cells.append(cell)
    done = cell_spec
    if not done:
        return []
    for c, ci in zip(cells, done, strict=True):
        c.stat_obs, c.stat_null = obs_stats[ci], null_stats[:, ci]
    _judge(cells, stats.to_floor_scale(obs_stats[done]), stats.to_floor_scale(null_stats[:, done]))
    return cells


def _judge(cells: Sequence[Cell], obs: FloatArray, null: FloatArray) -> None:
    """Set the cells' z, p and BH q from their statistics on the floor's scale: ``obs`` (C, S)
    against ``null`` (K, C, S), with the floor's tail dof per observable."""
    fam_names = sorted({c.observable for c in cells})
    family = np.array([fam_names.index(c.observable) for c in cells], dtype=np.int64)
    dof = stats.floor_tail_dof(null, family, scaled=True)
    p, z = stats.floor_pvalues(obs, null, dof, scaled=True)
    q = stats.bh_fdr(p.ravel()).reshape(p.shape)
    for c, pi, zi, qi in zip(cells, p, z, q, strict=True):
        c.p = tuple(float(v) if np.isfinite(v) else 1.0 for v in pi)
        c.z = tuple(float(v) if np.isfinite(v) else 0.0 for v in zi)
        c.q = tuple(float(v) if np.isfinite(v) else 1.0 for v in qi)


def pooled(runs: Sequence[Sequence[Cell]]) -> list[Cell]:
    """One localisation from several diagnoses' localisations of the same real records (the
    seed ensembles of :mod:`uwbcal.gap.stability`): one decision from all their run seeds, not
    one per ensemble.

    Per cell present in every run (with its raw statistics), on the floor's scale: each run's
    real statistic and its seeds' statistics are centred on that run's floor mean (the runs'
    scenarios may differ in fitted values, which would otherwise widen the floor by the spread
    between runs); the real statistic is the mean of the runs' centred ones and the floor is all
    their seeds' centred ones together (E x K seeds), judged as :func:`localise` judges one run
    (tail dof per observable, BH over all cells). The mean of E runs' statistics on the same
    records varies at most as much as one run's (the records' own sampling noise is shared), so
    judging it against one seed's spread does not call departures the floor would not.
    Returns new cells (copies of the first run's, means averaged over the runs); [] if no cell
    has statistics in every run.
    """
    if not runs:
        return []
    by_id = [{c.ident: c for c in r if c.stat_obs is not None and c.stat_null is not None} for r in runs]
    idents = [i for i in by_id[0] if all(i in b for b in by_id[1:])]
    if not idents:
        return []
    obs = np.zeros((len(idents), len(stats.STAT_NAMES)))
    nulls: list[FloatArray] = []
    for b in by_id:
        o = stats.to_floor_scale(np.stack([b[i].stat_obs for i in idents]))  # type: ignore[misc]
        nl = stats.to_floor_scale(np.stack([b[i].stat_null for i in idents], axis=1))  # type: ignore[misc]
        ok = np.isfinite(nl)
        n_ok = ok.sum(axis=0)
        mu = np.where(n_ok > 0, np.where(ok, nl, 0.0).sum(axis=0) / np.maximum(n_ok, 1), np.nan)
        obs += o - mu
        nulls.append(nl - mu)
    obs /= len(by_id)
    cells = [
        dataclasses.replace(
            by_id[0][i],
            real_mean=float(np.mean([b[i].real_mean for b in by_id])),
            sim_mean=float(np.mean([b[i].sim_mean for b in by_id])),
            sim_sd=float(np.mean([b[i].sim_sd for b in by_id])),
            stat_obs=None,
            stat_null=None,
        )
        for i in idents
    ]
    _judge(cells, obs, np.concatenate(nulls, axis=0))
    return cells


#: What :func:`_cell_stats` reads (set before a pool forks: nothing large is pickled to workers).
_CELLS: dict[str, Any] = {}


def _map_cells(n: int, jobs: int) -> list[tuple[FloatArray, FloatArray, Cell] | None]:
    """:func:`_cell_stats` of cells 0..n-1, in order; in a forked pool of ``jobs`` processes if
    ``jobs`` > 1 (serially inside a pool's worker, which may not fork)."""
    return forked_map(_cell_stats, n, jobs)


def _cell_stats(ci: int) -> tuple[FloatArray, FloatArray, Cell] | None:
    """Cell ``ci``'s statistics: each seed's against the other K - 1 (K, 4), the real records'
    against the same K pools averaged (4,), and the cell (z, p, q still empty); None if too small."""
    ro: dict[str, FloatArray] = _CELLS["ro"]
    so: list[dict[str, FloatArray]] = _CELLS["so"]
    name, reg, key, dkey, rmask, smasks = _CELLS["specs"][ci]
    pick = _CELLS["picks"][ci]
    t_edges = _CELLS["t_edges"]
    k = len(so)
    ns_ = len(stats.STAT_NAMES)
    fin: list[npt.NDArray[np.bool_] | None] = _CELLS["finite"][name]
    x = ro[name][rmask]
    x = x[np.isfinite(x)]
    # each seed's finite values in the cell (v[mask][finite] = v[mask & finite], one gather)
    ys = [so[j][name][smasks[j] if fin[j] is None else smasks[j] & fin[j]] for j in range(k)]
    ns = np.array([y.size for y in ys], dtype=np.float64)
    s1 = np.array([y.sum() for y in ys])
    s2 = np.array([(y * y).sum() for y in ys])
    ref_vals, ref_src = _reference(ys, pick)
    n_all, m_all = ns.sum(), s1.sum()
    if n_all < 5 or x.size < 5:
        return None
    mean_all = m_all / n_all
    var_all = max(s2.sum() / n_all - mean_all**2, 0.0) * n_all / max(n_all - 1, 1)
    null = np.full((k, ns_), np.nan)
    real_loo = np.full((k, ns_), np.nan)
    # sorted once: the reference without seed j is the sorted pool without seed j's entries
    order = np.argsort(ref_vals)  # the order among equal values does not change ref_j below
    ref_sorted, src_sorted = ref_vals[order], ref_src[order]
    xs = np.sort(x)
    x_robust = stats.robust_loc_scale(xs)
    x_moments = (float(np.mean(x)), float(np.var(x, ddof=1)))
    # the KS distances of all seeds' and of the real sample against the K leave-one-out references
    # are searched together (stats.ks_distances); per seed j: (j, sample location, its divisor,
    # reference location, its divisor)
    ks_null: list[tuple[int, float, float, float, float]] = []
    ks_real: list[tuple[int, float, float, float, float]] = []
    null_sorted: list[FloatArray] = []
    for j in range(k):  # real and seed j, each against the same pool of the other K - 1 seeds
        n_o = n_all - ns[j]
        if n_o < 3 or ns[j] < 3:
            continue
        m_o = (m_all - s1[j]) / n_o
        v_o = max((s2.sum() - s2[j]) / n_o - m_o**2, 0.0) * n_o / max(n_o - 1, 1)
        ref_j = ref_sorted[src_sorted != j]
        if ref_j.size < 5:  # stats.two_sample_stats: no statistics against fewer than 5 values
            continue
        ref_robust = stats.robust_loc_scale(ref_j)
        if ys[j].size >= 5:
            yj = np.sort(ys[j])
            y_moments = (float(np.mean(ys[j])), float(np.var(ys[j], ddof=1)))
            *loc_scale, std = stats.location_scale(
                ys[j].size, ref_j.size, y_moments, m_o, v_o, stats.robust_loc_scale(yj), ref_robust
            )
            null[j, :3] = loc_scale
            ks_null.append((j, *std))
            null_sorted.append(yj)
        *loc_scale, std = stats.location_scale(x.size, ref_j.size, x_moments, m_o, v_o, x_robust, ref_robust)
        real_loo[j, :3] = loc_scale
        ks_real.append((j, *std))
    loo = stats.LeaveOneOut(ref_sorted, src_sorted, k)
    for out, probs, sample, sizes in (
        (null, ks_null, null_sorted, [y.size for y in null_sorted]),
        (real_loo, ks_real, [xs], [x.size] * len(ks_real)),
    ):
        if not probs:
            continue
        pj, loc_, den_, rloc, rden = (np.array(c) for c in zip(*probs, strict=True))
        size = np.array(sizes, dtype=np.int64)
        if len(sample) > 1:  # the seeds' own samples, one after the other
            flat, start = np.concatenate(sample), np.concatenate([[0], np.cumsum(size)[:-1]])
        else:  # the real sample, for every seed
            flat, start = sample[0], np.zeros(size.size, np.int64)
        out[pj, 3] = stats.ks_distances(flat, start, size, loc_, den_, loo, pj, rloc, rden)
    with np.errstate(invalid="ignore"):
        obs = np.nanmean(real_loo, axis=0) if np.any(np.isfinite(real_loo)) else np.full(ns_, np.nan)
    cell = Cell(
        observable=name,
        regime=reg,
        key=key,
        direction=dkey,
        label=(
            ("all" if reg == "all" else obs_mod.label(reg, key, t_edges))
            if dkey < 0
            else f"{obs_mod.label('direction', dkey)}, {obs_mod.label(reg, key, t_edges)}"
        ),
        n_real=int(x.size),
        real_mean=float(x.mean()),
        sim_mean=float(mean_all),
        real_sd=float(x.std(ddof=1)),
        sim_sd=float(np.sqrt(var_all)),
        z=(),
        p=(),
        q=(),
    )
    return null, obs, cell


def _reference(
    ys: Sequence[FloatArray], pick: npt.NDArray[np.int64] | None
) -> tuple[FloatArray, npt.NDArray[np.int64]]:
    """(values, seed of each) of the pooled reference: the concatenated seeds' values, or the
    entries ``pick`` of that concatenation (the KS subsample), gathered from the seeds without
    building the whole pool (tens of millions of values at 10^5 records). The picked entries come
    in order of their position in the pool, not of ``pick``: the reference is only used sorted,
    and among equal values which seed's entry comes first does not change a leave-one-out
    reference's values."""
    k = len(ys)
    ns = np.array([y.size for y in ys], dtype=np.int64)
    if pick is None:
        pooled = np.concatenate(ys) if ys else np.zeros(0)
        return pooled, np.repeat(np.arange(k), ns)
    ps = np.sort(pick)
    ends = np.cumsum(ns)
    cut = np.searchsorted(ps, np.concatenate([[0], ends]))  # ps[cut[j]:cut[j + 1]] lie in seed j
    vals = np.empty(ps.size)
    for j in range(k):
        a, b = int(cut[j]), int(cut[j + 1])
        vals[a:b] = ys[j][ps[a:b] - (ends[j] - ns[j])]
    return vals, np.repeat(np.arange(k), np.diff(cut))


def is_open(after: Cell, before: Cell | None, alpha: float, closed: float) -> bool:
    """Whether a cell still differs with the named effects: some statistic significant (q <
    ``alpha``) that either was not before (a new discrepancy; ``before`` None: no such cell) or
    keeps more than ``closed`` times its |z| before."""
    for i, q in enumerate(after.q):
        if q >= alpha:
            continue
        if before is None or before.q[i] >= alpha or abs(after.z[i]) > closed * abs(before.z[i]):
            return True
    return False


def still_open(before: Sequence[Cell], after: Sequence[Cell], cfg: Config) -> list[Cell]:
    """Cells that still differ with the named effects (:func:`is_open`, ``cfg.cell_closed``)."""
    prev = {c.ident: c for c in before}
    out = [c for c in after if is_open(c, prev.get(c.ident), cfg.alpha, cfg.cell_closed)]
    return sorted(out, key=lambda c: min(c.q))
