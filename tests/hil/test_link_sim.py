"""The host link end to end against simulated stations: identity through the CLI, garbage
and every malformed-frame vector answered with the right ERROR while the station keeps
answering, reset, reopen, and `uwbcal sim` start-up and clean shutdown."""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from uwbcal.device import Device
from uwbcal.errors import LinkError, UwbcalError
from uwbcal.link import proto_gen as pg
from uwbcal.link.framing import Frame, FrameDecoder, FrameError, encode_frame
from uwbcal.simstations import SimWorld, repo_root, sim_cpu

VECTORS = json.loads((Path(__file__).resolve().parents[2] / "protocol" / "vectors.json").read_text())


def uwbcal(
    *args: str, env: dict[str, str] | None = None, timeout: float = 30
) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "uwbcal", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        env={**os.environ, **(env or {})},
    )


def test_two_stations_distinct_uids(sim_stations: Callable[..., SimWorld]) -> None:
    world = sim_stations(2)
    infos = []
    for port in world.ports:
        r = uwbcal("info", "--port", port, "--json")
        assert r.returncode == 0, r.stderr
        infos.append(json.loads(r.stdout))
    assert infos[0]["uid"] != infos[1]["uid"]
    for info, port in zip(infos, world.ports, strict=True):
        assert info["port"] == port and info["board"] == "native"
        assert info["protocol_version"] == pg.PROTOCOL_VERSION and info["max_payload"] == pg.MAX_PAYLOAD
        assert len(bytes.fromhex(info["uid"])) == 12


def test_uid_stable_across_restarts(sim_stations: Callable[..., SimWorld]) -> None:
    a = sim_stations(1)
    with Device.open(a.ports[0]) as d:
        uid1 = d.info().uid
    a.stop()
    b = sim_stations(1)
    with Device.open(b.ports[0]) as d:
        assert d.info().uid == uid1


def test_garbage_then_normal_answer(sim_stations: Callable[..., SimWorld]) -> None:
    rng = random.Random(1234)
    port = sim_stations(1).ports[0]
    with Device.open(port) as dev:
        for size in (1, 100, 5000, 20000):
            dev.client.send_raw(bytes(rng.randrange(256) for _ in range(size)))
            dev.ping(b"after garbage")
            dev.client.send_raw(bytes(rng.randrange(1, 256) for _ in range(size)))  # no delimiter at all
            dev.ping(bytes(range(256)))
        assert dev.info().board == "native"


@pytest.mark.parametrize("vec", VECTORS["malformed"], ids=lambda v: v["name"])
def test_malformed_frame_gets_its_error(
    sim_stations: Callable[..., SimWorld], vec: dict[str, object]
) -> None:
    port = sim_stations(1).ports[0]
    with Device.open(port) as dev:
        c = dev.client
        c.send_raw(b"\x00" + bytes.fromhex(str(vec["wire"])))
        got = c.read_frame(5.0)
        expected = bytes.fromhex(str(vec["response"]))
        assert isinstance(got, Frame), got
        assert encode_frame(got) == expected
        assert c.read_frame(0.2) is None  # exactly one answer
        dev.ping(b"still alive")


def test_max_payload_echo_and_too_long(sim_stations: Callable[..., SimWorld]) -> None:
    port = sim_stations(1).ports[0]
    with Device.open(port) as dev:
        dev.ping(bytes(pg.MAX_PAYLOAD))
        dev.ping(bytes((i % 255) + 1 for i in range(pg.MAX_PAYLOAD)))
        dev.client.send_raw(b"\x00" + b"\x55" * 3000 + b"\x00")
        got = dev.client.read_frame(5.0)
        assert isinstance(got, Frame) and got.type == pg.T_ERROR
        e = pg.ErrorResp.decode(got.payload)
        assert (e.code, e.detail) == (pg.ERR_TOO_LONG, 3000)
        dev.ping(b"ok")


def test_reset_keeps_port_and_identity(sim_stations: Callable[..., SimWorld]) -> None:
    world = sim_stations(1)
    pid = world.stations[0].process.pid
    with Device.open(world.ports[0]) as dev:
        before = dev.info()
        dev.reset()
        after = dev.info()
    assert after.uid == before.uid and after.port == before.port
    assert world.stations[0].process.poll() is None and world.stations[0].process.pid == pid  # re-exec


def test_reopen_after_close(sim_stations: Callable[..., SimWorld]) -> None:
    port = sim_stations(1).ports[0]
    for i in range(5):
        with Device.open(port) as dev:
            dev.ping(bytes([i]))
    time.sleep(0.05)  # no host attached for a while: the station keeps serving
    with Device.open(port) as dev:
        dev.ping(b"back")


def test_frame_errors_are_not_attributed_to_requests(sim_stations: Callable[..., SimWorld]) -> None:
    port = sim_stations(1).ports[0]
    with Device.open(port) as dev:
        dev.client.send_raw(b"\x00\x05\x01\x02\x00")  # bad COBS
        dev.ping(b"x")
        # the station answered the bad frame with ERROR seq 0 before the PING: kept aside
        assert [(u.code, u.detail) for u in dev.client.unattributed if isinstance(u, pg.ErrorResp)] == [
            (pg.ERR_BAD_COBS, 0)
        ]
        dev.ping(b"y")


