"""The bridge from the gap engine to the physics catalogue: knobs, candidates, re-simulation.

A *knob* is one number of the believed scenario that a candidate effect changes, named by a
string id:

- ``effect:<name>:<parameter>``: an effect parameter (switching the effect on);
- ``station:<id>:<field>``: a per-station hardware value (switching on the effect that
  governs it);
- ``switch:<name>``: an effect's on/off switch (1 on, 0 off).

:data:`KNOBS` says, per catalogue effect, which knob carries its magnitude and which grid of
values the signature is simulated at. An effect missing from the table (a catalogue
addition) falls back to its switch or its first parameter; the report names it.
:data:`PER_STATION_KNOBS` adds, for some effects, one more candidate per scenario station
(named ``<effect>[<station id>]``, e.g. ``timestamp_noise[1]`` for station 1's
``noise_scale``): offered only when the real session has at least two receivers, since with
one receiver a per-station scale is the effect's global knob again. :data:`PER_STATION_TX_KNOBS`
adds one per station for its transmitter (``timestamp_noise_tx[2]``: station 2's
``tx_noise_scale``), offered only with three or more transmitters.

The simulator itself is :mod:`uwbcal.vectorsim` (schedule-driven, vectorised); this module
only changes scenarios and maps station ids between the real session and the scenario.
"""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Final

import numpy as np

from uwbcal.errors import ScenarioError
from uwbcal.gap.config import FloatArray
from uwbcal.gap.engine import Candidate, Records, Variant
from uwbcal.physics.effects import EFFECTS, TAIL_WEIGHT_MAX
from uwbcal.physics.scenario import Scenario

#: Which station field belongs to which effect (switching the knob on switches the effect on).
STATION_FIELD_EFFECT: Final[dict[str, str]] = {
    "ppm": "clock_offset",
    "warmup_ppm": "warmup",
    "warmup_tau_s": "warmup",
    "warmup2_ppm": "warmup",
    "warmup2_tau_s": "warmup",
    "tempco_ppm_per_c": "temperature",
    "self_heating_c": "temperature",
    "tx_delay_error_ps": "antenna_delay",
    "rx_delay_error_ps": "antenna_delay",
    "bias_scale": "power_bias",
    "bias_shift_db": "power_bias",
    "bias_offset_ps": "power_bias",
    "fine_scale": "tx_gain",
    "car_int_scale": "car_int_error",
    "noise_scale": "timestamp_noise",
    "tx_noise_scale": "timestamp_noise",
}


@dataclass(frozen=True)
class KnobSpec:
    """How one effect's magnitude is varied.

    ``target`` "effect" (a parameter of the effect), "station" (a field of the scenario's
    ``station`` index: 0 first, 1 second, ... in file order) or "switch". ``kind`` "abs"
    (grid values as given), "add" (added to the believed value) or "mul" (times the believed
    value). ``unit`` of the knob.
    """

    target: str
    name: str
    kind: str
    values: tuple[float, ...]
    unit: str
    station: int = 1


#: Magnitude knob and signature grid per catalogue effect (see the module docstring).
KNOBS: Final[dict[str, KnobSpec]] = {
    "clock_offset": KnobSpec("station", "ppm", "add", (-6.0, -1.5, 1.5, 6.0), "ppm"),
    "warmup": KnobSpec("station", "warmup_ppm", "add", (-3.0, -1.0, -0.3, 0.3, 1.0, 3.0), "ppm"),
    "clock_wander": KnobSpec(
        "effect", "sigma_ppm_per_sqrt_s", "abs", (0.0, 2e-3, 6e-3, 1.5e-2), "ppm/sqrt(s)"
    ),
    "temperature": KnobSpec("effect", "ramp_c_per_s", "abs", (-0.02, 0.02), "degC/s"),
    "timestamp_noise": KnobSpec("effect", "floor_ps", "abs", (5.0, 50.0, 100.0, 200.0), "ps"),
    "quantisation": KnobSpec("switch", "quantisation", "abs", (0.0, 1.0), ""),
    "timestamp_wrap": KnobSpec("switch", "timestamp_wrap", "abs", (0.0, 1.0), ""),
    "delayed_tx_grid": KnobSpec("switch", "delayed_tx_grid", "abs", (0.0, 1.0), ""),
    "antenna_delay": KnobSpec("station", "rx_delay_error_ps", "add", (-300.0, 300.0), "ps"),
    "path_loss": KnobSpec("effect", "exponent", "abs", (1.6, 2.0, 2.5, 3.0), ""),
    "tx_gain": KnobSpec("effect", "coarse_step_db", "abs", (2.5, 3.0, 3.5), "dB"),
    "power_bias": KnobSpec("effect", "amplitude_m", "mul", (0.0, 0.5, 2.0, 3.0), "m"),
    "rx_power_estimate": KnobSpec("effect", "knee_dbm", "add", (-10.0, -4.0, 4.0, 10.0), "dBm"),
    "car_int_error": KnobSpec("effect", "slope_ppm_per_db", "abs", (0.0, 0.02, 0.06, 0.12), "ppm/dB"),
    "interference": KnobSpec("effect", "amplitude_ps", "abs", (0.0, 150.0, 500.0, 1500.0), "ps"),
    "multipath": KnobSpec("effect", "probability", "abs", (0.0, 0.05, 0.15, 0.4), ""),
}

