"""Running simulated worlds: where `uwbcal sim` announces its stations and medium.

`uwbcal sim` writes one small JSON file per running world into :func:`registry_dir`
(``$UWBCAL_SIM_DIR``, else ``$XDG_RUNTIME_DIR/uwbcal``, else ``/tmp/uwbcal-<uid>``):
its pid, its stations' ids and ports, and the medium's socket. `uwbcal ports` lists them,
`uwbcal sim move|where` and `uwbcal range --moves` find the medium that serves a port through
them. A file whose process is gone is ignored (and removed when seen).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from uwbcal.errors import UwbcalError


class NoSimulation(UwbcalError):
    """No running `uwbcal sim` serves what was asked for."""

    exit_code = 8


def registry_dir() -> Path:
    """Directory of the running worlds' files."""
    env = os.environ.get("UWBCAL_SIM_DIR")
    if env:
        return Path(env)
    run = os.environ.get("XDG_RUNTIME_DIR")
    return Path(run) / "uwbcal" if run else Path(f"/tmp/uwbcal-{os.getuid()}")


def announce(stations: list[dict[str, Any]], medium_socket: str | None, scenario: str | None) -> Path:
    """Write this process' world file (stations: ``{"id", "port"}``); returns its path."""
    d = registry_dir()
    d.mkdir(parents=True, exist_ok=True)
    path = d / f"sim-{os.getpid()}.json"
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps({"pid": os.getpid(), "stations": stations, "medium_socket": medium_socket,
                               "scenario": scenario}))
    tmp.replace(path)
    return path


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def running() -> list[dict[str, Any]]:
    """Every running world's record (pid, stations, medium_socket, scenario), oldest pid first."""
    d = registry_dir()
    out: list[dict[str, Any]] = []
    if not d.is_dir():
        return out
    for f in sorted(d.glob("sim-*.json")):
        try:
            doc = json.loads(f.read_text())
            pid = int(doc["pid"])
        except (OSError, ValueError, KeyError, TypeError):
            continue
        if not _alive(pid):
            f.unlink(missing_ok=True)
            continue
        out.append(doc)
    return sorted(out, key=lambda w: int(w["pid"]))


def world_of_port(port: str) -> dict[str, Any] | None:
    """The running world one of whose stations is on ``port`` (None when none is)."""
    real = os.path.realpath(port)
    for w in running():
        if any(os.path.realpath(s["port"]) == real for s in w["stations"]):
            return w
    return None


def station_on(world: dict[str, Any], port: str) -> int:
    """Station id on ``port`` in ``world``."""
    real = os.path.realpath(port)
    for s in world["stations"]:
        if os.path.realpath(s["port"]) == real:
            return int(s["id"])
    raise NoSimulation(f"{port}: not a station of the simulated world of pid {world['pid']}")


def the_world(pid: int | None = None) -> dict[str, Any]:
    """The running world with a medium (``pid`` picks one when several run)."""
    worlds = [w for w in running() if w.get("medium_socket") and (pid is None or int(w["pid"]) == pid)]
    if not worlds:
        raise NoSimulation("no running `uwbcal sim --scenario ...` with a radio medium"
                           + ("" if pid is None else f" with pid {pid}"))
    if len(worlds) > 1:
        raise NoSimulation(f"several simulated worlds run (pids {[w['pid'] for w in worlds]}): give --pid")
    return worlds[0]
