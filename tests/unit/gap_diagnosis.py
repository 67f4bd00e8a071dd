"""A bare engine.Diagnosis for report tests: only the verdict, the named effects and the selection
steps are set; every figure is empty or NaN."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from uwbcal.gap import engine


def bare(
    verdict: str, named: Sequence[dict[str, Any]], steps: Sequence[dict[str, Any]], group_regime: str
) -> engine.Diagnosis:
    """A Diagnosis with ``verdict``, ``named``, ``steps`` and ``group_regime``; shrinks NaN, nothing else."""
    nan3 = {"estimate": float("nan"), "ci_low": float("nan"), "ci_high": float("nan")}
    return engine.Diagnosis(
        verdict=verdict,
        summary="s",
        cells=[],
        significant=[],
        named=list(named),
        selection_steps=list(steps),
        lasso=[],
        lasso_agrees=None,
        shrink=dict(nan3),
        shrink_signature=dict(nan3),
        blackbox_shrink=dict(nan3),
        fraction_of_removable=float("nan"),
        excess={},
        n_features=0,
        n_groups=0,
        group_regime=group_regime,
        settings={},
    )
