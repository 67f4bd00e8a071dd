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

    def as_dict(self) -> dict[str, Any]:
        """JSON form."""
        return {"lost_frames": self.lost_frames, "index_gaps": self.index_gaps,
                "duplicates": self.duplicates, "missing_seqs": self.missing_seqs[:1000],
                "n_missing": len(self.missing_seqs)}


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
    """

    table = ""
    #: the stream message and its record struct
    batch: type[pg.TripletsResp] | type[pg.RangesResp]
    record: type[pg.WireStruct]

    def __init__(self, session: Session, *, seq_base: int = 0, expected_first_seq: int = 0) -> None:
        self.session = session
        self._pending: list[dict[str, Any]] = []
        self._pending_rows = 0
        self._pending_since = 0.0
        self.seq_base = seq_base
        self.next_seq = expected_first_seq      #: session seq expected next
        self.next_index: int | None = None      #: firmware running index expected next
        self.losses = Losses()
        self.written = 0
        self.clock = _Clock()
        self._seen_max = expected_first_seq - 1

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
        self.next_index = None

    def _check(self, first_index: int, n: int, seqs: npt.NDArray[np.int64],
               lost_frames: int) -> npt.NDArray[np.bool_]:
        """Loss bookkeeping; returns which records to keep (no duplicates)."""
        self.losses.lost_frames += lost_frames
        if self.next_index is not None and first_index != self.next_index:
            gap = (first_index - self.next_index) & 0xFFFFFFFF
            if gap < 0x80000000:
                self.losses.index_gaps += gap
        self.next_index = (first_index + n) & 0xFFFFFFFF
        keep = seqs > self._seen_max
        if not keep.all():
            self.losses.duplicates += int((~keep).sum())
        for s in seqs[keep].tolist():
            if s > self.next_seq:
                self.losses.missing_seqs.extend(range(self.next_seq, s))
            self.next_seq = max(self.next_seq, s + 1)
        if keep.any():
            self._seen_max = max(self._seen_max, int(seqs[keep].max()))
        return np.asarray(keep)

    def add(self, payload: bytes, lost_frames: int = 0) -> int:
        """Queue one stream frame's records for the session; returns how many (duplicates dropped).

        The batch header (first_index) is decoded with the generated message's layout and the
        records as a numpy view of the generated struct; ProtocolError when the payload is short.
        """
        batch, record = self.batch, self.record
        if len(payload) < batch.FIXED_SIZE:
            raise ProtocolError(f"{batch.NAME}: stream frame of {len(payload)} bytes has no header")
        (first_index,) = batch._S.unpack_from(payload)
        rec = pg.records_array(record, payload[batch.FIXED_SIZE:])
        if len(rec) == 0:
            return 0
        seqs = rec["seq"].astype(np.int64) + self.seq_base
        keep = self._check(first_index, len(rec), seqs, lost_frames)
        if not keep.any():
            return 0
        return self._queue(self._columns(rec[keep], seqs[keep]))

    def _columns(self, rec: npt.NDArray[np.void], seqs: npt.NDArray[np.int64]) -> dict[str, Any]:
        """The table's columns of new records (``seqs`` their session seqs)."""
        raise NotImplementedError


class TripletRecorder(StreamRecorder):
    """``triplets`` stream frames -> rows of the ``triplets`` table."""

    table = "triplets"
    batch = pg.TripletsResp
    record = pg.TripletRecord

    def __init__(self, session: Session, rx_station: int, spacing_s: float, distance_m: float | None,
                 *, seq_base: int = 0, step_base: int = 0, expected_first_seq: int = 0) -> None:
        super().__init__(session, seq_base=seq_base, expected_first_seq=expected_first_seq)
        self.rx_station = rx_station
        self.spacing_s = spacing_s
        self.distance_m = distance_m
        self.step_base = step_base

    def new_plan(self, seq_base: int, step_base: int = 0) -> None:  # type: ignore[override]
        """A new firmware plan: its seq and step numbering restart at 0."""
        super().new_plan(seq_base)
        self.step_base = step_base

    def _columns(self, rec: npt.NDArray[np.void], seqs: npt.NDArray[np.int64]) -> dict[str, Any]:
        tx = rec["tx"].astype(np.int64)
        rx = rec["rx"].astype(np.int64)
        temp = rec["temp_cc"].astype(np.float64)
        cols: dict[str, Any] = {
            "seq": seqs,
            "step": rec["step"].astype(np.int64) + self.step_base,
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
                 expected_first_seq: int = 0) -> None:
        super().__init__(session, seq_base=seq_base, expected_first_seq=expected_first_seq)
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
