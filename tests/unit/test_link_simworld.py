"""SimWorld's failure paths with stand-in station programs (shell scripts): every way a
station can fail to start is a one-line SimError, and nothing is left running."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest
from uwbcal.simstations import SimError, SimWorld, sim_cpu, station_binary


def script(tmp_path: Path, body: str) -> Path:
    p = tmp_path / "fake-station"
    p.write_text("#!/bin/sh\n" + body + "\n")
    p.chmod(p.stat().st_mode | stat.S_IXUSR)
    return p


@pytest.mark.parametrize(
    "body, message, timeout_s",
    [
        # the timeout is generous where the outcome must come before it (a loaded machine may
        # be slow to run the script), short where the outcome is the timeout itself
        ('echo "boom: no pty" >&2; exit 3', r"exited with code 3 before serving: boom: no pty", 10.0),
        ("echo HELLO; exec sleep 30", "unexpected first line 'HELLO'", 10.0),
        ("exec sleep 30", "printed no PTY line", 1.0),
        ("echo PTY /dev/uwbcal-no-such-pty; exec sleep 30", "does not answer PING", 1.0),
    ],
)
def test_start_failures(tmp_path: Path, body: str, message: str, timeout_s: float) -> None:
    world = SimWorld(n_stations=2, binary=script(tmp_path, body), workdir=tmp_path / "w",
                     start_timeout_s=timeout_s)
    with pytest.raises(SimError, match=message):
        world.start()
    assert world.stations and all(s.process.poll() is not None for s in world.stations)


def test_missing_binary_says_make_native(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("UWBCAL_STATION", str(tmp_path / "nope"))
    with pytest.raises(SimError, match="make native"):
        station_binary()
    with pytest.raises(SimError, match="make native"):
        station_binary(tmp_path / "also-nope")


def test_station_arguments(tmp_path: Path) -> None:
    """Each station gets its id, its own flash file in the workdir and the medium socket."""
    out = tmp_path / "args"
    body = f'echo "$@" >> {out}; echo "boom" >&2; exit 1'
    world = SimWorld(n_stations=1, ids=[5], binary=script(tmp_path, body), workdir=tmp_path / "w")
    world.medium_socket = "/tmp/medium.sock"
    with pytest.raises(SimError):
        world.start()
    assert out.read_text().split() == [
        "--id",
        "5",
        "--flash",
        str(tmp_path / "w" / "station-5.flash"),
        "--medium",
        "/tmp/medium.sock",
    ]
    assert os.path.isdir(tmp_path / "w")


def test_sim_cpu_choice(monkeypatch: pytest.MonkeyPatch) -> None:
    """$UWBCAL_SIM_CPU: auto takes the highest allowed CPU when there are two or more, none
    turns pinning off, a number must be an allowed CPU, anything else is a named error."""
    allowed = sorted(os.sched_getaffinity(0))
    assert sim_cpu("none") is None
    assert sim_cpu("off") is None
    assert sim_cpu("auto") == (allowed[-1] if len(allowed) >= 2 else None)
    assert sim_cpu(str(allowed[0])) == allowed[0]
    monkeypatch.setenv("UWBCAL_SIM_CPU", "none")
    assert sim_cpu() is None
    monkeypatch.setattr(os, "sched_getaffinity", lambda _pid: {0, 1, 2})
    assert sim_cpu("") == 2
    with pytest.raises(SimError, match="CPUs \\[0, 1, 2\\] only"):
        sim_cpu("5")
    with pytest.raises(SimError, match="expected auto, none or a CPU number"):
        sim_cpu("fast")
    monkeypatch.setattr(os, "sched_getaffinity", lambda _pid: {3})
    assert sim_cpu("auto") is None  # one CPU: nothing to gain
