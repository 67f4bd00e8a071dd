"""Simulation jobs of the diagnosis: simulate a variant at a seed and reduce it to features,
serially or in a forked process pool."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

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
    f = space.features(rec, _JOB["min_feature"])
    if not full:
        return f, None
    ob, reg = summarise(rec, space.t_edges, space.real_regimes, space.prf_mhz)
    # the real session's regimes (a re-simulation of its schedule) stay home: Runner.map puts
    # the same object back, so they are neither pickled nor held once per seed
    home = reg is space.real_regimes and space is _JOB["space"]
    return f, (ob, _REAL_REGIMES if home else reg)


class Runner:
    """Runs simulation jobs serially or in a forked process pool (``jobs`` > 1)."""

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
        self.pool: Any = None
        if cfg.jobs > 1:
            import multiprocessing as mp

            try:
                self.pool = mp.get_context("fork").Pool(cfg.jobs)
            except (OSError, ValueError):
                self.pool = None

    def map(self, tasks: Sequence[Task]) -> list[tuple[FloatArray, Summary | None]]:
        out = [_job(t) for t in tasks] if self.pool is None else list(self.pool.map(_job, tasks, chunksize=1))
        real = _JOB["space"].real_regimes
        return [(f, None if s is None else (s[0], real if s[1] is _REAL_REGIMES else s[1])) for f, s in out]

    def close(self) -> None:
        if self.pool is not None:
            self.pool.close()
            self.pool.join()
            self.pool = None
