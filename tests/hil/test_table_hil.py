"""Calibration tables end to end on simulated stations (the native firmware as a process, its
flash a file): push, stop, start again, pull byte for byte; another station's table refused
with one line unless --force; the station's own checks; and a power cut inside a real station
process during a table write leaves the old or the new table.
"""

from __future__ import annotations

import dataclasses
import termios
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from uwbcal import cli, tables
from uwbcal.corrections.power import PowerCurve
from uwbcal.errors import DeviceTimeout, LinkError, TableError
from uwbcal.link import proto_gen as pg
from uwbcal.link.client import Client, ErrorResponse
from uwbcal.link.transport import Transport
from uwbcal.simstations import SimWorld

CUT_EXIT_CODE = 86   # firmware/boards/native/flash.c


class Station:
    """Station 7 of a one-station SimWorld on ``workdir``: its flash file is
    workdir/station-7.flash, so a new Station on the same workdir is a power cycle."""

    def __init__(self, binary: Path, workdir: Path) -> None:
        self.world = SimWorld(n_stations=1, ids=[7], binary=binary, workdir=workdir)
        self.world.start()
        self.port = self.world.ports[0]
        self.proc = self.world.stations[0].process
        self.client: Client | None = Client(Transport(self.port), timeout=2.0)

    @property
    def c(self) -> Client:
        assert self.client is not None
        return self.client

    def release(self) -> str:
        """Close the test's own link (so that the CLI can open the port); the port."""
        if self.client is not None:
            self.client.close()
            self.client = None
        return self.port

    def stop(self) -> int:
        """SIGTERM; the exit code (0: clean, no sanitizer report)."""
        self.release()
        return self.world.stop()[7]


@pytest.fixture
def workdir(tmp_path: Path) -> Path:
    return tmp_path / "world"


@pytest.fixture
def station(station_binary: Path, workdir: Path) -> Iterator[Station]:
    s = Station(station_binary, workdir)
    yield s
    assert s.stop() == 0


def _curve(shift_ps: float = 0.0) -> PowerCurve:
    err_ps = (180.0, 90.0, 20.0, -30.0, -140.0, -260.0)
    return PowerCurve(measured_dbm=(-104.0, -95.0, -88.5, -84.0, -80.0, -77.0),
                      error_s=tuple((e + shift_ps) * 1e-12 for e in err_ps),
                      real_dbm=(-104.0, -95.0, -88.5, -83.0, -76.0, -68.0),
                      reference_real_dbm=-68.0, reference_measured_dbm=-77.0)


def _uid(c: Client) -> bytes:
    return bytes(c.request(pg.GetInfoReq()).uid)


def test_push_restart_pull_byte_identical(station_binary: Path, workdir: Path, tmp_path: Path) -> None:
    st = Station(station_binary, workdir)
    try:
        uid = _uid(st.c)
        data = tables.build(uid, _curve(), z_ps=-750.0, created_unix=1_763_770_000)
        r = tables.push(st.c, data, uid=uid, radio=(2, 64, 128))
        assert (r.slot, r.sequence) == (0, 1)
        # a second table: the store alternates slots, the newest wins
        data2 = tables.build(uid, _curve(12.5), z_ps=-700.0, created_unix=1_763_770_100)
        r2 = tables.push(st.c, data2, uid=uid)
        assert (r2.slot, r2.sequence) == (1, 2)
    finally:
        assert st.stop() == 0
    st = Station(station_binary, workdir)   # same flash file: a power cycle
    try:
        assert _uid(st.c) == uid
        assert tables.pull(st.c) == data2
        i = tables.info(st.c)
        assert (i.active, i.slot0_state, i.slot1_state, i.slot0_sequence, i.slot1_sequence) == (1, 1, 1, 1, 2)
        assert i.applied == 1 and i.table_crc32 == tables.decode(data2).crc32
        # and through the CLI: verify passes, pull writes the same bytes
        tables.save(tmp_path / "t2.json", data2)
        port = st.release()
        assert cli.main(["table", "verify", "--port", port, str(tmp_path / "t2.json")]) == 0
        assert cli.main(["table", "pull", "--port", port, "--out", str(tmp_path / "back.json")]) == 0
        assert tables.load(tmp_path / "back.json") == data2
        tables.save(tmp_path / "t1.json", data)
        stale = ["table", "verify", "--port", port, str(tmp_path / "t1.json")]
        assert cli.main(stale) == TableError.exit_code   # the older table is no longer the station's
    finally:
        assert st.stop() == 0


