"""Session runners: drift, power calibration and ranging against any two stations (a library).

The plans they run come from sessions/plan.py; the command-line glue (options, port
resolution, the printed summary) is in commands/_session.py. The runners speak only the wire
protocol (uwbcal.device), so the same code drives EVK1000
boards and simulated stations. Each run:

1. stops both stations (a resumed session may find them still running), configures their
   radios (the paper's settings unless told otherwise) and learns their station ids;
2. starts the receiver (``listen``) then the transmitter (``seq_start`` / ``range_start``);
3. appends every streamed record batch to the session as it arrives (sessions/recorder.py),
   with a progress bar and loss bookkeeping (stream frame counters, record indices, seq);
4. stops both and stores the stations' counters and what was lost in the session.

Nothing lost (sessions/gapfill.py): a record lost on the link is fetched back from the
recording station's ring; a triplet or exchange the ring no longer holds, or that never
produced a record, is measured again in a further firmware plan at the same gain step. The
firmware numbers the triplets / exchanges of each plan from 0; the recorder maps them onto the
session's seqs. A resumed session fills every hole, not only the tail. Records are never
written twice.

Units: time in us on the wire, s in the session; gains are TX_POWER octets; distances m.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, Final

from uwbcal import dw1000
from uwbcal.device import Device
from uwbcal.errors import SessionError, UwbcalError
from uwbcal.link import proto_gen as pg
from uwbcal.sessions import gapfill
from uwbcal.sessions.plan import RangePlan, TripletPlan
from uwbcal.sessions.recorder import METHOD_CODES, RangeRecorder, TripletRecorder
from uwbcal.sessions.store import Session

#: The paper's radio settings: channel 2, PRF 64 MHz, preamble 128, 6.81 Mb/s.
PAPER_RADIO: Final = {"channel": 2, "prf_mhz": 64, "preamble_len": 128, "data_rate": 2}
#: Default antenna delay registers, device units (Decawave's usual starting value).
DEFAULT_ANTD: Final = 16436
#: Resends of an unanswered request in a session: enough that a request survives a link that
#: loses one frame in five (0.2**6 = 6e-5), cheap on a good link (nothing is resent there).
SESSION_RETRIES: Final = 5
#: Fetches between two reads of the stream (new holes are found by reading it).
FETCHES_PER_READ: Final = 4
#: Time without any record after which the runner asks the transmitter whether it is done, s.
STALL_S: Final = 1.0
#: After the transmitter says done, how long to wait for the receiver's last batch, s (STOP then
#: streams what the receiver still holds, and fetching gets what was lost).
DRAIN_S: Final = 0.5


class RunError(UwbcalError):
    """A session could not be run (a station refused, or nothing arrived)."""

    exit_code = 9


# ---- stations ---------------------------------------------------------------------------

@dataclass
class StationInfo:
    """What the runner learnt about one station."""

    port: str
    station_id: int
    uid: str
    board: str
    firmware: str
    protocol_version: int


def prepare(dev: Device, radio: dict[str, int], tx_antd: int, rx_antd: int) -> StationInfo:
    """Stop whatever runs, configure the radio, return who the station is."""
    info = dev.info()
    dev.call(pg.StopReq())
    r = dev.call(pg.RadioConfigReq(channel=radio["channel"], prf_mhz=radio["prf_mhz"],
                                   preamble_len=radio["preamble_len"], data_rate=radio["data_rate"],
                                   preamble_code=radio.get("preamble_code", 0), tx_antd=tx_antd,
                                   rx_antd=rx_antd))
    if r.dev_id != dw1000.DEV_ID:
        raise RunError(f"{dev.port}: the radio reads DEV_ID 0x{r.dev_id:08X}, not a DW1000")
    return StationInfo(port=dev.port, station_id=r.station_id, uid=info.uid_hex, board=info.board,
                       firmware=info.firmware, protocol_version=info.protocol_version)


def drain(dev: Device) -> None:
    """Drop stream frames still queued from an earlier activity."""
    while dev.client.next_stream(0.05) is not None:
        pass


def session_meta(experiment: str, source: str, stations: list[StationInfo], radio: dict[str, int],
                 settings: dict[str, Any]) -> dict[str, Any]:
    """Meta entries of a new recorded session (sessions/schema.py META_KEYS)."""
    return {
        "kind": "recorded",
        "source": source,
        "experiment": experiment,
        "scenario": None,
        "seed": None,
        "station_uids": {str(s.station_id): s.uid for s in stations},
        "firmware_version": stations[0].firmware,
        "protocol_version": stations[0].protocol_version,
        "radio": {"channel": radio["channel"], "prf_mhz": radio["prf_mhz"],
                  "preamble_length": radio["preamble_len"],
                  "data_rate_kbps": dw1000.DATA_RATES_KBPS[radio["data_rate"]]},
        "settings": settings,
    }


def check_same_stations(session: Session, stations: list[StationInfo]) -> None:
    """SessionError unless the stations are the ones the session was recorded with."""
    want = session.meta.get("station_uids") or {}
    for st in stations:
        uid = want.get(str(st.station_id))
        if uid is not None and uid != st.uid:
            raise SessionError(f"{session.path}: station {st.station_id} on {st.port} has UID {st.uid}, "
                               f"the session was recorded with {uid}")


# ---- progress ---------------------------------------------------------------------------

class Progress:
    """A tqdm bar (or nothing): ``update(n)``, ``close()``."""

    def __init__(self, total: int, initial: int, desc: str, enabled: bool) -> None:
        self.bar: Any = None
        if enabled:
            from tqdm import tqdm

            self.bar = tqdm(total=total, initial=initial, desc=desc, unit="rec", dynamic_ncols=True,
                            smoothing=0.05)

    def update(self, n: int) -> None:
        if self.bar is not None and n:
            self.bar.update(n)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


# ---- triplet sessions -------------------------------------------------------------------

@dataclass
class RunResult:
    """Summary of one run (JSON-able with asdict)."""

    records: int
    expected: int
    wall_s: float
    losses: dict[str, Any]
    counters: dict[str, Any] = field(default_factory=dict)

    @property
    def complete(self) -> bool:
        """Every expected record is in the session, none missing."""
        return self.records >= self.expected and self.losses.get("n_missing", 0) == 0


def _take_streams(dev: Device, recorder: TripletRecorder | RangeRecorder, frame_type: int, wait_s: float,
                  progress: Progress, on_record: Callable[[int], None] | None) -> int:
    """Record the stream frames that arrive within ``wait_s`` and every one queued behind them,
    all in one batch (the host keeps up with a station that streams a record per frame);
    returns how many records were written."""
    batches: list[tuple[int, bytes, int]] = []
    size = (pg.TripletRecord if frame_type == pg.TripletsResp.TYPE else pg.RangeRecord).WIRE_SIZE
    f = dev.client.next_stream(wait_s)
    while f is not None:
        # a frame whose records do not add up (a station bug: the CRC passed) counts as lost
        if f.type == frame_type and len(f.payload) >= 4 and (len(f.payload) - 4) % size == 0:
            batches.append((int.from_bytes(f.payload[:4], "little"), f.payload[4:], f.lost))
        f = dev.client.next_stream(0.0)
    if not batches:
        return 0
    n = recorder.add_records_many(batches)
    progress.update(n)
    if on_record is not None and n:
        on_record(recorder.next_seq)
    return n


def _stream_loop(rx: Device, tx: Device, recorder: TripletRecorder | RangeRecorder, wanted: int,
                 frame_type: int, progress: Progress, on_record: Callable[[int], None] | None,
                 fetcher: gapfill.Fetcher) -> None:
    """Read stream frames from ``rx`` until ``wanted`` new records are in or the plan ends;
    a gap in the running record indices is fetched back at once (gapfill.Fetcher)."""
    last = time.monotonic()
    done_at: float | None = None
    got = 0
    while got < wanted:
        n = _take_streams(rx, recorder, frame_type, 0.0 if fetcher.holes() else 0.25, progress, on_record)
        got += n
        before = recorder.kept
        for _ in range(FETCHES_PER_READ):     # fetch holes before the ring overwrites them
            if not fetcher.fetch_one():
                break
        progress.update(recorder.kept - before)
        got += recorder.kept - before
        now = time.monotonic()
        if n:
            last = now
            continue
        if done_at is not None:
            if now - done_at > DRAIN_S:
                return
            continue
        if now - last > STALL_S:
            st = tx.call(pg.StatusReq())
            if st.done or st.state == 0:
                done_at = now
            last = now


def _finish_plan(rx: Device, recorder: TripletRecorder | RangeRecorder, frame_type: int,
                 fetcher: gapfill.Fetcher, progress: Progress, on_record: Callable[[int], None] | None,
                 others: Sequence[Device]) -> dict[str, Any]:
    """Stop a plan: the other stations first, then the recording one (which streams what it
    still holds before it answers), then fetch every hole its ring still holds. Returns the
    stations' counters by role order (others..., recorder)."""
    counters = [asdict(d.call(pg.StopReq())) for d in others]
    stop = rx.call(pg.StopReq())
    _take_streams(rx, recorder, frame_type, 0.05, progress, on_record)
    before = recorder.kept
    fetcher.fetch_all(stop.records)
    progress.update(recorder.kept - before)
    counters.append(asdict(stop))
    return {"stations": counters}


