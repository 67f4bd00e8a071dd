"""Seed-ensemble aggregation (gap/stability.py): a verdict is called only when the ensembles agree;
ensembles that name the same effects decide together which cells still differ."""

from __future__ import annotations

import dataclasses
from collections import Counter
from typing import Any

import numpy as np
from uwbcal.gap.config import Config
from uwbcal.gap.engine import Diagnosis
from uwbcal.gap.localise import Cell, _judge, pooled, still_open
from uwbcal.gap.stability import aggregate, pool_residual_cells
from uwbcal.gap.stats import to_floor_scale


def _d(verdict: str, named: list[tuple[str, float]]) -> Diagnosis:
    nm: list[dict[str, Any]] = [
        {"effect": e, "knob": f"k:{e}", "fitted": v, "unit": "", "baseline": 0.0} for e, v in named
    ]
    return Diagnosis(
        verdict=verdict,
        summary=verdict,
        cells=[],
        significant=[],
        named=nm,
        selection_steps=[],
        lasso=[],
        lasso_agrees=None,
        shrink={},
        shrink_signature={},
        blackbox_shrink={},
        fraction_of_removable=float("nan"),
        excess={},
        n_features=0,
        n_groups=0,
        group_regime="time",
        settings={},
    )


def test_agreeing_ensembles_give_the_majority_effects_with_median_values() -> None:
    runs = [
        _d("explained", [("noise", 50.0), ("offset", -1.9)]),
        _d("explained", [("noise", 54.0), ("offset", -1.8), ("temperature", 1e-3)]),
        _d("explained", [("noise", 52.0), ("offset", -1.9)]),
        _d("explained", [("noise", 60.0)]),
    ]
    a = aggregate(runs, 0.75)
    st = a.settings["stability"]
    assert a.verdict == "explained" and st["stable"] and st["verdict_share"] == 1.0
    assert [n["effect"] for n in a.named] == ["noise", "offset"]  # temperature: 1 of 4, dropped
    assert a.named[0]["fitted"] == 53.0 and a.named[0]["fitted_per_ensemble"] == [50.0, 54.0, 52.0, 60.0]


def test_disagreeing_ensembles_are_refused() -> None:
    runs = [_d("explained", [("noise", 50.0)]), _d("unexplained", [("noise", 50.0)])] * 2
    a = aggregate(runs, 0.75)
    assert a.verdict == "unstable" and a.settings["stability"]["verdict_share"] == 0.5
    assert "no verdict is called" in a.summary


def test_explained_with_another_lead_effect_is_refused() -> None:
    runs = [_d("explained", [("wander", 1.0)])] * 2 + [_d("explained", [("warmup", 1.0)])] * 2
    assert aggregate(runs, 0.75).verdict == "unstable"
    assert aggregate(runs[:3], 0.6).verdict == "explained"


# -- the cells still differing, decided once on the pooled run seeds of ensembles that agree --


def _cells(rng: np.random.Generator, depart: dict[int, float], shift: float = 0.0, k: int = 64) -> list[Cell]:
    """40 cells whose K seeds' statistics are standard normal (the distance: log-normal) around
    ``shift``; the real statistic is one more such draw, plus ``depart[i]`` floor SDs in cell i's
    mean and robust location."""
    out = []
    for i in range(40):
        null = rng.normal(size=(k, 4)) + shift
        null[:, 3] = np.exp(0.3 * rng.normal(size=k) - 2.0)
        obs = rng.normal(size=4) + shift
        obs[3] = np.exp(0.3 * rng.normal() - 2.0)
        obs[:2] += depart.get(i, 0.0)
        out.append(
            Cell("drift_residual", "time", i, f"t{i}", 100, 0.0, 0.0, 1.0, 1.0, (), (), (), 1000, obs, null)
        )
    return out


