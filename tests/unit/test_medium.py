"""The medium's register model and lock-step scheduler, against an ideal test world.

The ideal world (constant clock offsets, free-space delay, fixed quality registers) stands in
for uwbcal.physics only here, to check register and scheduling semantics exactly; the medium
with the real physics is checked in tests/unit/test_medium_physics.py and tests/hil.
"""

from __future__ import annotations

import os
import socket
import tempfile
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
from uwbcal.dw1000 import C_LIGHT, TIME_UNIT_S, TIMESTAMP_MOD
from uwbcal.medium import registers as R
from uwbcal.medium import wire
from uwbcal.medium.client import TunnelClient
from uwbcal.medium.core import Medium
from uwbcal.medium.port import Reception, TxFrame
from uwbcal.medium.server import MediumServer

H = TunnelClient.header
REPO = Path(__file__).resolve().parents[2]
CHAN2_PRF64_CODE9 = 2 | (2 << 4) | (2 << 18) | (9 << 22) | (9 << 27)
TX_FCTRL_20B = 22 | (2 << 13) | (1 << 15) | (2 << 16) | (0x5 << 18)   # 20-byte payload, 6.81M, 64 MHz, 128


class IdealWorld:
    """Clocks with constant offsets (ppm) and counter offsets, stations on a line, no noise."""

    def __init__(self, ppm: dict[int, float], x_m: dict[int, float], offset_units: dict[int, float]) -> None:
        self.ppm, self.x_m, self.off = ppm, x_m, offset_units
        self.calls: list[tuple[int, int, float | None]] = []

    def station_ids(self) -> list[int]:
        return sorted(self.ppm)

    def local_units(self, station: int, t_s: float) -> float:
        return self.off[station] + t_s * (1 + self.ppm[station] * 1e-6) / TIME_UNIT_S

    def true_time(self, station: int, units: float) -> float:
        return (units - self.off[station]) * TIME_UNIT_S / (1 + self.ppm[station] * 1e-6)

    def delayed_tx(self, station: int, dx_units: int, tx_antd: int) -> tuple[float, int]:
        grid = dx_units & ~0x1FF
        return self.true_time(station, grid), grid + tx_antd

    def receive(self, frame: TxFrame, rx_stations: list[int],
                rx_antd: dict[int, int]) -> dict[int, Reception]:
        out = {}
        for rx in rx_stations:
            self.calls.append((frame.tx_station, rx, None))
            arrival = frame.t_rmarker_s + abs(self.x_m[rx] - self.x_m[frame.tx_station]) / C_LIGHT
            stamp = round(self.local_units(rx, arrival)) - rx_antd[rx]
            out[rx] = Reception(arrival_s=arrival, stamp_units=stamp,
                                cir_pwr=1000 + frame.gain_octet, rxpacc=120, rxpacc_nosat=120, fp_ampl1=1,
                                fp_ampl2=2, fp_ampl3=3, std_noise=50, fp_index=700, car_int=-1234, ttcko=-55)
        return out

    def temperature_c(self, station: int, t_s: float) -> float:
        return 30.0

    def otp_vtemp(self, station: int) -> int:
        return 0x8A00 | 0xB0


def test_frame_round_trip_and_crc() -> None:
    f = wire.encode(wire.TUN_WAIT, 513, wire.WAIT_REQ.pack(123456789, 1))
    assert f.endswith(b"\0") and b"\0" not in f[:-1]
    assert wire.decode(f[:-1]) == (wire.TUN_WAIT, 0, 513, wire.WAIT_REQ.pack(123456789, 1))
    bad = bytearray(f[:-1])
    bad[3] ^= 0x10
    with pytest.raises(wire.FrameError):
        wire.decode(bytes(bad))


