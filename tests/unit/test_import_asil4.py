"""The N-node asil importer on the real four-node sample in tests/data/asil4 (see PROVENANCE.md)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from uwbcal.dw1000 import TIME_UNIT_S, wrap_diff
from uwbcal.errors import SessionError
from uwbcal.importers import asil
from uwbcal.sessions import columns

SAMPLE = Path(__file__).resolve().parents[1] / "data" / "asil4" / "run"


def test_twelve_directions_with_losses_counted() -> None:
    s = asil.load_run(SAMPLE)
    d = {(c["tx_station"], c["rx_station"]): c for c in s.meta["directions"]}
    assert sorted(d) == [(a, b) for a in range(4) for b in range(4) if a != b]
    # every node sent messages 0..47 (16 triplet slots per direction)
    assert all(c["messages_sent"] == 48 and c["triplet_slots"] == 16 for c in d.values())
    # node 1 missed 11 of node 0's messages: 3, 5, 9, 14, 20, 23, 28, 31, 38, 39, 46
    assert d[(0, 1)]["lost_message_ids"] == [3, 5, 9, 14, 20, 23, 28, 31, 38, 39, 46]
    assert d[(1, 0)]["messages_lost"] == 0 and d[(1, 0)]["triplets_complete"] == 16
    assert d[(3, 2)]["triplets_complete"] == 16
    assert s.n_records == sum(c["triplets_complete"] for c in d.values()) == 135
    assert s.meta["n_nodes"] == 4 and s.meta["distance_m"] is None
    assert list(s.triplets) == columns.names("triplets")


def test_pair_distances_and_spacing() -> None:
    t = asil.load_run(SAMPLE).triplets
    want = {(0, 1): 0.75, (0, 2): 0.55, (0, 3): 0.905, (1, 2): 0.62, (1, 3): 0.39, (2, 3): 0.51}
    for (a, b), dist in want.items():
        for tx, rx in ((a, b), (b, a)):
            sel = (t["tx_station"] == tx) & (t["rx_station"] == rx)
            assert np.all(t["distance_m"][sel] == dist)
    # P1 -> P2 is one turn of four nodes: nominally 4 x 20 ms, the logger jitters
    assert 0.06 < np.median(t["spacing_s"]) < 0.10


def test_one_clock_offset_per_node_pair_closes_around_loops() -> None:
    """Clock rates seen by each ordered pair: antisymmetric, and additive around a loop."""
    t = asil.load_run(SAMPLE).triplets
    d13t = wrap_diff(t["tx3"], t["tx1"]).astype(float)
    rate = (wrap_diff(t["rx3"], t["rx1"]) - d13t) / d13t * 1e6
    r = {}
    for a in range(4):
        for b in range(4):
            sel = (t["tx_station"] == a) & (t["rx_station"] == b)
            if a != b:
                r[a, b] = float(np.median(rate[sel]))
    for a in range(4):
        for b in range(a + 1, 4):
            assert abs(r[a, b] + r[b, a]) < 0.3
    # (0 -> 1) + (1 -> 2) = (0 -> 2): offsets relative to one reference add up
    assert abs(r[0, 1] + r[1, 2] - r[0, 2]) < 0.3
    assert abs(r[1, 3] + r[3, 2] - r[1, 2]) < 0.3


def test_eq1_residual_is_centimetres() -> None:
    t = asil.load_run(SAMPLE).triplets
    d12t = wrap_diff(t["tx2"], t["tx1"]).astype(float)
    d13t = wrap_diff(t["tx3"], t["tx1"]).astype(float)
    c12 = wrap_diff(t["rx2"], t["rx1"]) - d12t
    c13 = wrap_diff(t["rx3"], t["rx1"]) - d13t
    res_m = (c12 - c13 / d13t * d12t) * TIME_UNIT_S * 299_792_458.0
    assert np.median(np.abs(res_m)) < 0.05


def test_five_column_header_only_for_all_five(tmp_path: Path) -> None:
    run = tmp_path / "run"
    shutil.copytree(SAMPLE, run)
    f = run / "2026-02-24-01-01_ttyACM2.csv"
    lines = f.read_text().splitlines()
    lines[3] = lines[3] + ",0.0"  # a six-field row under a five-column header
    f.write_text("\n".join(lines) + "\n")
    with pytest.raises(SessionError, match=r"ttyACM2.csv: line 4: expected 5 fields, found 6"):
        asil.load_run(run)


def test_duplicate_node_id_named(tmp_path: Path) -> None:
    run = tmp_path / "run"
    shutil.copytree(SAMPLE, run)
    src = (run / "2026-02-24-01-01_ttyACM1.csv").read_text()
    (run / "2026-02-24-01-01_ttyACM3.csv").write_text(src)
    with pytest.raises(SessionError, match="node_id 1 also in"):
        asil.load_run(run)


def test_import_command_four_nodes(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from uwbcal.cli import main
    from uwbcal.sessions.store import Session

    out = tmp_path / "s4.db"
    assert main(["import", "asil", str(SAMPLE), "--out", str(out), "--json"]) == 0
    summary = __import__("json").loads(capsys.readouterr().out)
    assert summary["records"] == 135 and len(summary["directions"]) == 12
    with Session.open(out, readonly=True) as s:
        assert [st["id"] for st in s.stations()] == [0, 1, 2, 3]
        assert s.meta["pair_distances_m"]["1-3"] == 0.39
