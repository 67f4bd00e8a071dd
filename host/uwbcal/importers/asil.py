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

The steps live in their own modules: :mod:`uwbcal.importers.asil_params` (parameters.yaml),
:mod:`uwbcal.importers.asil_csv` (the node CSVs); this one pairs them into records and writes
the session.
"""

from __future__ import annotations

import hashlib
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from uwbcal.dw1000 import DELAYED_TX_GRID, TIME_UNIT_S, TIMESTAMP_MOD, wrap_diff
from uwbcal.errors import SessionError
from uwbcal.importers.asil_csv import (
    CSV_HEADER,
    CSV_HEADER_MULTI,
    TICKS_PER_S,
    IntArray,
    NodeLog,
    find_node_files,
    read_node_csv,
)
from uwbcal.importers.asil_params import check_parameters, node_value, pair_distance, parse_parameters
from uwbcal.sessions import columns

__all__ = [
    "CSV_HEADER",
    "CSV_HEADER_MULTI",
    "TICKS_PER_S",
    "ImportedSession",
    "NodeLog",
    "check_parameters",
    "find_node_files",
    "load_run",
    "parse_parameters",
    "read_node_csv",
    "write_session",
]

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
#: Messages per triplet (P1, P2, P3).
TRIPLET_LEN: Final = 3


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
        temp = node_value(params, "temperature", rx.node_id)
        dist = pair_distance(params, tx.node_id, rx.node_id)
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
                "temperature_c": node_value(params, "temperature", lg.node_id),
            }
            for lg in logs
        ],
        "n_nodes": len(logs),
        "distance_m": pair_distance(params, logs[0].node_id, logs[1].node_id) if len(logs) == 2 else None,
        "pair_distances_m": {
            f"{a.node_id}-{b.node_id}": pair_distance(params, a.node_id, b.node_id)
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
