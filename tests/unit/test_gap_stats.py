"""The gap diagnosis' statistics machinery on synthetic arrays (no physics)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats as sps
from uwbcal.gap import stats


def test_bh_matches_hand_computation_and_scipy() -> None:
    p = np.array([0.01, 0.04, 0.03, 0.5])
    # sorted 0.01 0.03 0.04 0.5 -> p*m/i = 0.04 0.06 0.0533 0.5 -> running min from the top
    np.testing.assert_allclose(stats.bh_fdr(p), [0.04, 0.16 / 3, 0.16 / 3, 0.5])
    rng = np.random.default_rng(1)
    q = rng.uniform(size=200) ** 3
    np.testing.assert_allclose(stats.bh_fdr(q), sps.false_discovery_control(q, method="bh"))
    assert np.isnan(stats.bh_fdr([np.nan, 0.2])[0])


def test_floor_pvalues_are_calibrated_and_powerful() -> None:
    rng = np.random.default_rng(2)
    k, cells = 16, 3000
    null = rng.normal(size=(k, cells, 4))
    null[..., 3] = np.exp(rng.normal(size=(k, cells)) * 0.2 - 2.0)  # a positive distance
    obs = rng.normal(size=(cells, 4))
    obs[:, 3] = np.exp(rng.normal(size=cells) * 0.2 - 2.0)
    p, z = stats.floor_pvalues(obs, null)
    assert p.shape == (cells, 4)
    frac = np.mean(p < 0.05, axis=0)
    assert np.all((frac > 0.03) & (frac < 0.07))  # exchangeable with the floor: uniform p
    obs_shift = obs.copy()
    obs_shift[:, 0] += 8.0
    p2, z2 = stats.floor_pvalues(obs_shift, null)
    assert np.mean(p2[:, 0] < 1e-4) > 0.95 and np.median(z2[:, 0]) > 5


def test_two_sample_stats_separate_location_scale_shape() -> None:
    rng = np.random.default_rng(3)
    ref = np.sort(rng.normal(size=20000))
    same = stats.two_sample_stats(rng.normal(size=500), ref, float(ref.mean()), float(ref.var(ddof=1)))
    shifted = stats.two_sample_stats(
        rng.normal(size=500) + 0.5, ref, float(ref.mean()), float(ref.var(ddof=1))
    )
    wider = stats.two_sample_stats(2.0 * rng.normal(size=500), ref, float(ref.mean()), float(ref.var(ddof=1)))
    bimodal = stats.two_sample_stats(
        np.sign(rng.normal(size=500)) + 0.2 * rng.normal(size=500),
        ref,
        float(ref.mean()),
        float(ref.var(ddof=1)),
    )
    assert abs(same[0]) < 4 and abs(same[2]) < 0.2 and same[3] < 0.1
    assert shifted[0] > 6 and shifted[1] > 0.3 and abs(shifted[2]) < 0.2
    assert wider[2] > 0.5 and abs(wider[0]) < 4
    assert bimodal[3] > 2 * same[3] and bimodal[3] > 0.1


def test_group_features_match_direct_computation() -> None:
    rng = np.random.default_rng(4)
    n, cells = 3000, 7
    cell = rng.integers(0, cells, n)
    key = rng.permutation(n).astype(float)
    v = rng.standard_t(4, size=n) + cell
    f = stats.group_features(v, cell, cells + 1, key, min_count=5)
    assert np.all(np.isnan(f[cells]))  # an empty cell
    for c in range(cells):
        x = v[cell == c][np.argsort(key[cell == c])]
        xs = np.sort(x)
        loc, mad = stats.robust_loc_scale(xs)
        d = x - x.mean()
        lag1 = np.sum(d[1:] * d[:-1]) / np.sum(d * d)
        tail = np.log(x.std(ddof=1) / mad)
        np.testing.assert_allclose(f[c], [x.mean(), loc, np.log(mad), lag1, tail], rtol=1e-10, atol=1e-12)
    lo, hi = int(np.floor(0.25 * 4)), int(np.ceil(0.75 * 4))
    assert stats.robust_loc_scale(np.array([0.0, 1.0, 2.0, 100.0]))[0] == pytest.approx(
        np.mean([0, 1, 2, 100][lo:hi])
    )


def test_lasso_soft_thresholds_orthonormal_design() -> None:
    rng = np.random.default_rng(5)
    q, _ = np.linalg.qr(rng.normal(size=(50, 6)))
    y = q @ np.array([3.0, -0.5, 0.0, 2.0, 0.2, -4.0]) + 0.01 * rng.normal(size=50)
    lam = 1.0
    xty = q.T @ y
    expect = np.sign(xty) * np.maximum(np.abs(xty) - lam, 0.0)
    np.testing.assert_allclose(stats.lasso_cd(q, y, lam), expect, atol=1e-9)


def test_bootstrap_and_shrink_intervals() -> None:
    rng = np.random.default_rng(6)
    v = rng.normal(1.0, 1.0, size=40)
    m, lo, hi = stats.bootstrap_mean_ci(v, np.random.default_rng(7))
    assert lo < m < hi and lo > 0.4 and hi < 1.6
    before = np.full(10, 100.0) + rng.normal(size=10)
    after = np.full(10, 5.0) + rng.normal(size=10)
    s, lo, hi = stats.shrink_ci(before, after, np.random.default_rng(8))
    assert 0.93 < lo <= s <= hi < 0.97
    s_over, _, _ = stats.shrink_ci(before, -after, np.random.default_rng(8))  # over-predicted scatter
    assert s_over == pytest.approx(s)