#: A pair of stations in a session table: ((column, station id), (column, station id)). Seqs
#: count per pair: a fleet session holds every ordered pair, each numbered from 0.
Pair = tuple[tuple[str, int], tuple[str, int]]


def _pair_sql(pair: Pair) -> tuple[str, tuple[int, int]]:
    (ca, a), (cb, b) = pair
    return f"{ca} = ? AND {cb} = ?", (a, b)


def _last_clock(session: Session, table: str, stamp: str, pair: Pair) -> tuple[int, float] | None:
    """The stamp and t_s of the pair's record that arrived last (resume continues its clock)."""
    where, args = _pair_sql(pair)
    row = session.conn.execute(f"SELECT {stamp}, t_s FROM {table} WHERE {where} ORDER BY rowid DESC LIMIT 1",
                               args).fetchone()
    return None if row is None or row[0] is None else (int(row[0]), float(row[1]))


def _stored_seqs(session: Session, table: str, pair: Pair) -> set[int]:
    """The seqs of the pair's records already in the session."""
    where, args = _pair_sql(pair)
    return {int(r[0]) for r in session.conn.execute(f"SELECT seq FROM {table} WHERE {where}", args)}


#: Runs one firmware plan (a pass: a map of session seqs, -1 an extra) with a progress bar;
#: returns its fetcher and the stations' counters.
PlanRunner = Callable[[Any, "Progress"], tuple[gapfill.Fetcher, dict[str, Any]]]


