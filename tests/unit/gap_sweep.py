"""One power sweep of the validation scenario, simulated (vectorsim) for the gap tests that need
records with every register column (levels through CIR_PWR and RXPACC, steps, receivers)."""

from __future__ import annotations

from typing import Any


def sweep(seed: int, per_step: int) -> dict[str, Any]:
    """The validation schedule's sweep (``per_step`` triplets per power step) at world ``seed``."""
    from uwbcal import vectorsim
    from uwbcal.gap import validate
    from uwbcal.physics.scenario import load_scenario
    from uwbcal.physics.world import World

    sc = load_scenario(validate.SCENARIO)
    rec, _ = vectorsim.run_triplets(World(sc, seed), validate.validation_schedule(sc, per_step=per_step))
    return dict(rec)