#: Per-station magnitude knobs (one candidate per scenario station, ``KnobSpec.station``
#: unused): the receiver's timestamp-jitter factor ``Station.noise_scale`` (wide grid: alone it
#: may have to carry a floor ten times the believed one).
PER_STATION_KNOBS: Final[dict[str, KnobSpec]] = {
    "timestamp_noise": KnobSpec("station", "noise_scale", "abs", (0.5, 2.0, 4.0, 8.0, 16.0, 32.0), ""),
}

#: Per-station transmitter knobs (one candidate per scenario station, named
#: ``<effect>_tx[<id>]``): the factor ``Station.tx_noise_scale`` on the catalogue's TX jitter
#: (``tx_jitter_ps``, 2 ps: the grid reaches 128 ps, the size of the asil nodes' jitter). In
#: direction i -> j the eq. 1 residual carries i's TX and j's RX jitter alike, so a transmitter's
#: scale can be told from the receivers' only when three or more stations transmit (with two, i's
#: TX and j's RX enter the same single direction): :data:`TX_SCALE_NEEDS`. Its own family
#: (:func:`uwbcal.gap.attribute.family`), so a receiver's scale is its runner-up rival.
PER_STATION_TX_KNOBS: Final[dict[str, KnobSpec]] = {
    "timestamp_noise": KnobSpec(
        "station", "tx_noise_scale", "abs", (0.5, 2.0, 4.0, 8.0, 16.0, 32.0, 64.0), ""
    ),
}
#: Fewest distinct transmitters for which a per-station TX scale is offered (Candidate.needs).
TX_SCALE_NEEDS: Final = ("tx_station", 3)


#: Other functional forms per effect (issue 13: a departure of another shape than the catalogue's
#: is left unnamed when the effect can only change its magnitude). Each entry is one alternative
#: shape: other knobs held at one value each (``KnobSpec.values[0]``, kind as in :data:`KNOBS`)
#: while the magnitude knob is fitted. Meant to span forms the effect takes in the world: warm-ups
#: settle over tens of seconds as well as minutes (two-stage crystal heating); late first paths
#: run from a few cm to half a metre (NLOS through people, walls), with an excess more or less
#: concentrated around its mean; the bias curve's centre and width vary with the receiver and PRF
#: [APS011]; the RX level estimate's compression differs between chips. They were chosen after
#: the blind trials (gap/blind.py) had shown which forms the catalogue missed, so those trials
#: are no longer a fully independent check of them (docs/GAP.md quotes only untuned seeds).
SHAPES: Final[dict[str, tuple[tuple[KnobSpec, ...], ...]]] = {
    "warmup": (
        (KnobSpec("station", "warmup_tau_s", "abs", (20.0,), "s"),),
        (KnobSpec("station", "warmup_tau_s", "abs", (60.0,), "s"),),
    ),
    "multipath": (
        (KnobSpec("effect", "mean_bias_m", "abs", (0.25,), "m"),),
        (KnobSpec("effect", "mean_bias_m", "abs", (0.5,), "m"),),
        (
            KnobSpec("effect", "mean_bias_m", "abs", (0.25,), "m"),
            KnobSpec("effect", "excess_shape", "abs", (4.0,), ""),
        ),
    ),
    "power_bias": (
        (KnobSpec("effect", "centre_dbm", "add", (-6.0,), "dBm"),),
        (KnobSpec("effect", "centre_dbm", "add", (6.0,), "dBm"),),
        (KnobSpec("effect", "width_db", "mul", (2.0,), "dB"),),
    ),
    "rx_power_estimate": (
        (KnobSpec("effect", "high_slope", "abs", (0.5,), "dB/dB"),),
        (KnobSpec("effect", "high_slope", "abs", (0.75,), "dB/dB"),),
    ),
}