def _fill(session: Session, rec: TripletRecorder | RangeRecorder, stamp: str, total: int, unit: str,
          progress: bool, passes: Callable[[list[int]], Sequence[Any]], run_plan: PlanRunner,
          pair: Pair, first_seq: int = 0) -> RunResult:
    """Run firmware plans until every seq first_seq..total-1 is in the session (at most
    gapfill.MAX_PASSES plans): the first pass measures what is missing, later passes measure
    again what was lost and could not be fetched back. Returns the run summary."""
    t0 = time.monotonic()
    clock = _last_clock(session, rec.table, stamp, pair)
    if clock is not None:
        rec.restore_clock(*clock)
    bar = Progress(total - first_seq, len(rec.seen & set(range(first_seq, total))), unit, progress)
    counters: dict[str, Any] = {}
    first = True
    try:
        while rec.losses.passes < gapfill.MAX_PASSES:
            missing = [q for q in rec.missing(total) if q >= first_seq]
            if not missing:
                break
            if not first:
                rec.losses.remeasured += len(missing)
            for p in passes(missing):
                rec.losses.passes += 1
                fetcher, counters = run_plan(p, bar)
                rec.losses.fetched += fetcher.stats.fetched
                rec.losses.fetch_failures += fetcher.stats.failures
                rec.losses.too_old += fetcher.stats.too_old
            first = False
    finally:
        rec.flush()
        bar.close()
    rec.losses.missing_seqs = [q for q in rec.missing(total) if q >= first_seq]
    return RunResult(records=session.count(rec.table), expected=total, wall_s=time.monotonic() - t0,
                     losses=rec.losses.as_dict(), counters=counters)


