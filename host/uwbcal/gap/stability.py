"""A verdict that is a property of the data, not of ``--seed``: the diagnosis over several seed
ensembles, aggregated.

Each ensemble is one whole diagnosis with its own block of run seeds (``cfg.seed + 7919 e``,
e = 0..E-1; within an ensemble every variant shares the same seeds: common random numbers).
The aggregate verdict is the verdict most ensembles reach; the named effects are those named by
at least half of the ensembles (a small extra effect that one ensemble adds is dropped), with the
median of their fitted values. The verdict is called only when at least ``min_share`` of the
ensembles agree on it (and, for "explained", on the first named effect too); otherwise it is
refused: "unstable", with the shares reported. The representative diagnosis (details, plots,
shrink) is the ensemble whose named effects are closest to the majority's.

Before the vote, the ensembles that name the same effects decide together which cells still
differ with them (:func:`pool_residual_cells`): one test on all their run seeds (E x K) instead
of E tests on K each, so a cell whose departure sits near the FDR level is not counted by some
ensembles and not by others (the second real asil run, 2026-01-15-01, split 15 to 17 over such a
cell). The other reasons for "unexplained" (too little shrink, a failed time-shape check, an
ambiguous effect) stay each ensemble's own.
"""

from __future__ import annotations

import dataclasses
from collections import Counter
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from uwbcal.gap.attribute import Candidate
from uwbcal.gap.config import Config, Records, Simulator
from uwbcal.gap.engine import Diagnosis, Refine, Shapes, diagnose, verdict_of
from uwbcal.gap.localise import pooled, still_open

#: Seed stride between ensembles (a prime, so the seed blocks of nearby --seed values never meet).
STRIDE = 7919


def diagnose_stable(
    real: Records,
    simulate: Simulator,
    candidates: Sequence[Candidate],
    cfg: Config,
    ensembles: int = 4,
    min_share: float = 0.75,
    progress: Callable[[str], None] | None = None,
    subsampled: Callable[[int], Simulator] | None = None,
    shapes: Shapes | None = None,
    refine: Refine | None = None,
) -> Diagnosis:
    """The aggregate diagnosis of the module docstring (``ensembles`` = 1: one plain diagnosis).

    With several ensembles and ``cfg.jobs`` > 1 the ensembles themselves run in one forked pool
    of ``min(jobs, ensembles)`` processes, each a whole diagnosis with its simulations in its own
    process (the same results as one after the other: every ensemble is fixed by its seed); the
    inputs reach the workers by the fork, only the diagnoses travel back.
    """
    say = progress or (lambda _m: None)
    n = max(1, ensembles)
    _ENSEMBLES.update(
        real=real,
        simulate=simulate,
        candidates=candidates,
        cfg=cfg,
        n=n,
        say=say,
        subsampled=subsampled,
        shapes=shapes,
        refine=refine,
    )
    try:
        runs = _run_pooled(n, cfg.jobs) if n > 1 and cfg.jobs > 1 else None
        if runs is None:
            runs = [_ensemble(e) for e in range(n)]
    finally:
        _ENSEMBLES.clear()
    if len(runs) == 1:
        return runs[0]
    return aggregate(pool_residual_cells(runs, cfg), min_share)


def pool_residual_cells(runs: Sequence[Diagnosis], cfg: Config) -> list[Diagnosis]:
    """The ensembles with the cells that still differ decided once per named set.

    Ensembles that name the same effects (at least two of them) pool their localisations before
    and after the named effects (:func:`uwbcal.gap.localise.pooled`); the cells still open in
    that pooled test (:func:`uwbcal.gap.localise.still_open`) replace each one's own, and its
    verdict is derived again (:func:`uwbcal.gap.engine.verdict_of`) with its own shrink,
    time-shape checks and ambiguities. ``settings["residual_cells"]`` records the pooling.
    Ensembles without named effects, or alone with their named set, are left as they are.
    """
    groups: dict[tuple[str, ...], list[int]] = {}
    for i, d in enumerate(runs):
        if d.named and d.cells and d.cells_after:
            groups.setdefault(tuple(sorted(n["effect"] for n in d.named)), []).append(i)
    out = list(runs)
    for idx in groups.values():
        if len(idx) < 2:
            continue
        before = pooled([runs[i].cells for i in idx])
        after = pooled([runs[i].cells_after for i in idx])
        if not before or not after:
            continue
        remaining = still_open(before, after, cfg)
        seeds = sum(
            next((c.stat_null.shape[0] for c in runs[i].cells if c.stat_null is not None), 0) for i in idx
        )
        for i in idx:
            d = runs[i]
            verdict, summary = verdict_of(
                len(d.significant),
                d.named,
                d.feature_shrink,
                d.shrink,
                d.shrink_aspects,
                remaining,
                d.criticism_failed,
                d.ambiguous,
                cfg,
            )
            pool = {
                "ensembles": len(idx),
                "run_seeds": seeds,
                "still_differing": len(remaining),
                "still_differing_in_this_ensemble_alone": len(d.remaining),
                "verdict_alone": d.verdict,
            }
            out[i] = dataclasses.replace(
                d,
                verdict=verdict,
                summary=f"{summary} (cells still differing: one test on {len(idx)} ensembles' {seeds} seeds)",
                remaining=remaining,
                settings={**d.settings, "residual_cells": pool},
            )
    return out


