"""Import a run of the asil-lab UWB clock dataset as a uwbcal session of drift triplets.

Source format (asil-lab/Uwb-clock-and-antenna-delay-dataset, see
../shared/data/asil-uwb-clock/README.md): a run directory holds one CSV per node
(``<run>-<try>_ttyACMn.csv``, header
``node_id,message_transmitter_id,message_id,timestamp_bit,timestamp_seconds`` followed, in
the two-node runs, by ``clock_offset(not_used)``) and a ``parameters.yaml``. The N nodes (2
or 4 in the published runs) take turns transmitting, one message every
``message_interval`` (12 ms for two nodes, 20 ms for four), so each node transmits about every
N * message_interval. A node logs the TX timestamp of each of its own messages (row with
``message_transmitter_id == node_id``) and the RX timestamp of each message it received from
any other node, both in DW1000 device units (1 / (128 * 499.2 MHz) s, about 15.65 ps) on
its own clock.

Conversion (the paper's drift triplets, eq. 1, from a plain alternating log): for each
transmitter, the messages with ids ``3j, 3j+1, 3j+2`` are P1, P2, P3 of triplet ``seq = j``.
TX times come from the transmitter's own file, RX times from the receiver's file. A triplet
with any of its three messages missing from either file is skipped and counted; triplets
never overlap, so they are independent. Every ordered node pair becomes records
(``tx_station`` -> ``rx_station``: 2 directions for two nodes, 12 for four), with the pair's
distance from ``node_pairs``. All gains are equal (a drift run, ``step`` 0; the gain octet is unknown and
stored as NULL), RX quality registers are not logged (NULL).

Timestamps: the logger already undid the 40-bit wrap, so values exceed 2**40 (up to about
3.3 * 2**40). They are stored exactly as given (``meta["timestamps"]["unwrapped_at_source"]``
says so); every analysis takes differences modulo 2**40 (:func:`uwbcal.dw1000.wrap_diff`),
which gives the same result for unwrapped and raw 40-bit values. A source that did not
unwrap (values below 2**40 that decrease at the wrap) is imported the same way.

Time base: ``t_s`` is the time of P1 on the transmitter's clock, in seconds since that node's
first logged row (both nodes start logging at node 0's first message, so the two time bases
agree to a few ms). The DW1000 counter starts at power-on, so
``meta["timestamps"]["session_start_since_counter_zero_s"]`` (the earliest first-row value,
meaningful for unwrapped logs) is roughly the time since power-on at the first record,
about 5 s here. ``spacing_s`` holds the actual P1 -> P2
interval on the TX clock, s: the logger's intervals are 23 ms or 33.4 ms rather than the
nominal 24 ms, so a nominal value would misdescribe the schedule; P2 -> P3 is exact in the
TX columns.
"""

from __future__ import annotations

import csv
import hashlib
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from uwbcal.dw1000 import DELAYED_TX_GRID, TICK_HZ, TIME_UNIT_S, TIMESTAMP_MOD, wrap_diff
from uwbcal.errors import SessionError
from uwbcal.sessions import columns

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
#: Where the published run came from (the shared README); the commit is read from that
#: README when the run directory sits beside it, else recorded as unknown.
SOURCE_REPO: Final = "asil-lab/Uwb-clock-and-antenna-delay-dataset"
SOURCE_CITATION: Final = (
    'Becoy, A. J., Peternel, L., Rajan, R. T., "Clock Synchronization and Antenna '
    'Delay Estimation for UWB-based Lunar Rover Networks", iSpaRo 2026.'
)
SOURCE_LICENSE: Final = (
    "The source repository states no license; files kept unchanged, with "
    "attribution, for research and testing use only."
)
#: Ticks per second used by the logger for ``timestamp_seconds`` (128 * 499.2 MHz).
TICKS_PER_S: Final = TICK_HZ
#: Messages per triplet (P1, P2, P3).
TRIPLET_LEN: Final = 3


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


