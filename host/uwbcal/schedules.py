"""Schedules: what the stations are asked to do in a session (true start times, spacing,
gains, stations, distances), for the vectorised simulator (:mod:`uwbcal.vectorsim`) to play.

Triplets: the TX station reads its clock at true time ``t_s`` (P1's DX_TIME = that reading),
P2 follows ``spacing_s`` and P3 ``spacing23_s`` after P2 on the TX clock (delayed TX; the
builders use one spacing, recorded sessions may have two), P1/P3 at ``gain13``, P2 at
``gain2``. TWR (the paper's exchange): M1 ref->tag at ``t_s`` (delayed TX on the reference
clock), M2 tag->ref programmed ``reply_s`` after the tag's M1 RX stamp, M3 ref->tag programmed
``reply2_s`` after the reference's M2 RX stamp. Builders: :func:`drift_schedule`,
:func:`power_schedule`, :func:`twr_schedule`; :func:`schedule_from_records` rebuilds the
schedule of any recorded session (simulated, firmware-in-the-loop or imported). Times s,
distances m, gains TX_POWER octets.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields

import numpy as np
import numpy.typing as npt

from uwbcal import dw1000
from uwbcal.errors import ScenarioError
from uwbcal.physics.scenario import Scenario
from uwbcal.physics.world import World
from uwbcal.sessions import plan

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
Columns = dict[str, np.ndarray]  # type: ignore[type-arg]

TU = dw1000.TIME_UNIT_S
#: Default TX gain octet of P1/P3 and TWR messages: coarse 0, fine 31 (15.5 dB, the highest).
DEFAULT_GAIN = dw1000.gain_octet(0, 31)
#: The paper's 11 TWR distances run from 3.515 m to 0.562 m; the intermediate ones are not
#: given, so these are evenly spaced between the two.
PAPER_DISTANCES_M = tuple(float(x) for x in np.round(np.linspace(0.562, 3.515, 11), 3))


def _i(x: npt.ArrayLike) -> IntArray:
    return np.asarray(x, dtype=np.int64)


def _fl(x: npt.ArrayLike) -> FloatArray:
    return np.asarray(x, dtype=np.float64)



@dataclass
class TripletSchedule:
    """P1/P2/P3 triplets to send. Arrays of equal length, one entry per (triplet, receiver).

    ``seq``, ``step`` (gain step index), ``tx_station``, ``rx_station``; ``t_s`` true time at
    which the TX reads its clock to program P1 (s); ``spacing_s`` P1->P2 on the TX clock (s);
    ``gain13``, ``gain2`` TX_POWER octets; ``distance_m`` (NaN: the scenario's);
    ``spacing23_s`` P2->P3 on the TX clock (s), left empty (the default) for P2->P3 =
    ``spacing_s`` (it is then filled with a copy of ``spacing_s``).
    """

    seq: IntArray
    step: IntArray
    tx_station: IntArray
    rx_station: IntArray
    t_s: FloatArray
    spacing_s: FloatArray
    gain13: IntArray
    gain2: IntArray
    distance_m: FloatArray
    spacing23_s: FloatArray = field(default_factory=lambda: np.zeros(0))

    def __post_init__(self) -> None:
        sp23 = np.asarray(self.spacing23_s, dtype=np.float64)
        if sp23.size == 0 and self.spacing_s.size:
            sp23 = np.asarray(self.spacing_s, dtype=np.float64).copy()
        if sp23.shape != np.shape(self.spacing_s):
            raise ScenarioError(
                f"spacing23_s has {sp23.size} entries, spacing_s {np.size(self.spacing_s)}: one per row"
            )
        self.spacing23_s = sp23

    def __len__(self) -> int:
        return int(self.seq.size)

    def as_dict(self) -> Columns:
        """The arrays by field name."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass
class RangeSchedule:
    """TWR exchanges to run (the paper's three messages), one entry per exchange.

    ``seq``, ``ref_station``, ``tag_station``; ``t_s`` true time the reference programs M1 (s);
    ``distance_m`` true distance (NaN: the scenario's); ``gain`` TX_POWER octet of every
    message; ``reply_s`` tag delay M1 RX -> M2 TX and ``reply2_s`` reference delay M2 RX ->
    M3 TX, each on the replying station's clock (s).
    """

    seq: IntArray
    ref_station: IntArray
    tag_station: IntArray
    t_s: FloatArray
    distance_m: FloatArray
    gain: IntArray
    reply_s: FloatArray
    reply2_s: FloatArray

    def __len__(self) -> int:
        return int(self.seq.size)

    def as_dict(self) -> Columns:
        """The arrays by field name."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


def _scenario_of(src: World | Scenario) -> Scenario:
    return src.scenario if isinstance(src, World) else src


def _pair(sc: Scenario, tx: int | None, rx: int | None) -> tuple[int, int]:
    ids = sc.station_ids
    if len(ids) < 2 and (tx is None or rx is None):
        raise ScenarioError(f"scenario {sc.name!r} needs two stations")
    a = ids[0] if tx is None else tx
    b = (ids[1] if ids[1] != a else ids[0]) if rx is None else rx
    sc.station(a)
    sc.station(b)
    if a == b:
        raise ScenarioError(f"TX and RX station are both {a}")
    return a, b


def drift_schedule(
    src: World | Scenario,
    count: int,
    spacing_s: float = 2e-3,
    period_s: float = 0.05,
    tx: int | None = None,
    rx: int | None = None,
    gain: int = DEFAULT_GAIN,
    start_s: float = 1.0,
    distance_m: float | None = None,
) -> TripletSchedule:
    """``count`` triplets at constant gain, one every ``period_s`` from ``start_s`` (s).

    Defaults: TX the scenario's first station, RX its second; 2 ms spacing (paper), 50 ms
    period (the paper's integrator test), full gain.
    """
    return power_schedule(
        src,
        steps=1,
        per_step=count,
        step_db=0.0,
        spacing_s=spacing_s,
        period_s=period_s,
        tx=tx,
        rx=rx,
        gain13=gain,
        start_s=start_s,
        distance_m=distance_m,
    )


def power_schedule(
    src: World | Scenario,
    steps: int,
    per_step: int,
    step_db: float = 0.5,
    spacing_s: float = 2e-3,
    period_s: float = 0.05,
    tx: int | None = None,
    rx: int | None = None,
    gain13: int = DEFAULT_GAIN,
    start_s: float = 1.0,
    distance_m: float | None = None,
) -> TripletSchedule:
    """A power sweep: ``steps`` gain levels of P2 (step 0 equal to P1/P3), ``per_step`` triplets
    each; P2's nominal gain drops by ``step_db`` per step (sessions/plan.gain_ladder, with the
    scenario's coarse step: the plan `uwbcal calibrate` sends), P1/P3 stay at ``gain13``."""
    sc = _scenario_of(src)
    if steps < 1 or per_step < 1:
        raise ScenarioError("a schedule needs at least one step and one triplet per step")
    coarse_step = float(sc.effects["tx_gain"].values()["coarse_step_db"])
    try:
        p = plan.TripletPlan.sweep(steps=steps, per_step=per_step, step_db=step_db,
                                   spacing_us=int(round(spacing_s * 1e6)),
                                   period_us=int(round(period_s * 1e6)), gain13=gain13,
                                   coarse_step_db=coarse_step)
    except plan.PlanError as exc:
        raise ScenarioError(str(exc)) from None
    return plan_schedule(sc, p, tx=tx, rx=rx, start_s=start_s, distance_m=distance_m)


def plan_schedule(
    src: World | Scenario,
    triplet_plan: plan.TripletPlan,
    tx: int | None = None,
    rx: int | None = None,
    start_s: float = 1.0,
    distance_m: float | None = None,
) -> TripletSchedule:
    """The schedule of a station's triplet plan (sessions/plan.py, what `uwbcal calibrate` sends):
    triplet k starts at ``start_s + k * period`` (s), P2 at ``gains2[k // per_step]``."""
    sc = _scenario_of(src)
    a, b = _pair(sc, tx, rx)
    per_step = triplet_plan.per_step
    n = triplet_plan.total
    seq = np.arange(n, dtype=np.int64)
    step = seq // per_step
    d = np.nan if distance_m is None else float(distance_m)
    return TripletSchedule(
        seq=seq,
        step=step,
        tx_station=np.full(n, a, np.int64),
        rx_station=np.full(n, b, np.int64),
        t_s=_fl(start_s + seq * (triplet_plan.period_us * 1e-6)),
        spacing_s=np.full(n, triplet_plan.spacing_us * 1e-6),
        gain13=np.full(n, triplet_plan.gain13, np.int64),
        gain2=_i(triplet_plan.gains2)[step],
        distance_m=np.full(n, d),
    )


def twr_schedule(
    src: World | Scenario,
    distances_m: Sequence[float] = PAPER_DISTANCES_M,
    per_distance: int = 2000,
    period_s: float = 0.02,
    reply_s: float = 1e-3,
    reply2_s: float = 1e-3,
    ref: int | None = None,
    tag: int | None = None,
    gain: int = DEFAULT_GAIN,
    start_s: float = 1.0,
    move_s: float = 1.0,
) -> RangeSchedule:
    """TWR runs: ``per_distance`` exchanges at each distance (m), one every ``period_s``, with
    ``move_s`` between distances. Defaults: the paper's 11 distances, 2000 exchanges each."""
    sc = _scenario_of(src)
    a, b = _pair(sc, ref, tag)
    if per_distance < 1 or not len(distances_m):
        raise ScenarioError("a TWR schedule needs at least one distance and one exchange")
    if period_s <= reply_s + reply2_s:
        raise ScenarioError(f"period {period_s} s must exceed reply {reply_s} s + reply2 {reply2_s} s")
    k = len(distances_m)
    n = k * per_distance
    seq = np.arange(n, dtype=np.int64)
    block = seq // per_distance
    t = start_s + seq * period_s + block * move_s
    return RangeSchedule(
        seq=seq,
        ref_station=np.full(n, a, np.int64),
        tag_station=np.full(n, b, np.int64),
        t_s=t,
        distance_m=_fl(distances_m)[block],
        gain=np.full(n, gain, np.int64),
        reply_s=np.full(n, reply_s),
        reply2_s=np.full(n, reply2_s),
    )


#: A recorded P2 -> P3 interval (TX stamps) within this of ``spacing_s`` (s) is taken as equal
#: to it: the 512-unit delayed-TX grid moves each TX stamp by < 8.01 ns, so a one-spacing
#: schedule's tx3 - tx2 is within 16 ns of its spacing; imports with unequal spacings differ
#: by milliseconds (asil: 23 and 33.4 ms).
SPACING23_TOL_S = 1e-6


def schedule_from_records(records: Mapping[str, npt.ArrayLike]) -> TripletSchedule | RangeSchedule:
    """The schedule of a recorded session's rows (``Session.read("triplets")`` or ``"ranges"``).

    Triplets use t_s, spacing_s, gain13, gain2, tx/rx_station, step, seq, distance_m, and the
    P2 -> P3 interval from the recorded TX stamps ((tx3 - tx2) modulo 2**40, on the TX clock)
    where it differs from spacing_s by more than :data:`SPACING23_TOL_S` (else spacing_s, so a
    one-spacing session is re-simulated exactly as it was scheduled). Ranges use
    t_s, ref/tag_station, gain, distance_m and take the reply delays from the recorded
    timestamps ((t2t - t1t) and (t3r - t2r) modulo 2**40: exact to within the TX antenna delay,
    about 0.26 us, and the 8 ns delayed-TX grid). NaN distances mean "the scenario's".
    """
    if "rx1" in records:
        n = np.asarray(records["seq"]).size
        step = _i(records["step"]) if "step" in records else np.zeros(n, np.int64)
        step = np.where(step < 0, 0, step)
        spacing = _fl(records["spacing_s"])
        spacing23 = spacing.copy()
        if "tx2" in records and "tx3" in records:
            sp23 = dw1000.wrap_diff(records["tx3"], records["tx2"]) * TU
            unequal = np.abs(sp23 - spacing) > SPACING23_TOL_S
            spacing23[unequal] = sp23[unequal]
        return TripletSchedule(
            seq=_i(records["seq"]),
            step=step,
            tx_station=_i(records["tx_station"]),
            rx_station=_i(records["rx_station"]),
            t_s=_fl(records["t_s"]),
            spacing_s=spacing,
            gain13=_i(records["gain13"]),
            gain2=_i(records["gain2"]),
            distance_m=_fl(records["distance_m"]),
            spacing23_s=spacing23,
        )
    if "t1r" in records:
        reply = dw1000.wrap_diff(records["t2t"], records["t1t"]) * TU
        reply2 = dw1000.wrap_diff(records["t3r"], records["t2r"]) * TU
        reply2 = np.where(reply2 > 0, reply2, reply)
        return RangeSchedule(
            seq=_i(records["seq"]),
            ref_station=_i(records["ref_station"]),
            tag_station=_i(records["tag_station"]),
            t_s=_fl(records["t_s"]),
            distance_m=_fl(records["distance_m"]),
            gain=_i(records["gain"]),
            reply_s=_fl(reply),
            reply2_s=_fl(reply2),
        )
    raise ScenarioError("records are neither triplets (rx1...) nor ranges (t1r...)")
