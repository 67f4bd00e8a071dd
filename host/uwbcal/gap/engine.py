"""The gap diagnosis proper: localise, attribute, quantify. Independent of the physics.

The engine sees the world model only through a :class:`Simulator`: a function from a
*variant* (knob settings on top of the believed scenario) and a seed to simulated records
on the real session's own schedule. :mod:`uwbcal.gap.model` builds one from the physics
catalogue; tests may build others.

Method (docs/GAP.md has the long form):

1. Localise. For every observable and every regime bin (and "all"), compare the real values
   with the pooled simulated values of K seeds with three statistics (location: Welch t;
   scale: log SD ratio; shape: KS distance of the standardised samples). The noise floor is
   the same statistics of each simulated seed against the other seeds; a Student-t
   predictive turns the floor into p-values; Benjamini-Hochberg controls the FDR over all
   cells and statistics. No rejection at ``alpha`` is "no significant gap".
2. Features. Per group (time block, or power step) and cell (direction x spacing x RX power
   x temperature x distance), the mean, log SD and lag-1 autocorrelation of every
   observable. Baseline mean m0 and seed-to-seed SD s per feature from the K seeds.
3. Attribute. Each candidate (an effect the scenario leaves off or fixes, through one
   parameter knob with a grid of values) has a signature: the mean feature change over
   paired seeds at each grid value (interpolated between them). Forward selection:
   leave-one-group-out, fit each candidate's knob on the training groups (least squares in
   units of s, on top of the effects already selected), score the held-out group's loss;
   add the candidate with the largest mean held-out improvement if the bootstrap CI of the
   improvement excludes zero, else stop. Cross-check: Lasso of the standardised residual on
   the signatures.
4. Quantify. Held-out shrink of the excess loss (loss minus its null expectation, the
   number of features) with a bootstrap CI over groups; the same for a flexible black-box
   residual model (per feature slot, a ridge line in the group's position); the fraction
   of the black-box's removable gap that the named effects remove.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from uwbcal.gap import observables as obs_mod
from uwbcal.gap import stats

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
Records = Mapping[str, Any]
#: Knob settings on top of the believed scenario: ((knob id, value), ...).
Variant = tuple[tuple[str, float], ...]
Simulator = Callable[[Variant, int], Records]

#: Regimes that make up a feature cell (besides the group regime).
CELL_REGIMES = ("direction", "spacing", "rx_power", "distance")


@dataclass(frozen=True)
class Candidate:
    """One candidate effect with the knob that sets its magnitude.

    ``knob`` is an id the simulator understands; ``baseline`` is the value the believed
    scenario uses (0 for an effect it leaves off); ``grid`` the values the signature is
    simulated at (the baseline is added). ``unit`` is the knob's unit. ``needs`` (record
    column, fewest distinct values) offers the candidate only when the real session has that
    many distinct values of the column: a per-receiver knob needs two receivers, else it is the
    same as the global knob of its effect (:func:`offered`). ``depends_on`` names an effect whose
    magnitude this knob multiplies (a receiver's noise scale and the noise floor): once that
    effect is selected, this candidate's signature is re-simulated on top of the effects
    selected so far (a signature at the believed scenario would be far too small).
    """

    effect: str
    knob: str
    baseline: float
    grid: tuple[float, ...]
    unit: str
    description: str = ""
    needs: tuple[str, int] | None = None
    depends_on: str | None = None


def offered(candidates: Sequence[Candidate], real: Records) -> tuple[list[Candidate], list[Candidate]]:
    """(candidates the real session can tell apart, candidates it cannot: see Candidate.needs)."""
    keep: list[Candidate] = []
    skip: list[Candidate] = []
    for c in candidates:
        if c.needs is not None:
            col = real.get(c.needs[0])
            distinct = 0 if col is None else int(np.unique(np.asarray(col)).size)
            if distinct < c.needs[1]:
                skip.append(c)
                continue
        keep.append(c)
    return keep, skip


@dataclass
class Config:
    """Settings of one diagnosis (defaults are what `uwbcal gap` uses)."""

    n_seeds: int = 16  # baseline re-simulations (noise floor and m0, s)
    n_seeds_signature: int = 3  # paired seeds per candidate grid value
    signature_max_records: int = 25_000  # signatures on a subsample of longer sessions
    jobs: int = 1  # worker processes for the simulations
    n_time_blocks: int = 10  # groups of a drift run
    alpha: float = 0.01  # BH FDR level of the localisation
    min_cell: int = 20  # fewest real records in a localisation cell
    min_feature: int = 8  # fewest records in a feature cell
    max_effects: int = 5  # forward selection stops at this many
    explained_shrink: float = 0.5  # named effects must remove this much of the held-out gap
    cell_closed: float = 0.2  # a cell is closed when |z| with the named effects <= this x |z| before
    selection_level: float = 0.99  # CI level of the forward-selection stopping rule
    ks_ref_max: int = 50_000  # pooled reference subsample for the KS distance
    seed: int = 0  # base seed of the re-simulations and bootstraps
    n_boot: int = 2000


@dataclass
class FeatureSpace:
    """The layout shared by real and simulated sessions: which group/cell/obs/stat each feature is."""

    observables: list[str]
    group_regime: str
    group_keys: IntArray  # distinct group keys of the real session
    cell_regimes: list[str]
    cell_keys: IntArray  # (n_cells, len(cell_regimes)) distinct cells of the real session
    t_edges: FloatArray
    feat_obs: IntArray = field(default_factory=lambda: np.zeros(0, np.int64))
    feat_group: IntArray = field(default_factory=lambda: np.zeros(0, np.int64))
    feat_cell: IntArray = field(default_factory=lambda: np.zeros(0, np.int64))
    feat_stat: IntArray = field(default_factory=lambda: np.zeros(0, np.int64))

    def __post_init__(self) -> None:
        no, ng, nc, ns = (
            len(self.observables),
            len(self.group_keys),
            len(self.cell_keys),
            len(stats.FEATURE_NAMES),
        )
        o, g, c, s = np.meshgrid(np.arange(no), np.arange(ng), np.arange(nc), np.arange(ns), indexing="ij")
        self.feat_obs, self.feat_group = o.ravel(), g.ravel()
        self.feat_cell, self.feat_stat = c.ravel(), s.ravel()

    @property
    def n_features(self) -> int:
        return int(self.feat_obs.size)

    real_regimes: obs_mod.Regimes | None = None

    def features(self, rec: Records, min_count: int) -> FloatArray:
        """The feature vector of one session (same layout for real and simulated).

        A re-simulation of the real schedule has the same records in the same order, so it
        takes the real session's regimes record by record (temperature, RX power and the
        like are conditions of the real record, not outputs of the simulation).
        """
        ob = obs_mod.observables(rec)
        n = obs_mod.n_records(rec)
        reg = self.real_regimes
        if reg is None or any(v.shape[0] != n for v in reg.keys.values()):
            reg = obs_mod.regimes(rec, t_edges=self.t_edges)
        no, ng, nc = len(self.observables), len(self.group_keys), len(self.cell_keys)
        gk = reg.keys.get(self.group_regime, np.zeros(n, np.int64))
        gi = _lookup(self.group_keys, gk)
        if self.cell_regimes:
            ck = np.stack([reg.keys.get(r, np.full(n, -1, np.int64)) for r in self.cell_regimes], axis=1)
            ci = _lookup_rows(self.cell_keys, ck)
        else:
            ci = np.zeros(n, np.int64)
        ok = (gi >= 0) & (ci >= 0)
        flat = np.where(ok, gi * nc + ci, -1)
        tkey = (
            np.asarray(rec.get("t_s"), dtype=np.float64)
            if rec.get("t_s") is not None
            else np.arange(n, dtype=np.float64)
        )
        nf = len(stats.FEATURE_NAMES)
        out = np.full((no, ng, nc, nf), np.nan)
        for i, name in enumerate(self.observables):
            v = ob.get(name)
            if v is None:
                continue
            m = ok & np.isfinite(v)
            f = stats.group_features(v[m], flat[m], ng * nc, tkey[m], min_count=min_count)
            out[i] = f.reshape(ng, nc, nf)
        return out.ravel()


def _lookup(keys: IntArray, x: IntArray) -> IntArray:
    """Index of each x in sorted unique ``keys``, -1 if absent."""
    pos = np.clip(np.searchsorted(keys, x), 0, max(len(keys) - 1, 0))
    return np.where((len(keys) > 0) & (keys[pos] == x), pos, -1).astype(np.int64)


def _lookup_rows(keys: IntArray, x: IntArray) -> IntArray:
    """Row index of each row of x in the unique rows ``keys``, -1 if absent."""
    if len(keys) == 0:
        return np.full(x.shape[0], -1, np.int64)
    both = np.concatenate([keys, x])
    _, inv = np.unique(both, axis=0, return_inverse=True)
    inv = inv.ravel()
    key_inv = inv[: len(keys)]
    table = np.full(int(inv.max()) + 1, -1, np.int64)
    table[key_inv] = np.arange(len(keys))
    return table[inv[len(keys) :]]


def build_space(real: Records, cfg: Config, observables: Sequence[str]) -> FeatureSpace:
    """The feature layout from the real session: groups are steps if it has several, else time blocks."""
    n = obs_mod.n_records(real)
    t = real.get("t_s")
    t_edges = (
        obs_mod.time_edges(np.asarray(t, np.float64), cfg.n_time_blocks)
        if t is not None
        else np.array([0.0, np.inf])
    )
    reg = obs_mod.regimes(real, t_edges=t_edges)
    step = reg.keys.get("step")
    if step is not None and np.unique(step).size >= 4:
        group_regime = "step"
    else:
        group_regime = "time"
    gk = reg.keys.get(group_regime, np.zeros(n, np.int64))
    cell_regs = [
        r for r in CELL_REGIMES if r in reg.keys and not (group_regime == "step" and r == "rx_power")
    ]
    if cell_regs:
        ck = np.stack([reg.keys[r] for r in cell_regs], axis=1)
        rows, counts = np.unique(ck, axis=0, return_counts=True)
        keep = counts >= cfg.min_feature * max(1, len(np.unique(gk)) // 2)
        cell_keys = rows[keep] if np.any(keep) else rows[np.argmax(counts)][None, :]
    else:
        cell_keys = np.zeros((1, 0), np.int64)
    return FeatureSpace(
        observables=list(observables),
        group_regime=group_regime,
        group_keys=np.unique(gk).astype(np.int64),
        cell_regimes=cell_regs,
        cell_keys=np.asarray(cell_keys, np.int64),
        t_edges=t_edges,
        real_regimes=reg,
    )


# --- localisation ------------------------------------------------------------------------


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

    def to_json(self) -> dict[str, Any]:
        return {
            "observable": self.observable,
            "unit": obs_mod.OBSERVABLES.get(self.observable, ""),
            "regime": self.regime,
            "key": self.key,
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


def summarise(rec: Records, t_edges: FloatArray, regimes: obs_mod.Regimes | None = None) -> Summary:
    """Observables and regime keys of one session (what localisation needs).

    ``regimes`` (the real session's) are used when the record counts agree: a re-simulation
    of the real schedule is compared record slot by record slot in the real conditions.
    """
    ob = obs_mod.observables(rec)
    n = obs_mod.n_records(rec)
    if regimes is not None and all(v.shape[0] == n for v in regimes.keys.values()):
        return ob, regimes
    return ob, obs_mod.regimes(rec, t_edges=t_edges)


def localise(real: Summary, sims: Sequence[Summary], cfg: Config, t_edges: FloatArray) -> list[Cell]:
    """Two-sample tests per observable and regime bin against the sim-vs-sim floor, BH-FDR."""
    rng = np.random.default_rng(cfg.seed + 7)
    ro, rr = real
    so = [x[0] for x in sims]
    sr = [x[1] for x in sims]
    k = len(sims)
    specs: list[tuple[str, str, int, npt.NDArray[np.bool_], list[npt.NDArray[np.bool_]]]] = []
    for name, rv in ro.items():
        if any(name not in o for o in so):
            continue
        specs.append((name, "all", 0, np.isfinite(rv), [np.isfinite(o[name]) for o in so]))
        for reg, keys in rr.keys.items():
            if any(reg not in s.keys for s in sr):
                continue
            uk, cnt = np.unique(keys[keys >= 0], return_counts=True)
            if uk.size < 2:
                continue
            for key in uk[cnt >= cfg.min_cell]:
                specs.append((name, reg, int(key), keys == key, [s.keys[reg] == key for s in sr]))
    cells: list[Cell] = []
    cell_spec: list[int] = []
    ns_ = len(stats.STAT_NAMES)
    obs_stats = np.full((len(specs), ns_), np.nan)
    null_stats = np.full((k, len(specs), ns_), np.nan)
    for ci, (name, reg, key, rmask, smasks) in enumerate(specs):
        x = ro[name][rmask]
        x = x[np.isfinite(x)]
        ys = [so[j][name][smasks[j]] for j in range(k)]
        ys = [y[np.isfinite(y)] for y in ys]
        ns = np.array([y.size for y in ys], dtype=np.float64)
        s1 = np.array([y.sum() for y in ys])
        s2 = np.array([(y * y).sum() for y in ys])
        pooled = np.concatenate(ys) if ys else np.zeros(0)
        src = np.repeat(np.arange(k), ns.astype(np.int64))
        if pooled.size > cfg.ks_ref_max:
            pick = rng.choice(pooled.size, cfg.ks_ref_max, replace=False)
            ref_vals, ref_src = pooled[pick], src[pick]
        else:
            ref_vals, ref_src = pooled, src
        n_all, m_all = ns.sum(), s1.sum()
        if n_all < 5 or x.size < 5:
            continue
        mean_all = m_all / n_all
        var_all = max(s2.sum() / n_all - mean_all**2, 0.0) * n_all / max(n_all - 1, 1)
        obs_stats[ci] = stats.two_sample_stats(x, np.sort(ref_vals), mean_all, var_all)
        for j in range(k):
            n_o = n_all - ns[j]
            if n_o < 3 or ns[j] < 3:
                continue
            m_o = (m_all - s1[j]) / n_o
            v_o = max((s2.sum() - s2[j]) / n_o - m_o**2, 0.0) * n_o / max(n_o - 1, 1)
            null_stats[j, ci] = stats.two_sample_stats(ys[j], np.sort(ref_vals[ref_src != j]), m_o, v_o)
        cell_spec.append(ci)
        cells.append(
            Cell(
                observable=name,
                regime=reg,
                key=key,
                label="all" if reg == "all" else obs_mod.label(reg, key, t_edges),
                n_real=int(x.size),
                real_mean=float(x.mean()),
                sim_mean=float(mean_all),
                real_sd=float(x.std(ddof=1)),
                sim_sd=float(np.sqrt(var_all)),
                z=(),
                p=(),
                q=(),
            )
        )
    done = cell_spec
    if not done:
        return []
    p, z = stats.floor_pvalues(obs_stats[done], null_stats[:, done])
    q = stats.bh_fdr(p.ravel()).reshape(p.shape)
    for c, pi, zi, qi in zip(cells, p, z, q, strict=True):
        c.p = tuple(float(v) if np.isfinite(v) else 1.0 for v in pi)
        c.z = tuple(float(v) if np.isfinite(v) else 0.0 for v in zi)
        c.q = tuple(float(v) if np.isfinite(v) else 1.0 for v in qi)
    return cells


# --- attribution -------------------------------------------------------------------------


@dataclass
class Signature:
    """A candidate's effect on the features at each grid value (baseline included: no change).

    ``deltas``: mean feature change in units of the floor s; ``log_ratio``: log of the
    seed-to-seed SD of each feature relative to the believed scenario's (pooled over groups
    per feature slot), so effects that add scatter (noise, wander, multipath) are modelled as
    such, not only as mean shifts.
    """

    candidate: Candidate
    thetas: FloatArray  # sorted grid incl. baseline
    deltas: FloatArray  # (n_grid, n_features), in units of the floor s
    log_ratio: FloatArray  # (n_grid, n_features)

    def _interp(self, table: FloatArray, theta: FloatArray) -> FloatArray:
        """Shape-preserving cubic (PCHIP) interpolation along the grid; linear for 2 points."""
        th = np.clip(np.asarray(theta, np.float64), self.thetas[0], self.thetas[-1])
        if len(self.thetas) >= 3:
            from scipy.interpolate import PchipInterpolator

            return np.asarray(PchipInterpolator(self.thetas, table, axis=0)(th), dtype=np.float64)
        hi = np.clip(np.searchsorted(self.thetas, th, side="right"), 1, len(self.thetas) - 1)
        lo = hi - 1
        w = (th - self.thetas[lo]) / np.maximum(self.thetas[hi] - self.thetas[lo], 1e-300)
        return np.asarray(table[lo] * (1 - w)[:, None] + table[hi] * w[:, None])

    def at(self, theta: FloatArray) -> FloatArray:
        """Interpolated mean change (units of s) at each theta: shape (len(theta), n_features)."""
        return self._interp(self.deltas, theta)

    def log_ratio_at(self, theta: FloatArray) -> FloatArray:
        """Interpolated log SD ratio at each theta: shape (len(theta), n_features)."""
        return self._interp(self.log_ratio, theta)


def _fine(sig: Signature, n: int = 121) -> FloatArray:
    """Fine theta grid over the signature's range (grid points included)."""
    return np.unique(np.concatenate([np.linspace(sig.thetas[0], sig.thetas[-1], n), sig.thetas]))