@dataclass(frozen=True)
class ShapeAxis:
    """One continuous shape parameter of an effect, refined by :func:`shape_refiner`.

    ``target`` and ``name`` as in :class:`KnobSpec`; ``log``: a step multiplies the value by
    ``step`` (else adds ``step``, in ``unit``); values stay within ``bounds``.
    """

    target: str
    name: str
    log: bool
    step: float
    bounds: tuple[float, float]
    unit: str


#: The shape parameters that :func:`shape_refiner` moves, per effect (issue 13: "effects with their
#: shape parameters free, not one magnitude"). :data:`SHAPES` offers a few fixed forms; a departure
#: between them (late paths of 15 cm with a concentrated excess, a bias curve of another centre) is
#: named right but leaves cells that the nearest form cannot close. Bounds span what the world
#: shows: late paths of 2 cm to 2 m with a heavy-tailed (shape 0.3), exponential (1) or narrow
#: (30) excess; the bias curve's centre across the DW1000's RX range, its width from a step to a
#: slope; the timestamp jitter from Gaussian to a Student-t of 2.2 dof (``tail_weight`` = 1/dof:
#: blind seeds 24 and 25 left one cell each of a t(5) jitter named right, a time block's scale
#: or KS shape that the Gaussian of the same SD does not make). (Multipath's first-path power
#: drop is no axis: no observable of the diagnosis sees it.)
SHAPE_AXES: Final[dict[str, tuple[ShapeAxis, ...]]] = {
    "multipath": (
        ShapeAxis("effect", "mean_bias_m", True, 2.0, (0.02, 2.0), "m"),
        ShapeAxis("effect", "excess_shape", True, 3.0, (0.3, 30.0), ""),
    ),
    "power_bias": (
        ShapeAxis("effect", "centre_dbm", False, 4.0, (-105.0, -55.0), "dBm"),
        ShapeAxis("effect", "width_db", True, 2.0, (0.5, 40.0), "dB"),
    ),
    "rx_power_estimate": (ShapeAxis("effect", "high_slope", False, 0.2, (0.0, 1.0), "dB/dB"),),
    "timestamp_noise": (ShapeAxis("effect", "tail_weight", False, 0.15, (0.0, TAIL_WEIGHT_MAX), ""),),
}


def knob_id(effect: str, spec: KnobSpec, scenario: Scenario) -> str:
    """The knob id string of an effect's spec in a scenario."""
    if spec.target == "station":
        ids = scenario.station_ids
        sid = ids[min(spec.station, len(ids) - 1)]
        return f"station:{sid}:{spec.name}"
    if spec.target == "switch":
        return f"switch:{spec.name}"
    return f"effect:{effect}:{spec.name}"


def believed_value(knob: str, scenario: Scenario) -> float:
    """The believed scenario's value of a knob (0 for an effect it leaves off)."""
    kind, a, *rest = knob.split(":")
    if kind == "switch":
        return 1.0 if scenario.enabled(a) else 0.0
    if kind == "effect":
        eff = scenario.effect(a)
        return float(eff.values()[rest[0]]) if eff.enabled else _off_value(a, rest[0])
    st = scenario.station(int(a))
    eff_name = STATION_FIELD_EFFECT.get(rest[0])
    if eff_name is not None and not scenario.enabled(eff_name):
        return 0.0
    return float(getattr(st, rest[0]))


def _off_value(effect: str, param: str) -> float:
    """The parameter value that is equivalent to the effect being off (magnitude 0)."""
    if param in (
        "amplitude_ps",
        "probability",
        "sigma_ppm_per_sqrt_s",
        "slope_ppm_per_db",
        "ramp_c_per_s",
        "floor_ps",
        "amplitude_m",
    ):
        return 0.0
    return float(EFFECTS[effect]().values().get(param, 0.0))


def apply_variant(scenario: Scenario, variant: Variant) -> Scenario:
    """The scenario with the knob settings of ``variant`` applied (effects switched on)."""
    sc = scenario
    for knob, value in variant:
        kind, a, *rest = knob.split(":")
        if kind == "switch":
            sc = sc.with_effects(enabled={a: bool(value >= 0.5)})
        elif kind == "effect":
            sc = sc.with_effects(enabled={a: True}, params={a: {rest[0]: float(value)}})
        elif kind == "station":
            eff_name = STATION_FIELD_EFFECT.get(rest[0])
            if eff_name is not None and not sc.enabled(eff_name):
                sc = sc.with_effects(enabled={eff_name: True})
            sc = sc.with_station(int(a), **{rest[0]: float(value)})
        else:
            raise ScenarioError(f"unknown knob {knob!r}")
    return sc