def _elapsed_units(log: NodeLog, ids: IntArray) -> npt.NDArray[np.float64]:
    """Device units from the node's first row to its TX of each message id in ``ids``.

    Works for unwrapped and raw 40-bit logs alike: the node's TX timestamps, in id order, are
    unwrapped by accumulating consecutive differences modulo 2**40 (rows are < 8.6 s apart).
    """
    order = np.argsort(log.tx_ids, kind="stable")
    t_ids, t_sorted = log.tx_ids[order], log.tx_ts[order]
    steps = wrap_diff(t_sorted[1:], t_sorted[:-1]) if t_sorted.size > 1 else np.zeros(0, np.int64)
    unwrapped = np.concatenate([[0], np.cumsum(steps)]) + int(wrap_diff(t_sorted[0], log.first_ts))
    return np.asarray(unwrapped[np.searchsorted(t_ids, ids)], dtype=np.float64)


@dataclass
class ImportedSession:
    """A converted run: triplet records (columns.TRIPLET layout) and metadata.

    ``triplets`` maps every TRIPLET column name to an array with one entry per record, or to
    None when the source has no value for any record (NULL column).
    """

    triplets: dict[str, npt.NDArray[Any] | None]
    meta: dict[str, Any]
    stats: dict[str, Any] = field(default_factory=dict)

    @property
    def n_records(self) -> int:
        """Number of triplet records."""
        seq = self.triplets["seq"]
        return 0 if seq is None else int(seq.shape[0])


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


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


_SCALAR_INT = re.compile(r"^[+-]?(0x[0-9a-fA-F]+|\d+)$")


def _scalar(text: str) -> Any:
    """A YAML scalar of the subset parameters.yaml uses: int (also 0x..), float, or string."""
    t = text.strip()
    if _SCALAR_INT.match(t):
        return int(t, 0) if not re.match(r"^[+-]?0\d", t) else int(t, 10)
    try:
        return float(t)
    except ValueError:
        return t.strip("'\"")


def parse_parameters(path: Path) -> dict[str, Any]:
    """Parse parameters.yaml (block mappings, block lists, scalars, ``#`` comments).

    Only the YAML subset the dataset uses; anything else is a SessionError naming the line.
    """
    if not path.is_file():
        raise SessionError(f"{path}: no such file")
    lines: list[tuple[int, int, str]] = []
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise SessionError(f"{path}: not text (byte {exc.start} is not UTF-8)") from None
    for no, line in enumerate(text.splitlines(), start=1):
        body = line.split("#", 1)[0].rstrip()
        if body.strip():
            lines.append((no, len(body) - len(body.lstrip(" ")), body.strip()))

    def block(i: int, indent: int) -> tuple[Any, int]:
        if i >= len(lines):
            return None, i
        if lines[i][2].startswith("- ") or lines[i][2] == "-":
            out_l: list[Any] = []
            while i < len(lines) and lines[i][1] == indent and lines[i][2].startswith("-"):
                no, _, text = lines[i]
                rest = text[1:].strip()
                if not rest:
                    val, i = block(i + 1, lines[i + 1][1] if i + 1 < len(lines) else indent + 2)
                    out_l.append(val)
                elif ":" in rest:  # "- key: ..." opens a mapping item
                    sub_indent = indent + (len(text) - len(rest))
                    lines[i] = (no, sub_indent, rest)
                    val, i = block(i, sub_indent)
                    out_l.append(val)
                else:
                    out_l.append(_scalar(rest))
                    i += 1
            return out_l, i
        out_d: dict[str, Any] = {}
        while i < len(lines) and lines[i][1] == indent:
            no, _, text = lines[i]
            if ":" not in text or text.startswith("-"):
                raise SessionError(f"{path}: line {no}: expected 'key: value'")
            key, _, value = text.partition(":")
            if value.strip():
                out_d[key.strip()] = _scalar(value)
                i += 1
            else:
                nxt = i + 1
                if nxt < len(lines) and (lines[nxt][1] > indent or lines[nxt][2].startswith("-")):
                    out_d[key.strip()], i = block(nxt, lines[nxt][1])
                else:
                    out_d[key.strip()] = None
                    i += 1
        if i < len(lines) and lines[i][1] > indent:
            raise SessionError(f"{path}: line {lines[i][0]}: unexpected indentation")
        return out_d, i

    value, end = block(0, lines[0][1] if lines else 0)
    if end != len(lines) or not isinstance(value, dict):
        no = lines[end][0] if end < len(lines) else len(lines)
        raise SessionError(f"{path}: line {no}: not the parameters.yaml layout")
    check_parameters(value, path)
    return value


