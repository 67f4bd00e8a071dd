"""Streamed record batches -> session rows, appended as they arrive.

A recorder turns the firmware's ``triplets`` / ``ranges`` stream frames (protocol/messages/
measurement.toml) into rows of the session's record tables (sessions/columns.py) and appends
each batch at once, in its own small transaction (sessions/store.py), so that a crash loses
nothing already written. It also keeps the bookkeeping that makes losses visible and resume
possible:

- ``seq_base`` / ``step_base`` map a firmware plan's own numbering (which restarts at 0 with
  every plan) to the session's (a resumed session continues where the last record stopped);
- the running record index of each batch (``first_index``) and the triplet/exchange numbers
  are checked for gaps and duplicates; duplicates are never written;
- ``t_s`` (time of P1 / M1 since the session's first record, s, on the transmitter's clock)
  is unwrapped across the 40-bit timestamp wrap from one record to the next.

Units: device units for timestamps (1 / (128 * 499.2 MHz) s), s, m, degC, dBm.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from uwbcal.dw1000 import TIME_UNIT_S, TIMESTAMP_MOD
from uwbcal.errors import ProtocolError
from uwbcal.link import proto_gen as pg
from uwbcal.sessions import columns
from uwbcal.sessions.store import Session

#: temp_cc value meaning "no temperature" (INT16_MIN), range_mm "no range computed on the station".
NO_TEMP: Final = pg.NO_TEMP_CC
NO_RANGE: Final = pg.NO_RANGE_MM
#: Ranging method codes of range_start / range_record and their names (the range_method enum).
METHOD_NAMES: Final = pg.RANGE_METHOD_NAMES
METHOD_CODES: Final = {v: k for k, v in METHOD_NAMES.items()}
_QNAMES: Final = [c[0] for c in columns.RX_QUALITY]


def _quality(q: npt.NDArray[Any], suffix: str) -> dict[str, npt.NDArray[np.int64]]:
    return {f"{n}{suffix}": np.asarray(q[n], dtype=np.int64) for n in _QNAMES}


@dataclass
class Losses:
    """What a stream lost, as the host can see it."""

    lost_frames: int = 0          #: stream frames missing (the frame counter jumped)
    index_gaps: int = 0           #: records missing by the batches' running index
    duplicates: int = 0           #: records received twice (not written again)
    missing_seqs: list[int] = field(default_factory=list)   #: session seq numbers never received
    fetched: int = 0              #: records got back from the station's ring after a loss
    fetch_failures: int = 0       #: fetch requests that went unanswered
    too_old: int = 0              #: lost records the ring no longer held (re-measured instead)
    remeasured: int = 0           #: triplets/exchanges measured again to fill a hole
    passes: int = 0               #: firmware plans run (1 when nothing needed re-measuring)

    def as_dict(self) -> dict[str, Any]:
        """JSON form."""
        return {"lost_frames": self.lost_frames, "index_gaps": self.index_gaps,
                "duplicates": self.duplicates, "missing_seqs": self.missing_seqs[:1000],
                "n_missing": len(self.missing_seqs), "fetched": self.fetched,
                "fetch_failures": self.fetch_failures, "too_old": self.too_old,
                "remeasured": self.remeasured, "passes": self.passes}


@dataclass
class _Clock:
    """Unwraps one station's 40-bit stamps into seconds since a reference."""

    ref_units: int | None = None
    last_units: int | None = None
    last_s: float = 0.0

    def seconds(self, stamps: npt.NDArray[np.int64]) -> npt.NDArray[np.float64]:
        out = np.empty(stamps.shape, dtype=np.float64)
        for i, u in enumerate(stamps.tolist()):
            if self.last_units is None:
                self.ref_units = u
                self.last_units = u
                self.last_s = 0.0
            else:
                d = (u - self.last_units) % TIMESTAMP_MOD
                if d >= TIMESTAMP_MOD // 2:
                    d -= TIMESTAMP_MOD
                self.last_s += d * TIME_UNIT_S
                self.last_units = u
            out[i] = self.last_s
        return out