class _Host:
    def __init__(self) -> None:
        self.now = 1000.0
        self.tx: list[tuple[int | None, int, object]] = []
        self.off = 0
        self.rx: list[float | None] = []

    def sys_time_units(self) -> float:
        return self.now

    def start_tx(self, dx_units: int | None, tx_antd: int, fmt: object) -> int:
        """The host's answer: TX_STAMP, unwrapped. A stand-in value that is NOT on the 512-unit
        grid (DX + TX_ANTD + 5), so that a model which rounded or masked it itself would show;
        the grid is the physics' (test_physics.py::test_delayed_tx_grid_and_antd) and is checked
        through the real medium in test_medium_physics.py::test_registers_carry_the_worlds_numbers."""
        self.tx.append((dx_units, tx_antd, fmt))
        assert dx_units is not None
        return dx_units + tx_antd + 5

    def radio_off(self) -> None:
        self.off += 1

    def rx_enable(self, at_units: float | None) -> None:
        self.rx.append(at_units)

    def temperature_c(self) -> float:
        return 30.0


def test_spi_headers_status_w1c_and_irq() -> None:
    m = R.Dw1000Model(host=_Host())
    assert m.spi_read(bytes([0x00]), 4) == (0xDECA0130).to_bytes(4, "little")
    # 3-byte header to LDE_RXANTD: EE 84 30 (REGISTERS.md writes "AE 84 30", which lacks bit 6).
    m.spi_write(bytes([0xEE, 0x84, 0x30]), (16400).to_bytes(2, "little"))
    assert m.get(R.LDE_IF, R.LDE_RXANTD_OFF, 2) == 16400
    assert m.parse_header(bytes([0x6E, 0x84, 0x30])) == (False, 0x2E, 0x1804)
    m.set_status(R.TXFRS | R.RXFCG)
    assert not m.irq                                   # SYS_MASK is 0 after reset
    m.spi_write(bytes([0x8E]), (R.TXFRS).to_bytes(4, "little"))
    assert m.irq
    m.spi_write(bytes([0x8F]), (R.TXFRS).to_bytes(4, "little"))   # write-1-to-clear
    assert not m.irq and m.status & R.RXFCG


def test_delayed_tx_passes_unwrapped_dx_and_writes_the_hosts_stamp_wrapped() -> None:
    host = _Host()
    host.now = float(TIMESTAMP_MOD - 1_000_000)        # just before the 40-bit wrap
    m = R.Dw1000Model(host=host)
    m.spi_write(bytes([0x98]), (16436).to_bytes(2, "little"))          # TX_ANTD
    m.spi_write(bytes([0x88]), TX_FCTRL_20B.to_bytes(5, "little"))
    dx = (TIMESTAMP_MOD - 1_000_000 + 50_000_000 + 0x1FF) % TIMESTAMP_MOD   # low 9 bits set, past the wrap
    m.spi_write(bytes([0x8A]), dx.to_bytes(5, "little"))
    m.spi_write(bytes([0x8D]), (R.TXSTRT | R.TXDLYS).to_bytes(4, "little"))
    assert not m.status & R.HPDWARN
    (dx_unwrapped, antd, _fmt), = host.tx
    assert dx_unwrapped == TIMESTAMP_MOD + dx and antd == 16436          # unwrapped past the wrap
    assert m.get(R.TX_TIME, 0, 5) == (dx + 16436 + 5) % TIMESTAMP_MOD    # the host's stamp, wrapped
    assert m.get(R.SYS_CTRL, 0, 4) == 0                                 # self-clearing


@pytest.mark.parametrize("lead_units", [-5000, 100, 2**39 + 10])
def test_late_delayed_tx_sets_hpdwarn_and_sends_nothing(lead_units: int) -> None:
    host = _Host()
    host.now = 5e9
    m = R.Dw1000Model(host=host)
    m.spi_write(bytes([0x88]), TX_FCTRL_20B.to_bytes(5, "little"))
    m.spi_write(bytes([0x8A]), ((int(host.now) + lead_units) % TIMESTAMP_MOD).to_bytes(5, "little"))
    m.spi_write(bytes([0x8D]), (R.TXSTRT | R.TXDLYS).to_bytes(4, "little"))
    assert m.status & R.HPDWARN and host.tx == [] and m.late_count == 1


