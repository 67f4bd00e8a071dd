"""The gap diagnosis proper: localise, attribute, quantify. Independent of the physics.

The engine sees the world model only through a :class:`Simulator`: a function from a
*variant* (knob settings on top of the believed scenario) and a seed to simulated records
on the real session's own schedule. :mod:`uwbcal.gap.model` builds one from the physics
catalogue; tests may build others.

Method (docs/GAP.md has the long form):

1. Localise. For every observable and every regime bin (and "all"), compare the real values
   with the pooled simulated values of K seeds with three statistics (location: Welch t;
   scale: log SD ratio; shape: KS distance of the standardised samples). The noise floor is
   the same statistics of each simulated seed against the other seeds; a Student-t
   predictive turns the floor into p-values; Benjamini-Hochberg controls the FDR over all
   cells and statistics. No rejection at ``alpha`` is "no significant gap".
2. Features. Per group (time block, or power step) and cell (direction x spacing x RX power
   x temperature x distance), the mean, log SD and lag-1 autocorrelation of every
   observable. Baseline mean m0 and seed-to-seed SD s per feature from the K seeds.
3. Attribute. Each candidate (an effect the scenario leaves off or fixes, through one
   parameter knob with a grid of values) has a signature: the mean feature change over
   paired seeds at each grid value (interpolated between them). Forward selection:
   leave-one-group-out, fit each candidate's knob on the training groups (least squares in
   units of s, on top of the effects already selected), score the held-out group's loss;
   add the candidate with the largest mean held-out improvement if the bootstrap CI of the
   improvement excludes zero, else stop. Cross-check: Lasso of the standardised residual on
   the signatures.
4. Quantify. Held-out shrink of the excess loss (loss minus its null expectation, the
   number of features) with a bootstrap CI over groups; the same for a flexible black-box
   residual model (per feature slot, a ridge line in the group's position); the fraction
   of the black-box's removable gap that the named effects remove.

The steps live in their own modules: :mod:`uwbcal.gap.localise`, :mod:`uwbcal.gap.features`,
:mod:`uwbcal.gap.attribute`, :mod:`uwbcal.gap.quantify`; the simulation pool in
:mod:`uwbcal.gap.pool`; settings in :mod:`uwbcal.gap.config`. This module runs them in order.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from uwbcal.gap import criticism, free, stats
from uwbcal.gap import observables as obs_mod
from uwbcal.gap.attribute import (
    Candidate,
    Chance,
    Selection,
    Signature,
    _cv_losses,
    _entry_level,
    _rounding,
    family,
    fit_effects,
    forward_select,
    lasso,
    offered,
    signatures,
)
from uwbcal.gap.config import Config, FloatArray, IntArray, Records, Simulator, Variant
from uwbcal.gap.features import (
    CELL_REGIMES,
    FeatureSpace,
    build_space,
    interleaved_folds,
    residual_by_group,
    slots,
)
from uwbcal.gap.localise import Cell, Summary, localise, still_open, summarise
from uwbcal.gap.pool import Runner
from uwbcal.gap.quantify import blackbox_losses, cells_closed, checks_passed, null_loss

__all__ = [
    "CELL_REGIMES",
    "Candidate",
    "Cell",
    "Config",
    "Diagnosis",
    "FeatureSpace",
    "FloatArray",
    "IntArray",
    "Records",
    "Selection",
    "Signature",
    "Simulator",
    "Summary",
    "Variant",
    "blackbox_losses",
    "build_space",
    "diagnose",
    "fit_effects",
    "forward_select",
    "localise",
    "offered",
    "summarise",
]


#: Effects that shape the clock rate slowly and flexibly: named, they may stand in for a warm-up
#: or a chance trend; the model criticism of the rate's time shape can refute them.
SLOW_CLOCK_EFFECTS = ("clock_wander", "temperature")
#: Candidates of free shape fitted to the clock rate: (real rate per record, re-simulated rates
#: seeds x records), ppm -> candidates (model.clock_shapes).
Shapes = Callable[[FloatArray, FloatArray], list[Candidate]]
#: The neighbours of a candidate along its effect's shape parameters, one step times the scale
#: (model.shape_refiner).
Refine = Callable[[Candidate, float], list[Candidate]]


@dataclass
class Diagnosis:
    """Everything one diagnosis found (JSON via :meth:`to_json`)."""

    verdict: str
    summary: str
    cells: list[Cell]
    significant: list[Cell]
    named: list[dict[str, Any]]
    selection_steps: list[dict[str, Any]]
    lasso: list[dict[str, Any]]
    lasso_agrees: bool | None
    shrink: dict[str, Any]  # the least aspect (_least): estimate, ci_low, ci_high, least
    shrink_signature: dict[str, float]
    blackbox_shrink: dict[str, float]
    fraction_of_removable: float
    excess: dict[str, float]
    n_features: int
    n_groups: int
    group_regime: str
    settings: dict[str, Any]
    residual_before: dict[str, Any] = field(default_factory=dict)
    residual_after: dict[str, Any] = field(default_factory=dict)
    group_labels: list[str] = field(default_factory=list)
    remaining: list[Cell] = field(default_factory=list)
    cells_after: list[Cell] = field(default_factory=list)
    not_offered: list[str] = field(default_factory=list)
    criticism: list[Any] = field(default_factory=list)  # criticism.Check of the named effects
    criticism_failed: list[str] = field(default_factory=list)
    ambiguous: list[str] = field(default_factory=list)  # "lead or runner-up" where the margin is thin
    no_trace: list[str] = field(default_factory=list)  # candidates whose signature is Monte-Carlo noise here
    rejected: list[str] = field(default_factory=list)  # named once, then refuted by the model criticism
    station_noise: dict[str, Any] = field(default_factory=dict)  # stations.station_noise of the real records
    local_departures: list[dict[str, Any]] = field(default_factory=list)  # stations.local_departures
    shrink_aspects: dict[str, Any] = field(default_factory=dict)  # _aspects of the named effects
    feature_shrink: float = float("nan")  # held-out re-simulated shrink of the feature loss (fraction)

    def to_json(self) -> dict[str, Any]:
        return {
            "verdict": self.verdict,
            "summary": self.summary,
            "named_effects": self.named,
            "candidates_not_offered": self.not_offered,
            "candidates_without_trace": self.no_trace,
            "rejected_by_criticism": self.rejected,
            "model_criticism": [c.to_json() for c in self.criticism],
            "model_criticism_failed": self.criticism_failed,
            "ambiguous": self.ambiguous,
            "station_noise": self.station_noise,
            "local_departures": self.local_departures,
            "selection": self.selection_steps,
            "lasso": self.lasso,
            "lasso_agrees": self.lasso_agrees,
            "heldout_shrink": self.shrink,
            "shrink_by_aspect": self.shrink_aspects,
            "heldout_shrink_signature_model": self.shrink_signature,
            "blackbox_shrink": self.blackbox_shrink,
            "excess_loss": self.excess,
            "groups": self.group_labels,
            "fraction_of_removable_gap": self.fraction_of_removable,
            "significant_cells": [c.to_json() for c in self.significant],
            "cells_still_differing_with_named_effects": [c.to_json() for c in self.remaining],
            "cells_with_named_effects": [c.to_json() for c in self.cells_after],
            "cells": [c.to_json() for c in self.cells],
            "n_features": self.n_features,
            "n_groups": self.n_groups,
            "group_regime": self.group_regime,
            "settings": self.settings,
            "residual_by_group_before": self.residual_before,
            "residual_by_group_after": self.residual_after,
        }


def diagnose(
    real: Records,
    simulate: Simulator,
    candidates: Sequence[Candidate],
    cfg: Config | None = None,
    progress: Callable[[str], None] | None = None,
    subsampled: Callable[[int], Simulator] | None = None,
    shapes: Shapes | None = None,
    refine: Refine | None = None,
) -> Diagnosis:
    """Run the whole diagnosis of ``real`` against ``simulate`` with ``candidates``.

    ``shapes(real clock rate, re-simulated clock rates)``, if given, fits candidates of free
    shape to the clock rate (model.clock_shapes), offered with the others when clock-rate cells
    differ and tried again without the slow clock effects when no explanation passes.
    ``refine(candidate, scale)``, if given, moves the effect named first along its shape
    parameters (model.shape_refiner), tried when no explanation passes.

    ``subsampled(stride)``, if given, is a simulator of every stride-th record of the real
    schedule: the candidates' signatures (many simulations, each a mean change of the
    features) are then simulated on at most ``cfg.signature_max_records`` records; the noise
    floor, the localisation and the re-simulated shrink always use the whole schedule.
    """
    import warnings

    from uwbcal.gap.allocator import reuse_freed_memory
    from uwbcal.gap.blas import one_blas_thread

    reuse_freed_memory()
    one_blas_thread()
    cfg = cfg or Config()
    say = progress or (lambda _m: None)
    candidates, skipped = offered(candidates, real)
    if skipped:
        say("not offered (the session cannot tell them apart): " + ", ".join(c.effect for c in skipped))
    rng = np.random.default_rng(cfg.seed + 11)
    warnings.filterwarnings("ignore", message="Mean of empty slice", category=RuntimeWarning)
    warnings.filterwarnings("ignore", message="Degrees of freedom", category=RuntimeWarning)
    ro = obs_mod.observables(real, cfg.prf_mhz)
    seeds = [cfg.seed * 1000 + 1 + i for i in range(cfg.n_seeds)]
    names = list(ro)
    space = build_space(real, cfg, names)
    n = obs_mod.n_records(real)
    sim_sub: Simulator | None = None
    space_sub: FeatureSpace | None = None
    if subsampled is not None and n > cfg.signature_max_records and space.real_regimes is not None:
        stride = int(np.ceil(n / cfg.signature_max_records))
        sim_sub = subsampled(stride)
        reg = space.real_regimes
        reg_sub = obs_mod.Regimes(keys={k: v[::stride] for k, v in reg.keys.items()}, t_edges=reg.t_edges)
        # the subsample's own folds: every stride-th record of the full session's folds would
        # leave whole folds empty (stride 4, 10 folds: only the even ones), and their signature
        # rows zero
        sub_folds = (
            None
            if space.fold_keys is None
            else interleaved_folds(
                {k: (None if v is None else np.asarray(v)[::stride]) for k, v in real.items()},
                reg_sub,
                cfg.n_time_blocks,
            )
        )
        space_sub = dataclasses.replace(space, real_regimes=reg_sub, fold_keys=sub_folds)
        say(f"candidate signatures on every {stride}th record")
    # free per-step terms (gap/free.py) are applied to whatever the simulator returns
    runner = Runner(
        free.wrap(simulate), space, cfg, None if sim_sub is None else free.wrap(sim_sub), space_sub
    )
    try:
        d = _diagnose(real, runner, candidates, cfg, say, rng, seeds, space, shapes, refine)
    finally:
        runner.close()
    d.not_offered = [f"{c.effect} ({c.knob})" for c in skipped]
    from uwbcal.gap import stations

    d.station_noise = stations.station_noise(real, seed=cfg.seed, prf_mhz=cfg.prf_mhz)
    d.local_departures = stations.local_departures(real, alpha=cfg.alpha, prf_mhz=cfg.prf_mhz)
    return d


def _aspects(
    shrink: dict[str, Any],
    significant: Sequence[Cell],
    cells_after: Sequence[Cell],
    checks_before: Sequence[criticism.Check],
    checks_after: Sequence[criticism.Check],
    cfg: Config,
) -> dict[str, Any]:
    """How much of each aspect of the gap the named effects remove (fractions, None: no gap there).

    ``features``: the held-out re-simulated shrink of the feature loss; ``cells``: the differing
    localisation cells closed, each cell one place (:func:`quantify.cells_closed`); ``time_shape``:
    the failing model-criticism checks that pass (:func:`quantify.checks_passed`).
    """

    def failing(checks: Sequence[criticism.Check]) -> list[Any]:
        bad = criticism.failed(checks, cfg.criticism_alpha, cfg.burst_alpha)
        return [(c.observable, c.direction, name) for c, name, _ in bad]

    return {
        "features": shrink.get("estimate"),
        "cells": cells_closed(significant, cells_after, cfg.alpha, cfg.cell_closed),
        "time_shape": checks_passed(failing(checks_before), failing(checks_after)),
        "time_shape_failing_before": [" ".join(x) for x in failing(checks_before)],
    }


def _least(features: dict[str, Any], aspects: dict[str, Any]) -> dict[str, Any]:
    """The reported shrink: the least of the aspects (``_aspects``), with the features' CI capped
    by the others. A gap whose time shape, or some of whose cells, the named effects leave as they
    were has not shrunk by what the clock rate's means alone say (issue 13, cause 4)."""
    est = features.get("estimate", float("nan"))
    lo, hi = features.get("ci_low", float("nan")), features.get("ci_high", float("nan"))
    out: dict[str, Any] = {"estimate": est, "ci_low": lo, "ci_high": hi, "least": "features"}
    if not (isinstance(est, float) and math.isfinite(est)):
        return out
    for name in ("cells", "time_shape"):
        v = aspects.get(name)
        if v is not None and v < out["estimate"]:
            out.update(estimate=float(v), least=name)
        if v is not None:
            out["ci_low"] = min(out["ci_low"], float(v))
            out["ci_high"] = min(out["ci_high"], float(v))
    return out


