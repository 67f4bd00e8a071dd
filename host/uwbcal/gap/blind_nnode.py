"""Simulated N-node asil-like sessions, written as asil-lab CSVs and read back through the importer.

The N-node form of :mod:`uwbcal.gap.blind`'s two-way sessions: N nodes take turns (one message
every ``interval`` s, the asil four-node logger's 20 ms, with its irregular turns), every message
is received by every other node, and the messages 3j, 3j+1, 3j+2 of a transmitter are triplet j
of each of its N - 1 directions. "Reality" is a given true scenario simulated by the project's
simulator, optionally changed by departures of :mod:`uwbcal.gap.departures` (written apart from
the physics); the records then take the path real data takes: one CSV per node and a
``parameters.yaml`` with ``node_pairs`` distances, imported by :func:`uwbcal.importers.asil.load_run`
(no RX registers, 40-bit raw timestamps, ``t_s`` from each node's first row, losses none).

What these sessions cannot show: everything the simulator's base shares with the believed world
(a null must be the believed world), and the real logger's losses and the correlation of one
emission's TX jitter across its receivers (each record's emission is drawn on its own).
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, Final

import numpy as np

from uwbcal.gap import departures as dep
from uwbcal.physics.scenario import Scenario

#: Turns between consecutive messages of the asil four-node logger (s) and their shares: the
#: nominal 20 ms interval comes out as 17.1, 22.5 or 33.3 ms (tests/data/asil4, node 0's log).
TURNS_S: Final = (0.0171, 0.0225, 0.0333)
TURN_SHARES: Final = (0.3, 0.55, 0.15)

Departure = Callable[[dict[str, Any], np.random.Generator], dict[str, Any]]


def round_robin_schedule(
    scenario: Scenario,
    duration_s: float,
    rng: np.random.Generator,
    distances_m: Mapping[tuple[int, int], float] | None = None,
    start_s: float = 1.0,
) -> Any:
    """The triplet schedule of the scenario's stations taking turns (asil-like), ``duration_s`` s.

    Message m of the round (every station once, in file order) leaves after a turn drawn from
    :data:`TURNS_S`; each station's messages 3j..3j+2 form triplet ``seq`` j, received by every other
    station (one record per direction). ``distances_m``: per unordered station pair (either key
    order), m; a missing pair takes the scenario's geometry (NaN in the schedule).
    """
    from uwbcal import vectorsim

    ids = scenario.station_ids
    n = len(ids)
    n_round = max(int(duration_s / (n * float(np.dot(TURNS_S, TURN_SHARES)))) // 3 * 3, 3)
    turns = rng.choice(np.asarray(TURNS_S), size=n_round * n, p=np.asarray(TURN_SHARES))
    t = start_s + np.concatenate([[0.0], np.cumsum(turns[:-1])])
    times = t.reshape(n_round, n)  # message m of station ids[k] at times[m, k]
    cols: dict[str, list[Any]] = {k: [] for k in ("seq", "tx", "rx", "t", "sp", "sp23", "d")}
    j = np.arange(n_round // 3)
    for k, tx in enumerate(ids):
        p1, p2, p3 = times[3 * j, k], times[3 * j + 1, k], times[3 * j + 2, k]
        for rx in ids:
            if rx == tx:
                continue
            d = float("nan")
            if distances_m is not None:
                d = float(distances_m.get((tx, rx), distances_m.get((rx, tx), float("nan"))))
            cols["seq"].append(j)
            cols["tx"].append(np.full(j.size, tx))
            cols["rx"].append(np.full(j.size, rx))
            cols["t"].append(p1)
            cols["sp"].append(p2 - p1)
            cols["sp23"].append(p3 - p2)
            cols["d"].append(np.full(j.size, d))
    cat = {k: np.concatenate(v) for k, v in cols.items()}
    order = np.lexsort((cat["rx"], cat["t"]))
    m = order.size
    return vectorsim.TripletSchedule(
        seq=cat["seq"][order].astype(np.int64),
        step=np.zeros(m, np.int64),
        tx_station=cat["tx"][order].astype(np.int64),
        rx_station=cat["rx"][order].astype(np.int64),
        t_s=cat["t"][order],
        spacing_s=cat["sp"][order],
        gain13=np.full(m, vectorsim.DEFAULT_GAIN, np.int64),
        gain2=np.full(m, vectorsim.DEFAULT_GAIN, np.int64),
        distance_m=cat["d"][order],
        spacing23_s=cat["sp23"][order],
    )


def write_asil_run(
    rec: Mapping[str, Any],
    node_of: Mapping[int, int],
    run_dir: Path,
    distances_m: Mapping[tuple[int, int], float],
    interval_s: float = 0.02,
) -> None:
    """Triplet records of an N-node session as an asil-lab run directory: one CSV per node (its own
    messages' TX rows, once per message, and its receptions' RX rows, in time order) and a
    ``parameters.yaml`` with ``nodes`` and ``node_pairs`` (``distances_m`` per pair of scenario ids,
    m). ``node_of``: scenario station id -> asil node id."""
    from uwbcal.importers.asil import CSV_HEADER_MULTI, TICKS_PER_S

    run_dir.mkdir(parents=True, exist_ok=True)
    tm = dep.message_times(rec)
    rows: dict[int, dict[tuple[int, int, int], tuple[float, int]]] = {n: {} for n in node_of.values()}
    tx_st, rx_st, seq = (np.asarray(rec[c]).tolist() for c in ("tx_station", "rx_station", "seq"))
    for i, (a, b, j) in enumerate(zip(tx_st, rx_st, seq, strict=True)):
        tx, rx = node_of[int(a)], node_of[int(b)]
        for k in range(3):
            mid = 3 * int(j) + k
            # a message's TX row once (every direction of it carries the same TX stamp)
            rows[tx].setdefault((tx, mid, 0), (float(tm[i, k]), int(rec[f"tx{k + 1}"][i])))
            rows[rx][(tx, mid, 1)] = (float(tm[i, k]) + 1e-9, int(rec[f"rx{k + 1}"][i]))
    nodes = sorted(node_of.values())
    for node in nodes:
        ordered = sorted(rows[node].items(), key=lambda kv: kv[1][0])
        lines = [",".join(CSV_HEADER_MULTI)]
        lines += [f"{node},{tx},{mid},{ts},{ts / TICKS_PER_S!r}" for (tx, mid, _), (_, ts) in ordered]
        (run_dir / f"nnode-01_ttyACM{node}.csv").write_text("\n".join(lines) + "\n", encoding="ascii")
    inv = {v: k for k, v in node_of.items()}
    pairs = [(a, b) for i, a in enumerate(nodes) for b in nodes[i + 1 :]]
    text = f"message_interval: {interval_s!r} # s\nnodes:\n" + "".join(f"- {n}\n" for n in nodes)
    text += "node_pairs:\n"
    for a, b in pairs:
        d = distances_m.get((inv[a], inv[b]), distances_m.get((inv[b], inv[a])))
        if d is not None:
            text += f"  - nodes:\n    - {a}\n    - {b}\n    distance: {float(d)!r} # m\n"
    (run_dir / "parameters.yaml").write_text(text, encoding="ascii")


def make_session(
    truth: Scenario,
    distances_m: Mapping[tuple[int, int], float],
    duration_s: float,
    seed: int,
    departures: Sequence[Departure] = (),
) -> dict[str, Any]:
    """An N-node session of the true world ``truth`` (``duration_s`` s, run seed ``seed``), changed
    by ``departures`` (each ``f(records, rng) -> records``, e.g. a :mod:`uwbcal.gap.departures`
    form), written as an asil run (scenario station k is asil node k - first id), imported back,
    with ``t_s`` counted from power-on as ``uwbcal gap`` counts it. Returns the triplet records in
    asil node ids."""
    from uwbcal import vectorsim
    from uwbcal.gap import model
    from uwbcal.importers import asil
    from uwbcal.physics.world import World

    rng = np.random.default_rng([seed, 17])
    sched = round_robin_schedule(truth, duration_s, rng, distances_m)
    world_sc = truth
    for sid in truth.station_ids:  # a DW1000 counter reads 0 at power-on: the log's time base says when
        world_sc = world_sc.with_station(sid, counter_offset_units=0)
    rec, _ = vectorsim.run_triplets(World(world_sc, 30_000_000 + seed % 1_000_000), sched)
    out: dict[str, Any] = dict(rec)
    for f in departures:
        out = f(out, rng)
    first = min(truth.station_ids)
    node_of = {sid: sid - first for sid in truth.station_ids}
    with tempfile.TemporaryDirectory() as tmp:
        run = Path(tmp) / "run"
        write_asil_run(out, node_of, run, distances_m)
        imp = asil.load_run(run)
        return model.since_power_on(imp.triplets, imp.meta)
