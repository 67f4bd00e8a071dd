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
BURST_ALPHA = engine.Config().burst_alpha


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


def _two_way(rng: np.random.Generator, scale: float, windows: dict[int, tuple[float, float, float]]) -> Any:
    """An asil-like two-direction session's eq. 1 residual (m): 84 s, alternating directions,
    Student-t (6 dof) jitter of ``scale``; ``windows[d] = (from_s, to_s, factor)`` multiplies
    direction d's jitter in that window (a floor that changes in time; written here, apart from
    the catalogue's and the blind generator's noise)."""
    t = np.arange(3500) * 0.024
    direction = np.where(np.arange(t.size) % 2 == 0, 1, 1000)
    sc = np.full(t.size, scale)
    for d, (a, b, f) in windows.items():
        sc[(direction == d) & (t >= a) & (t < b)] *= f
    return t, direction, 0.03 * sc * rng.standard_t(6, t.size)


def _jitter_failing(real: Any, sims: list[Any], t: Any, direction: Any, step: Any = None) -> list[str]:
    checks = criticism.criticise(
        {"drift_residual_m": real}, [{"drift_residual_m": s} for s in sims], t, direction, step=step
    )
    assert checks, "no check computed"
    return [f"{c.direction} {name}" for c, name, _ in criticism.failed(checks, ALPHA, BURST_ALPHA)]


def test_a_burst_of_extra_jitter_fails_the_jitter_check_in_its_direction() -> None:
    """A 10 s burst of twice the jitter in one direction (the issue's missed burst) against a
    scenario with a constant floor of another size: the jitter and burst checks fail there and
    only there; the same session without the burst passes (both are scale free)."""
    rng = np.random.default_rng(3)
    t, direction, real = _two_way(rng, 1.0, {1000: (30.0, 40.0, 2.0)})
    sims = [_two_way(rng, 1.2, {})[2] for _ in range(64)]
    assert _jitter_failing(real, sims, t, direction) == ["1->0 jitter", "1->0 burst"]
    assert _jitter_failing(_two_way(rng, 1.0, {})[2], sims, t, direction) == []


def test_the_jitter_check_is_left_out_of_a_power_sweep() -> None:
    """In a sweep the jitter follows the power steps by design: no jitter statistic there."""
    rng = np.random.default_rng(4)
    t, direction, real = _two_way(rng, 1.0, {1: (0.0, 42.0, 2.0), 1000: (0.0, 42.0, 2.0)})
    sims = [_two_way(rng, 1.0, {})[2] for _ in range(32)]
    step = (t >= 42.0).astype(np.int64)
    checks = criticism.criticise(
        {"drift_residual_m": real}, [{"drift_residual_m": s} for s in sims], t, direction, step=step
    )
    assert checks and all(c.p[criticism.CHECKS.index("jitter")] == 1.0 for c in checks)
    assert "jitter" in " ".join(_jitter_failing(real, sims, t, direction))  # without the steps it fails


def test_a_statistic_not_computed_is_not_counted_in_holm() -> None:
    """A clock-rate check has no jitter statistic (real NaN, p 1): Holm counts three tests, so
    a trend at p 3e-4 fails at 0.001 (adjusted 9e-4), as it did before the jitter statistic."""
    nan = float("nan")
    rate = criticism.Check(
        "clock_rate_ppm", "0->1", (1.0, 1.0, 0.0, nan, nan), (0.0,) * 5, (3.6, 0, 0, 0, 0), (3e-4, 1, 1, 1, 1)
    )
    assert [name for _, name, _ in criticism.failed([rate], 1e-3)] == ["trend"]
    resid = criticism.Check(
        "drift_residual_m", "0->1", (1.0, 1.0, 0.0, 0.1, 0.2), (0.0,) * 5, (3.6, 0, 0, 0, 0),
        (3e-4, 1, 1, 1, 1),
    )
    assert criticism.failed([resid], 1e-3) == []  # four tests: 1.2e-3 (burst is judged apart)


def _burst_check(direction: str, p_burst: float) -> criticism.Check:
    return criticism.Check(
        "drift_residual_m", direction, (0.0, 1.0, 0.0, 0.1, -0.4), (0.0,) * 5, (0, 0, 0, 0, -4.0),
        (1, 1, 1, 1, p_burst), window=(3.0, 13.0),
    )


