"""Hardware-in-the-loop without hardware: simulated stations (the native firmware, ASan+UBSan
build by default) as processes on ptys, talked to with the real host code.

Fixtures:
  station_binary     the station executable ($UWBCAL_STATION, else build/native-asan/...),
                     never older than the firmware sources: a build output of this tree is
                     brought up to date with `make` (from any entry point, bare pytest
                     included); any other binary older than a source is refused
  sim_stations       factory: ``world = sim_stations(n, scenario=None, **SimWorld kwargs)``
                     (``binary=`` another station program, e.g. the USB station's launcher)
                     starts n stations (ids 1..n) that answer PING and returns the running
                     :class:`~uwbcal.simstations.SimWorld` (``world.ports``, ``world.stations``).
                     At teardown every station is stopped with SIGTERM and must exit cleanly
                     (code 0: no sanitizer report, no crash); otherwise the test fails and
                     names the log.
  sim_ports          shortcut: ``sim_ports(n)`` -> list of n ports.
"""

from __future__ import annotations

import os
import subprocess
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from uwbcal.simstations import SimWorld, repo_root

ASAN_STATION = repo_root() / "build" / "native-asan" / "uwbcal-station"


#: What a station binary is built from (the Makefile's FW_SRC, NATIVE_SRC and FW_HDR).
FIRMWARE_SOURCES = ("firmware/core", "firmware/dw1000", "firmware/boards/native")


def _newest_source() -> tuple[float, Path]:
    root = repo_root()
    files = [p for d in FIRMWARE_SOURCES for p in (root / d).glob("*.[ch]")] + [root / "VERSION"]
    return max((p.stat().st_mtime, p) for p in files)


def fresh_station(path: Path) -> Path:
    """``path``, made or checked current with the firmware sources in this tree.

    A build output of this tree (build/native*/uwbcal-station) is handed to ``make``, which
    rebuilds it when any source (or the version flags) changed. Any other binary is refused
    when it is older than the newest source: a stale station would test old code."""
    root = repo_root()
    try:
        target = path.resolve().relative_to(root)
    except ValueError:
        target = None
    if target is not None and target.parts[0] == "build" and target.name == "uwbcal-station":
        res = subprocess.run(["make", "-s", "--no-print-directory", "-C", str(root), str(target)],
                             capture_output=True, text=True)
        if res.returncode != 0:
            pytest.fail(f"`make {target}` failed:\n{res.stdout}{res.stderr}")
        return path
    if not path.is_file():
        pytest.fail(f"UWBCAL_STATION={path} does not exist")
    when, newest = _newest_source()
    if path.stat().st_mtime < when:
        pytest.fail(f"UWBCAL_STATION={path} is older than {newest.relative_to(root)}: rebuild it")
    return path


@pytest.fixture(scope="session")
def station_binary() -> Path:
    env = os.environ.get("UWBCAL_STATION")
    return fresh_station(Path(env) if env else ASAN_STATION)


@pytest.fixture
def sim_stations(station_binary: Path, tmp_path: Path) -> Iterator[Callable[..., SimWorld]]:
    worlds: list[SimWorld] = []

    def start(n: int = 1, scenario: Path | None = None, **kw: Any) -> SimWorld:
        kw.setdefault("binary", station_binary)  # another station program may be given
        world = SimWorld(
            n_stations=n,
            scenario=scenario,
            workdir=tmp_path / f"world{len(worlds)}",
            **kw,
        )
        worlds.append(world)
        world.start()
        return world

    yield start
    problems = []
    for world in worlds:
        for sid, code in world.stop().items():
            if code != 0:
                log = world.workdir / f"station-{sid}.log" if world.workdir else "?"
                problems.append(f"station {sid} exited with code {code} (log: {log})")
    if problems:
        pytest.fail("; ".join(problems))


@pytest.fixture
def sim_ports(sim_stations: Callable[..., SimWorld]) -> Callable[[int], list[str]]:
    def start(n: int = 1) -> list[str]:
        return sim_stations(n).ports

    return start