def test_temperature_sar_and_otp() -> None:
    m = R.Dw1000Model(host=_Host())
    m.otp[R.OTP_VTEMP_ADDR] = 0x8AB0
    m.spi_write(H(True, R.OTP_IF, 0x04), (0x0009).to_bytes(2, "little"))
    m.spi_write(H(True, R.OTP_IF, 0x06), (0x0003).to_bytes(2, "little"))
    assert m.spi_read(H(False, R.OTP_IF, 0x0A), 4) == (0x8AB0).to_bytes(4, "little")
    m.spi_write(bytes([0xAA]), b"\x00")
    m.spi_write(bytes([0xAA]), b"\x01")
    ltemp = m.spi_read(H(False, R.TX_CAL, 0x03), 2)[1]
    assert ltemp == round(0x8A + (30.0 - 23.0) / 1.14)  # DW1000 User Manual 6.4


class _Sink:
    def __init__(self) -> None:
        self.frames: list[tuple[int, int, int, bytes]] = []

    def __call__(self, data: bytes) -> None:
        self.frames.append(wire.decode(data[:-1]))


def test_lock_step_time_moves_only_when_all_wait() -> None:
    world = IdealWorld({1: 0.0, 2: 0.0}, {1: 0.0, 2: 1.0}, {1: 0.0, 2: 0.0})
    med = Medium(world, pace_idle=False)
    s1, s2 = _Sink(), _Sink()
    a, b = med.hello(1, s1), med.hello(2, s2)
    med.start_wait(a, 7, 1000, 0)
    assert med.advance() is None and med.now_ps == 0 and s1.frames == []   # station 2 still runs
    med.start_wait(b, 9, 500, 0)
    med.advance()
    assert med.now_ps == 500 * 10**6
    assert [f[2] for f in s2.frames] == [9] and s1.frames == []            # only the earlier deadline
    assert wire.WAIT_RESP.unpack(s2.frames[0][3]) == (500, 0)


def test_idle_stations_are_paced_to_real_time() -> None:
    wall = [100.0]
    world = IdealWorld({1: 0.0}, {1: 0.0}, {1: 0.0})
    med = Medium(world, pace_idle=True, clock=lambda: wall[0])
    s1 = _Sink()
    a = med.hello(1, s1)
    med.start_wait(a, 1, 2_000_000, wire.MODE_IDLE)     # 2 s of idling
    delay = med.advance()
    assert delay == pytest.approx(2.0) and s1.frames == []
    wall[0] += 0.5
    med.cancel(a)                                        # host input after 0.5 s of real time
    assert wire.WAIT_RESP.unpack(s1.frames[0][3])[0] == 500_000
    med.start_wait(a, 2, 1_000_000, 0)                   # not idle: no pacing
    assert med.advance() is None and med.now_ps == 10**12


@pytest.fixture()
def served() -> Iterator[tuple[str, IdealWorld, Medium]]:
    world = IdealWorld({1: 10.0, 2: -5.0}, {1: 0.0, 2: 30.0}, {1: 12345.0, 2: 9.9e11})
    med = Medium(world, pace_idle=False)
    with tempfile.TemporaryDirectory() as d:
        path = os.path.join(d, "medium.sock")
        server = MediumServer(med, path)
        t = threading.Thread(target=server.serve, daemon=True)
        t.start()
        yield path, world, med
        server.running = False
        # wake the loop so that it sees running == False
        _poke(path)
        t.join(5)
        server.close()


def _configure(c: TunnelClient, antd: int) -> None:
    c.write_int(R.CHAN_CTRL, 0, CHAN2_PRF64_CODE9, 4)
    c.write_int(R.TX_ANTD, 0, antd, 2)
    c.write_int(R.LDE_IF, R.LDE_RXANTD_OFF, antd, 2)
    c.write_int(R.SYS_MASK, 0, 0x2427D080, 4)
    c.write_int(R.SYS_STATUS, 0, 0xFFFFFFFF, 4)


