"""The RX jitter's tail (TimestampNoise.tail_weight): default, validation, the drawn shape.

The shape is checked against scipy's Student-t, not against the simulator's own formula: the
jitter a receiver adds (RxBatch.error_s with every other effect off) must be t of 1/w dof scaled
to the effect's sigma, and at w = 0 a Gaussian of that sigma.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats
from test_physics_noise_scale import BASE  # the same two stations
from uwbcal import vectorsim as S
from uwbcal.errors import ScenarioError
from uwbcal.physics import World, parse_scenario
from uwbcal.physics.effects import TAIL_WEIGHT_MAX
from uwbcal.physics.scenario import Scenario

FLOOR_PS = 100.0


def _jitter_only(tail_weight: float) -> Scenario:
    return (
        parse_scenario(BASE)
        .with_all_effects(False)
        .with_effects(
            enabled={"timestamp_noise": True},
            params={
                "timestamp_noise": {
                    "floor_ps": FLOOR_PS,
                    "snr_ps": 0.0,
                    "tx_jitter_ps": 0.0,
                    "tail_weight": tail_weight,
                }
            },
        )
    )


def _errors_in_sigmas(tail_weight: float, n: int, seed: int) -> np.ndarray:
    """The RX timestamp errors of ``n`` receptions, in units of the effect's sigma."""
    w = World(_jitter_only(tail_weight), seed=seed)
    t = 0.001 * np.arange(n, dtype=np.float64) + 0.5
    rx = w.receive(1, 2, t, 0x0E)
    return np.asarray(rx.error_s) / (FLOOR_PS * 1e-12)


def test_default_is_gaussian_and_changes_nothing() -> None:
    sc = parse_scenario(BASE)
    assert sc.effects["timestamp_noise"].tail_weight == 0.0  # type: ignore[attr-defined]
    explicit = sc.with_effects(params={"timestamp_noise": {"tail_weight": 0.0}})
    sched = S.drift_schedule(sc, 50, tx=1, rx=2, period_s=0.02)
    a, _ = S.run_triplets(World(sc, seed=5), sched)
    b, _ = S.run_triplets(World(explicit, seed=5), sched)
    assert all(np.array_equal(a[k], b[k]) for k in a)


@pytest.mark.parametrize("bad", ["-0.1", "0.5", "nan"])
def test_tail_weight_outside_its_range_is_rejected(bad: str) -> None:
    with pytest.raises(ScenarioError, match="tail_weight"):
        parse_scenario(BASE + f"[effects.timestamp_noise]\ntail_weight = {bad}\n")


def test_the_value_round_trips_through_toml() -> None:
    sc = parse_scenario(BASE).with_effects(params={"timestamp_noise": {"tail_weight": 0.2}})
    back = parse_scenario(sc.to_toml())
    assert back.effects["timestamp_noise"].tail_weight == 0.2  # type: ignore[attr-defined]


@pytest.mark.parametrize("w", [0.2, TAIL_WEIGHT_MAX])
def test_the_jitter_is_student_t_of_one_over_w_dof_with_the_same_sd(w: float) -> None:
    n = 20_000
    e = _errors_in_sigmas(w, n, seed=21)
    dof = 1.0 / w
    t_ref = stats.t(dof, scale=math.sqrt((dof - 2.0) / dof))  # SD 1
    assert stats.kstest(e, t_ref.cdf).pvalue > 1e-3
    assert stats.kstest(e, stats.norm.cdf).pvalue < 1e-6  # a Gaussian of the same SD is not it
    # the median absolute deviation is the tail-free check of the scale: t's, not the Gaussian's
    mad = float(np.median(np.abs(e)))
    se = 1.0 / (2.0 * math.sqrt(n) * t_ref.pdf(t_ref.ppf(0.75)))  # sample median of |e|
    assert abs(mad - t_ref.ppf(0.75)) < 4.0 * se


def test_at_zero_the_jitter_is_gaussian() -> None:
    e = _errors_in_sigmas(0.0, 20_000, seed=22)
    assert stats.kstest(e, stats.norm.cdf).pvalue > 1e-3
