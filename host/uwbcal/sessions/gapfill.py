"""Nothing lost on a bad link: fetch missed records back from the station's ring, and plan
the re-measurement of what the ring no longer holds.

Two layers (protocol/messages/measurement.toml, ``triplets_fetch`` / ``ranges_fetch``):

1. While a firmware plan runs, every record carries a running index. A gap in the indices
   the host received (a stream frame lost, corrupted or cut short) is asked for again with
   a fetch request; the station answers from its ring of recent records (MEAS_RING_CAP, 32
   records on the EVK1000), also after STOP, until the next activity begins.
2. A record the ring no longer holds (the link was down for longer than the ring lasts), or
   a triplet/exchange that never produced a record (lost on the air), is measured again:
   :func:`triplet_passes` / :func:`range_passes` turn the missing session seqs into
   firmware plans with the same gain step, and a map from the plan's own numbering to the
   session's.

Units: running indices and seqs are counts; timeouts are s.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Final, Protocol

import numpy as np
import numpy.typing as npt

from uwbcal.device import Device
from uwbcal.errors import DeviceTimeout
from uwbcal.link import proto_gen as pg

#: Longest wait for one fetch answer, s (a lost answer is retried). The fetcher waits less once
#: it has measured the link: RTT_FACTOR x the smoothed round trip, at least FETCH_MIN_S, since
#: the ring (32 records, about 0.2 s of a 2 ms plan) must not overwrite a hole while it waits.
FETCH_TIMEOUT_S: Final = 0.25
FETCH_MIN_S: Final = 0.01
RTT_FACTOR: Final = 8.0
#: Retries of one fetch request (a request that still fails leaves its records to re-measure).
FETCH_RETRIES: Final = 4
#: Records asked for in one fetch at most: one frame's worth. After an unanswered attempt the
#: fetcher asks for one record at a time (a short frame survives a noisy link more often),
#: and grows again with every answer.
FETCH_MAX: Final = min(pg.TripletsFetchResp.TAIL_MAX, pg.RangesFetchResp.TAIL_MAX)
#: At most this many firmware plans (passes) re-measure the holes of one run.
MAX_PASSES: Final = 12
#: A pass over at most this many distinct hole counts runs one plan per count; more, one plan
#: sized to the largest (the extra triplets are not written).
MAX_GROUPS: Final = 3
#: Steps of one firmware plan (seq_start gains2 holds 1 to 64).
MAX_PLAN_STEPS: Final = 64


class Recorder(Protocol):
    """What the fetcher needs of a stream recorder (sessions/recorder.py)."""

    indices: set[int]
    next_index: int

    def add_records(self, first_index: int, records: bytes, lost_frames: int = 0) -> int: ...


@dataclass
class FetchStats:
    """What fetching got back and what it could not."""

    fetched: int = 0
    failures: int = 0
    too_old: int = 0


class Fetcher:
    """Asks one station for the records of its current plan that the host missed.

    ``known_next`` is the index the station will give its next record, as far as the host
    knows (the highest index received + 1, or the station's own count from STOP/fetch).
    """

    def __init__(self, dev: Device, stream_type: int, recorder: Recorder) -> None:
        self.req_cls: type[pg.TripletsFetchReq] | type[pg.RangesFetchReq]
        if stream_type == pg.TripletsResp.TYPE:
            self.req_cls = pg.TripletsFetchReq
        elif stream_type == pg.RangesResp.TYPE:
            self.req_cls = pg.RangesFetchReq
        else:
            raise ValueError(f"no fetch for stream type 0x{stream_type:02X}")
        self.dev = dev
        self.recorder = recorder
        self.known_next = 0
        self.gone: set[int] = set()   #: indices the ring no longer holds
        self.stats = FetchStats()
        self.batch = FETCH_MAX        #: records asked for per request now
        self._low = 0                 #: every index below is received or gone
        self.rtt_s: float | None = None  #: smoothed fetch round trip, s

    def holes(self) -> list[int]:
        """Indices below ``known_next`` neither received nor known to be gone, ascending."""
        have = self.recorder.indices
        self.known_next = max(self.known_next, self.recorder.next_index)
        while self._low < self.known_next and (self._low in have or self._low in self.gone):
            self._low += 1
        return [i for i in range(self._low, self.known_next) if i not in have and i not in self.gone]

    def timeout_s(self, longest: float = FETCH_TIMEOUT_S) -> float:
        """How long to wait for one fetch answer now, s."""
        if self.rtt_s is None:
            return longest
        return min(longest, max(FETCH_MIN_S, RTT_FACTOR * self.rtt_s))

    def fetch_one(self, timeout: float = FETCH_TIMEOUT_S, retries: int = FETCH_RETRIES) -> bool:
        """Ask for the oldest hole (and the holes right after it); False when there is none.
        ``timeout`` is the longest wait per attempt (see :meth:`timeout_s`)."""
        holes = self.holes()
        if not holes:
            return False
        first = holes[0]
        frame = None
        for _attempt in range(retries + 1):
            count = 1
            while count < self.batch and count < len(holes) and holes[count] == first + count:
                count += 1
            # A fetch only reads the ring: each attempt may be a new request (new seq), so the
            # next one can ask for fewer records.
            payload = self.req_cls(first_index=first, count=count).encode()
            t0 = time.monotonic()
            try:
                frame = self.dev.client.request_frame(self.req_cls.TYPE, payload,
                                                      timeout=self.timeout_s(timeout), retries=0)
                rtt = time.monotonic() - t0
                self.rtt_s = rtt if self.rtt_s is None else 0.8 * self.rtt_s + 0.2 * rtt
                self.batch = min(FETCH_MAX, self.batch + 1)
                break
            except DeviceTimeout:
                self.batch = 1
        if frame is None:
            self.stats.failures += 1
            self.gone.add(first)          # left to re-measure
            return True
        size = (pg.TripletRecord if self.req_cls is pg.TripletsFetchReq else pg.RangeRecord).WIRE_SIZE
        if len(frame.payload) < 12 or (len(frame.payload) - 12) % size:
            self.stats.failures += 1      # a malformed answer (a station bug): re-measure instead
            self.gone.add(first)
            return True
        oldest = int.from_bytes(frame.payload[0:4], "little")
        nxt = int.from_bytes(frame.payload[4:8], "little")
        self.known_next = max(self.known_next, nxt)
        got = self.recorder.add_records(int.from_bytes(frame.payload[8:12], "little"), frame.payload[12:])
        self.stats.fetched += got
        if first < oldest:
            old = [i for i in holes if i < oldest]
            self.gone.update(old)
            self.stats.too_old += len(old)
        elif frame.payload[12:] == b"" and first < nxt:
            self.gone.add(first)          # should not happen: held but not returned
        return True

    def fetch_all(self, produced: int, timeout: float = FETCH_TIMEOUT_S,
                  retries: int = FETCH_RETRIES) -> None:
        """After STOP: the station produced ``produced`` records; get every hole it still holds."""
        self.known_next = max(self.known_next, produced)
        while self.fetch_one(timeout, retries):
            pass


# ---- re-measurement plans ------------------------------------------------------------------

@dataclass(frozen=True)
class TripletPass:
    """One firmware plan that re-measures holes: per_step triplets at each of gains2, and the
    session seq of each of its triplets (-1: an extra, not written)."""

    per_step: int
    gains2: tuple[int, ...]
    seq_map: npt.NDArray[np.int64]

    @property
    def total(self) -> int:
        """Triplets the firmware plan sends."""
        return self.per_step * len(self.gains2)


def triplet_passes(missing: list[int], per_step: int, gains2: tuple[int, ...]) -> list[TripletPass]:
    """Firmware plans that measure the session seqs ``missing`` again, each at its own gain step
    (seq // per_step). A fresh session gives the whole plan; a resumed tail gives the partial
    step and the full steps after it; scattered holes give a few plans (MAX_GROUPS)."""
    by_step: dict[int, list[int]] = {}
    for s in missing:
        by_step.setdefault(s // per_step, []).append(s)
    steps = sorted(by_step)
    if not steps:
        return []
    counts = sorted({len(by_step[j]) for j in steps})
    groups: list[tuple[int, list[int]]]
    if len(counts) <= MAX_GROUPS:
        groups = [(c, [j for j in steps if len(by_step[j]) == c]) for c in counts]
    else:
        groups = [(max(counts), steps)]
    out: list[TripletPass] = []
    for n, js in groups:
        for k in range(0, len(js), MAX_PLAN_STEPS):
            chunk = js[k:k + MAX_PLAN_STEPS]
            seq_map = np.full(n * len(chunk), -1, dtype=np.int64)
            for i, j in enumerate(chunk):
                seqs = by_step[j]
                seq_map[i * n:i * n + len(seqs)] = seqs
            out.append(TripletPass(n, tuple(gains2[j] for j in chunk), seq_map))
    return out


def range_passes(missing: list[int]) -> list[npt.NDArray[np.int64]]:
    """Session seq maps of the ranging plans that measure the exchanges ``missing`` again (one
    plan: every exchange of a ranging plan is alike)."""
    return [np.asarray(missing, dtype=np.int64)] if missing else []
