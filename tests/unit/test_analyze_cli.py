"""`uwbcal analyze drift|power|twr` on simulated session files: JSON, stored results, plots."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from uwbcal import cli, dw1000, vectorsim
from uwbcal.physics.scenario import load_scenario
from uwbcal.sessions.store import Session


@pytest.fixture(scope="module")
def sessions(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("sessions")
    sc = load_scenario("paper_antenna")
    out = {}
    out["drift"] = vectorsim.simulate_session(sc, vectorsim.drift_schedule(sc, 1000), d / "drift.db", seed=3)
    out["p1"] = vectorsim.simulate_session(sc, vectorsim.power_schedule(sc, 60, 300, step_db=0.5),
                                           d / "p1.db", seed=4)
    out["p2"] = vectorsim.simulate_session(sc, vectorsim.power_schedule(sc, 60, 300, step_db=0.5, tx=1, rx=2),
                                           d / "p2.db", seed=5)
    out["twr"] = vectorsim.simulate_session(
        sc, vectorsim.twr_schedule(sc, per_distance=200, gain=dw1000.gain_octet(0, 13)), d / "twr.db", seed=6)
    return out


def run_json(args: list[str], capsys: pytest.CaptureFixture[str]) -> dict:  # type: ignore[type-arg]
    assert cli.main(args) == 0
    return json.loads(capsys.readouterr().out)  # type: ignore[no-any-return]


def test_analyze_drift(sessions: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    r = run_json(["analyze", "drift", str(sessions["drift"]), "--json", "--plots", str(tmp_path)], capsys)
    (pair,) = r["pairs"]
    assert (pair["tx_station"], pair["rx_station"]) == (2, 1)
    assert abs(pair["uncorrected"]["mean_m"]) > 1.0
    assert abs(pair["corrected"]["mean_m"]) < 4 * pair["corrected"]["sem_m"] + 1e-5
    assert pair["carrier_integrator"] is not None
    assert Path(r["plots"][0]).exists()
    with Session.open(sessions["drift"]) as s:
        assert s.result("analyze_drift")["pairs"][0]["corrected"]["n"] == 1000


def test_analyze_power_then_twr(sessions: dict[str, Path], tmp_path: Path,
                                capsys: pytest.CaptureFixture[str]) -> None:
    r = run_json(["analyze", "power", str(sessions["p1"]), "--json"], capsys)
    (c,) = r["calibrations"]
    assert c["rx_station"] == 1 and len(c["steps"]) == 60
    assert np.all(np.diff(c["curve"]["measured_dbm"]) > 0)
    run_json(["analyze", "power", str(sessions["p2"]), "--json"], capsys)
    t = run_json(["analyze", "twr", str(sessions["twr"]), "--json", "--power", str(sessions["p1"]),
                  "--power", str(sessions["p2"]), "--plots", str(tmp_path)], capsys)
    assert t["curves_for_stations"] == [1, 2]
    assert t["missing_methods"] == ["station"]      # the vectorised simulator has no on-station table
    m = t["methods"]
    assert len(t["distances_m"]) == 11
    assert m["paper"]["std_all_m"] < m["paper_no_power"]["std_all_m"]
    assert m["paper"]["std_all_m"] < m["paper_no_drift"]["std_all_m"]
    # text report works too
    assert cli.main(["analyze", "twr", str(sessions["twr"]), "--no-store"]) == 0
    assert "paper_no_power" in capsys.readouterr().out


def test_analyze_errors_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                     sessions: dict[str, Path]) -> None:
    assert cli.main(["analyze", "drift", str(tmp_path / "missing.db")]) == 5
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no such session" in err
    assert cli.main(["analyze", "twr", str(sessions["drift"])]) == 5  # no range records
    assert "no range records" in capsys.readouterr().err


def test_analyze_drift_on_imported_real_data(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # The real two-node sample (tests/data/asil, see its PROVENANCE.md): timestamps unwrapped at the
    # source, no RX registers. Eq. 1 takes C12 from tens of metres to a residual consistent with 0.
    sample = Path(__file__).resolve().parents[1] / "data" / "asil" / "run"
    db = tmp_path / "asil.db"
    assert cli.main(["import", "asil", str(sample), "--out", str(db)]) == 0
    capsys.readouterr()
    r = run_json(["analyze", "drift", str(db), "--json"], capsys)
    assert len(r["pairs"]) == 2
    for p in r["pairs"]:
        assert abs(p["uncorrected"]["mean_m"]) > 10.0
        assert 5.0 < abs(p["drift_ppm_mean"]) < 8.0
        assert abs(p["corrected"]["mean_m"]) < 4 * p["corrected"]["sem_m"]
        assert p["corrected"]["std_m"] < 0.1
        assert p["carrier_integrator"] is None
    # the two directions see opposite clock offsets
    assert r["pairs"][0]["drift_ppm_mean"] == pytest.approx(-r["pairs"][1]["drift_ppm_mean"], abs=0.01)
