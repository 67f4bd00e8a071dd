"""Hardware-in-the-loop without hardware: simulated stations (the native firmware, ASan+UBSan
build by default) as processes on ptys, talked to with the real host code.

Fixtures:
  station_binary     the station executable ($UWBCAL_STATION, else build/native-asan/...)
  sim_stations       factory: ``world = sim_stations(n, scenario=None, **SimWorld kwargs)``
                     (``binary=`` another station program, e.g. the USB station's launcher)
                     starts n stations (ids 1..n) that answer PING and returns the running
                     :class:`~uwbcal.simworld.SimWorld` (``world.ports``, ``world.stations``).
                     At teardown every station is stopped with SIGTERM and must exit cleanly
                     (code 0: no sanitizer report, no crash); otherwise the test fails and
                     names the log.
  sim_ports          shortcut: ``sim_ports(n)`` -> list of n ports.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from uwbcal.simworld import SimWorld, repo_root

ASAN_STATION = repo_root() / "build" / "native-asan" / "uwbcal-station"


@pytest.fixture(scope="session")
def station_binary() -> Path:
    env = os.environ.get("UWBCAL_STATION")
    path = Path(env) if env else ASAN_STATION
    if not path.is_file():
        if env:
            pytest.fail(f"UWBCAL_STATION={env} does not exist")
        pytest.skip(f"no station binary at {path}: run `make native`")
    return path


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
