"""Session runners: drift, power calibration and ranging against any two stations.

The runners speak only the wire protocol (uwbcal.device), so the same code drives EVK1000
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

import argparse
import math
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import ExitStack, contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Final

from uwbcal import dw1000
from uwbcal.device import Device
from uwbcal.errors import DeviceTimeout, LinkError, SessionError, UwbcalError
from uwbcal.link import proto_gen as pg
from uwbcal.sessions import gapfill
from uwbcal.sessions.recorder import METHOD_CODES, RangeRecorder, TripletRecorder
from uwbcal.sessions.store import Session

#: The paper's radio settings: channel 2, PRF 64 MHz, preamble 128, 6.81 Mb/s.
PAPER_RADIO: Final = {"channel": 2, "prf_mhz": 64, "preamble_len": 128, "data_rate": 2}
DATA_RATE_KBPS: Final = {0: 110, 1: 850, 2: 6810}
#: Default antenna delay registers, device units (Decawave's usual starting value).
DEFAULT_ANTD: Final = 16436
#: Highest TX_POWER octet the ladders start from: coarse 0, fine 31 (nominal +15.5 dB).
TOP_GAIN: Final = dw1000.gain_octet(0, 31)
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


# ---- plans ------------------------------------------------------------------------------

def gain_ladder(top_octet: int, step_db: float, steps: int, coarse_step_db: float = 3.0) -> list[int]:
    """TX_POWER octets for nominal gains top, top - step_db, ... (``steps`` values).

    Each nominal gain is reached with the smallest coarse setting whose fine gain (0.5 dB
    steps, 0..15.5 dB) can make it; a value no octet can make raises RunError.
    """
    top = float(dw1000.gain_nominal_db(top_octet, coarse_step_db))
    out: list[int] = []
    for i in range(steps):
        want = top - i * step_db
        for coarse in range(7):
            fine = (want + coarse * coarse_step_db) / 0.5
            if -1e-6 <= fine <= 31 + 1e-6 and abs(fine - round(fine)) < 1e-6:
                out.append(dw1000.gain_octet(coarse, int(round(fine))))
                break
        else:
            raise RunError(f"no TX_POWER octet gives nominal {want:+.2f} dB (step {i}: use 0.5 dB multiples "
                           f"within {top - 6 * coarse_step_db:+.1f}..{top:+.1f} dB)")
    return out


@dataclass(frozen=True)
class TripletPlan:
    """P1/P2/P3 triplets: ``per_step`` per entry of ``gains2``; spacing and period in us."""

    per_step: int
    spacing_us: int
    period_us: int
    gain13: int
    gains2: tuple[int, ...]

    @classmethod
    def from_settings(cls, st: dict[str, Any]) -> TripletPlan:
        """The plan stored in a session's settings (drift and calibrate sessions)."""
        return cls(per_step=int(st["per_step"]), spacing_us=int(st["spacing_us"]),
                   period_us=int(st["period_us"]), gain13=int(st["gain13"]),
                   gains2=tuple(int(g) for g in st["gains2"]))

    @property
    def total(self) -> int:
        """Triplets in the whole plan."""
        return self.per_step * len(self.gains2)

    def remaining(self, done: int) -> list[tuple[int, int, TripletPlan]]:
        """Firmware plans that send triplets ``done``..total-1: (seq_base, step_base, plan)."""
        out: list[tuple[int, int, TripletPlan]] = []
        if done >= self.total:
            return out
        step0, k = divmod(done, self.per_step)
        if k:
            out.append((done, step0, TripletPlan(self.per_step - k, self.spacing_us, self.period_us,
                                                  self.gain13, (self.gains2[step0],))))
            step0 += 1
        if step0 < len(self.gains2):
            out.append((step0 * self.per_step, step0,
                        TripletPlan(self.per_step, self.spacing_us, self.period_us, self.gain13,
                                    self.gains2[step0:])))
        return out


def default_period_us(spacing_us: int) -> int:
    """P1 to next P1: every message ``spacing_us`` after the previous one, as in the paper
    ("the time between every message was about 2 ms"): 3 x spacing."""
    return 3 * spacing_us


