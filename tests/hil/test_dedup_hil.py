"""At-most-once requests against simulated stations, through the raw framing: a request frame
sent twice with the same seq (a host retry after a lost answer) gets the same answer byte for
byte, and its handler runs once -- a status answer is not recomputed although the counters
moved, and a seq_start sent twice starts one plan."""

from __future__ import annotations

import time
from collections.abc import Callable

from uwbcal.device import Device
from uwbcal.link import proto_gen as pg
from uwbcal.link.client import Client
from uwbcal.link.framing import Frame, encode_frame
from uwbcal.sessions.plan import TOP_GAIN
from uwbcal.simstations import SimWorld, repo_root

SCENARIO = repo_root() / "scenarios" / "two_stations.toml"
#: Generous bound for anything the simulated stations do (ASan build), s.
DEADLINE_S = 60.0


def _wire(req: pg.Message, seq: int) -> bytes:
    """A request frame on the wire, preceded by a flushing 0x00 as the client sends it."""
    return b"\x00" + encode_frame(Frame(type=req.TYPE, seq=seq, payload=req.encode()))


def _answers(c: Client, n: int) -> list[Frame]:
    """The next ``n`` response frames (stream frames skipped)."""
    out: list[Frame] = []
    deadline = time.monotonic() + DEADLINE_S
    while len(out) < n:
        assert time.monotonic() < deadline, f"{len(out)} of {n} answers arrived"
        f = c.read_frame(1.0)
        if isinstance(f, Frame) and f.is_response:
            out.append(f)
        else:
            assert f is None or isinstance(f, Frame) and f.is_stream, f
    return out


def _send_twice(c: Client, wire: bytes) -> tuple[Frame, Frame]:
    """Send the same frame twice, the retry after the first answer; both answers."""
    c.send_raw(wire)
    (a1,) = _answers(c, 1)
    c.send_raw(wire)
    (a2,) = _answers(c, 1)
    return a1, a2


def _configure(tx: Device, rx: Device) -> tuple[int, int]:
    ids = []
    for d in (tx, rx):
        d.call(pg.StopReq())
        ids.append(d.radio_config().station_id)
    return ids[0], ids[1]


def _max_rx_seq(rx: Device, at_least: int) -> int:
    """Read rx's triplet stream until a record with TX triplet number >= at_least arrives."""
    deadline = time.monotonic() + DEADLINE_S
    best = -1
    while best < at_least:
        assert time.monotonic() < deadline, f"no triplet {at_least} received (last {best})"
        f = rx.client.next_stream(1.0)
        if f is not None and f.type == pg.TripletsResp.TYPE:
            best = max([best, *(r.seq for r in pg.TripletsResp.decode(f.payload).records)])
    return best


def test_ping_and_status_retried_with_the_same_seq(sim_stations: Callable[..., SimWorld]) -> None:
    world = sim_stations(scenario=SCENARIO)
    with Device.open(world.ports[0]) as tx, Device.open(world.ports[1]) as rx:
        tx_id, _ = _configure(tx, rx)
        c = tx.client

        seq = c.next_seq()
        a1, a2 = _send_twice(c, _wire(pg.PingReq(data=b"retried ping"), seq))
        assert (a1.type, a1.seq, a1.payload) == (pg.T_PING, seq, b"retried ping")
        assert encode_frame(a2) == encode_frame(a1)

        # status while a plan runs: the retry's answer is the first one, not a fresh reading
        rx.call(pg.ListenReq(role=0, peer=tx_id, reply_us=0))
        tx.call(pg.SeqStartReq(per_step=2000, spacing_us=1000, period_us=3000, gain13=TOP_GAIN,
                               gains2=bytes([TOP_GAIN])))
        seq = c.next_seq()
        wire = _wire(pg.StatusReq(), seq)
        c.send_raw(wire)
        (s1,) = _answers(c, 1)
        first = pg.StatusResp.decode(s1.payload)
        assert s1.type == pg.T_STATUS and s1.seq == seq and first.state == 1
        _max_rx_seq(rx, first.sent + 3)          # the transmitter has moved on since
        c.send_raw(wire)
        (s2,) = _answers(c, 1)
        assert encode_frame(s2) == encode_frame(s1)
        assert tx.call(pg.StatusReq()).sent > first.sent   # a new seq is a new reading
        tx.call(pg.StopReq())
        rx.call(pg.StopReq())


def test_seq_start_retried_with_the_same_seq_starts_one_plan(sim_stations: Callable[..., SimWorld]) -> None:
    world = sim_stations(scenario=SCENARIO)
    with Device.open(world.ports[0]) as tx, Device.open(world.ports[1]) as rx:
        tx_id, _ = _configure(tx, rx)
        rx.call(pg.ListenReq(role=0, peer=tx_id, reply_us=0))
        total = 150
        req = pg.SeqStartReq(per_step=total, spacing_us=1000, period_us=3000, gain13=TOP_GAIN,
                             gains2=bytes([TOP_GAIN]))
        seq = tx.client.next_seq()
        a1, a2 = _send_twice(tx.client, _wire(req, seq))
        # run twice, the retry would find the plan running (ERROR busy) or, had it finished,
        # start a second one (more records than triplets planned, checked below)
        assert a1.type == pg.T_SEQ_START and a1.seq == seq, a1
        assert pg.SeqStartResp.decode(a1.payload).total == total
        assert encode_frame(a2) == encode_frame(a1)

        deadline = time.monotonic() + DEADLINE_S
        while not tx.call(pg.StatusReq()).done:
            assert time.monotonic() < deadline, "the plan did not finish"
            while rx.client.next_stream(0.1) is not None:   # keep the rx link drained
                pass
        tx_counters = tx.call(pg.StopReq())
        rx_counters = rx.call(pg.StopReq())
        assert tx_counters.sent == total
        assert 0 < rx_counters.records <= total, rx_counters
