"""The asil dataset's node CSVs: the published headers, one node's rows (:class:`NodeLog`), the
strict reader and the choice of one try's files in a run directory (the source format is described
in :mod:`uwbcal.importers.asil`). Timestamps in DW1000 device units (1 / (128 * 499.2 MHz) s)."""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import numpy as np
import numpy.typing as npt

from uwbcal.dw1000 import TICK_HZ
from uwbcal.errors import SessionError

IntArray = npt.NDArray[np.int64]

#: Header of a two-node run's CSV, exactly as published.
CSV_HEADER: Final = (
    "node_id",
    "message_transmitter_id",
    "message_id",
    "timestamp_bit",
    "timestamp_seconds",
    "clock_offset(not_used)",
)
#: Header of the multi-node runs' CSVs (no clock_offset column), exactly as published.
CSV_HEADER_MULTI: Final = CSV_HEADER[:5]
#: Ticks per second used by the logger for ``timestamp_seconds`` (128 * 499.2 MHz).
TICKS_PER_S: Final = TICK_HZ

@dataclass(frozen=True)
class NodeLog:
    """The rows of one node's CSV. Timestamps in device units, as given (maybe > 2**40)."""

    path: Path
    node_id: int
    tx_ids: IntArray  # message ids this node transmitted
    tx_ts: IntArray  # their TX timestamps, device units, this node's clock
    rx_from: IntArray  # transmitter id of each received message
    rx_ids: IntArray  # message id of each received message
    rx_ts: IntArray  # RX timestamps, device units, this node's clock
    n_rows: int
    first_ts: int  # timestamp of the file's first row (the node's time origin)


def read_node_csv(path: Path) -> NodeLog:
    """Parse one node's CSV strictly; any defect is a SessionError naming file and line."""
    if not path.is_file():
        raise SessionError(f"{path}: no such file")
    raw = path.read_bytes()
    if not raw:
        raise SessionError(f"{path}: empty file (expected the header {','.join(CSV_HEADER)})")
    if not raw.endswith(b"\n"):
        n_lines = raw.count(b"\n") + 1
        raise SessionError(f"{path}: line {n_lines}: truncated (the last line has no line end)")
    try:
        text = raw.decode("ascii")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise SessionError(f"{path}: line {line}: not ASCII text") from exc
    rows = list(csv.reader(text.splitlines()))
    header = tuple(c.strip() for c in rows[0])
    if header not in (CSV_HEADER, CSV_HEADER_MULTI):
        raise SessionError(
            f"{path}: line 1: header {','.join(rows[0])!r} is neither {','.join(CSV_HEADER)!r} "
            f"nor {','.join(CSV_HEADER_MULTI)!r}"
        )
    n_fields = len(header)
    if len(rows) < 2:
        raise SessionError(f"{path}: no data rows after the header")
    node = np.empty(len(rows) - 1, dtype=np.int64)
    sender = np.empty_like(node)
    mid = np.empty_like(node)
    ts = np.empty_like(node)
    for i, row in enumerate(rows[1:]):
        lineno = i + 2
        if len(row) != n_fields:
            raise SessionError(f"{path}: line {lineno}: expected {n_fields} fields, found {len(row)}")
        try:
            node[i], sender[i], mid[i], ts[i] = (int(row[0]), int(row[1]), int(row[2]), int(row[3]))
            secs = float(row[4])
            if n_fields > 5:
                float(row[5])
        except ValueError as exc:
            raise SessionError(f"{path}: line {lineno}: malformed value ({exc})") from exc
        if ts[i] < 0 or mid[i] < 0:
            raise SessionError(f"{path}: line {lineno}: negative message id or timestamp")
        if abs(secs - ts[i] / TICKS_PER_S) > 1e-9 * max(1.0, abs(secs)):
            raise SessionError(
                f"{path}: line {lineno}: timestamp_seconds {row[4]} disagrees with "
                f"timestamp_bit {row[3]} (truncated or edited row?)"
            )
    node_id = int(node[0])
    bad = np.flatnonzero(node != node_id)
    if bad.size:
        raise SessionError(
            f"{path}: line {int(bad[0]) + 2}: node_id {int(node[bad[0]])} in the file of node {node_id}"
        )
    is_tx = sender == node_id
    for mask, what in ((is_tx, "TX"), (~is_tx, "RX")):
        keys = sender[mask] * (1 << 32) + mid[mask]
        uniq, counts = np.unique(keys, return_counts=True)
        if np.any(counts > 1):
            dup = uniq[counts > 1][0]
            line = int(np.flatnonzero(mask)[np.flatnonzero(keys == dup)[1]]) + 2
            raise SessionError(
                f"{path}: line {line}: duplicate {what} row for message {int(dup % (1 << 32))}"
            )
    return NodeLog(
        path=path,
        node_id=node_id,
        tx_ids=mid[is_tx],
        tx_ts=ts[is_tx],
        rx_from=sender[~is_tx],
        rx_ids=mid[~is_tx],
        rx_ts=ts[~is_tx],
        n_rows=len(rows) - 1,
        first_ts=int(ts[0]),
    )


def find_node_files(run_dir: Path, try_name: str | None = None) -> list[Path]:
    """The node CSVs of one try of a run directory (``<try>_ttyACM<n>.csv``)."""
    if not run_dir.is_dir():
        raise SessionError(f"{run_dir}: no such run directory")
    files = sorted(run_dir.glob("*.csv"))
    tries: dict[str, list[Path]] = {}
    for f in files:
        tries.setdefault(f.stem.rsplit("_", 1)[0], []).append(f)
    if not tries:
        raise SessionError(f"{run_dir}: no node CSV files (*.csv)")
    if try_name is None:
        if len(tries) > 1:
            raise SessionError(
                f"{run_dir}: several tries ({', '.join(sorted(tries))}); choose one with --try"
            )
        try_name = next(iter(tries))
    if try_name not in tries:
        raise SessionError(f"{run_dir}: no try {try_name!r} (have {', '.join(sorted(tries))})")
    chosen = tries[try_name]
    if len(chosen) < 2:
        raise SessionError(
            f"{run_dir}: try {try_name} has {len(chosen)} node file, expected one per node (at least 2)"
        )
    return chosen
