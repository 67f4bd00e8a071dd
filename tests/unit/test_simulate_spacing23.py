"""TripletSchedule with a separate P2 -> P3 spacing (spacing23_s), and its recovery from records."""

from __future__ import annotations

import numpy as np
import pytest
from uwbcal import dw1000
from uwbcal import vectorsim as S
from uwbcal.errors import ScenarioError
from uwbcal.physics import World, load_scenario

TU = dw1000.TIME_UNIT_S


def _d(rec: dict[str, np.ndarray], a: str, b: str) -> np.ndarray:
    return dw1000.wrap_diff(rec[a], rec[b]).astype(np.float64)


def test_default_spacing23_is_spacing_and_length_is_checked() -> None:
    sc = load_scenario("two_stations")
    s = S.drift_schedule(sc, 20, spacing_s=2e-3)
    assert np.array_equal(s.spacing23_s, s.spacing_s)
    with pytest.raises(ScenarioError, match="spacing23_s"):
        S.TripletSchedule(**{**s.as_dict(), "spacing23_s": np.full(3, 1e-3)})


def test_unequal_spacings_are_played_and_recovered_from_the_tx_stamps() -> None:
    sc = load_scenario("two_stations")
    s = S.drift_schedule(sc, 400, spacing_s=23e-3, period_s=0.1)
    sp23 = np.where(np.arange(400) % 2 == 0, 23e-3, 33.4e-3)
    s = S.TripletSchedule(**{**s.as_dict(), "spacing23_s": sp23})
    rec, _ = S.run_triplets(World(sc, seed=2), s)
    # TX stamps sit on the 512-unit grid: each interval is within 512 units of the programmed one
    assert np.all(np.abs(_d(rec, "tx3", "tx2") * TU - sp23) < 512 * TU)
    assert np.all(np.abs(_d(rec, "tx2", "tx1") * TU - 23e-3) < 512 * TU)
    back = S.schedule_from_records(rec)
    assert isinstance(back, S.TripletSchedule)
    even = np.arange(400) % 2 == 0
    assert np.array_equal(back.spacing23_s[even], back.spacing_s[even])  # equal: exactly spacing_s
    assert np.all(np.abs(back.spacing23_s[~even] - 33.4e-3) < 512 * TU)
    # re-simulating the recovered schedule gives the same P3 intervals (to the grid)
    again, _ = S.run_triplets(World(sc, seed=2), back)
    assert np.all(np.abs(_d(again, "tx3", "tx2") - _d(rec, "tx3", "tx2")) <= 512)


def test_eq1_residual_vanishes_with_unequal_spacings_when_ideal() -> None:
    sc = load_scenario("two_stations").with_all_effects(False).with_effects(enabled={"clock_offset": True})
    sc = sc.with_station(1, ppm=20.0)
    s = S.drift_schedule(sc, 200, spacing_s=23e-3, period_s=0.1)
    s = S.TripletSchedule(**{**s.as_dict(), "spacing23_s": np.full(200, 33.4e-3)})
    rec, _ = S.run_triplets(World(sc, seed=1), s)
    res = _d(rec, "rx2", "rx1") - _d(rec, "tx2", "tx1") * _d(rec, "rx3", "rx1") / _d(rec, "tx3", "tx1")
    assert np.max(np.abs(res)) <= 1.0  # units: only the rounding of the three RX stamps