def _feature_shrink(res: dict[str, Any]) -> float:
    """The held-out re-simulated shrink of the feature loss of an explanation (NaN: none)."""
    v = res.get("aspects", {}).get("features")
    return float(v) if v is not None else float("nan")


def _aspect_text(aspects: dict[str, Any]) -> str:
    """The shrink's aspects in words: "held-out feature loss 100%, differing cells 83%, ..."."""
    words = {
        "features": "held-out feature loss",
        "cells": "differing cells",
        "time_shape": "failing time-shape checks",
    }
    return ", ".join(
        f"{w} {100 * aspects[k]:.0f}%" for k, w in words.items() if isinstance(aspects.get(k), (int, float))
    )


def verdict_of(
    n_significant: int,
    named: Sequence[dict[str, Any]],
    s_feat: float,
    shrink: dict[str, Any],
    aspects: dict[str, Any],
    remaining: Sequence[Cell],
    failed_checks: Sequence[str],
    ambiguous: Sequence[str],
    cfg: Config,
) -> tuple[str, str]:
    """(verdict, summary) of a diagnosis that found a gap in ``n_significant`` cells: "explained"
    when effects are named, their held-out feature shrink ``s_feat`` (fraction) reaches
    ``cfg.explained_shrink``, no cell still differs (``remaining``), the time-shape checks pass
    and no named effect is ambiguous with its runner-up; else "unexplained", with the reasons."""
    if not named:
        return "unexplained", (
            f"gap in {n_significant} cells; no catalogued effect improves held-out groups: unexplained"
        )
    s_est, s_lo, s_hi = shrink["estimate"], shrink["ci_low"], shrink["ci_high"]
    if not s_feat >= cfg.explained_shrink or remaining or failed_checks or ambiguous:
        eff = " + ".join(n["effect"] for n in named)
        why = []
        if not s_feat >= cfg.explained_shrink:
            why.append(f"they remove only {100 * s_feat:.0f}% of the held-out feature loss")
        if remaining:
            why.append(f"{len(remaining)} cells still differ from the simulation with them")
        if failed_checks:
            why.append("the time shape is not reproduced (" + "; ".join(failed_checks[:2]) + ")")
        if ambiguous:
            why.append("the data cannot tell " + "; ".join(ambiguous) + " apart")
        return "unexplained", (
            f"gap in {n_significant} cells; unexplained: the best catalogued candidates ({eff}) "
            f"remove {100 * s_est:.0f}% of the gap ({_aspect_text(aspects)}), but " + ", and ".join(why)
        )
    eff = " + ".join(f"{n['effect']} ({n['knob']} = {n['fitted']:.4g} {n['unit']})" for n in named)
    return "explained", (
        f"gap in {n_significant} cells; explained by {eff}; held-out shrink "
        f"{100 * s_est:.0f}% [{100 * s_lo:.0f}, {100 * s_hi:.0f}]"
    )


