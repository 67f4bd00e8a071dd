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

Resume: the firmware numbers the triplets / exchanges of each plan from 0, so a resumed
session starts a new plan for what is missing after the last stored record and maps its
numbers onto the session's (seq_base, step_base). Records are never written twice.

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
from uwbcal.sessions.plan import RangePlan, TripletPlan
from uwbcal.sessions.recorder import METHOD_CODES, RangeRecorder, TripletRecorder
from uwbcal.sessions.store import Session

#: The paper's radio settings: channel 2, PRF 64 MHz, preamble 128, 6.81 Mb/s.
PAPER_RADIO: Final = {"channel": 2, "prf_mhz": 64, "preamble_len": 128, "data_rate": 2}
DATA_RATE_KBPS: Final = {0: 110, 1: 850, 2: 6810}
#: Default antenna delay registers, device units (Decawave's usual starting value).
DEFAULT_ANTD: Final = 16436
#: Time without any record after which the runner asks the transmitter whether it is done, s.
STALL_S: Final = 3.0
#: After the transmitter says done, how long to wait for the receiver's last batch, s.
DRAIN_S: Final = 2.0


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
                  "data_rate_kbps": DATA_RATE_KBPS[radio["data_rate"]]},
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


def _stream_loop(rx: Device, tx: Device, recorder: TripletRecorder | RangeRecorder, end_seq: int,
                 frame_type: int, progress: Progress, on_record: Callable[[int], None] | None) -> None:
    """Read stream frames from ``rx`` until the session seq reaches ``end_seq`` or the plan ends."""
    last = time.monotonic()
    done_at: float | None = None
    while recorder.next_seq < end_seq:
        f = rx.client.next_stream(0.25)
        now = time.monotonic()
        if f is not None and f.type == frame_type:
            n = recorder.add(f.payload, f.lost)
            progress.update(n)
            if on_record is not None and n:
                on_record(recorder.next_seq)
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


def run_triplets(tx: Device, rx: Device, session: Session, plan: TripletPlan, tx_station: int,
                 rx_station: int, distance_m: float | None, *, done: int = 0, progress: bool = True,
                 on_record: Callable[[int], None] | None = None) -> RunResult:
    """Run (the rest of) a triplet plan; records go to ``session`` as they arrive.

    ``done`` triplets are already in the session (resume). ``on_record`` is called with the
    next expected session seq after every written batch (tests use it to interrupt a run).
    """
    t0 = time.monotonic()
    rec = TripletRecorder(session, rx_station, plan.spacing_us * 1e-6, distance_m, expected_first_seq=done)
    if done:
        last = session.conn.execute("SELECT tx1, t_s FROM triplets WHERE seq = ?", (done - 1,)).fetchone()
        if last is not None:
            rec.restore_clock(int(last[0]), float(last[1]))
    bar = Progress(plan.total, done, "triplets", progress)
    counters: dict[str, Any] = {}
    try:
        for seq_base, step_base, sub in plan.remaining(done):
            rec.new_plan(seq_base, step_base)
            rx.call(pg.StopReq())
            drain(rx)
            rx.call(pg.ListenReq(role=0, peer=tx_station, reply_us=0))
            r = tx.call(pg.SeqStartReq(per_step=sub.per_step, spacing_us=sub.spacing_us,
                                       period_us=sub.period_us, gain13=sub.gain13, gains2=bytes(sub.gains2)))
            if r.total != sub.total:
                raise RunError(f"{tx.port}: the station plans {r.total} triplets, the host {sub.total}")
            _stream_loop(rx, tx, rec, seq_base + sub.total, pg.TripletsResp.TYPE, bar, on_record)
            counters = {"tx": asdict(tx.call(pg.StopReq())), "rx": asdict(rx.call(pg.StopReq()))}
    finally:
        rec.flush()
        bar.close()
    missing = list(range(rec.next_seq, plan.total))
    rec.losses.missing_seqs.extend(missing)
    return RunResult(records=session.count("triplets"), expected=plan.total, wall_s=time.monotonic() - t0,
                     losses=rec.losses.as_dict(), counters=counters)


# ---- range sessions ---------------------------------------------------------------------

def run_ranges(ref: Device, tag: Device, session: Session, plan: RangePlan, ref_station: int,
               tag_station: int, distance_m: float | None, *, done: int = 0, progress: bool = True,
               on_record: Callable[[int], None] | None = None) -> RunResult:
    """Run (the rest of) a ranging plan between a reference and a tag."""
    t0 = time.monotonic()
    rec = RangeRecorder(session, ref_station, distance_m, seq_base=done, expected_first_seq=done)
    if done:
        last = session.conn.execute("SELECT t1r, t_s FROM ranges WHERE seq = ?", (done - 1,)).fetchone()
        if last is not None:
            rec.restore_clock(int(last[0]), float(last[1]))
    bar = Progress(plan.count, done, "exchanges", progress)
    counters: dict[str, Any] = {}
    try:
        if done < plan.count:
            for d in (tag, ref):
                d.call(pg.StopReq())
                drain(d)
            tag.call(pg.ListenReq(role=1, peer=ref_station, reply_us=plan.reply_us))
            ref.call(pg.RangeStartReq(method=METHOD_CODES[plan.method], tag=tag_station,
                                      count=plan.count - done, period_us=plan.period_us,
                                      reply_us=plan.reply_us, gain=plan.gain))
            _stream_loop(ref, ref, rec, plan.count, pg.RangesResp.TYPE, bar, on_record)
            counters = {"ref": asdict(ref.call(pg.StopReq())), "tag": asdict(tag.call(pg.StopReq()))}
    finally:
        rec.flush()
        bar.close()
    rec.losses.missing_seqs.extend(range(rec.next_seq, plan.count))
    return RunResult(records=session.count("ranges"), expected=plan.count, wall_s=time.monotonic() - t0,
                     losses=rec.losses.as_dict(), counters=counters)


def run_ranges_at(ref: Device, tag: Device, session: Session, plan: RangePlan, ref_station: int,
                  tag_station: int, distances_m: Sequence[float], place: Callable[[float], None], *,
                  done: int = 0, progress: bool = True) -> RunResult:
    """``plan.count`` exchanges at each distance of ``distances_m`` (m), one session.

    Before each distance still to do, ``place(d)`` puts the tag there (moves a simulated
    station, or asks the user to move the board). ``done`` exchanges are already in the session
    (resume): the distance it was at continues without moving again. The result sums the runs.
    """
    per = plan.count
    total = per * len(distances_m)
    t0 = time.monotonic()
    res: RunResult | None = None
    lost: dict[str, Any] = {}
    for k, d in enumerate(distances_m):
        end = (k + 1) * per
        if done >= end:
            continue
        if done == k * per:
            place(d)
        res = run_ranges(ref, tag, session, replace(plan, count=end), ref_station, tag_station, d,
                         done=done, progress=progress)
        for key, v in res.losses.items():
            lost[key] = lost.get(key, 0) + v if isinstance(v, int) else [*lost.get(key, []), *v]
        done = end
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


def records_done(session: Session, table: str) -> int:
    """Records of ``table`` already in the session (its last seq + 1; 0 when empty): where a
    resumed run starts."""
    last = session.last_seq(table)
    return 0 if last is None else last + 1


def record_run(session: Session, name: str, result: RunResult) -> None:
    """Store the run's summary in the session (results ``run``, appended per resume)."""
    runs = session.results().get("runs", [])
    runs.append({"name": name, "records": result.records, "expected": result.expected,
                 "wall_s": result.wall_s, "losses": result.losses, "counters": result.counters,
                 "complete": result.complete})
    session.set_result("runs", runs)
