"""The firmware programs TX_ANTD and LDE_RXANTD from its calibration table (issue 14): a table
pushed with antenna delays 100 device units above what the host asks for shortens every raw
range by 100 units (about 0.47 m: the tag's reply looks 2 x 100 units longer), and erasing the
table restores the host's values."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from uwbcal import cli, dw1000, tables
from uwbcal.corrections import twr
from uwbcal.corrections.power import PowerCurve
from uwbcal.device import Device
from uwbcal.sessions.runner import DEFAULT_ANTD
from uwbcal.sessions.store import Session
from uwbcal.simstations import SimWorld, repo_root

SCENARIO = repo_root() / "scenarios" / "two_stations.toml"
CURVE = PowerCurve(measured_dbm=(-100.0, -80.0), error_s=(0.0, 0.0), real_dbm=(-100.0, -80.0),
                   reference_real_dbm=-80.0, reference_measured_dbm=-80.0)


def _raw_range_m(db: Path) -> float:
    with Session.open(db, readonly=True) as s:
        rg = s.read("ranges")
    tof = twr.paper_tof_units(rg["t1r"], rg["t1t"], rg["t2t"], rg["t2r"], rg["t3r"], rg["t3t"])
    return float(np.median(twr.units_to_range_m(tof)))


def _range(world: SimWorld, db: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["range", "--ref", world.ports[0], "--tag", world.ports[1], "--count", "60", "--out",
                     str(db), "--no-progress", "--json"]) == 0
    json.loads(capsys.readouterr().out.strip().splitlines()[-1])


def test_table_antenna_delays_are_programmed(sim_stations: Callable[..., SimWorld], tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    world = sim_stations(scenario=SCENARIO)
    _range(world, tmp_path / "before.db", capsys)
    with Device.open(world.ports[1]) as dev:
        uid = bytes(dev.info().uid)
        antd = DEFAULT_ANTD + 100
        tables.push(dev.client, tables.build(uid, CURVE, tx_antd=antd, rx_antd=antd))
    _range(world, tmp_path / "with_table.db", capsys)
    with Device.open(world.ports[1]) as dev:
        tables.erase(dev.client)
    _range(world, tmp_path / "after.db", capsys)
    before, with_table, after = (_raw_range_m(tmp_path / f"{n}.db")
                                 for n in ("before", "with_table", "after"))
    assert with_table - before == pytest.approx(-100 * dw1000.METRES_PER_UNIT, abs=0.02)
    assert after == pytest.approx(before, abs=0.02)
