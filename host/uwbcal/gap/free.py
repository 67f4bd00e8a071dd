"""Free per-step terms of a power sweep: the discrepancy's own shape, named by where it lives.

A power-dependent departure of another functional form than the catalogue's (a bias curve of
another shape, an RX level estimate that compresses with another slope, gain steps each off by
an error of its own) is left "unexplained" by a one-magnitude knob: the named effect is right
but the cells of some steps still differ. Issue 13 asks for a flexible per-effect term with the
effect named from where the discrepancy lives. These terms are one free number per (receiver,
power step), added to the simulated records:

- ``free:stamp:<rx>:<step>``: P2's RX timestamp at receiver ``rx`` in step ``step`` is late by
  this many metres of path (device units, rounded stochastically so the mean shift is exact);
- ``free:level:<rx>:<step>``: the RX level the chip reports for P2 is higher by this many dB
  (through CIR_PWR, as the chip's registers would carry it);
- ``free:lscale:<rx>:<step>``: P2's reported levels spread about their step mean by exp(value)
  times (a compressed estimate, slope below 1, also compresses the level's own noise);
- ``free:l13scale:<rx>:-1``: the same for the levels of P1 and P3 (constant gain, every step);
- ``free:lmap:-1:-1`` with ``free:lknot:<rx>:<level in 0.01 dBm>`` knots: a per-level map, every
  reported level of receiver ``rx`` (P1, P2 and P3) higher by the knots' value interpolated at that
  level, times the ``lmap`` magnitude (:func:`level_map`). A compression whose knee falls inside
  a power step bends that step's level distribution, which an offset and a spread per step cannot.

Where the fitted discrepancy lives names the effect (:func:`name_of`, from the per-step terms):
stamps alone, the power-dependent timestamp error (``power_bias``); levels alone (offsets or
spreads), the RX level estimate (``rx_power_estimate``); stamps and levels, the power that really
reached the receiver (``tx_gain``: a real power error moves the reported level and, through the
bias curve, the stamp), unless more of the stamps' variation than ``Config.free_uncoupled_share``
sits where the levels do not move (:func:`stamps_without_power_error`): then the bias curve and the
level estimate (``SPLIT``). A
P1/P3 level spread term stands for the level estimate whatever the per-step terms name
(:func:`effect_of`).

Their signatures are exact, not simulated (:func:`signatures`): a stamp offset moves the mean
and the robust location of the eq. 1 residual of that step's cells by the offset, a level
offset those of the RX level, a spread factor the log robust scale of the RX level (or of the
P3 - P1 level) by its log, and nothing else.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Final, NamedTuple

import numpy as np
import numpy.typing as npt

from uwbcal.dw1000 import METRES_PER_UNIT, TIMESTAMP_MOD
from uwbcal.gap import observables as obs_mod
from uwbcal.gap.attribute import Candidate, Signature
from uwbcal.gap.config import FloatArray, IntArray, Records, Simulator, Variant
from uwbcal.gap.features import FeatureSpace
from uwbcal.gap.stats import FEATURE_NAMES

PREFIX: Final = "free:"
_LOCATION: Final = tuple(FEATURE_NAMES.index(s) for s in ("mean", "robust_loc"))
_SCALE: Final = (FEATURE_NAMES.index("log_scale"),)


class Kind(NamedTuple):
    """One kind of free term: the observable it moves, which of its feature statistics, whether
    there is one term per power step (else one per receiver), the term's unit and plain words."""

    observable: str
    stats: tuple[int, ...]
    per_step: bool
    unit: str
    words: str


