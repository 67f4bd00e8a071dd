"""Benchmark: the gap diagnosis of a 100k-record session (bar: under 60 s on 2 cores).

The session is the validation schedule (power sweep of 8 steps, at 2 ms and 0.25 ms spacing)
with 6250 triplets per step and spacing (100 000 records), simulated with the power-bias curve
2.4 times the believed one withheld, and diagnosed against the believed scenario with the
defaults of `uwbcal gap` (16 re-simulations, 2 worker processes). Prints the wall time and the
verdict (the diagnosis must still name the withheld effect at this size).
"""

from __future__ import annotations

import os
import sys
import time


def main() -> int:
    from uwbcal import vectorsim
    from uwbcal.gap import engine, model, validate
    from uwbcal.physics.scenario import load_scenario
    from uwbcal.physics.world import World

    sc = load_scenario(validate.SCENARIO)
    sched = validate.validation_schedule(sc, per_step=6250)
    knob = next(c for c in model.candidates(sc) if c.effect == "power_bias")
    world = World(model.apply_variant(sc, ((knob.knob, 2.4 * knob.baseline),)), 99)
    real, _ = vectorsim.run_triplets(world, sched)
    n = len(real["seq"])
    jobs = min(2, os.cpu_count() or 1)
    t0 = time.perf_counter()
    sim = model.physics_simulator(real, sc)
    sub = model.subsampled_simulators(real, sc)
    d = engine.diagnose(real, sim, model.candidates(sc), engine.Config(jobs=jobs), subsampled=sub)
    dt = time.perf_counter() - t0
    named = ", ".join(f"{x['effect']}={x['fitted']:.4g}" for x in d.named) or "-"
    print(
        f"bench gap_100k: {dt:.1f} s (bar < 60 s) ({n} records, {jobs} workers, "
        f"verdict {d.verdict}: {named}, held-out shrink {d.shrink['estimate']:.3f})"
    )
    return 0 if n == 100_000 else 1


if __name__ == "__main__":
    sys.exit(main())