def _nll(r: FloatArray, mu: FloatArray, lr: FloatArray) -> FloatArray:
    """Gaussian negative log-likelihood (times 2, without constants) per feature."""
    return np.asarray((r - mu) ** 2 * np.exp(-2.0 * lr) + 2.0 * lr)


def fit_effects(
    r: FloatArray, sigs: Sequence[Signature], mask: npt.NDArray[np.bool_], sweeps: int = 3
) -> tuple[list[float], FloatArray, FloatArray]:
    """Fit each signature's theta on features ``mask`` (coordinate descent over grid searches).

    ``r`` is the standardised residual (real - m0) / s. Criterion: Gaussian NLL with the
    summed mean changes and summed log SD ratios of the effects. Returns the thetas, the
    predicted mean change and the predicted log SD ratio on every feature.
    """
    thetas = [float(s.candidate.baseline) for s in sigs]
    fines = [_fine(s) for s in sigs]
    mtab = [s.at(f) for s, f in zip(sigs, fines, strict=True)]
    ltab = [s.log_ratio_at(f) for s, f in zip(sigs, fines, strict=True)]
    mu = [np.zeros_like(r) for _ in sigs]
    lr = [np.zeros_like(r) for _ in sigs]
    for _ in range(sweeps if len(sigs) > 1 else 1):
        for i in range(len(sigs)):
            mo = sum((mu[j] for j in range(len(sigs)) if j != i), np.zeros_like(r))[mask]
            lo = sum((lr[j] for j in range(len(sigs)) if j != i), np.zeros_like(r))[mask]
            loss = np.sum(
                _nll(r[mask][None, :], mo[None, :] + mtab[i][:, mask], lo[None, :] + ltab[i][:, mask]), axis=1
            )
            b = int(np.argmin(loss))
            thetas[i] = float(fines[i][b])
            mu[i] = mtab[i][b]
            lr[i] = ltab[i][b]
    return thetas, sum(mu, np.zeros_like(r)), sum(lr, np.zeros_like(r))