def _variant(chosen: Sequence[Signature], thetas: Sequence[float]) -> Variant:
    """The scenario variant of the effects ``chosen`` at their knob values ``thetas``."""
    return tuple(kv for sg, t in zip(chosen, thetas, strict=True) for kv in sg.candidate.variant(t))


def _per_receiver_of(c: Candidate) -> str | None:
    """The effect whose per-receiver knob ``c`` is (a receiver's noise scale), else None."""
    return c.depends_on if c.needs is not None and c.needs[0] == "rx_station" else None


def _every_receiver(chosen: Sequence[Signature], real: Records) -> list[str]:
    """Effects whose per-receiver knob is named for as many stations as the session has receivers
    (two or more; the knobs' ids are scenario ids, which a recording's may map onto, and a station
    that receives nothing leaves no trace to be named for)."""
    n_rx = np.unique(np.asarray(real["rx_station"])).size
    by: dict[str, set[str]] = {}
    for sg in chosen:
        eff = _per_receiver_of(sg.candidate)
        if eff is not None:
            by.setdefault(eff, set()).add(sg.candidate.knob)
    return [e for e, knobs in by.items() if n_rx > 1 and len(knobs) >= n_rx]


def _passes(res: dict[str, Any], cfg: Config) -> bool:
    """Whether an explanation (``explain``'s result) would be called "explained"."""
    return (
        bool(res["chosen"])
        and bool(_feature_shrink(res) >= cfg.explained_shrink)
        and not res["remaining"]
        and not res["failed_checks"]
        and not res["ambiguous"]
    )


def _no_worse(alt: dict[str, Any], res: dict[str, Any]) -> bool:
    """Whether explanation ``alt`` is at least as good as ``res`` by each criterion of the verdict
    (:func:`_passes`): no more cells still differing, no more failed time-shape checks, not
    ambiguous where ``res`` is not, and a shrink (the least of its aspects) not below the lower
    end of ``res``'s bootstrap CI (NaN: not shown, so not no worse)."""
    est = float(alt.get("shrink", {}).get("estimate", float("nan")))
    low = float(res.get("shrink", {}).get("ci_low", float("nan")))
    return (
        bool(alt["chosen"])
        and len(alt["remaining"]) <= len(res["remaining"])
        and len(alt["failed_checks"]) <= len(res["failed_checks"])
        and (not alt["ambiguous"] or bool(res["ambiguous"]))
        and math.isfinite(est)
        and math.isfinite(low)
        and est >= low
    )


