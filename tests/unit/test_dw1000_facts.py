"""DW1000 facts checked against the numbers Decawave states, typed here from the sources and not
taken from the project's own constants (so that the firmware, the host and the simulator, which
share uwbcal.dw1000 and the generated chip facts, cannot agree on a wrong value unnoticed).

Sources: DW1000 User Manual 2.18, section 4.7.2 (RX level: 10 log10(C 2^17 / N^2) - A, A = 121.74
at PRF 64 MHz, 115.72 at PRF 16 MHz; 113.77 in older manuals) and section 7.2.40.11 / Decawave's
public ss_twr_init example (clock offset from DRX_CAR_INT: FREQ_OFFSET_MULTIPLIER =
998.4e6 / 2.0 / 1024.0 / 131072.0 Hz per LSB, HERTZ_TO_PPM_MULTIPLIER_CHAN_2 = -1.0e6 / 3993.6e6,
and the tag's interval scaled by (1 - clockOffsetRatio) in the reference's time base).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from uwbcal import dw1000
from uwbcal import vectorsim as sim
from uwbcal.corrections import twr
from uwbcal.physics import World, load_scenario


def test_rx_level_constant_a_as_the_manual_states() -> None:
    assert dw1000.RX_LEVEL_A_DBM[64] == 121.74
    assert dw1000.RX_LEVEL_A_DBM[16] == 115.72
    # the manual's formula worked by hand: C = N = 1024 -> 10 log10(128) - 121.74 = -100.6679 dBm
    assert float(dw1000.rx_level_dbm(1024, 1024)) == pytest.approx(10 * math.log10(128.0) - 121.74, abs=1e-9)
    assert float(dw1000.rx_level_dbm(1024, 1024)) == pytest.approx(-100.6679, abs=1e-4)
    assert float(dw1000.rx_level_dbm(1024, 1024, prf_mhz=16)) == pytest.approx(-94.6479, abs=1e-4)


@pytest.mark.parametrize("car_int", [1000, -1000, 0x0FFFFF, -(1 << 20)])
def test_carrier_integrator_sign_and_scale_as_decawaves_example(car_int: int) -> None:
    freq_offset_multiplier = 998.4e6 / 2.0 / 1024.0 / 131072.0
    hertz_to_ppm_chan2 = -1.0e6 / 3993.6e6
    want_ppm = car_int * freq_offset_multiplier * hertz_to_ppm_chan2
    assert float(dw1000.car_int_to_ppm(car_int, channel=2)) == pytest.approx(want_ppm, rel=1e-12)
    # positive integrator -> negative ppm in this convention (the local clock runs fast)
    assert math.copysign(1.0, float(dw1000.car_int_to_ppm(car_int))) == -math.copysign(1.0, car_int)


def test_carrier_integrator_correction_points_the_right_way_end_to_end() -> None:
    """Single-sided TWR on the simulator with a large clock offset: Decawave's correction
    (tag interval x (1 - ppm 1e-6)) brings it onto double-sided TWR (which needs no clock model);
    the opposite sign doubles the clock error instead. The power-dependent integrator error and
    the timestamp noise are switched off so that only the sign can move the result."""
    sc = load_scenario("paper_antenna").with_effects(
        enabled={"car_int_error": False, "timestamp_noise": False})
    sc = sc.with_station(2, ppm=15.0)
    world = World(sc, seed=3)
    rec, _ = sim.run_ranges(world, sim.twr_schedule(sc, distances_m=[3.0], per_distance=50))
    cols = [rec[k] for k in ("t1r", "t1t", "t2t", "t2r")]
    ds = twr.ds_tof_units(*cols, rec["t3r"], rec["t3t"])
    raw = twr.ss_tof_units(*cols)
    fixed = twr.ss_tof_units(*cols, car_int_r2=rec["car_int_r2"])
    flipped = twr.ss_tof_units(*cols, car_int_r2=-np.asarray(rec["car_int_r2"]))
    m = dw1000.METRES_PER_UNIT
    e_raw = float(np.median(raw - ds)) * m
    e_fixed = float(np.median(fixed - ds)) * m
    e_flipped = float(np.median(flipped - ds)) * m
    assert abs(e_raw) > 0.5                               # ~15 ppm x 1 ms reply x c / 2 ... and more
    assert abs(e_fixed) < 0.05 * abs(e_raw)
    assert abs(e_flipped) == pytest.approx(2 * abs(e_raw), rel=0.05)
