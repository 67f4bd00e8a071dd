"""The gap diagnosis end to end on simulated sessions with a known withheld effect."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from uwbcal.gap import engine, model, validate
from uwbcal.physics.scenario import load_scenario
from uwbcal.physics.world import World

CFG = engine.Config(n_seeds=12, n_seeds_signature=2, n_boot=600, seed=3)


def _real(variant: model.Variant, seed: int, per_step: int = 120) -> tuple[dict[str, np.ndarray], object]:
    from uwbcal import vectorsim

    sc = load_scenario(validate.SCENARIO)
    sched = validate.validation_schedule(sc, per_step=per_step)
    rec, _ = vectorsim.run_triplets(World(model.apply_variant(sc, variant), seed), sched)
    return rec, sc


@pytest.mark.parametrize("effect,value", [("interference", 800.0), ("power_bias", 2.4)])
def test_withheld_effect_is_named_and_closes_the_gap(effect: str, value: float) -> None:
    sc = load_scenario(validate.SCENARIO)
    cand = {c.effect: c for c in model.candidates(sc)}[effect]
    true = value if effect != "power_bias" else cand.baseline * value
    real, _ = _real(((cand.knob, true),), seed=4242)
    d = engine.diagnose(real, model.physics_simulator(real, sc), model.candidates(sc), CFG)
    assert d.verdict == "explained"
    assert d.named[0]["effect"] == effect
    assert abs(d.named[0]["fitted"] - true) < 0.15 * abs(true - cand.baseline)
    assert d.shrink["estimate"] >= 0.8
    assert any(c.observable == "drift_residual_m" for c in d.significant)


def test_null_session_has_no_gap() -> None:
    real, sc = _real((), seed=777)
    d = engine.diagnose(real, model.physics_simulator(real, sc), model.candidates(sc), CFG)  # type: ignore[arg-type]
    assert d.verdict == "no significant gap"
    assert d.named == [] and d.significant == []
    assert all(min(c.q) >= CFG.alpha for c in d.cells) and len(d.cells) > 20


def test_out_of_catalogue_perturbation_only_moves_p2() -> None:
    real, _ = _real((), seed=5, per_step=40)
    pert = validate.p2_sinusoid(real, amplitude_units=6.0, period_s=10.0)
    for k in ("rx1", "rx3", "tx1", "tx2", "tx3"):
        np.testing.assert_array_equal(pert[k], real[k])
    shift = (np.asarray(pert["rx2"]) - np.asarray(real["rx2"])) % (1 << 40)
    shift = np.where(shift > 1 << 39, shift - (1 << 40), shift)
    assert shift.max() == 6 and shift.min() == -6


def test_small_validate_run(tmp_path: Path) -> None:
    res = validate.validate(
        n_trials=5,
        seed=11,
        jobs=1,
        per_step=100,
        cfg=engine.Config(n_seeds=10, n_seeds_signature=2, n_boot=500),
    )
    assert res["trials"] == 5 and sum(res["counts"].values()) == 5
    assert {"single", "null", "two", "outside", "below"} == set(res["counts"])
    for r in res["results"]:
        if r["kind"] == "null":
            assert r["correct"], r["summary"]
        if r["kind"] == "single":
            assert r["correct"], (r["truths"], r["summary"])
    json.dumps(res, default=str)


def test_gap_command_on_a_simulated_session(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from uwbcal import vectorsim
    from uwbcal.cli import main

    sc = load_scenario(validate.SCENARIO)
    sched = validate.validation_schedule(sc, per_step=80)
    db = tmp_path / "s.db"
    vectorsim.simulate_session(
        model.apply_variant(sc, (("effect:interference:amplitude_ps", 900.0),)), sched, db, seed=31337
    )
    rc = main(
        [
            "gap",
            str(db),
            "--scenario",
            validate.SCENARIO,
            "--seeds",
            "10",
            "--jobs",
            "1",
            "--ensembles",
            "2",
            "--json",
            "--quiet",
            "--report",
            str(tmp_path / "rep"),
            "--write-scenario",
            str(tmp_path / "fitted.toml"),
        ]
    )
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    assert out["verdict"] == "explained" and out["named_effects"][0]["effect"] == "interference"
    assert out["settings"]["stability"]["ensembles"] == 2 and out["settings"]["stability"]["stable"]
    assert (tmp_path / "rep" / "gap_localisation.png").stat().st_size > 1000
    assert (tmp_path / "rep" / "report.txt").read_text().startswith("gap diagnosis")
    md = (tmp_path / "rep" / "report.md").read_text()
    assert "interference amplitude" in md.split("## Details")[0]
    assert "![gap_localisation](gap_localisation.png)" in md
    # the fitted scenario: the believed one with interference at its fitted amplitude, readable again
    fitted = load_scenario(tmp_path / "fitted.toml")
    amp = fitted.effect("interference").values()["amplitude_ps"]
    assert fitted.enabled("interference") and abs(amp - out["named_effects"][0]["fitted"]) < 1e-6
    assert abs(amp - 900.0) < 0.25 * (900.0 - 40.0)
    assert fitted.station_ids == sc.station_ids