KINDS: Final[dict[str, Kind]] = {
    "stamp": Kind("drift_residual_m", _LOCATION, True, "m", "P2 RX timestamp offset per power step"),
    "level": Kind("rx_level_dbm", _LOCATION, True, "dB", "P2 reported RX level offset per power step"),
    "lscale": Kind(
        "rx_level_dbm", _SCALE, True, "", "log spread factor of P2's reported level per power step"
    ),
    "l13scale": Kind("p13_level_db", _SCALE, False, "", "log spread factor of P1's and P3's reported levels"),
}
#: The per-level map's magnitude knob and its knots' kind (:func:`level_map`); its knots are
#: shape settings of one candidate, not terms with signatures of their own.
MAP_KNOB: Final = f"{PREFIX}lmap:-1:-1"
_KNOT: Final = "lknot"
MAP_WORDS: Final = "reported RX level mapped level by level onto the recording's (per-level map)"
#: Knot spacing of the map (dB) and the quantiles of each (receiver, step) it is fitted at.
_MAP_STEP_DB: Final = 0.05
_MAP_QUANTILES: Final = np.linspace(0.02, 0.98, 25)
#: Fewest finite levels on each side for a (receiver, step) to enter the map's fit.
_MAP_MIN_LEVELS: Final = 20
#: Which catalogue effect each kind's discrepancy points at (:func:`name_of`).
_FAMILY_OF_KIND: Final = {"stamp": "stamp", "level": "level", "lscale": "level", "l13scale": "level"}
#: What stamps and levels needed together name when the stamps are not a power error's
#: (:func:`stamps_without_power_error`): the bias curve and the level estimate, each its own kind.
SPLIT: Final = "power_bias+rx_power_estimate"
#: Catalogue effects a free per-step term stands in for (the power-dependent ones).
POWER_FAMILY: Final = ("power_bias", "rx_power_estimate", "tx_gain")


def is_free(knob: str) -> bool:
    """Whether a knob id is a free per-step term."""
    return knob.startswith(PREFIX)


def parse(knob: str) -> tuple[str, int, int]:
    """(kind, receiver station, step) of a free knob id."""
    _, kind, rx, step = knob.split(":")
    return kind, int(rx), int(step)


def name_of(kinds: set[str]) -> str | None:
    """The catalogue effect a set of needed term kinds points at (see the module docstring); None
    unless a per-step kind is among them (a discrepancy alike in every step is no power effect).

    Only the per-step kinds name it: a power error in P2's steps moves P2's stamps and levels
    step by step and leaves P1 and P3 (constant gain) alone, so a P1/P3 level spread next to
    per-step stamps is no sign of a power error (it is the level estimate's, :func:`effect_of`).
    A blind tanh power bias was named a TX gain error from per-step stamps and that spread."""
    if not any(per_step(k) for k in kinds):
        return None
    where = {_FAMILY_OF_KIND[k] for k in kinds if per_step(k)}
    if where == {"stamp"}:
        return "power_bias"
    if where == {"level"}:
        return "rx_power_estimate"
    if where == {"stamp", "level"}:
        return "tx_gain"
    return None