@dataclass
class Selection:
    """Forward-selection result (per-group held-out losses: NLL for the selection, chi2 for shrink).

    ``signatures`` are the candidates' signatures as last used (re-simulated ones replaced).
    """

    chosen: list[int]
    steps: list[dict[str, Any]]
    fold_chi2_base: FloatArray
    fold_chi2_sel: FloatArray
    signatures: list[Signature] = field(default_factory=list)


#: Re-simulates signatures on top of the chosen ones: (all signatures, chosen indices, indices
#: to redo) -> the redone signatures by index.
Relinearise = Callable[[Sequence["Signature"], Sequence[int], Sequence[int]], dict[int, "Signature"]]


def _cv_losses(
    r: FloatArray, sigs: Sequence[Signature], groups: IntArray, n_groups: int
) -> tuple[FloatArray, FloatArray]:
    """Leave-one-group-out held-out (NLL, chi2) per group, effects ``sigs`` fitted on the rest."""
    nll = np.zeros(n_groups)
    chi2 = np.zeros(n_groups)
    for g in range(n_groups):
        test = groups == g
        if not sigs:
            nll[g] = chi2[g] = float(np.sum(r[test] ** 2))
            continue
        _, mu, lr = fit_effects(r, sigs, ~test)
        nll[g] = float(np.sum(_nll(r[test], mu[test], lr[test])))
        chi2[g] = float(np.sum((r[test] - mu[test]) ** 2 * np.exp(-2.0 * lr[test])))
    return nll, chi2