def test_burst_is_judged_apart_at_its_own_level() -> None:
    """``burst`` is outside the Holm family: its p times the number of checks that computed it,
    against ``burst_alpha``: 0.004 x 2 directions fails at 0.01 and passes at 0.001."""
    checks = [_burst_check("0->1", 0.004), _burst_check("1->0", 0.5)]
    assert [(c.direction, name) for c, name, _ in criticism.failed(checks, 1e-3, 0.01)] == [("0->1", "burst")]
    assert criticism.failed(checks, 1e-3, 0.001) == []
    assert criticism.failed(checks, 1e-3) == []  # default: the Holm level
    (c, name, p_adj), = criticism.failed(checks, 1e-3, 0.01)
    said = criticism.describe(c, name, p_adj)
    assert "burst 3..13 s" in said and "0.008" in said


def test_a_window_of_less_jitter_fails_burst_whatever_the_floor() -> None:
    """A 10 s window at 0.6 x the jitter in one direction (the second real asil run's 1 -> 0 window,
    written here with a t(6) jitter) against scenarios whose floor is 0.85, 1 and 1.2 x the
    real one: burst fails in that direction at every floor (a ratio within the direction), and
    nothing fails in the other."""
    rng = np.random.default_rng(11)
    t, direction, real = _two_way(rng, 1.0, {1000: (20.0, 30.0, 0.6)})
    for floor in (0.85, 1.0, 1.2):
        sims = [_two_way(rng, floor, {})[2] for _ in range(64)]
        failing = _jitter_failing(real, sims, t, direction)
        assert "1->0 burst" in failing and not any(f.startswith("0->1") for f in failing), (floor, failing)


def test_every_departing_window_is_listed_not_only_the_worst() -> None:
    """Two calm windows (0.6 x the jitter) in one direction, at 20..30 s and 60..70 s (the second
    real asil run's try 02 departs in two places, and which is the worst changed with the seed):
    ``burst_windows`` lists windows at both, the worst first and equal to ``window``, each
    overlapping a calm stretch; the verdict's reason names the second after the worst. With one
    calm window, every listed window overlaps it."""
    rng = np.random.default_rng(12)
    t, direction, real = _two_way(rng, 1.0, {1000: (20.0, 30.0, 0.6)})
    calm = [(20.0, 30.0), (60.0, 70.0)]
    real = np.where((direction == 1000) & (t >= 60.0) & (t < 70.0), 0.6 * real, real)
    sims = [_two_way(rng, 1.0, {})[2] for _ in range(64)]

    def listed(values: Any) -> tuple[criticism.Check, list[tuple[float, float]]]:
        checks = criticism.criticise(
            {"drift_residual_m": values}, [{"drift_residual_m": x} for x in sims], t, direction
        )
        (c,) = [c for c in checks if c.direction == "1->0"]
        return c, [(w[0], w[1]) for w in c.burst_windows]

    def overlaps(w: tuple[float, float], spans: list[tuple[float, float]]) -> bool:
        return any(w[0] < b and a < w[1] for a, b in spans)

    c, wins = listed(real)
    assert wins and wins[0] == c.window, (wins, c.window)
    assert all(overlaps(w, calm) for w in wins), wins
    assert all(any(overlaps(w, [span]) for w in wins) for span in calm), wins
    assert [w[4] for w in c.burst_windows] == sorted(w[4] for w in c.burst_windows)
    (fail,) = [x for x in criticism.failed([c], ALPHA, BURST_ALPHA) if x[1] == "burst"]
    said = criticism.describe(*fail, BURST_ALPHA)
    assert "; also " in said, said
    assert "; also " not in criticism.describe(*fail)  # no level: the worst alone, as before
    # overlapping windows are one span: the reason names the other calm stretch once
    assert said.split("; also ")[1].count(" s (x") == 1, said
    one = np.where((direction == 1000) & (t >= 60.0) & (t < 70.0), real / 0.6, real)
    c, wins = listed(one)
    assert wins and all(overlaps(w, calm[:1]) for w in wins), wins


