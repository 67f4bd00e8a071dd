"""The session file: one SQLite database (stdlib sqlite3) per session.

Schema: :mod:`uwbcal.sessions.schema` and docs/SESSIONS.md. Record tables are append-only and
written in small transactions (:data:`CHUNK_ROWS` rows at most per commit), so a crash or an
unplugged cable loses nothing already committed and a broken session can be resumed from
:meth:`Session.last_seq`. The database runs in WAL mode with ``synchronous=FULL`` while open
and is checkpointed back into the single file on :meth:`Session.close`.

Reading gives numpy arrays: REAL -> float64 (NULL -> nan), INTEGER -> int64 (NULL ->
:data:`~uwbcal.sessions.schema.INT_NULL`, test with :func:`is_null`), TEXT -> object array of
str (NULL -> None).
"""

from __future__ import annotations

import csv
import datetime as _dt
import json
import math
import os
import sqlite3
import struct
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
import numpy.typing as npt

from uwbcal.errors import SessionError
from uwbcal.sessions import columns
from uwbcal.sessions.schema import APPLICATION_ID, AUX_TABLES, INT_NULL, SCHEMA_VERSION, table_sql

#: Rows per transaction when appending.
CHUNK_ROWS = 20_000
_MAGIC = b"SQLite format 3\x00"

Columns = dict[str, np.ndarray]  # type: ignore[type-arg]
Rows = Mapping[str, npt.ArrayLike] | Sequence[Mapping[str, Any]]


def is_null(values: npt.ArrayLike) -> npt.NDArray[np.bool_]:
    """Where a column read from a session is NULL (nan, INT_NULL or None)."""
    a = np.asarray(values)
    if a.dtype.kind == "f":
        return np.asarray(np.isnan(a))
    if a.dtype.kind in "iu":
        return np.asarray(a == INT_NULL)
    return np.asarray(np.array([v is None for v in a.ravel()], dtype=bool).reshape(a.shape))


def _json_default(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, Path):
        return str(o)
    if isinstance(o, (set, frozenset)):
        return sorted(o)
    raise TypeError(f"cannot store {type(o).__name__} as JSON")


def _dumps(obj: Any) -> str:
    try:
        return json.dumps(obj, default=_json_default, allow_nan=True, sort_keys=False)
    except (TypeError, ValueError) as exc:
        raise SessionError(f"cannot store value as JSON: {exc}") from None


def _check_header(path: Path) -> None:
    """SessionError if the file is not an SQLite file or is visibly truncated."""
    size = path.stat().st_size
    if size == 0:
        raise SessionError(f"{path}: empty file, not a session")
    with path.open("rb") as f:
        head = f.read(100)
    if len(head) < 100 or not head.startswith(_MAGIC):
        if head.startswith(_MAGIC[: min(len(head), 16)]) and len(head) < 100:
            raise SessionError(f"{path}: truncated session file ({size} bytes)")
        raise SessionError(f"{path}: not a session file (not an SQLite database)")
    page_size = struct.unpack(">H", head[16:18])[0]
    page_size = 65536 if page_size == 1 else page_size
    change, pages, valid_for = (
        struct.unpack(">I", head[24:28])[0],
        struct.unpack(">I", head[28:32])[0],
        struct.unpack(">I", head[92:96])[0],
    )
    wal = Path(str(path) + "-wal")
    if page_size and size % page_size:
        raise SessionError(
            f"{path}: truncated session file ({size} bytes is not a whole number of {page_size}-byte pages)"
        )
    if (
        valid_for == change
        and pages
        and not (wal.exists() and wal.stat().st_size)
        and size < pages * page_size
    ):
        raise SessionError(f"{path}: truncated session file ({size} of {pages * page_size} bytes)")


