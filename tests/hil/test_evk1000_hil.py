"""The EVK1000 image itself in the loop: build/evk1000/uwbcal-evk1000.bin (built here with
`make firmware`, never a stale file) runs in the emulated EVK1000 (uwbcal.evk1000) and is
talked to through the same pty and medium paths as a native station.

- GET_INFO reports board "evk1000" (and "evk1000/hsi" with the crystal made to fail);
- garbage on the link, then a normal answer;
- a 200-triplet calibration and a 100-exchange ranging session through the medium with both
  stations emulated: no lost record, and results equal to the native stations' for the same
  scenario and seed within noise;
- table push / pull / verify, kept across a power cycle (the flash file);
- a power cut at every flash operation of a table write, through the FPEC model: after the
  restart the station holds the old table or the new one, never neither.

What these tests cannot see: timing the emulator does not model (SPI and USART bytes take no
time, one cycle per instruction, no flash wait states), the real DW1000 (the medium's model
answers), and the real chip's flash (the FPEC model follows PM0075; partial states of a cut
are the model's choice).
"""

from __future__ import annotations

import json
import random
import shutil
import subprocess
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from test_table_hil import _curve  # the same example power curve as the native table tests
from uwbcal import cli, tables
from uwbcal.corrections import analysis
from uwbcal.device import Device
from uwbcal.evk1000.errors import PowerCut
from uwbcal.evk1000.fpec import FlashFile
from uwbcal.evk1000.image import Symbols
from uwbcal.evk1000.station import PtyLink, Station, program_image
from uwbcal.link.client import Client
from uwbcal.link.transport import Transport
from uwbcal.sessions.store import Session
from uwbcal.simstations import SimWorld, repo_root

ROOT = repo_root()
IMAGE = ROOT / "build" / "evk1000" / "uwbcal-evk1000.bin"          # host link: USB (default)
USART_IMAGE = ROOT / "build" / "evk1000-usart" / "uwbcal-evk1000.bin"  # `make firmware LINK=usart`
SCENARIO = ROOT / "scenarios" / "two_stations.toml"
STEPS, PER_STEP = 10, 20     # 3 dB steps from the top gain: several below -85 dBm