#: What :func:`_ensemble` needs, set before the pool forks (nothing is pickled to the workers).
_ENSEMBLES: dict[str, Any] = {}


def _ensemble(e: int) -> Diagnosis:
    """Ensemble ``e``'s whole diagnosis (its seed block ``cfg.seed + STRIDE e``)."""
    x = _ENSEMBLES
    cfg: Config = x["cfg"]
    n: int = x["n"]
    say: Callable[[str], None] = x["say"]
    pooled = bool(x.get("pooled"))
    c = dataclasses.replace(cfg, seed=cfg.seed + STRIDE * e, jobs=1 if pooled else cfg.jobs)
    say(f"ensemble {e + 1}/{n} (seed {c.seed})")
    prefix = f"[{e + 1}/{n}] " if pooled else ""
    d = diagnose(
        x["real"],
        x["simulate"],
        x["candidates"],
        c,
        progress=lambda m: say(prefix + m),
        subsampled=x["subsampled"],
        shapes=x.get("shapes"),
        refine=x.get("refine"),
    )
    d.settings = {**d.settings, "jobs": cfg.jobs}  # what was asked, not how the pool split it
    return d


def _run_pooled(n: int, jobs: int) -> list[Diagnosis] | None:
    """The ensembles in one forked pool, in order; None if no pool can be made."""
    import multiprocessing as mp

    from uwbcal.gap.allocator import reuse_freed_memory
    from uwbcal.gap.blas import one_blas_thread

    reuse_freed_memory()
    one_blas_thread()
    _ENSEMBLES["pooled"] = True
    try:
        pool = mp.get_context("fork").Pool(min(jobs, n))
    except (OSError, ValueError):
        _ENSEMBLES["pooled"] = False
        return None
    try:
        return list(pool.map(_ensemble, range(n), chunksize=1))
    finally:
        pool.close()
        pool.join()


def aggregate(runs: Sequence[Diagnosis], min_share: float) -> Diagnosis:
    """Aggregate verdict, named effects and stability figures of several ensembles."""
    k = len(runs)
    verdicts = Counter(d.verdict for d in runs)
    verdict, v_n = verdicts.most_common(1)[0]
    sets = Counter(tuple(sorted(n["effect"] for n in d.named)) for d in runs)
    _, s_n = sets.most_common(1)[0]
    counts = Counter(n["effect"] for d in runs for n in d.named)
    majority = [e for e, c in counts.items() if c >= k / 2]  # named by at least half
    firsts = Counter(d.named[0]["effect"] if d.named else "-" for d in runs if d.verdict == verdict)
    first, f_n = firsts.most_common(1)[0]
    stable = v_n / k >= min_share and (verdict != "explained" or f_n / k >= min_share)
    agree = [d for d in runs if d.verdict == verdict] if stable else list(runs)
    rep = min(agree, key=lambda d: len({n["effect"] for n in d.named} ^ set(majority)))
    out = dataclasses.replace(rep)
    fitted: dict[str, list[float]] = {}
    for d in runs:
        for n in d.named:
            fitted.setdefault(n["effect"], []).append(float(n["fitted"]))
    entry = {n["effect"]: n for d in [*reversed(runs), rep] for n in d.named}  # rep's entry wins
    order = [n["effect"] for n in rep.named if n["effect"] in majority]
    order += sorted((e for e in majority if e not in order), key=lambda e: -counts[e])
    out.named = [
        {
            **entry[e],
            "fitted": float(np.median(fitted[e])),
            "fitted_per_ensemble": fitted[e],
            "named_by": counts[e],
        }
        for e in order
    ]
    stability: dict[str, Any] = {
        "ensembles": k,
        "verdicts": dict(verdicts),
        "verdict_share": v_n / k,
        "named_sets": {" + ".join(s) or "-": c for s, c in sets.items()},
        "named_share": s_n / k,
        "first_named": first,
        "first_named_share": f_n / k,
        "named_by_majority": sorted(majority),
        "min_share": min_share,
        "stable": bool(stable),
    }
    alone = [d.settings["residual_cells"]["verdict_alone"] for d in runs if "residual_cells" in d.settings]
    if alone:  # what the pooled residual-cell test (pool_residual_cells) changed
        stability["residual_cells_pooled_in"] = len(alone)
        stability["verdicts_alone"] = dict(
            Counter(
                d.settings["residual_cells"]["verdict_alone"] if "residual_cells" in d.settings else d.verdict
                for d in runs
            )
        )
    out.settings = {**rep.settings, "stability": stability}
    if not stable:
        out.verdict = "unstable"
        shares = ", ".join(f"{v} {c}/{k}" for v, c in verdicts.items())
        out.summary = (
            f"unstable: the {k} seed ensembles disagree ({shares}; named sets {stability['named_sets']}); "
            "no verdict is called. " + rep.summary
        )
    else:
        out.summary = f"{rep.summary} [stable: {v_n}/{k} ensembles agree]"
    return out