def stamps_without_power_error(
    real_stamp: FloatArray,
    real_level: FloatArray,
    sim_stamp: FloatArray,
    sim_level: FloatArray,
    rx: IntArray,
    step: IntArray,
    margin: float,
) -> float | None:
    """Share (0-1) of the P2 stamps' variation over the power steps that no real power error can
    put there; None when no receiver has two steps with finite stamps and levels.

    A real power error of e dB in a step (what :func:`name_of` calls ``tx_gain`` when stamps and
    levels are both needed) moves that step's reported P2 level by about e (less where the
    estimate compresses) and its stamp through the bias curve, by about its slope times e. Where
    the level does not move, neither does the stamp. A bias curve of another shape next to a
    compressing level estimate moves the stamps of steps whose levels stay put.

    Per receiver and step, real minus believed: the stamp discrepancy s_i (per-step mean of the
    eq. 1 residual, m) and the level discrepancy l_i (mean reported P2 level, dB); ``sim_*`` are
    (seeds, records) re-simulations of the believed scenario. The steepest stamp per reported dB
    that the power error can give, k (m/dB), is ``margin`` times the steepest secant of the
    re-simulations' per-step mean stamp against their mean level between adjacent steps (the
    believed curve seen through the believed estimate; the real curve may be steeper). A step's
    stamp beyond k |l_i| cannot come from its power: the share is the sum over steps of
    max(0, |s_i - c| - k |l_i|)^2, c the common offset that minimises it (a discrepancy alike in
    every step is no power effect), over the sum of (s_i - mean s)^2, pooled over receivers."""
    from scipy.optimize import minimize_scalar

    excess = total = 0.0
    for sid in np.unique(rx):
        ds, dl, ms, ml = [], [], [], []
        for st in np.unique(step[rx == sid]):
            sel = (rx == sid) & (step == st) & np.isfinite(real_stamp) & np.isfinite(real_level)
            if not sel.any():
                continue
            s_sim, l_sim = sim_stamp[:, sel], sim_level[:, sel]
            if not (np.isfinite(s_sim).any() and np.isfinite(l_sim).any()):
                continue
            ms.append(float(np.nanmean(s_sim)))
            ml.append(float(np.nanmean(l_sim)))
            ds.append(float(np.mean(real_stamp[sel])) - ms[-1])
            dl.append(float(np.mean(real_level[sel])) - ml[-1])
        if len(ds) < 2:
            continue
        order = np.argsort(ml)
        d_l = np.diff(np.asarray(ml)[order])
        d_s = np.diff(np.asarray(ms)[order])
        ok = d_l > 0
        k = margin * float(np.max(np.abs(d_s[ok] / d_l[ok]))) if ok.any() else 0.0
        s, room = np.asarray(ds), k * np.abs(np.asarray(dl))
        spread = float(np.sum((s - s.mean()) ** 2))
        if spread == 0.0:
            continue

        def hinge(c: float, s: FloatArray = s, room: FloatArray = room) -> float:
            return float(np.sum(np.maximum(0.0, np.abs(s - c) - room) ** 2))

        best = minimize_scalar(hinge, bounds=(float(s.min()), float(s.max())), method="bounded")
        excess += min(float(best.fun), hinge(float(np.median(s))))
        total += spread
    return excess / total if total > 0.0 else None


def effect_of(kind: str, name: str) -> str:
    """The catalogue effect a needed term of ``kind`` stands for when the per-step terms name
    ``name`` (:func:`name_of`, or ``SPLIT``): ``name`` for a per-step kind; for a P1/P3 kind, the
    RX level estimate (those levels come at constant gain, so no power effect of P2 moves them).
    Under ``SPLIT`` the stamps stand for the bias curve and the levels for the level estimate."""
    if name == SPLIT:
        return "power_bias" if _FAMILY_OF_KIND[kind] == "stamp" else "rx_power_estimate"
    return name if per_step(kind) else "rx_power_estimate"


def words(kind: str) -> str:
    """Plain words for a free kind (a per-step kind's, or the per-level map's)."""
    return MAP_WORDS if kind == parse(MAP_KNOB)[0] else KINDS[kind].words


