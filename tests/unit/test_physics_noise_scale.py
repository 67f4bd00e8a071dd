"""Per-station timestamp-noise scale (Station.noise_scale): default, validation, per-receiver spread."""

from __future__ import annotations

import math

import numpy as np
import pytest
from uwbcal import dw1000
from uwbcal import vectorsim as S
from uwbcal.errors import ScenarioError
from uwbcal.physics import World, parse_scenario

TU = dw1000.TIME_UNIT_S

BASE = """
name = "t"
seed = 3
[[stations]]
id = 1
position_m = [0.0, 0.0, 0.0]
[[stations]]
id = 2
position_m = [1.5, 0.0, 0.0]
"""


def _both_directions(sc: object, count: int) -> S.TripletSchedule:
    s12 = S.drift_schedule(sc, count, tx=1, rx=2, period_s=0.02)  # type: ignore[arg-type]
    s21 = S.drift_schedule(sc, count, tx=2, rx=1, period_s=0.02, start_s=1.01)  # type: ignore[arg-type]
    return S.TripletSchedule(**{k: np.concatenate([v, getattr(s21, k)]) for k, v in s12.as_dict().items()})


def _eq1_residual_units(rec: dict[str, np.ndarray]) -> np.ndarray:
    """Eq. 1 residual in device units: (rx2 - rx1) - (tx2 - tx1) (rx3 - rx1) / (tx3 - tx1)."""

    def d(a: str, b: str) -> np.ndarray:
        return dw1000.wrap_diff(rec[a], rec[b]).astype(np.float64)

    return d("rx2", "rx1") - d("tx2", "tx1") * d("rx3", "rx1") / d("tx3", "tx1")


def test_default_scale_is_one_and_changes_nothing() -> None:
    sc = parse_scenario(BASE)
    assert all(s.noise_scale == 1.0 for s in sc.stations)
    explicit = sc.with_station(1, noise_scale=1.0).with_station(2, noise_scale=1.0)
    sched = _both_directions(sc, 50)
    a, _ = S.run_triplets(World(sc, seed=5), sched)
    b, _ = S.run_triplets(World(explicit, seed=5), sched)
    assert all(np.array_equal(a[k], b[k]) for k in a)
    back = parse_scenario(sc.with_station(2, noise_scale=2.5).to_toml())
    assert back.station(2).noise_scale == 2.5 and back.station(1).noise_scale == 1.0


@pytest.mark.parametrize("bad", ["-1.0", "nan"])
def test_negative_or_nan_scale_is_rejected(bad: str) -> None:
    with pytest.raises(ScenarioError, match="noise_scale"):
        parse_scenario(BASE + f"noise_scale = {bad}\n")


def test_per_receiver_residual_spread_follows_the_scale() -> None:
    """Only RX jitter and quantisation: the eq. 1 residual's variance per receiver is
    1.5 sigma_rx**2 (equal spacings) plus the quantisation's, so the spreads' ratio is known."""
    floor_ps, scale = 100.0, 3.0
    sc = (
        parse_scenario(BASE)
        .with_all_effects(False)
        .with_effects(
            enabled={"timestamp_noise": True},
            params={"timestamp_noise": {"floor_ps": floor_ps, "snr_ps": 0.0, "tx_jitter_ps": 0.0}},
        )
        .with_station(1, noise_scale=scale)
    )
    n = 4000
    rec, _ = S.run_triplets(World(sc, seed=11), _both_directions(sc, n))
    res = _eq1_residual_units(rec)
    rx = np.asarray(rec["rx_station"])
    sd1, sd2 = float(np.std(res[rx == 1], ddof=1)), float(np.std(res[rx == 2], ddof=1))
    # rounding to the unit (quantisation off) adds TU**2 / 12 per stamp; the eq. 1 weights are
    # 1, 1/2, 1/2 (equal spacings up to the 512-unit grid), so each variance is 1.5 x per stamp
    q2 = 1.0 / 12.0
    s2 = (floor_ps * 1e-12 / TU) ** 2
    expected = math.sqrt((scale**2 * s2 + q2) / (s2 + q2))
    assert sd2 == pytest.approx(math.sqrt(1.5 * (s2 + q2)), rel=4 / math.sqrt(2 * (n - 1)))
    # log of a ratio of two independent SDs of n Gaussian values: standard error 1 / sqrt(n - 1)
    assert abs(math.log(sd1 / sd2) - math.log(expected)) < 4.0 / math.sqrt(n - 1)


