"""Re-measurement plans and the fetcher's bookkeeping (sessions/gapfill.py), without stations."""

from __future__ import annotations

from typing import Any

import numpy as np
from uwbcal.errors import DeviceTimeout
from uwbcal.link import proto_gen as pg
from uwbcal.link.framing import Frame
from uwbcal.sessions import gapfill

GAINS = (31, 29, 27, 25)


def test_fresh_session_is_the_whole_plan() -> None:
    (p,) = gapfill.triplet_passes(list(range(40)), 10, GAINS)
    assert (p.per_step, p.gains2) == (10, GAINS) and p.seq_map.tolist() == list(range(40))


def test_resumed_tail_is_the_partial_step_then_the_full_steps() -> None:
    ps = gapfill.triplet_passes(list(range(13, 40)), 10, GAINS)
    assert [(p.per_step, p.gains2) for p in ps] == [(7, (29,)), (10, (27, 25))]
    assert ps[0].seq_map.tolist() == list(range(13, 20)) and ps[1].seq_map.tolist() == list(range(20, 40))


def test_scattered_holes_keep_their_gain_step() -> None:
    holes = [3, 11, 12, 25, 26, 27, 30, 31, 32, 33]
    ps = gapfill.triplet_passes(holes, 10, GAINS)
    got = {}
    for p in ps:
        for k, s in enumerate(p.seq_map.tolist()):
            if s >= 0:
                assert p.gains2[k // p.per_step] == GAINS[s // 10]   # measured at its own step's gain
                got[s] = got.get(s, 0) + 1
    assert sorted(got) == holes and set(got.values()) == {1}          # each hole exactly once


def test_many_hole_counts_make_one_plan_with_extras() -> None:
    holes = [0, 10, 11, 20, 21, 22, 30, 31, 32, 33]                   # 4 different counts
    (p,) = gapfill.triplet_passes(holes, 10, GAINS)
    assert p.per_step == 4 and sorted(int(s) for s in p.seq_map if s >= 0) == holes
    assert int((p.seq_map < 0).sum()) == 6                            # extras, not written


class _Rec:
    def __init__(self) -> None:
        self.indices: set[int] = set()
        self.next_index = 0
        self.got: list[int] = []

    def add_records(self, first_index: int, records: bytes, lost_frames: int = 0) -> int:
        n = len(records) // pg.TripletRecord.WIRE_SIZE
        self.indices.update(range(first_index, first_index + n))
        self.next_index = max(self.next_index, first_index + n)
        self.got += list(range(first_index, first_index + n))
        return n


class _Client:
    """Answers fetches from a ring holding indices oldest..next-1; drops the first ``lose``."""

    def __init__(self, oldest: int, nxt: int, lose: int = 0) -> None:
        self.oldest, self.next, self.lose, self.asked = oldest, nxt, lose, 0

    def request_frame(self, type_: int, payload: bytes, **kw: Any) -> Frame:
        self.asked += 1
        if self.lose:
            self.lose -= 1
            raise DeviceTimeout("lost")
        req = pg.TripletsFetchReq.decode(payload)
        have = [i for i in range(req.first_index, req.first_index + min(req.count, 3))
                if self.oldest <= i < self.next]
        recs = tuple(pg.TripletRecord(seq=i) for i in have)
        return Frame(type=type_, seq=1, flags=1, payload=pg.TripletsFetchResp(
            oldest=self.oldest, next=self.next, first_index=req.first_index, records=recs).encode())


class _Dev:
    def __init__(self, client: _Client) -> None:
        self.client = client


def test_fetcher_gets_what_the_ring_holds_and_gives_up_the_rest() -> None:
    rec = _Rec()
    rec.indices = {0, 1, 5, 9}
    rec.next_index = 10
    f = gapfill.Fetcher(_Dev(_Client(oldest=4, nxt=12, lose=1)), pg.TripletsResp.TYPE, rec)  # type: ignore[arg-type]
    f.fetch_all(12)
    assert sorted(rec.got) == [4, 6, 7, 8, 10, 11]                    # held: fetched (one answer lost)
    assert f.gone == {2, 3} and f.stats.too_old == 2 and not f.holes()
    assert np.array_equal(sorted(rec.indices | f.gone), np.arange(12))
