"""`uwbcal gap validate`: the diagnosis checked on data whose cause is known (withheld).

Each trial draws what the "real" world has that the believed scenario lacks, simulates the
"real" session with it (a seed the diagnosis never uses), and diagnoses that session with the
believed scenario. Trial kinds:

- ``single``: one catalogue effect at a detectable magnitude (drawn uniformly from its range
  in :data:`TRUTHS`); right when the verdict is "explained" and the first named effect is it.
- ``null``: nothing withheld; right when the verdict is "no significant gap".
- ``two``: two catalogue effects; right when the first named effect is one of them (both
  named is reported as well).
- ``outside``: :func:`p2_sinusoid`, a perturbation that is NOT part of the physics catalogue
  (defined here only for validation); right when the verdict is "unexplained".
- ``below``: one catalogue effect at a magnitude well below detection; reported (no bar).

The session is a power sweep (8 steps of 3 dB on P2) played twice, at 2 ms and at 0.25 ms
spacing, between the believed scenario's first two stations: every effect with a signature in
triplet records (clock, timestamps, power, carrier integrator, interference, multipath) can
show. Effects with no signature in triplet records are not drawn: antenna delays (a constant,
cancels in every triplet difference), the 40-bit wrap and the 512-unit TX grid (differences are
taken modulo 2**40, TX stamps are the real emission grid), quantisation (below the noise).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Final

import numpy as np

from uwbcal.gap import engine, model
from uwbcal.physics.scenario import Scenario

#: Validation scenario: the repo's two-station example.
SCENARIO: Final = "two_stations"


@dataclass(frozen=True)
class Truth:
    """A withheld effect for validation: its knob and the range of magnitudes drawn.

    ``kind`` "abs" (the value drawn uniformly in [lo, hi]), "add" (believed + a value drawn in
    +-[lo, hi], random sign), "mul" (believed * a value in [lo, hi]). ``below`` is the
    below-detection magnitude, in the same kind.
    """

    effect: str
    kind: str
    lo: float
    hi: float
    below: float


#: Effects drawn by the validation and their detectable ranges.
TRUTHS: Final[tuple[Truth, ...]] = (
    Truth("timestamp_noise", "abs", 40.0, 150.0, 7.0),
    Truth("clock_wander", "abs", 4e-3, 1.2e-2, 3e-4),
    Truth("warmup", "add", 0.6, 2.5, 0.001),
    Truth("interference", "abs", 250.0, 1200.0, 45.0),
    Truth("power_bias", "mul", 1.8, 2.8, 1.03),
    Truth("rx_power_estimate", "add", 4.0, 9.0, 0.1),
    Truth("car_int_error", "abs", 0.05, 0.11, 0.021),
    Truth("multipath", "abs", 0.08, 0.35, 0.021),
    Truth("clock_offset", "add", 1.5, 5.0, 0.002),
)


def validation_schedule(scenario: Scenario, per_step: int = 200, steps: int = 8) -> Any:
    """The validation session's schedule (see the module docstring)."""
    from uwbcal import vectorsim

    a = vectorsim.power_schedule(
        scenario, steps=steps, per_step=per_step, step_db=3.0, spacing_s=2e-3, period_s=0.02, start_s=1.0
    )
    t_end = float(a.t_s[-1]) + 0.5
    b = vectorsim.power_schedule(
        scenario, steps=steps, per_step=per_step, step_db=3.0, spacing_s=2.5e-4, period_s=0.02, start_s=t_end
    )
    d = {k: np.concatenate([getattr(a, k), getattr(b, k)]) for k in a.as_dict()}
    d["seq"] = np.arange(d["seq"].size, dtype=np.int64)
    return vectorsim.TripletSchedule(**d)


def p2_sinusoid(rec: dict[str, Any], amplitude_units: float, period_s: float) -> dict[str, Any]:
    """NOT A CATALOGUE EFFECT (validation only): P2's RX stamp moves by A sin(2 pi t / T) units.

    A slow periodic delay on one message of the three (as a temperature-cycled path inside one
    receiver channel could cause); the physics catalogue has nothing periodic that acts on P2
    alone, so the diagnosis must call the gap it makes unexplained.
    """
    out = dict(rec)
    t = np.asarray(rec["t_s"], np.float64)
    shift = np.rint(amplitude_units * np.sin(2 * np.pi * t / period_s)).astype(np.int64)
    rx2 = np.asarray(rec["rx2"], np.int64) + shift
    out["rx2"] = rx2 % (1 << 40) if np.all(np.asarray(rec["rx2"]) < (1 << 40)) else rx2
    return out


