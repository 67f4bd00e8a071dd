"""Session recorder logic without stations (plans and gain ladders: tests/unit/test_plan.py):
loss / duplicate bookkeeping and t_s across the 40-bit wrap (synthetic stream frames)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from uwbcal.link import proto_gen as pg
from uwbcal.sessions.recorder import RangeRecorder, TripletRecorder
from uwbcal.sessions.schema import INT_NULL
from uwbcal.sessions.store import Session


def _triplets(first_index: int, seqs: list[int], tx1: list[int], step: int = 0) -> bytes:
    recs = [pg.TripletRecord(seq=s, step=step, tx_station=1, gain13=31, gain2=29,
                             tx=(t, (t + 127_795_200) % 2**40, (t + 255_590_400) % 2**40),
                             rx=(t + 5, t + 6, t + 7), temp_cc=2512 if s % 2 else -32768)
            for s, t in zip(seqs, tx1, strict=True)]
    return pg.TripletsResp(first_index=first_index, records=tuple(recs)).encode()


def test_triplet_recorder_losses_duplicates_and_wrap(tmp_path: Path) -> None:
    with Session.create(tmp_path / "s.db", {"kind": "recorded"}) as s:
        rec = TripletRecorder(s, rx_station=2, spacing_s=2e-3, distance_m=3.0)
        six_ms = 383_385_600                              # 6 ms in device units
        t = [2**40 - six_ms, 0, six_ms - 0]               # P1 stamps across the 40-bit wrap
        t[1] = (t[0] + six_ms) % 2**40
        t[2] = (t[1] + six_ms) % 2**40
        assert rec.add(_triplets(0, [0, 1, 2], t)) == 3
        assert rec.add(_triplets(0, [0, 1, 2], t)) == 0               # a repeated frame: nothing written
        assert rec.add(_triplets(5, [5], [(t[2] + 3 * six_ms) % 2**40]), lost_frames=1) == 1
        rec.flush()
        tr = s.read("triplets")
    assert tr["seq"].tolist() == [0, 1, 2, 5]
    np.testing.assert_allclose(tr["t_s"], [0.0, 6e-3, 12e-3, 30e-3], atol=1e-12)   # unwrapped
    assert tr["rx_station"].tolist() == [2] * 4 and (tr["distance_m"] == 3.0).all()
    assert np.isnan(tr["temp_c"][0]) and tr["temp_c"][1] == pytest.approx(25.12)
    assert rec.losses.duplicates == 3 and rec.missing(6) == [3, 4]
    assert rec.losses.lost_frames == 1 and rec.losses.index_gaps == 2


def test_recorder_maps_a_resumed_plan(tmp_path: Path) -> None:
    with Session.create(tmp_path / "s.db", {"kind": "recorded"}) as s:
        rec = TripletRecorder(s, rx_station=2, spacing_s=2e-3, distance_m=None, expected_first_seq=13)
        rec.restore_clock(1_000_000, 0.5)
        rec.new_plan(13, 1)
        rec.add(_triplets(0, [0, 1], [1_000_000 + 383_385_600, 1_000_000 + 2 * 383_385_600]))
        rec.flush()
        tr = s.read("triplets")
    assert tr["seq"].tolist() == [13, 14] and tr["step"].tolist() == [1, 1]
    np.testing.assert_allclose(tr["t_s"], [0.506, 0.512], atol=1e-9)
    assert rec.missing(15) == []                      # 0..12 taken as stored (expected_first_seq)


def test_range_recorder_single_sided_has_no_m3(tmp_path: Path) -> None:
    recs = (pg.RangeRecord(seq=0, method=1, gain=31, tag_station=2, t=(10, 20, 30, 40, 0, 0),
                           range_mm=-(2**31)),
            pg.RangeRecord(seq=1, method=0, gain=31, tag_station=2, t=(50, 60, 70, 80, 90, 99),
                           range_mm=1234))
    with Session.create(tmp_path / "s.db", {"kind": "recorded"}) as s:
        rec = RangeRecorder(s, ref_station=1, distance_m=2.0)
        rec.add(pg.RangesResp(first_index=0, records=recs).encode())
        rec.flush()
        rg = s.read("ranges")
    assert rg["method"].tolist() == ["ss", "paper"]
    assert rg["t3r"][0] == INT_NULL and rg["t3t"][1] == 99
    assert np.isnan(rg["range_station_m"][0]) and rg["range_station_m"][1] == pytest.approx(1.234)
