"""`uwbcal export csv SESSION [--out DIR] [--json]`: a session's record tables as CSV files.

One file per non-empty record table (``<session>_<table>.csv``: header = column names of
sessions/columns.py, NULL = empty cell) plus ``<session>_meta.json`` (metadata, stations and
stored results). Parquet is not offered: it needs pyarrow, which uwbcal does not depend on.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any


def register(subparsers: Any) -> None:
    """Add the ``export`` command."""
    p = subparsers.add_parser("export", help="write a session's records as CSV (one file per table)",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("format", choices=("csv",), help="output format")
    p.add_argument("session", type=Path, help="session file (SQLite)")
    p.add_argument("--out", type=Path, default=None, metavar="DIR",
                   help="directory (default: beside the session)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Export every non-empty record table and the metadata."""
    from uwbcal.errors import SessionError
    from uwbcal.sessions import columns
    from uwbcal.sessions.store import Session

    if not args.session.exists():
        raise SessionError(f"{args.session}: no such session file")
    out_dir: Path = args.out or args.session.parent
    out_dir.mkdir(parents=True, exist_ok=True)
    stem = args.session.stem
    files: list[dict[str, Any]] = []
    with Session.open(args.session, readonly=True) as s:
        for table in columns.TABLES:
            if s.count(table) == 0:
                continue
            path = out_dir / f"{stem}_{table}.csv"
            files.append({"table": table, "file": str(path), "rows": s.export_csv(table, path)})
        meta_path = out_dir / f"{stem}_meta.json"
        meta_path.write_text(json.dumps({"meta": s.meta, "stations": s.stations(), "results": s.results()},
                                        indent=1, default=str) + "\n")
    if args.json:
        print(json.dumps({"session": str(args.session), "files": files, "meta": str(meta_path)}))
    else:
        for f in files:
            print(f"wrote {f['file']}: {f['rows']} {f['table']} records")
        print(f"wrote {meta_path}: metadata, stations, stored results")
    return 0