@pytest.fixture(scope="session")
def evk_image() -> Path:
    """The image, built now (make is incremental and rebuilds on a new git hash)."""
    if shutil.which("arm-none-eabi-gcc") is None:
        pytest.skip("arm-none-eabi-gcc is missing (tools/bootstrap.sh installs it): "
                    "cannot build the image")
    r = subprocess.run(["make", "-s", "firmware"], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    return IMAGE


@pytest.fixture(scope="session")
def evk_usart_image(evk_image: Path) -> Path:
    """The USART1 build of the same sources (for what the USB link cannot show)."""
    r = subprocess.run(["make", "-s", "firmware", "LINK=usart"], cwd=ROOT, capture_output=True, text=True,
                       timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    return USART_IMAGE


@pytest.fixture
def evk_world(evk_image: Path, tmp_path: Path) -> Iterator[Callable[..., SimWorld]]:
    worlds: list[SimWorld] = []

    def start(**kw: Any) -> SimWorld:
        kw.setdefault("board", "evk1000")
        kw.setdefault("image", evk_image)
        w = SimWorld(workdir=tmp_path / f"world{len(worlds)}", start_timeout_s=60.0, **kw)
        worlds.append(w)
        w.start()
        return w

    yield start
    for w in worlds:
        codes = w.stop()
        assert all(c == 0 for c in codes.values()), f"emulated stations exited with {codes} ({w.workdir})"


def test_info_garbage_then_answer(evk_world: Callable[..., SimWorld]) -> None:
    port = evk_world(n_stations=1).ports[0]
    rng = random.Random(7)
    with Device.open(port) as dev:
        info = dev.info()
        assert info.board == "evk1000" and info.radio_ok
        for size in (1, 100, 3000):
            dev.client.send_raw(bytes(rng.randrange(256) for _ in range(size)))
            dev.ping(b"after garbage")
            dev.client.send_raw(bytes(rng.randrange(1, 256) for _ in range(size)))  # no delimiter
            dev.ping(bytes(range(256)))
        assert dev.info().uid == info.uid


def test_hse_failure_reports_hsi(evk_world: Callable[..., SimWorld], evk_usart_image: Path) -> None:
    # On the HSI fallback there is no 48 MHz for USB: the USB image stays off the bus (as on a
    # real board), so GET_INFO can only be asked over the USART1 build.
    port = evk_world(n_stations=1, extra_args=["--hse-fail"], image=evk_usart_image).ports[0]
    with Device.open(port) as dev:
        assert dev.info().board == "evk1000/hsi"


def _calibrate(ports: list[str], out: Path, capsys: pytest.CaptureFixture[str]) -> dict[str, Any]:
    rc = cli.main(["calibrate", "--tx", ports[0], "--rx", ports[1], "--steps", str(STEPS), "--step-db", "3",
                   "--per-step", str(PER_STEP), "--spacing", "2ms", "--out", str(out), "--no-progress",
                   "--json", "--no-analysis"])
    text = capsys.readouterr().out
    assert rc == 0, text
    return dict(json.loads(text.strip().splitlines()[-1]))


def test_calibration_equals_native_within_noise(evk_world: Callable[..., SimWorld], station_binary: Path,
                                                 tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    results = {}
    for board in ("evk1000", "native"):
        w = evk_world(scenario=SCENARIO, board=board, binary=station_binary, seed=3)
        run = _calibrate(w.ports, tmp_path / f"{board}.db", capsys)["run"]
        assert run["complete"] and run["records"] == STEPS * PER_STEP
        assert run["losses"]["lost_frames"] == 0 and run["losses"]["n_missing"] == 0
        assert run["counters"]["tx"]["late"] == 0 and run["counters"]["rx"]["dropped"] == 0
        with Session.open(tmp_path / f"{board}.db", readonly=True) as s:
            rec = dict(s.read("triplets"))
        assert sorted(rec["seq"].tolist()) == list(range(STEPS * PER_STEP))
        results[board] = next(iter(analysis.calibrate_power_records(rec).values())).to_dict()["steps"]
        w.stop()
    import numpy as np

    for x, y in zip(results["evk1000"], results["native"], strict=True):
        assert x["gain2"] == y["gain2"]
        sem = np.hypot(x["error_sem_s"], y["error_sem_s"])
        assert abs(x["error_s"] - y["error_s"]) < 5 * sem + 2e-12, (x, y)


def _ds_ranges_m(db: Path) -> Any:
    import numpy as np
    from uwbcal import dw1000

    with Session.open(db, readonly=True) as s:
        rg = s.read("ranges")
    assert rg["seq"].tolist() == list(range(len(rg["seq"])))          # no gap, no duplicate
    ra = dw1000.wrap_diff(rg["t2r"], rg["t1r"]).astype(float)
    rb = dw1000.wrap_diff(rg["t3t"], rg["t2t"]).astype(float)
    da = dw1000.wrap_diff(rg["t3r"], rg["t2r"]).astype(float)
    db_ = dw1000.wrap_diff(rg["t2t"], rg["t1t"]).astype(float)
    return np.asarray((ra * rb - da * db_) / (ra + rb + da + db_) * dw1000.METRES_PER_UNIT)


def test_ranging_equals_native_within_noise(evk_world: Callable[..., SimWorld], station_binary: Path,
                                            tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A double-sided TWR session of 100 exchanges, both stations emulated, then native.

    At the default 1 ms reply, with no exchange measured again: this emulator found the tag's
    first reply late on the image (the calibration table's first lookup, about 47 000
    instructions = 0.65 ms at 72 MHz, fell inside the reply window; the native station takes no
    virtual time for it). The station now loads its table at boot."""
    import numpy as np

    got = {}
    for board in ("evk1000", "native"):
        w = evk_world(scenario=SCENARIO, board=board, binary=station_binary, seed=5)
        db = tmp_path / f"{board}.db"
        rc = cli.main(["range", "--ref", w.ports[0], "--tag", w.ports[1], "--count", "100", "--method", "ds",
                       "--out", str(db), "--no-progress", "--json"])
        run = json.loads(capsys.readouterr().out.strip().splitlines()[-1])["run"]
        assert rc == 0 and run["complete"] and run["records"] == 100, run
        assert run["losses"].get("remeasured", 0) == 0 and run["losses"].get("fetched", 0) == 0, run
        got[board] = _ds_ranges_m(db)
        w.stop()
    a, b = got["evk1000"], got["native"]
    sem = np.hypot(np.std(a) / np.sqrt(a.size), np.std(b) / np.sqrt(b.size))
    assert abs(np.mean(a) - np.mean(b)) < 5 * sem + 0.005, (np.mean(a), np.mean(b), sem)


def test_table_push_pull_verify_across_power_cycle(evk_world: Callable[..., SimWorld],
                                                   tmp_path: Path) -> None:
    w = evk_world(n_stations=1, ids=[7])
    with Device.open(w.ports[0]) as dev:
        uid = bytes(dev.info().uid)
    data = tables.build(uid, _curve(), z_ps=-750.0, created_unix=1_763_770_000)
    tables.save(tmp_path / "t.json", data)
    port = w.ports[0]
    assert cli.main(["table", "push", "--port", port, str(tmp_path / "t.json")]) == 0
    assert w.stop() == {7: 0}
    again = SimWorld(n_stations=1, ids=[7], board="evk1000", workdir=w.workdir, image=IMAGE,
                     start_timeout_s=60.0)      # the same flash file: a power cycle
    again.start()
    try:
        p = again.ports[0]
        assert cli.main(["table", "verify", "--port", p, str(tmp_path / "t.json")]) == 0
        assert cli.main(["table", "pull", "--port", p, "--out", str(tmp_path / "back.json")]) == 0
        assert tables.load(tmp_path / "back.json") == data
    finally:
        assert again.stop() == {7: 0}


class InProcess:
    """An emulated station in a thread of this process (no medium): fast power cycles."""

    def __init__(self, flash_path: Path, cut_at: int | None = None) -> None:
        self.flash = FlashFile(flash_path)
        self.link = PtyLink()
        self.station = Station(7, self.flash, self.link, None, symbols=Symbols(), cut_at=cut_at)
        self.error: BaseException | None = None
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()
        self.client = Client(Transport(self.link.path), timeout=2.0)

    def _serve(self) -> None:
        try:
            self.station.serve()
        except BaseException as exc:  # noqa: BLE001 - handed to the test
            self.error = exc

    def stop(self) -> None:
        self.client.close()
        self.station.running = False
        self.thread.join(30)
        self.flash.close()
        import os

        os.close(self.link.master)


def test_power_cut_at_every_flash_operation_of_a_table_write(evk_usart_image: Path, tmp_path: Path) -> None:
    # The USART1 build: the same flash driver and table store, and a link that needs no USB
    # enumeration after each of the hundreds of power cycles (InProcess serves USART1).
    from uwbcal.link import proto_gen as pg

    flash_path = tmp_path / "station.flash"
    f = FlashFile(flash_path)
    program_image(f, evk_usart_image.read_bytes())
    f.close()
    st = InProcess(flash_path)
    uid = bytes(st.client.request(pg.GetInfoReq()).uid)
    old = tables.build(uid, _curve(), created_unix=1_763_770_000)
    ops0 = st.station.machine.fpec.ops
    tables.push(st.client, old, uid=uid)
    n_ops = st.station.machine.fpec.ops - ops0
    st.stop()
    assert st.error is None
    assert n_ops > 100                     # an erase and every half-word of the slot
    new = tables.build(uid, _curve(40.0), created_unix=1_763_770_500)
    base = flash_path.read_bytes()
    outcomes = {"old": 0, "new": 0}
    for cut in range(1, n_ops + 1):
        flash_path.write_bytes(base)       # the old table only, before every cut
        st = InProcess(flash_path)
        st.station.machine.fpec.cut_at = st.station.machine.fpec.ops + cut   # the cut-th op from now
        try:
            for off in range(0, len(new), 256):
                st.client.request(pg.TableWriteReq(offset=off, data=new[off:off + 256]))
            try:
                commit = pg.TableCommitReq(length=len(new), crc32=tables.decode(new).crc32, force=0)
                st.client.request(commit, timeout=0.05, retries=0)   # the answer never comes
            except Exception:  # noqa: BLE001 - the power went away mid-answer
                pass
            st.thread.join(30)
        finally:
            st.stop()
        assert isinstance(st.error, PowerCut), (cut, st.error)
        st = InProcess(flash_path)         # power back on
        try:
            got = tables.pull(st.client)
            assert got in (old, new), f"cut at operation {cut}: neither table"
            outcomes["old" if got == old else "new"] += 1
        finally:
            st.stop()
    assert outcomes["old"] > 0



def test_flash_through_gdb_then_boot_from_flash_file(evk_image: Path, tmp_path: Path) -> None:
    """`uwbcal flash --gdb` loads the ELF into an erased emulated EVK1000 through its GDB stub
    (gdb-multiarch's `load`, as through OpenOCD's GDB server); the station then boots the
    image from its flash file."""
    import socket
    import sys
    import time

    gdb = shutil.which("gdb-multiarch") or shutil.which("arm-none-eabi-gdb")
    if gdb is None:
        pytest.skip("gdb-multiarch (or arm-none-eabi-gdb) is not installed: apt-get install gdb-multiarch")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    flash = tmp_path / "gdb.flash"
    err = open(tmp_path / "station.log", "wb")  # noqa: SIM115
    proc = subprocess.Popen([sys.executable, "-m", "uwbcal.evk1000", "--id", "5", "--flash", str(flash),
                             "--gdb", f"127.0.0.1:{port}"], stdout=subprocess.PIPE, stderr=err)
    try:
        assert proc.stdout is not None
        pty = proc.stdout.readline().decode().split()[1]
        deadline = time.monotonic() + 30
        while b"GDB stub listening" not in (tmp_path / "station.log").read_bytes():
            assert time.monotonic() < deadline and proc.poll() is None
            time.sleep(0.05)
        assert cli.main(["flash", "--gdb", f"127.0.0.1:{port}", "--image", str(evk_image)]) == 0
        assert flash.read_bytes()[:evk_image.stat().st_size] == evk_image.read_bytes()
        with Device.open(pty) as dev:
            assert dev.info().board == "evk1000"
    finally:
        proc.terminate()
        assert proc.wait(10) == 0
        err.close()