def run_triplets(tx: Device, rx: Device, session: Session, plan: TripletPlan, tx_station: int,
                 rx_station: int, distance_m: float | None, *, progress: bool = True,
                 on_record: Callable[[int], None] | None = None) -> RunResult:
    """Run (the rest of) a triplet plan; records go to ``session`` as they arrive.

    Every triplet 0..total-1 not yet in the session is measured, wherever the hole is (a
    resumed session, a broken link): records lost on the way are fetched back from the
    receiver's ring, and what the ring no longer holds is measured again at the same gain step
    in a further firmware plan (gapfill.py), at most gapfill.MAX_PASSES plans: the session's
    own records decide where a resumed run starts. ``on_record`` is called with the highest
    session seq + 1 after every written batch (tests use it to interrupt a run).
    """
    pair: Pair = (("tx_station", tx_station), ("rx_station", rx_station))
    rec = TripletRecorder(session, rx_station, plan.spacing_us * 1e-6, distance_m,
                          seen=_stored_seqs(session, "triplets", pair), per_step=plan.per_step)

    def run_plan(sub: gapfill.TripletPass, bar: Progress) -> tuple[gapfill.Fetcher, dict[str, Any]]:
        rec.new_plan_map(sub.seq_map)
        rx.call(pg.StopReq())
        drain(rx)
        fetcher = gapfill.Fetcher(rx, pg.TripletsResp.TYPE, rec)
        rx.call(pg.ListenReq(role=0, peer=tx_station, reply_us=0))
        r = tx.call(pg.SeqStartReq(per_step=sub.per_step, spacing_us=plan.spacing_us,
                                   period_us=plan.period_us, gain13=plan.gain13, gains2=bytes(sub.gains2)))
        if r.total != sub.total:
            raise RunError(f"{tx.port}: the station plans {r.total} triplets, the host {sub.total}")
        wanted = int((sub.seq_map >= 0).sum())
        _stream_loop(rx, tx, rec, wanted, pg.TripletsResp.TYPE, bar, on_record, fetcher)
        c = _finish_plan(rx, rec, pg.TripletsResp.TYPE, fetcher, bar, on_record, [tx])
        return fetcher, {"tx": c["stations"][0], "rx": c["stations"][1]}

    return _fill(session, rec, "tx1", plan.total, "triplets", progress,
                 lambda missing: gapfill.triplet_passes(missing, plan.per_step, plan.gains2), run_plan, pair)


# ---- range sessions ---------------------------------------------------------------------