def candidates(scenario: Scenario, exclude: Sequence[str] = ()) -> list[Candidate]:
    """Every catalogue effect the scenario leaves off or fixes, with its knob and grid."""
    out: list[Candidate] = []
    for name, cls in EFFECTS.items():
        if name in exclude:
            continue
        spec = KNOBS.get(name)
        if spec is None:  # a catalogue addition without a table entry: its switch
            params = cls.parameters()
            spec = (
                KnobSpec("effect", next(iter(params)), "mul", (0.0, 0.5, 2.0), params[next(iter(params))][1])
                if params
                else KnobSpec("switch", name, "abs", (0.0, 1.0), "")
            )
        kid = knob_id(name, spec, scenario)
        base = believed_value(kid, scenario)
        grid = _grid(spec, base, cls)
        grid = tuple(sorted({float(g) for g in grid} - {float(base)}))
        if not grid:
            continue
        doc = (cls.__doc__ or "").strip().splitlines()[0]
        out.append(
            Candidate(effect=name, knob=kid, baseline=float(base), grid=grid, unit=spec.unit, description=doc)
        )
        for form in SHAPES.get(name, ()):
            shape = tuple(
                (
                    knob_id(name, sh, scenario),
                    float(_grid(sh, believed_value(knob_id(name, sh, scenario), scenario), cls)[0]),
                )
                for sh in form
            )
            if all(v == believed_value(k, scenario) for k, v in shape):
                continue
            words = ", ".join(
                f"{sh.name} = {v:.4g} {sh.unit}".rstrip() for sh, (_, v) in zip(form, shape, strict=True)
            )
            out.append(
                Candidate(
                    effect=name,
                    knob=kid,
                    baseline=float(base),
                    grid=grid,
                    unit=spec.unit,
                    description=f"{doc} ({words})",
                    shape=shape,
                )
            )
        # the transmitter's scales (offered by the engine only with TX_SCALE_NEEDS transmitters),
        # then the receivers'
        out += _station_candidates(
            name, PER_STATION_TX_KNOBS, "_tx", "transmitter", TX_SCALE_NEEDS, scenario, cls
        )
        out += _station_candidates(name, PER_STATION_KNOBS, "", "receiver", ("rx_station", 2), scenario, cls)
    return out


def _station_candidates(
    name: str,
    knobs: dict[str, KnobSpec],
    suffix: str,
    side: str,
    needs: tuple[str, int],
    scenario: Scenario,
    cls: type[Any],
) -> list[Candidate]:
    """One candidate per scenario station for the effect's per-station knob in ``knobs``
    (:data:`PER_STATION_KNOBS`, :data:`PER_STATION_TX_KNOBS`), named ``<effect><suffix>[<id>]``
    and offered when the session has ``needs``; none with fewer scenario stations than that."""
    ps = knobs.get(name)
    if ps is None or len(scenario.station_ids) < needs[1]:
        return []
    out = []
    for sid in scenario.station_ids:
        kid = f"station:{sid}:{ps.name}"
        base = believed_value(kid, scenario)
        grid = tuple(sorted({float(g) for g in _grid(ps, base, cls)} - {float(base)}))
        out.append(
            Candidate(
                effect=f"{name}{suffix}[{sid}]",
                knob=kid,
                baseline=float(base),
                grid=grid,
                unit=ps.unit,
                description=f"station {sid}'s {ps.name} ({name}, this {side} only)",
                needs=needs,
                # a scale of a jitter adds variance to the floor's: its signature at the believed
                # 6 ps floor would be far too large once a floor of tens of ps is selected
                depends_on=name,
            )
        )
    return out


def _grid(spec: KnobSpec, base: float, cls: type[Any]) -> tuple[float, ...]:
    """A spec's signature grid around the believed value ``base``."""
    if spec.kind == "add":
        return tuple(base + v for v in spec.values)
    if spec.kind == "mul":
        ref = base if base != 0 else float(cls().values().get(spec.name, 1.0))
        return tuple(ref * v for v in spec.values)
    return spec.values