def level_map(real_lv: FloatArray, sim_lv: FloatArray, rx: IntArray, step: IntArray) -> Candidate | None:
    """A per-level map of the reported RX level (dBm) fitted to the recording: the candidate
    ``rx_power_estimate`` whose shape is the knots and whose knob (``MAP_KNOB``, 1 = the map as
    fitted) scales them; None if no (receiver, step) has levels enough.

    ``real_lv`` P2's reported level per real record, ``sim_lv`` the same per re-simulated seed and
    record (seeds x records, the believed scenario), ``rx``/``step`` each record's receiver and
    power step. In every (receiver, step) the same power reaches the chip in both, so the real
    level's quantiles against the simulated ones trace the map from the believed reported level to
    the real one; pooled over a receiver's steps, an increasing fit (isotonic regression: an RX
    level estimate never falls as the power rises) through those pairs is the map, knotted every
    0.05 dB over the levels seen and held at its end values beyond them. It moves levels only, so
    it stands for the RX level estimate (:func:`name_of`: levels alone)."""
    from scipy.optimize import isotonic_regression

    shape: list[tuple[str, float]] = []
    for sid in np.unique(rx).tolist():
        xs: list[FloatArray] = []
        ys: list[FloatArray] = []
        for k in np.unique(step[rx == sid]).tolist():
            sel = (rx == sid) & (step == k)
            a, b = real_lv[sel], sim_lv[:, sel]
            a, b = a[np.isfinite(a)], b[np.isfinite(b)]
            if min(a.size, b.size) >= _MAP_MIN_LEVELS:
                xs.append(np.quantile(b, _MAP_QUANTILES))
                ys.append(np.quantile(a, _MAP_QUANTILES))
        if not xs:
            continue
        x, y = np.concatenate(xs), np.concatenate(ys)
        o = np.argsort(x, kind="stable")
        x, g = x[o], np.asarray(isotonic_regression(y[o], increasing=True).x, np.float64)
        lo, hi = np.floor(x[0] / _MAP_STEP_DB), np.ceil(x[-1] / _MAP_STEP_DB)
        grid = np.arange(lo, hi + 1) * _MAP_STEP_DB
        delta = np.interp(grid, x, g) - grid
        shape += [
            (f"{PREFIX}{_KNOT}:{sid}:{round(v * 100)}", float(d)) for v, d in zip(grid, delta, strict=True)
        ]
    if not shape:
        return None
    return Candidate(
        effect="rx_power_estimate",
        knob=MAP_KNOB,
        baseline=0.0,
        grid=(0.5, 1.0, 1.5),
        unit="",
        description=f"{MAP_WORDS}: {len(shape)} knots, magnitude 1 = as fitted (free term)",
        shape=tuple(shape),
    )


def _mapped(lv: FloatArray, knots: list[tuple[float, float]], amp: float) -> FloatArray:
    """The per-level map's change (dB) of levels ``lv`` (dBm): ``amp`` x the knots' (level dBm,
    change dB) interpolated, held at the end values; 0 where a level is not finite."""
    k = np.array(sorted(knots), np.float64)
    return np.nan_to_num(amp * np.interp(lv, k[:, 0], k[:, 1]))


def apply(rec: Records, terms: Mapping[str, float], seed: int) -> dict[str, Any]:
    """Records with the free terms ``{knob: value}`` added (see the module docstring)."""
    out = dict(rec)
    if not terms:
        return out
    rx = np.asarray(rec["rx_station"], np.int64)
    step = np.asarray(rec["step"], np.int64) if rec.get("step") is not None else np.zeros(rx.size, np.int64)
    stamp = np.zeros(rx.size)
    level = {k: np.zeros(rx.size) for k in (1, 2, 3)}
    lv: dict[int, FloatArray] | None = None
    knots: dict[int, list[tuple[float, float]]] = {}
    for knob, value in terms.items():
        kind, sid, k = parse(knob)
        sel = ((rx == sid) | (sid < 0)) & ((step == k) | (k < 0))
        if kind == _KNOT:
            knots.setdefault(sid, []).append((k / 100.0, float(value)))
        elif knob == MAP_KNOB:
            continue
        elif kind == "stamp":
            stamp[sel] += value / METRES_PER_UNIT
        elif kind == "level":
            level[2][sel] += value
        elif kind in ("lscale", "l13scale"):
            lv = obs_mod.levels(rec) if lv is None else lv
            for m in (2,) if kind == "lscale" else (1, 3):
                if m in lv and np.any(sel & np.isfinite(lv[m])):
                    dev = lv[m] - np.nanmean(lv[m][sel])
                    level[m][sel] += np.nan_to_num(np.expm1(value) * dev[sel])
        else:
            raise ValueError(f"unknown free term {knob!r}")
    amp = float(terms.get(MAP_KNOB, 0.0))
    if knots and amp != 0.0:
        lv = obs_mod.levels(rec) if lv is None else lv
        for sid, kn in knots.items():
            sel = rx == sid
            for m in (1, 2, 3):
                if m in lv:
                    level[m][sel] += _mapped(lv[m][sel], kn, amp)
    if np.any(stamp):
        rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, 1313])
        add = np.floor(stamp + rng.random(rx.size)).astype(np.int64)  # mean shift exact
        old = np.asarray(rec["rx2"], np.int64)
        new = old + np.where(stamp != 0, add, 0)
        out["rx2"] = new % TIMESTAMP_MOD if np.all(old < TIMESTAMP_MOD) else new
    for m, d in level.items():
        if np.any(d) and rec.get(f"cir_pwr{m}") is not None:
            c = np.asarray(rec[f"cir_pwr{m}"])
            scaled = np.asarray(c, np.float64) * 10.0 ** (d / 10.0)
            out[f"cir_pwr{m}"] = np.where(d != 0, np.maximum(np.rint(scaled), 1), c).astype(c.dtype)
    return out


