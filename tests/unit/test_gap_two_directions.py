"""Two-direction sessions: the localisation compares like with like (issue 13, cause 1).

The project's own simulator plays "real" on the schedule of a real two-node asil run (both
directions, clock rates near +x and -x ppm). Before the fix, cells that pooled both directions
were compared with a pool of K seeds while their floor came from pools of K - 1, and such cells
scored |z| of 5..18 on pure simulator output: a false alarm on every seed tried.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from uwbcal.gap import engine, model
from uwbcal.importers import asil
from uwbcal.physics.scenario import load_scenario

SAMPLE = Path(__file__).resolve().parents[1] / "data" / "asil" / "run"


@pytest.mark.parametrize("seed", [0, 1])
def test_simulator_as_real_two_directions_no_false_alarm(seed: int) -> None:
    real0 = dict(asil.load_run(SAMPLE).triplets)
    sc = load_scenario("two_stations")
    sim = model.physics_simulator(real0, sc)
    fake = {**real0, **sim((), 900_000 + seed)}
    cfg = engine.Config(n_seeds=12, n_seeds_signature=2, n_boot=500, seed=seed)
    d = engine.diagnose(fake, model.physics_simulator(fake, sc), model.candidates(sc), cfg)
    assert d.verdict == "no significant gap", [(c.observable, c.label, c.z) for c in d.significant]
    # no cell pools the two directions: every non-direction cell names its direction
    assert d.cells and all(c.direction >= 0 for c in d.cells if c.regime != "direction")
    assert {c.label for c in d.cells if c.regime == "direction"} == {"0->1", "1->0"}


def test_since_power_on_uses_the_logged_start() -> None:
    imp = asil.load_run(SAMPLE)
    start = imp.meta["timestamps"]["session_start_since_counter_zero_s"]
    moved = model.since_power_on(imp.triplets, imp.meta)
    assert 1.0 < start < 60.0
    assert abs(float(moved["t_s"][0]) - float(imp.triplets["t_s"][0]) - start) < 1e-12
    assert model.since_power_on(imp.triplets, {})["t_s"] is imp.triplets["t_s"]
