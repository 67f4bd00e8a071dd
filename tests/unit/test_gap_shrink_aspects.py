"""The gap's shrink by aspect: cells closed and time-shape checks passed, each place counted once.

Issue 13, cause 4: a shrink summed over features (z^2) is decided by the most precisely measured
observable, so a flexible wrong effect that puts the clock rate's means right showed 99 % while
the time shape it missed stayed as far off as before. These tests pin the counting rules on
hand-made cells and checks (no physics), and that the reported shrink is the least aspect.
"""

from __future__ import annotations

import math

from uwbcal.gap import engine
from uwbcal.gap.criticism import CHECKS, Check
from uwbcal.gap.localise import Cell, still_open
from uwbcal.gap.quantify import cells_closed, checks_passed

ALPHA = 0.01
CLOSED = 0.2  # Config.cell_closed


def _cell(obs: str, key: int, z: float, q: float) -> Cell:
    return Cell(
        observable=obs,
        regime="time",
        key=key,
        label=f"t{key}",
        n_real=100,
        real_mean=0.0,
        sim_mean=0.0,
        real_sd=1.0,
        sim_sd=1.0,
        z=(z, 0.0, 0.0, 0.0),
        p=(q, 1.0, 1.0, 1.0),
        q=(q, 1.0, 1.0, 1.0),
    )


def test_each_differing_cell_is_one_place_whatever_its_z() -> None:
    before = [_cell("clock_rate_ppm", 0, 5000.0, 1e-30), _cell("drift_residual_m", 0, 6.0, 1e-5)]
    # the huge clock-rate cell closes, the small residual cell keeps all of its |z|: half the places
    after = [_cell("clock_rate_ppm", 0, 0.5, 0.9), _cell("drift_residual_m", 0, 6.0, 1e-5)]
    assert cells_closed(before, after, ALPHA, CLOSED) == 0.5
    # the other way round: the residual closes, the rate keeps a tenth of its |z| (still significant)
    after2 = [_cell("clock_rate_ppm", 0, 500.0, 1e-20), _cell("drift_residual_m", 0, 1.0, 0.5)]
    assert math.isclose(cells_closed(before, after2, ALPHA, CLOSED) or 0.0, 1.0 - 0.1 / 2.0)


def test_a_place_the_verdict_calls_open_counts_whole_however_far_its_z_fell() -> None:
    """A wrong flexible effect that brings the rate's cell from z 5000 to 1500 has not closed a
    third of it: the cell is still open (|z| above 0.2 of before) and counts as one place left,
    the same test the verdict applies (localise.still_open)."""
    before = [_cell("clock_rate_ppm", 0, 5000.0, 1e-30), _cell("drift_residual_m", 0, 6.0, 1e-5)]
    after = [_cell("clock_rate_ppm", 0, 1500.0, 1e-25), _cell("drift_residual_m", 0, 1.0, 0.5)]
    assert cells_closed(before, after, ALPHA, CLOSED) == 0.5
    cfg = engine.Config(alpha=ALPHA, cell_closed=CLOSED)
    assert [c.observable for c in still_open(before, after, cfg)] == ["clock_rate_ppm"]
    # at 0.2 of its |z| the verdict calls it closed, and it counts that fraction
    at = [_cell("clock_rate_ppm", 0, 1000.0, 1e-25), after[1]]
    assert still_open(before, at, cfg) == []
    assert math.isclose(cells_closed(before, at, ALPHA, CLOSED) or 0.0, 1.0 - 0.2 / 2.0)


def test_new_discrepancies_count_and_the_result_stays_in_0_1() -> None:
    before = [_cell("clock_rate_ppm", 0, 50.0, 1e-10)]
    after = [_cell("clock_rate_ppm", 0, 1.0, 0.5), _cell("drift_residual_m", 3, 5.0, 1e-4)]
    assert cells_closed(before, after, ALPHA, CLOSED) == 0.0  # one closed, one new: nothing gained
    after3 = [*after, _cell("drift_residual_m", 4, 5.0, 1e-4)]
    assert cells_closed(before, after3, ALPHA, CLOSED) == 0.0  # more new than before: still 0, not negative
    # no gap either way
    assert cells_closed([], [_cell("clock_rate_ppm", 0, 1.0, 0.5)], ALPHA, CLOSED) is None


def test_checks_passed_counts_failing_checks() -> None:
    a, b, c = ("clock_rate_ppm", "0->1", "trend"), ("clock_rate_ppm", "0->1", "step"), ("x", "1->0", "lag1")
    assert checks_passed([a, b], []) == 1.0
    assert checks_passed([a, b], [b]) == 0.5
    assert checks_passed([a], [a, c]) == 0.0  # one kept, one new
    assert checks_passed([], [c]) == 0.0  # the named effects break a time shape the believed world had
    assert checks_passed([], []) is None


def _check(z_trend: float, p_trend: float) -> Check:
    zero = (0.0,) * len(CHECKS)
    return Check(
        "clock_rate_ppm", "0->1", zero, zero, (z_trend, *zero[1:]), (p_trend, *(1.0,) * (len(CHECKS) - 1))
    )


def test_reported_shrink_is_the_least_aspect() -> None:
    cfg = engine.Config()
    before = [_cell("clock_rate_ppm", 0, 5000.0, 1e-30)]
    after = [_cell("clock_rate_ppm", 0, 0.5, 0.9)]
    features = {"estimate": 0.999, "ci_low": 0.99, "ci_high": 1.0}
    # a wrong flexible effect: the features and the cells close, the rate's trend fails as before
    asp = engine._aspects(features, before, after, [_check(40.0, 1e-12)], [_check(12.0, 1e-8)], cfg)
    assert asp["features"] == 0.999 and asp["cells"] == 1.0 and asp["time_shape"] == 0.0
    s = engine._least(features, asp)
    assert s["estimate"] == 0.0 and s["ci_high"] == 0.0 and s["least"] == "time_shape"
    # the right effect: every aspect closes, the shrink is the features' own
    asp2 = engine._aspects(features, before, after, [_check(40.0, 1e-12)], [_check(0.3, 0.7)], cfg)
    s2 = engine._least(features, asp2)
    assert s2["estimate"] == 0.999 and s2["ci_low"] == 0.99 and s2["least"] == "features"
