"""The world model against closed-form cases (uwbcal.physics)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from uwbcal import dw1000
from uwbcal.errors import ScenarioError
from uwbcal.physics import EFFECTS, World, load_scenario, parse_scenario
from uwbcal.physics import models as M

TU = dw1000.TIME_UNIT_S
C = dw1000.C_LIGHT

BASE = """
name = "t"
seed = 3
[[stations]]
id = 1
position_m = [0.0, 0.0, 0.0]
counter_offset_units = 0
[[stations]]
id = 2
position_m = [1.5, 0.0, 0.0]
counter_offset_units = 0
"""


def ideal(text: str = BASE) -> World:
    return World(parse_scenario(text).with_all_effects(False))


# --- closed forms ----------------------------------------------------------------------------


def test_friis_closed_form() -> None:
    f = dw1000.CHANNEL_FREQ_HZ[2]
    assert M.friis_loss_db(1.0, f) == pytest.approx(20 * math.log10(4 * math.pi * f / C), abs=1e-12)
    assert M.friis_loss_db(1.0, 3993.6e6) == pytest.approx(44.475, abs=1e-3)
    assert M.friis_loss_db(3.0, f) - M.friis_loss_db(1.5, f) == pytest.approx(20 * math.log10(2), abs=1e-12)


def test_air_and_cable_power_and_delay() -> None:
    sc = parse_scenario(BASE).with_effects(enabled={"path_loss": True})
    w = World(sc)
    p, tof, d = w.propagation(1, 2, np.array([dw1000.gain_octet(0, 20)]))
    expected = -30.0 + 10.0 - M.friis_loss_db(1.5, 3993.6e6)
    assert p[0] == pytest.approx(expected, abs=1e-9)
    assert tof[0] == pytest.approx(1.5 / C, rel=1e-12) and d[0] == 1.5
    cable = BASE + '[[links]]\na = 1\nb = 2\nkind = "cable"\nlength_m = 0.1\nattenuation_db = 45.0\n'
    wc = World(parse_scenario(cable))
    p, tof, _ = wc.propagation(2, 1, np.array([dw1000.gain_octet(0, 0)]))
    assert p[0] == pytest.approx(-30.0 - 45.0) and tof[0] == pytest.approx(0.1 / (0.7 * C))


def test_path_loss_off_ignores_distance() -> None:
    w = World(parse_scenario(BASE).with_effects(enabled={"path_loss": False}))
    p1 = w.propagation(1, 2, np.array([0]), np.array([0.5]))[0]
    p2 = w.propagation(1, 2, np.array([0]), np.array([5.0]))[0]
    assert p1[0] == p2[0] == pytest.approx(-30.0 - M.friis_loss_db(1.0, 3993.6e6)[()])


def test_delayed_tx_grid_and_antd() -> None:
    w = World(parse_scenario(BASE).with_all_effects(False).with_effects(enabled={"delayed_tx_grid": True}))
    dx = np.array([1000, 1023, 1024, 1535, 1536]) + (1 << 30)
    tb = w.delayed_tx(1, dx)
    assert list(tb.grid_units - (1 << 30)) == [512, 512, 1024, 1024, 1536]
    assert np.all(tb.stamp_unwrapped == tb.grid_units + 16436)
    w2 = World(w.scenario.with_effects(enabled={"delayed_tx_grid": True}))
    assert np.all(w2.delayed_tx(1, dx).grid_units == dx & ~np.int64(511))
    w3 = World(w.scenario.with_effects(enabled={"delayed_tx_grid": False}))
    assert np.all(w3.delayed_tx(1, dx, tx_antd=100).stamp_unwrapped == dx + 100)


def test_wrap_modulo_2_40() -> None:
    text = BASE.replace("counter_offset_units = 0", f"counter_offset_units = {(1 << 40) - 1000}", 1)
    w = World(parse_scenario(text).with_all_effects(False).with_effects(enabled={"timestamp_wrap": True}))
    t = np.array([0.0, 1e-6, 1.0])
    tb = w.delayed_tx(1, np.floor(w.local_units(1, t)).astype(np.int64))
    assert np.all(tb.stamp < (1 << 40)) and np.all(tb.stamp >= 0)
    assert tb.stamp_unwrapped[1] >= 1 << 40  # wrapped for real
    assert np.all(dw1000.wrap_diff(tb.stamp[1:], tb.stamp[:-1]) == np.diff(tb.stamp_unwrapped))
    off = World(w.scenario.with_effects(enabled={"timestamp_wrap": False}))
    tb2 = off.delayed_tx(1, np.floor(off.local_units(1, t)).astype(np.int64))
    assert np.all(tb2.stamp == tb2.stamp_unwrapped)


def test_clock_integral_closed_form() -> None:
    text = BASE.replace("id = 1\n", "id = 1\nppm = 4.0\nwarmup_ppm = -2.0\nwarmup_tau_s = 200.0\n", 1)
    w = World(
        parse_scenario(text)
        .with_all_effects(False)
        .with_effects(enabled={"clock_offset": True, "warmup": True})
    )
    t = np.array([0.0, 10.0, 200.0, 900.0, 3600.0])
    expected = t + 1e-6 * (4.0 * t - 2.0 * 200.0 * (1.0 - np.exp(-t / 200.0)))
    assert np.allclose(w.local_s(1, t), expected, rtol=0, atol=1e-13)
    y = w.offset_ppm(1, t)
    assert np.allclose(y, 4.0 - 2.0 * np.exp(-t / 200.0), atol=1e-12)
    # ~15 min to settle: within 1.25 % of the warm-up amplitude after 900 s, far from it at 60 s
    assert abs(y[3] - 4.0) < 0.025 and abs(w.offset_ppm(1, [60.0])[0] - 4.0) > 1.0


def test_two_stage_warmup_adds_its_own_exponential() -> None:
    text = BASE.replace(
        "id = 1\n",
        "id = 1\nwarmup_ppm = 0.5\nwarmup_tau_s = 150.0\nwarmup2_ppm = 1.5\nwarmup2_tau_s = 12.0\n",
        1,
    )
    sc = parse_scenario(text).with_all_effects(False).with_effects(enabled={"warmup": True})
    w = World(sc)
    t = np.array([0.0, 5.0, 30.0, 120.0])
    y = 0.5 * np.exp(-t / 150.0) + 1.5 * np.exp(-t / 12.0)
    assert np.allclose(w.offset_ppm(1, t), y, atol=1e-12)
    phase = 0.5 * 150.0 * -np.expm1(-t / 150.0) + 1.5 * 12.0 * -np.expm1(-t / 12.0)
    assert np.allclose(w.local_s(1, t), t + 1e-6 * phase, rtol=0, atol=1e-13)
    again = parse_scenario(sc.to_toml()).station(1)
    assert (again.warmup2_ppm, again.warmup2_tau_s) == (1.5, 12.0)
    with pytest.raises(ScenarioError, match="warmup2_tau_s"):
        parse_scenario(BASE.replace("id = 1\n", "id = 1\nwarmup2_tau_s = 0.0\n", 1))


def test_clock_phase_is_integral_of_frequency_with_wander_and_temperature() -> None:
    sc = load_scenario("two_stations").with_effects(params={"clock_wander": {"sigma_ppm_per_sqrt_s": 0.05}})
    w = World(sc, seed=5)
    t = np.linspace(0.3, 500.0, 200)
    h = 1e-3
    num = (w.local_s(1, t + h) - w.local_s(1, t - h)) / (2 * h)
    assert np.allclose((num - 1.0) * 1e6, w.offset_ppm(1, t), atol=2e-3)
    # wander really wanders, and the inverse is exact
    assert (
        np.ptp(w.offset_ppm(1, t) - World(sc.with_effects(enabled={"clock_wander": False})).offset_ppm(1, t))
        > 0.05
    )
    back = w.true_time_s(1, w.local_s(1, t))
    assert np.max(np.abs(back - t)) < 1e-12


def test_clock_query_order_does_not_matter() -> None:
    sc = load_scenario("two_stations")
    a, b = World(sc, seed=9), World(sc, seed=9)
    t = np.array([5.0, 2000.0, 17.5])
    late_first = a.local_s(1, t[::-1])[::-1]
    assert np.array_equal(late_first, b.local_s(1, t))


def test_estimate_map_monotone_compressing_and_invertible() -> None:
    e = EFFECTS["rx_power_estimate"]()
    kw = dict(knee_dbm=e.knee_dbm, knee_width_db=e.knee_width_db, high_slope=e.high_slope)  # type: ignore[attr-defined]
    p = np.linspace(-115, -30, 2000)
    est = M.estimated_level_dbm(p, **kw)
    assert np.all(np.diff(est) > 0)
    low = p < -90
    assert np.max(np.abs(est[low] - p[low])) < 0.05  # right below about -85 dBm
    assert M.estimated_level_dbm(-70.0, **kw) < -70.0 - 5  # under-reads strong signals
    assert np.allclose(M.true_level_dbm(est, **kw), p, atol=1e-8)


def test_registers_read_back_the_estimate() -> None:
    sc = load_scenario("paper_antenna")
    w = World(sc, seed=2)
    octets = np.array([dw1000.gain_octet(c, f) for c in range(7) for f in range(0, 32, 4)])
    tb = w.delayed_tx(2, np.full(octets.size, 10**9) + np.arange(octets.size) * 10**8)
    rb = w.receive(2, 1, tb.t_true_s, octets)
    lvl = dw1000.rx_level_dbm(rb.regs["cir_pwr"], rb.regs["rxpacc"])
    tol = 10 * np.log10(1 + 0.5 / rb.regs["cir_pwr"]) + 1e-9  # CIR_PWR rounding
    assert np.all(np.abs(lvl - rb.est_dbm) <= tol)
    fp = dw1000.fp_power_dbm(rb.regs["fp_ampl1"], rb.regs["fp_ampl2"], rb.regs["fp_ampl3"], rb.regs["rxpacc"])
    assert np.allclose(fp, rb.est_dbm - 2.0, atol=0.01)
    assert np.all(rb.regs["rxpacc_nosat"] != rb.regs["rxpacc"])
    assert np.all((rb.regs["cir_pwr"] >= 1) & (rb.regs["cir_pwr"] <= 0xFFFF))


def test_car_int_round_trip_and_power_jump() -> None:
    sc = load_scenario("paper_cable")
    quiet = World(sc.with_effects(enabled={"car_int_error": False}), seed=1)
    tb = quiet.delayed_tx(2, np.arange(5) * 10**9 + 10**10)
    rb = quiet.receive(2, 1, tb.t_true_s, np.full(5, 0x1F))
    ppm = dw1000.car_int_to_ppm(rb.regs["car_int"])
    lsb = dw1000.car_int_to_ppm(1.0)
    assert np.all(np.abs(ppm - (-rb.offset_ppm)) <= abs(lsb) / 2 + 1e-12)
    # ttcko/ttcki carries the same (TX-minus-RX) offset
    assert np.allclose(rb.regs["ttcko"] / rb.regs["ttcki"] * 1e6, -rb.offset_ppm, atol=0.05)
    # power-dependent error: only the RX power changes -> the integrator moves by slope * dP
    noisy = World(sc.with_effects(params={"car_int_error": {"noise_ppm": 0.0}}), seed=1)
    t = np.full(2, 100.0)
    hi = noisy.receive(2, 1, t, np.array([0x1F, 0x1F]))
    lo = noisy.receive(2, 1, t, np.array([0xDF, 0xDF]))
    d_ppm = dw1000.car_int_to_ppm(lo.regs["car_int"]) - dw1000.car_int_to_ppm(hi.regs["car_int"])
    expected = 0.02 * (lo.rx_dbm - hi.rx_dbm)
    assert np.allclose(d_ppm, expected, atol=2 * abs(lsb))
    assert abs(expected[0]) > 0.3


def test_bias_curve_near_aps011_and_per_station() -> None:
    b = EFFECTS["power_bias"]()
    x = np.asarray(dw1000.APS011_LEVEL_DBM)
    fit = M.bias_curve_m(x, **b.values())
    assert np.max(np.abs(fit - dw1000.aps011_bias_m(x))) < 0.005
    assert np.all(np.diff(M.bias_curve_m(np.linspace(-100, -55, 100), **b.values())) < 0)  # falls with power
    w = World(load_scenario("paper_cable"))
    p = np.array([-80.0])
    s2 = w.scenario.station(2)
    expected = s2.bias_scale * M.bias_curve_m(p - s2.bias_shift_db, **b.values()) / C
    assert w.power_bias_s(2, p)[0] == pytest.approx(expected[0], rel=1e-12)
    assert w.power_bias_s(1, p)[0] != w.power_bias_s(2, p)[0]


def test_interference_closed_form() -> None:
    e = EFFECTS["interference"]()
    a, tau = e.amplitude_ps, e.tau_s  # type: ignore[attr-defined]
    assert M.interference_shift_s(150e-6, a, tau) == pytest.approx(a * 1e-12 * math.exp(-150e-6 / tau))
    assert M.interference_shift_s(150e-6, a, tau) > 5e-12  # significant: > 1.5 mm
    assert M.interference_shift_s(2e-3, a, tau) < 1e-15  # negligible
    assert M.interference_shift_s(np.inf, a, tau) == 0.0


def test_tx_gain_nonideal_and_switch() -> None:
    sc = load_scenario("paper_cable")
    w = World(sc)
    octs = np.array([dw1000.gain_octet(c, 31) for c in range(7)])
    g = w.tx_gain_db(2, octs)
    errs = np.asarray(sc.station(2).coarse_errors_db)
    assert np.allclose(g, 31 * 0.5 * 1.02 - 3.0 * np.arange(7) + errs)
    w_off = World(sc.with_effects(enabled={"tx_gain": False}))
    assert np.allclose(w_off.tx_gain_db(2, octs), dw1000.gain_nominal_db(octs, 3.0))
    w25 = World(sc.with_effects(enabled={"tx_gain": False}, params={"tx_gain": {"coarse_step_db": 2.5}}))
    assert np.allclose(w25.tx_gain_db(2, octs), dw1000.gain_nominal_db(octs, 2.5))
    assert w.tx_gain_db(2, [dw1000.gain_octet(7, 0)])[0] == -np.inf


def test_timestamp_noise_grows_at_low_snr() -> None:
    s = M.timestamp_sigma_s(np.array([-60.0, -95.0, -101.0]), 6.0, 20.0, -95.0)
    assert s[0] == pytest.approx(6e-12, rel=1e-3)
    assert s[1] == pytest.approx(math.hypot(6, 20) * 1e-12)
    assert s[2] > s[1]


def test_all_effects_off_gives_exact_ideal_timestamps() -> None:
    w = ideal()
    d_units = 320.2
    d = d_units * dw1000.METRES_PER_UNIT
    dx = (np.arange(10, dtype=np.int64) + 1) * 10**9
    tb = w.delayed_tx(1, dx)
    assert np.array_equal(tb.stamp, dx + 16436)
    rb = w.receive(1, 2, tb.t_true_s, np.zeros(10, np.int64), np.full(10, d))
    assert np.array_equal(rb.stamp - tb.stamp, np.full(10, 320))
    assert np.all(rb.error_s == 0.0) and np.all(rb.bias_s == 0.0)
    assert np.all(rb.est_dbm == rb.rx_dbm)


def test_multipath_probability_and_sign() -> None:
    sc = (
        parse_scenario(BASE)
        .with_all_effects(False)
        .with_effects(
            enabled={"multipath": True}, params={"multipath": {"probability": 0.2, "mean_bias_m": 0.3}}
        )
    )
    w = World(sc, seed=4)
    n = 20000
    rb = w.receive(1, 2, np.linspace(1, 100, n), np.zeros(n, np.int64))
    excess = (rb.t_arrival_s - np.linspace(1, 100, n) - rb.tof_s) * C
    late = excess > 1e-4
    assert late.mean() == pytest.approx(0.2, abs=0.01)
    assert np.all(excess > -1e-4) and excess[late].mean() == pytest.approx(0.3, rel=0.05)


@pytest.mark.parametrize("k", [1.0, 4.0])
def test_multipath_excess_shape_keeps_the_mean(k: float) -> None:
    """A gamma excess of shape k: mean mean_bias_m whatever k, coefficient of variation 1/sqrt(k)."""
    sc = (
        parse_scenario(BASE)
        .with_all_effects(False)
        .with_effects(
            enabled={"multipath": True},
            params={"multipath": {"probability": 1.0, "mean_bias_m": 0.3, "excess_shape": k}},
        )
    )
    n = 20000
    rb = World(sc, seed=5).receive(1, 2, np.linspace(1, 100, n), np.zeros(n, np.int64))
    excess = (rb.t_arrival_s - np.linspace(1, 100, n) - rb.tof_s) * C
    assert excess.mean() == pytest.approx(0.3, rel=0.03)
    assert excess.std() / excess.mean() == pytest.approx(1.0 / math.sqrt(k), rel=0.05)


def test_temperature_range_drift() -> None:
    sc = parse_scenario(BASE.replace("id = 1\n", "id = 1\nself_heating_c = 10.0\n", 1)).with_all_effects(
        False
    )
    sc = sc.with_effects(enabled={"temperature": True}, params={"temperature": {"heating_tau_s": 100.0}})
    w = World(sc)
    t = np.array([0.0, 5000.0])
    temp = w.temperature_c(1, t)
    assert temp[0] == pytest.approx(25.0) and temp[1] == pytest.approx(35.0, abs=1e-6)
    rb = w.receive(2, 1, t, np.zeros(2, np.int64))
    # each hardware delay of a warmed station grows by half of 2.15 mm/degC (TWR over two stations)
    assert rb.error_s[1] - rb.error_s[0] == pytest.approx(10.0 * 2.15e-3 / C / 2, rel=1e-6)


def test_reproducible_per_seed() -> None:
    sc = load_scenario("two_stations")
    a = World(sc, seed=11).receive(1, 2, np.linspace(1, 2, 50), np.full(50, 0x1F))
    b = World(sc, seed=11).receive(1, 2, np.linspace(1, 2, 50), np.full(50, 0x1F))
    c = World(sc, seed=12).receive(1, 2, np.linspace(1, 2, 50), np.full(50, 0x1F))
    assert np.array_equal(a.stamp, b.stamp) and all(np.array_equal(a.regs[k], b.regs[k]) for k in a.regs)
    assert not np.array_equal(a.stamp, c.stamp)


def test_per_frame_transmit_matches_vectorised() -> None:
    sc = load_scenario("two_stations").with_effects(
        enabled={
            "timestamp_noise": False,
            "rx_power_estimate": False,
            "car_int_error": False,
            "multipath": False,
        }
    )
    w1, w2 = World(sc, seed=1), World(sc, seed=1)
    t = 3.25
    rec = w1.transmit(1, t, 0x1F)[2]
    vec = w2.receive(1, 2, np.array([t]), np.array([0x1F]))
    assert rec.stamp == int(vec.stamp[0]) and rec.rx_dbm == vec.rx_dbm[0]
    assert rec.regs["car_int"] == int(vec.regs["car_int"][0])
    # the per-frame path tracks the interference gap
    again = w1.transmit(1, t + 150e-6, 0x1F)[2]
    assert again.error_s - rec.error_s == pytest.approx(
        M.interference_shift_s(150e-6, 40.0, 120e-6)[()], rel=1e-3
    )


# --- scenarios --------------------------------------------------------------------------------


def test_examples_load_and_round_trip() -> None:
    for name in ("paper_cable", "paper_antenna", "two_stations"):
        sc = load_scenario(name)
        assert parse_scenario(sc.to_toml()).to_dict() == sc.to_dict()
    assert load_scenario("paper_cable").link(1, 2).kind == "cable"
    assert load_scenario("paper_antenna").distance_m(1, 2) == pytest.approx(1.5)


@pytest.mark.parametrize(
    "text, words",
    [
        (BASE + "bogus = 1\n", "bogus"),
        (BASE.replace("id = 2", 'id = 2\nppm = "fast"'), "ppm"),
        (BASE + "[effects.warp]\nenabled = true\n", "warp"),
        (BASE + "[effects.warmup]\nspeed = 3\n", "speed"),
        (BASE + '[effects.interference]\namplitude_ps = "big"\n', "amplitude_ps"),
        (BASE + "[[links]]\na = 1\nb = 9\n", "station 9"),
        (BASE + "[radio]\nchannel = 6\n", "radio.channel"),
        (BASE.replace("[0.0, 0.0, 0.0]", "[0.0, 0.0]"), "position_m"),
        ("seed = 1\n", "stations"),
        ("name = [\n", "TOML"),
    ],
)
def test_scenario_errors_name_the_key(text: str, words: str) -> None:
    with pytest.raises(ScenarioError, match=words):
        parse_scenario(text)


def test_with_effects_and_station() -> None:
    sc = load_scenario("paper_cable")
    s2 = sc.with_effects(enabled={"warmup": False}, params={"interference": {"amplitude_ps": 10.0}})
    assert not s2.enabled("warmup") and sc.enabled("warmup")
    assert s2.effects["interference"].values()["amplitude_ps"] == 10.0
    with pytest.raises(ScenarioError, match="nope"):
        sc.with_effects(enabled={"nope": True})
    with pytest.raises(ScenarioError, match="tau"):
        sc.with_effects(params={"warmup": {"tau": 1.0}})
    s3 = sc.with_station(2, ppm=7.0)
    assert s3.station(2).ppm == 7.0 and sc.station(2).ppm == 3.0
    with pytest.raises(ScenarioError, match="colour"):
        sc.with_station(2, colour=1)
    assert set(EFFECTS) >= {
        "clock_offset",
        "warmup",
        "clock_wander",
        "timestamp_noise",
        "quantisation",
        "timestamp_wrap",
        "delayed_tx_grid",
        "path_loss",
        "power_bias",
        "rx_power_estimate",
        "car_int_error",
        "tx_gain",
        "antenna_delay",
        "interference",
        "temperature",
        "multipath",
    }
    for cls in EFFECTS.values():
        assert cls.__doc__ and ("Source" in cls.__doc__ or "[UM]" in cls.__doc__)


def test_physics_doc_lists_every_effect_and_parameter() -> None:
    from pathlib import Path

    doc = (Path(__file__).resolve().parents[2] / "docs" / "PHYSICS.md").read_text()
    for name, cls in EFFECTS.items():
        assert f"### `{name}`" in doc, name
        for p in cls.parameters():
            assert f"`{p}`" in doc, (name, p)


def test_hardware_draws_follow_the_scenario_seed_not_the_run_seed() -> None:
    sc = load_scenario("two_stations")  # no counter offsets, no coarse errors given: drawn
    a, b = World(sc, seed=1), World(sc, seed=2)
    assert a.clock(1).counter0_units == b.clock(1).counter0_units
    octs = np.arange(0, 224, 32)
    assert np.array_equal(a.tx_gain_db(1, octs), b.tx_gain_db(1, octs))
    c = World(sc.with_seed(99), seed=1)
    assert c.clock(1).counter0_units != a.clock(1).counter0_units
    assert not np.array_equal(c.tx_gain_db(1, octs), a.tx_gain_db(1, octs))