def shape_refiner(scenario: Scenario) -> Callable[[Candidate, float], list[Candidate]]:
    """``refine(candidate, scale) -> candidates``: the candidate's effect moved along its
    :data:`SHAPE_AXES` by one step times ``scale``, from the shape it has (the believed value where
    its shape leaves an axis alone): every combination of -1, 0, +1 steps on its axes (the
    diagonals too: a late-path excess of another size and spread is off along both; 8 shapes for
    two axes); engine.diagnose's ``refine``. The magnitude knob and
    its grid stay the candidate's. No axes: no candidates."""

    def refine(cand: Candidate, scale: float) -> list[Candidate]:
        axes = SHAPE_AXES.get(cand.effect, ())
        if not axes or cand.effect not in EFFECTS:
            return []
        doc = (EFFECTS[cand.effect].__doc__ or "").strip().splitlines()[0]
        current = dict(cand.shape)
        kids = [knob_id(cand.effect, KnobSpec(a.target, a.name, "abs", (), a.unit), scenario) for a in axes]
        start = [float(current.get(k, believed_value(k, scenario))) for k in kids]

        def moved(i: int, sign: int) -> float:
            ax, v0 = axes[i], start[i]
            v = v0 * ax.step ** (sign * scale) if ax.log else v0 + sign * ax.step * scale
            return float(min(max(v, ax.bounds[0]), ax.bounds[1]))

        out: list[Candidate] = []
        seen: set[tuple[float, ...]] = {tuple(start)}
        for m in itertools.product((-1, 0, 1), repeat=len(axes)):
            vals = tuple(moved(i, m[i]) if m[i] else start[i] for i in range(len(axes)))
            if vals in seen:  # clipped back onto a shape already offered
                continue
            seen.add(vals)
            shape = {**current, **{k: v for k, v, v0 in zip(kids, vals, start, strict=True) if v != v0}}
            words = ", ".join(f"{k.split(':')[-1]} = {x:.4g}" for k, x in shape.items())
            out.append(dataclasses.replace(cand, description=f"{doc} ({words})", shape=tuple(shape.items())))
        return out

    return refine


# --- station ids between the real session and the scenario --------------------------------


def station_map(real_ids: Sequence[int], scenario: Scenario) -> dict[int, int]:
    """Real station id -> scenario station id: equal ids if they all exist, else by order."""
    sc_ids = scenario.station_ids
    real = sorted(set(int(i) for i in real_ids))
    if all(i in sc_ids for i in real):
        return {i: i for i in real}
    if len(real) > len(sc_ids):
        raise ScenarioError(f"the session has stations {real} but the scenario only {sc_ids}")
    return dict(zip(real, sc_ids[: len(real)], strict=True))


def remap_stations(rec: Mapping[str, Any], mapping: Mapping[int, int]) -> dict[str, Any]:
    """A copy of records with tx_station / rx_station mapped through ``mapping``."""
    out = dict(rec)
    for col in ("tx_station", "rx_station", "ref_station", "tag_station"):
        v = rec.get(col)
        if v is not None:
            a = np.asarray(v, dtype=np.int64)
            keys = np.array(sorted(mapping), dtype=np.int64)
            vals = np.array([mapping[int(k)] for k in keys], dtype=np.int64)
            pos = np.clip(np.searchsorted(keys, a), 0, len(keys) - 1)
            out[col] = np.where(keys[pos] == a, vals[pos], a)
    return out


SimulateFn = Callable[[Scenario, int], Records]


def make_simulator(
    scenario: Scenario, run: SimulateFn, cache: dict[tuple[Variant, int], Records] | None = None
) -> Callable[[Variant, int], Records]:
    """The engine's simulator: ``run(scenario_with_variant, seed)`` with an optional cache."""

    def sim(variant: Variant, seed: int) -> Records:
        key = (variant, seed)
        if cache is not None and key in cache:
            return cache[key]
        rec = run(apply_variant(scenario, variant), seed)
        if cache is not None:
            cache[key] = rec
        return rec

    return sim


# --- re-simulating a session's own schedule --------------------------------------------------


@dataclass
class SessionSchedule:
    """A recorded session's triplet schedule, in scenario station ids, ready to re-simulate.

    ``base`` is :func:`uwbcal.vectorsim.schedule_from_records` of the records with NULL gains
    filled by the simulator's default gain and station ids mapped to the scenario's (its
    ``spacing23_s`` holds the recorded P2 -> P3 intervals where they differ from P1 -> P2, as
    in the asil log's 23 / 33 ms turns); ``mapping`` real id -> scenario id.
    """

    base: Any
    mapping: dict[int, int]