def run_ranges(ref: Device, tag: Device, session: Session, plan: RangePlan, ref_station: int,
               tag_station: int, distance_m: float | None, *, progress: bool = True,
               on_record: Callable[[int], None] | None = None, first_seq: int = 0) -> RunResult:
    """Run (the rest of) a ranging plan between a reference and a tag: every exchange
    first_seq..count-1 not yet in the session, holes included (see :func:`run_triplets`)."""
    pair: Pair = (("ref_station", ref_station), ("tag_station", tag_station))
    rec = RangeRecorder(session, ref_station, distance_m, seen=_stored_seqs(session, "ranges", pair))

    def run_plan(seq_map: Any, bar: Progress) -> tuple[gapfill.Fetcher, dict[str, Any]]:
        rec.new_plan_map(seq_map)
        for d in (tag, ref):
            d.call(pg.StopReq())
            drain(d)
        fetcher = gapfill.Fetcher(ref, pg.RangesResp.TYPE, rec)
        tag.call(pg.ListenReq(role=1, peer=ref_station, reply_us=plan.reply_us))
        ref.call(pg.RangeStartReq(method=METHOD_CODES[plan.method], tag=tag_station, count=len(seq_map),
                                  period_us=plan.period_us, reply_us=plan.reply_us, gain=plan.gain))
        _stream_loop(ref, ref, rec, len(seq_map), pg.RangesResp.TYPE, bar, on_record, fetcher)
        c = _finish_plan(ref, rec, pg.RangesResp.TYPE, fetcher, bar, on_record, [tag])
        return fetcher, {"ref": c["stations"][1], "tag": c["stations"][0]}

    return _fill(session, rec, "t1r", plan.count, "exchanges", progress, gapfill.range_passes, run_plan,
                 pair, first_seq)


def run_ranges_at(ref: Device, tag: Device, session: Session, plan: RangePlan, ref_station: int,
                  tag_station: int, distances_m: Sequence[float], place: Callable[[float], None], *,
                  progress: bool = True) -> RunResult:
    """``plan.count`` exchanges at each distance of ``distances_m`` (m), one session.

    Distance k owns seqs k*count..(k+1)*count-1. Before a distance none of whose exchanges is
    stored, ``place(d)`` puts the tag there (moves a simulated station, or asks the user to move
    the board); a distance with some stored (resume) continues where it is. Holes are filled
    only within the distance being measured, so no exchange is recorded at the wrong distance;
    an incomplete distance stops the run before the tag is moved (``--resume`` continues).
    The stored seqs decide what is left. The result sums the runs."""
    per = plan.count
    total = per * len(distances_m)
    t0 = time.monotonic()
    res: RunResult | None = None
    lost: dict[str, Any] = {}
    for k, d in enumerate(distances_m):
        block = set(range(k * per, (k + 1) * per))
        stored = block & _stored_seqs(session, "ranges", (("ref_station", ref_station),
                                                          ("tag_station", tag_station)))
        if stored == block:
            continue
        if not stored:
            place(d)
        res = run_ranges(ref, tag, session, replace(plan, count=(k + 1) * per), ref_station, tag_station, d,
                         progress=progress, first_seq=k * per)
        for key, v in res.losses.items():
            lost[key] = lost.get(key, 0) + v if isinstance(v, int) else [*lost.get(key, []), *v]
        if not res.complete:
            break
    if res is None:
        return RunResult(records=session.count("ranges"), expected=total, wall_s=0.0,
                         losses={"n_missing": 0, "lost_frames": 0, "duplicates": 0})
    return RunResult(records=session.count("ranges"), expected=total, wall_s=time.monotonic() - t0,
                     losses=lost or res.losses, counters=res.counters)


# ---- session files ----------------------------------------------------------------------

def open_or_create(out: Path | None, resume: Path | None, meta: Callable[[], dict[str, Any]],
                   force: bool) -> tuple[Session, dict[str, Any]]:
    """A new session at ``out`` (meta from ``meta()``), or the session to resume; returns it and
    its settings."""
    if resume is not None:
        s = Session.open(resume)
        settings = s.meta.get("settings")
        if not isinstance(settings, dict):
            s.close()
            raise SessionError(f"{resume}: no run settings in the session: cannot resume it")
        return s, settings
    if out is None:
        raise RunError("give --out S.db (a new session) or --resume S.db")
    m = meta()
    return Session.create(out, m, overwrite=force), m["settings"]


def record_run(session: Session, name: str, result: RunResult) -> None:
    """Store the run's summary in the session (results ``run``, appended per resume)."""
    runs = session.results().get("runs", [])
    runs.append({"name": name, "records": result.records, "expected": result.expected,
                 "wall_s": result.wall_s, "losses": result.losses, "counters": result.counters,
                 "complete": result.complete})
    session.set_result("runs", runs)