def parse_duration_us(text: str) -> int:
    """'2ms', '150us', '0.5s' or a bare number of us -> integer microseconds."""
    t = text.strip().lower()
    for suffix, scale in (("us", 1.0), ("ms", 1e3), ("s", 1e6)):
        if t.endswith(suffix):
            t, mult = t[: -len(suffix)], scale
            break
    else:
        mult = 1.0
    try:
        v = float(t) * mult
    except ValueError:
        raise RunError(f"bad duration {text!r} (examples: 2ms, 150us, 0.5s)") from None
    if not math.isfinite(v) or v <= 0:
        raise RunError(f"duration {text!r} must be positive")
    return int(round(v))


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


def _last_clock(session: Session, table: str, stamp: str) -> tuple[int, float] | None:
    """The stamp and t_s of the record that arrived last (resume continues its clock)."""
    row = session.conn.execute(f"SELECT {stamp}, t_s FROM {table} ORDER BY rowid DESC LIMIT 1").fetchone()
    return None if row is None or row[0] is None else (int(row[0]), float(row[1]))


def _stored_seqs(session: Session, table: str) -> set[int]:
    return {int(x) for x in session.read(table, ["seq"])["seq"].tolist()}


#: Runs one firmware plan (a pass: a map of session seqs, -1 an extra) with a progress bar;
#: returns its fetcher and the stations' counters.
PlanRunner = Callable[[Any, "Progress"], tuple[gapfill.Fetcher, dict[str, Any]]]


def _fill(session: Session, rec: TripletRecorder | RangeRecorder, stamp: str, total: int, unit: str,
          progress: bool, passes: Callable[[list[int]], Sequence[Any]], run_plan: PlanRunner) -> RunResult:
    """Run firmware plans until every seq 0..total-1 is in the session (at most
    gapfill.MAX_PASSES plans): the first pass measures what is missing, later passes measure
    again what was lost and could not be fetched back. Returns the run summary."""
    t0 = time.monotonic()
    clock = _last_clock(session, rec.table, stamp)
    if clock is not None:
        rec.restore_clock(*clock)
    bar = Progress(total, len(rec.seen & set(range(total))), unit, progress)
    counters: dict[str, Any] = {}
    first = True
    try:
        while rec.losses.passes < gapfill.MAX_PASSES:
            missing = rec.missing(total)
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
    rec.losses.missing_seqs = rec.missing(total)
    return RunResult(records=session.count(rec.table), expected=total, wall_s=time.monotonic() - t0,
                     losses=rec.losses.as_dict(), counters=counters)


def run_triplets(tx: Device, rx: Device, session: Session, plan: TripletPlan, tx_station: int,
                 rx_station: int, distance_m: float | None, *, done: int = 0, progress: bool = True,
                 on_record: Callable[[int], None] | None = None) -> RunResult:
    """Run (the rest of) a triplet plan; records go to ``session`` as they arrive.

    Every triplet 0..total-1 not yet in the session is measured, wherever the hole is (a
    resumed session, a broken link): records lost on the way are fetched back from the
    receiver's ring, and what the ring no longer holds is measured again at the same gain step
    in a further firmware plan (gapfill.py), at most gapfill.MAX_PASSES plans. ``done`` is
    what the caller believes is stored already; the session's own records decide.
    ``on_record`` is called with the highest session seq + 1 after every written batch (tests
    use it to interrupt a run).
    """
    del done  # the stored seqs decide, holes included
    rec = TripletRecorder(session, rx_station, plan.spacing_us * 1e-6, distance_m,
                          seen=_stored_seqs(session, "triplets"), per_step=plan.per_step)

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
                 lambda missing: gapfill.triplet_passes(missing, plan.per_step, plan.gains2), run_plan)


# ---- range sessions ---------------------------------------------------------------------

