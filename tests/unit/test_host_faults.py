"""The host's faults of issue 12, each with its own test: one line on stderr, a non-zero exit,
no traceback, and nothing written half-way. What these cannot see: a real USB port vanishing
(the pyserial call that fails is simulated), and damage SQLite itself does not detect."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import shutil
import sqlite3
import termios
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from uwbcal import cli, tables, vectorsim
from uwbcal.errors import LinkError
from uwbcal.link import proto_gen as pg
from uwbcal.link.client import Client
from uwbcal.link.framing import Frame, encode_frame
from uwbcal.link.transport import Transport
from uwbcal.physics.scenario import load_scenario
from uwbcal.sessions.store import Session

DATA = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "asil-uwb-clock" / "2026-01-23-01"
ASIL = Path(__file__).resolve().parents[1] / "data" / "asil" / "run"


def _one_line_error(capsys: pytest.CaptureFixture[str], rc: int, *needles: str) -> str:
    """The error of a failed command: one line on stderr, or with --json one JSON object
    ``{"error", "code"}`` on stdout (and nothing on stderr); no traceback either way."""
    out, err = (x.strip() for x in capsys.readouterr())
    assert rc not in (0, None), err or out
    if not err and out.startswith("{"):
        doc = json.loads(out)
        assert len(out.splitlines()) == 1 and doc["code"] == rc, out
        err = doc["error"]
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    for n in needles:
        assert n in err, err
    return err


def _digest(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def drift_db(tmp_path_factory: pytest.TempPathFactory) -> Path:
    sc = load_scenario("two_stations")
    d = tmp_path_factory.mktemp("faults")
    return vectorsim.simulate_session(sc, vectorsim.drift_schedule(sc, 3000), d / "drift.db", seed=3)


def _copy(src: Path, tmp_path: Path) -> Path:
    dst = tmp_path / src.name
    shutil.copy(src, dst)
    return dst


class _VanishingSerial:
    """pyserial's POSIX port whose tcdrain fails: the port went away during a write."""

    def write(self, data: bytes) -> int:
        return len(data)

    def flush(self) -> None:
        raise termios.error(5, "Input/output error")

    def close(self) -> None:
        raise termios.error(5, "Input/output error")


def test_port_vanishing_during_a_write_is_a_link_error() -> None:
    t = Transport.__new__(Transport)
    t.port = "/dev/ttyACM9"
    t._ser = _VanishingSerial()  # type: ignore[assignment]
    with pytest.raises(LinkError) as exc:
        t.write(b"\x00\x01")
    assert str(exc.value) == "port /dev/ttyACM9: write failed: Input/output error"
    t.close()  # closing a vanished port is quiet


