"""The user's multi-distance job on simulated stations, from the command line: calibrate both
directions, `uwbcal sim move`, `uwbcal range --distances 1,2,4,7 --moves`, `uwbcal analyze twr`
(several sessions) -- and the bar of issue 14: at 1, 2, 4 and 7 m the paper's method (drift +
power curves) has the smallest error spread of all methods, and twr.png draws it."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import pytest
from uwbcal import cli, simregistry
from uwbcal.sessions.store import Session
from uwbcal.simstations import SimWorld, repo_root

SCENARIO = repo_root() / "scenarios" / "two_stations.toml"


def _json(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, dict]:  # type: ignore[type-arg]
    rc = cli.main(list(argv))
    lines = capsys.readouterr().out.strip().splitlines()
    return rc, json.loads(lines[-1])


def test_multi_distance_session_paper_method_has_the_smallest_spread(
        sim_stations: Callable[..., SimWorld], tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("UWBCAL_SIM_DIR", str(tmp_path / "reg"))
    world = sim_stations(scenario=SCENARIO)
    p1, p2 = world.ports
    simregistry.announce([{"id": s.id, "port": s.port} for s in world.stations], world.medium_socket,
                         str(SCENARIO))
    rc, moved = _json(capsys, "sim", "move", "2", "--to", "1,0,1", "--json")
    assert rc == 0 and moved["position_m"] == [1.0, 0.0, 1.0]
    cals = []
    for tx, rx, name in ((p1, p2, "c12"), (p2, p1, "c21")):
        db = tmp_path / f"{name}.db"
        rc, out = _json(capsys, "calibrate", "--tx", tx, "--rx", rx, "--step-db", "1", "--steps", "31",
                        "--per-step", "60", "--distance", "1", "--out", str(db), "--no-progress", "--json")
        assert rc == 0 and out["run"]["complete"], out
        cals += ["--power", str(db)]
    rdb = tmp_path / "r.db"
    rc, out = _json(capsys, "range", "--ref", p1, "--tag", p2, "--count", "150", "--distances", "1,2,4,7",
                    "--moves", "--out", str(rdb), "--no-progress", "--json", *cals)
    assert rc == 0 and out["run"]["records"] == 600, out["run"]
    with Session.open(rdb, readonly=True) as s:
        d = s.read("ranges")["distance_m"]
    assert sorted(set(d.tolist())) == [1.0, 2.0, 4.0, 7.0]
    rc, twr = _json(capsys, "analyze", "twr", str(rdb), "--json", "--plots", str(tmp_path / "plots"), *cals)
    assert rc == 0
    spread = {k: m["std_all_m"] for k, m in twr["methods"].items() if m["std_all_m"] is not None}
    assert min(spread, key=spread.__getitem__) == "paper", spread
    assert spread["paper"] < 0.5 * spread["paper_no_power"]
    assert twr["distances_m"] == [1.0, 2.0, 4.0, 7.0]
    assert twr["corrections"]["power_curves"]["applied"] == 600
    assert twr["warnings"] == []                      # calibrated at 1 m: every level was swept
    assert Path(twr["plots"][0]).stat().st_size > 10_000