def _outcome(res: dict[str, Any], cfg: Config) -> dict[str, Any]:
    """What a retried explanation (free terms, clock shapes) gave, for its selection step."""
    return {
        "passes": _passes(res, cfg),
        "shrink": res["shrink"]["estimate"],
        "failed_checks": res["failed_checks"],
        "cells_still_differing": [
            f"{c.observable} {c.label} z {', '.join(f'{v:+.1f}' for v in c.z)}" for c in res["remaining"]
        ],
    }


def _no_checks() -> tuple[dict[str, Any], list[Cell], list[Cell], list[Any], list[str], list[str]]:
    """(residual after, cells still differing, cells after, criticism checks, failed checks,
    ambiguities) of no explanation: empty until an explanation fills them."""
    return {}, [], [], [], [], []


def _kept(
    res: dict[str, Any], alt: dict[str, Any], step: dict[str, Any], cfg: Config, or_no_worse: bool = False
) -> dict[str, Any]:
    """``alt`` (a retried explanation whose steps begin with ``step``, passed as ``prior``) if it
    passes, or, with ``or_no_worse``, if it is no worse than ``res`` (:func:`_no_worse`; ``step``
    says "kept"), else ``res`` with ``step`` appended; ``step`` records the outcome
    (:func:`_outcome`)."""
    step.update(_outcome(alt, cfg))
    if step["passes"]:
        return alt
    if or_no_worse and _no_worse(alt, res):
        step["kept"] = "no worse with fewer knobs"
        return alt
    res["steps"] = [*res["steps"], step]
    return res


