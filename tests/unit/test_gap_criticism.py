"""Model criticism's time-shape checks on a simulated sweep's clock rate: a frequency step is not a
random walk, however large the walk that the sims are given; a random walk of another size or
with heavy-tailed increments is one (the step and the walks are written here, apart from the blind
generator's)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from gap_sweep import sweep
from uwbcal.gap import criticism, engine
from uwbcal.gap import observables as obs_mod

ALPHA = engine.Config().criticism_alpha


@pytest.fixture(scope="module")
def rates() -> tuple[np.ndarray, list[np.ndarray]]:
    """Record times (s) and the clock rate (ppm) of the validation sweep at 13 world seeds."""
    recs = [sweep(s, 200) for s in range(1, 14)]
    t = np.asarray(recs[0]["t_s"], np.float64)
    return t, [obs_mod.observables(r)["clock_rate_ppm"] for r in recs]


def _walk(rng: np.random.Generator, t: np.ndarray, ppm_per_sqrt_s: float, laplace: bool = False) -> Any:
    """A random walk of the frequency (ppm) sampled at ``t``, Gaussian or Laplace increments."""
    dt = np.diff(t, prepend=t[0])
    inc = rng.laplace(0.0, 1 / np.sqrt(2), t.size) if laplace else rng.normal(0.0, 1.0, t.size)
    return np.cumsum(inc * ppm_per_sqrt_s * np.sqrt(dt))


def _failed_statistics(real: np.ndarray, sims: list[np.ndarray], t: np.ndarray) -> list[str]:
    checks = criticism.criticise({"clock_rate_ppm": real}, [{"clock_rate_ppm": s} for s in sims], t, None)
    assert checks, "no check computed"
    return [name for _, name, _ in criticism.failed(checks, ALPHA)]


@pytest.mark.parametrize("at_s", [25.2, 34.8])
def test_a_frequency_step_fails_the_step_check_against_a_fitted_wander(
    rates: tuple[np.ndarray, list[np.ndarray]], at_s: float
) -> None:
    """0.55 ppm at one moment inside a time block (so two increments share it), sims with a wander
    of 0.01 ppm/sqrt(s): blind seed 15 trial 9's step and fitted wander. The old statistic,
    max |d - mean| / SD, is inflated by the step itself: it passed both (z +2.7, +3.3)."""
    t, cr = rates
    rng = np.random.default_rng(int(at_s))
    real = cr[0] + 0.55 * (t >= at_s)
    sims = [c + _walk(rng, t, 0.01) for c in cr[1:]]
    assert "step" in _failed_statistics(real, sims, t)
    # the same sims, no step: nothing fails
    assert _failed_statistics(cr[0] + _walk(rng, t, 0.01), sims, t) == []


@pytest.mark.parametrize(("scale", "laplace"), [(0.02, False), (0.005, False), (0.02, True), (0.005, True)])
def test_a_random_walk_of_another_size_or_tail_passes(
    rates: tuple[np.ndarray, list[np.ndarray]], scale: float, laplace: bool
) -> None:
    """The checks are scale free, and a heavy-tailed walk (Laplace increments, as a real crystal's
    may be) is still a walk: no check fails in any of 4 draws."""
    t, cr = rates
    for rep in range(4):
        rng = np.random.default_rng(100 * rep + int(1000 * scale) + laplace)
        real = cr[rep % 3] + _walk(rng, t, scale, laplace)
        sims = [c + _walk(rng, t, 0.01) for i, c in enumerate(cr) if i != rep % 3]
        assert _failed_statistics(real, sims, t) == [], (rep, scale, laplace)
