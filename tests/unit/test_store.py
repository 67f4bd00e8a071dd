"""The session file (uwbcal.sessions.store): round trips, NULLs, errors, resume."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import numpy as np
import pytest
from uwbcal.errors import SessionError
from uwbcal.sessions import columns
from uwbcal.sessions.schema import INT_NULL, SCHEMA_VERSION, columns_markdown, table_sql
from uwbcal.sessions.store import CHUNK_ROWS, Session, is_null


def make_rows(n: int, rng: np.random.Generator) -> dict[str, np.ndarray]:  # type: ignore[type-arg]
    rows: dict[str, np.ndarray] = {}  # type: ignore[type-arg]
    for name, typ, _, _ in columns.TRIPLET:
        if typ == "INTEGER":
            rows[name] = rng.integers(0, 1 << 40, n)
        else:
            rows[name] = rng.normal(size=n)
    rows["seq"] = np.arange(n)
    return rows


def test_round_trip_with_nulls(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    rows = make_rows(1000, rng)
    rows["temp_c"][5] = np.nan
    rows["car_int1"][7] = INT_NULL
    with Session.create(tmp_path / "s.db", {"kind": "recorded", "settings": {"spacing_s": 0.002}}) as s:
        assert s.append("triplets", rows) == 1000
        s.add_station(1, "DECA-1", "one", {"role": "rx"})
    with Session.open(tmp_path / "s.db") as s:
        back = s.read("triplets")
        assert list(back) == columns.names("triplets")
        for k, v in rows.items():
            assert np.array_equal(back[k], v, equal_nan=True), k
        assert back["car_int1"].dtype == np.int64 and is_null(back["car_int1"])[7]
        assert is_null(back["temp_c"])[5] and is_null(back["temp_c"]).sum() == 1
        assert s.meta["settings"] == {"spacing_s": 0.002} and s.meta["schema_version"] == SCHEMA_VERSION
        assert s.stations()[0]["uid"] == "DECA-1"
        assert s.last_seq("triplets") == 999 and s.last_seq("ranges") is None


def test_rows_of_mappings_missing_columns_and_text(tmp_path: Path) -> None:
    with Session.create(tmp_path / "r.db", {}) as s:
        s.append("ranges", [{"seq": 1, "method": "ss", "t1r": 5}, {"seq": 2, "method": "paper", "t3r": None}])
        r = s.read("ranges")
        assert list(r["method"]) == ["ss", "paper"]
        assert r["t1r"][0] == 5 and r["t1r"][1] == INT_NULL and np.isnan(r["distance_m"]).all()
        with pytest.raises(SessionError, match="colour"):
            s.append("ranges", {"colour": [1]})
        with pytest.raises(SessionError, match="unknown record table"):
            s.append("nope", {"seq": [1]})
        with pytest.raises(SessionError, match="integers"):
            s.append("ranges", {"seq": [1.5]})
        assert s.append("ranges", []) == 0


def test_results_and_csv(tmp_path: Path) -> None:
    with Session.create(tmp_path / "c.db", {}) as s:
        s.append("truth_ranges", {"seq": np.arange(3), "distance_m": [1.0, np.nan, 3.0]})
        s.set_result("twr", {"std_m": np.float64(0.01), "curve": np.arange(3)})
        assert s.result("twr") == {"std_m": 0.01, "curve": [0, 1, 2]}
        assert list(s.results()) == ["twr"]
        with pytest.raises(SessionError, match="no result"):
            s.result("missing")
        n = s.export_csv("truth_ranges", tmp_path / "t.csv")
    lines = (tmp_path / "t.csv").read_text().splitlines()
    assert n == 3 and lines[0].split(",") == columns.names("truth_ranges") and lines[2].split(",")[1] == ""


def test_refuses_overwrite(tmp_path: Path) -> None:
    Session.create(tmp_path / "o.db", {"kind": "a"}).close()
    with pytest.raises(SessionError, match="overwrite"):
        Session.create(tmp_path / "o.db", {})
    with Session.create(tmp_path / "o.db", {"kind": "b"}, overwrite=True) as s:
        assert s.meta["kind"] == "b"


def test_open_errors_name_the_problem(tmp_path: Path) -> None:
    with pytest.raises(SessionError, match="no such"):
        Session.open(tmp_path / "missing.db")
    (tmp_path / "text.db").write_text("hello, not a database at all" * 10)
    with pytest.raises(SessionError, match="not a session"):
        Session.open(tmp_path / "text.db")
    (tmp_path / "empty.db").write_bytes(b"")
    with pytest.raises(SessionError, match="empty"):
        Session.open(tmp_path / "empty.db")
    other = sqlite3.connect(tmp_path / "other.db")
    other.execute("CREATE TABLE x (a)")
    other.commit()
    other.close()
    with pytest.raises(SessionError, match="not a uwbcal session"):
        Session.open(tmp_path / "other.db")
    Session.create(tmp_path / "future.db", {}).close()
    c = sqlite3.connect(tmp_path / "future.db")
    c.execute("PRAGMA user_version = 99")
    c.commit()
    c.close()
    with pytest.raises(SessionError, match="schema version 99"):
        Session.open(tmp_path / "future.db")


def test_truncated_file(tmp_path: Path) -> None:
    p = tmp_path / "t.db"
    with Session.create(p, {}) as s:
        s.append("triplets", make_rows(3000, np.random.default_rng(2)))
    data = p.read_bytes()
    assert len(data) > 8192
    p.write_bytes(data[: len(data) // 2 // 4096 * 4096])
    with pytest.raises(SessionError, match="truncated"):
        Session.open(p)
    p.write_bytes(data[:5000])
    with pytest.raises(SessionError, match="truncated"):
        Session.open(p)
    p.write_bytes(data[:60])
    with pytest.raises(SessionError, match="truncated|not a session"):
        Session.open(p)


def test_committed_rows_survive_a_crash(tmp_path: Path) -> None:
    p = tmp_path / "crash.db"
    s = Session.create(p, {"kind": "recorded"})
    s.append("triplets", make_rows(CHUNK_ROWS + 10, np.random.default_rng(3)))
    # another process sees everything committed while the writer is still open (no close = crash)
    with Session.open(p, readonly=True) as r:
        assert r.count("triplets") == CHUNK_ROWS + 10 and r.last_seq("triplets") == CHUNK_ROWS + 9
    s.conn.close()  # the writer dies without a checkpoint
    with Session.open(p) as again:
        assert again.count("triplets") == CHUNK_ROWS + 10
        again.append("triplets", {"seq": [CHUNK_ROWS + 10]})  # resume
        assert again.last_seq("triplets") == CHUNK_ROWS + 10
        again.verify()


def test_schema_helpers() -> None:
    assert table_sql("truth_ranges").startswith("CREATE TABLE truth_ranges (seq INTEGER, distance_m REAL")
    md = columns_markdown("triplets")
    assert "`cir_pwr1`" in md and "device units" in md


def test_sessions_doc_lists_every_column() -> None:
    doc = (Path(__file__).resolve().parents[2] / "docs" / "SESSIONS.md").read_text()
    for table, cols in columns.TABLES.items():
        assert f"### `{table}`" in doc
        for name, typ, _, _ in cols:
            assert f"| `{name}` | {typ} |" in doc, (table, name)
