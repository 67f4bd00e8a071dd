"""A fleet on simulated stations: `uwbcal calibrate --stations P1,P2,P3` runs every ordered pair
into one session; `uwbcal table build` writes each station's table; `table push --all` and
`table verify --all` give each station the table made for its UID."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import pytest
from uwbcal import cli
from uwbcal.sessions.store import Session
from uwbcal.simstations import SimWorld, repo_root

SCENARIO = repo_root() / "scenarios" / "three_stations.toml"


def test_fleet_calibration_tables_for_every_station(sim_stations: Callable[..., SimWorld], tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    world = sim_stations(scenario=SCENARIO)
    ports = ",".join(world.ports)
    db = tmp_path / "fleet.db"
    rc = cli.main(["calibrate", "--stations", ports, "--step-db", "1", "--steps", "31", "--per-step", "20",
                   "--out", str(db), "--no-progress", "--json"])
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert rc == 0 and out["run"]["complete"] and out["run"]["records"] == 6 * 31 * 20, out["run"]
    pairs = {(c["tx_station"], c["rx_station"]) for c in out["analysis"]["calibrations"]}
    assert pairs == {(a, b) for a in (1, 2, 3) for b in (1, 2, 3) if a != b}
    with Session.open(db, readonly=True) as s:
        assert s.meta["settings"]["pairs"] == [[1, 2], [1, 3], [2, 1], [2, 3], [3, 1], [3, 2]]
    tables = tmp_path / "tables"
    assert cli.main(["table", "build", str(db), "--out", str(tables), "--json"]) == 0
    built = json.loads(capsys.readouterr().out)["tables"]
    assert [t["station"] for t in built] == [1, 2, 3]
    assert all(t["validity"]["swept_measured_dbm"][0] < t["validity"]["swept_measured_dbm"][1] for t in built)
    # push in reverse port order: each station still gets its own table, matched by UID
    rev = ",".join(reversed(world.ports))
    assert cli.main(["table", "push", "--all", "--ports", rev, str(tables), "--json"]) == 0
    pushed = json.loads(capsys.readouterr().out)["pushed"]
    by_port = {p["port"]: Path(p["table"]).name for p in pushed}
    assert by_port == {world.ports[i]: f"station{i + 1}.json" for i in range(3)}
    assert cli.main(["table", "verify", "--all", "--ports", ports, str(tables), "--json"]) == 0
    assert all(v["matches"] and v["applied"] for v in json.loads(capsys.readouterr().out)["verified"])
