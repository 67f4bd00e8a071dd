"""Station faults of issue 12 on a simulated station: RESET leaks no file descriptor (the flash
file is opened O_CLOEXEC), and requests that arrive in the same read as a RESET are answered by
the restarted station instead of being dropped. What this cannot see: the EVK1000's own
board_link_keep (the bytes kept in .noinit RAM across the SYSRESETREQ), which is built with
`make firmware` but has run on no board yet."""

from __future__ import annotations

import os
import time
from collections.abc import Callable

from uwbcal.device import Device
from uwbcal.link import proto_gen as pg
from uwbcal.link.framing import Frame, encode_frame
from uwbcal.simstations import SimWorld


def _fds(pid: int) -> int:
    return len(os.listdir(f"/proc/{pid}/fd"))


def test_reset_leaks_no_descriptor(sim_stations: Callable[..., SimWorld]) -> None:
    world = sim_stations(1)
    pid = world.stations[0].process.pid
    with Device.open(world.ports[0]) as dev:
        dev.reset()
        before = _fds(pid)
        for _ in range(20):
            dev.reset()
        assert world.stations[0].process.pid == pid and world.stations[0].process.poll() is None
        assert _fds(pid) == before, f"{_fds(pid) - before} descriptors leaked over 20 resets"


def test_requests_behind_a_reset_in_one_read_are_answered(sim_stations: Callable[..., SimWorld]) -> None:
    world = sim_stations(1)
    with Device.open(world.ports[0]) as dev:
        c = dev.client
        a, b, d = c.next_seq(), c.next_seq(), c.next_seq()
        burst = b"".join(b"\x00" + encode_frame(Frame(type=t, seq=s, payload=p)) for t, s, p in (
            (pg.T_PING, a, b"before"), (pg.ResetReq.TYPE, b, b""), (pg.T_PING, d, b"after")))
        c.send_raw(burst)                       # one write: the station reads it in one go
        answered: dict[int, bytes] = {}
        deadline = time.monotonic() + 10
        while len(answered) < 3 and time.monotonic() < deadline:
            f = c.read_frame(0.2)
            if isinstance(f, Frame) and f.is_response:
                answered[f.seq] = f.payload
        assert answered.get(a) == b"before" and b in answered
        assert answered.get(d) == b"after", "the request behind RESET got no answer"
