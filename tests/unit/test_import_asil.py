"""The asil importer on the real sample in tests/data/asil (see its PROVENANCE.md)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from uwbcal.dw1000 import METRES_PER_UNIT, TIMESTAMP_MOD, wrap_diff
from uwbcal.errors import SessionError, UwbcalError
from uwbcal.importers import asil
from uwbcal.sessions import columns

SAMPLE = Path(__file__).resolve().parents[1] / "data" / "asil" / "run"
ACM0 = "2026-01-23-01-01_ttyACM0.csv"
ACM1 = "2026-01-23-01-01_ttyACM1.csv"


def _copy(tmp_path: Path) -> Path:
    run = tmp_path / "run"
    shutil.copytree(SAMPLE, run)
    return run


def _eq1_units(t: dict[str, np.ndarray]) -> np.ndarray:
    """Eq. 1 residual in device units, from the record columns (independent of the gap code)."""
    d12t = wrap_diff(t["tx2"], t["tx1"]).astype(float)
    d13t = wrap_diff(t["tx3"], t["tx1"]).astype(float)
    c12 = wrap_diff(t["rx2"], t["rx1"]) - d12t
    c13 = wrap_diff(t["rx3"], t["rx1"]) - d13t
    return np.asarray(c12 - c13 / d13t * d12t)


def test_counts_and_lost_messages() -> None:
    s = asil.load_run(SAMPLE)
    d = {(c["tx_station"], c["rx_station"]): c for c in s.meta["directions"]}
    # messages 420..620 of each node; node 1 missed node 0's 454 and 553
    assert d[(0, 1)]["messages_sent"] == 201
    assert d[(0, 1)]["lost_message_ids"] == [454, 553]
    assert d[(1, 0)]["messages_lost"] == 0
    # slots 420..620 -> 67 triplets each way; the two lost messages break two of node 0's
    assert d[(0, 1)]["triplets_complete"] == 65 and d[(0, 1)]["triplets_incomplete"] == 2
    assert d[(1, 0)]["triplets_complete"] == 67
    assert s.n_records == 132
    seq0 = s.triplets["seq"][s.triplets["tx_station"] == 0]
    assert 454 // 3 not in seq0 and 553 // 3 not in seq0 and 140 in seq0


def test_columns_layout_and_meta() -> None:
    s = asil.load_run(SAMPLE)
    assert list(s.triplets) == columns.names("triplets")
    assert s.triplets["cir_pwr1"] is None and s.triplets["gain2"] is None
    assert np.all(s.triplets["distance_m"] == 0.457)
    temps = {int(tx): float(t) for tx, t in zip(s.triplets["rx_station"], s.triplets["temp_c"], strict=True)}
    assert temps == {1: 20.3, 0: 20.2}  # RX station temperature from parameters.yaml
    assert s.meta["provenance"]["repo"] == "asil-lab/Uwb-clock-and-antenna-delay-dataset"
    assert s.meta["provenance"]["commit"] == "bf630f316616d96a10edc48a5bbc921e0efc74c7"
    assert "node_distance: 0.457" in s.meta["parameters_yaml"]
    assert s.meta["parameters"]["temperature"] == [20.2, 20.3]
    assert s.meta["parameters"]["node_pairs"][0]["nodes"] == [0, 1]
    assert s.meta["timestamps"]["unwrapped_at_source"] is True
    # P1 -> P3 spans two of the transmitter's turns (nominally 2 x 24 ms; the logger jitters)
    sp13 = wrap_diff(s.triplets["tx3"], s.triplets["tx1"]) * 1.5650040064102565e-11
    assert np.all((sp13 > 0.020) & (sp13 < 0.100)) and 0.040 < np.median(sp13) < 0.060


def test_timestamps_stored_as_given_and_wrap_invariant(tmp_path: Path) -> None:
    s = asil.load_run(SAMPLE)
    t = s.triplets
    raw0 = (SAMPLE / ACM0).read_text().splitlines()[1:]
    given = {int(r.split(",")[3]) for r in raw0}
    assert set(t["tx1"][t["tx_station"] == 0]) <= given  # not reduced modulo 2**40
    assert np.any(t["rx3"] >= TIMESTAMP_MOD) and np.any(t["tx1"] < TIMESTAMP_MOD)
    crossing = (t["tx1"] < TIMESTAMP_MOD) & (t["tx3"] >= TIMESTAMP_MOD)
    # a raw 40-bit log (wrapped) of the same run imports to the same eq. 1 residuals
    run = _copy(tmp_path)
    for name in (ACM0, ACM1):
        lines = (run / name).read_bytes().split(b"\r\n")
        out = [lines[0]]
        for ln in lines[1:]:
            if ln:
                f = ln.split(b",")
                bit = int(f[3]) % TIMESTAMP_MOD
                f[3] = str(bit).encode()
                f[4] = repr(bit / asil.TICKS_PER_S).encode()
                out.append(b",".join(f))
        (run / name).write_bytes(b"\r\n".join(out) + b"\r\n")
    w = asil.load_run(run)
    assert np.all(w.triplets["tx1"] < TIMESTAMP_MOD)
    assert w.meta["timestamps"]["unwrapped_at_source"] is False
    np.testing.assert_array_equal(_eq1_units(w.triplets), _eq1_units(t))
    assert np.count_nonzero(crossing) > 0
    # the drift residual is small (cm) once differences are taken modulo 2**40
    assert np.max(np.abs(_eq1_units(t)[crossing])) * METRES_PER_UNIT < 0.2  # metres


def test_real_clock_rate_is_consistent_both_ways() -> None:
    t = asil.load_run(SAMPLE).triplets
    d13t = wrap_diff(t["tx3"], t["tx1"]).astype(float)
    rate = (wrap_diff(t["rx3"], t["rx1"]) - d13t) / d13t * 1e6
    r01 = np.median(rate[t["tx_station"] == 0])
    r10 = np.median(rate[t["tx_station"] == 1])
    assert 3.0 < abs(r01) < 10.0 and abs(r01 + r10) < 0.05  # one clock offset, seen from both ends


@pytest.mark.parametrize(
    "damage,needle",
    [
        ("missing", "no such file"),
        ("truncated", "line 403: truncated"),
        ("fields", "line 5: expected 6 fields"),
        ("value", "line 7: malformed value"),
        ("seconds", "line 9: timestamp_seconds"),
        ("header", "line 1: header"),
        ("duplicate", "duplicate TX row"),
    ],
)
def test_clear_errors(tmp_path: Path, damage: str, needle: str) -> None:
    run = _copy(tmp_path)
    f = run / ACM0
    lines = f.read_bytes().split(b"\r\n")
    if damage == "missing":
        (run / "parameters.yaml").unlink()
        f = run / "parameters.yaml"
    elif damage == "truncated":
        f.write_bytes(f.read_bytes()[:-30])
    elif damage == "fields":
        lines[4] = b",".join(lines[4].split(b",")[:4])
        f.write_bytes(b"\r\n".join(lines))
    elif damage == "value":
        lines[6] = lines[6].replace(b",", b",x", 1)
        f.write_bytes(b"\r\n".join(lines))
    elif damage == "seconds":
        parts = lines[8].split(b",")
        parts[3] = str(int(parts[3]) + 10**9).encode()
        lines[8] = b",".join(parts)
        f.write_bytes(b"\r\n".join(lines))
    elif damage == "header":
        lines[0] = lines[0].replace(b"message_id", b"msg")
        f.write_bytes(b"\r\n".join(lines))
    elif damage == "duplicate":
        lines.insert(3, lines[1])
        f.write_bytes(b"\r\n".join(lines))
    with pytest.raises(SessionError) as exc:
        asil.load_run(run)
    assert isinstance(exc.value, UwbcalError)
    assert needle in str(exc.value) and f.name in str(exc.value)


def test_missing_run_dir_and_node_file(tmp_path: Path) -> None:
    with pytest.raises(SessionError, match="no such run directory"):
        asil.load_run(tmp_path / "nope")
    run = _copy(tmp_path)
    (run / ACM1).unlink()
    with pytest.raises(SessionError, match="1 node file, expected one per node"):
        asil.load_run(run)


def test_import_command_writes_a_session(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from uwbcal.cli import main
    from uwbcal.sessions.schema import INT_NULL
    from uwbcal.sessions.store import Session

    out = tmp_path / "s.db"
    assert main(["import", "asil", str(SAMPLE), "--out", str(out), "--json"]) == 0
    summary = __import__("json").loads(capsys.readouterr().out)
    assert summary["records"] == 132 and summary["messages_lost"] == 2 and summary["triplets_incomplete"] == 2
    with Session.open(out, readonly=True) as s:
        rec = s.read("triplets")
        meta = s.meta
        assert [st["id"] for st in s.stations()] == [0, 1]
    direct = asil.load_run(SAMPLE).triplets
    for k in ("tx1", "rx3", "seq", "tx_station"):
        np.testing.assert_array_equal(rec[k], direct[k])
    assert np.all(rec["gain13"] == INT_NULL)  # unknown gain stays NULL
    assert meta["kind"] == "imported" and meta["provenance"]["files"]
    assert meta["timestamps"]["unwrapped_at_source"] is True
    # refuses to overwrite, as a one-line error
    assert main(["import", "asil", str(SAMPLE), "--out", str(out)]) == 5
    assert "exists" in capsys.readouterr().err