def forward_select(
    r: FloatArray,
    sigs: Sequence[Signature],
    groups: IntArray,
    n_groups: int,
    cfg: Config,
    rng: np.random.Generator,
    relinearise: Relinearise | None = None,
) -> Selection:
    """Forward selection scored by held-out NLL; stop when the improvement's CI includes 0.

    Each step ranks the remaining candidates alone, then also tries blocks of two or three
    of the five leading ones (an offset and a drift may each explain nothing alone), takes
    the block or single with the largest mean held-out improvement if its CI excludes zero,
    and drops any member of a block whose own contribution's CI includes zero. After a step,
    candidates that depend on a chosen effect (``Candidate.depends_on``) get their signature
    re-simulated on top of the chosen effects (``relinearise``), once.
    """
    from itertools import combinations

    sigs = list(sigs)
    redone: set[int] = set()
    chosen: list[int] = []
    base_nll, base_chi2 = _cv_losses(r, [], groups, n_groups)
    current, current_chi2 = base_nll.copy(), base_chi2.copy()
    steps: list[dict[str, Any]] = []
    cache: dict[tuple[tuple[int, ...], tuple[int, ...]], tuple[FloatArray, FloatArray]] = {}

    def losses(block: tuple[int, ...]) -> tuple[FloatArray, FloatArray]:
        key = (tuple(sorted(chosen)), tuple(sorted(block)))
        if key not in cache:
            cache[key] = _cv_losses(r, [sigs[j] for j in chosen] + [sigs[j] for j in block], groups, n_groups)
        return cache[key]

    while len(chosen) < cfg.max_effects:
        singles = []
        for i in range(len(sigs)):
            if i in chosen:
                continue
            nll, _ = losses((i,))
            mean, lo, hi = stats.bootstrap_mean_ci(current - nll, rng, cfg.n_boot, level=cfg.selection_level)
            singles.append((mean, lo, hi, i))
        if not singles:
            break
        singles.sort(key=lambda t: -t[0])
        step: dict[str, Any] = {
            "step": len(chosen) + 1,
            "ranking": [
                {
                    "effect": sigs[t[3]].candidate.effect,
                    "knob": sigs[t[3]].candidate.knob,
                    "heldout_improvement": t[0],
                    "ci": [t[1], t[2]],
                }
                for t in singles[:6]
            ],
        }
        steps.append(step)
        options: list[tuple[float, float, float, tuple[int, ...]]] = [
            (t[0], t[1], t[2], (t[3],)) for t in singles
        ]
        lead = [t[3] for t in singles[:5] if t[0] > 0]
        room = cfg.max_effects - len(chosen)
        for size in (2, 3):
            if size > room:
                break
            for combo in combinations(lead, size):
                nll, _ = losses(combo)
                mean, lo, hi = stats.bootstrap_mean_ci(
                    current - nll, rng, cfg.n_boot, level=cfg.selection_level
                )
                options.append((mean, lo, hi, combo))
        options.sort(key=lambda t: -t[0])
        pick = options[0]
        if not pick[1] > 0.0:  # the CI of the held-out improvement includes zero: stop
            break
        block = list(pick[3])
        if len(block) > 1:  # prune members that the rest of the block does not need
            gain: dict[int, float] = {}
            for j in list(block):
                rest = tuple(x for x in block if x != j)
                if not rest:
                    continue
                nll_rest, _ = losses(rest)
                nll_all, _ = losses(tuple(block))
                m_j, lo, _ = stats.bootstrap_mean_ci(
                    nll_rest - nll_all, rng, cfg.n_boot, level=cfg.selection_level
                )
                gain[j] = m_j
                if not lo > 0.0:
                    block.remove(j)
            block.sort(key=lambda j: -gain.get(j, 0.0))  # the member that matters most first
            step["block"] = [sigs[j].candidate.effect for j in block]
        nll, chi2 = losses(tuple(block))
        chosen.extend(block)
        current, current_chi2 = nll, chi2
        if relinearise is not None:
            names = {sigs[j].candidate.effect for j in chosen}
            todo = [
                i
                for i in range(len(sigs))
                if i not in chosen and i not in redone and sigs[i].candidate.depends_on in names
            ]
            if todo:
                for i, sg in relinearise(sigs, chosen, todo).items():
                    sigs[i] = sg
                redone.update(todo)
                cache.clear()
                step["resimulated_signatures"] = [sigs[i].candidate.effect for i in todo]
    return Selection(
        chosen=chosen, steps=steps, fold_chi2_base=base_chi2, fold_chi2_sel=current_chi2, signatures=sigs
    )


