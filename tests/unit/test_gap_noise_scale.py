"""The gap diagnosis names a withheld per-station timestamp-noise scale (Station.noise_scale)."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import numpy as np
from uwbcal import vectorsim as S
from uwbcal.gap import engine, model, validate
from uwbcal.physics.scenario import load_scenario
from uwbcal.physics.world import World

CFG = engine.Config(n_seeds=12, n_seeds_signature=2, n_boot=600, seed=3)


def _two_way_schedule(sc: object, count: int) -> S.TripletSchedule:
    """Alternating directions, as the asil logger: 1 -> 2 every 20 ms, 2 -> 1 10 ms later."""
    a = S.drift_schedule(sc, count, tx=1, rx=2, period_s=0.02)  # type: ignore[arg-type]
    b = S.drift_schedule(sc, count, tx=2, rx=1, period_s=0.02, start_s=1.01)  # type: ignore[arg-type]
    d = {k: np.concatenate([v, getattr(b, k)]) for k, v in a.as_dict().items()}
    d["seq"] = np.arange(d["seq"].size, dtype=np.int64)
    return S.TripletSchedule(**d)


def test_per_station_candidates_are_offered_only_with_two_receivers() -> None:
    sc = load_scenario(validate.SCENARIO)
    cands = model.candidates(sc)
    per = [c for c in cands if c.knob.endswith(":noise_scale")]
    assert [c.effect for c in per] == ["timestamp_noise[1]", "timestamp_noise[2]"]
    assert all(c.baseline == 1.0 and c.depends_on == "timestamp_noise" for c in per)
    one_way = {"rx_station": np.full(10, 2)}
    keep, skip = engine.offered(cands, one_way)
    assert skip == per and len(keep) == len(cands) - 2
    keep, skip = engine.offered(cands, {"rx_station": np.array([1, 2, 1])})
    assert skip == [] and keep == cands


def test_every_receivers_scale_named_is_read_as_one_floor() -> None:
    """engine._every_receiver: the per-receiver scales of an effect named for as many stations as
    the session has receivers (then the selection is run again with the global knob alone)."""
    sc = load_scenario(validate.SCENARIO)
    cands = model.candidates(sc)
    by = {c.effect: c for c in cands}

    def sig(c: model.Candidate) -> SimpleNamespace:
        return SimpleNamespace(candidate=c)  # the one field of a Signature the rule reads

    two_rx = {"rx_station": np.array([1, 2, 1, 2])}
    both = [sig(by["timestamp_noise[2]"]), sig(by["timestamp_noise[1]"]), sig(by["temperature"])]
    assert engine._every_receiver(both, two_rx) == ["timestamp_noise"]  # type: ignore[arg-type]
    one = [sig(by["timestamp_noise[2]"]), sig(by["timestamp_noise"])]
    assert engine._every_receiver(one, two_rx) == []  # type: ignore[arg-type]
    # one receiver: no per-receiver knob stands apart from the global one
    assert engine._every_receiver(both[:1], {"rx_station": np.array([2, 2])}) == []  # type: ignore[arg-type]
    assert engine._per_receiver_of(by["timestamp_noise"]) is None
    assert engine._per_receiver_of(by["timestamp_noise[1]"]) == "timestamp_noise"


def test_withheld_receiver_noise_scale_is_named() -> None:
    sc = load_scenario(validate.SCENARIO)
    true = 12.0  # station 2 receives with 12 x the catalogue's jitter (72 ps floor), station 1 as believed
    sched = _two_way_schedule(sc, 800)
    real, _ = S.run_triplets(World(model.apply_variant(sc, (("station:2:noise_scale", true),)), 4243), sched)
    d = engine.diagnose(real, model.physics_simulator(real, sc), model.candidates(sc), CFG)
    assert d.verdict == "explained", d.summary
    assert d.named[0]["effect"] == "timestamp_noise[2]"
    assert d.named[0]["knob"] == "station:2:noise_scale"
    assert abs(d.named[0]["fitted"] - true) < 0.15 * (true - 1.0)
    assert d.shrink["estimate"] >= 0.8
    noisy = [c for c in d.significant if c.observable == "drift_residual_m" and c.label == "1->2"]
    quiet = [c for c in d.significant if c.observable == "drift_residual_m" and c.label == "2->1"]
    assert noisy and not quiet


def test_report_names_the_one_floor_step() -> None:
    """report.text shows the step that replaced every receiver's own scale by the global knob."""
    from gap_diagnosis import bare
    from uwbcal.gap import report

    step = {
        "step": "one effect for every receiver",
        "instead_of": ["timestamp_noise[2]", "timestamp_noise[1]"],
        "named": ["timestamp_noise", "temperature"],
        "passes": True,
    }
    d = bare("explained", [], [step], "time")
    assert (
        "one effect for every receiver: instead of timestamp_noise[2] + timestamp_noise[1] -> "
        "timestamp_noise + temperature (passes the checks: True)"
    ) in report.text(d)


def test_report_says_when_the_one_floor_is_kept_without_passing() -> None:
    from gap_diagnosis import bare
    from uwbcal.gap import report

    step = {
        "step": "one effect for every receiver",
        "instead_of": ["timestamp_noise[2]", "timestamp_noise[1]"],
        "named": ["clock_wander", "timestamp_noise"],
        "passes": False,
        "kept": "no worse with fewer knobs",
    }
    d = bare("unexplained", [], [step], "time")
    assert (
        "one effect for every receiver: instead of timestamp_noise[2] + timestamp_noise[1] -> "
        "clock_wander + timestamp_noise (passes the checks: False; kept: no worse with fewer knobs)"
    ) in report.text(d)


def _explanation(remaining: int, failed: int, ambiguous: bool, shrink: float, low: float) -> dict[str, Any]:
    """The fields of an explanation (engine's ``explain`` result) that the verdict reads."""
    return {
        "chosen": ["x"],
        "remaining": ["cell"] * remaining,
        "failed_checks": ["check"] * failed,
        "ambiguous": ["a"] if ambiguous else [],
        "shrink": {"estimate": shrink, "ci_low": low, "ci_high": 1.0},
    }


def test_the_one_floor_is_no_worse_only_by_every_criterion_of_the_verdict() -> None:
    """engine._no_worse: the simpler explanation replaces the per-receiver one only if it leaves no
    more cells, fails no more checks, is not ambiguous where that one is not and its shrink is not
    below the lower end of that one's CI."""
    res = _explanation(1, 0, False, 0.97, 0.93)
    ok = _explanation(1, 0, False, 0.94, 0.85)
    nan = float("nan")
    assert engine._no_worse(ok, res)  # type: ignore[arg-type]
    assert engine._no_worse(_explanation(0, 0, False, 0.99, 0.95), res)  # type: ignore[arg-type]
    assert not engine._no_worse(_explanation(1, 0, False, 0.92, 0.8), res)  # type: ignore[arg-type]
    assert not engine._no_worse(_explanation(2, 0, False, 0.99, 0.95), res)  # type: ignore[arg-type]
    assert not engine._no_worse(_explanation(1, 1, False, 0.99, 0.95), res)  # type: ignore[arg-type]
    assert not engine._no_worse(_explanation(1, 0, True, 0.99, 0.95), res)  # type: ignore[arg-type]
    assert not engine._no_worse(_explanation(1, 0, False, nan, nan), res)  # type: ignore[arg-type]
    assert not engine._no_worse(ok, _explanation(1, 0, False, 0.97, nan))  # type: ignore[arg-type]
    assert not engine._no_worse({**ok, "chosen": []}, res)  # type: ignore[arg-type]
