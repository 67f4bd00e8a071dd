"""Shape refinement of the effect named first (model.shape_refiner, engine step "shape refinement")."""

from __future__ import annotations

import pytest
from uwbcal.gap import blind, engine, model, report
from uwbcal.gap.validate import SCENARIO
from uwbcal.physics.scenario import load_scenario

#: Candidates of the end-to-end case: late paths, the noise, the power family and the slow clock
#: effects (the full catalogue runs in tools/bench/bench_gap_blind.py; here it would triple the
#: test's time)
_EFFECTS = ("multipath", "timestamp_noise", "power_bias", "clock_wander", "temperature")


@pytest.mark.parametrize(
    "seed",
    [
        # each reception late with probability 0.25 by a log-normal excess of median 25 cm: named
        # right but "unexplained" with 8 cells still differing before the refinement existed
        229908771,
        # probability 0.24, median 17 cm (blind seed 10, trial 30): a refinement scored by the
        # features' held-out NLL alone moved the excess the wrong way (gamma shape 4 -> 20.8) and
        # left 2 cells (KS shape of the clock rate); scored by the cells still differing, it passes
        2047110907,
        # probability 0.09, median 11 cm (blind seed 16, trial 2): refined to 0 cells, then selected
        # again timestamp noise joined and the clock rate's KS shape read z +4.9; the set the
        # refinement scored passes
        166272249,
    ],
)
def test_late_paths_between_the_catalogues_forms_are_explained_once_their_shape_is_refined(seed: int) -> None:
    """A blind sweep (departures.py: each reception late by a log-normal excess, log-SD 0.6; the
    catalogue's late paths are gamma-distributed, in three fixed sizes)."""
    sc = load_scenario(SCENARIO)
    spec = {"trial": 0, "kind": "single", "form": "sweep", "departures": ["multipath"], "seed": seed}
    rec, _ = blind.make_session(spec, sc, 40.0, 200)
    cands = [c for c in model.candidates(sc) if c.effect in _EFFECTS]
    cfg = engine.Config(seed=seed % 100_000)  # the blind trial's own settings
    d = engine.diagnose(rec, model.physics_simulator(rec, sc), cands, cfg, refine=model.shape_refiner(sc))
    steps = [s for s in d.selection_steps if s.get("step") == "shape refinement"]
    # the refinement ran (the catalogue's forms did not pass), moved the shape, and its explanation
    # is the one kept
    assert steps and steps[0]["to"] != steps[0]["from"], d.summary
    assert [n["effect"] for n in d.named][:1] == ["multipath"], d.summary
    assert d.verdict == "explained", (d.summary, steps)
    shape = dict((k, v) for k, v in d.named[0]["shape"])
    assert shape, "the named late paths keep their refined shape"
    # the text report says what the refinement moved and that its explanation passed
    assert (
        f"shape refinement: {steps[0]['from']} -> {steps[0]['to']} (passes the checks: True)"
        in report.text(d)
    )


def test_heavy_tailed_jitter_is_explained_once_the_noise_tail_is_refined() -> None:
    """The blind generator's jitter is a Student-t (departures.extra_jitter), the catalogue's a
    Gaussian: the refinement moves ``tail_weight`` (1/dof) off 0 and the explanation passes.

    47 ps in a two-way asil-like session (blind seed 24, trial 29): one block's eq. 1 residual
    scale left (z +4.7: 56 records, a few t draws far out). (The sweep of blind seed 25, trial 0,
    a t jitter of 130 ps whose Gaussian left one time block's KS shape of the clock rate at z
    +4.5, passes too, in 1-2 minutes: run by tools/bench/bench_gap_blind.py, not here.)"""
    seed = 832654318
    sc = load_scenario(SCENARIO)
    spec = {"trial": 0, "kind": "single", "form": "two_way", "departures": ["timestamp_noise"], "seed": seed}
    rec, _ = blind.make_session(spec, sc, 40.0, 200)
    cands = [c for c in model.candidates(sc) if c.effect in _EFFECTS]
    cfg = engine.Config(seed=seed % 100_000)
    d = engine.diagnose(rec, model.physics_simulator(rec, sc), cands, cfg, refine=model.shape_refiner(sc))
    steps = [s for s in d.selection_steps if s.get("step") == "shape refinement"]
    assert steps and steps[0]["effect"] == "timestamp_noise", d.summary
    named = [n["effect"] for n in d.named]
    assert d.verdict == "explained" and named[:1] == ["timestamp_noise"], (d.summary, steps)
    shape = dict((k, v) for k, v in d.named[0]["shape"])
    assert shape.get("effect:timestamp_noise:tail_weight", 0.0) > 0.0, (shape, steps)
