"""Simulation jobs of the diagnosis: simulate a variant at a seed and reduce it to features,
serially or in a forked process pool."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from uwbcal.gap import observables as obs_mod
from uwbcal.gap.config import Config, FloatArray, Simulator, Variant
from uwbcal.gap.features import FeatureSpace
from uwbcal.gap.localise import Summary, summarise

_JOB: dict[str, Any] = {}
#: Stands for the space's real regimes in a job's returned summary (None: keeps its identity
#: through pickling).
_REAL_REGIMES: Any = None


Task = tuple[Variant, int, bool, bool]


def _job(args: Task) -> tuple[FloatArray, Summary | None]:
    """Simulate one (variant, seed[, subsampled schedule]) and reduce it to features (and, if
    asked, its summary)."""
    variant, seed, full, sub = args
    sub = sub and _JOB.get("simulate_sub") is not None
    rec = _JOB["simulate_sub" if sub else "simulate"](variant, seed)
    space: FeatureSpace = _JOB["space_sub" if sub else "space"]
    ob = obs_mod.observables(rec, space.prf_mhz)  # once for the features and the summary
    f = space.features(rec, _JOB["min_feature"], ob)
    if not full:
        return f, None
    ob, reg = summarise(rec, space.t_edges, space.real_regimes, space.prf_mhz, ob)
    # the real session's regimes (a re-simulation of its schedule) stay home: Runner.map puts
    # the same object back, so they are neither pickled nor held once per seed
    home = reg is space.real_regimes and space is _JOB["space"]
    return f, (ob, _REAL_REGIMES if home else reg)


#: What identifies a job's result: (variant, seed, on the subsampled schedule).
Key = tuple[Variant, int, bool]
#: Variants whose summaries a Runner keeps (each one observables array per record and seed).
KEEP_VARIANTS = 2


class Runner:
    """Runs simulation jobs serially or in a forked process pool (``jobs`` > 1).

    A simulator is a function of (variant, seed), so a job asked for again is not run again: the
    features of every job are kept (a few thousand numbers each), and the summaries (observables
    per record) of the last :data:`KEEP_VARIANTS` calls that re-simulated one variant on the
    whole schedule, which such a call also computes when it asks only for features. The diagnosis
    asks for the same job more than once: the believed scenario's signature base on every
    signature call, and the re-simulation with the named effects, whose two held-out folds and
    re-localisation often fit the same values (all three at 100k records).
    """

    def __init__(
        self,
        simulate: Simulator,
        space: FeatureSpace,
        cfg: Config,
        simulate_sub: Simulator | None = None,
        space_sub: FeatureSpace | None = None,
    ) -> None:
        _JOB.update(
            simulate=simulate,
            space=space,
            min_feature=cfg.min_feature,
            simulate_sub=simulate_sub,
            space_sub=space_sub,
        )
        self.subsampled = simulate_sub is not None
        #: (first seeds, Monte-Carlo SE target) of the signatures of a subsampled session
        #: (attribute.signatures; Config.signature_seeds_first); None: every seed for every candidate
        self.sequential: tuple[int, float] | None = (
            (cfg.signature_seeds_first, cfg.signature_se)
            if self.subsampled and cfg.signature_seeds_first > 0
            else None
        )
        self.pool: Any = None
        self._features: dict[Key, FloatArray] = {}
        self._summaries: dict[Variant, dict[Key, Summary]] = {}  # oldest variant first
        if cfg.jobs > 1:
            import multiprocessing as mp

            try:
                self.pool = mp.get_context("fork").Pool(cfg.jobs)
            except (OSError, ValueError):
                self.pool = None

    def map(self, tasks: Sequence[Task]) -> list[tuple[FloatArray, Summary | None]]:
        keys: list[Key] = [(t[0], t[1], t[3] and self.subsampled) for t in tasks]
        # one variant over seeds on the whole schedule: its summaries are kept (see the class)
        one = len({k[0] for k in keys}) == 1 and not any(k[2] for k in keys)
        summaries = {k: v for kept in self._summaries.values() for k, v in kept.items()}
        todo: dict[Key, Task] = {}
        for t, key in zip(tasks, keys, strict=True):
            if key not in self._features or (t[2] and key not in summaries):
                full = one or t[2] or (key in todo and todo[key][2])
                todo[key] = (t[0], t[1], full, t[3])
        run = list(todo.values())
        out = [_job(t) for t in run] if self.pool is None else list(self.pool.map(_job, run, chunksize=1))
        real = _JOB["space"].real_regimes
        for key, (f, s) in zip(todo, out, strict=True):
            self._features[key] = f
            if s is not None:
                summaries[key] = (s[0], real if s[1] is _REAL_REGIMES else s[1])
        if one:  # the last KEEP_VARIANTS such variants (the held-out folds and the fit on all groups)
            variant = keys[0][0]
            self._summaries.pop(variant, None)
            self._summaries[variant] = {key: summaries[key] for key in keys if key in summaries}
            while len(self._summaries) > KEEP_VARIANTS:
                self._summaries.pop(next(iter(self._summaries)))
        pairs = zip(tasks, keys, strict=True)
        return [(self._features[key], summaries[key] if t[2] else None) for t, key in pairs]

    def close(self) -> None:
        if self.pool is not None:
            self.pool.close()
            self.pool.join()
            self.pool = None
