"""Session plans (sessions/plan.py): the one gain ladder stations and the simulator share,
sweep plans, resume splits, durations."""

from __future__ import annotations

import numpy as np
import pytest
from uwbcal import dw1000, vectorsim
from uwbcal.physics.scenario import load_scenario
from uwbcal.sessions import plan as pl


def test_gain_ladder_nominal_steps() -> None:
    g = pl.gain_ladder(pl.TOP_GAIN, 0.5, 41)
    nominal = dw1000.gain_nominal_db(g)
    assert len(set(g)) == 41
    np.testing.assert_allclose(np.diff(nominal), -0.5)
    assert nominal[0] - nominal[-1] == pytest.approx(20.0)
    with pytest.raises(pl.PlanError):
        pl.gain_ladder(pl.TOP_GAIN, 0.3, 3)            # not a 0.5 dB multiple
    with pytest.raises(pl.PlanError):
        pl.gain_ladder(pl.TOP_GAIN, 3.0, 20)           # below coarse 6 / fine 0


def test_parse_duration() -> None:
    assert pl.parse_duration_us("2ms") == 2000
    assert pl.parse_duration_us("150us") == 150
    assert pl.parse_duration_us("0.5s") == 500_000
    assert pl.default_period_us(2000) == 6000
    with pytest.raises(pl.PlanError):
        pl.parse_duration_us("fast")


def test_three_db_steps_use_the_coarse_gain_as_on_the_paper_cable() -> None:
    g = pl.gain_ladder(pl.TOP_GAIN, 3.0, 7)
    assert [o >> 5 for o in g] == list(range(7)) and all(o & 31 == 31 for o in g)
    fine = pl.gain_ladder(pl.TOP_GAIN, 0.5, 3)
    assert [o >> 5 for o in fine] == [0, 0, 0]


def test_stations_and_simulator_play_the_same_sweep() -> None:
    """`uwbcal calibrate` (TripletPlan.sweep) and `uwbcal paper` (vectorsim.power_schedule) put
    the same P2 gains at the same steps, for fine and coarse steps alike."""
    sc = load_scenario("paper_antenna")
    coarse = float(sc.effects["tx_gain"].values()["coarse_step_db"])
    for step_db, steps in ((0.5, 61), (3.0, 7), (1.0, 31)):
        plan = pl.TripletPlan.sweep(steps=steps, per_step=4, step_db=step_db, spacing_us=2000,
                                    coarse_step_db=coarse)
        sched = vectorsim.power_schedule(sc, steps=steps, per_step=4, step_db=step_db, spacing_s=2e-3,
                                        period_s=plan.period_us * 1e-6)
        np.testing.assert_array_equal(sched.gain2, np.repeat(plan.gains2, 4))
        sched2 = vectorsim.plan_schedule(sc, plan)
        np.testing.assert_array_equal(sched2.gain2, sched.gain2)
        np.testing.assert_allclose(sched2.t_s, sched.t_s)


def test_sweep_rejects_a_period_shorter_than_two_spacings() -> None:
    with pytest.raises(pl.PlanError, match="twice the spacing"):
        pl.TripletPlan.sweep(steps=3, per_step=4, step_db=0.5, spacing_us=2000, period_us=3000)
