"""Seed-ensemble aggregation (gap/stability.py): a verdict is called only when the ensembles agree."""

from __future__ import annotations

from typing import Any

from uwbcal.gap.engine import Diagnosis
from uwbcal.gap.stability import aggregate


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