def session_schedule(real: Mapping[str, Any], scenario: Scenario) -> SessionSchedule:
    """The schedule of the real session's triplet records (see :class:`SessionSchedule`)."""
    from uwbcal import vectorsim
    from uwbcal.sessions.schema import INT_NULL

    rec = dict(real)
    n = int(np.asarray(rec["seq"]).size)
    for g in ("gain13", "gain2"):
        v = rec.get(g)
        a = np.full(n, INT_NULL, np.int64) if v is None else np.asarray(v, np.int64)
        rec[g] = np.where(a == INT_NULL, vectorsim.DEFAULT_GAIN, a)
    st = rec.get("step")
    rec["step"] = np.zeros(n, np.int64) if st is None else np.where(np.asarray(st) == INT_NULL, 0, st)
    if rec.get("distance_m") is None:
        rec["distance_m"] = np.full(n, np.nan)
    mapping = station_map(
        np.concatenate([np.asarray(rec["tx_station"]), np.asarray(rec["rx_station"])]).tolist(), scenario
    )
    rec = remap_stations(rec, mapping)
    return SessionSchedule(base=vectorsim.schedule_from_records(rec), mapping=mapping)


def run_session(scenario: Scenario, sched: SessionSchedule, seed: int) -> dict[str, Any]:
    """Simulate the session's schedule once; records in the real session's station ids."""
    from uwbcal import vectorsim
    from uwbcal.physics.world import World

    rec, _ = vectorsim.run_triplets(World(scenario, seed), sched.base)
    inverse = {v: k for k, v in sched.mapping.items()}
    return remap_stations(rec, inverse)


def physics_simulator(real: Mapping[str, Any], scenario: Scenario) -> Callable[[Variant, int], Records]:
    """The engine's simulator for a real session: its own schedule, the scenario plus knobs."""
    sched = session_schedule(real, scenario)
    return make_simulator(scenario, lambda sc, seed: run_session(sc, sched, seed))


def since_power_on(rec: Mapping[str, Any], meta: Mapping[str, Any]) -> dict[str, Any]:
    """Records with ``t_s`` counted from the counter's zero (power-on) when the session says where
    that was (``meta["timestamps"]["session_start_since_counter_zero_s"]``, set by the asil
    importer for logs the logger unwrapped), else unchanged.

    The scenario's warm-up runs from the world's power-on: re-simulating a session that started
    5 s after power-on as if it started at power-on puts the believed warm-up in the wrong phase
    (a clock-rate gap of its own, and false alarms on nulls imported the same way).
    """
    ts = meta.get("timestamps")
    if not isinstance(ts, Mapping) or rec.get("t_s") is None:
        return dict(rec)
    start = ts.get("session_start_since_counter_zero_s")
    if not isinstance(start, int | float) or not np.isfinite(start):
        return dict(rec)
    if not (ts.get("unwrapped_at_source") or float(start) < 17.0):  # a raw 40-bit counter wraps at 17.2 s
        return dict(rec)
    out = dict(rec)
    out["t_s"] = np.asarray(rec["t_s"], np.float64) + float(start)
    return out


def every_nth(rec: Mapping[str, Any], stride: int) -> dict[str, Any]:
    """Every ``stride``-th record (columns sliced; None columns kept)."""
    return {k: (None if v is None else np.asarray(v)[::stride]) for k, v in rec.items()}


def subsampled_simulators(
    real: Mapping[str, Any], scenario: Scenario
) -> Callable[[int], Callable[[Variant, int], Records]]:
    """``stride -> simulator`` of every stride-th record of the real schedule (engine.diagnose's
    ``subsampled``)."""
    return lambda stride: physics_simulator(every_nth(real, stride), scenario)


# --- clock shapes fitted to the rate (a warm-up of free time constants) ------------------------

#: Strong evidence (Kass and Raftery) for a second warm-up stage: BIC difference above this.
BIC_STRONG: Final = 10.0
#: ... and this many times the largest gain of a re-simulation of the believed world against the
#: mean of the others (their clock wander fits a fast stage as well).
NULL_FACTOR: Final = 3.0
#: Time constants (s) the rate fit profiles over before its refinement.
_TAU_GRID: Final = np.geomspace(2.0, 3000.0, 48)


