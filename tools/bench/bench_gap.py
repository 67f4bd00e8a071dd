"""Benchmark: the gap diagnosis of a 100k-record session (issue 13's goal: under 10 s on 2 cores).

The session is the validation schedule (power sweep of 8 steps, at 2 ms and 0.25 ms spacing)
with 6250 triplets per step and spacing (100 000 records), simulated with the power-bias curve
2.4 times the believed one withheld, and diagnosed against the believed scenario with the
defaults of `uwbcal gap` (64 re-simulations and 12 signature seeds, 2 worker processes, one
ensemble; BENCH_JOBS=1 in
the environment runs it serially, so each stage's wall time is its CPU time; BENCH_SEEDS=K,S
takes K re-simulations and S signature seeds instead, as `--seeds K --signature-seeds S`
would). Prints the wall
time, the CPU time of this process and its workers (user + system: what the diagnosis costs
when the cores are shared), the wall time of each stage (from the diagnosis' progress
messages) and the verdict (the diagnosis must still name the withheld effect at this size).

Figures of 2026-11-25 (2-core machine shared with another job; wall times move with its load,
CPU times much less), docs/GAP.md "Speed": before issue 13's speed work 36-51 s wall and 50-51 s
CPU, after it 12 s wall at load 0.7 (25-27 s at load 3) and 22-26 s CPU (21 s serially), with a
byte-identical diagnosis (then 16 re-simulations and 3 signature seeds). With the final
defaults of issue 13 (64 / 12 seeds, which the real run's stable verdict needs, and interleaved
folds for sweeps): 55 s wall, 98 s CPU, power bias named first at its true value, explained.
The goal of 10 s is not met. Fourth session, with the clock shapes and the shape refiner passed as
`uwbcal gap` passes them: 72 s wall, 126 s CPU, the same verdict.

Fifth session (2026-11-26, docs/GAP.md "Speed at 100k records"; the machine's load average was 2-6
from other jobs, so CPU times are the measure): serially, the code before and after ran side by
side, 186.6 s CPU (338 s wall) before, 125.5 s CPU (276 s wall) after phase 1 (the same diagnosis,
byte for byte); with 2 workers at load 2.4-4.0, 184.5 s wall before, 122.3 s after. Each stage's
CPU time is printed next to its wall time (a worker's CPU counts when its pool closes);
BENCH_JSON=path writes the diagnosis as `uwbcal gap --json` does, to compare runs. Phase 2
(sequential signature seeds for sessions over 25k records, which changes what is computed):
93.8 s CPU against phase 1's 113.0 s side by side (load 1-3), the same verdict, named effects and
fitted values; with 2 workers 94 s wall / 96 s CPU at load 2.2-3.5.

Fourteenth session (2026-11-28, load 1-2, docs/GAP.md "Speed, fourteenth session"): the code before
measured 147.6 s wall / 249 s CPU (the diagnosis had grown since the fifth session); after the fits'
masked sums as one matrix product, the rate fit's profile by projection and one BLAS thread per
process, 91.4 s wall / 159 s CPU, the same verdict, named effects and fitted values (the JSON differs
in 4 floats by at most 4e-15 relative).

Fifteenth session (2026-11-28, load 1-1.4, old and new one after the other): the chance check of
a pick fits a member to the first 8 believed re-simulations and to the other 56 only while it
beats all of those: 97.1 s wall / 169.6 s CPU before, 90.5 s / 156.8 s after; the same decisions
(the JSON differs only in the largest null and count reported for four members set aside).
"""

from __future__ import annotations

import os
import sys
import time


def _cpu_s() -> float:
    """User + system time of this process and its waited-for children, s."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


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
    stages: list[tuple[str, float, float]] = []
    marks = [("setup", time.perf_counter(), _cpu_s())]

    def say(msg: str) -> None:  # a progress message ends the stage before it
        now, cpu_now = time.perf_counter(), _cpu_s()
        stages.append((marks[-1][0], now - marks[-1][1], cpu_now - marks[-1][2]))
        marks.append((msg.split(" (")[0], now, cpu_now))

    cpu0 = _cpu_s()
    t0 = time.perf_counter()
    sim = model.physics_simulator(real, sc)
    sub = model.subsampled_simulators(real, sc)
    jobs = int(os.environ.get("BENCH_JOBS", jobs))
    seeds = os.environ.get("BENCH_SEEDS")  # "K,S": K re-simulations, S signature seeds (default 64,12)
    names = ("n_seeds", "n_seeds_signature")
    k_s = {} if not seeds else dict(zip(names, map(int, seeds.split(",")), strict=True))
    cfg = engine.Config(jobs=jobs, **k_s)
    d = engine.diagnose(  # as `uwbcal gap` calls it (one ensemble)
        real,
        sim,
        model.candidates(sc),
        cfg,
        progress=say,
        subsampled=sub,
        shapes=model.clock_shapes(real, sc),
        refine=model.shape_refiner(sc),
    )
    dt = time.perf_counter() - t0
    say("end")
    cpu = _cpu_s() - cpu0
    named = ", ".join(f"{x['effect']}={x['fitted']:.4g}" for x in d.named) or "-"
    for name, s, c in stages:
        if s >= 0.05:  # a worker's CPU time counts when the pool that ran it is closed
            print(f"  stage {s:5.1f} s (CPU {c:5.1f} s)  {name}")
    out = os.environ.get("BENCH_JSON")
    if out:  # the diagnosis as `uwbcal gap --json` writes it, to compare runs byte for byte
        import json

        from uwbcal.commands.gap import _clean, _json_default

        with open(out, "w") as fh:
            json.dump(_clean(d.to_json()), fh, indent=1, default=_json_default)
    print(
        f"bench gap_100k: {dt:.1f} s (goal < 10 s; CPU {cpu:.1f} s) ({n} records, {jobs} workers, "
        f"verdict {d.verdict}: {named}, held-out shrink {d.shrink['estimate']:.3f})"
    )
    return 0 if n == 100_000 else 1


if __name__ == "__main__":
    sys.exit(main())
