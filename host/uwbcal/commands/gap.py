"""`uwbcal gap REAL.db [--scenario S] [--json] [--report DIR]`: diagnose the sim-to-real gap.

Re-simulates the session's own schedule over many seeds with the scenario the simulator
believes in, localises where real and simulated records differ (per observable and regime,
against a sim-vs-sim noise floor, BH-FDR), attributes the gap to catalogue effects the
scenario leaves off or fixes (fitted on training groups, scored on held-out groups, forward
selection, Lasso cross-check) and quantifies the held-out shrink. docs/GAP.md has the method.

`uwbcal gap validate [--trials N] [--seed S] [--json]` runs the diagnosis on simulated
sessions whose cause is known (withheld effect, null, two effects, an out-of-catalogue
perturbation, below-detection magnitudes) and reports accuracy, false alarms and shrink.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path
from typing import Any

from uwbcal.gap.config import Config


def register(sub: Any) -> None:
    """Add the `gap` subcommand."""
    p = sub.add_parser(
        "gap",
        help="diagnose the sim-to-real gap of a session (or: gap validate)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("session", help="session file (.db), or 'validate'")
    p.add_argument(
        "--scenario",
        default=None,
        help="scenario the simulator believes in (file or example name); default: the "
        "session's own scenario if it has one, else two_stations",
    )
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.add_argument("--report", type=Path, default=None, help="directory for report.txt, gap.json and plots")
    p.add_argument(
        "--write-scenario",
        type=Path,
        default=None,
        metavar="FITTED.toml",
        help="write the believed scenario with the named effects at their fitted values "
        "(usable by `uwbcal paper --scenario` and `uwbcal demo --scenario`)",
    )
    p.add_argument(
        "--seeds", type=int, default=Config.n_seeds, help="re-simulations of the schedule (noise floor)"
    )
    p.add_argument(
        "--signature-seeds",
        type=int,
        default=Config.n_seeds_signature,
        help="paired re-simulations per candidate value (its signature)",
    )
    p.add_argument(
        "--ensembles",
        type=int,
        default=4,
        help="whole diagnoses over independent seed blocks, aggregated; the verdict is refused "
        "('unstable') unless 3/4 of them agree (1: one diagnosis, faster)",
    )
    p.add_argument(
        "--blind",
        action="store_true",
        help="validate: trials against independent departure forms (two-way asil-like sessions "
        "through the importer, and sweeps) instead of the catalogue's own effects",
    )
    p.add_argument("--seed", type=int, default=0, help="base seed of re-simulations, bootstraps and trials")
    p.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1), help="worker processes")
    p.add_argument("--alpha", type=float, default=0.01, help="FDR level of the localisation")
    p.add_argument("--trials", type=int, default=40, help="validate: number of trials")
    p.add_argument("--per-step", type=int, default=200, help="validate: triplets per gain step and spacing")
    p.add_argument("--no-progress", "--quiet", dest="quiet", action="store_true",
                   help="no progress on stderr (--quiet is the old name)")
    p.set_defaults(func=run)


def _json_default(o: Any) -> Any:
    import numpy as np

    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)


def _clean(o: Any) -> Any:
    """NaN/inf -> None so the JSON is standard."""
    if isinstance(o, float) and not math.isfinite(o):
        return None
    if isinstance(o, dict):
        return {k: _clean(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_clean(v) for v in o]
    return o


def run(args: argparse.Namespace) -> int:
    """Dispatch to the diagnosis or the validation."""
    say = (lambda m: None) if args.quiet else (lambda m: print(f"gap: {m}", file=sys.stderr, flush=True))
    if args.session == "validate":
        return _validate(args, say)
    return _diagnose(args, say)


def _diagnose(args: argparse.Namespace, say: Any) -> int:
    from uwbcal.errors import SessionError
    from uwbcal.gap import engine, model, report
    from uwbcal.physics.scenario import load_scenario, parse_scenario
    from uwbcal.sessions.store import Session

    with Session.open(args.session, readonly=True) as s:
        meta = s.meta
        real = model.since_power_on(s.read("triplets"), meta)
    if real["seq"].size == 0:
        raise SessionError(f"{args.session}: no triplet records (the gap diagnosis needs triplets)")
    if args.scenario is not None:
        scenario = load_scenario(args.scenario)
        sc_src = args.scenario
    elif isinstance(meta.get("scenario"), str) and meta["scenario"].strip():
        scenario = parse_scenario(meta["scenario"], name="session")
        sc_src = "the session's own scenario"
    else:
        scenario = load_scenario("two_stations")
        sc_src = "two_stations (default; the session has no scenario)"
    say(f"scenario: {sc_src}")
    from uwbcal.corrections.analysis import session_prf_mhz

    prf = session_prf_mhz(meta)  # the diagnosis reads the session's radio (the RX level's A)
    if scenario.radio.prf_mhz != prf:
        say(f"warning: the scenario's radio is PRF {scenario.radio.prf_mhz} MHz, the session's {prf} MHz: "
            "RX level observables of the simulation and the session are not comparable")
    from uwbcal.gap.nnode import believed_world, time_blocks

    cfg = engine.Config(
        n_seeds=args.seeds,
        n_seeds_signature=max(1, args.signature_seeds),
        seed=args.seed,
        jobs=max(1, args.jobs),
        alpha=args.alpha,
        prf_mhz=prf,
        # an N-node session spreads its records over N (N - 1) directions: fewer, longer time blocks
        # where ten would leave a direction's blocks too few records for a feature (gap/nnode.py)
        n_time_blocks=time_blocks(real, engine.Config.min_feature, engine.Config.n_time_blocks),
    )
    if cfg.n_time_blocks != (ten := engine.Config.n_time_blocks):
        say(f"{cfg.n_time_blocks} time blocks (too few records per direction for {ten})")
    if real["seq"].size < cfg.min_cell:
        # too few to test anything: "no significant gap" would be a claim with no test behind it
        raise SessionError(f"{args.session}: {real['seq'].size} triplet record(s); the gap diagnosis "
                           f"needs at least {cfg.min_cell} to test anything")
    # a session with more stations than the scenario: the believed N-station world is built here
    # (the scenario's stations, then stations at the catalogue's hardware with clock offsets fitted
    # to the session's rates; gap/nnode.py), and the report says what was added
    untested = _thin_directions(real, cfg.min_cell, args.session)  # refused before any simulation
    if untested:
        say(f"directions with fewer than {cfg.min_cell} records are not localised: " + ", ".join(untested))
    world = believed_world(real, scenario, prf)
    scenario = world.scenario
    for line in world.describe():
        say(line)
    if world.added:
        sc_src += f" + {len(world.added)} added station{'s' if len(world.added) > 1 else ''}"
    sim = model.physics_simulator(real, scenario)
    from uwbcal.gap.stability import diagnose_stable

    d = diagnose_stable(
        real,
        sim,
        model.candidates(scenario),
        cfg,
        ensembles=max(1, args.ensembles),
        progress=say,
        subsampled=model.subsampled_simulators(real, scenario),
        shapes=model.clock_shapes(real, scenario),
        refine=model.shape_refiner(scenario),
    )
    out = _clean({"session": str(args.session), "scenario": sc_src, **d.to_json()})
    txt = report.text(d, title=f"{args.session} against {sc_src}")
    if untested:
        out["directions_not_localised"] = untested
    if world.added:
        out["stations_added"] = _clean(world.to_json())
        head, _, rest = txt.partition("\n")
        txt = "\n".join([head, *world.describe(), rest])
    if args.report is not None:
        args.report.mkdir(parents=True, exist_ok=True)
        (args.report / "gap.json").write_text(json.dumps(out, indent=1, default=_json_default))
        (args.report / "report.txt").write_text(txt + "\n")
        pngs = report.plots(d, args.report)
        md = report.markdown(d, str(args.session), sc_src, pngs)
        if world.added:  # the stations nobody described, right under the title
            head, _, rest = md.partition("\n")
            md = "\n".join([head, "", *(f"> {x}" for x in world.describe()), rest])
        (args.report / "report.md").write_text(md + "\n")
        for p in [*pngs, args.report / "report.md"]:
            say(f"wrote {p}")
    if args.write_scenario is not None:
        from uwbcal.gap.fitted import fitted_scenario, scenario_toml

        fitted = fitted_scenario(scenario, d.named, name=args.write_scenario.stem)
        header = [
            f"Written by `uwbcal gap {args.session} --write-scenario` (seed {args.seed}, {args.seeds} seeds)",
            f"against {sc_src}: verdict {d.verdict!r}.",
            *world.describe(),
            *(
                f"{n['effect']}: {n['knob']} = {n['fitted']:.6g} {n['unit']} (believed {n['baseline']:.6g})"
                for n in d.named
            ),
        ]
        args.write_scenario.parent.mkdir(parents=True, exist_ok=True)
        args.write_scenario.write_text(scenario_toml(fitted, header), encoding="utf-8")
        say(f"wrote {args.write_scenario}")
        out["fitted_scenario"] = str(args.write_scenario)
    if args.json:
        print(json.dumps(out, indent=1, default=_json_default))
    else:
        print(txt)
    return 0


def _thin_directions(real: dict[str, Any], min_cell: int, session: str) -> list[str]:
    """Directions (``tx->rx``) with fewer than ``min_cell`` records, which the localisation leaves
    out (it compares every direction on its own); SessionError when that is every direction: with
    twelve directions of a four-node run, a short recording can have no cell at all, and "no
    significant gap" would then be a claim with no test behind it."""
    import numpy as np

    from uwbcal.errors import SessionError

    tx, rx = np.asarray(real["tx_station"]), np.asarray(real["rx_station"])
    pairs, counts = np.unique(np.stack([tx, rx], axis=1), axis=0, return_counts=True)
    if pairs.shape[0] < 2:  # one direction: its cells are the whole session's
        return []
    thin = [f"{a}->{b}" for (a, b), n in zip(pairs.tolist(), counts.tolist(), strict=True) if n < min_cell]
    if len(thin) == pairs.shape[0]:
        raise SessionError(
            f"{session}: every one of its {len(thin)} directions has fewer than {min_cell} triplet records "
            f"({int(counts.min())}..{int(counts.max())}); the gap diagnosis localises each direction on its "
            "own, so it would test nothing (a longer recording is needed)"
        )
    return thin