# --- the transmitter's factor (Station.tx_noise_scale) ------------------------------------------


def test_default_tx_scale_is_one_and_changes_nothing() -> None:
    sc = parse_scenario(BASE)
    assert all(s.tx_noise_scale == 1.0 for s in sc.stations)
    explicit = sc.with_station(1, tx_noise_scale=1.0).with_station(2, tx_noise_scale=1.0)
    sched = _both_directions(sc, 50)
    a, _ = S.run_triplets(World(sc, seed=5), sched)
    b, _ = S.run_triplets(World(explicit, seed=5), sched)
    assert all(np.array_equal(a[k], b[k]) for k in a)
    back = parse_scenario(sc.with_station(1, tx_noise_scale=4.0).to_toml())
    assert back.station(1).tx_noise_scale == 4.0 and back.station(2).tx_noise_scale == 1.0


def test_tx_scale_changes_no_other_random_number() -> None:
    """A scale changes the jitter's size, not the draws: station 2's emissions, which keep their
    factor, come out the same to the unit when station 1's factor changes."""
    sc = parse_scenario(BASE).with_effects(params={"timestamp_noise": {"tx_jitter_ps": 40.0}})
    sched = _both_directions(sc, 200)
    a, _ = S.run_triplets(World(sc, seed=9), sched)
    b, _ = S.run_triplets(World(sc.with_station(1, tx_noise_scale=5.0), seed=9), sched)
    tx2 = np.asarray(a["tx_station"]) == 2
    assert all(np.array_equal(a[k][tx2], b[k][tx2]) for k in ("rx1", "rx2", "rx3"))
    assert not np.array_equal(a["rx2"][~tx2], b["rx2"][~tx2])


@pytest.mark.parametrize("bad", ["-0.5", "inf"])
def test_negative_or_infinite_tx_scale_is_rejected(bad: str) -> None:
    with pytest.raises(ScenarioError, match="tx_noise_scale"):
        parse_scenario(BASE + f"tx_noise_scale = {bad}\n")


def test_per_transmitter_residual_spread_follows_the_tx_scale() -> None:
    """Only TX jitter and rounding: a jittered emission moves the true departure, so the receiver's
    stamp of that message moves with it, and the eq. 1 residual's variance per transmitter is
    1.5 (k_tx sigma_tx)**2 plus the rounding's, as for RX jitter."""
    tx_ps, scale = 100.0, 3.0
    sc = (
        parse_scenario(BASE)
        .with_all_effects(False)
        .with_effects(
            enabled={"timestamp_noise": True},
            params={"timestamp_noise": {"floor_ps": 0.0, "snr_ps": 0.0, "tx_jitter_ps": tx_ps}},
        )
        .with_station(1, tx_noise_scale=scale)
    )
    n = 4000
    rec, _ = S.run_triplets(World(sc, seed=12), _both_directions(sc, n))
    res = _eq1_residual_units(rec)
    tx = np.asarray(rec["tx_station"])
    sd1, sd2 = float(np.std(res[tx == 1], ddof=1)), float(np.std(res[tx == 2], ddof=1))
    q2 = 1.0 / 12.0
    s2 = (tx_ps * 1e-12 / TU) ** 2
    expected = math.sqrt((scale**2 * s2 + q2) / (s2 + q2))
    assert sd2 == pytest.approx(math.sqrt(1.5 * (s2 + q2)), rel=4 / math.sqrt(2 * (n - 1)))
    assert abs(math.log(sd1 / sd2) - math.log(expected)) < 4.0 / math.sqrt(n - 1)
