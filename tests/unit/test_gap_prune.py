"""Pruning an effect whose re-simulated records differ where the believed ones did not
(engine step "pruned")."""

from __future__ import annotations

from uwbcal.gap import blind, engine, model, report
from uwbcal.gap.validate import SCENARIO
from uwbcal.physics.scenario import load_scenario

#: Candidates of the end-to-end case: the power family (with the free per-step terms), the noise,
#: the slow clock effect and interference, the effect the re-selection on top of the free terms
#: picked (the full catalogue runs in tools/bench/bench_gap_blind.py; here it would triple the
#: test's time)
_EFFECTS = ("power_bias", "rx_power_estimate", "tx_gain", "timestamp_noise", "clock_wander", "interference")


def test_an_effect_that_only_adds_a_discrepancy_is_dropped() -> None:
    """Blind seed 8, trial 16 (untuned when it failed): a sweep whose P2 stamps are biased by
    0.144 m x tanh((L2 + 81.2 dBm) / 4.3 dB), a curve of another form than the catalogue's. The
    free per-step stamp terms name the power bias, but the other effects selected on top of them
    took interference, whose re-simulated records differed from the real ones in a clock-rate cell
    (KS z +5.5) that had not differed before (+0.8): "unexplained". Without it every check passes.

    Since the tenth session's check against believed re-simulations (attribute._beyond_chance) the
    interference is no longer selected here (see the test below), so the pruning is exercised
    with that check off, as the case first ran."""
    sc = load_scenario(SCENARIO)
    spec = next(s for s in blind.plan(40, 8) if s["trial"] == 16)
    assert spec["departures"] == ["power_bias"]
    rec, _ = blind.make_session(spec, sc, 40.0, 200)
    cands = [c for c in model.candidates(sc) if c.effect in _EFFECTS]
    # the blind trial's own settings, without the chance check (min_null_seeds above the seeds)
    cfg = engine.Config(seed=int(spec["seed"]) % 100_000, min_null_seeds=10_000)
    d = engine.diagnose(rec, model.physics_simulator(rec, sc), cands, cfg)
    pruned = [s for s in d.selection_steps if s.get("step") == "pruned"]
    assert pruned and "differed only with it" in pruned[0]["why"], d.summary
    assert pruned[0]["dropped"] not in [n["effect"] for n in d.named]
    assert [n["effect"] for n in d.named][:1] == ["power_bias"], d.summary
    assert d.verdict == "explained", d.summary
    assert f"pruned: {pruned[0]['dropped']} (" in report.text(d)


def test_the_same_case_with_the_chance_check_names_the_bias_curve_without_interference() -> None:
    """The same session with the default settings, where every pick must beat what it gives on
    believed re-simulations: the selection on top of the free terms no longer takes interference."""
    sc = load_scenario(SCENARIO)
    spec = next(s for s in blind.plan(40, 8) if s["trial"] == 16)
    rec, _ = blind.make_session(spec, sc, 40.0, 200)
    cands = [c for c in model.candidates(sc) if c.effect in _EFFECTS]
    d = engine.diagnose(
        rec, model.physics_simulator(rec, sc), cands, engine.Config(seed=int(spec["seed"]) % 100_000)
    )
    named = [n["effect"] for n in d.named]
    assert named[:1] == ["power_bias"] and "interference" not in named, d.summary
    assert d.verdict == "explained", d.summary