def rss_profile(u: FloatArray, y: FloatArray, tau0: float) -> Callable[[FloatArray], FloatArray]:
    """``taus -> rss``: the residual sum of squares (units of y squared) of the least-squares fit of
    y by c + d e^(-u/tau0) + b e^(-u/T), for each T in ``taus`` (s; u in s).

    The constant and the tau0 stage are projected out once, so each T is a one-column regression
    of what is left: the same least squares as ``np.linalg.lstsq`` on the three columns, to
    rounding, at a fraction of the cost (the rate fit of :func:`clock_shapes` profiles 48 T's of
    up to 10^5 records, 65 times a diagnosis). A column the other two span, to lstsq's rank
    tolerance, adds nothing. Columns go 8 at a time (memory: 8 x 3 x 8 bytes per record).
    """
    q = np.linalg.qr(np.stack([np.ones_like(u), np.exp(-u / tau0)], axis=1))[0]
    ry = y - q @ (q.T @ y)
    tol = (np.finfo(np.float64).eps * max(u.size, 3)) ** 2

    def rss(taus: FloatArray) -> FloatArray:
        out = np.empty(len(taus))
        for a in range(0, len(taus), 8):
            x3 = np.exp(-u[:, None] / np.asarray(taus[a : a + 8], np.float64)[None, :])
            r3 = x3 - q @ (q.T @ x3)
            n3 = np.einsum("ij,ij->j", r3, r3)
            keep = n3 > tol * np.einsum("ij,ij->j", x3, x3)
            beta = np.where(keep, (r3.T @ ry) / np.where(keep, n3, 1.0), 0.0)
            r3 *= beta[None, :]
            np.subtract(ry[:, None], r3, out=r3)
            out[a : a + 8] = np.einsum("ij,ij->j", r3, r3)
        return out

    return rss