def wrap(simulate: Simulator) -> Simulator:
    """A simulator that also understands free knobs (the rest of the variant goes to ``simulate``)."""

    def sim(variant: Variant, seed: int) -> Records:
        terms = {k: v for k, v in variant if is_free(k)}
        if not terms:
            return simulate(variant, seed)
        rec = simulate(tuple((k, v) for k, v in variant if not is_free(k)), seed)
        return apply(rec, terms, seed)

    return sim


def _feature_segments(space: FeatureSpace) -> tuple[IntArray, IntArray]:
    """(receiver station, step) of every feature's cell; -1 where the layout has none."""
    nf = space.n_features
    step = np.full(nf, -1, np.int64)
    rx = np.full(nf, -1, np.int64)
    if space.group_regime == "step":
        step = space.group_keys[space.feat_group]
    elif "step" in space.cell_regimes:
        step = space.cell_keys[space.feat_cell, space.cell_regimes.index("step")]
    if "direction" in space.cell_regimes:
        rx = space.cell_keys[space.feat_cell, space.cell_regimes.index("direction")] % 1000
    return rx, step


def offered(space: FeatureSpace) -> bool:
    """Whether the layout separates power steps (a sweep) so free per-step terms can be fitted."""
    return space.group_regime == "step" or "step" in space.cell_regimes


def signatures(
    space: FeatureSpace, good: npt.NDArray[np.bool_], sd: FloatArray, r: FloatArray, family: str
) -> list[Signature]:
    """Exact signatures of every free term the layout holds, labelled with effect ``family``.

    ``sd`` the floor's SD per feature (all features), ``r`` the standardised residual on the good
    ones: each term's grid spans twice the largest residual it could have to carry.
    """
    rx, step = _feature_segments(space)
    rx, step = rx[good], step[good]
    obs, stat = space.feat_obs[good], space.feat_stat[good]
    s = sd[good]
    out: list[Signature] = []
    for kind, (observable, stats_, per_step, unit, words) in KINDS.items():
        if observable not in space.observables:
            continue
        oi = space.observables.index(observable)
        hit_obs = (obs == oi) & np.isin(stat, stats_) & (step >= 0)
        segs = {(int(a), int(b) if per_step else -1) for a, b in zip(rx[hit_obs], step[hit_obs], strict=True)}
        for sid, k in sorted(segs):
            hit = hit_obs & (rx == sid) & ((step == k) | (k < 0))
            w = np.where(hit, 1.0 / s, 0.0)
            span = 2.0 * float(np.max(np.abs(r[hit]) * s[hit])) if np.any(hit) else 0.0
            if not span > 0:
                continue
            thetas = np.array([-span, 0.0, span])
            cand = Candidate(
                effect=family,
                knob=f"{PREFIX}{kind}:{sid}:{k}",
                baseline=0.0,
                grid=(-span, span),
                unit=unit,
                description=f"{words} (free term: receiver {sid}" + (f", step {k})" if k >= 0 else ")"),
            )
            out.append(
                Signature(
                    candidate=cand,
                    thetas=thetas,
                    deltas=thetas[:, None] * w[None, :],
                    log_ratio=np.zeros((3, w.size)),
                    trace_z=float("inf"),
                )
            )
    return out


