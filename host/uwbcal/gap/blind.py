"""`uwbcal gap validate --blind`: the diagnosis checked against departures it has never seen.

"Reality" is the believed scenario simulated by the project's simulator (a null must be the
believed world) plus departures in forms of their own (:mod:`uwbcal.gap.departures`, written
apart from the physics catalogue). Two session forms, fed in through the paths real data takes:

- ``two_way``: an asil-like drift run between two nodes taking turns (messages every 11.5 ms,
  P1 -> P2 23 or 33.4 ms like the real logger), both directions, written as asil-lab CSV files
  and read back with :func:`uwbcal.importers.asil.load_run` (no RX registers, like a real log);
- ``sweep``: the recorder-style power sweep of :func:`uwbcal.gap.validate.validation_schedule`
  (one direction, RX registers).

Trial kinds: ``single`` (one departure standing for one catalogue effect: right when the verdict
is "explained" and that effect is named first), ``null`` (no departure: right when "no
significant gap"), ``pair`` (two departures: right when the first named is one of them), ``decoy``
(a departure no catalogue effect describes: right when not "explained"). Figures per session
form and overall (:func:`summarise`).
"""

from __future__ import annotations

import math
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Final

import numpy as np

from uwbcal.gap import departures as dep
from uwbcal.gap import engine, model
from uwbcal.physics.scenario import Scenario

#: Catalogue effect each single departure stands for, per session form.
SINGLES: Final[dict[str, tuple[str, ...]]] = {
    "two_way": (
        "warmup",
        "clock_wander",
        "clock_offset",
        "timestamp_noise",
        "timestamp_noise[2]",
        "multipath",
    ),
    "sweep": ("power_bias", "rx_power_estimate", "tx_gain", "timestamp_noise", "multipath", "warmup"),
}
DECOYS: Final[dict[str, tuple[str, ...]]] = {
    "two_way": ("freq_step", "cycle", "jitter_burst"),
    "sweep": ("p3_drift", "freq_step"),
}
FORMS: Final = ("two_way", "sweep")