def test_sim_command_json_and_sigterm(station_binary: Path) -> None:
    proc = subprocess.Popen(
        [sys.executable, "-m", "uwbcal", "sim", "--stations", "2", "--json", "--seed", "3"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "UWBCAL_STATION": str(station_binary)},
    )
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        doc = json.loads(line)
        assert [s["id"] for s in doc["stations"]] == [1, 2]
        ports = [s["port"] for s in doc["stations"]]
        uids = set()
        for port in ports:
            with Device.open(port) as dev:
                uids.add(dev.info().uid)
        assert len(uids) == 2
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(20) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.stderr is not None
    assert "Traceback" not in proc.stderr.read()
    for port in ports:  # the stations are gone with their ptys
        with pytest.raises(UwbcalError):
            with Device.open(port, timeout=0.2, retries=0) as dev:
                dev.ping()


def test_sim_command_text_and_sigint(station_binary: Path) -> None:
    proc = subprocess.Popen(
        [sys.executable, "-m", "uwbcal", "sim", "--stations", "1"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "UWBCAL_STATION": str(station_binary)},
    )
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline().strip()
        assert line.startswith("station 1: /dev/")
        proc.send_signal(signal.SIGINT)
        assert proc.wait(20) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_wrong_port_one_line() -> None:
    r = uwbcal("info", "--port", "/dev/uwbcal-missing")
    assert r.returncode == LinkError.exit_code
    assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr


def _cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # utime + stime


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc")
def test_idle_station_does_not_spin(sim_stations: Callable[..., SimWorld]) -> None:
    """With no host attached (the pty reports hang-up) and with one attached but silent, the
    station sleeps in board_idle: a spinning loop would burn about a CPU second per second."""
    world = sim_stations(1)
    pid = world.stations[0].process.pid
    for attached in (False, True):
        dev = Device.open(world.ports[0]) if attached else None
        before = _cpu_s(pid)
        time.sleep(1.0)
        used = _cpu_s(pid) - before
        if dev is not None:
            dev.ping()
            dev.close()
        assert used < 0.3, (attached, used)


def test_station_classifies_bad_frames_like_the_host(sim_stations: Callable[..., SimWorld]) -> None:
    """Seeded streams of mutated vector frames and junk: the station answers every non-empty
    frame exactly once, in order, and its framing errors (code, detail) are the ones the
    host's FrameDecoder predicts for the same bytes."""
    rng = random.Random(77)
    # every vector but RESET (a mutated frame passes the CRC with probability 2**-32)
    wires = [bytes.fromhex(v["wire"]) for v in VECTORS["frames"] + VECTORS["malformed"]
             if v.get("message") != "reset"]
    port = sim_stations(1).ports[0]
    with Device.open(port) as dev:
        for _round in range(8):
            parts = [b"\x00"]
            for _ in range(25):
                w = bytearray(rng.choice(wires)[:-1])
                if rng.random() < 0.2:
                    w = bytearray(rng.randrange(1, 256) for _ in range(rng.randrange(1, 80)))
                for _flip in range(rng.randrange(0, 3)):
                    w[rng.randrange(len(w))] = rng.randrange(1, 256)
                parts.append(bytes(w) + b"\x00")
            stream = b"".join(parts)
            predicted = FrameDecoder().feed(stream)
            dev.client.send_raw(stream)
            answers = []
            for _ in predicted:
                got = dev.client.read_frame(5.0)
                assert isinstance(got, Frame)
                answers.append(got)
            assert dev.client.read_frame(0.3) is None
            for want, got in zip(predicted, answers, strict=True):
                assert got.is_response
                if isinstance(want, FrameError):
                    e = pg.ErrorResp.decode(got.payload)
                    assert (got.type, got.seq, e.code, e.detail) == (pg.T_ERROR, 0, want.code, want.detail)
                else:
                    assert got.seq == want.seq
            dev.ping(b"still here")


def test_medium_and_stations_share_one_cpu(sim_stations: Callable[..., SimWorld]) -> None:
    """With a medium, the lock-step processes are pinned to sim_cpu(); the host is not."""
    cpu = sim_cpu()
    if cpu is None:
        pytest.skip("one CPU (or UWBCAL_SIM_CPU=none): nothing is pinned")
    probe = subprocess.Popen(["sleep", "5"])
    try:
        os.sched_setaffinity(probe.pid, {cpu})
    except OSError as e:       # some containers refuse it; SimWorld then runs unpinned, by design
        pytest.skip(f"this machine refuses CPU pinning ({e}): SimWorld runs unpinned")
    finally:
        probe.kill()
        probe.wait()
    host_cpus = os.sched_getaffinity(0)
    world = sim_stations(scenario=repo_root() / "scenarios" / "two_stations.toml")
    medium = getattr(world.medium, "process", None)
    assert isinstance(medium, subprocess.Popen)
    for pid in [medium.pid, *(st.process.pid for st in world.stations)]:
        assert os.sched_getaffinity(pid) == {cpu}
    assert os.sched_getaffinity(0) == host_cpus
    # Without a medium the stations are independent and keep every CPU.
    plain = sim_stations(2)
    for st in plain.stations:
        assert os.sched_getaffinity(st.process.pid) == host_cpus
