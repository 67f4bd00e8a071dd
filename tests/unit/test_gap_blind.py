"""The independent departures (gap/departures.py) and the blind trials (gap/blind.py)."""

from __future__ import annotations

import ast
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from uwbcal.dw1000 import wrap_diff
from uwbcal.gap import blind, departures, engine, observables
from uwbcal.physics.scenario import load_scenario


def _two_way(seed: int = 3, duration_s: float = 12.0) -> dict[str, np.ndarray]:
    from uwbcal import vectorsim
    from uwbcal.physics.world import World

    sc = load_scenario("two_stations")
    sched = blind.two_way_schedule(sc, duration_s, np.random.default_rng(seed))
    rec, _ = vectorsim.run_triplets(World(sc, seed), sched)
    return dict(rec)


def test_departures_are_written_apart_from_the_catalogue() -> None:
    src = Path(departures.__file__).read_text()
    mods = {n.module for n in ast.walk(ast.parse(src)) if isinstance(n, ast.ImportFrom)}
    mods |= {a.name for n in ast.walk(ast.parse(src)) if isinstance(n, ast.Import) for a in n.names}
    assert not any(m and (m.startswith("uwbcal.physics") or m.startswith("uwbcal.gap")) for m in mods), mods


def test_constant_clock_departure_moves_the_rate_both_ways() -> None:
    rec = _two_way()
    out = departures.clock_departure(rec, 2, departures.constant(0.8))
    r0 = observables.observables(rec)["clock_rate_ppm"]
    r1 = observables.observables(out)["clock_rate_ppm"]
    to2 = np.asarray(rec["rx_station"]) == 2
    assert abs(np.median(r1[to2] - r0[to2]) - 0.8) < 0.01  # station 2 receives: its clock runs fast
    assert abs(np.median(r1[~to2] - r0[~to2]) + 0.8) < 0.01  # station 2 transmits: the other sees -0.8
    for k in ("tx1", "tx2", "tx3"):
        np.testing.assert_array_equal(out[k], rec[k])


def test_clock_departure_moves_the_carrier_integrator_as_the_physics_does() -> None:
    # the carrier integrator measures the carrier's frequency offset, so it follows a clock's
    # departure; checked against the simulator's own clock offset of the same size (two
    # implementations: departures.py knows nothing of the physics)
    from uwbcal import vectorsim
    from uwbcal.gap import model, validate
    from uwbcal.physics.world import World

    sc = load_scenario("two_stations")
    sched = validate.validation_schedule(sc, per_step=40)
    rec, _ = vectorsim.run_triplets(World(sc, 5), sched)
    faster, _ = vectorsim.run_triplets(
        World(model.apply_variant(sc, (("station:2:ppm", sc.station(2).ppm + 2.0),)), 5), sched
    )
    moved = departures.clock_departure(rec, 2, departures.constant(2.0))
    key = "car_int_ppm_minus_rate"
    o0, o_phys, o_dep = (observables.observables(x) for x in (rec, faster, moved))
    shift_phys = float(np.mean(o_phys[key]) - np.mean(o0[key]))
    shift_dep = float(np.mean(o_dep[key]) - np.mean(o0[key]))
    assert abs(shift_phys) > 3.0  # the rate moves by 2 ppm and the integrator by -2
    assert abs(shift_dep - shift_phys) < 0.02
    assert np.asarray(moved["car_int1"]).dtype == np.asarray(rec["car_int1"]).dtype


def test_jitter_and_p3_drift_touch_only_what_they_say() -> None:
    rec = _two_way()
    rng = np.random.default_rng(1)
    out = departures.extra_jitter(rec, rng, 100.0, rx_station=1)
    one = np.asarray(rec["rx_station"]) == 1
    d = wrap_diff(np.asarray(out["rx2"]), np.asarray(rec["rx2"]))
    assert np.all(d[~one] == 0) and np.std(d[one]) * 15.65 > 60.0
    p3 = departures.p3_drift(rec, 0.01)
    np.testing.assert_array_equal(p3["rx2"], rec["rx2"])
    assert np.any(np.asarray(p3["rx3"]) != np.asarray(rec["rx3"]))


def test_saturation_compresses_reported_levels_above_the_knee() -> None:
    from uwbcal import vectorsim
    from uwbcal.gap import validate
    from uwbcal.physics.world import World

    sc = load_scenario("two_stations")
    rec, _ = vectorsim.run_triplets(World(sc, 5), validate.validation_schedule(sc, per_step=20))
    lv = departures.reported_level(rec, 2)
    knee = float(np.median(lv))
    out = departures.level_saturation(rec, knee, 0.5)
    lv2 = departures.reported_level(out, 2)
    hi = lv > knee + 1.0
    assert np.allclose(lv2[hi] - knee, 0.5 * (lv[hi] - knee), atol=0.05)
    assert np.allclose(lv2[lv < knee - 0.1], lv[lv < knee - 0.1], atol=0.01)


def test_blind_two_way_null_through_the_importer_has_no_gap() -> None:
    sc = load_scenario("two_stations")
    spec = {"trial": 0, "kind": "null", "form": "two_way", "departures": [], "seed": 4242}
    r = blind.run_trial(spec, sc, engine.Config(n_seeds=10, n_seeds_signature=2, n_boot=400), 20.0, 100)
    assert r["records"] > 500 and r["verdict"] == "no significant gap" and r["correct"], r["summary"]


def test_blind_plan_mixes_forms_and_kinds() -> None:
    specs = blind.plan(20, 3)
    kinds = {s["kind"] for s in specs}
    forms = {(s["form"], s["kind"]) for s in specs}
    assert kinds == {"single", "null", "pair", "decoy"} and ("two_way", "single") in forms
    assert ("sweep", "single") in forms
    assert all(len(s["departures"]) == 2 for s in specs if s["kind"] == "pair")


@pytest.mark.parametrize("jobs", [1, 2])
def test_each_trial_reaches_on_result_as_it_finishes(monkeypatch: pytest.MonkeyPatch, jobs: int) -> None:
    """validate_blind(on_result=...) hands every trial's result over once, the same dict the summary
    scores (a stopped long run keeps what was measured: tools/bench/bench_gap_blind.py)."""

    def fake(spec: dict[str, Any], *_a: Any) -> dict[str, Any]:  # a trial without its diagnosis
        right = spec["kind"] != "null" or spec["trial"] % 2 == 0
        return {
            **spec,
            "verdict": "x",
            "named": [],
            "shrink": 0.5,
            "correct": right,
            "named_first_right": right,
        }

    monkeypatch.setattr(blind, "run_trial", fake)
    seen: list[dict[str, Any]] = []
    out = blind.validate_blind(12, seed=5, jobs=jobs, on_result=seen.append)
    assert sorted(r["trial"] for r in seen) == list(range(12))
    assert [r["trial"] for r in out["results"]] == list(range(12))
    assert sorted(seen, key=lambda r: r["trial"]) == out["results"]
    assert out["trials"] == 12