class Session:
    """An open session file. Use :meth:`create` or :meth:`open`; a context manager closes it."""

    def __init__(self, path: Path, conn: sqlite3.Connection, readonly: bool = False) -> None:
        self.path = path
        self._conn: sqlite3.Connection | None = conn
        self.readonly = readonly

    # -- life cycle -----------------------------------------------------------------------
    @classmethod
    def create(cls, path: str | Path, meta: Mapping[str, Any], overwrite: bool = False) -> Session:
        """A new session file with the schema and ``meta`` (JSON-able values, docs/SESSIONS.md).

        Refuses to replace an existing file unless ``overwrite``.
        """
        p = Path(path)
        if p.exists():
            if not overwrite:
                raise SessionError(f"{p}: exists; refusing to overwrite (pass overwrite / --force)")
            for q in (p, Path(str(p) + "-wal"), Path(str(p) + "-shm"), Path(str(p) + "-journal")):
                if q.exists():
                    q.unlink()
        if p.parent and not p.parent.exists():
            p.parent.mkdir(parents=True, exist_ok=True)
        try:
            conn = sqlite3.connect(str(p), isolation_level=None)
            conn.execute(f"PRAGMA application_id = {APPLICATION_ID}")
            conn.execute(f"PRAGMA user_version = {SCHEMA_VERSION}")
            conn.execute("PRAGMA journal_mode = WAL")
            conn.execute("PRAGMA synchronous = FULL")
            conn.execute("BEGIN")
            for sql in AUX_TABLES.values():
                conn.execute(sql)
            for table in columns.TABLES:
                conn.execute(table_sql(table))
            m = {"schema_version": SCHEMA_VERSION, **dict(meta)}
            m.setdefault("created", _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"))
            conn.executemany(
                "INSERT INTO meta(key, value) VALUES (?, ?)", [(k, _dumps(v)) for k, v in m.items()]
            )
            conn.execute("COMMIT")
        except sqlite3.Error as exc:
            raise SessionError(f"{p}: cannot create session: {exc}") from None
        return cls(p, conn)

    @classmethod
    def open(cls, path: str | Path, readonly: bool = False) -> Session:
        """Open an existing session; SessionError says what is wrong (missing, not a session,
        unknown schema version, truncated or corrupt)."""
        p = Path(path)
        if not p.exists():
            raise SessionError(f"{p}: no such session file")
        if not p.is_file():
            raise SessionError(f"{p}: not a file")
        _check_header(p)
        try:
            if readonly:
                conn = sqlite3.connect(f"file:{p}?mode=ro", uri=True, isolation_level=None)
            else:
                conn = sqlite3.connect(str(p), isolation_level=None)
            app = conn.execute("PRAGMA application_id").fetchone()[0]
            ver = conn.execute("PRAGMA user_version").fetchone()[0]
            tables = {r[0] for r in conn.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        except sqlite3.DatabaseError as exc:
            raise SessionError(f"{p}: corrupt or not a session file ({exc})") from None
        if app != APPLICATION_ID:
            conn.close()
            raise SessionError(
                f"{p}: not a uwbcal session (SQLite application_id {app:#x}, expected {APPLICATION_ID:#x})"
            )
        if ver > SCHEMA_VERSION or ver < 1:
            conn.close()
            raise SessionError(
                f"{p}: unknown session schema version {ver} (this uwbcal reads 1..{SCHEMA_VERSION})"
            )
        missing = [t for t in (*AUX_TABLES, *columns.TABLES) if t not in tables]
        if missing:
            conn.close()
            raise SessionError(f"{p}: inconsistent session: table(s) {', '.join(missing)} missing")
        try:
            if not readonly:
                conn.execute("PRAGMA journal_mode = WAL")
                conn.execute("PRAGMA synchronous = FULL")
            conn.execute("SELECT count(*) FROM meta").fetchone()
        except sqlite3.DatabaseError as exc:
            conn.close()
            raise SessionError(f"{p}: corrupt session file ({exc})") from None
        return cls(p, conn, readonly)

    @property
    def conn(self) -> sqlite3.Connection:
        """The sqlite3 connection; SessionError once closed."""
        if self._conn is None:
            raise SessionError(f"{self.path}: session is closed")
        return self._conn

    def close(self) -> None:
        """Checkpoint the WAL into the file and close (idempotent)."""
        if self._conn is not None:
            try:
                if not self.readonly:
                    self._conn.execute("PRAGMA wal_checkpoint(TRUNCATE)")
                    self._conn.execute("PRAGMA journal_mode = DELETE")
            except sqlite3.Error:
                pass
            self._conn.close()
            self._conn = None

    def __enter__(self) -> Session:
        return self

    def __exit__(
        self, et: type[BaseException] | None, ev: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def _exec(self, sql: str, args: Sequence[Any] = ()) -> sqlite3.Cursor:
        try:
            return self.conn.execute(sql, args)
        except sqlite3.DatabaseError as exc:
            raise SessionError(f"{self.path}: {exc}") from None

    def _all(self, sql: str, args: Sequence[Any] = ()) -> list[Any]:
        """Every row of a query; a damaged page found on the way is a SessionError too."""
        cur = self._exec(sql, args)
        try:
            return cur.fetchall()
        except sqlite3.DatabaseError as exc:
            raise SessionError(f"{self.path}: corrupt session file ({exc})") from None

    # -- meta, stations, results ----------------------------------------------------------
    @property
    def meta(self) -> dict[str, Any]:
        """Every meta entry, decoded from JSON."""
        rows = self._all("SELECT key, value FROM meta ORDER BY rowid")
        return {k: self._json("meta key", k, v) for k, v in rows}

    def _json(self, what: str, name: str, text: Any) -> Any:
        """A stored JSON value; SessionError naming it when the file holds something else."""
        try:
            return json.loads(text)
        except (TypeError, ValueError):
            raise SessionError(f"{self.path}: {what} {name!r} is not JSON ({str(text)[:40]!r})") from None

    def set_meta(self, key: str, value: Any) -> None:
        """Set one meta entry (JSON-able value)."""
        self._exec("INSERT OR REPLACE INTO meta(key, value) VALUES (?, ?)", (key, _dumps(value)))

    def add_station(
        self, station_id: int, uid: str, name: str = "", info: Mapping[str, Any] | None = None
    ) -> None:
        """Record (or update) a station: id, device UID, name, JSON info."""
        self._exec(
            "INSERT OR REPLACE INTO stations(id, uid, name, info) VALUES (?, ?, ?, ?)",
            (int(station_id), uid, name, _dumps(dict(info or {}))),
        )

    def stations(self) -> list[dict[str, Any]]:
        """Stations as dicts {id, uid, name, info}."""
        return [
            {"id": i, "uid": u, "name": n, "info": json.loads(j or "{}")}
            for i, u, n, j in self._all("SELECT id, uid, name, info FROM stations ORDER BY id")
        ]

    def set_result(self, name: str, obj: Any) -> None:
        """Store (or replace) a derived result as JSON (numpy arrays and scalars allowed)."""
        now = _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")
        self._exec(
            "INSERT OR REPLACE INTO results(name, created, json) VALUES (?, ?, ?)", (name, now, _dumps(obj))
        )

    def result(self, name: str) -> Any:
        """One stored result; SessionError if absent."""
        row = self._exec("SELECT json FROM results WHERE name = ?", (name,)).fetchone()
        if row is None:
            raise SessionError(f"{self.path}: no result {name!r}")
        return json.loads(row[0])

    def results(self) -> dict[str, Any]:
        """Every stored result by name."""
        rows = self._all("SELECT name, json FROM results ORDER BY name")
        return {n: self._json("result", n, j) for n, j in rows}

    # -- records --------------------------------------------------------------------------
    @staticmethod
    def _columns(table: str) -> tuple[columns.Column, ...]:
        try:
            return columns.TABLES[table]
        except KeyError:
            raise SessionError(
                f"unknown record table {table!r} (tables: {', '.join(columns.TABLES)})"
            ) from None

    def append(self, table: str, rows: Rows) -> int:
        """Append records; returns how many. ``rows`` is a mapping column -> array (columnar) or a
        sequence of row mappings. Missing columns are NULL; nan (REAL), INT_NULL (INTEGER) and
        None become NULL; unknown column names are an error. Commits every CHUNK_ROWS rows."""
        cols = self._columns(table)
        names = [c[0] for c in cols]
        data: Mapping[str, Any]
        if isinstance(rows, Mapping):
            data = rows
        else:
            seq = list(rows)
            if not seq:
                return 0
            keys: set[str] = set().union(*(r.keys() for r in seq))
            data = {k: [r.get(k) for r in seq] for k in keys}
        unknown = [k for k in data if k not in names]
        if unknown:
            raise SessionError(f"table {table}: unknown column(s) {', '.join(sorted(unknown))}")
        present = [c for c in cols if c[0] in data]
        if not present:
            return 0
        lists: list[list[Any]] = []
        n = -1
        for name, typ, _, _ in present:
            lst = self._to_sql(table, name, typ, data[name])
            if n >= 0 and len(lst) != n:
                raise SessionError(f"table {table}: column {name} has {len(lst)} rows, others {n}")
            n = len(lst)
            lists.append(lst)
        if n <= 0:
            return 0
        sql = (
            f"INSERT INTO {table} ({', '.join(c[0] for c in present)}) "
            f"VALUES ({', '.join('?' for _ in present)})"
        )
        conn = self.conn
        try:
            for start in range(0, n, CHUNK_ROWS):
                chunk = zip(*(lst[start : start + CHUNK_ROWS] for lst in lists), strict=True)
                conn.execute("BEGIN")
                try:
                    conn.executemany(sql, chunk)
                    conn.execute("COMMIT")
                except BaseException:
                    conn.execute("ROLLBACK")
                    raise
        except sqlite3.DatabaseError as exc:
            raise SessionError(f"{self.path}: append to {table}: {exc}") from None
        return n

    @staticmethod
    def _to_sql(table: str, name: str, typ: str, values: Any) -> list[Any]:
        if isinstance(values, np.ndarray) and values.ndim == 0:
            values = values.reshape(1)
        if typ == "REAL":
            try:
                a = np.asarray(values, dtype=np.float64)
            except (TypeError, ValueError):
                raise SessionError(f"table {table}: column {name} needs numbers") from None
            lst: list[Any] = a.ravel().tolist()
            if np.isnan(a).any():
                lst = [None if math.isnan(x) else x for x in lst]
            return lst
        if typ == "INTEGER":
            if isinstance(values, np.ndarray) and values.dtype.kind in "iub":
                ai = values.astype(np.int64, copy=False).ravel()
                lst = ai.tolist()
                if (ai == INT_NULL).any():
                    lst = [None if x == INT_NULL else x for x in lst]
                return lst
            out: list[Any] = []
            for v in values.tolist() if isinstance(values, np.ndarray) else list(values):
                if v is None or (isinstance(v, float) and math.isnan(v)) or v == INT_NULL:
                    out.append(None)
                elif isinstance(v, (int, np.integer)) or (isinstance(v, float) and v.is_integer()):
                    out.append(int(v))
                else:
                    raise SessionError(f"table {table}: column {name} needs integers, got {v!r}")
            return out
        return [
            None if v is None else str(v)
            for v in (values.tolist() if isinstance(values, np.ndarray) else list(values))
        ]

    def read(self, table: str, names: Sequence[str] | None = None) -> Columns:
        """A record table as arrays by column name, in arrival order (see the module doc for NULLs)."""
        cols = self._columns(table)
        if names is not None:
            known = {c[0] for c in cols}
            bad = [x for x in names if x not in known]
            if bad:
                raise SessionError(f"table {table}: unknown column(s) {', '.join(bad)}")
            cols = tuple(c for c in cols if c[0] in set(names))
        rows = self._all(f"SELECT {', '.join(c[0] for c in cols)} FROM {table} ORDER BY rowid")
        out: Columns = {}
        if rows and all(c[1] != "TEXT" for c in cols):
            # fast path: one float64 matrix (None -> nan), exact for integers below 2**53
            try:
                mat = np.array(rows, dtype=np.float64)
            except (TypeError, ValueError):
                mat = None
            if mat is not None and mat.ndim == 2 and not (np.abs(mat) >= 2.0**53).any():
                for i, (name, typ, _, _) in enumerate(cols):
                    col = mat[:, i]
                    if typ == "INTEGER":
                        nulls = np.isnan(col)
                        ints = np.where(nulls, 0.0, col).astype(np.int64)
                        if nulls.any():
                            ints[nulls] = INT_NULL
                        out[name] = ints
                    else:
                        out[name] = np.ascontiguousarray(col)
                return out
        by_col: list[tuple[Any, ...]] = list(zip(*rows, strict=True)) if rows else [() for _ in cols]
        for (name, typ, _, _), vals in zip(cols, by_col, strict=True):
            if typ == "REAL":
                out[name] = np.array(vals, dtype=np.float64) if vals else np.zeros(0)
            elif typ == "INTEGER":
                try:
                    out[name] = np.array(vals, dtype=np.int64) if vals else np.zeros(0, np.int64)
                except (TypeError, ValueError, OverflowError):
                    out[name] = self._int_column(table, name, vals)
            else:
                out[name] = np.array(vals, dtype=object) if vals else np.zeros(0, dtype=object)
        return out

    def _int_column(self, table: str, name: str, vals: Sequence[Any]) -> npt.NDArray[np.int64]:
        """An INTEGER column with NULLs; SessionError naming the first value that is no integer."""
        for i, v in enumerate(vals):
            if v is not None and (not isinstance(v, int) or not -(2**63) <= v < 2**63):
                raise SessionError(f"{self.path}: table {table}, column {name}, record {i + 1}: "
                                   f"{str(v)[:40]!r} is not an integer (the file was altered)")
        return np.array([INT_NULL if v is None else v for v in vals], dtype=np.int64)

    def count(self, table: str) -> int:
        """Number of records in a table."""
        self._columns(table)
        return int(self._exec(f"SELECT count(*) FROM {table}").fetchone()[0])

    def last_seq(self, table: str) -> int | None:
        """Highest ``seq`` recorded in a table (to resume a broken session), None if empty."""
        self._columns(table)
        v = self._exec(f"SELECT max(seq) FROM {table}").fetchone()[0]
        return None if v is None else int(v)

    def iter_rows(self, table: str) -> Iterator[tuple[Any, ...]]:
        """Raw rows in column order (for streaming large tables)."""
        cols = self._columns(table)
        cur = self._exec(f"SELECT {', '.join(c[0] for c in cols)} FROM {table} ORDER BY rowid")
        try:
            yield from cur
        except sqlite3.DatabaseError as exc:
            raise SessionError(f"{self.path}: corrupt session file ({exc})") from None

    def export_csv(self, table: str, path: str | Path) -> int:
        """Write a record table as CSV (header = column names, NULL = empty); returns rows written."""
        cols = self._columns(table)
        n = 0
        p = Path(path)
        with p.open("w", newline="", encoding="utf-8") as f:
            w = csv.writer(f)
            w.writerow([c[0] for c in cols])
            for row in self.iter_rows(table):
                w.writerow(["" if v is None else v for v in row])
                n += 1
        return n

    def verify(self, full: bool = False) -> None:
        """Run SQLite's quick_check (``full``: integrity_check, which also compares every index
        with its table); SessionError if the file is damaged."""
        try:
            res = self.conn.execute("PRAGMA integrity_check" if full else "PRAGMA quick_check").fetchall()
        except sqlite3.DatabaseError as exc:
            raise SessionError(f"{self.path}: corrupt session file ({exc})") from None
        if res != [("ok",)]:
            raise SessionError(f"{self.path}: corrupt session file ({res[0][0]})")


def file_size(path: str | Path) -> int:
    """Size of a session file and its WAL, bytes."""
    p = Path(path)
    return sum(os.path.getsize(q) for q in (p, Path(str(p) + "-wal")) if q.exists())
