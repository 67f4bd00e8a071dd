"""Closing the loop: fitted scenarios (gap/fitted.py) and their use by `uwbcal paper --scenario`."""

from __future__ import annotations

from uwbcal.gap import fitted
from uwbcal.paper import with_effects_of
from uwbcal.physics.scenario import load_scenario, parse_scenario

FLOOR = "effect:timestamp_noise:floor_ps"


def test_fitted_scenario_sets_the_named_knobs_and_reads_back() -> None:
    sc = load_scenario("two_stations")
    named = [
        {"effect": "timestamp_noise", "knob": FLOOR, "fitted": 52.0, "unit": "ps"},
        {"effect": "timestamp_noise[1]", "knob": "station:1:noise_scale", "fitted": 1.6, "unit": ""},
        {"effect": "clock_offset", "knob": "station:2:ppm", "fitted": -1.9, "unit": "ppm"},
    ]
    f = fitted.fitted_scenario(sc, named, name="asil_test")
    assert f.effect("timestamp_noise").values()["floor_ps"] == 52.0
    assert f.station(1).noise_scale == 1.6 and f.station(2).ppm == -1.9
    assert f.station(2).noise_scale == sc.station(2).noise_scale
    text = fitted.scenario_toml(f, ["header line"])
    assert text.startswith("# header line\n")
    again = parse_scenario(text, name="asil_test")
    assert again.to_toml() == f.to_toml()
    assert [fitted.plain_name(n) for n in named] == [
        "timestamp noise floor",
        "station 1 receiver timestamp-noise scale",
        "station 2 clock offset",
    ]


def test_paper_takes_the_effects_and_keeps_its_stations() -> None:
    ant = load_scenario("paper_antenna")
    f = fitted.fitted_scenario(
        load_scenario("two_stations"),
        [{"effect": "timestamp_noise", "knob": FLOOR, "fitted": 50.0, "unit": "ps"}],
        name="f",
    )
    mixed = with_effects_of(ant, f)
    assert mixed.effect("timestamp_noise").values()["floor_ps"] == 50.0
    assert mixed.stations == tuple(
        s.__class__(**{**s.__dict__, "noise_scale": f.station(s.id).noise_scale}) for s in ant.stations
    )
    assert mixed.distance_m(1, 2) == ant.distance_m(1, 2)


def test_free_per_step_terms_are_named_but_not_written_into_the_scenario() -> None:
    """A free per-step term (gap/free.py) is the discrepancy's own shape, not a scenario parameter:
    the fitted scenario is the believed one with the other named knobs, and the name reads plainly."""
    sc = load_scenario("two_stations")
    free_term = {"effect": "tx_gain", "knob": "free:stamp", "fitted": 0.013, "unit": "m", "shape": []}
    named = [free_term, {"effect": "timestamp_noise", "knob": FLOOR, "fitted": 52.0, "unit": "ps"}]
    f = fitted.fitted_scenario(sc, named, name="with_free")
    assert f.effect("timestamp_noise").values()["floor_ps"] == 52.0
    assert f.to_toml() == fitted.fitted_scenario(sc, named[1:], name="with_free").to_toml()
    assert fitted.plain_name(free_term) == "tx gain: P2 RX timestamp offset per power step (RMS)"