def blackbox_losses(
    r: FloatArray, groups: IntArray, n_groups: int, slot: IntArray, gpos: FloatArray, ridge: float = 1.0
) -> FloatArray:
    """Held-out loss per group of a flexible residual model.

    Per feature slot (observable x cell x statistic), a ridge-regularised line in the group's
    position ``gpos`` (time or step), fitted on the other groups: a binned regression on the
    regime variables with a trend across groups.
    """
    out = np.zeros(n_groups)
    n_slots = int(slot.max()) + 1 if slot.size else 0
    x = gpos[groups]
    for g in range(n_groups):
        tr = groups != g
        w = np.bincount(slot[tr], minlength=n_slots).astype(np.float64)
        sx = np.bincount(slot[tr], weights=x[tr], minlength=n_slots)
        sy = np.bincount(slot[tr], weights=r[tr], minlength=n_slots)
        sxx = np.bincount(slot[tr], weights=x[tr] ** 2, minlength=n_slots)
        sxy = np.bincount(slot[tr], weights=x[tr] * r[tr], minlength=n_slots)
        mx = sx / np.maximum(w, 1)
        my = sy / np.maximum(w, 1)
        vx = sxx - w * mx**2
        cxy = sxy - w * mx * my
        slope = cxy / (vx + ridge)
        te = ~tr
        pred = my[slot[te]] + slope[slot[te]] * (x[te] - mx[slot[te]])
        out[g] = float(np.sum((r[te] - pred) ** 2))
    return out


# --- orchestration -----------------------------------------------------------------------


@dataclass
class Diagnosis:
    """Everything one diagnosis found (JSON via :meth:`to_json`)."""

    verdict: str
    summary: str
    cells: list[Cell]
    significant: list[Cell]
    named: list[dict[str, Any]]
    selection_steps: list[dict[str, Any]]
    lasso: list[dict[str, Any]]
    lasso_agrees: bool | None
    shrink: dict[str, float]
    shrink_signature: dict[str, float]
    blackbox_shrink: dict[str, float]
    fraction_of_removable: float
    excess: dict[str, float]
    n_features: int
    n_groups: int
    group_regime: str
    settings: dict[str, Any]
    residual_before: dict[str, Any] = field(default_factory=dict)
    residual_after: dict[str, Any] = field(default_factory=dict)
    group_labels: list[str] = field(default_factory=list)
    remaining: list[Cell] = field(default_factory=list)
    cells_after: list[Cell] = field(default_factory=list)
    not_offered: list[str] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        return {
            "verdict": self.verdict,
            "summary": self.summary,
            "named_effects": self.named,
            "candidates_not_offered": self.not_offered,
            "selection": self.selection_steps,
            "lasso": self.lasso,
            "lasso_agrees": self.lasso_agrees,
            "heldout_shrink": self.shrink,
            "heldout_shrink_signature_model": self.shrink_signature,
            "blackbox_shrink": self.blackbox_shrink,
            "excess_loss": self.excess,
            "groups": self.group_labels,
            "fraction_of_removable_gap": self.fraction_of_removable,
            "significant_cells": [c.to_json() for c in self.significant],
            "cells_still_differing_with_named_effects": [c.to_json() for c in self.remaining],
            "cells_with_named_effects": [c.to_json() for c in self.cells_after],
            "cells": [c.to_json() for c in self.cells],
            "n_features": self.n_features,
            "n_groups": self.n_groups,
            "group_regime": self.group_regime,
            "settings": self.settings,
            "residual_by_group_before": self.residual_before,
            "residual_by_group_after": self.residual_after,
        }


# --- workers: simulate and reduce, in a process pool when asked ------------------------------

_JOB: dict[str, Any] = {}


Task = tuple[Variant, int, bool, bool]


def _job(args: Task) -> tuple[FloatArray, Summary | None]:
    """Simulate one (variant, seed[, subsampled schedule]) and reduce it to features (and, if
    asked, its summary)."""
    variant, seed, full, sub = args
    sub = sub and _JOB.get("simulate_sub") is not None
    rec = _JOB["simulate_sub" if sub else "simulate"](variant, seed)
    space: FeatureSpace = _JOB["space_sub" if sub else "space"]
    f = space.features(rec, _JOB["min_feature"])
    return f, (summarise(rec, space.t_edges, space.real_regimes) if full else None)


class _Runner:
    """Runs simulation jobs serially or in a forked process pool (``jobs`` > 1)."""

    def __init__(
        self,
        simulate: Simulator,
        space: FeatureSpace,
        cfg: Config,
        simulate_sub: Simulator | None = None,
        space_sub: FeatureSpace | None = None,
    ) -> None:
        _JOB.update(
            simulate=simulate,
            space=space,
            min_feature=cfg.min_feature,
            simulate_sub=simulate_sub,
            space_sub=space_sub,
        )
        self.subsampled = simulate_sub is not None
        self.pool: Any = None
        if cfg.jobs > 1:
            import multiprocessing as mp

            try:
                self.pool = mp.get_context("fork").Pool(cfg.jobs)
            except (OSError, ValueError):
                self.pool = None

    def map(self, tasks: Sequence[Task]) -> list[tuple[FloatArray, Summary | None]]:
        if self.pool is None:
            return [_job(t) for t in tasks]
        return list(self.pool.map(_job, tasks, chunksize=1))

    def close(self) -> None:
        if self.pool is not None:
            self.pool.close()
            self.pool.join()
            self.pool = None