def test_frame_through_the_socket(served: tuple[str, IdealWorld, Medium]) -> None:
    path, world, med = served
    tx, rx = TunnelClient(path, 1), TunnelClient(path, 2)
    _configure(tx, 16000)
    _configure(rx, 16100)
    rx.write_int(R.SYS_CTRL, 0, R.RXENAB, 4)
    now = tx.read_int(R.SYS_TIME, 0, 5)
    assert now % 512 == 0
    dx = (now + 63_897_600) % TIMESTAMP_MOD                    # 1 ms ahead
    tx.write_int(R.TX_POWER, 0, 0x65656565, 4)
    tx.write_int(R.TX_FCTRL, 0, TX_FCTRL_20B, 5)
    tx.write(R.TX_BUFFER, 0, bytes(range(20)))
    tx.write_int(R.DX_TIME, 0, dx, 5)
    tx.write_int(R.SYS_CTRL, 0, R.TXSTRT | R.TXDLYS, 4)
    assert not tx.read_int(R.SYS_STATUS, 0, 4) & R.HPDWARN
    # Both stations wait; the transmitter's TXFRS and the receiver's RXFCG raise their IRQs.
    rx.send_wait(10_000_000)
    t_tx_us, irq_tx = tx.wait(10_000_000)
    assert irq_tx and tx.read_int(R.SYS_STATUS, 0, 4) & R.TXFRS
    assert tx.read_int(R.TX_TIME, 0, 5) == ((dx & ~0x1FF) + 16000) % TIMESTAMP_MOD
    tx.write_int(R.SYS_STATUS, 0, R.TXFRS, 4)          # else the next wait ends at once (level IRQ)
    tx.send_wait(20_000_000)
    t_rx_us, irq_rx = rx.wait_answer()
    assert irq_rx and t_rx_us >= t_tx_us - 1
    st = rx.read_int(R.SYS_STATUS, 0, 4)
    assert st & R.RXFCG and st & R.RXDFR
    finfo = rx.read_int(R.RX_FINFO, 0, 4)
    assert finfo & 0x7F == 22 and finfo >> 20 == 120
    assert rx.read(R.RX_BUFFER, 0, 20) == bytes(range(20))
    stamp = rx.read_int(R.RX_TIME, 0, 5)
    t_true = world.true_time(1, dx & ~0x1FF) + 30.0 / C_LIGHT
    assert stamp == (round(world.local_units(2, t_true)) - 16100) % TIMESTAMP_MOD
    assert rx.read_int(R.RX_FQUAL, 6, 2) == 1000 + 0x65
    car = rx.read_int(R.DRX_CONF, R.DRX_CAR_INT_OFF, 3)
    assert car - (1 << 21) == -1234
    assert world.calls == [(1, 2, None)]
    tx.close()
    rx.close()


def test_receiver_off_misses_the_frame_and_trxoff_cancels(served: tuple[str, IdealWorld, Medium]) -> None:
    path, world, med = served
    tx, rx = TunnelClient(path, 1), TunnelClient(path, 2)
    _configure(tx, 0)
    _configure(rx, 0)
    now = tx.read_int(R.SYS_TIME, 0, 5)
    tx.write_int(R.TX_FCTRL, 0, TX_FCTRL_20B, 5)
    tx.write_int(R.DX_TIME, 0, (now + 63_897_600) % TIMESTAMP_MOD, 5)
    tx.write_int(R.SYS_CTRL, 0, R.TXSTRT | R.TXDLYS, 4)
    rx.send_wait(5_000)                                     # receiver never enabled
    _, irq = tx.wait(5_000)
    assert irq
    tx.write_int(R.SYS_STATUS, 0, 0xFFFFFFFF, 4)
    tx.send_wait(10_000)
    assert rx.wait_answer() == (5_000, False)
    assert world.calls == []
    # A delayed TX cancelled by TRXOFF never goes out.
    rx.write_int(R.SYS_CTRL, 0, R.RXENAB, 4)
    rx.send_wait(20_000)
    assert tx.wait_answer() == (10_000, False)
    now = tx.read_int(R.SYS_TIME, 0, 5)
    tx.write_int(R.DX_TIME, 0, (now + 63_897_600) % TIMESTAMP_MOD, 5)
    tx.write_int(R.SYS_CTRL, 0, R.TXSTRT | R.TXDLYS, 4)
    tx.write_int(R.SYS_CTRL, 0, R.TRXOFF, 4)
    assert tx.wait(20_000) == (20_000, False)
    assert rx.wait_answer() == (20_000, False) and world.calls == []
    tx.close()
    rx.close()