def clock_shapes(
    real: Mapping[str, Any], scenario: Scenario
) -> Callable[[FloatArray, FloatArray], list[Candidate]]:
    """``fit(real rate, re-simulated rates (seeds x records)) -> candidates`` (ppm): a warm-up whose
    time constants are fitted to the session's own clock rate (engine.diagnose's ``shapes``).

    The rate is measured to about 1e-4 ppm per time block, so a warm-up of other time constants
    than the catalogue's few forms (:data:`SHAPES`) leaves many floor SDs that clock wander, the
    flexible effect, then absorbs (issue 13: a two-stage warm-up named wander). The departure of
    the warm-up station's frequency g(u) (u s since its power-on; records it receives see +g, those
    it sends -g) is fitted as c + da e^(-u/T0) + b e^(-u/T), T0 the believed warm-up's time
    constant, T free (profiled least squares, then a bounded refinement in log T). The candidate is
    the warm-up settling to the final offset ppm + c, its believed stage at amplitude a0 + da and a
    second stage (``warmup2_ppm``, ``warmup2_tau_s`` = T) whose amplitude is the knob. Returns no
    candidate unless the second stage is strongly needed (:data:`BIC_STRONG`).
    """
    from scipy.optimize import minimize_scalar

    ids = scenario.station_ids
    sid = ids[min(KNOBS["warmup"].station, len(ids) - 1)]
    mapping = station_map(
        np.concatenate([np.asarray(real["tx_station"]), np.asarray(real["rx_station"])]).tolist(), scenario
    )
    real_of = {v: k for k, v in mapping.items()}
    st = scenario.station(sid)
    on = scenario.enabled("warmup")
    a0 = float(st.warmup_ppm) if on else 0.0
    tau0 = float(st.warmup_tau_s)
    u = np.asarray(real["t_s"], np.float64) - float(st.power_on_s)
    sign = np.where(np.asarray(real["rx_station"]) == real_of.get(sid, -1), 1.0, 0.0) - np.where(
        np.asarray(real["tx_station"]) == real_of.get(sid, -1), 1.0, 0.0
    )

    def gain(y: FloatArray) -> tuple[float, float, float, float, float]:
        """(BIC gain of the second stage, T, c, da, b) of one rate departure per record."""
        ok = (sign != 0) & np.isfinite(y) & np.isfinite(u)
        if np.count_nonzero(ok) < 20:
            return 0.0, tau0, 0.0, 0.0, 0.0
        uu, yy = np.maximum(u[ok], 0.0), y[ok]

        def solve(log_tau: float) -> tuple[float, FloatArray]:
            x = np.stack([np.ones_like(uu), np.exp(-uu / tau0), np.exp(-uu / np.exp(log_tau))], axis=1)
            coef, *_ = np.linalg.lstsq(x, yy, rcond=None)
            return float(np.sum((yy - x @ coef) ** 2)), coef

        profile = rss_profile(uu, yy, tau0)

        def rss_at(log_taus: FloatArray) -> FloatArray:
            return profile(np.exp(log_taus))

        k = int(np.argmin(rss_at(np.log(_TAU_GRID))))
        lo, hi = np.log(_TAU_GRID[max(k - 1, 0)]), np.log(_TAU_GRID[min(k + 1, _TAU_GRID.size - 1)])
        best = minimize_scalar(lambda lt: float(rss_at(np.array([lt]))[0]), bounds=(lo, hi), method="bounded")
        log_tau = float(best.x) if best.success else float(np.log(_TAU_GRID[k]))
        rss1, (c, da, b) = solve(log_tau)
        x0 = np.stack([np.ones_like(uu), np.exp(-uu / tau0)], axis=1)
        rss0 = float(np.sum((yy - x0 @ np.linalg.lstsq(x0, yy, rcond=None)[0]) ** 2))
        n = yy.size
        g = n * np.log(rss0 / rss1) - 2.0 * np.log(n) if rss1 > 0 and np.isfinite(b) else 0.0
        return float(g), float(np.exp(log_tau)), float(c), float(da), float(b)

    def fit(rate_real: FloatArray, rate_sims: FloatArray) -> list[Candidate]:
        sims = np.asarray(rate_sims, np.float64)
        mean = np.nanmean(sims, axis=0)
        y_real = sign * (np.asarray(rate_real, np.float64) - mean)
        g, tau, c, da, b = gain(y_real)
        # a second stage only if the rate needs it: its BIC gain (two parameters more than offset
        # + believed stage) must be strong and far beyond what re-simulations of the believed world
        # show against the others' mean (its own clock wander fits a fast stage too)
        k = sims.shape[0]

        def null_gain(j: int) -> float:
            return gain(sign * (sims[j] - np.nanmean(np.delete(sims, j, axis=0), axis=0)))[0]

        # the null gains are heavy-tailed (a believed world's wander can make a hump that a fast
        # stage fits): a blind pure clock offset of -3.4 ppm, whose own wander scored 333, cleared
        # 3x the largest of the first 8 (under 111) but not of all 64 (64 other seeds: largest
        # 209), and its warm-up candidate then beat the offset. Eight first, every seed when the
        # real gain clears those
        null = [null_gain(j) for j in range(min(k, 8))]
        if g > max(BIC_STRONG, NULL_FACTOR * max(null, default=0.0)):
            null += [null_gain(j) for j in range(len(null), k)]
        if not g > max(BIC_STRONG, NULL_FACTOR * max(null, default=0.0)):
            return []
        if not _TAU_GRID[0] * 1.05 < tau < _TAU_GRID[-1] / 1.05:  # at the edge: no time constant found
            return []
        knob = f"station:{sid}:warmup2_ppm"
        base = believed_value(knob, scenario)
        # the warm-up settles to a final offset of its own: the fitted asymptote goes with the shape
        # (without it the believed stage, nearly a ramp over a short session, took the offset's part
        # and the re-simulated rate left a trend of 20 floor SDs)
        shape = (
            (f"station:{sid}:ppm", float(st.ppm if scenario.enabled("clock_offset") else 0.0) + c),
            (f"station:{sid}:warmup_ppm", a0 + da),
            (f"station:{sid}:warmup2_tau_s", tau),
        )
        # the same station's plain offset, simulated at the rate's own mean departure: without it the
        # fitted warm-up (exact at its fitted asymptote) met only the catalogue's offset, interpolated
        # between grid points ppm apart, and won on that precision alone with a second stage of 0.01
        # ppm (a blind pure offset of -3.4 ppm was named a warm-up)
        okr = (sign != 0) & np.isfinite(y_real)
        c1 = float(np.mean(y_real[okr])) if np.any(okr) else c
        knob_o = f"station:{sid}:ppm"
        base_o = believed_value(knob_o, scenario)
        step_o = max(0.05, 0.1 * abs(c1))
        offset = Candidate(
            effect="clock_offset",
            knob=knob_o,
            baseline=base_o,
            grid=tuple(sorted({base_o + c1 - step_o, base_o + c1, base_o + c1 + step_o} - {base_o})),
            unit="ppm",
            description=f"clock offset fitted to the clock rate ({c1:+.4g} ppm on station {sid})",
            shape=((knob_o, base_o + c1),),
        )
        return [
            offset,
            Candidate(
                effect="warmup",
                knob=knob,
                baseline=base,
                grid=tuple(sorted({base + 0.5 * b, base + b, base + 1.5 * b})),
                unit="ppm",
                description=(
                    f"warm-up in two stages fitted to the clock rate (believed stage {a0 + da:.3g} ppm "
                    f"over {tau0:.4g} s, second stage over {tau:.4g} s)"
                ),
                shape=shape,
            ),
        ]

    return fit
