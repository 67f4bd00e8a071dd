"""Step 4 of the diagnosis: how much of the gap do the named effects remove?

Held-out losses of a flexible black-box residual model and the null expectation of the
held-out loss (each simulated seed against the others); the shrink itself is
:func:`uwbcal.gap.stats.shrink_ci` of these per-group excess losses.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from uwbcal.gap.config import FloatArray, IntArray
from uwbcal.gap.localise import Cell, is_open


def blackbox_losses(
    r: FloatArray, groups: IntArray, n_groups: int, slot: IntArray, gpos: FloatArray, ridge: float = 1.0
) -> FloatArray:
    """Held-out loss per group of a flexible residual model.

    Per feature slot (observable x cell x statistic), a ridge-regularised line in the group's
    position ``gpos`` (time or step), fitted on the other groups: a binned regression on the
    regime variables with a trend across groups.
    """
    out = np.zeros(n_groups)
    n_slots = int(slot.max()) + 1 if slot.size else 0
    x = gpos[groups]
    for g in range(n_groups):
        tr = groups != g
        w = np.bincount(slot[tr], minlength=n_slots).astype(np.float64)
        sx = np.bincount(slot[tr], weights=x[tr], minlength=n_slots)
        sy = np.bincount(slot[tr], weights=r[tr], minlength=n_slots)
        sxx = np.bincount(slot[tr], weights=x[tr] ** 2, minlength=n_slots)
        sxy = np.bincount(slot[tr], weights=x[tr] * r[tr], minlength=n_slots)
        mx = sx / np.maximum(w, 1)
        my = sy / np.maximum(w, 1)
        vx = sxx - w * mx**2
        cxy = sxy - w * mx * my
        slope = cxy / (vx + ridge)
        te = ~tr
        pred = my[slot[te]] + slope[slot[te]] * (x[te] - mx[slot[te]])
        out[g] = float(np.sum((r[te] - pred) ** 2))
    return out


def null_loss(f_sims: FloatArray, good: npt.NDArray[np.bool_], groups: IntArray, n_groups: int) -> FloatArray:
    """Expected held-out loss per group under a correct model: each seed against the others."""
    k = f_sims.shape[0]
    out = np.zeros(n_groups)
    for j in range(k):
        others = np.delete(f_sims, j, axis=0)
        m = np.nanmean(others, axis=0)[good]
        s = np.nanstd(others, axis=0, ddof=1)[good] * np.sqrt(1.0 + 1.0 / (k - 1))
        rj = (f_sims[j][good] - m) / np.where(s > 0, s, 1.0)
        rj = np.where(np.isfinite(rj), rj, 0.0)
        out += np.bincount(groups, weights=rj * rj, minlength=n_groups)
    return np.asarray(out / k, dtype=np.float64)


def cells_closed(
    before: Sequence[Cell], after: Sequence[Cell], alpha: float, closed: float
) -> float | None:
    """Fraction of the differing places (localisation cells) that the named effects close.

    Every cell that differs before (some statistic with q < ``alpha``) is one place, whatever its
    |z|: the sum of z^2 lets the most precisely measured observable (the clock rate, known to
    1e-4 ppm) decide alone. A place that is no longer significant counts 0; one still significant
    but closed by the verdict's rule (:func:`localise.is_open`: no statistic keeps more than
    ``closed`` times its |z| before) counts the fraction of its largest |z| it keeps; one still
    open counts 1, as does a cell that differs only with the named effects (a new discrepancy). Result
    1 - left / max(places, left), in [0, 1]; ``None`` when no cell differs either way.

    An open place counts whole: counted by the |z| it kept, a wrong flexible effect that brings
    a clock-rate cell from z 200 to 20 earned 90 % of it (blind decoys, a frequency step and a
    cycle, read 90 % and 87 % with 7 of 26 and 18 of 52 places open).
    """
    prev = {c.ident: c for c in before}
    places = sum(1 for c in before if min(c.q) < alpha)
    left = 0.0
    for c in after:
        sig = [i for i, q in enumerate(c.q) if q < alpha]
        if not sig:
            continue
        b = prev.get(c.ident)
        if b is None or is_open(c, b, alpha, closed):  # open, or new (not significant before)
            left += 1.0
            continue
        # closed: every significant statistic was significant before, so b has some
        z_after = max(abs(c.z[i]) for i in sig)
        z_before = max(abs(b.z[i]) for i, q in enumerate(b.q) if q < alpha)
        left += min(1.0, z_after / z_before) if z_before > 0 else 1.0
    if places == 0 and left == 0.0:
        return None
    return 1.0 - left / max(float(places), left)


def checks_passed(before: Sequence[int], after: Sequence[int]) -> float | None:
    """Fraction of the failing time-shape checks (model criticism) that pass with the named effects.

    ``before``/``after``: identifiers of the checks failing against the believed scenario and
    against it with the named effects. A check failing only with them counts as one more left.
    1 - left / max(failing before, left), in [0, 1]; ``None`` when no check fails either way.
    """
    b, a = set(before), set(after)
    if not b and not a:
        return None
    return 1.0 - len(a) / max(len(b), len(a))
