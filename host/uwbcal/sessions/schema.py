"""The SQLite schema of a session file, derived from :mod:`uwbcal.sessions.columns`.

Schema version 1 (docs/SESSIONS.md):
- one table per entry of ``columns.TABLES`` (triplets, ranges, truth_triplets, truth_ranges),
  its columns in ``columns`` order with their SQL types; the implicit rowid is the arrival order;
- ``meta(key TEXT PRIMARY KEY, value TEXT)``: one JSON value per key;
- ``stations(id INTEGER PRIMARY KEY, uid TEXT, name TEXT, info TEXT)``: info is JSON;
- ``results(name TEXT PRIMARY KEY, created TEXT, json TEXT)``: derived results as JSON;
- ``PRAGMA application_id`` = :data:`APPLICATION_ID` ("UWBC") and ``PRAGMA user_version`` =
  :data:`SCHEMA_VERSION`; meta key ``schema_version`` repeats it.
"""

from __future__ import annotations

from typing import Final

import numpy as np

from uwbcal.sessions import columns

#: Version of the session schema this code writes and the highest it reads.
SCHEMA_VERSION: Final = 1
#: PRAGMA application_id of a session file: the ASCII bytes "UWBC".
APPLICATION_ID: Final = 0x55574243
#: Value that stands for NULL in an INTEGER column read into an int64 array.
INT_NULL: Final = int(np.iinfo(np.int64).min)

#: Tables besides the record tables.
AUX_TABLES: Final[dict[str, str]] = {
    "meta": "CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL)",
    "stations": "CREATE TABLE stations (id INTEGER PRIMARY KEY, uid TEXT, name TEXT, info TEXT)",
    "results": "CREATE TABLE results (name TEXT PRIMARY KEY, created TEXT NOT NULL, json TEXT NOT NULL)",
}

#: Meta keys a session carries (values are JSON); a writer may add others.
META_KEYS: Final[dict[str, str]] = {
    "schema_version": "integer, the schema version (also PRAGMA user_version)",
    "kind": '"simulated" | "recorded" | "imported"',
    "source": "free text: what produced the session (command, tool, importer and its input)",
    "experiment": '"drift" | "power" | "twr" | other: what the session measured',
    "scenario": "TOML text of the scenario (simulated and firmware-in-the-loop sessions), else null",
    "seed": "run seed (simulated), else null",
    "station_uids": 'object {"station id": "device UID"}',
    "firmware_version": "firmware version string of the stations, or null",
    "protocol_version": "wire protocol version, or null",
    "radio": "object {channel, prf_mhz, preamble_length, data_rate_kbps}",
    "settings": "object: the run's settings (spacing, steps, distances, ...)",
    "created": "ISO 8601 UTC time the session was created",
}


def table_sql(table: str) -> str:
    """CREATE TABLE statement of one record table (columns.TABLES)."""
    cols = ", ".join(f"{name} {typ}" for name, typ, _, _ in columns.TABLES[table])
    return f"CREATE TABLE {table} ({cols})"


def columns_markdown(table: str) -> str:
    """A Markdown table of a record table's columns (name, SQL type, unit, meaning)."""
    lines = ["| column | type | unit / register | meaning |", "|---|---|---|---|"]
    for name, typ, unit, desc in columns.TABLES[table]:
        lines.append(f"| `{name}` | {typ} | {unit} | {desc} |")
    return "\n".join(lines)