def _validate(args: argparse.Namespace, say: Any) -> int:
    from uwbcal.gap import engine, validate

    cfg = engine.Config(n_seeds=args.seeds, alpha=args.alpha)
    if args.blind:
        return _validate_blind(args, cfg, say)
    res = validate.validate(
        n_trials=args.trials,
        seed=args.seed,
        jobs=max(1, args.jobs),
        per_step=args.per_step,
        cfg=cfg,
        progress=say,
    )
    if args.json:
        print(json.dumps(_clean(res), indent=1, default=_json_default))
        return 0
    f = res["figures"]
    print(f"gap validate: {res['trials']} trials {res['counts']}")
    print(
        f"  top-1 attribution, single-effect trials: {_p(f['top1_single'])} (bar 90%)  "
        f"per effect: {res['per_effect_single']}"
    )
    print(
        f"  no gap on null trials: {_p(f['no_gap_null'])} (bar 95%); "
        f"false alarms {_p(f['false_alarms_null'])}"
    )
    print(f"  unexplained on out-of-catalogue trials: {_p(f['unexplained_outside'])} (bar 100%)")
    print(
        f"  two-effect trials: first named is a withheld one {_p(f['top1_in_two'])}, both named "
        f"{_p(f['both_named_two'])}"
    )
    print(f"  below detection: no gap reported {_p(f['no_gap_below_detection'])}")
    print(
        f"  held-out shrink where named correctly: median {_p(f['shrink_median_correct_single'])}, "
        f"min {_p(f['shrink_min_correct_single'])}, "
        f">= 80% in {_p(f['shrink_ge_80pct_correct_single'])} (bar: all)"
    )
    print(
        "  parameter recovery: median |fitted - true| / |true - believed| = "
        f"{f['param_rel_error_median']:.3g}"
    )
    print(f"  lasso cross-check agrees (correct single trials): {_p(f['lasso_agrees_correct_single'])}")
    _bars_and_misses(
        res["bars"],
        [
            f"{r['trial']} {r['kind']} truth {[t['effect'] for t in r['truths']]} -> "
            f"{r['verdict']} {[n['effect'] for n in r['named']]}"
            for r in res["results"]
            if not r["correct"]
        ],
    )
    return 0