def common(sigs: list[Signature]) -> list[Signature]:
    """Per receiver, one term moving all of ``sigs``' steps alike (their deltas at a common value):
    what a discrepancy that does not depend on the power step needs (an antenna delay, late paths
    on every reception), against which the per-step terms' variation is tested."""
    out: list[Signature] = []
    for sid in sorted({parse(sg.candidate.knob)[1] for sg in sigs}):
        mine = [sg for sg in sigs if parse(sg.candidate.knob)[1] == sid]
        span = max(float(sg.thetas[-1]) for sg in mine)
        thetas = np.array([-span, 0.0, span])
        w = sum(sg.deltas[-1] / float(sg.thetas[-1]) for sg in mine)
        kind = parse(mine[0].candidate.knob)[0]
        cand = Candidate(
            effect=mine[0].candidate.effect,
            knob=f"{PREFIX}{kind}:{sid}:-1",
            baseline=0.0,
            grid=(-span, span),
            unit=mine[0].candidate.unit,
            description=f"{KINDS[kind].words}, one value for every step (receiver {sid})",
        )
        out.append(Signature(cand, thetas, thetas[:, None] * np.asarray(w)[None, :], np.zeros((3, w.size))))
    return out


def per_step(kind: str) -> bool:
    """Whether a kind has one term per power step (else one per receiver)."""
    return KINDS[kind].per_step


def _map_summary(n: dict[str, Any]) -> dict[str, Any]:
    """The per-level map's named entry with its knots (the shape) as the change at every whole
    dBm they span, per receiver (``per_level``, dB: magnitude times the fitted map)."""
    amp = float(n["fitted"])
    by: dict[int, list[tuple[float, float]]] = {}
    for knob, v in n["shape"]:
        _, sid, c = parse(str(knob))
        by.setdefault(sid, []).append((c / 100.0, float(v)))
    per: dict[str, float] = {}
    for sid, kn in sorted(by.items()):
        at = np.arange(np.ceil(min(kn)[0]), np.floor(max(kn)[0]) + 1.0)
        per.update(
            {f"rx {sid} at {x:.0f} dBm": float(d) for x, d in zip(at, _mapped(at, kn, amp), strict=True)}
        )
    return {
        **n,
        "shape": [],
        "description": f"{MAP_WORDS} (free term, not a scenario parameter)",
        "per_level": per,
    }


def summarise(named: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Named entries with the free terms of each kind collapsed into one (fitted = RMS, per step)."""
    out: list[dict[str, Any] | str] = []  # a str marks where a kind's collapsed entry goes
    groups: dict[str, list[dict[str, Any]]] = {}
    for n in named:
        if str(n["knob"]) == MAP_KNOB:
            out.append(_map_summary(n))
        elif is_free(str(n["knob"])):
            kind = parse(str(n["knob"]))[0]
            if kind not in groups:
                out.append(kind)
            groups.setdefault(kind, []).append(n)
        else:
            out.append(n)
    collapsed: dict[str, dict[str, Any]] = {}
    for kind, rows in groups.items():
        vals = np.array([float(n["fitted"]) for n in rows])
        unit, words = KINDS[kind].unit, KINDS[kind].words
        collapsed[kind] = {
            "effect": rows[0]["effect"],
            "knob": f"{PREFIX}{kind}",
            "shape": [],
            "fitted": float(np.sqrt(np.mean(vals**2))),
            "baseline": 0.0,
            "unit": unit,
            "description": f"{words} (RMS over {len(rows)} steps; free terms, not a scenario parameter)",
            "at_grid_edge": any(bool(n["at_grid_edge"]) for n in rows),
            "per_step": {
                f"rx {parse(str(n['knob']))[1]} step {parse(str(n['knob']))[2]}": float(n["fitted"])
                for n in rows
            },
        }
    return [collapsed[n] if isinstance(n, str) else n for n in out]
