"""Settings and shared types of the gap diagnosis (the engine's vocabulary, no logic)."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
Records = Mapping[str, Any]
#: Knob settings on top of the believed scenario: ((knob id, value), ...).
Variant = tuple[tuple[str, float], ...]
Simulator = Callable[[Variant, int], Records]


@dataclass
class Config:
    """Settings of one diagnosis (defaults are what `uwbcal gap` uses)."""

    # 64 and 12, not 16 and 3: with the Monte-Carlo noise of 16 / 3 seeds the real asil run's
    # named set changed with --seed (GAP.md, "Stable verdicts"); the fast engine affords it
    n_seeds: int = 64  # baseline re-simulations (noise floor and m0, s)
    n_seeds_signature: int = 12  # paired seeds per candidate grid value
    signature_max_records: int = 25_000  # signatures on a subsample of longer sessions
    # sessions longer than signature_max_records: each candidate's signature is first taken on
    # this many of the n_seeds_signature seeds, and on all of them only if its mean changes are not
    # yet known to signature_se floor SDs (RMS Monte-Carlo SE; 0: all seeds for every candidate).
    # Sessions of signature_max_records or fewer always use all seeds
    signature_seeds_first: int = 4
    signature_se: float = 0.25
    jobs: int = 1  # worker processes for the simulations
    n_time_blocks: int = 10  # groups of a drift run
    alpha: float = 0.01  # BH FDR level of the localisation
    criticism_alpha: float = 0.001  # model criticism fails below this Holm p (a guard against gross misfits)
    # a time-local departure of the jitter (criticism's ``burst``) fails below this Bonferroni p: the
    # localisation's level, as for any other place of the gap
    burst_alpha: float = 0.01
    min_cell: int = 20  # fewest real records in a localisation cell
    min_feature: int = 8  # fewest records in a feature cell
    max_effects: int = 5  # forward selection stops at this many
    refine_rounds: int = 4  # rounds of the shape refinement of an effect named but not explaining
    min_trace_z: float = 8.0  # drop candidates whose signature stands out of Monte-Carlo noise by less
    explained_shrink: float = 0.5  # named effects must remove this much of the held-out gap
    # stamps and levels needed per power step name a TX gain error unless more than
    # free_uncoupled_share of the stamps' variation sits beyond free_slope_margin x the believed
    # curve's steepest stamp per reported dB times the step's level change (free.py)
    free_slope_margin: float = 2.0
    free_uncoupled_share: float = 0.25
    cell_closed: float = 0.2  # a cell is closed when |z| with the named effects <= this x |z| before
    selection_level: float = 0.99  # CI level of the forward-selection stopping rule
    # believed re-simulations (the first null_seeds of the n_seeds) on every one of which a pick
    # must improve the held-out loss less than on the real session (attribute._beyond_chance);
    # fewer than min_null_seeds available: no such check
    null_seeds: int = 64
    min_null_seeds: int = 8
    ks_ref_max: int = 50_000  # pooled reference subsample for the KS distance
    seed: int = 0  # base seed of the re-simulations and bootstraps
    n_boot: int = 2000
    prf_mhz: int = 64  # the session's PRF (MHz; meta radio.prf_mhz): the RX level estimate's A depends on it