def _bars_and_misses(bars: dict[str, bool], misses: list[str]) -> None:
    """The bars met or not, then one line per wrong trial."""
    for bar, ok in bars.items():
        print(f"  bar {bar}: {'met' if ok else 'NOT MET'}")
    for m in misses:
        print(f"  wrong: trial {m}")


def _validate_blind(args: argparse.Namespace, cfg: Any, say: Any) -> int:
    from uwbcal.gap import blind

    res = blind.validate_blind(
        n_trials=args.trials, seed=args.seed, jobs=max(1, args.jobs), cfg=cfg, progress=say
    )
    if args.json:
        print(json.dumps(_clean(res), indent=1, default=_json_default))
        return 0
    print(f"gap validate --blind: {res['trials']} trials")
    for name, f in [("all", res["figures"])] + list(res["per_form"].items()):
        print(
            f"  [{name}] single right {_p(f['single_right'])} "
            f"(named first {_p(f['single_named_first_right'])}), "
            f"null false alarms {_p(f['null_false_alarms'])}, "
            f"decoys unexplained {_p(f['decoys_unexplained'])}, "
            f"pairs right {_p(f['pairs_right'])}, >=80% shrink only when right "
            f"{_p(f['shrink_ge_80_only_when_right'])} (and on right singles "
            f"{_p(f['shrink_ge_80_when_single_right'])}); {f['counts']}"
        )
    print(f"  per departure (single): {res['per_departure_single']}")
    _bars_and_misses(
        res["bars"],
        [
            f"{r['trial']} {r['form']} {r['kind']} {r['departures']} -> {r['verdict']} {r['named']}"
            for r in res["results"]
            if not r["correct"]
        ],
    )
    return 0


def _p(x: float) -> str:
    return "n/a" if not math.isfinite(x) else f"{100 * x:.0f}%"
