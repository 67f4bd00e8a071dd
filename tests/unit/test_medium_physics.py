"""The medium on the real physics World: one implementation of the physics, determinism for a
seed, the 40-bit wrap of the registers, and moving a station through the control socket."""

from __future__ import annotations

import os
import socket
import tempfile
import threading
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
import pytest
from uwbcal.dw1000 import TIMESTAMP_MOD
from uwbcal.medium import registers as R
from uwbcal.medium.client import TunnelClient
from uwbcal.medium.core import Medium
from uwbcal.medium.launcher import MediumError, control
from uwbcal.medium.server import MediumServer
from uwbcal.medium.world_adapter import MediumWorldAdapter
from uwbcal.physics.scenario import parse_scenario
from uwbcal.physics.world import World

SCENARIO = """
name = "pair"
seed = 3
[[stations]]
id = 1
position_m = [0.0, 0.0, 1.0]
ppm = 3.0
[[stations]]
id = 2
position_m = [5.0, 0.0, 1.0]
ppm = -2.0
bias_scale = 1.2
"""
CHAN = 2 | (2 << 4) | (2 << 18) | (9 << 22) | (9 << 27)
FCTRL = 22 | (2 << 13) | (1 << 15) | (2 << 16) | (0x5 << 18)


@contextmanager
def _served(seed: int) -> Iterator[tuple[str, MediumWorldAdapter, Medium, MediumServer]]:
    world = MediumWorldAdapter(parse_scenario(SCENARIO), seed)
    med = Medium(world, pace_idle=False)
    with tempfile.TemporaryDirectory() as d:
        path = os.path.join(d, "m.sock")
        server = MediumServer(med, path)
        t = threading.Thread(target=server.serve, daemon=True)
        t.start()
        try:
            yield path, world, med, server
        finally:
            server.running = False
            _poke(path)
            t.join(5)
            server.close()


def _exchange(path: str, n: int, gains: list[int]) -> list[tuple[int, int, int, int]]:
    """Station 1 sends n delayed frames 2 ms apart to station 2.

    Returns (TX_STAMP, RX_STAMP, CIR_PWR, CAR_INT) per frame."""
    tx, rx = TunnelClient(path, 1), TunnelClient(path, 2)
    out = []
    for c in (tx, rx):
        c.write_int(R.CHAN_CTRL, 0, CHAN, 4)
        c.write_int(R.TX_ANTD, 0, 16436, 2)
        c.write_int(R.LDE_IF, R.LDE_RXANTD_OFF, 16436, 2)
        c.write_int(R.SYS_MASK, 0, 0x2427D080, 4)
        c.write_int(R.TX_FCTRL, 0, FCTRL, 5)
    start = tx.read_int(R.SYS_TIME, 0, 5)
    for k in range(n):
        rx.write_int(R.SYS_STATUS, 0, 0xFFFFFFFF, 4)
        rx.write_int(R.SYS_CTRL, 0, R.RXENAB, 4)
        tx.write_int(R.SYS_STATUS, 0, 0xFFFFFFFF, 4)
        g = gains[k % len(gains)]
        tx.write_int(R.TX_POWER, 0, g * 0x01010101, 4)
        tx.write(R.TX_BUFFER, 0, bytes(20))
        tx.write_int(R.DX_TIME, 0, (start + (k + 1) * 127_795_200) % TIMESTAMP_MOD, 5)
        tx.write_int(R.SYS_CTRL, 0, R.TXSTRT | R.TXDLYS, 4)
        rx.send_wait(10**12)
        _, irq = tx.wait(10**12)
        assert irq
        tx.write_int(R.SYS_STATUS, 0, 0xFFFFFFFF, 4)
        tx.send_wait(10**12)
        _, irq = rx.wait_answer()
        assert irq and rx.read_int(R.SYS_STATUS, 0, 4) & R.RXFCG
        car = rx.read_int(R.DRX_CONF, R.DRX_CAR_INT_OFF, 3)
        out.append((tx.read_int(R.TX_TIME, 0, 5), rx.read_int(R.RX_TIME, 0, 5),
                    rx.read_int(R.RX_FQUAL, 6, 2), car - (1 << 21) if car & (1 << 20) else car))
        tx.cancel()                      # tun_cancel answers the transmitter's pending wait now
        assert not tx.wait_answer()[1]
    tx.close()
    rx.close()
    return out


def test_deterministic_for_a_seed_and_different_for_another() -> None:
    gains = [0x1F, 0x15, 0x0B]
    with _served(5) as (path, *_):
        a = _exchange(path, 12, gains)
    with _served(5) as (path, *_):
        b = _exchange(path, 12, gains)
    with _served(6) as (path, *_):
        c = _exchange(path, 12, gains)
    assert a == b
    assert [x[0] for x in a] == [x[0] for x in c]          # TX stamps: programmed, no noise
    assert [x[1] for x in a] != [x[1] for x in c]          # RX stamps: noise from the run seed


def test_registers_carry_the_worlds_numbers() -> None:
    """The medium adds nothing: TX stamps are DX_TIME on the grid + TX_ANTD, and the drift seen in
    the RX stamps and the carrier integrator are the World's clocks (3 ppm vs -2 ppm)."""
    with _served(5) as (path, world, med, _):
        got = _exchange(path, 8, [0x1F])
    tx = np.array([g[0] for g in got], dtype=np.int64)
    rxs = np.array([g[1] for g in got], dtype=np.int64)
    assert ((tx - 16436) % 512 == 0).all()
    dtx = np.diff(tx) % TIMESTAMP_MOD
    drx = np.diff(rxs) % TIMESTAMP_MOD
    ratio_ppm = float(np.mean(drx / dtx - 1.0) * 1e6)
    truth = World(parse_scenario(SCENARIO), 5)
    expect = float(truth.offset_ppm(2, 0.01) - truth.offset_ppm(1, 0.01))
    assert abs(ratio_ppm - expect) < 0.05, (ratio_ppm, expect)
    assert all(g[3] < 0 for g in got)        # RX clock slower than TX: negative (positive = local fast)
    assert med.frames == 8 and med.receptions == 8


def test_moving_a_station_changes_the_received_power() -> None:
    with _served(5) as (path, world, _med, _server):
        near = _exchange(path, 4, [0x1F])
        assert control(path, "move 2 50.0 0.0 1.0") == "ok"
        assert control(path, "where 2").split()[1:] == ["50.0", "0.0", "1.0"]
        assert world.distance_m(1, 2) == 50.0
        far = _exchange(path, 4, [0x1F])
        assert control(path, "stats").startswith("ok now_s=")
        with pytest.raises(MediumError, match="unknown command"):
            control(path, "fly 2")
    assert np.mean([f[2] for f in far]) < np.mean([n[2] for n in near]) / 10   # 20 dB weaker


def _poke(path: str) -> None:
    """Wake the server's select so that it sees ``running`` is false."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
        try:
            s.connect(path)
        except OSError:
            pass


def test_a_station_the_scenario_does_not_name_is_refused() -> None:
    with _served(5) as (path, _world, med, _server):
        with pytest.raises(RuntimeError, match="ERROR"):
            TunnelClient(path, 7)
        a = TunnelClient(path, 1)                 # the medium is still serving
        assert a.read_int(R.DEV_ID_REG, 0, 4) == 0xDECA0130
        a.close()
        assert 7 not in med.stations