@dataclass(frozen=True)
class RangePlan:
    """``count`` exchanges of one method; period and reply delay in us; one TX gain."""

    method: str
    count: int
    period_us: int
    reply_us: int
    gain: int

    @classmethod
    def from_settings(cls, st: dict[str, Any]) -> RangePlan:
        """The plan stored in a range session's settings."""
        return cls(method=str(st["method"]), count=int(st["count"]), period_us=int(st["period_us"]),
                   reply_us=int(st["reply_us"]), gain=int(st["gain"]))


def run_ranges(ref: Device, tag: Device, session: Session, plan: RangePlan, ref_station: int,
               tag_station: int, distance_m: float | None, *, done: int = 0, progress: bool = True,
               on_record: Callable[[int], None] | None = None) -> RunResult:
    """Run (the rest of) a ranging plan between a reference and a tag: every exchange
    0..count-1 not yet in the session, holes included (see :func:`run_triplets`)."""
    del done  # the stored seqs decide, holes included
    rec = RangeRecorder(session, ref_station, distance_m, seen=_stored_seqs(session, "ranges"))

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

    return _fill(session, rec, "t1r", plan.count, "exchanges", progress, gapfill.range_passes, run_plan)


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


# ---- command-line plumbing shared by drift / calibrate / range ---------------------------

def add_common_args(p: Any) -> None:
    """Options every session command takes."""
    p.add_argument("--out", type=Path, metavar="S.db", help="new session file")
    p.add_argument("--resume", type=Path, metavar="S.db", help="continue a broken session")
    p.add_argument("--force", action="store_true", help="overwrite --out if it exists")
    p.add_argument("--json", action="store_true", help="print the analysis as one JSON object")
    p.add_argument("--plots", type=Path, metavar="DIR", help="write the analysis' PNG figures into DIR")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--no-analysis", action="store_true", help="record only")
    p.add_argument("--tx-antd", type=int, default=DEFAULT_ANTD, help="TX antenna delay, device units")
    p.add_argument("--rx-antd", type=int, default=DEFAULT_ANTD, help="RX antenna delay, device units")
    p.add_argument("--timeout", type=float, default=2.0, help="link timeout per request, s")
    p.add_argument("--retries", type=int, default=SESSION_RETRIES,
                   help="resends of an unanswered request before the session gives up (a noisy link "
                        "needs a few; every request runs at most once on the station)")


def parse_octet(text: str) -> int:
    """A TX_POWER octet from '0x1f', '31' or 'coarse:fine' (e.g. '0:31')."""
    try:
        if ":" in text:
            c, f = text.split(":", 1)
            return dw1000.gain_octet(int(c), int(f))
        v = int(text, 0)
    except ValueError as exc:
        raise RunError(f"bad gain {text!r}: {exc}") from None
    if not 0 <= v <= 0xFF:
        raise RunError(f"gain octet {text!r} out of 0..255")
    return v


def open_devices(ports: list[str], timeout: float, retries: int = SESSION_RETRIES) -> list[Device]:
    """Open the ports (LinkError names the one that fails)."""
    if retries < 0:
        raise RunError(f"--retries {retries}: give 0 or more")
    devs: list[Device] = []
    try:
        for port in ports:
            devs.append(Device.open(port, timeout=timeout, retries=retries))
    except BaseException:
        for d in devs:
            d.close()
        raise
    return devs


def finish(args: Any, session: Session, kind: str, result: RunResult, power: list[Path] | None = None) -> int:
    """Print the run summary and the corrections engineer's analysis (report or JSON)."""
    import json

    from uwbcal.commands import analyze as an

    out: dict[str, Any] = {"run": {"records": result.records, "expected": result.expected,
                                   "wall_s": round(result.wall_s, 3), "complete": result.complete,
                                   "losses": result.losses, "counters": result.counters}}
    text = [f"session {session.path}: {result.records}/{result.expected} records, "
            f"{result.losses['n_missing']} missing, {result.losses['lost_frames']} stream frames lost "
            f"({result.losses.get('fetched', 0)} records fetched back, {result.losses.get('remeasured', 0)} "
            f"re-measured), {result.losses['duplicates']} duplicates dropped, {result.wall_s:.1f} s"]
    if not args.no_analysis and result.records:
        if args.plots is not None:
            args.plots.mkdir(parents=True, exist_ok=True)
        try:
            if kind == "drift":
                res = an.analyze_drift_session(session, args.plots)
            elif kind == "power":
                res = an.analyze_power_session(session, args.plots, -85.0, True, 3.0)
            else:
                res = an.analyze_twr_session(session, args.plots, power or [], None)
            res = an._finite(res)
            session.set_result(f"analyze_{kind}", res)
            out["analysis"] = res
            text.append(an.report(kind, res))
        except UwbcalError as exc:
            out["analysis_error"] = str(exc)
            text.append(f"analysis failed: {exc}")
    if args.json:
        print(json.dumps(out))
    else:
        print("\n".join(text))
    return 0 if result.complete else 10