#: A recorder commits its pending rows when they are this old (s) or this many.
FLUSH_S: Final = 0.1
FLUSH_ROWS: Final = 600


class StreamRecorder:
    """Common part of the triplet and range recorders.

    Rows are committed in small transactions: at the latest :data:`FLUSH_S` seconds or
    :data:`FLUSH_ROWS` rows after they arrived, and by :meth:`flush` (the runner calls it on
    every exit path, Ctrl-C included). One commit (an fsync) per stream frame would throttle a
    simulated world to the disk's speed; a host killed hard loses at most the last
    :data:`FLUSH_S` seconds, which ``--resume`` runs again.

    Records may arrive in any order (streamed, fetched again from the station's ring, or
    re-measured): a session seq already seen is never written twice (``seen``), and the
    firmware running indices received in the current plan (``indices``) tell which records to
    fetch again.
    """

    table = ""
    #: the stream message and its record struct
    batch: type[pg.TripletsResp] | type[pg.RangesResp]
    record: type[pg.WireStruct]

    def __init__(self, session: Session, *, seq_base: int = 0, expected_first_seq: int = 0,
                 seen: set[int] | None = None) -> None:
        self.session = session
        self._pending: list[dict[str, Any]] = []
        self._pending_rows = 0
        self._pending_since = 0.0
        self.seq_base = seq_base
        #: fw seq -> session seq (-1: not wanted) of the running plan; None: seq_base + fw seq
        self.seq_map: npt.NDArray[np.int64] | None = None
        self.next_seq = expected_first_seq      #: highest session seq seen + 1
        self.losses = Losses()
        self.written = 0
        self.clock = _Clock()
        #: session seqs in the session or pending (never written twice)
        self.seen: set[int] = set(seen) if seen is not None else set(range(expected_first_seq))
        #: firmware running indices received in the current plan, and the highest + 1
        self.indices: set[int] = set()
        self.next_index = 0
        #: records kept (written or pending) since this recorder was made
        self.kept = 0

    def _queue(self, cols: dict[str, Any]) -> int:
        n = len(cols["seq"])
        if not self._pending:
            self._pending_since = time.monotonic()
        self._pending.append(cols)
        self._pending_rows += n
        if self._pending_rows >= FLUSH_ROWS or time.monotonic() - self._pending_since >= FLUSH_S:
            self.flush()
        return n

    def flush(self) -> int:
        """Commit every pending row now; returns how many."""
        if not self._pending:
            return 0
        if len(self._pending) == 1:
            cols = self._pending[0]
        else:
            cols = {k: np.concatenate([p[k] for p in self._pending]) for k in self._pending[0]}
        self._pending = []
        self._pending_rows = 0
        n = self.session.append(self.table, cols)
        self.written += n
        return n

    def restore_clock(self, last_stamp: int, last_t_s: float) -> None:
        """Continue t_s after a resume from the last stored record."""
        self.clock.last_units = last_stamp
        self.clock.ref_units = last_stamp
        self.clock.last_s = last_t_s

    def new_plan(self, seq_base: int) -> None:
        """A new firmware plan starts (its numbering restarts at 0, its index too)."""
        self.seq_base = seq_base
        self.seq_map = None
        self.indices = set()
        self.next_index = 0

    def new_plan_map(self, seq_map: npt.ArrayLike) -> None:
        """A new firmware plan whose triplet/exchange k is session seq ``seq_map[k]`` (-1: an
        extra the session does not need; it is not written)."""
        self.seq_map = np.asarray(seq_map, dtype=np.int64)
        self.seq_base = 0
        self.indices = set()
        self.next_index = 0

    def add(self, payload: bytes, lost_frames: int = 0) -> int:
        """Queue one stream frame's records for the session; returns how many (duplicates dropped).

        The batch header (first_index) is decoded with the generated message's layout;
        ProtocolError when the payload is too short to hold it."""
        batch = self.batch
        if len(payload) < batch.FIXED_SIZE:
            raise ProtocolError(f"{batch.NAME}: stream frame of {len(payload)} bytes has no header")
        (first_index,) = batch._S.unpack_from(payload)
        return self.add_records_many([(first_index, payload[batch.FIXED_SIZE:], lost_frames)])

    def add_records(self, first_index: int, records: bytes, lost_frames: int = 0) -> int:
        """Queue records (wire form) whose first has running index ``first_index``."""
        return self.add_records_many([(first_index, records, lost_frames)])

    def add_records_many(self, batches: list[tuple[int, bytes, int]]) -> int:
        """Queue the records (wire form, the generated record struct as a numpy view) of several
        frames at once: (first_index, records, lost_frames) each; returns how many were kept
        (duplicates and records the session does not want dropped)."""
        rec = pg.records_array(self.record, b"".join(b[1] for b in batches))
        if len(rec) == 0:
            return 0
        size = self.record.WIRE_SIZE
        seqs = self._session_seqs(rec["seq"].astype(np.int64))
        keep = self._check([(f, len(r) // size, lost) for f, r, lost in batches], seqs)
        rec, seqs = rec[keep], seqs[keep]
        if len(rec) == 0:
            return 0
        return self._queue(self._columns(rec, seqs))

    def _columns(self, rec: npt.NDArray[np.void], seqs: npt.NDArray[np.int64]) -> dict[str, Any]:
        """The table's columns of new records (``seqs`` their session seqs)."""
        raise NotImplementedError

    def missing(self, total: int) -> list[int]:
        """Session seqs 0..total-1 not seen yet, ascending."""
        return [s for s in range(total) if s not in self.seen]

    def _session_seqs(self, fw_seqs: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
        if self.seq_map is None:
            return fw_seqs + self.seq_base
        out = np.full(fw_seqs.shape, -1, dtype=np.int64)
        ok = (fw_seqs >= 0) & (fw_seqs < len(self.seq_map))
        out[ok] = self.seq_map[fw_seqs[ok]]
        return out

    def _check(self, batches: list[tuple[int, int, int]],
               seqs: npt.NDArray[np.int64]) -> npt.NDArray[np.bool_]:
        """Loss bookkeeping for ``batches`` of (first_index, records, lost_frames) whose records'
        session seqs are ``seqs``; returns which records to keep (wanted, not seen before)."""
        for first_index, n, lost_frames in batches:
            self.losses.lost_frames += lost_frames
            if first_index > self.next_index:
                self.losses.index_gaps += first_index - self.next_index
            self.next_index = max(self.next_index, first_index + n)
            self.indices.update(range(first_index, first_index + n))
        keep = np.array([s >= 0 and s not in self.seen for s in seqs.tolist()], dtype=bool)
        dup = int(((seqs >= 0) & ~keep).sum())
        self.losses.duplicates += dup
        kept = seqs[keep].tolist()
        self.seen.update(kept)
        self.kept += len(kept)
        if kept:
            self.next_seq = max(self.next_seq, max(kept) + 1)
        return keep


class TripletRecorder(StreamRecorder):
    """``triplets`` stream frames -> rows of the ``triplets`` table."""

    table = "triplets"
    batch = pg.TripletsResp
    record = pg.TripletRecord

    def __init__(self, session: Session, rx_station: int, spacing_s: float, distance_m: float | None,
                 *, seq_base: int = 0, step_base: int = 0, expected_first_seq: int = 0,
                 seen: set[int] | None = None, per_step: int | None = None) -> None:
        super().__init__(session, seq_base=seq_base, expected_first_seq=expected_first_seq, seen=seen)
        #: triplets per gain step of the session's plan: a mapped plan's step is seq // per_step
        self.per_step = per_step
        self.rx_station = rx_station
        self.spacing_s = spacing_s
        self.distance_m = distance_m
        self.step_base = step_base

    def new_plan(self, seq_base: int, step_base: int = 0) -> None:  # type: ignore[override]
        """A new firmware plan: its seq and step numbering restart at 0."""
        super().new_plan(seq_base)
        self.step_base = step_base

    def _columns(self, rec: npt.NDArray[np.void], seqs: npt.NDArray[np.int64]) -> dict[str, Any]:
        if self.seq_map is not None and self.per_step:
            steps = seqs // self.per_step
        else:
            steps = rec["step"].astype(np.int64) + self.step_base
        tx = rec["tx"].astype(np.int64)
        rx = rec["rx"].astype(np.int64)
        temp = rec["temp_cc"].astype(np.float64)
        cols: dict[str, Any] = {
            "seq": seqs,
            "step": steps,
            "tx_station": rec["tx_station"].astype(np.int64),
            "rx_station": np.full(len(rec), self.rx_station, dtype=np.int64),
            "t_s": self.clock.seconds(tx[:, 0]),
            "spacing_s": np.full(len(rec), self.spacing_s),
            "gain13": rec["gain13"].astype(np.int64),
            "gain2": rec["gain2"].astype(np.int64),
            "temp_c": np.where(temp == NO_TEMP, np.nan, temp / 100.0),
            "distance_m": np.full(len(rec), np.nan if self.distance_m is None else self.distance_m),
        }
        for k in range(3):
            cols[f"tx{k + 1}"] = tx[:, k]
            cols[f"rx{k + 1}"] = rx[:, k]
            cols.update(_quality(rec["q"][:, k], str(k + 1)))
        return cols


class RangeRecorder(StreamRecorder):
    """``ranges`` stream frames -> rows of the ``ranges`` table."""

    table = "ranges"
    batch = pg.RangesResp
    record = pg.RangeRecord

    def __init__(self, session: Session, ref_station: int, distance_m: float | None, *, seq_base: int = 0,
                 expected_first_seq: int = 0, seen: set[int] | None = None) -> None:
        super().__init__(session, seq_base=seq_base, expected_first_seq=expected_first_seq, seen=seen)
        self.ref_station = ref_station
        self.distance_m = distance_m

    def _columns(self, rec: npt.NDArray[np.void], seqs: npt.NDArray[np.int64]) -> dict[str, Any]:
        t = rec["t"].astype(np.int64)
        methods = rec["method"].astype(np.int64)
        temp = rec["temp_cc"].astype(np.float64)
        rng = rec["range_mm"].astype(np.float64)
        cols: dict[str, Any] = {
            "seq": seqs,
            "method": np.array([METHOD_NAMES.get(int(m), str(int(m))) for m in methods], dtype=object),
            "ref_station": np.full(len(rec), self.ref_station, dtype=np.int64),
            "tag_station": rec["tag_station"].astype(np.int64),
            "t_s": self.clock.seconds(t[:, 0]),
            "distance_m": np.full(len(rec), np.nan if self.distance_m is None else self.distance_m),
            "gain": rec["gain"].astype(np.int64),
            "temp_c": np.where(temp == NO_TEMP, np.nan, temp / 100.0),
            "range_station_m": np.where(rng == NO_RANGE, np.nan, rng / 1000.0),
        }
        names = ("t1r", "t1t", "t2t", "t2r", "t3r", "t3t")
        single = methods == METHOD_CODES["ss"]
        from uwbcal.sessions.schema import INT_NULL

        for k, name in enumerate(names):
            col = t[:, k].copy()
            if name in ("t3r", "t3t"):
                col[single] = INT_NULL
            cols[name] = col
        for key, suffix in (("q_t1", "_t1"), ("q_r2", "_r2"), ("q_t3", "_t3")):
            q = _quality(rec[key], suffix)
            if suffix == "_t3":
                for v in q.values():
                    v[single] = INT_NULL
            cols.update(q)
        return cols