def test_burst_windows_merge_into_spans_only_when_they_overlap_and_depart_the_same_way() -> None:
    """Calm windows at 20..30 and 25..35 s are one span; a noisy one overlapping a calm one is not."""
    at = [(60, 70, -0.5), (20, 30, -0.5), (25, 35, -0.4), (65, 75, 0.3)]
    wins = [(float(a), float(b), lr, 0.0, 0.0) for a, b, lr in at]
    spans = [(20.0, 35.0, -0.5, -0.4), (60.0, 70.0, -0.5, -0.5), (65.0, 75.0, 0.3, 0.3)]
    assert criticism._spans(wins) == spans


def _late_paths(rng: np.random.Generator, t: Any, share: float) -> Any:
    """Late first paths written apart from the catalogue: log-normal excess (median 0.2 m, log SD
    1.0) on ``share`` of the records, m."""
    late = rng.random(t.size) < share
    return np.where(late, rng.lognormal(np.log(0.2), 1.0, t.size), 0.0)


def test_burst_holds_its_level_with_late_paths_the_scenario_holds() -> None:
    """Sessions with a constant t(6) jitter plus 30 % log-normal late paths, against re-simulations
    of the same form (the named effects reproduce them): burst fails in at most 4 of 100 sessions
    (level 1 %; 2 of 300 with other seeds, and 2 of 300 without late paths). Against
    re-simulations without the late paths it fails more often (5 of 60): the check is about the
    jitter the scenario predicts, not about a normal sample."""
    rng = np.random.default_rng(12)

    def session() -> Any:
        t, direction, r = _two_way(rng, 0.3, {})
        return r + _late_paths(rng, t, 0.3)

    t, direction, _ = _two_way(rng, 0.3, {})
    sims = [session() for _ in range(64)]
    fails = sum("burst" in " ".join(_jitter_failing(session(), sims, t, direction)) for _ in range(100))
    assert fails <= 4, fails


def _plain_mean_increment_stats(
    values: np.ndarray, block: np.ndarray, n_blocks: int, min_count: int = 5
) -> Any:
    """criticism.increment_stats as it was before issue 13's fifteenth session (block means)."""
    ok = np.isfinite(values) & (block >= 0)
    cnt = np.bincount(block[ok], minlength=n_blocks)
    m = (np.bincount(block[ok], weights=values[ok], minlength=n_blocks) / np.maximum(cnt, 1))[
        cnt >= min_count
    ]
    d = np.diff(m)
    sd = float(np.std(d, ddof=1))
    dm = np.abs(d - np.median(d))
    dc = d - d.mean()
    return np.array(
        [
            float(np.mean(d) / (sd / np.sqrt(d.size))),
            float(np.max(dm) / (1.4826 * float(np.median(dm)))),
            float(np.sum(dc[1:] * dc[:-1]) / float(np.sum(dc * dc))),
        ]
    )


def test_rare_gross_outliers_are_no_time_shape(monkeypatch: pytest.MonkeyPatch) -> None:
    """Blind seed 24, trial 10: two-way late paths (log-normal, 31 %, median 0.23 m) named right,
    then refused by the step check of the eq. 1 residual (z +4.3, Holm p 0.00099): the real tail
    was longer than the catalogue's, and a block mean moves with a few of its records. Here a
    rate-like observable with unit noise and, on 0.2 % of records, +20..60 (one every few blocks),
    against 40 re-simulations whose excess is frequent and small (30 %, exponential of mean 1): the
    same at every time, so no check may fail. With the blocks' interquartile means none does in
    30 sessions; with plain means (as before) the step or trend check fails in several of them."""
    t = np.linspace(0.0, 40.0, 1100)

    def rate(rng: np.random.Generator, rare: bool) -> np.ndarray:
        v = rng.normal(0.0, 1.0, t.size)
        if rare:
            return v + (rng.random(t.size) < 0.002) * rng.uniform(20.0, 60.0, t.size)
        return v + (rng.random(t.size) < 0.3) * rng.exponential(1.0, t.size)

    def failures() -> int:
        n = 0
        for seed in range(30):
            rng = np.random.default_rng([4, seed])
            real = rate(rng, True)
            n += bool(_failed_statistics(real, [rate(rng, False) for _ in range(40)], t))
        return n

    assert failures() == 0
    monkeypatch.setattr(criticism, "increment_stats", _plain_mean_increment_stats)
    assert failures() >= 3  # the case exists: block means took the outliers for a shape