def _check_snapshot(c: TunnelClient, blocks: list[tuple[int, int, bytes]]) -> set[int]:
    """Every snapshot block is exactly what the read returns; returns the register ids."""
    for rid, off, data in blocks:
        assert c.read(rid, off, len(data)) == data, f"register {rid:#04x}+{off:#x}"
    return {rid for rid, _, _ in blocks}


def test_wait_snapshot_is_what_the_reads_return(served: tuple[str, IdealWorld, Medium]) -> None:
    path, world, med = served
    tx, rx = TunnelClient(path, 1), TunnelClient(path, 2)
    _configure(tx, 16000)
    _configure(rx, 16100)
    rx.write_int(R.SYS_CTRL, 0, R.RXENAB, 4)
    now = tx.read_int(R.SYS_TIME, 0, 5)
    tx.write_int(R.TX_FCTRL, 0, TX_FCTRL_20B, 5)
    tx.write(R.TX_BUFFER, 0, bytes(range(20)))
    tx.write_int(R.DX_TIME, 0, (now + 63_897_600) % TIMESTAMP_MOD, 5)
    tx.write_int(R.SYS_CTRL, 0, R.TXSTRT | R.TXDLYS, 4)
    rx.send_wait(10_000_000, wire.MODE_SNAPSHOT)
    # The transmitter asks for the clock too (bit3), the receiver does not.
    _, irq, blocks = tx.wait_snapshot(10_000_000, wire.MODE_SNAPSHOT | wire.MODE_SNAPSHOT_TIME)
    assert irq and _check_snapshot(tx, blocks) == {R.SYS_TIME, R.SYS_STATUS, R.TX_TIME}
    assert dict(((rid, off), d) for rid, off, d in blocks)[(R.SYS_STATUS, 0)][0] & R.TXFRS
    tx.write_int(R.SYS_STATUS, 0, R.TXFRS, 4)
    tx.send_wait(20_000_000)
    body = rx._recv_frame()[3]
    assert body[8] == 1
    blocks = wire.parse_snapshot(body[wire.WAIT_RESP.size:])
    regs = _check_snapshot(rx, blocks)
    assert regs == {R.SYS_STATUS, R.TX_TIME, R.RX_FINFO, R.RX_TIME, R.RX_FQUAL, R.DRX_CONF, R.RX_TTCKI,
                    R.RX_TTCKO, R.RX_BUFFER}
    assert (R.RX_BUFFER, 0, bytes(range(20))) in blocks
    # Without bit2 the answer is the 9 bytes of old.
    rx.write_int(R.SYS_STATUS, 0, 0xFFFFFFFF, 4)
    rx.send_wait(20_000_000)
    assert len(tx._recv_frame()[3]) == wire.WAIT_RESP.size
    assert len(rx._recv_frame()[3]) == wire.WAIT_RESP.size
    tx.close()
    rx.close()


def _poke(path: str) -> None:
    """Wake the server's select so that it sees ``running`` is false."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
        try:
            s.connect(path)
        except OSError:
            pass