def two_way_schedule(scenario: Scenario, duration_s: float, rng: np.random.Generator) -> Any:
    """Two nodes taking turns (asil-like): node A's messages 23 or 33.4 ms apart, B 11.5 ms after A."""
    from uwbcal import vectorsim

    a_id, b_id = scenario.station_ids[:2]
    n_msg = int(duration_s / 0.024) // 3 * 3
    gaps = np.where(rng.random(n_msg) < 0.85, 0.023, 0.0334)
    a_t = 1.0 + np.concatenate([[0.0], np.cumsum(gaps[:-1])])
    rows: dict[str, list[Any]] = {k: [] for k in ("seq", "tx", "rx", "t", "sp", "sp23")}
    for tx, rx, times in ((a_id, b_id, a_t), (b_id, a_id, a_t + 0.0115)):
        j = np.arange(n_msg // 3)
        rows["seq"].append(j)
        rows["tx"].append(np.full(j.size, tx))
        rows["rx"].append(np.full(j.size, rx))
        rows["t"].append(times[3 * j])
        rows["sp"].append(times[3 * j + 1] - times[3 * j])
        rows["sp23"].append(times[3 * j + 2] - times[3 * j + 1])
    cat = {k: np.concatenate(v) for k, v in rows.items()}
    order = np.argsort(cat["t"], kind="stable")
    n = order.size
    return vectorsim.TripletSchedule(
        seq=cat["seq"][order].astype(np.int64),
        step=np.zeros(n, np.int64),
        tx_station=cat["tx"][order].astype(np.int64),
        rx_station=cat["rx"][order].astype(np.int64),
        t_s=cat["t"][order],
        spacing_s=cat["sp"][order],
        gain13=np.full(n, vectorsim.DEFAULT_GAIN, np.int64),
        gain2=np.full(n, vectorsim.DEFAULT_GAIN, np.int64),
        distance_m=np.full(n, np.nan),
        spacing23_s=cat["sp23"][order],
    )


def write_asil_csv(rec: dict[str, Any], node_of: dict[int, int], run_dir: Path, distance_m: float) -> None:
    """Records of a two-way session as an asil-lab run directory (one CSV per node + parameters)."""
    from uwbcal.importers.asil import CSV_HEADER_MULTI, TICKS_PER_S

    run_dir.mkdir(parents=True, exist_ok=True)
    tm = dep.message_times(rec)
    per_node: dict[int, list[tuple[float, int, int, int]]] = {n: [] for n in node_of.values()}
    for i in range(np.asarray(rec["seq"]).size):
        tx, rx, j = node_of[int(rec["tx_station"][i])], node_of[int(rec["rx_station"][i])], int(rec["seq"][i])
        for k in range(3):
            mid = 3 * j + k
            per_node[tx].append((float(tm[i, k]), tx, mid, int(rec[f"tx{k + 1}"][i])))
            per_node[rx].append((float(tm[i, k]) + 1e-9, tx, mid, int(rec[f"rx{k + 1}"][i])))
    for node, rows in per_node.items():
        rows.sort()
        lines = [",".join(CSV_HEADER_MULTI)]
        lines += [f"{node},{tx},{mid},{ts},{ts / TICKS_PER_S!r}" for _, tx, mid, ts in rows]
        (run_dir / f"blind-01_ttyACM{node}.csv").write_text("\n".join(lines) + "\n", encoding="ascii")
    nodes = sorted(node_of.values())
    (run_dir / "parameters.yaml").write_text(
        "message_interval: 1.15e-2 # s\nnodes:\n"
        + "".join(f"- {n}\n" for n in nodes)
        + f"node_distance: {distance_m}\n",
        encoding="ascii",
    )


def _draw_departure(
    name: str, form: str, rec: dict[str, Any], rng: np.random.Generator, sids: Sequence[int]
) -> tuple[dict[str, Any], dict[str, Any]]:
    """Apply one named departure with drawn magnitudes: (new records, its description)."""
    t = np.asarray(rec["t_s"], np.float64)
    t_end = float(t.max()) + 1.0
    sign = 1.0 if rng.random() < 0.5 else -1.0
    p: dict[str, Any]
    other = sids[1]
    if name == "warmup":
        p = {
            "a1_ppm": sign * rng.uniform(0.6, 2.5),
            "tau1_s": rng.uniform(8.0, 30.0),
            "a2_ppm": sign * rng.uniform(0.3, 1.5),
            "tau2_s": rng.uniform(60.0, 300.0),
            "t0_s": rng.uniform(0.0, 5.0),
        }
        return dep.clock_departure(rec, other, dep.two_time_constants(**p)), p
    if name == "clock_wander":
        p = {"sigma_ppm": rng.uniform(0.03, 0.1), "taus_s": (15.0, 150.0)}
        fn = dep.wander_ou(rng, p["sigma_ppm"], p["taus_s"], t_end)
        return dep.clock_departure(rec, other, fn), p
    if name == "clock_offset":
        p = {"ppm": sign * rng.uniform(1.5, 5.0)}
        return dep.clock_departure(rec, other, dep.constant(p["ppm"])), p
    if name == "timestamp_noise":
        p = {"scale_ps": rng.uniform(40.0, 150.0)}
        return dep.extra_jitter(rec, rng, p["scale_ps"]), p
    if name.startswith("timestamp_noise["):
        sid = int(name[name.index("[") + 1 : -1])
        p = {"scale_ps": rng.uniform(60.0, 200.0), "rx_station": sid}
        return dep.extra_jitter(rec, rng, p["scale_ps"], rx_station=sid), p
    if name == "multipath":
        p = {"prob": rng.uniform(0.08, 0.35), "median_m": rng.uniform(0.1, 0.5)}
        return dep.late_paths(rec, rng, p["prob"], p["median_m"]), p
    if name == "power_bias":
        lv = dep.reported_level(rec, 2)
        p = {
            "amplitude_m": rng.uniform(0.05, 0.15),
            "centre_dbm": float(np.quantile(lv[np.isfinite(lv)], rng.uniform(0.3, 0.7))),
            "width_db": rng.uniform(4.0, 10.0),
        }
        return dep.level_bias(rec, **p), p
    if name == "rx_power_estimate":
        lv = dep.reported_level(rec, 2)
        p = {
            "knee_dbm": float(np.quantile(lv[np.isfinite(lv)], rng.uniform(0.4, 0.7))),
            "slope": rng.uniform(0.3, 0.7),
        }
        return dep.level_saturation(rec, **p), p
    if name == "tx_gain":
        p = {"sd_db": rng.uniform(0.7, 1.5), "bias_m_per_db": 0.01}
        return dep.step_gain_errors(rec, rng, p["sd_db"], p["bias_m_per_db"]), p
    if name == "freq_step":
        p = {"ppm": sign * rng.uniform(0.3, 1.0), "at_s": float(np.quantile(t, rng.uniform(0.3, 0.7)))}
        return dep.clock_departure(rec, other, dep.freq_step(p["ppm"], p["at_s"])), p
    if name == "cycle":
        p = {
            "amplitude_ppm": rng.uniform(0.3, 1.0),
            "period_s": rng.uniform(8.0, 20.0),
            "phase": rng.uniform(0, 6.28),
        }
        return dep.clock_departure(rec, other, dep.cycle(**p)), p
    if name == "jitter_burst":
        start = float(np.quantile(t, rng.uniform(0.2, 0.6)))
        p = {"scale_ps": rng.uniform(150.0, 300.0), "tx_station": sids[0], "window_s": (start, start + 10.0)}
        return dep.extra_jitter(rec, rng, p["scale_ps"], tx_station=sids[0], window_s=p["window_s"]), p
    if name == "p3_drift":
        p = {"metres_per_s": sign * rng.uniform(0.002, 0.01)}
        return dep.p3_drift(rec, p["metres_per_s"]), p
    raise ValueError(f"unknown departure {name!r}")


def plan(n_trials: int, seed: int) -> list[dict[str, Any]]:
    """Trials: half single, then null, pair and decoy; alternating session forms; shuffled."""
    rng = np.random.default_rng([seed, 1313])
    n_null = max(1, round(0.2 * n_trials))
    n_pair = max(1, round(0.1 * n_trials))
    n_decoy = max(1, round(0.15 * n_trials))
    n_single = max(1, n_trials - n_null - n_pair - n_decoy)
    kinds = ["single"] * n_single + ["null"] * n_null + ["pair"] * n_pair + ["decoy"] * n_decoy
    out = []
    counters: dict[tuple[str, str], int] = {}
    for i, kind in enumerate(kinds[:n_trials]):
        form = FORMS[i % 2]
        c = counters.get((kind, form), 0)
        counters[(kind, form)] = c + 1
        if kind == "single":
            names = [SINGLES[form][c % len(SINGLES[form])]]
        elif kind == "pair":
            pick = rng.choice(len(SINGLES[form]), 2, replace=False)
            names = [SINGLES[form][int(j)] for j in pick]
            if "timestamp_noise" in names and any(n.startswith("timestamp_noise[") for n in names):
                names = [SINGLES[form][0], SINGLES[form][2]]
        elif kind == "decoy":
            names = [DECOYS[form][c % len(DECOYS[form])]]
        else:
            names = []
        out.append({"kind": kind, "form": form, "departures": names, "seed": int(rng.integers(0, 2**31 - 1))})
    order = rng.permutation(len(out))
    return [{"trial": i, **out[j]} for i, j in enumerate(order)]


def make_session(
    spec: dict[str, Any], scenario: Scenario, duration_s: float, per_step: int
) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """The trial's "real" records (through the asil importer for two_way) and the departures drawn."""
    from uwbcal import vectorsim
    from uwbcal.gap import validate
    from uwbcal.importers import asil
    from uwbcal.physics.world import World

    rng = np.random.default_rng([spec["seed"], 9])
    form = spec["form"]
    sched = (
        two_way_schedule(scenario, duration_s, rng)
        if form == "two_way"
        else validate.validation_schedule(scenario, per_step=per_step)
    )
    world_sc = scenario
    if form == "two_way":  # a DW1000 counter reads 0 at power-on: the asil log's time base says when
        for sid in scenario.station_ids:
            world_sc = world_sc.with_station(sid, counter_offset_units=0)
    sim_rec, _ = vectorsim.run_triplets(World(world_sc, 20_000_000 + spec["seed"] % 1_000_000), sched)
    rec: dict[str, Any] = dict(sim_rec)
    drawn = []
    sids = scenario.station_ids[:2]
    for name in spec["departures"]:
        rec, params = _draw_departure(name, form, rec, rng, sids)
        drawn.append({"departure": name, **{k: v for k, v in params.items()}})
    if form == "two_way":
        node_of = {sids[0]: 0, sids[1]: 1}
        with tempfile.TemporaryDirectory() as tmp:
            run = Path(tmp) / "run"
            write_asil_csv(rec, node_of, run, scenario.distance_m(sids[0], sids[1]))
            imp = asil.load_run(run)
            rec = model.since_power_on(imp.triplets, imp.meta)
    return rec, drawn


def run_trial(
    spec: dict[str, Any], scenario: Scenario, cfg: engine.Config, duration_s: float, per_step: int
) -> dict[str, Any]:
    """One blind trial: make the session, diagnose it with the believed scenario, score."""
    rec, drawn = make_session(spec, scenario, duration_s, per_step)
    c = engine.Config(**{**cfg.__dict__, "seed": int(spec["seed"]) % 100_000, "jobs": 1})
    d = engine.diagnose(
        rec,
        model.physics_simulator(rec, scenario),
        model.candidates(scenario),
        c,
        subsampled=model.subsampled_simulators(rec, scenario),
        shapes=model.clock_shapes(rec, scenario),
        refine=model.shape_refiner(scenario),
    )
    named = [n["effect"] for n in d.named]
    truth = list(spec["departures"])
    kind = spec["kind"]
    first_right = bool(named) and named[0] in truth
    if kind == "null":
        correct = d.verdict == "no significant gap"
    elif kind == "single":
        correct = d.verdict == "explained" and first_right
    elif kind == "pair":
        correct = d.verdict == "explained" and first_right
    else:
        correct = d.verdict != "explained"
    return {
        **spec,
        "drawn": drawn,
        "verdict": d.verdict,
        "named": named,
        "named_first_right": first_right,
        "correct": bool(correct),
        "shrink": d.shrink.get("estimate"),
        "shrink_by_aspect": d.shrink_aspects,
        "criticism_failed": d.criticism_failed,
        "cells_still_differing": len(d.remaining),
        "summary": d.summary,
        "records": int(np.asarray(rec["seq"]).size),
    }


_BL: dict[str, Any] = {}


def _job(spec: dict[str, Any]) -> dict[str, Any]:
    return run_trial(spec, _BL["scenario"], _BL["cfg"], _BL["duration_s"], _BL["per_step"])


def validate_blind(
    n_trials: int = 40,
    seed: int = 0,
    jobs: int = 2,
    cfg: engine.Config | None = None,
    duration_s: float = 40.0,
    per_step: int = 200,
    progress: Callable[[str], None] | None = None,
    on_result: Callable[[dict[str, Any]], None] | None = None,
) -> dict[str, Any]:
    """Run the blind trials (``jobs`` processes) and summarise per session form.

    ``on_result`` gets each trial's result as it finishes (in finishing order), so a caller can
    keep what was measured if a long run is stopped."""
    from uwbcal.gap.validate import SCENARIO
    from uwbcal.physics.scenario import load_scenario

    say = progress or (lambda _m: None)
    specs = plan(n_trials, seed)
    _BL.update(
        scenario=load_scenario(SCENARIO), cfg=cfg or engine.Config(), duration_s=duration_s, per_step=per_step
    )
    results: list[dict[str, Any]] = []

    def note(r: dict[str, Any]) -> None:
        results.append(r)
        shrink = f"{100 * r['shrink']:.0f}%" if _finite(r["shrink"]) else "n/a"
        say(
            f"blind trial {len(results)}/{len(specs)} {r['form']} {r['kind']} {r['departures']}: "
            f"{r['verdict']} {r['named'][:3]} shrink {shrink} ({'right' if r['correct'] else 'WRONG'})"
        )
        if on_result is not None:
            on_result(r)

    if jobs > 1 and len(specs) > 1:
        import multiprocessing as mp

        with mp.get_context("fork").Pool(jobs) as pool:
            for r in pool.imap_unordered(_job, specs):
                note(r)
    else:
        for sp in specs:
            note(_job(sp))
    results.sort(key=lambda r: r["trial"])
    return summarise(results)


def _frac(xs: Sequence[bool]) -> float:
    return float(np.mean(xs)) if len(xs) else float("nan")


def _figures(rs: Sequence[dict[str, Any]]) -> dict[str, Any]:
    by = {k: [r for r in rs if r["kind"] == k] for k in ("single", "null", "pair", "decoy")}
    high = [
        r
        for r in rs
        if r["kind"] in ("single", "pair", "decoy") and _finite(r["shrink"]) and r["shrink"] >= 0.8
    ]
    return {
        "single_right": _frac([r["correct"] for r in by["single"]]),
        "single_named_first_right": _frac([r["named_first_right"] for r in by["single"]]),
        "null_false_alarms": _frac([not r["correct"] for r in by["null"]]),
        "decoys_unexplained": _frac([r["correct"] for r in by["decoy"]]),
        "pairs_right": _frac([r["correct"] for r in by["pair"]]),
        "shrink_ge_80_only_when_right": _frac(
            [r["kind"] != "decoy" and r["named_first_right"] for r in high]
        ),
        # the other side: a shrink that is never high would pass the bar above trivially
        "shrink_ge_80_when_single_right": _frac(
            [_finite(r["shrink"]) and r["shrink"] >= 0.8 for r in by["single"] if r["correct"]]
        ),
        "counts": {k: len(v) for k, v in by.items()},
    }


def _finite(x: Any) -> bool:
    return x is not None and isinstance(x, float) and math.isfinite(x)


def summarise(results: list[dict[str, Any]]) -> dict[str, Any]:
    """Figures overall and per session form, and the issue-13 bars on the overall figures."""
    overall = _figures(results)
    per_form = {f: _figures([r for r in results if r["form"] == f]) for f in FORMS}
    per_departure: dict[str, list[int]] = {}
    for r in results:
        if r["kind"] == "single":
            k = f"{r['form']}:{r['departures'][0]}"
            per_departure.setdefault(k, [0, 0])
            per_departure[k][0] += int(r["correct"])
            per_departure[k][1] += 1
    bars = {
        "single right >= 90%": overall["single_right"] >= 0.9,
        "null false alarms <= 5%": overall["null_false_alarms"] <= 0.05,
        "every decoy unexplained": overall["decoys_unexplained"] == 1.0,
        ">= 80% shrink only when the right effect is named": overall["shrink_ge_80_only_when_right"] == 1.0,
    }
    return {
        "trials": len(results),
        "figures": overall,
        "per_form": per_form,
        "per_departure_single": {k: f"{v[0]}/{v[1]}" for k, v in sorted(per_departure.items())},
        "bars": bars,
        "results": results,
    }