def _own(cells: list[Cell]) -> list[Cell]:
    """The cells judged alone, as localise judges one run."""
    out = [dataclasses.replace(c) for c in cells]
    _judge(
        out,
        to_floor_scale(np.stack([c.stat_obs for c in cells])),  # type: ignore[misc]
        to_floor_scale(np.stack([c.stat_null for c in cells], axis=1)),  # type: ignore[misc]
    )
    return out


def test_one_run_pooled_is_judged_as_localise_judges_it() -> None:
    cells = _cells(np.random.default_rng(1), {3: 6.0})
    own, one = _own(cells), pooled([cells])
    assert [c.ident for c in one] == [c.ident for c in own]
    assert np.allclose([c.z for c in one], [c.z for c in own])
    assert np.allclose([c.q for c in one], [c.q for c in own])


def test_pooled_runs_are_centred_on_their_own_floors() -> None:
    """Ensembles fitted at other values shift a cell's floor as a whole; pooled, the shift
    between them must not widen the floor (uncentred, the departing cell's z shrinks ~4x)."""
    rng = np.random.default_rng(2)
    runs = [_cells(rng, {5: 7.0}, shift=4.0 * e) for e in range(4)]
    pool = pooled(runs)
    own = [_own(r)[5].z[0] for r in runs]
    assert abs(pool[5].z[0]) > 0.7 * min(abs(z) for z in own)
    assert min(pool[5].q[:2]) < 0.01
    assert sum(min(c.q) < 0.01 for c in pool) == 1


def _diagnosis(before: list[Cell], after: list[Cell], cfg: Config) -> Diagnosis:
    d = _d("explained", [("noise", 50.0)])
    remaining = still_open(before, after, cfg)
    return dataclasses.replace(
        d,
        verdict="unexplained" if remaining else "explained",
        cells=before,
        cells_after=after,
        significant=[c for c in before if min(c.q) < cfg.alpha],
        remaining=remaining,
        feature_shrink=0.99,
        shrink={"estimate": 0.99, "ci_low": 0.95, "ci_high": 1.0},
    )


def test_ensembles_split_by_a_cell_near_the_fdr_level_get_one_decision() -> None:
    """Two ensembles with the same named effects, one cell departing near the 1 % FDR level
    after them: alone they may disagree (the premise is checked over the draws); pooled, they
    always reach one verdict, and the ensembles' own verdicts are kept in the record."""
    cfg = Config()
    split = 0
    for seed in range(12):
        rng = np.random.default_rng(100 + seed)
        runs = [
            _diagnosis(_own(_cells(rng, {0: 12.0, 1: 8.0})), _own(_cells(rng, {0: 4.3})), cfg)
            for _ in range(2)
        ]
        alone = {d.verdict for d in runs}
        split += len(alone) > 1
        out = pool_residual_cells(runs, cfg)
        assert len({d.verdict for d in out}) == 1
        assert all(d.settings["residual_cells"]["ensembles"] == 2 for d in out)
        assert [d.settings["residual_cells"]["verdict_alone"] for d in out] == [d.verdict for d in runs]
        assert all(d.remaining == out[0].remaining for d in out)
        st = aggregate(out, 0.75).settings["stability"]
        assert st["residual_cells_pooled_in"] == 2
        assert st["verdicts_alone"] == dict(Counter(d.verdict for d in runs))
    assert split >= 2  # the premise: alone, the ensembles do split on this cell


def test_ensembles_with_other_named_effects_are_not_pooled() -> None:
    cfg = Config()
    rng = np.random.default_rng(7)
    a = _diagnosis(_own(_cells(rng, {0: 12.0})), _own(_cells(rng, {0: 4.3})), cfg)
    b = dataclasses.replace(
        _diagnosis(_own(_cells(rng, {0: 12.0})), _own(_cells(rng, {0: 4.3})), cfg),
        named=[{"effect": "wander", "knob": "k", "fitted": 1.0, "unit": "", "baseline": 0.0}],
    )
    out = pool_residual_cells([a, b], cfg)
    assert out == [a, b] and "residual_cells" not in out[0].settings