def resolve_ports(args: argparse.Namespace, command: str, roles: Sequence[str]) -> None:
    """Check and complete the port options ``--<role>`` of a session command (in place).

    A new session needs every port (RunError otherwise). ``--resume S.db`` needs a session
    recorded by ``command`` (SessionError otherwise); a port not given takes the one stored in
    the session's settings (``<role>_port``).
    """
    if args.resume is None and any(getattr(args, role) is None for role in roles):
        raise RunError("give " + " and ".join(f"--{role} PORT" for role in roles))
    if args.resume is not None:
        with Session.open(args.resume, readonly=True) as s0:
            st0 = s0.meta.get("settings") or {}
        if st0.get("command") != command:
            raise SessionError(f"{args.resume}: not a {command} session ({st0.get('command')!r})")
        for role in roles:
            stored = st0.get(f"{role}_port")
            if getattr(args, role) is None and stored is None:
                raise SessionError(f"{args.resume}: its settings name no {role} port; give --{role} PORT")
            setattr(args, role, getattr(args, role) or stored)


#: What :func:`command_stations` yields: devices, radio settings, what each station said.
CommandStations = tuple[list[Device], dict[str, int], list[StationInfo]]


@contextmanager
def command_stations(args: argparse.Namespace, command: str,
                     roles: Sequence[str]) -> Iterator[CommandStations]:
    """The stations of a session command, open and prepared: resolves the ports
    (:func:`resolve_ports`), opens them, stops and configures each (the paper's radio, the
    antenna delays of ``args``). Yields (devices, radio settings, station infos) in ``roles``
    order; closes the devices on exit."""
    resolve_ports(args, command, roles)
    devs = open_devices([getattr(args, role) for role in roles], args.timeout,
                        getattr(args, "retries", SESSION_RETRIES))
    with ExitStack() as stack:
        for d in devs:
            stack.enter_context(d)
        radio = dict(PAPER_RADIO)
        infos = [prepare(d, radio, args.tx_antd, args.rx_antd) for d in devs]
        yield devs, radio, infos


@contextmanager
def command_session(args: argparse.Namespace, stations: list[StationInfo],
                    meta: Callable[[], dict[str, Any]]) -> Iterator[tuple[Session, dict[str, Any]]]:
    """The session of a session command: new at ``--out`` (``meta()`` gives its meta) or the
    one to ``--resume``, checked to belong to ``stations`` (SessionError otherwise), with the
    stations added. Yields (session, its settings); closes the session on exit."""
    session, st = open_or_create(args.out, args.resume, meta, args.force)
    with session:
        check_same_stations(session, stations)
        for info in stations:
            session.add_station(info.station_id, info.uid, info.board, {"port": info.port,
                                                                        "firmware": info.firmware})
        try:
            yield session, st
        except (LinkError, DeviceTimeout) as exc:
            raise type(exc)(f"{exc}; {resume_hint(session, st)}") from None


def resume_hint(session: Session, settings: dict[str, Any]) -> str:
    """What to do after a link loss: the session keeps what arrived; --resume fills the rest."""
    n = sum(session.count(t) for t in ("triplets", "ranges"))
    cmd = settings.get("command") or "<command>"
    return (f"{session.path} keeps the {n} records received: continue it with "
            f"`uwbcal {cmd} --resume {session.path}` once the station answers again (with its port "
            f"option if the port changed)")