def _null_loss(
    f_sims: FloatArray, good: npt.NDArray[np.bool_], groups: IntArray, n_groups: int
) -> FloatArray:
    """Expected held-out loss per group under a correct model: each seed against the others."""
    k = f_sims.shape[0]
    out = np.zeros(n_groups)
    for j in range(k):
        others = np.delete(f_sims, j, axis=0)
        m = np.nanmean(others, axis=0)[good]
        s = np.nanstd(others, axis=0, ddof=1)[good] * np.sqrt(1.0 + 1.0 / (k - 1))
        rj = (f_sims[j][good] - m) / np.where(s > 0, s, 1.0)
        rj = np.where(np.isfinite(rj), rj, 0.0)
        out += np.bincount(groups, weights=rj * rj, minlength=n_groups)
    return np.asarray(out / k, dtype=np.float64)


def diagnose(
    real: Records,
    simulate: Simulator,
    candidates: Sequence[Candidate],
    cfg: Config | None = None,
    progress: Callable[[str], None] | None = None,
    subsampled: Callable[[int], Simulator] | None = None,
) -> Diagnosis:
    """Run the whole diagnosis of ``real`` against ``simulate`` with ``candidates``.

    ``subsampled(stride)``, if given, is a simulator of every stride-th record of the real
    schedule: the candidates' signatures (many simulations, each a mean change of the
    features) are then simulated on at most ``cfg.signature_max_records`` records; the noise
    floor, the localisation and the re-simulated shrink always use the whole schedule.
    """
    import warnings

    cfg = cfg or Config()
    say = progress or (lambda _m: None)
    candidates, skipped = offered(candidates, real)
    if skipped:
        say("not offered (the session cannot tell them apart): " + ", ".join(c.effect for c in skipped))
    rng = np.random.default_rng(cfg.seed + 11)
    warnings.filterwarnings("ignore", message="Mean of empty slice", category=RuntimeWarning)
    warnings.filterwarnings("ignore", message="Degrees of freedom", category=RuntimeWarning)
    ro = obs_mod.observables(real)
    seeds = [cfg.seed * 1000 + 1 + i for i in range(cfg.n_seeds)]
    names = list(ro)
    space = build_space(real, cfg, names)
    n = obs_mod.n_records(real)
    sim_sub: Simulator | None = None
    space_sub: FeatureSpace | None = None
    if subsampled is not None and n > cfg.signature_max_records and space.real_regimes is not None:
        import dataclasses

        stride = int(np.ceil(n / cfg.signature_max_records))
        sim_sub = subsampled(stride)
        reg = space.real_regimes
        space_sub = dataclasses.replace(
            space,
            real_regimes=obs_mod.Regimes(
                keys={k: v[::stride] for k, v in reg.keys.items()}, t_edges=reg.t_edges
            ),
        )
        say(f"candidate signatures on every {stride}th record")
    runner = _Runner(simulate, space, cfg, sim_sub, space_sub)
    try:
        d = _diagnose(real, runner, candidates, cfg, say, rng, seeds, space)
    finally:
        runner.close()
    d.not_offered = [f"{c.effect} ({c.knob})" for c in skipped]
    return d