def _diagnose(
    real: Records,
    runner: Runner,
    candidates: Sequence[Candidate],
    cfg: Config,
    say: Callable[[str], None],
    rng: np.random.Generator,
    seeds: list[int],
    space: FeatureSpace,
    shapes: Shapes | None = None,
    refine: Refine | None = None,
) -> Diagnosis:
    say(f"re-simulating the session's schedule over {len(seeds)} seeds")
    base = runner.map([((), s, True, False) for s in seeds])
    sims = [b[1] for b in base if b[1] is not None]
    say("localising")
    real_summary = summarise(real, space.t_edges, space.real_regimes, cfg.prf_mhz)
    cells = localise(real_summary, sims, cfg, space.t_edges)
    significant = [c for c in cells if min(c.q) < cfg.alpha]
    significant.sort(key=lambda c: min(c.q))

    def critique(sim_obs: Sequence[dict[str, FloatArray]]) -> list[criticism.Check]:
        """Model criticism of the real time shape against re-simulated observables."""
        t_real = real.get("t_s")
        if t_real is None:
            return []
        reg = space.real_regimes
        return criticism.criticise(
            real_summary[0],
            sim_obs,
            np.asarray(t_real, np.float64),
            None if reg is None else reg.keys.get("direction"),
            step=None if space.group_regime not in ("fold", "step") or reg is None else reg.keys.get("step"),
        )

    # the believed scenario's own time-shape misfit: the places of the gap that only the criticism sees
    checks_before = critique([x[0] for x in sims]) if significant else []

    f_real = space.features(real, cfg.min_feature)
    f_sims = np.stack([b[0] for b in base])
    k = len(seeds)
    m0 = np.nanmean(f_sims, axis=0)
    sd = np.nanstd(f_sims, axis=0, ddof=1) * np.sqrt(1.0 + 1.0 / k)
    good = np.isfinite(f_real) & np.all(np.isfinite(f_sims), axis=0) & (sd > 0)
    r = np.where(good, (f_real - m0) / np.where(sd > 0, sd, 1.0), 0.0)[good]
    groups = space.feat_group[good]
    n_groups = len(space.group_keys)
    slot = slots(space, good)
    gpos = np.arange(n_groups, dtype=np.float64)
    lnull = null_loss(f_sims, good, groups, n_groups)
    # believed re-simulations standardised as the real session is (against the mean of the others:
    # f_j - mean_{-j} = k / (k - 1) (f_j - mean))
    n_null = min(cfg.null_seeds, k)
    chance = (
        Chance(
            ((f_sims[:n_null] - m0) / np.where(sd > 0, sd, 1.0) * (k / (k - 1.0)))[:, good],
            groups,
            n_groups,
            cfg.jobs,
        )
        if n_null >= max(cfg.min_null_seeds, 1)
        else None
    )
    settings = {k_: getattr(cfg, k_) for k_ in cfg.__dataclass_fields__}
    before = residual_by_group(r, groups, space, good)

    named: list[dict[str, Any]] = []
    steps: list[dict[str, Any]] = []
    lasso_rows: list[dict[str, Any]] = []
    lasso_agrees: bool | None = None
    nan3 = {"estimate": float("nan"), "ci_low": float("nan"), "ci_high": float("nan")}
    shrink, shrink_sig, bb = dict(nan3), dict(nan3), dict(nan3)
    frac = s_feat = float("nan")
    after, remaining, cells_after, checks, failed_checks, ambiguous = _no_checks()
    no_trace: list[str] = []
    rejected: list[str] = []
    aspects: dict[str, Any] = {}
    excess = {
        "before": float(np.sum(np.bincount(groups, weights=r * r, minlength=n_groups) - lnull)),
        "null_loss": float(lnull.sum()),
        "n_features": int(r.size),
    }
    if not significant:
        verdict = "no significant gap"
        summary = (
            f"no significant gap: none of {len(cells)} cells x {len(stats.STAT_NAMES)} statistics "
            f"differs from the sim-vs-sim floor at FDR {cfg.alpha}"
        )
    else:
        say(f"signatures of {len(candidates)} candidates")
        sigs = signatures(candidates, runner, seeds[: cfg.n_seeds_signature], f_sims, sd, good, space)
        fewer = [sg.candidate.label for sg in sigs if 0 < sg.n_seeds < cfg.n_seeds_signature]
        if fewer:  # a long session's sequential signature seeds (Config.signature_seeds_first)
            n_first, se = cfg.signature_seeds_first, cfg.signature_se
            say(f"signatures known to {se} floor SDs on {n_first} seeds: " + ", ".join(fewer))
        traceless = [sg for sg in sigs if sg.trace_z < cfg.min_trace_z and sg.candidate.depends_on is None]
        if traceless:  # noise-only signatures: fitting them to the residual only adds chance picks
            say("no trace in this session: " + ", ".join(sg.candidate.label for sg in traceless))
            sigs = [sg for sg in sigs if sg not in traceless]
        no_trace = [f"{sg.candidate.label} (trace z {sg.trace_z:.1f})" for sg in traceless]
        say("forward selection")

        def relinearise(
            all_sigs: Sequence[Signature], chosen_idx: Sequence[int], todo: Sequence[int]
        ) -> dict[int, Signature]:
            picked = [all_sigs[j] for j in chosen_idx]
            th, _, _ = fit_effects(r, picked, np.ones_like(r, dtype=bool))
            on_top = _variant(picked, th)
            say("re-simulating signatures on top of " + ", ".join(f"{k} = {v:.4g}" for k, v in on_top))
            redo = signatures(
                [all_sigs[i].candidate for i in todo],
                runner,
                seeds[: cfg.n_seeds_signature],
                f_sims,
                sd,
                good,
                space,
                on_top=on_top,
            )
            return dict(zip(todo, redo, strict=True))

        def relocalised(variant: Variant) -> tuple[list[Any], list[Cell]]:
            """The schedule re-simulated with ``variant`` on every seed (with summaries) and the
            real session's cells localised against those re-simulations."""
            res_all = runner.map([(variant, s_, True, False) for s_ in seeds])
            sims_all = [x[1] for x in res_all if x[1] is not None]
            return res_all, localise(real_summary, sims_all, cfg, space.t_edges)

        def assess(
            chosen: list[Signature], exc0: FloatArray, boot: np.random.Generator = rng
        ) -> dict[str, Any]:
            """Re-simulated two-fold shrink, re-localisation, criticism and the shrink's aspects of
            the effects ``chosen`` (their knobs fitted here); ``exc0`` the believed scenario's
            held-out excess loss per group; ``boot`` draws the shrink's bootstrap."""
            named: list[dict[str, Any]] = []
            say("re-simulating with the named effects (two-fold held-out shrink)")
            loss_rs = np.zeros(n_groups)
            null_rs = np.zeros(n_groups)
            fitted_folds = []
            for fold in (0, 1):
                test = (groups % 2) == fold
                th_fold, _, _ = fit_effects(r, chosen, ~test)
                fitted_folds.append([float(t) for t in th_fold])
                variant = _variant(chosen, th_fold)
                fv = np.stack([x[0] for x in runner.map([(variant, s_, False, False) for s_ in seeds])])
                ok1 = good & np.all(np.isfinite(fv), axis=0)
                with np.errstate(invalid="ignore"):
                    m1 = np.nanmean(fv, axis=0)
                    sd1 = np.nanstd(fv, axis=0, ddof=1) * np.sqrt(1.0 + 1.0 / k)
                r1 = np.where(ok1 & (sd1 > 0), (f_real - m1) / np.where(sd1 > 0, sd1, 1.0), 0.0)[good]
                lg = np.bincount(groups, weights=r1 * r1, minlength=n_groups)
                ln = null_loss(np.where(np.isfinite(fv), fv, 0.0), good, groups, n_groups)
                gsel = np.arange(n_groups) % 2 == fold
                loss_rs[gsel] = lg[gsel]
                null_rs[gsel] = ln[gsel]
            exc_rs = loss_rs - null_rs
            shrink = dict(
                zip(
                    ("estimate", "ci_low", "ci_high"),
                    stats.shrink_ci(exc0, exc_rs, boot, cfg.n_boot),
                    strict=True,
                )
            )
            shrink["fitted_per_fold"] = fitted_folds  # type: ignore[assignment]
            exc_after = float(exc_rs.sum())
            thetas, pred, plr = fit_effects(r, chosen, np.ones_like(r, dtype=bool))
            after = residual_by_group((r - pred) * np.exp(-plr), groups, space, good)
            for sg, th in zip(chosen, thetas, strict=True):
                c = sg.candidate
                named.append(
                    {
                        "effect": c.effect,
                        "knob": c.knob,
                        "shape": [[k, v] for k, v in c.shape],
                        "fitted": th,
                        "baseline": c.baseline,
                        "unit": c.unit,
                        "description": c.description,
                        "at_grid_edge": bool(th <= sg.thetas[0] or th >= sg.thetas[-1]),
                    }
                )
            named = free.summarise(named)
            say("re-localising against the scenario with the named effects")
            res_all, cells_after = relocalised(_variant(chosen, thetas))
            remaining = still_open(cells, cells_after, cfg)
            checks = critique([x[1][0] for x in res_all if x[1] is not None])
            failed_checks = [
                criticism.describe(c, name, p_adj, cfg.burst_alpha)
                for c, name, p_adj in criticism.failed(checks, cfg.criticism_alpha, cfg.burst_alpha)
            ]
            aspects = _aspects(shrink, significant, cells_after, checks_before, checks, cfg)
            aspects["features_ci"] = [shrink["ci_low"], shrink["ci_high"]]
            shrink = {**_least(shrink, aspects), "fitted_per_fold": shrink["fitted_per_fold"]}
            return {
                "shrink": shrink,
                "aspects": aspects,
                "exc_after": exc_after,
                "after": after,
                "named": named,
                "cells_after": cells_after,
                "remaining": remaining,
                "checks": checks,
                "failed_checks": failed_checks,
            }

        def explain(
            sigs: list[Signature],
            fixed: list[Signature] | None = None,
            prior: list[dict[str, Any]] | None = None,
        ) -> dict[str, Any]:
            """Selection, re-simulated shrink, re-localisation and criticism with ``sigs``; ``fixed``
            effects are in the model from the start (forward_select), ``prior`` steps before."""
            named: list[dict[str, Any]] = []
            after, remaining, cells_after, checks, failed_checks, ambiguous = _no_checks()
            shrink = dict(nan3)
            aspects: dict[str, Any] = {}
            exc_after = float("nan")
            sel = forward_select(
                r, sigs, groups, n_groups, cfg, rng, relinearise, fixed=fixed or (), chance=chance
            )
            sigs = sel.signatures
            steps = [*(prior or []), *sel.steps]
            chosen = [*(fixed or []), *(sel.signatures[i] for i in sel.chosen)]
            exc0 = sel.fold_chi2_base - lnull
            exc1 = sel.fold_chi2_sel - lnull
            shrink_sig = dict(
                zip(
                    ("estimate", "ci_low", "ci_high"),
                    stats.shrink_ci(exc0, exc1, rng, cfg.n_boot),
                    strict=True,
                )
            )
            bbl = blackbox_losses(r, groups, n_groups, slot, gpos)
            bb = dict(
                zip(
                    ("estimate", "ci_low", "ci_high"),
                    stats.shrink_ci(exc0, bbl - lnull, rng, cfg.n_boot),
                    strict=True,
                )
            )
            if chosen:
                a = assess(chosen, exc0)
                # the effect named first must beat its runner-up; later, smaller steps that are
                # ambiguous are reported (selection[i].runner_up) but do not decide the verdict
                # (this selection's first step: ``steps`` may begin with ``prior`` ones)
                # (and so must every other member of a first block: chosen with the lead, not after it)
                st0 = sel.steps[0] if sel.steps and not fixed else {}
                rus = [(st0.get("lead"), st0.get("runner_up")), *st0.get("member_runner_ups", {}).items()]
                for member, ru in rus:
                    if ru and ru["effects"] and not ru["ci"][0] > 0.0:
                        ambiguous.append(f"{member} or {' + '.join(ru['effects'])}")
                # an effect added after the lead may fit the features of the training groups and
                # still make the re-simulated records differ where the believed ones did not (a
                # new discrepancy: blind sweep, a bias of another form with free per-step terms
                # left one clock-rate cell at KS z +5.5 that was +0.8 before). The full records
                # are the arbiter: drop such an effect when the explanation without it passes
                before_ids = {c.ident for c in significant}
                new_cells = [c for c in a["remaining"] if c.ident not in before_ids]
                # (the lead stays: the first effect selected, or the fixed terms; the attempts draw
                # their bootstraps apart, so that one that fails changes nothing after it)
                first = max(1, len(fixed or []))
                boot = np.random.default_rng(cfg.seed + 17)
                if new_cells and len(chosen) > first:
                    for j in range(len(chosen) - 1, first - 1, -1):
                        fewer = [sg for i, sg in enumerate(chosen) if i != j]
                        say(f"without {chosen[j].candidate.label}: re-simulating")
                        b = assess(fewer, exc0, boot)
                        ok = _feature_shrink(b) >= cfg.explained_shrink
                        if b["remaining"] or b["failed_checks"] or not ok:
                            continue
                        steps = [
                            *steps,
                            {
                                "step": "pruned",
                                "dropped": chosen[j].candidate.label,
                                "why": f"{len(new_cells)} cells differed only with it: "
                                + "; ".join(f"{c.observable} {c.label}" for c in new_cells[:3]),
                            },
                        ]
                        chosen, a = fewer, b
                        break
                shrink, aspects, exc_after, after, named = (
                    a["shrink"],
                    a["aspects"],
                    a["exc_after"],
                    a["after"],
                    a["named"],
                )
                cells_after, remaining, checks, failed_checks = (
                    a["cells_after"],
                    a["remaining"],
                    a["checks"],
                    a["failed_checks"],
                )
            return {
                "sigs": sigs,
                "steps": steps,
                "exc0": exc0,
                "shrink_sig": shrink_sig,
                "bb": bb,
                "chosen": chosen,
                "shrink": shrink,
                "aspects": aspects,
                "exc_after": exc_after,
                "after": after,
                "named": named,
                "cells_after": cells_after,
                "remaining": remaining,
                "checks": checks,
                "failed_checks": failed_checks,
                "ambiguous": ambiguous,
            }

        # a flexible clock effect (a random walk of the frequency, a temperature ramp through the
        # tempco) can absorb a warm-up, or a chance trend, as far as per-group means and spreads
        # go; when the model criticism says the rate's time shape is not reproduced, the
        # selection is run again without those named and that explanation is kept if it passes
        # (GAP.md, step 7)
        #
        # the clock rate's gap may have a shape the catalogue's fixed forms miss (a warm-up in two
        # stages): candidates whose time constants are fitted to the rate itself (model.
        # clock_shapes, offered only when the rate strongly needs them) compete from the start
        rate_cells = any(c.observable == "clock_rate_ppm" for c in significant)
        extra: list[Candidate] = []
        if shapes is not None and rate_cells and "clock_rate_ppm" in real_summary[0]:
            rates = [x[0]["clock_rate_ppm"] for x in sims if "clock_rate_ppm" in x[0]]
            extra = shapes(real_summary[0]["clock_rate_ppm"], np.stack(rates)) if rates else []
        shape_sigs: list[Signature] = []
        if extra:
            say("clock shapes fitted to the rate: " + "; ".join(c.description for c in extra))
            shape_sigs = signatures(extra, runner, seeds[: cfg.n_seeds_signature], f_sims, sd, good, space)
        res = explain([*sigs, *shape_sigs])
        slow = [n["effect"] for n in res["named"] if n["effect"] in SLOW_CLOCK_EFFECTS]
        if slow and any(f.startswith("clock_rate_ppm") for f in res["failed_checks"]):
            say("the clock rate's time shape is not reproduced: selecting again without " + ", ".join(slow))
            alt = explain([sg for sg in [*sigs, *shape_sigs] if sg.candidate.effect not in slow])
            if alt["chosen"] and not any(f.startswith("clock_rate_ppm") for f in alt["failed_checks"]):
                alt["rejected"] = [f"{e} (the rate's time shape: {res['failed_checks'][0]})" for e in slow]
                res = alt
        if not _passes(res, cfg) and free.offered(space):
            # a sweep the catalogue's forms do not explain: a power-dependent effect of another
            # form leaves per-step discrepancies. Free per-step terms, the effect named from
            # where they are needed (gap/free.py), the other effects selected again on top
            say("free per-step terms")
            terms = free.signatures(space, good, sd, r, "power_bias")
            by_kind = {k: [sg for sg in terms if free.parse(sg.candidate.knob)[0] == k] for k in free.KINDS}
            all_terms = [sg for k in free.KINDS for sg in by_kind[k]]
            l_all = _cv_losses(r, all_terms, groups, n_groups)[0]
            need: dict[str, list[float]] = {}
            level, n_boot = _entry_level(cfg, sum(1 for v in by_kind.values() if v))
            for kind, mine in by_kind.items():
                if not mine:
                    continue
                # a per-step kind is needed when its variation over the steps is: against one value
                # for every step (late paths or an antenna delay move every step alike)
                rest = [sg for sg in all_terms if sg not in mine] + (
                    free.common(mine) if free.per_step(kind) else []
                )
                l_rest = _cv_losses(r, rest, groups, n_groups)[0]
                m_, lo_, hi_ = stats.bootstrap_mean_ci(l_rest - l_all, rng, n_boot, level=level)
                if lo_ > _rounding(l_all):
                    need[kind] = [m_, lo_, hi_]
            name = free.name_of(set(need))
            step_free: dict[str, Any] = {
                "step": "free per-step terms",
                "needed": {k: {"heldout_improvement": v[0], "ci": v[1:]} for k, v in need.items()},
            }
            obs_real = real_summary[0]
            pair = ("drift_residual_m", "rx_level_dbm")
            if name == "tx_gain" and all(o in obs_real and all(o in x[0] for x in sims) for o in pair):
                # stamps and levels: a power error's stamps move only where its levels do; a
                # bias curve of another shape beside a compressing estimate was named a TX gain
                # error (blind seed 16, trial 30: stamps of 2-7 cm in steps whose levels moved
                # by 0.02 dB)
                share = free.stamps_without_power_error(
                    np.asarray(obs_real["drift_residual_m"], np.float64),
                    np.asarray(obs_real["rx_level_dbm"], np.float64),
                    np.stack([x[0]["drift_residual_m"] for x in sims]),
                    np.stack([x[0]["rx_level_dbm"] for x in sims]),
                    np.asarray(real["rx_station"], np.int64),
                    np.asarray(real["step"], np.int64),
                    cfg.free_slope_margin,
                )
                step_free["stamps_without_power_error"] = share
                if share is not None and share > cfg.free_uncoupled_share:
                    name = free.SPLIT
            step_free["named"] = name
            if name is not None:
                fixed = [
                    dataclasses.replace(
                        sg, candidate=dataclasses.replace(sg.candidate, effect=free.effect_of(k, name))
                    )
                    for k in need
                    for sg in by_kind[k]
                ]
                # the other effects are selected again on top of the free terms: picked next to
                # a power effect of the wrong form, some only patched its misfit
                others = [
                    sg for sg in [*sigs, *shape_sigs] if family(sg.candidate.effect) not in free.POWER_FAMILY
                ]
                res = _kept(
                    res, explain(others, fixed=fixed, prior=[*res["steps"], step_free]), step_free, cfg
                )
                lv_real = real_summary[0].get("rx_level_dbm")
                if name == "rx_power_estimate" and not _passes(res, cfg) and lv_real is not None:
                    # levels alone, and cells still differ: an offset and a spread per step are
                    # affine within the step, a compression whose knee falls inside a step is not
                    # (blind sweeps: a hard knee left the straddling step's level at KS z +4.4 and
                    # +8.4, every other cell closed). A per-level map of the reported level fitted
                    # by quantiles (free.level_map) in place of the per-step level terms
                    lv_sims = [x[0]["rx_level_dbm"] for x in sims if "rx_level_dbm" in x[0]]
                    cand = free.level_map(
                        np.asarray(lv_real, np.float64),
                        np.stack(lv_sims),
                        np.asarray(real["rx_station"], np.int64),
                        np.asarray(real["step"], np.int64),
                    )
                    if cand is not None:
                        say("a per-level map of the reported RX level")
                        sig_map = signatures(
                            [cand], runner, seeds[: cfg.n_seeds_signature], f_sims, sd, good, space
                        )
                        step_map: dict[str, Any] = {
                            "step": "per-level map",
                            "from": "per-step level terms",
                            "to": cand.label,
                        }
                        alt = explain(others, fixed=sig_map, prior=[*res["steps"], step_map])
                        res = _kept(res, alt, step_map, cfg)
            else:
                res["steps"] = [*res["steps"], step_free]
        if shape_sigs and not _passes(res, cfg):
            # the clock shapes again with the slow flexible clock effects set aside (they absorb any
            # shape, and a chance trend next to a warm-up)
            pool = [sg for sg in sigs if sg.candidate.effect not in SLOW_CLOCK_EFFECTS] + shape_sigs
            step_shape: dict[str, Any] = {
                "step": "clock shapes fitted to the rate",
                "candidates": [c.description for c in extra],
            }
            prior = [*res["steps"], step_shape]
            alt = explain(pool, prior=prior)
            step_shape["named"] = [n["effect"] for n in alt["named"]]
            step_shape["selection"] = [
                [f"{x['shape']} {x['heldout_improvement']:.3g}" for x in st_.get("ranking", [])[:4]]
                for st_ in alt["steps"][len(prior) :]
            ]
            res = _kept(res, alt, step_shape, cfg)
        lead = res["chosen"][0] if res["chosen"] else None
        if refine is not None and lead is not None and not _passes(res, cfg) and refine(lead.candidate, 1.0):
            # the effect named first, in a shape between the catalogue's fixed forms (late paths of
            # another size and spread): a pattern search over its shape parameters, each shape
            # scored by the cells that still differ with it next to the other named effects (its
            # knob fitted, the schedule re-simulated and localised), then by its held-out NLL;
            # then the whole explanation again with the best shape, kept only if it passes
            say(f"refining the shape of {lead.candidate.effect}")
            rest = list(res["chosen"][1:])

            def score(sg: Signature) -> tuple[int, float]:
                """(cells still differing, held-out NLL) with ``sg`` in the lead's place: the
                records' own test first (a late-path excess of another spread moves the KS shape of
                the clock rate, which no feature's NLL weighs much), the features' fit breaks ties."""
                chosen_ = [sg, *rest]
                loss = float(np.mean(_cv_losses(r, chosen_, groups, n_groups)[0]))
                th, _, _ = fit_effects(r, chosen_, np.ones_like(r, dtype=bool))
                return len(still_open(cells, relocalised(_variant(chosen_, th))[1], cfg)), loss

            best, best_score = (
                lead,
                (len(res["remaining"]), float(np.mean(_cv_losses(r, res["chosen"], groups, n_groups)[0]))),
            )
            seen = {frozenset(lead.candidate.shape)}
            scale = 1.0
            rounds: list[str] = []
            for _ in range(cfg.refine_rounds):
                near = [c for c in refine(best.candidate, scale) if frozenset(c.shape) not in seen]
                seen |= {frozenset(c.shape) for c in near}
                new = (
                    signatures(near, runner, seeds[: cfg.n_seeds_signature], f_sims, sd, good, space)
                    if near
                    else []
                )
                scores = [score(sg) for sg in new]
                j = min(range(len(scores)), key=scores.__getitem__) if scores else -1
                if j >= 0 and scores[j] < best_score:
                    best, best_score = new[j], scores[j]
                else:
                    scale /= 2.0
                rounds.append(f"{best.candidate.label}: {best_score[0]} cells, {best_score[1]:.6g}")
                if best_score[0] == 0:
                    break
            step_ref: dict[str, Any] = {
                "step": "shape refinement",
                "effect": lead.candidate.effect,
                "from": lead.candidate.label,
                "to": best.candidate.label,
                "rounds": rounds,
            }
            if best is not lead:
                # the refined shape in place of the effect's fixed forms (the selection would pick
                # back the form whose features fit best, whatever its records' test)
                others = [sg for sg in res["sigs"] if sg.candidate.effect != lead.candidate.effect]
                alt = explain([*others, best], prior=[*res["steps"], step_ref])
                step_ref["named"] = [n["effect"] for n in alt["named"]]
                if not _passes(alt, cfg) and best_score[0] < len(res["remaining"]):
                    # the set the refinement scored (the refined lead beside the effects named
                    # with it), without selecting again: the selection can add an effect whose
                    # features' NLL gains while its records' test loses (blind seed 16, trial 2:
                    # late paths refined to 0 cells; selected again, timestamp noise joined and
                    # left the clock rate's KS shape at z +4.9). Kept only if it passes
                    alt_set = explain([], fixed=[best, *rest], prior=[*res["steps"], step_ref])
                    if _passes(alt_set, cfg):
                        step_ref["named_selected_again"] = step_ref["named"]
                        step_ref["named"] = [n["effect"] for n in alt_set["named"]]
                        step_ref["kept"] = "the set as scored"
                        alt = alt_set
                res = _kept(res, alt, step_ref, cfg)
            else:
                res["steps"] = [*res["steps"], step_ref]
        for eff in _every_receiver(res["chosen"], real):
            # every receiver's own noise scale named: one scale per receiver is one global floor
            # plus their differences (with two nodes the records cannot tell them apart), so the
            # selection runs again without the per-receiver knobs and that explanation, with fewer
            # knobs, is kept if it passes (blind seed 11, trial 38: a Student-t jitter on every
            # receiver named as both receivers' scales) or, when neither passes, if it is no worse
            per_rx = [sg for sg in res["sigs"] if _per_receiver_of(sg.candidate) == eff]
            pool = [sg for sg in res["sigs"] if sg not in per_rx]
            if not any(sg.candidate.effect == eff for sg in pool):
                continue
            say(f"every receiver's {eff} scale named: selecting again with one {eff} for all")
            step_one: dict[str, Any] = {
                "step": "one effect for every receiver",
                "instead_of": [sg.candidate.label for sg in res["chosen"] if sg in per_rx],
            }
            alt = explain(pool, prior=[*res["steps"], step_one])
            step_one["named"] = [n["effect"] for n in alt["named"]]
            # when neither passes, the one effect for all is kept if it is no worse by any
            # criterion of the verdict: fewer knobs for the same account (real asil run
            # 2026-01-15-01 try 01: 2 of 4 ensembles named both receivers' scales, 15.3 and 15.6 x
            # the floor, the other 2 the one floor of 90 ps, and the named set changed with --seed)
            res = _kept(res, alt, step_one, cfg, or_no_worse=True)
        sigs, steps, exc0, shrink_sig, bb = (
            res["sigs"],
            res["steps"],
            res["exc0"],
            res["shrink_sig"],
            res["bb"],
        )
        chosen, shrink, after, named = res["chosen"], res["shrink"], res["after"], res["named"]
        cells_after, remaining, checks = res["cells_after"], res["remaining"], res["checks"]
        failed_checks, ambiguous = res["failed_checks"], res["ambiguous"]
        rejected = res.get("rejected", [])
        aspects = res["aspects"]
        if chosen:
            excess["after_resimulated"] = res["exc_after"]
        excess["before_heldout"] = float(exc0.sum())
        b_est = bb["estimate"]
        s_feat = _feature_shrink(res)
        frac = s_feat / b_est if b_est > 0 else float("nan")
        lasso_rows, lasso_top = lasso(r, sigs)
        if chosen:
            lasso_agrees = lasso_top == chosen[0].candidate.effect
        verdict, summary = verdict_of(
            len(significant), named, s_feat, shrink, aspects, remaining, failed_checks, ambiguous, cfg
        )
    return Diagnosis(
        verdict=verdict,
        summary=summary,
        feature_shrink=s_feat,
        cells=cells,
        significant=significant,
        named=named,
        selection_steps=steps,
        lasso=lasso_rows,
        lasso_agrees=lasso_agrees,
        shrink=shrink,
        shrink_signature=shrink_sig,
        blackbox_shrink=bb,
        fraction_of_removable=frac,
        excess=excess,
        n_features=int(r.size),
        n_groups=n_groups,
        group_regime=space.group_regime,
        settings=settings,
        residual_before=before,
        residual_after=after,
        remaining=remaining,
        cells_after=cells_after,
        criticism=checks,
        criticism_failed=failed_checks,
        ambiguous=ambiguous,
        no_trace=no_trace,
        rejected=rejected,
        shrink_aspects=aspects,
        group_labels=[obs_mod.label(space.group_regime, int(g), space.t_edges) for g in space.group_keys],
    )
