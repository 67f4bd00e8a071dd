"""The gap diagnosis' fast paths compute what the plain ones compute (issue 13, speed).

Each test runs the batched / cached / pooled path and a plain reference written out here (the
code before the speed-up) on the same inputs and asks for equal results: bit for bit where the
arithmetic is the same, which is every path here but two: the fits' masked sums of the t loss and
the rate fit's profile over time constants are compared to rounding (see their tests).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest
from test_gap_stability import _d
from uwbcal.gap import attribute, localise, stability, stats
from uwbcal.gap.attribute import Candidate, Signature
from uwbcal.gap.config import Config
from uwbcal.gap.engine import Diagnosis
from uwbcal.gap.observables import Regimes


def _signatures(rng: np.random.Generator, n_feat: int, n_sig: int) -> list[Signature]:
    out = []
    for i in range(n_sig):
        grid = np.sort(np.unique(np.concatenate([[0.0], rng.uniform(-2, 3, 5)])))
        slope = rng.normal(size=n_feat) * (rng.random(n_feat) < 0.3)
        deltas = np.outer(grid, slope) + 0.2 * np.outer(grid**2, rng.normal(size=n_feat))
        lr = np.outer(np.abs(grid), 0.1 * rng.random(n_feat) * (rng.random(n_feat) < 0.2))
        c = Candidate(effect=f"e{i}", knob=f"k{i}", baseline=0.0, grid=tuple(grid), unit="")
        out.append(Signature(candidate=c, thetas=grid, deltas=deltas, log_ratio=lr))
    return out


def _fit_plain(
    r: npt.NDArray[np.float64], sigs: Sequence[Signature], mask: npt.NDArray[np.bool_], sweeps: int = 3
) -> tuple[list[float], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """fit_effects the plain way: tables re-interpolated, one fit at a time, then the zoom pass."""
    thetas = [float(s.candidate.baseline) for s in sigs]
    fines = [attribute._fine(s) for s in sigs]
    mtab = [s.at(f) for s, f in zip(sigs, fines, strict=True)]
    ltab = [s.log_ratio_at(f) for s, f in zip(sigs, fines, strict=True)]
    mu = [np.zeros_like(r) for _ in sigs]
    lr = [np.zeros_like(r) for _ in sigs]
    picks = [0] * len(sigs)
    for _ in range(sweeps if len(sigs) > 1 else 1):
        for i in range(len(sigs)):
            mo = sum((mu[j] for j in range(len(sigs)) if j != i), np.zeros_like(r))[mask]
            lo = sum((lr[j] for j in range(len(sigs)) if j != i), np.zeros_like(r))[mask]
            loss = np.sum(
                attribute._nll(
                    r[mask][None, :], mo[None, :] + mtab[i][:, mask], lo[None, :] + ltab[i][:, mask]
                ),
                axis=1,
            )
            b = int(np.argmin(loss))
            picks[i] = b
            thetas[i] = float(fines[i][b])
            mu[i] = mtab[i][b]
            lr[i] = ltab[i][b]
    for i, b in enumerate(picks):  # zoom between the grid neighbours of each pick
        zt = np.linspace(fines[i][max(b - 1, 0)], fines[i][min(b + 1, fines[i].size - 1)], 33)
        zm, zl = sigs[i].at(zt), sigs[i].log_ratio_at(zt)
        mo = sum((mu[j] for j in range(len(sigs)) if j != i), np.zeros_like(r))[mask]
        lo = sum((lr[j] for j in range(len(sigs)) if j != i), np.zeros_like(r))[mask]
        zloss = np.sum(
            attribute._nll(r[mask][None, :], mo[None, :] + zm[:, mask], lo[None, :] + zl[:, mask]), axis=1
        )
        now = float(np.sum(attribute._nll(r[mask], mo + mu[i][mask], lo + lr[i][mask])))
        bz = int(np.argmin(zloss))
        if zloss[bz] < now:
            thetas[i], mu[i], lr[i] = float(zt[bz]), zm[bz], zl[bz]
    return thetas, sum(mu, np.zeros_like(r)), sum(lr, np.zeros_like(r))


@pytest.mark.parametrize("n_sig", [1, 2, 3])
def test_batched_fold_fits_equal_one_fit_per_fold(n_sig: int) -> None:
    rng = np.random.default_rng(10 + n_sig)
    n_feat, n_groups = 300, 7
    sigs = _signatures(rng, n_feat, n_sig)
    groups = rng.integers(0, n_groups, n_feat)
    r = rng.normal(size=n_feat) + sigs[0].at(np.array([1.3]))[0]
    nll, chi2 = attribute._cv_losses(r, sigs, groups, n_groups)
    for g in range(n_groups):
        test = groups == g
        th, mu, lr = _fit_plain(r, sigs, ~test)
        th2, mu2, lr2 = attribute.fit_effects(r, sigs, ~test)
        assert th == th2 and np.array_equal(mu, mu2) and np.array_equal(lr, lr2)
        assert nll[g] == float(np.sum(attribute._nll(r[test], mu[test], lr[test])))
        assert chi2[g] == float(np.sum((r[test] - mu[test]) ** 2 * np.exp(-2.0 * lr[test])))
    # the fit moved off the baseline: the comparison is not between two do-nothing fits
    assert attribute.fit_effects(r, sigs, np.ones(n_feat, bool))[0][0] != 0.0


def test_nll_in_two_buffers_equals_the_plain_expression_in_values_and_memory_order() -> None:
    rng = np.random.default_rng(19)
    r = rng.normal(size=300) * 30
    mu, lr = rng.normal(size=(40, 300)), rng.normal(size=(40, 300)) * 0.2
    cols = rng.random(300) < 0.8  # a[:, mask] is Fortran-ordered, and so are ufuncs of it

    def plain(r_: Any, mu_: Any, lr_: Any) -> Any:
        return (attribute.ROBUST_DOF + 1.0) * np.log1p(
            (r_ - mu_) ** 2 * np.exp(-2.0 * lr_) / attribute.ROBUST_DOF
        ) + 2.0 * lr_

    for args in (
        (r[None, :], mu, lr),
        (r[cols][None, :], mu[:, cols], lr[:, cols]),
        (r, mu[3], lr[3]),
        (r[:5], mu[:, :5], lr[0, :5]),
        (r[:5], mu[0, :5], lr[:, :5]),  # lr broadcasts beyond r - mu
    ):
        got, want = attribute._nll(*args), plain(*args)
        assert np.array_equal(got, want)
        assert got.flags["C_CONTIGUOUS"] == want.flags["C_CONTIGUOUS"]
        assert np.array_equal(np.sum(got, axis=-1), np.sum(want, axis=-1))


def test_forward_selection_with_its_fits_in_a_pool_equals_serial() -> None:
    rng = np.random.default_rng(21)
    n_feat, n_groups = 400, 8
    sigs = _signatures(rng, n_feat, 7)
    groups = np.repeat(np.arange(n_groups), n_feat // n_groups)
    r = rng.normal(size=n_feat) + sigs[0].at(np.array([1.3]))[0] + sigs[3].at(np.array([-1.1]))[0]
    runs = []
    for jobs in (1, 2):
        fresh = [dataclasses.replace(sg) for sg in sigs]  # no tables built by the other run
        cfg = Config(jobs=jobs)
        sel = attribute.forward_select(r, fresh, groups, n_groups, cfg, np.random.default_rng(0))
        runs.append((sel.chosen, sel.steps, sel.fold_chi2_base.tolist(), sel.fold_chi2_sel.tolist()))
    assert runs[0] == runs[1]
    # the pool ran: several steps, each ranking several singles (and blocks of the leading ones)
    assert len(runs[0][1]) >= 2 and all(len(st["ranking"]) > 3 for st in runs[0][1])


def test_fine_tables_are_the_interpolated_grid() -> None:
    sig = _signatures(np.random.default_rng(3), 50, 1)[0]
    fine, m, lr = sig.fine_tables()
    assert np.array_equal(fine, attribute._fine(sig))
    assert np.array_equal(m, sig.at(fine)) and np.array_equal(lr, sig.log_ratio_at(fine))
    assert sig.fine_tables()[1] is m  # built once
    assert dataclasses.replace(sig, deltas=2 * sig.deltas).fine_tables()[1][-1] == pytest.approx(2 * m[-1])


def test_zoom_tables_are_the_interpolated_zoom_grid() -> None:
    sig = _signatures(np.random.default_rng(4), 50, 1)[0]
    fine = sig.fine_tables()[0]
    for b in [0, 5, fine.size - 1, 5, *range(10, 10 + attribute.ZOOM_KEPT + 2), 5]:
        zt, zm, zl = sig.zoom_tables(b)
        want = np.linspace(fine[max(b - 1, 0)], fine[min(b + 1, fine.size - 1)], 33)
        assert np.array_equal(zt, want)
        assert np.array_equal(zm, sig.at(want)) and np.array_equal(zl, sig.log_ratio_at(want))
        assert len(sig._zooms) <= attribute.ZOOM_KEPT
    assert sig.zoom_tables(5)[1] is sig.zoom_tables(5)[1]  # kept


def test_group_features_with_a_given_order_equal_the_plain_ones() -> None:
    rng = np.random.default_rng(5)
    n, cells = 5000, 9
    cell = rng.integers(0, cells, n)
    key = rng.permutation(n).astype(float)
    v = np.round(rng.standard_t(3, size=n) * 40) / 40 + cell  # quantised: many ties
    plain = stats.group_features(v, cell, cells, key)
    fast = stats.group_features(v, cell, cells, key, order=np.lexsort((key, cell)))
    assert np.array_equal(plain, fast, equal_nan=True)
    with pytest.raises(ValueError, match="finite"):
        stats.group_features(np.where(cell == 0, np.nan, v), cell, cells, key, order=np.lexsort((key, cell)))


def _group_features_plain(
    values: npt.NDArray[np.float64], cell: npt.NDArray[np.int64], n_cells: int, key: npt.NDArray[np.float64]
) -> npt.NDArray[np.float64]:
    """stats.group_features before the speed-ups: one (cell, time) and one (cell, value) lexsort."""
    out = np.full((n_cells, 5), np.nan)
    ok = np.isfinite(values)
    v, c, k = values[ok], cell[ok], key[ok]
    cnt = np.bincount(c, minlength=n_cells)
    mean = np.bincount(c, weights=v, minlength=n_cells) / np.maximum(cnt, 1)
    dev = v - mean[c]
    s2 = np.bincount(c, weights=dev * dev, minlength=n_cells)
    order = np.lexsort((k, c))
    cs, ds = c[order], dev[order]
    same = cs[1:] == cs[:-1]
    prod = np.bincount(cs[1:][same], weights=(ds[1:] * ds[:-1])[same], minlength=n_cells)
    lag1 = prod / np.maximum(s2, 1e-300)
    start = np.concatenate([[0], np.cumsum(cnt)[:-1]])
    csum = np.concatenate([[0.0], np.cumsum(v[np.lexsort((v, c))])])
    lo = np.floor(0.25 * cnt).astype(np.int64)
    hi = np.maximum(np.ceil(0.75 * cnt).astype(np.int64), lo + 1)
    loc = (csum[np.minimum(start + hi, v.size)] - csum[start + lo]) / (hi - lo)
    mad = np.bincount(c, weights=np.abs(v - loc[c]), minlength=n_cells) / np.maximum(cnt, 1)
    good = cnt >= 5
    sd = np.sqrt(s2 / np.maximum(cnt - 1, 1))
    out[good] = np.stack(
        [
            mean[good],
            loc[good],
            np.log(np.maximum(mad[good], 1e-300)),
            lag1[good],
            np.log(np.maximum(sd[good], 1e-300) / np.maximum(mad[good], 1e-300)),
        ],
        axis=1,
    )
    return out


def test_a_group_plan_reused_for_other_values_equals_the_plain_features() -> None:
    rng = np.random.default_rng(15)
    n, cells = 4000, 13
    cell = rng.integers(0, cells, n)
    cell[cell == 12] = 11  # an empty cell
    cell[:3] = 12  # and one below min_count
    key = rng.permutation(n).astype(float)
    plan = stats.GroupPlan(cell, cells, np.lexsort((key, cell)), 5)
    for q in (40.0, 3.0, 1e6):  # heavy ties .. none
        v = np.round(rng.standard_t(3, size=n) * q) / q + cell
        want = _group_features_plain(v, cell, cells, key)
        assert np.array_equal(plan.features(v), want, equal_nan=True)
        assert np.array_equal(stats.group_features(v, cell, cells, key), want, equal_nan=True)
    some_nan = np.where(rng.random(n) < 0.05, np.nan, v)
    assert np.array_equal(
        stats.group_features(some_nan, cell, cells, key),
        _group_features_plain(some_nan, cell, cells, key),
        equal_nan=True,
    )


def test_feature_space_plans_follow_the_finite_records() -> None:
    """A FeatureSpace reuses its plan only while the same records are finite."""
    from uwbcal.gap.features import FeatureSpace

    rng = np.random.default_rng(16)
    n = 3000
    t = np.sort(rng.uniform(0, 30, n))
    keys = {
        "time": np.minimum((t // 3).astype(np.int64), 9),
        "spacing": rng.integers(0, 3, n).astype(np.int64),
    }
    reg = Regimes(keys=keys, t_edges=np.linspace(0, 30, 11))
    space = FeatureSpace(
        observables=["clock_rate_ppm"],
        group_regime="time",
        group_keys=np.arange(10, dtype=np.int64),
        cell_regimes=["spacing"],
        cell_keys=np.arange(3, dtype=np.int64)[:, None],
        t_edges=reg.t_edges,
        real_regimes=reg,
    )
    flat = keys["time"] * 3 + keys["spacing"]

    def session(drop: float) -> dict[str, Any]:
        """Records whose clock rate is quantised noise, NaN (P3 stamps equal P1's: 0/0) on ``drop``."""
        tx1 = np.arange(n, dtype=np.int64) * 10**9
        d13 = np.full(n, 2 * 10**8, np.int64)
        c13 = rng.integers(990, 1010, n)  # rate = c13 / d13 * 1e6: about 5 ppm, many ties
        gone = rng.random(n) < drop
        d13[gone], c13[gone] = 0, 0
        return {
            "seq": np.arange(n),
            "t_s": t,
            "tx1": tx1,
            "tx2": tx1 + 10**8,
            "tx3": tx1 + d13,
            "rx1": tx1 + 5,
            "rx2": tx1 + 5 + 10**8,
            "rx3": tx1 + 5 + d13 + c13,
        }

    from uwbcal.gap import observables as obs_mod

    nan_counts = []
    for drop in (0.0, 0.0, 0.1, 0.0, 0.2, 0.2):
        rec = session(drop)
        v = obs_mod.observables(rec)["clock_rate_ppm"]
        nan_counts.append(int(np.count_nonzero(np.isnan(v))))
        want = _group_features_plain(v, flat, 30, t)
        assert np.array_equal(space.features(rec, 5).reshape(30, 5), want, equal_nan=True)
    assert nan_counts[0] == 0 and nan_counts[2] > 100 and nan_counts[4] != nan_counts[5]


def _ks_plain(xs: npt.NDArray[np.float64], loc: float, den: float, zr: npt.NDArray[np.float64]) -> float:
    """stats.two_sample_stats' KS distance before the speed-up: the ECDF at every sample value."""
    n, nr = xs.size, zr.size
    cdf_ref = np.searchsorted(zr, (xs - loc) / den, side="right") / nr
    i = np.arange(1, n + 1) / n
    return float(np.max(np.maximum(np.abs(i - cdf_ref), np.abs(i - 1.0 / n - cdf_ref))))


def test_ks_distance_by_branch_and_bound_equals_every_point() -> None:
    rng = np.random.default_rng(17)
    searched = []
    for trial in range(120):
        n = int(rng.choice([7, 3000, 4200, 9000, 30000]))
        nr = int(rng.choice([6, 800, 20000]))
        q = float(rng.choice([0.0, 4.0, 300.0]))  # quantised like timestamps or register values
        x = rng.standard_t(4, n) * float(rng.choice([1.0, 1.7])) + float(rng.choice([0.0, 0.02, 0.4, 5.0]))
        r = rng.normal(size=nr)
        if q:
            x, r = np.round(x * q) / q, np.round(r * q) / q
        xs, zr = np.sort(x), np.sort(r)
        loc, den = float(rng.normal(0, 0.1)), float(rng.uniform(0.8, 1.3))
        assert stats.ks_distance(xs, loc, den, zr) == _ks_plain(xs, loc, den, zr), trial
        searched.append(n > 4 * stats._KS_STRIDES[0])
    assert sum(searched) > 30  # the branch and bound ran, not only the plain path


def test_leave_one_out_counts_and_ks_distances_equal_the_built_references() -> None:
    """Every seed's and a real sample's KS distance against the K leave-one-out references at once
    (stats.ks_distances) equals one plain KS distance per built reference; ties and quantised values
    included, and a seed without values in the pool."""
    rng = np.random.default_rng(20)
    for trial in range(12):
        k = int(rng.choice([3, 8]))
        q = float(rng.choice([0.0, 6.0]))
        sizes = rng.integers(0, 3000, k) if trial % 3 else np.full(k, 2500)
        sizes[0] = 0 if trial % 4 == 1 else sizes[0]
        ys = [rng.normal(size=int(m)) * (1 + 0.1 * j) for j, m in enumerate(sizes)]
        if q:
            ys = [np.round(y * q) / q for y in ys]
        pool = np.concatenate(ys)
        src = np.repeat(np.arange(k), [y.size for y in ys])
        order = np.argsort(pool, kind="stable")
        pool, src = pool[order], src[order]
        loo = stats.LeaveOneOut(pool, src, k)
        x = np.sort(rng.standard_t(5, size=int(rng.choice([6, 5000]))) + float(rng.choice([0.0, 0.3])))
        if q:
            x = np.sort(np.round(x * q) / q)
        probs, want = [], []
        for j in range(k):
            ref_j = pool[src != j]
            rloc, rden = float(rng.normal(0, 0.05)), float(rng.uniform(0.9, 1.1))
            zr = (ref_j - rloc) / rden
            qs = rng.normal(size=50) * 2
            if q:
                qs = np.concatenate([qs, zr[:: max(zr.size // 40, 1)]])  # queries on the values
            got = loo.count(np.full(qs.size, j), qs, np.full(qs.size, rloc), np.full(qs.size, rden))
            assert np.array_equal(got, np.searchsorted(zr, qs, side="right"))
            own = np.sort(ys[j])
            for sample, sl, sd in ((own, 0.01, 1.02), (x, -0.02, 0.97)):
                if sample.size:
                    probs.append((j, sl, sd, rloc, rden, sample))
                    want.append(_ks_plain(sample, sl, sd, zr))
        sample_all = np.concatenate([p[5] for p in probs])
        size = np.array([p[5].size for p in probs], dtype=np.int64)
        start = np.concatenate([[0], np.cumsum(size)[:-1]])
        col = [np.array([p[i] for p in probs]) for i in range(5)]
        got_ks = stats.ks_distances(sample_all, start, size, col[1], col[2], loo, col[0], col[3], col[4])
        assert np.array_equal(got_ks, np.array(want)), trial


def test_picked_reference_equals_the_pick_of_the_whole_pool() -> None:
    rng = np.random.default_rng(18)
    ys = [np.round(rng.normal(size=int(rng.integers(50, 400))) * 4) / 4 for _ in range(9)]
    pooled = np.concatenate(ys)
    src = np.repeat(np.arange(9), [y.size for y in ys])
    pick = rng.choice(pooled.size, 700, replace=False)
    vals, seed = localise._reference(ys, pick)
    order, order_plain = np.argsort(vals), np.argsort(pooled[pick])
    for j in range(9):  # each leave-one-out reference has the same values in the same order
        got = vals[order][seed[order] != j]
        assert np.array_equal(got, pooled[pick][order_plain][src[pick][order_plain] != j])
    whole, seed_whole = localise._reference(ys, None)
    assert np.array_equal(whole, pooled) and np.array_equal(seed_whole, src)


@pytest.mark.parametrize("jobs", [1, 2])
def test_runner_runs_each_job_once_and_returns_what_a_fresh_run_does(jobs: int) -> None:
    from uwbcal import vectorsim
    from uwbcal.gap import model, pool, validate
    from uwbcal.gap.features import build_space
    from uwbcal.physics.scenario import load_scenario
    from uwbcal.physics.world import World

    sc = load_scenario(validate.SCENARIO)
    real, _ = vectorsim.run_triplets(World(sc, 3), validate.validation_schedule(sc, per_step=30))
    cfg = Config(jobs=jobs)
    space = build_space(real, cfg, ["drift_residual_m", "clock_rate_ppm"])
    physics = model.physics_simulator(real, sc)
    calls: list[tuple[Any, int]] = []

    def sim(variant: Any, seed: int) -> Any:
        calls.append((variant, seed))
        return physics(variant, seed)

    a, b = (("effect:interference:amplitude_ps", 300.0),), (("effect:multipath:probability", 0.1),)
    plan = [  # (tasks of one map call, jobs it should run)
        ([((), 1, True, False), ((), 2, True, False)], 2),
        ([((), 1, False, False), (a, 1, False, False), (a, 2, False, False)], 2),  # the base is known
        ([(b, 1, False, False), (b, 2, False, False)], 2),  # one variant: summaries kept
        ([(b, 2, True, False), (b, 1, True, False)], 0),
        ([(a, 1, True, False)], 1),  # its features are known, its summary is not
    ]
    runner = pool.Runner(sim, space, cfg)
    try:
        for tasks, runs in plan:
            calls.clear()
            got = runner.map(tasks)
            if jobs == 1:  # the workers' calls are not seen here
                assert len(calls) == runs
            pool._JOB.update(simulate=physics)
            for t, (f, summ) in zip(tasks, got, strict=True):
                f0, s0 = pool._job(t)
                assert np.array_equal(f, f0, equal_nan=True)
                assert (summ is None) == (s0 is None)
                if summ is not None and s0 is not None:
                    assert summ[1] is space.real_regimes
                    assert summ[0].keys() == s0[0].keys()
                    assert all(np.array_equal(summ[0][k], s0[0][k], equal_nan=True) for k in s0[0])
            pool._JOB.update(simulate=sim)
    finally:
        runner.close()


def _summaries(rng: np.random.Generator, k: int, n: int) -> tuple[Any, list[Any]]:
    keys = {
        "direction": np.repeat([1002, 2001], n // 2).astype(np.int64),
        "step": rng.integers(0, 4, n).astype(np.int64),
    }
    reg = Regimes(keys=keys, t_edges=np.array([0.0, np.inf]))

    def ob(shift: float) -> dict[str, npt.NDArray[np.float64]]:
        x = np.round(rng.normal(size=n) * 8 + shift) / 8  # quantised like a timestamp
        x[rng.random(n) < 0.01] = np.nan
        return {"a": x, "b": rng.standard_t(4, size=n) + 0.1 * keys["step"]}

    return (ob(8.0), reg), [(ob(0.0), reg) for _ in range(k)]


def test_localise_in_a_pool_equals_serial() -> None:
    real, sims = _summaries(np.random.default_rng(6), 6, 2000)
    t_edges = np.array([0.0, np.inf])
    cfg = Config(ks_ref_max=3000, min_cell=20)  # pools above 3000 values are subsampled: rng order
    serial = localise.localise(real, sims, cfg, t_edges)
    pooled = localise.localise(real, sims, dataclasses.replace(cfg, jobs=2), t_edges)
    assert len(serial) > 8
    assert [c.to_json() for c in serial] == [c.to_json() for c in pooled]
    assert any(min(c.q) < 0.01 for c in serial)  # the shifted observable is found


def _fake_diagnosis(cfg: Config) -> Diagnosis:
    d = _d("explained" if cfg.seed % 3 else "unexplained", [("e", float(cfg.seed))])
    d.summary = f"seed {cfg.seed} jobs {cfg.jobs}"
    d.settings = {"jobs": cfg.jobs, "seed": cfg.seed}
    return d


def test_ensembles_in_one_pool_equal_one_after_the_other(monkeypatch: pytest.MonkeyPatch) -> None:
    seen: list[tuple[int, int]] = []

    def fake(real: Any, simulate: Any, candidates: Any, cfg: Config, **_kw: Any) -> Diagnosis:
        seen.append((cfg.seed, cfg.jobs))
        return _fake_diagnosis(cfg)

    monkeypatch.setattr(stability, "diagnose", fake)
    runs = {}
    for jobs in (1, 2):
        cfg = Config(seed=5, jobs=jobs)
        runs[jobs] = stability.diagnose_stable({}, lambda v, s: {}, [], cfg, ensembles=3, min_share=0.5)
    assert seen == [(5, 1), (5 + stability.STRIDE, 1), (5 + 2 * stability.STRIDE, 1)]  # jobs 2: in workers
    a, b = runs[1], runs[2]
    assert a.verdict == b.verdict and a.named == b.named and a.summary == b.summary
    assert {**a.settings, "jobs": 2} == b.settings
    assert b.settings["jobs"] == 2 and b.named[0]["fitted_per_ensemble"] == [
        5.0,
        5.0 + stability.STRIDE,
        5.0 + 2 * stability.STRIDE,
    ]


def test_window_log_ratios_equal_the_plain_clipped_means() -> None:
    """stations.window_log_ratios (cumulative sums) against each window's clipped mean deviation
    and the rest's, written out plainly, with values on a lattice and a lost record."""
    from uwbcal.gap.stations import CLIP_SD, window_log_ratios, windows

    rng = np.random.default_rng(8)
    for n in (61, 400, 401):
        t = np.sort(rng.uniform(0.0, 60.0, n))
        v = np.round(rng.standard_t(3, size=n) * 5) / 5  # ties, as whole DW1000 ticks give
        v[n // 3] = np.nan
        wins = windows(t, 10.0, 10)
        got = window_log_ratios(v, wins)
        ok = np.isfinite(v)
        dev = np.abs(v - np.median(v[ok]))
        sd = 1.4826 * np.median(dev[ok]) or 1.2533 * np.mean(dev[ok])
        d = np.minimum(dev, CLIP_SD * sd)
        for k, (_s, _e, i0, i1) in enumerate(wins):
            inside = np.zeros(n, bool)
            inside[i0:i1] = True
            want = np.log(np.mean(d[inside & ok]) / np.mean(d[~inside & ok]))
            assert got[k] == pytest.approx(want, rel=1e-12, abs=1e-12)


# --- phase 2 of the 100k-record speed work: changes of what is computed, for long sessions ------


def test_sequential_signature_seeds_take_more_seeds_only_where_needed() -> None:
    """A subsampled session's signatures: on the first seeds where the changes are already known to
    Config.signature_se floor SDs, on all seeds where not; each equals the plain signature on the
    seeds it used."""
    from uwbcal import vectorsim
    from uwbcal.gap import model, pool, validate
    from uwbcal.gap.features import build_space
    from uwbcal.physics.scenario import load_scenario
    from uwbcal.physics.world import World

    sc = load_scenario(validate.SCENARIO)
    real, _ = vectorsim.run_triplets(World(sc, 5), validate.validation_schedule(sc, per_step=40))
    cfg = Config(signature_seeds_first=3, signature_se=0.5)
    space = build_space(real, cfg, ["drift_residual_m", "clock_rate_ppm", "rx_level_dbm"])
    sim = model.physics_simulator(real, sc)
    seeds = list(range(1, 9))
    f_sims = np.stack([space.features(sim((), s), cfg.min_feature) for s in range(100, 124)])
    sd = np.nanstd(f_sims, axis=0, ddof=1)
    good = np.all(np.isfinite(f_sims), axis=0) & (sd > 0)
    cands = {c.effect: c for c in model.candidates(sc) if not c.shape}
    picked = [cands["rx_power_estimate"], cands["clock_wander"]]  # a deterministic and a noisy one
    runner = pool.Runner(sim, space, cfg, sim, space)  # "subsampled": the same schedule here
    assert runner.sequential == (3, 0.5)
    short = pool.Runner(sim, space, cfg)  # a session short enough for signatures on all records
    assert short.sequential is None
    short.close()
    plain = pool.Runner(sim, space, dataclasses.replace(cfg, signature_seeds_first=0), sim, space)
    assert plain.sequential is None
    try:
        got = attribute.signatures(picked, runner, seeds, f_sims, sd, good, space)
        assert [sg.n_seeds for sg in got] == [3, 8]
        for sg, n in zip(got, (3, 8), strict=True):
            want = attribute.signatures([sg.candidate], plain, seeds[:n], f_sims, sd, good, space)[0]
            assert np.array_equal(sg.deltas, want.deltas) and np.array_equal(sg.log_ratio, want.log_ratio)
            assert sg.trace_z == want.trace_z
    finally:
        runner.close()
        plain.close()


def test_masked_nll_sums_equal_the_sums_of_the_plain_nll_over_each_mask() -> None:
    rng = np.random.default_rng(23)
    n_feat, n_grid = 400, 37
    r = rng.normal(size=n_feat) * rng.choice([1.0, 30.0, 3000.0], n_feat)  # gross residuals too
    mo, lo = rng.normal(size=n_feat), rng.normal(size=n_feat) * 0.3
    mtab, ltab = rng.normal(size=(n_grid, n_feat)) * 5, rng.normal(size=(n_grid, n_feat)) * 0.4
    masks = rng.random((9, n_feat)) < 0.7
    plain = attribute._nll(r[None, :], mo[None, :] + mtab, lo[None, :] + ltab)
    want = np.stack([np.sum(plain[:, m], axis=1) for m in masks], axis=1)
    got = attribute._masked_nll_sums(r, mo, lo, mtab, ltab, np.exp(-2.0 * ltab), masks.astype(np.float64))
    # a few ulps per term (log(1 + z) for log1p(z), exp(-2 a) exp(-2 b) for exp(-2 (a + b)), another
    # order of addition): far below a loss difference that could change a pick
    assert got.shape == want.shape
    np.testing.assert_allclose(got, want, rtol=1e-11, atol=1e-9)
    assert np.array_equal(np.argmin(got, axis=0), np.argmin(want, axis=0))
    # a feature that is not finite spoils only the sums of the masks that hold it
    r2 = r.copy()
    r2[5] = np.nan
    masks[:4, 5] = False
    masks[4:, 5] = True
    plain = attribute._nll(r2[None, :], mo[None, :] + mtab, lo[None, :] + ltab)
    want = np.stack([np.sum(plain[:, m], axis=1) for m in masks], axis=1)
    got = attribute._masked_nll_sums(r2, mo, lo, mtab, ltab, np.exp(-2.0 * ltab), masks.astype(np.float64))
    np.testing.assert_allclose(got[:, :4], want[:, :4], rtol=1e-11, atol=1e-9)
    assert np.all(np.isnan(got[:, 4:])) and np.all(np.isnan(want[:, 4:]))


def test_rate_profile_equals_three_column_least_squares() -> None:
    from uwbcal.gap import model

    rng = np.random.default_rng(29)
    u = np.sort(rng.uniform(0.0, 900.0, 5000))
    y = 0.3 - 0.8 * np.exp(-u / 40.0) + 0.5 * np.exp(-u / 7.0) + rng.normal(size=u.size) * 0.01
    taus = np.concatenate([np.geomspace(2.0, 3000.0, 19), [40.0]])  # 40 s: the believed stage again
    got = model.rss_profile(u, y, 40.0)(taus)
    for t, g in zip(taus, got, strict=True):
        x = np.stack([np.ones_like(u), np.exp(-u / 40.0), np.exp(-u / t)], axis=1)
        coef = np.linalg.lstsq(x, y, rcond=None)[0]
        want = float(np.sum((y - x @ coef) ** 2))
        assert g == pytest.approx(want, rel=1e-8, abs=1e-12)
    assert taus[int(np.argmin(got))] == pytest.approx(7.0, rel=0.3)  # the second stage is found