def _diagnose(
    real: Records,
    runner: _Runner,
    candidates: Sequence[Candidate],
    cfg: Config,
    say: Callable[[str], None],
    rng: np.random.Generator,
    seeds: list[int],
    space: FeatureSpace,
) -> Diagnosis:
    say(f"re-simulating the session's schedule over {len(seeds)} seeds")
    base = runner.map([((), s, True, False) for s in seeds])
    sims = [b[1] for b in base if b[1] is not None]
    say("localising")
    cells = localise(summarise(real, space.t_edges, space.real_regimes), sims, cfg, space.t_edges)
    significant = [c for c in cells if min(c.q) < cfg.alpha]
    significant.sort(key=lambda c: min(c.q))

    f_real = space.features(real, cfg.min_feature)
    f_sims = np.stack([b[0] for b in base])
    k = len(seeds)
    m0 = np.nanmean(f_sims, axis=0)
    sd = np.nanstd(f_sims, axis=0, ddof=1) * np.sqrt(1.0 + 1.0 / k)
    good = np.isfinite(f_real) & np.all(np.isfinite(f_sims), axis=0) & (sd > 0)
    r = np.where(good, (f_real - m0) / np.where(sd > 0, sd, 1.0), 0.0)[good]
    groups = space.feat_group[good]
    n_groups = len(space.group_keys)
    slot = _slots(space, good)
    gpos = np.arange(n_groups, dtype=np.float64)
    lnull = _null_loss(f_sims, good, groups, n_groups)
    settings = {k_: getattr(cfg, k_) for k_ in cfg.__dataclass_fields__}
    before = _residual_by_group(r, groups, space, good)

    named: list[dict[str, Any]] = []
    steps: list[dict[str, Any]] = []
    lasso_rows: list[dict[str, Any]] = []
    lasso_agrees: bool | None = None
    nan3 = {"estimate": float("nan"), "ci_low": float("nan"), "ci_high": float("nan")}
    shrink, shrink_sig, bb = dict(nan3), dict(nan3), dict(nan3)
    frac = float("nan")
    after: dict[str, Any] = {}
    remaining: list[Cell] = []
    cells_after: list[Cell] = []
    excess = {
        "before": float(np.sum(np.bincount(groups, weights=r * r, minlength=n_groups) - lnull)),
        "null_loss": float(lnull.sum()),
        "n_features": int(r.size),
    }
    if not significant:
        verdict = "no significant gap"
        summary = (
            f"no significant gap: none of {len(cells)} cells x {len(stats.STAT_NAMES)} statistics "
            f"differs from the sim-vs-sim floor at FDR {cfg.alpha}"
        )
    else:
        say(f"signatures of {len(candidates)} candidates")
        sigs = _signatures(candidates, runner, seeds[: cfg.n_seeds_signature], f_sims, sd, good, space)
        say("forward selection")

        def relinearise(
            all_sigs: Sequence[Signature], chosen_idx: Sequence[int], todo: Sequence[int]
        ) -> dict[int, Signature]:
            picked = [all_sigs[j] for j in chosen_idx]
            th, _, _ = fit_effects(r, picked, np.ones_like(r, dtype=bool))
            on_top = tuple((sg.candidate.knob, float(t)) for sg, t in zip(picked, th, strict=True))
            say("re-simulating signatures on top of " + ", ".join(f"{k} = {v:.4g}" for k, v in on_top))
            redo = _signatures(
                [all_sigs[i].candidate for i in todo],
                runner,
                seeds[: cfg.n_seeds_signature],
                f_sims,
                sd,
                good,
                space,
                on_top=on_top,
            )
            return dict(zip(todo, redo, strict=True))

        sel = forward_select(r, sigs, groups, n_groups, cfg, rng, relinearise)
        sigs = sel.signatures
        steps = sel.steps
        exc0 = sel.fold_chi2_base - lnull
        exc1 = sel.fold_chi2_sel - lnull
        shrink_sig = dict(
            zip(("estimate", "ci_low", "ci_high"), stats.shrink_ci(exc0, exc1, rng, cfg.n_boot), strict=True)
        )
        bbl = blackbox_losses(r, groups, n_groups, slot, gpos)
        bb = dict(
            zip(
                ("estimate", "ci_low", "ci_high"),
                stats.shrink_ci(exc0, bbl - lnull, rng, cfg.n_boot),
                strict=True,
            )
        )
        chosen = [sigs[i] for i in sel.chosen]
        if chosen:
            say("re-simulating with the named effects (two-fold held-out shrink)")
            loss_rs = np.zeros(n_groups)
            null_rs = np.zeros(n_groups)
            fitted_folds = []
            for fold in (0, 1):
                test = (groups % 2) == fold
                th_fold, _, _ = fit_effects(r, chosen, ~test)
                fitted_folds.append([float(t) for t in th_fold])
                variant = tuple((c.candidate.knob, float(t)) for c, t in zip(chosen, th_fold, strict=True))
                fv = np.stack([x[0] for x in runner.map([(variant, s_, False, False) for s_ in seeds])])
                ok1 = good & np.all(np.isfinite(fv), axis=0)
                with np.errstate(invalid="ignore"):
                    m1 = np.nanmean(fv, axis=0)
                    sd1 = np.nanstd(fv, axis=0, ddof=1) * np.sqrt(1.0 + 1.0 / k)
                r1 = np.where(ok1 & (sd1 > 0), (f_real - m1) / np.where(sd1 > 0, sd1, 1.0), 0.0)[good]
                lg = np.bincount(groups, weights=r1 * r1, minlength=n_groups)
                ln = _null_loss(np.where(np.isfinite(fv), fv, 0.0), good, groups, n_groups)
                gsel = np.arange(n_groups) % 2 == fold
                loss_rs[gsel] = lg[gsel]
                null_rs[gsel] = ln[gsel]
            exc_rs = loss_rs - null_rs
            shrink = dict(
                zip(
                    ("estimate", "ci_low", "ci_high"),
                    stats.shrink_ci(exc0, exc_rs, rng, cfg.n_boot),
                    strict=True,
                )
            )
            shrink["fitted_per_fold"] = fitted_folds  # type: ignore[assignment]
            excess["after_resimulated"] = float(exc_rs.sum())
            thetas, pred, plr = fit_effects(r, chosen, np.ones_like(r, dtype=bool))
            after = _residual_by_group((r - pred) * np.exp(-plr), groups, space, good)
            for sg, th in zip(chosen, thetas, strict=True):
                c = sg.candidate
                named.append(
                    {
                        "effect": c.effect,
                        "knob": c.knob,
                        "fitted": th,
                        "baseline": c.baseline,
                        "unit": c.unit,
                        "description": c.description,
                        "at_grid_edge": bool(th <= sg.thetas[0] or th >= sg.thetas[-1]),
                    }
                )
            say("re-localising against the scenario with the named effects")
            variant_all = tuple((c.candidate.knob, float(t)) for c, t in zip(chosen, thetas, strict=True))
            res_all = runner.map([(variant_all, s_, True, False) for s_ in seeds])
            cells_after = localise(
                summarise(real, space.t_edges, space.real_regimes),
                [x[1] for x in res_all if x[1] is not None],
                cfg,
                space.t_edges,
            )
            remaining = _still_open(cells, cells_after, cfg)
        excess["before_heldout"] = float(exc0.sum())
        b_est = bb["estimate"]
        frac = shrink["estimate"] / b_est if b_est > 0 else float("nan")
        lasso_rows, lasso_top = _lasso(r, sigs)
        if chosen:
            lasso_agrees = lasso_top == chosen[0].candidate.effect
        s_est, s_lo, s_hi = shrink["estimate"], shrink["ci_low"], shrink["ci_high"]
        if not chosen:
            verdict = "unexplained"
            summary = (
                f"gap in {len(significant)} cells; no catalogued effect improves held-out groups: unexplained"
            )
        elif not s_est >= cfg.explained_shrink or remaining:
            verdict = "unexplained"
            eff = " + ".join(n["effect"] for n in named)
            summary = (
                f"gap in {len(significant)} cells; unexplained: the best catalogued candidates ({eff}) "
                f"remove {100 * s_est:.0f}% of the held-out gap but {len(remaining)} cells still differ "
                "from the simulation with them"
            )
        else:
            eff = " + ".join(f"{n['effect']} ({n['knob']} = {n['fitted']:.4g} {n['unit']})" for n in named)
            verdict = "explained"
            summary = (
                f"gap in {len(significant)} cells; explained by {eff}; held-out shrink "
                f"{100 * s_est:.0f}% [{100 * s_lo:.0f}, {100 * s_hi:.0f}]"
            )
    return Diagnosis(
        verdict=verdict,
        summary=summary,
        cells=cells,
        significant=significant,
        named=named,
        selection_steps=steps,
        lasso=lasso_rows,
        lasso_agrees=lasso_agrees,
        shrink=shrink,
        shrink_signature=shrink_sig,
        blackbox_shrink=bb,
        fraction_of_removable=frac,
        excess=excess,
        n_features=int(r.size),
        n_groups=n_groups,
        group_regime=space.group_regime,
        settings=settings,
        residual_before=before,
        residual_after=after,
        remaining=remaining,
        cells_after=cells_after,
        group_labels=[obs_mod.label(space.group_regime, int(g), space.t_edges) for g in space.group_keys],
    )