def _draw(
    truth: Truth, scenario: Scenario, rng: np.random.Generator, below: bool
) -> tuple[str, float, float]:
    """(knob, true value, believed value) of one drawn truth."""
    cands = {c.effect: c for c in model.candidates(scenario)}
    c = cands[truth.effect]
    base = c.baseline
    if truth.kind == "abs":
        v = truth.below if below else float(rng.uniform(truth.lo, truth.hi))
    elif truth.kind == "add":
        mag = truth.below if below else float(rng.uniform(truth.lo, truth.hi))
        v = base + mag * (1.0 if rng.random() < 0.5 else -1.0)
    else:
        ref = base if base != 0 else 1.0
        v = ref * (truth.below if below else float(rng.uniform(truth.lo, truth.hi)))
    return c.knob, v, base


def plan(n_trials: int, seed: int) -> list[dict[str, Any]]:
    """The trial list: kinds in fixed proportions (half single, the rest split), shuffled."""
    rng = np.random.default_rng([seed, 77])
    n_null = max(1, round(0.15 * n_trials))
    n_two = max(1, round(0.1 * n_trials))
    n_out = max(1, round(0.1 * n_trials))
    n_below = max(1, round(0.1 * n_trials))
    n_single = max(1, n_trials - n_null - n_two - n_out - n_below)
    kinds = (
        ["single"] * n_single
        + ["null"] * n_null
        + ["two"] * n_two
        + ["outside"] * n_out
        + ["below"] * n_below
    )
    kinds = kinds[: max(n_trials, 1)]
    out = []
    order = rng.permutation(len(kinds))
    for i, j in enumerate(order):
        out.append({"trial": i, "kind": kinds[j], "seed": int(rng.integers(0, 2**31 - 1))})
    return out


def run_trial(spec: dict[str, Any], scenario: Scenario, cfg: engine.Config, per_step: int) -> dict[str, Any]:
    """One trial: draw, simulate "real", diagnose, score."""
    from uwbcal import vectorsim
    from uwbcal.physics.world import World

    rng = np.random.default_rng([spec["seed"], 5])
    kind = spec["kind"]
    sched = validation_schedule(scenario, per_step=per_step)
    truths: list[dict[str, Any]] = []
    variant: list[tuple[str, float]] = []
    pool = list(TRUTHS)
    if kind in ("single", "below", "two"):
        picks = rng.choice(len(pool), size=2 if kind == "two" else 1, replace=False)
        for p in picks:
            t = pool[int(p)]
            knob, v, base = _draw(t, scenario, rng, below=(kind == "below"))
            variant.append((knob, v))
            truths.append({"effect": t.effect, "knob": knob, "true": v, "believed": base})
    real_seed = 10_000_000 + int(spec["seed"]) % 1_000_000
    real, _ = vectorsim.run_triplets(World(model.apply_variant(scenario, tuple(variant)), real_seed), sched)
    if kind == "outside":
        amp = float(rng.uniform(3.0, 8.0))
        period = float(rng.uniform(0.3, 0.5)) * float(np.ptp(sched.t_s))
        real = p2_sinusoid(real, amp, period)
        truths.append(
            {
                "effect": "p2_sinusoid (not in the catalogue)",
                "knob": "amplitude_units",
                "true": amp,
                "believed": 0.0,
                "period_s": period,
            }
        )
    sim = model.physics_simulator(real, scenario)
    c = engine.Config(**{**cfg.__dict__, "seed": int(spec["seed"]) % 100_000, "jobs": 1})
    d = engine.diagnose(real, sim, model.candidates(scenario), c)
    named = [n["effect"] for n in d.named]
    truth_effects = [t["effect"] for t in truths]
    if kind == "null":
        correct = d.verdict == "no significant gap"
    elif kind == "single":
        correct = d.verdict == "explained" and bool(named) and named[0] == truth_effects[0]
    elif kind == "two":
        correct = d.verdict == "explained" and bool(named) and named[0] in truth_effects
    elif kind == "outside":
        correct = d.verdict == "unexplained"
    else:
        correct = d.verdict == "no significant gap"
    recovery = []
    for tr in truths:
        for n in d.named:
            if n["effect"] == tr["effect"] and tr["true"] != tr["believed"]:
                recovery.append(
                    {
                        "effect": tr["effect"],
                        "true": tr["true"],
                        "fitted": n["fitted"],
                        "relative_error": abs(n["fitted"] - tr["true"]) / abs(tr["true"] - tr["believed"]),
                    }
                )
    return {
        **spec,
        "truths": truths,
        "verdict": d.verdict,
        "named": d.named,
        "correct": bool(correct),
        "both_named": kind == "two" and all(e in named for e in truth_effects),
        "shrink": d.shrink.get("estimate"),
        "shrink_ci": [d.shrink.get("ci_low"), d.shrink.get("ci_high")],
        "blackbox_shrink": d.blackbox_shrink.get("estimate"),
        "lasso_agrees": d.lasso_agrees,
        "n_significant": len(d.significant),
        "recovery": recovery,
        "summary": d.summary,
    }


