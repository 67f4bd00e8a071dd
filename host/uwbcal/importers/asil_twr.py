"""Two-way ranging exchanges hidden in an asil round-robin run (N nodes taking turns).

In a run of asil-lab/Uwb-clock-and-antenna-delay-dataset the nodes transmit in turn, one
message each, and every node logs its own TX timestamps and the RX timestamps of every message
it hears (see uwbcal.importers.asil). For a node pair (a, b), a's message k (M1), b's next
message (M2: id k if b transmits after a in the round, else k + 1) and a's message k + 1 (M3)
are the paper's three-message exchange with a as reference and b as tag: M1 a->b, M2 b->a,
M3 a->b, every timestamp on the clock of the node that logged it. Each ordered pair gives one
exchange per round (both directions of a pair are kept: they are two independent estimates).

Output columns follow columns.RANGE: ``t1r`` reference TX of M1, ``t1t`` tag RX of M1, ``t2t``
tag TX of M2, ``t2r`` reference RX of M2, ``t3r`` reference TX of M3, ``t3t`` tag RX of M3,
device units as logged. An exchange with any of its six timestamps missing is skipped.
The logged run has TX and RX antenna delays 0 (parameters.yaml), so the times of flight carry
each node's whole TX + RX delay.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from uwbcal.importers.asil_csv import NodeLog, find_node_files, read_node_csv
from uwbcal.importers.asil_params import pair_distance, parse_parameters

IntArray = npt.NDArray[np.int64]


@dataclass(frozen=True)
class PairExchanges:
    """The three-message exchanges of one ordered pair (reference ``ref``, tag ``tag``)."""

    ref: int
    tag: int
    distance_m: float | None
    t1r: IntArray
    t1t: IntArray
    t2t: IntArray
    t2r: IntArray
    t3r: IntArray
    t3t: IntArray

    @property
    def n(self) -> int:
        """Number of complete exchanges."""
        return int(self.t1r.size)


def _lookup(keys: IntArray, values: IntArray, want: IntArray) -> tuple[IntArray, npt.NDArray[np.bool_]]:
    """values[keys == want] for each want (sorted search), and which were found."""
    order = np.argsort(keys, kind="stable")
    k, v = keys[order], values[order]
    if k.size == 0:
        return np.zeros(want.size, np.int64), np.zeros(want.size, bool)
    pos = np.clip(np.searchsorted(k, want), 0, k.size - 1)
    ok = k[pos] == want
    return v[pos], ok


def _rx_of(log: NodeLog, sender: int, ids: IntArray) -> tuple[IntArray, npt.NDArray[np.bool_]]:
    sel = log.rx_from == sender
    return _lookup(log.rx_ids[sel], log.rx_ts[sel], ids)


def pair_exchanges(ref: NodeLog, tag: NodeLog, distance_m: float | None = None) -> PairExchanges:
    """Every complete exchange with ``ref`` as reference and ``tag`` as tag."""
    k = np.sort(ref.tx_ids)
    k = k[np.isin(k + 1, ref.tx_ids)]
    m2 = k if tag.node_id > ref.node_id else k + 1          # the tag's next message after M1
    t1r, ok1 = _lookup(ref.tx_ids, ref.tx_ts, k)
    t1t, ok2 = _rx_of(tag, ref.node_id, k)
    t2t, ok3 = _lookup(tag.tx_ids, tag.tx_ts, m2)
    t2r, ok4 = _rx_of(ref, tag.node_id, m2)
    t3r, ok5 = _lookup(ref.tx_ids, ref.tx_ts, k + 1)
    t3t, ok6 = _rx_of(tag, ref.node_id, k + 1)
    ok = ok1 & ok2 & ok3 & ok4 & ok5 & ok6
    return PairExchanges(ref=ref.node_id, tag=tag.node_id, distance_m=distance_m, t1r=t1r[ok], t1t=t1t[ok],
                         t2t=t2t[ok], t2r=t2r[ok], t3r=t3r[ok], t3t=t3t[ok])


def run_exchanges(run_dir: str | Path, try_name: str | None = None) -> list[PairExchanges]:
    """The exchanges of every ordered node pair of one try of a run, with the pair distances
    of its parameters.yaml (m)."""
    run = Path(run_dir)
    logs = sorted((read_node_csv(f) for f in find_node_files(run, try_name)), key=lambda lg: lg.node_id)
    params = parse_parameters(run / "parameters.yaml")
    return [pair_exchanges(a, b, pair_distance(params, a.node_id, b.node_id))
            for a in logs for b in logs if a is not b]