def _still_open(before: Sequence[Cell], after: Sequence[Cell], cfg: Config) -> list[Cell]:
    """Cells that still differ with the named effects: significant, and either not significant
    before (a new discrepancy) or with |z| above ``cell_closed`` times its |z| before."""
    prev = {(c.observable, c.regime, c.key): c for c in before}
    out = []
    for c in after:
        b = prev.get((c.observable, c.regime, c.key))
        for i, q in enumerate(c.q):
            if q >= cfg.alpha:
                continue
            if b is None or b.q[i] >= cfg.alpha or abs(c.z[i]) > cfg.cell_closed * abs(b.z[i]):
                out.append(c)
                break
    return sorted(out, key=lambda c: min(c.q))


def _signatures(
    candidates: Sequence[Candidate],
    runner: _Runner,
    seeds: Sequence[int],
    f_sims: FloatArray,
    sd: FloatArray,
    good: npt.NDArray[np.bool_],
    space: FeatureSpace,
    on_top: Variant = (),
) -> list[Signature]:
    """Simulate each candidate at its grid values on paired seeds; changes in units of s.

    ``on_top``: knob settings the changes are taken against (default the believed scenario);
    the changes stay in units of the believed scenario's s, the SD ratios are against ``on_top``.
    """
    sub = runner.subsampled
    own_base = bool(sub or on_top)
    tasks: list[Task] = [(on_top, s, False, sub) for s in seeds] if own_base else []
    grids = []
    for c in candidates:
        grid = sorted(set(c.grid) | {c.baseline})
        grids.append(grid)
        tasks += [(on_top + ((c.knob, th),), s, False, sub) for th in grid if th != c.baseline for s in seeds]
    results = iter(runner.map(tasks))
    base = np.stack([next(results)[0] for _ in seeds]) if own_base else f_sims[: len(seeds)]
    slot = _slots(space, good)
    n_slots = int(slot.max()) + 1 if slot.size else 0
    with np.errstate(invalid="ignore"):
        var0 = np.nanvar(base, axis=0, ddof=1)[good]
    v0 = np.bincount(slot, weights=np.nan_to_num(var0), minlength=n_slots)
    out = []
    for c, grid in zip(candidates, grids, strict=True):
        deltas, ratios = [], []
        for th in grid:
            if th == c.baseline:
                deltas.append(np.zeros(int(good.sum())))
                ratios.append(np.zeros(int(good.sum())))
                continue
            fs = np.stack([next(results)[0] for _ in seeds])
            with np.errstate(invalid="ignore"):
                d = np.nanmean(fs - base, axis=0)[good] / sd[good]
                var1 = np.nanvar(fs, axis=0, ddof=1)[good]
            v1 = np.bincount(slot, weights=np.nan_to_num(var1), minlength=n_slots)
            lr = 0.5 * np.log(np.maximum(v1, 1e-300) / np.maximum(v0, 1e-300))
            lr = np.where((v0 > 0) & (v1 > 0), lr, 0.0)
            deltas.append(np.where(np.isfinite(d), d, 0.0))
            ratios.append(lr[slot])
        out.append(
            Signature(
                candidate=c,
                thetas=np.asarray(grid, np.float64),
                deltas=np.stack(deltas),
                log_ratio=np.stack(ratios),
            )
        )
    return out


def _slots(space: FeatureSpace, good: npt.NDArray[np.bool_]) -> IntArray:
    """Feature slot (observable x cell x statistic, pooled over groups) of each good feature."""
    key = np.stack([space.feat_obs, space.feat_cell, space.feat_stat], 1)[good]
    return np.unique(key, axis=0, return_inverse=True)[1].ravel().astype(np.int64)


def _lasso(r: FloatArray, sigs: Sequence[Signature]) -> tuple[list[dict[str, Any]], str | None]:
    """Lasso of the residual on each candidate's signature at its grid extremes (both signs)."""
    cols, labels = [], []
    for s in sigs:
        b = s.candidate.baseline
        for th in (s.thetas[0], s.thetas[-1]):
            if th != b:
                cols.append(s.at(np.array([th]))[0])
                labels.append((s.candidate.effect, float(th)))
    if not cols:
        return [], None
    x = np.stack(cols, axis=1)
    norms = np.linalg.norm(x, axis=0)
    xn = x / np.where(norms > 0, norms, 1.0)
    lam = float(np.sqrt(2.0 * np.log(max(r.size, 2))))
    coef = stats.lasso_cd(xn, r, lam)
    contrib = np.abs(coef)
    rows: list[dict[str, Any]] = [
        {"effect": e, "at": th, "weight": float(cf / n) if n > 0 else 0.0, "contribution": float(ct)}
        for (e, th), cf, n, ct in zip(labels, coef, norms, contrib, strict=True)
    ]
    rows.sort(key=lambda d: -d["contribution"])
    top = rows[0]["effect"] if rows and rows[0]["contribution"] > 0 else None
    return [d for d in rows if d["contribution"] > 0], (str(top) if top is not None else None)


def _residual_by_group(
    r: FloatArray, groups: IntArray, space: FeatureSpace, good: npt.NDArray[np.bool_]
) -> dict[str, Any]:
    """Mean squared standardised residual per group and per observable x statistic (for plots)."""
    obs_i = space.feat_obs[good]
    st_i = space.feat_stat[good]
    out: dict[str, Any] = {}
    for oi, name in enumerate(space.observables):
        for si, sname in enumerate(stats.FEATURE_NAMES):
            m = (obs_i == oi) & (st_i == si)
            if not np.any(m):
                continue
            cnt = np.bincount(groups[m], minlength=len(space.group_keys))
            ssq = np.bincount(groups[m], weights=r[m] ** 2, minlength=len(space.group_keys))
            mean_r = np.bincount(groups[m], weights=r[m], minlength=len(space.group_keys))
            out[f"{name}:{sname}"] = {
                "mean_z": [float(v) for v in mean_r / np.maximum(cnt, 1)],
                "mean_z2": [float(v) for v in ssq / np.maximum(cnt, 1)],
            }
    out["groups"] = [obs_mod.label(space.group_regime, int(k), space.t_edges) for k in space.group_keys]
    return out