#: Keys of parameters.yaml the importer reads, and the numbers they must hold.
_NUMBER_KEYS: Final = ("node_distance", "message_interval", "clock_offset")


def check_parameters(params: Mapping[str, Any], path: Path) -> None:
    """SessionError naming the first key of parameters.yaml the importer reads that is missing or
    of the wrong kind: ``nodes`` (a list of node ids), the numbers of _NUMBER_KEYS, ``temperature``
    (one number per node) and ``node_pairs`` (``nodes`` pairs with a ``distance``). Keys the
    importer does not read are kept as they are, unchecked."""
    def is_num(v: Any) -> bool:
        return isinstance(v, int | float) and not isinstance(v, bool)

    nodes = params.get("nodes")
    if not isinstance(nodes, list) or not nodes or not all(isinstance(n, int) for n in nodes):
        raise SessionError(f"{path}: 'nodes' must be a list of node ids (got {nodes!r:.40})")
    for key in _NUMBER_KEYS:
        if key in params and not is_num(params[key]):
            raise SessionError(f"{path}: '{key}' must be a number (got {params[key]!r:.40})")
    temp = params.get("temperature")
    if temp is not None and (not isinstance(temp, list) or not all(is_num(t) for t in temp)):
        raise SessionError(f"{path}: 'temperature' must be a list of numbers, one per node "
                           f"(got {temp!r:.40})")
    pairs = params.get("node_pairs")
    if pairs is not None:
        ok = isinstance(pairs, list) and all(
            isinstance(p, dict) and isinstance(p.get("nodes"), list) and len(p["nodes"]) == 2
            and is_num(p.get("distance")) for p in pairs)
        if not ok:
            raise SessionError(f"{path}: 'node_pairs' must list 'nodes: [a, b]' with a 'distance' in m")


def _source_commit(run_dir: Path) -> str:
    """The source commit named in a README beside the run directory, else 'unknown'."""
    for readme in (run_dir / "README.md", run_dir.parent / "README.md", run_dir.parent / "PROVENANCE.md"):
        if readme.is_file():
            m = re.search(
                r"(?i)commit:?\s+`?([0-9a-f]{40})`?", readme.read_text(encoding="utf-8", errors="replace")
            )
            if m:
                return m.group(1)
    return "unknown"


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


