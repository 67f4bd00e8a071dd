"""Closed-form tests of the corrections: every formula against an exact synthetic case.

The synthetic world here is independent of uwbcal.physics: linear clocks, a known power error E,
timestamps rounded to device units and wrapped at 2**40. Seeded.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from uwbcal import dw1000
from uwbcal.corrections import drift, power, twr, zoffset

U = dw1000.TIME_UNIT_S
MOD = dw1000.TIMESTAMP_MOD


def make_triplets(n: int, eps: np.ndarray | float, e1: np.ndarray | float, e2: np.ndarray | float,
                  spacing_s: float = 2e-3, start_units: int = 0, noise_units: float = 0.0,
                  seed: int = 1) -> dict[str, np.ndarray]:
    """P1/P2/P3 at TX times on the 512 grid; RX = (1 + eps) * TX + phase + E (+ noise), rounded, wrapped."""
    rng = np.random.default_rng(seed)
    sp = round(spacing_s / U / 512) * 512
    base = start_units + np.arange(n, dtype=np.int64) * 512 * 40000
    tx = [base + k * sp for k in range(3)]
    eps_a = np.broadcast_to(np.asarray(eps, dtype=np.float64), (n,))
    e = [np.broadcast_to(np.asarray(x, dtype=np.float64), (n,)) for x in (e1, e2, e1)]
    phase = 123456789.25
    noise = [noise_units * rng.standard_normal(n) for _ in range(3)]
    rx = [np.rint((1 + eps_a) * tx[k].astype(np.float64) + phase + e[k] + noise[k]).astype(np.int64) % MOD
          for k in range(3)]
    return {"tx1": tx[0] % MOD, "tx2": tx[1] % MOD, "tx3": tx[2] % MOD,
            "rx1": rx[0], "rx2": rx[1], "rx3": rx[2]}


def diffs(t: dict[str, np.ndarray]) -> drift.TripletDiffs:
    return drift.triplet_diffs(t["tx1"], t["tx2"], t["tx3"], t["rx1"], t["rx2"], t["rx3"])


def test_eq1_removes_linear_drift_exactly_up_to_quantisation() -> None:
    t = make_triplets(1000, eps=5e-6, e1=0.0, e2=0.0)
    d = diffs(t)
    unc = drift.c12_uncorrected(d)
    cor = drift.c12_corrected(d)
    # Without correction C12 = eps * dT_tx12 (about 639 units = 3 m at 2 ms and 5 ppm).
    np.testing.assert_allclose(unc, 5e-6 * d.dtx12, atol=1.01)
    assert np.max(np.abs(cor)) <= 1.01  # rounding of rx1..rx3: 0.5 + 1 * ... bounded by 1 unit
    np.testing.assert_allclose(drift.drift_ratio(d), 5e-6, atol=2e-9)


def test_eq1_leaves_power_error_of_p2() -> None:
    e2 = np.linspace(-40.0, 60.0, 500)  # device units
    t = make_triplets(500, eps=-7e-6, e1=3.0, e2=e2)
    cor = drift.c12_corrected(diffs(t))
    np.testing.assert_allclose(cor, e2 - 3.0, atol=1.01)


def test_eq1_across_the_40_bit_wrap() -> None:
    t = make_triplets(200, eps=4e-6, e1=0.0, e2=10.0, start_units=MOD - 512 * 40000 * 100)
    assert (t["rx1"] > t["rx3"]).any() or (t["tx1"] > t["tx3"]).any()  # some triplets straddle the wrap
    cor = drift.c12_corrected(diffs(t))
    np.testing.assert_allclose(cor, 10.0, atol=1.01)


def test_eq1_during_warm_up_residual_is_second_order() -> None:
    # eps changes by 2 ppm over the run (warm-up): linear interpolation within 4 ms stays exact to
    # well below one unit, while the uncorrected error follows eps.
    n = 4000
    eps = 5e-6 + 2e-6 * (1 - np.exp(-np.arange(n) / 800.0))
    t = make_triplets(n, eps=eps, e1=0.0, e2=0.0, noise_units=3.0, seed=7)
    res = drift.analyze_drift(**t)
    assert abs(res.corrected.mean_m) < 4 * res.corrected.sem_m + 1e-5
    assert res.uncorrected.mean_m > 2.5  # metres: about eps * 2 ms * c
    assert res.drift_ppm_last > res.drift_ppm_first + 1.0


@settings(max_examples=50, deadline=None)
@given(eps_ppm=st.floats(-40, 40), e21=st.floats(-200, 200), start=st.integers(0, MOD - 1))
def test_eq1_property(eps_ppm: float, e21: float, start: int) -> None:
    t = make_triplets(3, eps=eps_ppm * 1e-6, e1=0.0, e2=e21, start_units=start)
    np.testing.assert_allclose(drift.c12_corrected(diffs(t)), e21, atol=1.01)


def test_carrier_integrator_baseline() -> None:
    eps = 5e-6
    t = make_triplets(100, eps=eps, e1=0.0, e2=0.0)
    d = diffs(t)
    ci_exact = dw1000.ppm_to_car_int(-eps * 1e6)  # reads TX minus RX: RX fast -> negative
    np.testing.assert_allclose(drift.c12_carrier_integrator(d, np.full(100, ci_exact)), 0.0, atol=1.01)
    # An integrator 0.1 ppm off leaves 0.1e-6 * dT_tx12 (about 12.8 units = 6 cm at 2 ms).
    ci_off = dw1000.ppm_to_car_int(-eps * 1e6 + 0.1)
    np.testing.assert_allclose(drift.c12_carrier_integrator(d, np.full(100, ci_off)), 0.1e-6 * d.dtx12,
                               atol=1.01)
    res = drift.analyze_drift(**t, car_int1=np.full(100, ci_off), car_int2=np.full(100, ci_off))
    assert res.carrier_integrator is not None
    assert res.carrier_integrator.mean_m == pytest.approx(0.1e-6 * 2e-3 * dw1000.C_LIGHT, rel=0.01)


def test_noise_floor_formula() -> None:
    # 1.5 sigma^2 for r = 0.5, quantisation added in quadrature
    sigma = 100e-12
    q = U / np.sqrt(12)
    expect = np.sqrt(1.5) * np.hypot(sigma, q) * dw1000.C_LIGHT / 10.0
    assert drift.noise_floor_m(sigma, 100) == pytest.approx(expect)
    # and it is what a synthetic run shows (std of C'12)
    t = make_triplets(20000, eps=1e-6, e1=0.0, e2=0.0, noise_units=sigma / U, seed=3)
    res = drift.analyze_drift(**t)
    assert res.corrected.std_m == pytest.approx(drift.noise_floor_m(sigma, 1), rel=0.03)


# --- TWR -----------------------------------------------------------------------------------

def make_exchanges(n: int, tof_units: float, eps: float, e1: float, e2: float, reply_units: float = 64e3,
                   m3_units: float = 128e3, seed: int = 2, start: float = 1e9) -> dict[str, np.ndarray]:
    """Reference clock = true time; tag clock (1 + eps) t + phi; measured RX = true + E (E3 = E1)."""
    rng = np.random.default_rng(seed)
    tau1 = start + np.arange(n) * 1e7 + rng.uniform(0, 1e5, n)
    tau2 = tau1 + tof_units + reply_units + rng.uniform(0, 1e4, n)
    tau3 = tau1 + m3_units
    phi = 5e11

    def tag(tt: np.ndarray) -> np.ndarray:
        return (1 + eps) * tt + phi

    def q(x: np.ndarray) -> np.ndarray:
        return np.rint(x).astype(np.int64) % MOD

    return {"t1r": q(tau1), "t1t": q(tag(tau1 + tof_units) + e1), "t2t": q(tag(tau2)),
            "t2r": q(tau2 + tof_units + e2), "t3r": q(tau3), "t3t": q(tag(tau3 + tof_units) + e1)}


def test_paper_twr_recovers_tof_with_both_corrections() -> None:
    tof, eps, e1, e2 = 700.0, 8e-6, 25.0, -12.0
    x = make_exchanges(500, tof, eps, e1, e2)
    est = twr.paper_tof_units(**x, e1_units=e1, e2_units=e2)
    assert np.max(np.abs(est - tof)) < 1.5  # quantisation of six timestamps
    assert abs(np.mean(est) - tof) < 0.1


def test_paper_twr_without_power_correction_is_biased_by_half_e1_plus_e2() -> None:
    tof, eps, e1, e2 = 300.0, -6e-6, 25.0, -12.0
    x = make_exchanges(500, tof, eps, e1, e2)
    est = twr.paper_tof_units(**x)
    assert np.mean(est) == pytest.approx(tof + 0.5 * (e1 + e2), abs=0.1)


def test_paper_twr_without_drift_correction_has_the_drift_term() -> None:
    tof, eps = 300.0, 6e-6
    x = make_exchanges(500, tof, eps, 0.0, 0.0)
    est = twr.paper_tof_units(x["t1r"], x["t1t"], x["t2t"], x["t2r"], drift=False)
    tau12 = dw1000.wrap_diff(x["t2r"], x["t1r"]) - tof
    np.testing.assert_allclose(est, tof - 0.5 * eps * (tau12 - tof), atol=1.5)
    assert np.mean(est) < tof - 0.1  # 0.5 * 6 ppm * 64e3 = 0.19 units shorter


def test_ss_twr_and_carrier_integrator() -> None:
    tof, eps, e1, e2 = 500.0, 10e-6, 4.0, 6.0
    x = make_exchanges(400, tof, eps, e1, e2, reply_units=6.4e6)  # 100 us reply: 5 units drift error
    plain = twr.ss_tof_units(x["t1r"], x["t1t"], x["t2t"], x["t2r"])
    assert np.mean(plain) == pytest.approx(tof + 5.0 - 0.5 * eps * (6.4e6 + 5e3 - tof), abs=0.2)
    # the reference's integrator reads TX (tag) minus RX (reference): +eps
    ci = np.full(400, dw1000.ppm_to_car_int(eps * 1e6))
    corr = twr.ss_tof_units(x["t1r"], x["t1t"], x["t2t"], x["t2r"], car_int_r2=ci)
    assert np.mean(corr) == pytest.approx(tof + 5.0, abs=0.2)


def test_ds_twr_closed_form() -> None:
    tof, eps = 400.0, 15e-6
    x = make_exchanges(400, tof, eps, 0.0, 0.0, reply_units=3e6, m3_units=9e6)
    ds = twr.ds_tof_units(**x)
    assert abs(np.mean(ds) - tof) < 0.1
    assert np.max(np.abs(ds - tof)) < 1.5
    # power errors bias DS-TWR by about (E1 + E2) / 2
    y = make_exchanges(400, tof, eps, 10.0, 20.0, reply_units=3e6, m3_units=9e6)
    assert np.mean(twr.ds_tof_units(**y)) == pytest.approx(tof + 15.0, abs=0.5)


def test_aps011_table() -> None:
    r = np.array([1.0, 1.0, 1.0, 1.0])
    out = twr.aps011_corrected_range_m(r, [-77.0, -61.0, -93.0, -50.0])
    np.testing.assert_allclose(out, [1.0, 1.11, 1.0 - 0.081, 1.11])


def test_z_from_known_distance() -> None:
    rng = np.random.default_rng(5)
    ranges = 2.0 - 0.3 + 0.01 * rng.standard_normal(2000)
    z = zoffset.z_from_known_distance_m(ranges, 2.0)
    assert z == pytest.approx(0.3, abs=0.001)
    assert zoffset.apply_z_m(1.7, z) == pytest.approx(2.0, abs=0.001)
    assert zoffset.antenna_delay_units(0.3) == pytest.approx(-0.3 / dw1000.METRES_PER_UNIT)


# --- power ---------------------------------------------------------------------------------

def true_error_units(real_dbm: np.ndarray) -> np.ndarray:
    """A sigmoid-like timestamp error (units): later at low power, about 40 units over the range."""
    return 20.0 * np.tanh((-80.0 - real_dbm) / 6.0)


def measured_from_real(real_dbm: np.ndarray) -> np.ndarray:
    """Right below -85 dBm, under-reads above: soft saturation (a synthetic stand-in for the DW1000)."""
    x = real_dbm + 85.0
    return np.where(x < 0, real_dbm, -85.0 + 8.0 * np.tanh(x / 8.0))


def test_power_calibration_recovers_curve_and_real_power() -> None:
    rng = np.random.default_rng(11)
    ref_dbm = -72.0
    n_steps, per = 50, 400
    fine = np.arange(n_steps)  # 0.5 dB steps down from fine gain 31
    gain13 = dw1000.gain_octet(0, 31)
    g2 = np.array([dw1000.gain_octet(0, 31 - int(k)) if k < 32 else dw1000.gain_octet(3, 31 - int(k) + 18)
                   for k in fine])
    nominal = dw1000.gain_nominal_db(g2) - dw1000.gain_nominal_db(gain13)
    step = np.repeat(fine, per)
    real2 = ref_dbm + np.repeat(nominal, per)
    e1 = float(true_error_units(np.array([ref_dbm]))[0])
    e2 = true_error_units(real2)
    t = make_triplets(step.size, eps=3e-6, e1=e1, e2=e2, noise_units=4.0, seed=12)
    meas2 = measured_from_real(real2) + 0.3 * rng.standard_normal(step.size)
    meas1 = measured_from_real(np.full(step.size, ref_dbm))
    cal = power.calibrate_power(**t, step=step, gain13=np.full(step.size, gain13), gain2=g2[step],
                                measured2_dbm=meas2, measured1_dbm=meas1)
    real_est = np.array([s.real_dbm for s in cal.steps])
    assert np.sqrt(np.mean((real_est - (ref_dbm + nominal)) ** 2)) < 0.2
    assert cal.slope == pytest.approx(1.0, abs=0.05)
    assert cal.offset_dbm == pytest.approx(ref_dbm, abs=0.3)
    # curve against truth after removing the constant E(ref)
    c = cal.curve
    truth = (true_error_units(np.asarray(c.real_dbm)) - e1) * U
    rms_m = np.sqrt(np.mean((np.asarray(c.error_s) - truth) ** 2)) * dw1000.C_LIGHT
    assert rms_m < 0.003
    assert np.all(np.diff(c.measured_dbm) > 0)
    # error at P1's power is zero by construction, at the weakest step about +E(-97) - E(-72)
    assert c.error_at_real(ref_dbm)[()] == pytest.approx(0.0, abs=2 * U)
    # round trip through a dict
    assert power.PowerCurve.from_dict(c.to_dict()) == c


def test_power_calibration_fits_the_step_size_when_the_nominal_is_wrong() -> None:
    # Real fine steps are 0.45 dB while the analysis assumes 0.5 dB: the fitted slope absorbs it.
    ref_dbm = -80.0
    k = np.arange(30)
    gain13 = dw1000.gain_octet(0, 31)
    g2 = np.array([dw1000.gain_octet(0, 31 - int(i)) for i in k])
    step = np.repeat(k, 50)
    real2 = ref_dbm - 0.45 * step
    t = make_triplets(step.size, eps=1e-6, e1=0.0, e2=0.0)
    cal = power.calibrate_power(**t, step=step, gain13=np.full(step.size, gain13), gain2=g2[step],
                                measured2_dbm=measured_from_real(real2))
    assert cal.slope == pytest.approx(0.9, abs=0.01)
    real_est = np.array([s.real_dbm for s in cal.steps])
    np.testing.assert_allclose(real_est, ref_dbm - 0.45 * k, atol=0.05)


def test_power_calibration_needs_a_low_power_step() -> None:
    t = make_triplets(10, eps=1e-6, e1=0.0, e2=0.0)
    with pytest.raises(Exception, match="below"):
        power.calibrate_power(**t, step=np.zeros(10, int), gain13=np.zeros(10, int), gain2=np.zeros(10, int),
                              measured2_dbm=np.full(10, -70.0))


def test_isotonic_and_robust_mean() -> None:
    np.testing.assert_allclose(power.isotonic_increasing([1.0, 3.0, 2.0, 4.0]), [1.0, 2.5, 2.5, 4.0])
    x = np.concatenate([np.zeros(99), [1e6]])
    mean, _, n = power.robust_mean(x + np.linspace(-1, 1, 100))
    assert n == 99 and abs(mean) < 0.05


def test_power_curve_validates_axes() -> None:
    with pytest.raises(ValueError):
        power.PowerCurve((1.0, 0.5), (0.0, 0.0), (1.0, 2.0), 0.0, 0.0)
    c = power.PowerCurve((-90.0, -80.0), (1e-10, 0.0), (-90.0, -75.0), -75.0, -80.0)
    np.testing.assert_allclose(c.error_at_measured([-95.0, -85.0, -70.0]), [1e-10, 0.5e-10, 0.0])
    np.testing.assert_allclose(c.real_from_measured([-95.0, -85.0]), [-95.0, -82.5])


def test_rx_level_nosat_correction() -> None:
    lvl = dw1000.rx_level_dbm(1000, 100)
    assert power.rx_level_from_registers(1000, 100)[()] == pytest.approx(lvl)
    # RXPACC == RXPACC_NOSAT: N less the standard SFD (user manual: 5 symbols at 850k/6.8M, 64 at
    # 110k), the numbers written here from the manual, not from the shared constants
    corrected = power.rx_level_from_registers(1000, 100, rxpacc_nosat=100)
    assert corrected[()] == pytest.approx(float(dw1000.rx_level_dbm(1000, 95)))
    slow = power.rx_level_from_registers(1000, 100, rxpacc_nosat=100, data_rate_kbps=110)
    assert slow[()] == pytest.approx(float(dw1000.rx_level_dbm(1000, 36)))
    unsat = power.rx_level_from_registers(1000, 100, rxpacc_nosat=108)
    assert unsat[()] == pytest.approx(lvl)


def test_stitching_recovers_real_power_with_coarse_gain_errors() -> None:
    # A 0.5 dB sweep over 30 dB crosses coarse settings whose real steps are off by tenths of a dB
    # and whose fine steps are 2 % large: a line through nominal gains extrapolates badly, the
    # stitched segments do not.
    oct_list = [dw1000.gain_octet(0, f) for f in range(31, -1, -1)]
    for c in range(1, 6):
        oct_list += [dw1000.gain_octet(c, f) for f in range(5, -1, -1)]
    octs = np.array(oct_list[:60])
    coarse_err = np.array([0.0, 0.25, -0.15, 0.35, 0.1, -0.3, 0.2])
    real_gain = 0.5 * 1.02 * (octs & 31) - 3.0 * (octs >> 5) + coarse_err[octs >> 5]
    real = -62.0 + real_gain - real_gain[0]
    meas = measured_from_real(real)
    est, scale, n_low = power.stitch_real_power((octs & 31) * 0.5, octs >> 5, meas)
    assert scale == pytest.approx(1.02, abs=0.01)
    assert n_low >= 5
    assert np.sqrt(np.mean((est - real) ** 2)) < 0.15
    nominal = dw1000.gain_nominal_db(octs) - dw1000.gain_nominal_db(octs[0])
    a, b, _ = power.fit_measured_vs_real(nominal, meas)
    assert np.sqrt(np.mean((a + b * nominal - real) ** 2)) > 0.5  # the paper's line is off here
    with pytest.raises(ValueError):
        power.stitch_real_power(np.zeros(5), np.arange(5), meas[:5])  # one step per coarse setting