def test_other_uid_refused_one_line_force_overrides(station: Station, tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    uid = _uid(station.c)
    other = bytes(b ^ 0x5A for b in uid)
    t = tmp_path / "other.json"
    tables.save(t, tables.build(other, _curve(), created_unix=1_763_770_000))
    port = station.release()
    capsys.readouterr()
    assert cli.main(["table", "push", "--port", port, str(t)]) == TableError.exit_code
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1, lines
    assert lines[0].startswith("uwbcal table: error: ")
    assert other.hex() in lines[0] and uid.hex() in lines[0] and "--force" in lines[0]
    c = Client(Transport(port), timeout=2.0)
    try:
        assert tables.info(c).active == 0xFF   # nothing reached the flash
    finally:
        c.close()
    assert cli.main(["table", "push", "--port", port, "--force", str(t)]) == 0
    assert "slot 0, sequence 1" in capsys.readouterr().out
    c = Client(Transport(port), timeout=2.0)
    try:
        assert tables.pull(c) == tables.load(t)
        assert tables.info(c).applied == 1   # a forced table is used as pushed
    finally:
        c.close()


def test_other_radio_refused(station: Station) -> None:
    uid = _uid(station.c)
    data = tables.build(uid, _curve(), channel=5, created_unix=1_763_770_000)
    with pytest.raises(TableError, match="channel 5"):
        tables.push(station.c, data, uid=uid, radio=(2, 64, 128))
    assert tables.push(station.c, data, uid=uid, radio=(2, 64, 128), force=True).sequence == 1


def test_station_names_the_bad_field(station: Station) -> None:
    """The firmware checks on its own: a table with an unordered axis (host checks bypassed)
    is answered bad_value with the cal_table field index, and flash is untouched."""
    c = station.c
    uid = _uid(c)
    good = tables.build(uid, _curve(), created_unix=1_763_770_000)
    t = tables.decode(good)
    bad = tables.seal(dataclasses.replace(t, curve_dbm=(t.curve_dbm[0], t.curve_dbm[0]) + t.curve_dbm[2:]))
    for off in range(0, len(bad), 256):
        c.request(pg.TableWriteReq(offset=off, data=bad[off:off + 256]))
    with pytest.raises(ErrorResponse) as ei:
        c.request(pg.TableCommitReq(length=len(bad), crc32=tables.decode(bad).crc32, force=0))
    assert ei.value.code == pg.ERR_BAD_VALUE
    assert ei.value.detail == tables.FIELD_NAMES.index("curve_dbm")
    p = tables.problem(bad)
    assert p is not None and p[0] == ei.value.detail   # the host's check agrees
    assert tables.info(c).active == 0xFF
    # the push path turns the station's answer into a one-line TableError naming the field
    with pytest.raises(TableError, match="field curve_dbm"):
        tables.push(c, bad, uid=uid)


@pytest.mark.parametrize("cut_at", [0, 1, 9, 150, 299, 300, 301])
def test_power_cut_in_station_process(station_binary: Path, workdir: Path, cut_at: int,
                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """The native flash cuts the power at operation cut_at of the next table write (the process
    exits); after a restart the station holds the old table or the new one, never neither.
    (tests/firmware/test_table_store.c covers every operation and three ways of tearing.)"""
    st = Station(station_binary, workdir)
    try:
        uid = _uid(st.c)
        old = tables.build(uid, _curve(), created_unix=1_763_770_000)
        tables.push(st.c, old, uid=uid)
    finally:
        assert st.stop() == 0
    new = tables.build(uid, _curve(40.0), created_unix=1_763_770_500)
    monkeypatch.setenv("UWBCAL_FLASH_CUT_AT", str(cut_at))
    monkeypatch.setenv("UWBCAL_FLASH_TEAR", "partial")
    monkeypatch.setenv("UWBCAL_FLASH_SEED", str(1000 + cut_at))
    st = Station(station_binary, workdir)
    monkeypatch.delenv("UWBCAL_FLASH_CUT_AT")
    try:
        for off in range(0, len(new), 256):
            st.c.request(pg.TableWriteReq(offset=off, data=new[off:off + 256]))
        # the process dies while answering; tcdrain() on the vanished pty may raise termios.error
        # (not yet turned into LinkError by the transport)
        with pytest.raises((DeviceTimeout, LinkError, ErrorResponse, termios.error)):
            st.c.request(pg.TableCommitReq(length=len(new), crc32=tables.decode(new).crc32, force=0),
                         timeout=3.0, retries=0)
        deadline = time.monotonic() + 10
        while st.proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        code = st.stop()
    assert code == CUT_EXIT_CODE
    st = Station(station_binary, workdir)
    try:
        got = tables.pull(st.c)
        assert got in (old, new)
        if cut_at < 301:
            assert got == old   # the commit word's last half-word is operation 301
        i = tables.info(st.c)
        assert i.applied == 1
        written = 1 - i.active if got == old else i.active
        if got == old:
            states = (i.slot0_state, i.slot1_state)
            assert states[written] in (0, 2)   # the interrupted slot: empty or torn, reported
        # and the store recovers: the next write succeeds and wins
        assert tables.push(st.c, new, uid=uid).sequence == 2
        assert tables.pull(st.c) == new
    finally:
        assert st.stop() == 0


def test_station_range_matches_host_recomputation(station_binary: Path, tmp_path: Path) -> None:
    """Two stations with their own tables in the simulated medium range with the paper's
    exchange: every range the reference computed on the station (range_mm) equals the host's
    recomputation from the raw record and the two tables, to the millimetre."""
    import numpy as np
    from uwbcal.device import Device
    from uwbcal.medium.launcher import MediumProcess
    from uwbcal.sessions.store import Session

    scenario = Path(__file__).resolve().parents[2] / "scenarios" / "two_stations.toml"
    world = SimWorld(n_stations=2, binary=station_binary, workdir=tmp_path / "w",
                     medium=MediumProcess(scenario))
    world.start()
    try:
        tabs: dict[int, bytes] = {}
        for sid, port in zip((1, 2), world.ports, strict=True):
            with Device.open(port) as d:
                uid = bytes(d.info().uid)
                tabs[sid] = tables.build(uid, _curve(5.0 * sid), z_ps=-150.0 * sid,
                                         created_unix=1_763_770_000)
                tables.push(d.client, tabs[sid], uid=uid)
        out = tmp_path / "r.db"
        assert cli.main(["range", "--ref", world.ports[0], "--tag", world.ports[1], "--count", "40",
                         "--out", str(out)]) == 0
    finally:
        codes = world.stop()
    assert codes == {1: 0, 2: 0}
    with Session.open(out, readonly=True) as s:
        r = s.read("ranges")
    ref, tag = tables.decode(tabs[1]), tables.decode(tabs[2])
    station = r["range_station_m"]
    assert len(station) == 40 and np.isfinite(station).all()
    n = 0
    names = ("t1r", "t1t", "t2t", "t2r", "t3r", "t3t")
    for i in range(len(station)):
        t6 = [int(r[k][i]) for k in names]
        mm = tables.station_range_mm(t6, tag, ref, (int(r["cir_pwr_t1"][i]), int(r["rxpacc_t1"][i])),
                                     (int(r["cir_pwr_r2"][i]), int(r["rxpacc_r2"][i])))
        assert mm is not None and mm == round(station[i] * 1000), (i, mm, station[i])
        n += 1
    assert n == 40
    # and the tables did something: without them the same exchanges give other ranges
    plain = tables.range_mm([int(r[k][0]) for k in names], 0.0, 0.0, 0.0)
    assert plain is not None and abs(plain - round(station[0] * 1000)) > 50