_VAL: dict[str, Any] = {}


def _trial_job(spec: dict[str, Any]) -> dict[str, Any]:
    return run_trial(spec, _VAL["scenario"], _VAL["cfg"], _VAL["per_step"])


def validate(
    n_trials: int = 40,
    seed: int = 0,
    jobs: int = 2,
    per_step: int = 200,
    cfg: engine.Config | None = None,
    scenario: Scenario | None = None,
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Run the trials (in ``jobs`` processes) and summarise them against the bars."""
    from uwbcal.physics.scenario import load_scenario

    say = progress or (lambda _m: None)
    sc = scenario or load_scenario(SCENARIO)
    cfg = cfg or engine.Config()
    specs = plan(n_trials, seed)
    _VAL.update(scenario=sc, cfg=cfg, per_step=per_step)
    results: list[dict[str, Any]] = []
    if jobs > 1 and len(specs) > 1:
        import multiprocessing as mp

        with mp.get_context("fork").Pool(jobs) as pool:
            for res in pool.imap(_trial_job, specs):
                results.append(res)
                say(
                    f"trial {res['trial'] + 1}/{len(specs)} {res['kind']}: {res['verdict']} "
                    f"({'right' if res['correct'] else 'WRONG'})"
                )
    else:
        for sp in specs:
            res = _trial_job(sp)
            results.append(res)
            say(
                f"trial {res['trial'] + 1}/{len(specs)} {res['kind']}: {res['verdict']} "
                f"({'right' if res['correct'] else 'WRONG'})"
            )
    return summarise(results)


def _frac(xs: Sequence[bool]) -> float:
    return float(np.mean(xs)) if len(xs) else float("nan")


def summarise(results: list[dict[str, Any]]) -> dict[str, Any]:
    """Figures and bars of a list of trial results."""
    by = {k: [r for r in results if r["kind"] == k] for k in ("single", "null", "two", "outside", "below")}
    single_ok = [r for r in by["single"] if r["correct"]]
    shrinks = [
        float(r["shrink"]) for r in single_ok if r["shrink"] is not None and math.isfinite(r["shrink"])
    ]
    rel = [x["relative_error"] for r in single_ok for x in r["recovery"]]
    per_effect: dict[str, list[int]] = {}
    for r in by["single"]:
        e = r["truths"][0]["effect"]
        per_effect.setdefault(e, [0, 0])
        per_effect[e][0] += int(r["correct"])
        per_effect[e][1] += 1
    figures = {
        "top1_single": _frac([r["correct"] for r in by["single"]]),
        "no_gap_null": _frac([r["correct"] for r in by["null"]]),
        "false_alarms_null": _frac([not r["correct"] for r in by["null"]]),
        "unexplained_outside": _frac([r["correct"] for r in by["outside"]]),
        "top1_in_two": _frac([r["correct"] for r in by["two"]]),
        "both_named_two": _frac([r["both_named"] for r in by["two"]]),
        "no_gap_below_detection": _frac([r["correct"] for r in by["below"]]),
        "shrink_median_correct_single": float(np.median(shrinks)) if shrinks else float("nan"),
        "shrink_min_correct_single": float(np.min(shrinks)) if shrinks else float("nan"),
        "shrink_ge_80pct_correct_single": _frac([s >= 0.8 for s in shrinks]),
        "param_rel_error_median": float(np.median(rel)) if rel else float("nan"),
        "lasso_agrees_correct_single": _frac([bool(r["lasso_agrees"]) for r in single_ok]),
    }
    bars = {
        "top1_single >= 0.90": figures["top1_single"] >= 0.90,
        "no_gap_null >= 0.95": figures["no_gap_null"] >= 0.95,
        "unexplained_outside == 1": figures["unexplained_outside"] == 1.0,
        "shrink >= 0.80 on every correct single trial": figures["shrink_ge_80pct_correct_single"] == 1.0,
    }
    return {
        "trials": len(results),
        "counts": {k: len(v) for k, v in by.items()},
        "figures": figures,
        "bars": bars,
        "per_effect_single": {k: f"{v[0]}/{v[1]}" for k, v in sorted(per_effect.items())},
        "results": results,
    }