def _direction(tx: NodeLog, rx: NodeLog) -> tuple[dict[str, IntArray], dict[str, Any]]:
    """Triplets of transmitter ``tx`` received by ``rx``: index arrays and loss counts."""
    tx_order = np.argsort(tx.tx_ids, kind="stable")
    t_ids, t_ts = tx.tx_ids[tx_order], tx.tx_ts[tx_order]
    sel = rx.rx_from == tx.node_id
    r_ids, r_ts = rx.rx_ids[sel], rx.rx_ts[sel]
    r_order = np.argsort(r_ids, kind="stable")
    r_ids, r_ts = r_ids[r_order], r_ts[r_order]
    received = np.isin(t_ids, r_ids)
    lost = t_ids[~received]
    orphan_rx = r_ids[~np.isin(r_ids, t_ids)]
    max_id = int(max(t_ids.max(initial=-1), r_ids.max(initial=-1)))
    min_id = int(min(t_ids.min(initial=max_id), r_ids.min(initial=max_id)))
    first_slot = max(min_id, 0) // TRIPLET_LEN
    n_slots = max((max_id + 1) // TRIPLET_LEN - first_slot, 0)
    first = (first_slot + np.arange(n_slots, dtype=np.int64)) * TRIPLET_LEN
    need = first[:, None] + np.arange(TRIPLET_LEN)[None, :]
    have_tx = np.isin(need, t_ids)
    have_rx = np.isin(need, r_ids)
    complete = np.all(have_tx & have_rx, axis=1)
    ids = need[complete]
    tx_pos = np.searchsorted(t_ids, ids)
    rx_pos = np.searchsorted(r_ids, ids)
    out = {"seq": first[complete] // TRIPLET_LEN, "tx": t_ts[tx_pos], "rx": r_ts[rx_pos]}
    counts = {
        "tx_station": tx.node_id,
        "rx_station": rx.node_id,
        "messages_sent": int(t_ids.size),
        "messages_received": int(np.count_nonzero(received)),
        "messages_lost": int(lost.size),
        "lost_message_ids": [int(x) for x in lost],
        "rx_without_tx_row": int(orphan_rx.size),
        "triplet_slots": int(n_slots),
        "triplets_complete": int(np.count_nonzero(complete)),
        "triplets_incomplete": int(n_slots - np.count_nonzero(complete)),
        "first_message_id": min_id,
        "last_message_id": max_id,
        "messages_after_last_slot": int(max_id + 1 - (first_slot + n_slots) * TRIPLET_LEN),
    }
    return out, counts


def _node_value(params: Mapping[str, Any], key: str, node_id: int) -> float | None:
    """Per-node list value of parameters.yaml (indexed like ``nodes``), or None."""
    values, nodes = params.get(key), params.get("nodes")
    if not isinstance(values, list) or not isinstance(nodes, list) or node_id not in nodes:
        return None
    idx = nodes.index(node_id)
    v = values[idx] if idx < len(values) else None
    return float(v) if isinstance(v, int | float) else None


def _pair_distance(params: Mapping[str, Any], a: int, b: int) -> float | None:
    """Distance of the node pair (a, b), m, from node_pairs or node_distance."""
    pairs = params.get("node_pairs")
    if isinstance(pairs, list):
        for p in pairs:
            if isinstance(p, dict) and sorted(p.get("nodes") or []) == sorted([a, b]):
                d = p.get("distance")
                if isinstance(d, int | float):
                    return float(d)
    d = params.get("node_distance")
    return float(d) if isinstance(d, int | float) else None


def load_run(run_dir: str | Path, try_name: str | None = None) -> ImportedSession:
    """Convert one try of an asil run directory into triplet records and metadata.

    Raises SessionError (naming the file and line) for a missing, truncated or malformed file.
    """
    run = Path(run_dir)
    files = find_node_files(run, try_name)
    logs = [read_node_csv(f) for f in files]
    seen: dict[int, Path] = {}
    for lg in logs:
        if lg.node_id in seen:
            raise SessionError(f"{lg.path}: node_id {lg.node_id} also in {seen[lg.node_id]}")
        seen[lg.node_id] = lg.path
    logs.sort(key=lambda lg: lg.node_id)
    params_path = run / "parameters.yaml"
    params = parse_parameters(params_path)
    params_text = params_path.read_text(encoding="utf-8")

    start_units = min(int(lg.first_ts) for lg in logs)
    start_s = start_units * TIME_UNIT_S
    n_cols = {name: [] for name in columns.names("triplets")}  # type: dict[str, list[npt.NDArray[Any]]]
    directions = []
    pairs = [(tx, rx) for tx in logs for rx in logs if tx is not rx]
    for tx, rx in pairs:
        d, counts = _direction(tx, rx)
        directions.append(counts)
        n = d["seq"].size
        temp = _node_value(params, "temperature", rx.node_id)
        dist = _pair_distance(params, tx.node_id, rx.node_id)
        tx1 = d["tx"][:, 0]
        vals: dict[str, npt.NDArray[Any]] = {
            "seq": d["seq"],
            "step": np.zeros(n, np.int64),
            "tx_station": np.full(n, tx.node_id, np.int64),
            "rx_station": np.full(n, rx.node_id, np.int64),
            "t_s": _elapsed_units(tx, d["seq"] * TRIPLET_LEN) * TIME_UNIT_S,
            "spacing_s": wrap_diff(d["tx"][:, 1], tx1) * TIME_UNIT_S,
            "tx1": d["tx"][:, 0],
            "tx2": d["tx"][:, 1],
            "tx3": d["tx"][:, 2],
            "rx1": d["rx"][:, 0],
            "rx2": d["rx"][:, 1],
            "rx3": d["rx"][:, 2],
            "temp_c": np.full(n, np.nan if temp is None else temp),
            "distance_m": np.full(n, np.nan if dist is None else dist),
        }
        for k, v in vals.items():
            n_cols[k].append(v)
    triplets: dict[str, npt.NDArray[Any] | None] = {
        k: (np.concatenate(v) if v else None) for k, v in n_cols.items()
    }
    off_grid = sum(int(np.count_nonzero(lg.tx_ts % DELAYED_TX_GRID)) for lg in logs)
    order = np.lexsort((np.asarray(triplets["seq"]), np.asarray(triplets["t_s"])))
    triplets = {k: (None if v is None else v[order]) for k, v in triplets.items()}
    max_ts = max(int(np.max(np.concatenate([lg.tx_ts, lg.rx_ts]))) for lg in logs)
    commit = _source_commit(run)
    meta: dict[str, Any] = {
        "kind": "imported",
        "source": f"uwbcal import asil {run} ({SOURCE_REPO} @ {commit})",
        "scenario": None,
        "seed": None,
        "firmware_version": None,
        "protocol_version": None,
        "station_uids": {str(lg.node_id): f"asil-node-{lg.node_id:#04x}" for lg in logs},
        "radio": {
            "channel": None,
            "prf_mhz": None,
            "preamble_length": params.get("preamble_length"),
            "data_rate_kbps": None,
        },
        "settings": {
            "message_interval_s": params.get("message_interval"),
            "triplet_spacing_nominal_s": len(logs) * float(params["message_interval"])
            if isinstance(params.get("message_interval"), int | float)
            else None,
        },
        "provenance": {
            "format": "asil-uwb-clock",
            "repo": SOURCE_REPO,
            "commit": commit,
            "run_dir": str(run.resolve()),
            "try": files[0].stem.rsplit("_", 1)[0],
            "files": {
                f.name: {"sha256": _sha256(f), "rows": lg.n_rows}
                for f, lg in zip(files, sorted(logs, key=lambda lg: files.index(lg.path)), strict=True)
            },
            "citation": SOURCE_CITATION,
            "license": SOURCE_LICENSE,
        },
        "importer": "uwbcal.importers.asil",
        "experiment": "drift",
        "parameters_yaml": params_text,
        "parameters": params,
        "stations": [
            {
                "id": lg.node_id,
                "file": lg.path.name,
                "temperature_c": _node_value(params, "temperature", lg.node_id),
            }
            for lg in logs
        ],
        "n_nodes": len(logs),
        "distance_m": _pair_distance(params, logs[0].node_id, logs[1].node_id) if len(logs) == 2 else None,
        "pair_distances_m": {
            f"{a.node_id}-{b.node_id}": _pair_distance(params, a.node_id, b.node_id)
            for a, b in pairs
            if a.node_id < b.node_id
        },
        "message_interval_s": params.get("message_interval"),
        "triplet_rule": "messages 3j, 3j+1, 3j+2 of one transmitter are P1, P2, P3 of triplet j; "
        "incomplete triplets skipped",
        "timestamps": {
            "unit_s": TIME_UNIT_S,
            "unwrapped_at_source": bool(max_ts >= TIMESTAMP_MOD),
            "max_value": max_ts,
            "max_over_2_40": max_ts / TIMESTAMP_MOD,
            "note": "stored exactly as given; take every difference modulo 2**40",
            "session_start_units": start_units,
            "session_start_since_counter_zero_s": start_s,
            "tx_rows_off_512_grid": off_grid,
        },
        "spacing_note": "spacing_s is the actual P1->P2 interval on the TX clock (not nominal)",
        "directions": directions,
    }
    stats = {
        "records": int(order.size),
        "messages_lost": sum(c["messages_lost"] for c in directions),
        "triplets_incomplete": sum(c["triplets_incomplete"] for c in directions),
    }
    return ImportedSession(triplets=triplets, meta=meta, stats=stats)


def write_session(imported: ImportedSession, out: str | Path, overwrite: bool = False) -> Path:
    """Write an imported run as a session file (triplets table, stations, meta); returns the path."""
    from uwbcal.sessions.store import Session

    cols = {k: v for k, v in imported.triplets.items() if v is not None}
    with Session.create(out, imported.meta, overwrite=overwrite) as s:
        for st in imported.meta["stations"]:
            s.add_station(
                int(st["id"]),
                f"asil-node-{int(st['id']):#04x}",
                st["file"],
                {"role": "real", "temperature_c": st["temperature_c"]},
            )
        s.append("triplets", cols)
        s.set_result(
            "import", {"importer": "asil", **imported.stats, "directions": imported.meta["directions"]}
        )
    return Path(out)