def test_corrupt_data_pages(drift_db: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    db = _copy(drift_db, tmp_path)
    with sqlite3.connect(db) as c:
        page = c.execute("PRAGMA page_size").fetchone()[0]
        n_pages = c.execute("PRAGMA page_count").fetchone()[0]
    raw = bytearray(db.read_bytes())
    for k in range(n_pages // 2, n_pages // 2 + 4):            # data pages of the triplets table
        raw[k * page:(k + 1) * page] = b"\xa5" * page
    db.write_bytes(bytes(raw))
    before = _digest(db)
    rc = cli.main(["analyze", "drift", str(db)])
    _one_line_error(capsys, rc, str(db))
    assert _digest(db) == before


def test_text_in_an_integer_column(drift_db: Path, tmp_path: Path,
                                   capsys: pytest.CaptureFixture[str]) -> None:
    db = _copy(drift_db, tmp_path)
    with sqlite3.connect(db) as c:
        c.execute("UPDATE triplets SET rx2 = 'twelve' WHERE rowid = 7")
    rc = cli.main(["analyze", "drift", str(db), "--json"])
    _one_line_error(capsys, rc, str(db), "rx2", "'twelve'")
    with Session.open(db, readonly=True) as s:
        assert "analyze_drift" not in s.results()


def test_analyze_never_writes_into_a_damaged_file(drift_db: Path, tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    db = _copy(drift_db, tmp_path)
    with Session.open(db) as s:
        s.set_result("zzzz_marker", {"x": 1})
    with sqlite3.connect(db) as c:
        page = c.execute("PRAGMA page_size").fetchone()[0]
        root = c.execute("SELECT rootpage FROM sqlite_master "
                         "WHERE name = 'sqlite_autoindex_results_1'").fetchone()[0]
    raw = bytearray(db.read_bytes())
    at = raw.find(b"zzzz_marker", (root - 1) * page, root * page)
    assert at > 0
    raw[at + 10] = ord("x")                 # the index no longer matches its table: records still read
    db.write_bytes(bytes(raw))
    with sqlite3.connect(db) as c:
        assert c.execute("PRAGMA integrity_check").fetchone()[0] != "ok"
    before = _digest(db)
    rc = cli.main(["analyze", "drift", str(db)])
    _one_line_error(capsys, rc, str(db), "corrupt")
    assert _digest(db) == before


def test_table_show_with_too_many_curve_points(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    m = tuple(float(x) for x in np.linspace(-105.0, -75.0, 6))
    curve = tables.PowerCurve(measured_dbm=m, error_s=tuple(0.0 for _ in m), real_dbm=m,
                              reference_real_dbm=-70.0, reference_measured_dbm=-75.0)
    data = tables.build(bytes(12), curve, created_unix=1_700_000_000)
    t = tables.decode(data)
    bad = tables.seal(dataclasses.replace(t, n_curve=40, a_dbm=float("nan")))
    tables.save(tmp_path / "bad.json", bad)
    rc = cli.main(["table", "show", str(tmp_path / "bad.json")])
    out = capsys.readouterr()
    assert "INVALID" in out.out and "Traceback" not in out.err
    assert rc != 0 and len(out.err.strip().splitlines()) == 1 and "n_curve" in out.err
    rc = cli.main(["table", "show", str(tmp_path / "bad.json"), "--json"])
    out = capsys.readouterr()

    def no_nan(x: str) -> Any:
        raise AssertionError(f"{x} in strict JSON")

    doc = json.loads(out.out, parse_constant=no_nan)
    assert rc != 0 and doc["invalid"]["field"] == "n_curve" and doc["a_dbm"] is None


def test_duplicated_stream_frame_is_not_65535_lost() -> None:
    class Wire:
        port = "fake"

        def __init__(self, data: bytes) -> None:
            self.data = data

        def read(self, wait_s: float) -> bytes:
            out, self.data = self.data, b""
            return out

        def write(self, data: bytes) -> None:
            pass

        def close(self) -> None:
            pass

    def f(seq: int) -> bytes:
        return encode_frame(Frame(type=pg.TripletsResp.TYPE, seq=seq, flags=pg.FLAG_STREAM,
                                  payload=seq.to_bytes(4, "little")))

    c = Client(Wire(f(0) + f(1) + f(1) + f(2) + f(4)))  # type: ignore[arg-type]
    got = [c.next_stream(0.01) for _ in range(5)]
    assert [g.lost for g in got if g is not None] == [0, 0, 0, 0, 1]
    assert c.stream_lost[pg.TripletsResp.TYPE] == 1 and c.stream_dup[pg.TripletsResp.TYPE] == 1


@pytest.mark.parametrize("garbage,needle", [
    ("nodes: hello\n", "'nodes'"),
    ("nodes:\n- 0\n- 1\nnode_distance: far\n", "'node_distance'"),
    ("nodes:\n- 0\n- 1\ntemperature:\n- warm\n", "'temperature'"),
    ("\x00\xff\xfe garbage", "parameters.yaml"),
])
def test_import_asil_refuses_garbage_parameters(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                garbage: str, needle: str) -> None:
    src = DATA if DATA.is_dir() else ASIL
    run = tmp_path / "run"
    shutil.copytree(src, run)
    (run / "parameters.yaml").write_bytes(garbage.encode("latin-1"))
    out = tmp_path / "a.db"
    rc = cli.main(["import", "asil", str(run), "--out", str(out)])
    _one_line_error(capsys, rc, needle)
    assert not out.exists()


def test_gap_on_a_one_record_session(drift_db: Path, tmp_path: Path,
                                     capsys: pytest.CaptureFixture[str]) -> None:
    db = _copy(drift_db, tmp_path)
    with sqlite3.connect(db) as c:
        c.execute("DELETE FROM triplets WHERE rowid > 1")
    rc = cli.main(["gap", str(db), "--quiet"])
    _one_line_error(capsys, rc, "1 triplet record", "at least")
